"""GeoJSON geometries as an extra OSM label source (``--osm geojson:PATH:key=value``).

Some label sets come as plain geometries without OSM tags: building footprints exported from
OSM or traced by others (the Kampala footprints in ``../shared/data``), a land-cover survey.
This source turns the features of a GeoJSON FeatureCollection (WGS84, RFC 7946) that touch
a box into an OSM XML file carrying the tags given to it (``{"building": "yes"}``), so they
go through the same parser and class rules as any OSM data:

* Point / MultiPoint -> tagged nodes;
* LineString / MultiLineString -> tagged ways;
* Polygon without holes -> a tagged closed way;
* Polygon with holes, MultiPolygon -> a tagged ``type=multipolygon`` relation with
  untagged outer/inner member ways (holes stay holes);
* GeometryCollection -> each member as above.

Features are selected, not cut: every feature whose geometry intersects the box is written
whole (the parser clips at the sample edge).  Ids start at :data:`ID_BASE` (far above OSM's)
and follow the order of the features in the file, so the output is deterministic.  The
file is read once and indexed (shapely STRtree); unreadable geometries are skipped with a
warning.  Timestamp: the GeoJSON file's modification time (GeoJSON carries none).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator, Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import osmium
import osmium.osm.mutable as mutable
import shapely
from shapely.geometry import shape
from shapely.geometry.base import BaseGeometry

from osmseg.errors import ConfigError, OSMDataError
from osmseg.grid import LngLatBBox
from osmseg.osm.base import OsmExtract
from osmseg.osm.store import cache_name, check_bbox, iso_utc, read_done, write_done
from osmseg.output.atomic import atomic_path

logger = logging.getLogger(__name__)

#: Ids of the objects made start above this. Not negative ids (JOSM's convention for new
#: objects): pyosmium's node location cache, which the parser uses, ignores negative ids.
#: OSM's own ids are below 2e10 today, so 10**15 never clashes when sources are merged.
ID_BASE = 10**15


class _OsmBuilder:
    """Collects nodes, ways and relations with ids from :data:`ID_BASE` for one output file."""

    def __init__(self) -> None:
        self.nodes: list[mutable.Node] = []
        self.ways: list[mutable.Way] = []
        self.relations: list[mutable.Relation] = []

    def node(self, lon: float, lat: float, tags: Mapping[str, str] | None = None) -> int:
        nid = ID_BASE + len(self.nodes) + 1
        self.nodes.append(mutable.Node(id=nid, location=(lon, lat), tags=dict(tags or {})))
        return nid

    def way(self, coords: Any, tags: Mapping[str, str] | None = None, closed: bool = False) -> int:
        points = [tuple(c[:2]) for c in coords]
        if closed and len(points) > 1 and points[0] == points[-1]:
            points = points[:-1]
        refs = [self.node(x, y) for x, y in points]
        if closed:
            refs.append(refs[0])
        wid = ID_BASE + len(self.ways) + 1
        self.ways.append(mutable.Way(id=wid, nodes=refs, tags=dict(tags or {})))
        return wid

    def add(self, geom: BaseGeometry, tags: Mapping[str, str]) -> None:
        kind = geom.geom_type
        if kind == "Point":
            self.node(geom.x, geom.y, tags)
        elif kind == "LineString":
            if len(geom.coords) >= 2:
                self.way(geom.coords, tags)
        elif kind == "Polygon" and not geom.interiors:
            if len(geom.exterior.coords) >= 4:
                self.way(geom.exterior.coords, tags, closed=True)
        elif kind in ("Polygon", "MultiPolygon"):
            members = []
            for poly in shapely.get_parts(geom):
                if len(poly.exterior.coords) < 4:
                    continue
                members.append(("w", self.way(poly.exterior.coords, closed=True), "outer"))
                members.extend(("w", self.way(ring.coords, closed=True), "inner") for ring in poly.interiors)
            if members:
                rid = ID_BASE + len(self.relations) + 1
                self.relations.append(mutable.Relation(id=rid, members=members,
                                                       tags={"type": "multipolygon", **tags}))
        else:  # Multi* and GeometryCollection
            for part in shapely.get_parts(geom):
                self.add(part, tags)

    def write(self, path: Path) -> dict[str, int]:
        """Write everything as OSM XML to ``path`` atomically; returns the counts."""
        with atomic_path(path) as tmp:
            with osmium.SimpleWriter(osmium.io.File(str(tmp), "osm"), overwrite=True) as writer:
                for n in self.nodes:
                    writer.add_node(n)
                for w in self.ways:
                    writer.add_way(w)
                for r in self.relations:
                    writer.add_relation(r)
        return {"n": len(self.nodes), "w": len(self.ways), "r": len(self.relations)}


def parse_tags(text: str) -> dict[str, str]:
    """``key=value[,key=value...]`` as a dict; ConfigError if malformed.

    >>> parse_tags("building=yes"), parse_tags("landuse=forest,leaf_type=broadleaved")
    ({'building': 'yes'}, {'landuse': 'forest', 'leaf_type': 'broadleaved'})
    """
    tags = {}
    for item in text.split(","):
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise ConfigError(f"GeoJSON tags {text!r}: write them as key=value[,key=value], e.g. building=yes")
        tags[key.strip()] = value.strip()
    return tags


class GeoJsonSource:
    """Features of a GeoJSON file, tagged with ``tags``, as OSM XML per box (see the module doc).

    Args:
        path: a GeoJSON FeatureCollection in WGS84 longitude/latitude.
        workdir: folder for the OSM files made (created).
        tags: OSM tags given to every feature, e.g. ``{"building": "yes"}``.
    """

    name = "geojson"
    attribution = "see the GeoJSON file's source for its licence"

    def __init__(self, path: Path, workdir: Path, tags: Mapping[str, str]) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise ConfigError(f"--osm geojson:{self.path}: file not found; give the path of a GeoJSON FeatureCollection")
        if not tags or not all(isinstance(k, str) and isinstance(v, str) and k and v for k, v in tags.items()):
            raise ConfigError(f"--osm geojson:{self.path}: give the OSM tags for its features, e.g. geojson:PATH:building=yes")
        self.workdir = Path(workdir)
        self.tags = dict(sorted(tags.items()))
        stat = self.path.stat()
        self._identity = (str(self.path.resolve()), str(stat.st_size), str(stat.st_mtime_ns),
                          json.dumps(self.tags, sort_keys=True))
        self._timestamp = iso_utc(datetime.fromtimestamp(stat.st_mtime, tz=timezone.utc))
        self._geoms: list[BaseGeometry] | None = None
        self._tree: shapely.STRtree | None = None

    def _load(self) -> tuple[list[BaseGeometry], shapely.STRtree]:
        if self._geoms is None or self._tree is None:
            self._geoms = list(_read_geometries(self.path))
            self._tree = shapely.STRtree(self._geoms)
        return self._geoms, self._tree

    def fetch(self, bbox: LngLatBBox) -> OsmExtract:
        """An OSM XML file of the features that intersect ``bbox`` (reused when already made)."""
        bbox = check_bbox(bbox)
        stem = cache_name("geojson", bbox, *self._identity)
        marker = self.workdir / f"{stem}.json"
        done = read_done(marker)
        if done is not None:
            return done
        geoms, tree = self._load()
        hits = sorted(int(i) for i in tree.query(shapely.box(*bbox), predicate="intersects"))
        builder = _OsmBuilder()
        for i in hits:
            builder.add(geoms[i], self.tags)
        self.workdir.mkdir(parents=True, exist_ok=True)
        path = self.workdir / f"{stem}.osm"
        counts = builder.write(path)
        info = {"source": "geojson", "path": str(self.path), "tags": self.tags, "bbox": list(bbox),
                "features": len(hits), "counts": counts, "timestamp_from": "file modification time"}
        return write_done(marker, OsmExtract(paths=(path,), timestamp=self._timestamp, info=info))

    def describe(self) -> dict[str, Any]:
        """JSON-able description for the manifest."""
        return {"source": "geojson", "path": str(self.path), "tags": self.tags, "timestamp": self._timestamp,
                "attribution": self.attribution}


def _read_geometries(path: Path) -> Iterator[BaseGeometry]:
    """The valid geometries of a GeoJSON FeatureCollection (or single Feature/geometry), in order."""
    hint = "give a GeoJSON FeatureCollection in WGS84 longitude/latitude"
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise OSMDataError(f"--osm geojson:{path}: not readable JSON ({str(exc).splitlines()[0]}); {hint}") from None
    if isinstance(data, dict) and data.get("type") == "FeatureCollection" and isinstance(data.get("features"), list):
        features = data["features"]
    elif isinstance(data, dict) and data.get("type") == "Feature":
        features = [data]
    elif isinstance(data, dict) and "coordinates" in data or isinstance(data, dict) and data.get("type") == "GeometryCollection":
        features = [{"type": "Feature", "geometry": data}]
    else:
        raise OSMDataError(f"--osm geojson:{path}: not a GeoJSON FeatureCollection; {hint}")
    skipped = 0
    for i, feature in enumerate(features):
        geometry = feature.get("geometry") if isinstance(feature, dict) else None
        try:
            geom = shape(geometry) if geometry else None
        except (AttributeError, KeyError, TypeError, ValueError, shapely.errors.GEOSException):
            geom = None
        if geom is None or geom.is_empty or not _in_wgs84(geom):
            skipped += 1
            logger.debug("%s: feature %d has no usable WGS84 geometry: skipped", path, i)
            continue
        yield geom
    if skipped:
        logger.warning("%s: %d of %d features have no usable WGS84 geometry: skipped", path, skipped, len(features))


def _in_wgs84(geom: BaseGeometry) -> bool:
    w, s, e, n = geom.bounds
    return bool(-180 <= w <= e <= 180 and -90 <= s <= n <= 90)
