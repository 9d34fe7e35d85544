"""A 3-D scene for :mod:`localization.bench.georender` from OpenStreetMap: heights from the tags.

The geometry and the classes come from the builder's own OSM reader
(:func:`osmseg.osm.features.read_features`: the same class rules that draw the label masks);
the heights from a second, small pass over the file with osmium that reads what OSM says of
them, since the label masks have no use for heights:

* **buildings**: ``height`` (metres; ``"12 m"``, ``"40'"`` and ``"40 ft"`` understood), else
  ``building:levels`` x 3 m + 1 m of roof, else a height drawn per building from
  :data:`BUILDING_FALLBACK_M` with the scene's seed (most OSM buildings carry neither tag); a
  ``min_height`` lifts the base (a bridge-like upper floor).
* **trees** (``natural=tree`` nodes, drawn by the rules as crowns of ``diameter_crown``):
  ``height`` else a seeded draw from :data:`TREE_FALLBACK_M`; the crown starts at a third of
  the height and lets some rays through (:func:`localization.bench.georender.tree_crown`).
* **woods** (``natural=wood``, ``landuse=forest``): standing trees on a jittered grid of
  :data:`WOOD_SPACING_M` inside the area, each a crown as above.
* everything else is ground, drawn in the rules' order (roads over grass).

Coordinates: Web Mercator metres are scaled by ``cos(latitude)`` of the scene's centre to
metres on the ground, with the centre at (0, 0) (x east, y north). Every random draw depends
on ``seed`` and the object's OSM id only, so a scene is the same whatever part of the file or
order of reading.
"""

from __future__ import annotations

import dataclasses
import math
import re
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mercantile
import numpy as np
import osmium
import shapely
from shapely.geometry.base import BaseGeometry

from localization.bench.georender import GroundPatch, Scene, Solid, tree_crown
from osmseg.classes import ClassTable
from osmseg.errors import ConfigError
from osmseg.grid import ground_resolution, sample_grid
from osmseg.osm.features import read_features

__all__ = ["BUILDING_FALLBACK_M", "TREE_FALLBACK_M", "WOOD_SPACING_M", "OsmScene", "parse_height",
           "read_heights", "scene_from_osm"]

#: heights drawn (uniformly, per object, seeded) when OSM says nothing
BUILDING_FALLBACK_M = (4.0, 16.0)
TREE_FALLBACK_M = (6.0, 15.0)
#: spacing of the standing trees put into woods and forests
WOOD_SPACING_M = 7.0
LEVEL_M, ROOF_M = 3.0, 1.0
_HEIGHT_KEYS = ("height", "building:levels", "min_height")
_WOOD = {("natural", "wood"), ("landuse", "forest")}
_NUMBER = re.compile(r"^\s*([0-9]+(?:[.,][0-9]+)?)\s*(m|metres|meters|ft|feet|'|)\s*$", re.IGNORECASE)


def parse_height(text: str | None) -> float | None:
    """Metres from an OSM height value, None when it is not one.

    >>> parse_height("12"), parse_height("12.5 m"), parse_height("40'"), parse_height("tall")
    (12.0, 12.5, 12.192, None)
    """
    if text is None:
        return None
    m = _NUMBER.match(text)
    if not m:
        return None
    value = float(m.group(1).replace(",", "."))
    return round(value * 0.3048, 3) if m.group(2).lower() in ("ft", "feet", "'") else value


@dataclass(frozen=True)
class Tags:
    """What OSM says of one object's height, and whether it is a wood."""

    height: float | None = None
    levels: float | None = None
    min_height: float | None = None
    wood: bool = False


def read_heights(paths: Sequence[Path | str]) -> dict[str, Tags]:
    """The height tags of every object that has one, or is a wood, keyed ``"n<id>"``,
    ``"w<id>"``, ``"r<id>"`` as :class:`osmseg.osm.features.Feature` names them (one osmium
    pass per file, only tagged objects reach Python)."""
    found: dict[str, Tags] = {}
    keys = (*_HEIGHT_KEYS, "natural", "landuse")
    for path in paths:
        for obj in osmium.FileProcessor(str(path)).with_filter(osmium.filter.KeyFilter(*keys)):
            tags = obj.tags
            wood = any(tags.get(k) == v for k, v in _WOOD)
            levels = parse_height(tags.get("building:levels"))
            entry = Tags(parse_height(tags.get("height")), levels, parse_height(tags.get("min_height")), wood)
            if entry != Tags():
                found[f"{obj.type_str()}{obj.id}"] = entry
    return found


def _draw(seed: int, osm_id: str, span: tuple[float, float]) -> float:
    rng = np.random.default_rng([seed, zlib.crc32(osm_id.encode())])
    return round(float(rng.uniform(*span)), 2)


def building_height(tags: Tags | None, seed: int, osm_id: str) -> float:
    """A building's height in metres: its tag, else its levels, else a seeded draw.

    >>> building_height(Tags(height=20.0), 0, "w1"), building_height(Tags(levels=2), 0, "w1")
    (20.0, 7.0)
    >>> 4.0 <= building_height(None, 0, "w1") <= 16.0
    True
    """
    if tags is not None and tags.height:
        return tags.height
    if tags is not None and tags.levels:
        return tags.levels * LEVEL_M + ROOF_M
    return _draw(seed, osm_id, BUILDING_FALLBACK_M)


@dataclass(frozen=True)
class OsmScene:
    """A scene in ground metres around (``lon``, ``lat``), which is (0, 0)."""

    scene: Scene
    lon: float
    lat: float

    def to_local(self, lon: float, lat: float) -> tuple[float, float]:
        """Ground metres east and north of the centre of a point given in degrees."""
        x0, y0 = mercantile.xy(self.lon, self.lat)
        x, y = mercantile.xy(lon, lat)
        k = math.cos(math.radians(self.lat))
        return (x - x0) * k, (y - y0) * k


def _local(geometry: BaseGeometry, origin: tuple[float, float], k: float) -> BaseGeometry:
    return shapely.transform(geometry, lambda xy: (xy - np.asarray(origin)) * k)


def _polygons(geometry: BaseGeometry) -> list[BaseGeometry]:
    return [g for g in getattr(geometry, "geoms", [geometry]) if g.geom_type == "Polygon" and not g.is_empty]


def _wood_trees(area: BaseGeometry, seed: int, osm_id: str) -> list[tuple[float, float, float]]:
    """(x, y, height) of standing trees on a jittered grid inside ``area``."""
    x0, y0, x1, y1 = area.bounds
    xs, ys = np.meshgrid(np.arange(x0, x1, WOOD_SPACING_M), np.arange(y0, y1, WOOD_SPACING_M))
    rng = np.random.default_rng([seed, zlib.crc32(osm_id.encode()), 1])
    px = xs.ravel() + rng.uniform(0, WOOD_SPACING_M, xs.size)
    py = ys.ravel() + rng.uniform(0, WOOD_SPACING_M, xs.size)
    heights = rng.uniform(*TREE_FALLBACK_M, xs.size)
    inside = shapely.contains_xy(area, px, py)
    return list(zip(px[inside].tolist(), py[inside].tolist(), heights[inside].tolist(), strict=True))


def scene_from_osm(paths: Sequence[Path | str], lon: float, lat: float, table: ClassTable, radius_m: float = 200.0,
                   seed: int = 0, ground_class: str | None = None) -> OsmScene:
    """The scene within about ``radius_m`` of (``lon``, ``lat``) from OSM file(s) ``paths``,
    classed by ``table`` (which must have a ``building`` class; ``tree`` is used for crowns when
    it has one). ``ground_class``: the class of ground no feature covers (default unlabeled)."""
    if "building" not in table.by_name:
        raise ConfigError(f"class table {table.name} has no building class; a 3-D scene needs one")
    if not table.has_rules:
        raise ConfigError(f"class table {table.name!r} carries no OSM tag rules (a dataset or checkpoint records its "
                          "classes' names and colours only), so it cannot draw the OSM file: the table file the dataset "
                          "was built with is not where the build read it; put it back, or run from the folder the "
                          "build ran in")
    zoom = 18
    tile_m = ground_resolution(lat, zoom) * 256
    size = 2 * math.ceil(radius_m / tile_m) + 1
    grid = sample_grid(lon, lat, zoom, size)
    # a mapped table (classes6) draws with its base's rules (classes13), then names the classes its own way
    lookup = table.lookup_from_base()
    features = [dataclasses.replace(f, class_id=int(lookup[f.class_id]))
                for f in read_features(list(paths), grid, table.base or table)]
    heights = read_heights(paths)
    origin, k = mercantile.xy(lon, lat), math.cos(math.radians(lat))
    building = table.by_name["building"].id
    tree = table.by_name["tree"].id if "tree" in table.by_name else None
    solids: list[Solid] = []
    ground: list[tuple[int, int, GroundPatch]] = []
    for i, f in enumerate(features):
        geometry = _local(f.geometry, origin, k)
        tags = heights.get(f.osm_id)
        if f.class_id == building:
            top = building_height(tags, seed, f.osm_id)
            base = min(tags.min_height or 0.0, top / 2) if tags is not None else 0.0
            solids += [Solid(p, base, top, building) for p in _polygons(geometry)]
        elif tree is not None and f.class_id == tree and f.kind == "point":
            c = geometry.centroid
            height = (tags.height if tags is not None and tags.height else None) or _draw(seed, f.osm_id, TREE_FALLBACK_M)
            radius = math.sqrt(geometry.area / math.pi)
            solids.append(tree_crown(c.x, c.y, height, tree, radius_m=radius))
        else:
            ground += [(f.order, i, GroundPatch(p, f.class_id)) for p in _polygons(geometry)]
            if tags is not None and tags.wood:
                for x, y, h in _wood_trees(geometry, seed, f.osm_id):
                    solids.append(tree_crown(x, y, h, tree if tree is not None else f.class_id))
    ground.sort(key=lambda t: (t[0], t[1]))  # the rules' draw order, file order within it
    base_class = table.by_name[ground_class].id if ground_class else table.unlabeled.id
    return OsmScene(Scene(tuple(solids), tuple(g for _, _, g in ground), base_class, seed), lon, lat)
