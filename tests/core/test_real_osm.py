"""Class rules on real OSM extracts, and building masks on real roofs (../shared/data).

Skipped when ../shared/data is absent.  Expectations are checked against OSM objects read
independently here (plain osmium + mercantile), not against our own reader's output:

* Helsinki PBF (full tags, with coastline) and West Oakland XML (the API's format): the
  classes a city centre must have appear, and buildings, trees, roads and the sea land on the
  pixels their own OSM coordinates say.
* Kampala: real z21 drone tiles + real OSM building footprints (GeoJSON, no tags) turned into
  OSM XML with building=yes.  The mask's building outlines must sit on the image's edges (roof
  outlines): image edge strength along the outlines peaks at zero shift and is clearly
  stronger than with the mask shifted by 5-6 px.  A debug overlay is saved in tmp_path (run
  with ``--basetemp=/tmp/osmseg-debug`` to keep it where you can look at it).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import mercantile
import numpy as np
import osmium
import pytest
import shapely
from conftest import shared_path
from PIL import Image

from osmseg.classes import load_class_table
from osmseg.grid import SampleGrid, sample_grid
from osmseg.osm.features import read_features
from osmseg.quality import edge_alignment, outline
from osmseg.rasterize import rasterize

pytestmark = pytest.mark.shared_data

T13 = load_class_table()
ID = {c.name: c.id for c in T13.classes}
HIDDEN = {"tunnel", "location", "parking"}
PAVED = {"asphalt", "paved", "concrete", "paving_stones", "sett", "cobblestone"}

#: Helsinki grids (z18, ~380 m square): the Esplanadi/Erottaja centre, and the bay under the
#: Pitkasilta bridge (coastline crosses the box).
HELSINKI_CENTRE = (24.944, 60.168)
HELSINKI_BAY = (24.9492, 60.1775)


def helsinki() -> Path:
    return shared_path("helsinki-osm", "helsinki.osm.pbf")


def to_pixels(grid: SampleGrid, lonlat: np.ndarray) -> np.ndarray:
    """(N, 2) lon/lat to (N, 2) fractional (col, row) of ``grid``, via mercantile (independent)."""
    xy = np.array([mercantile.xy(lon, lat) for lon, lat in lonlat])
    inverse = ~grid.transform
    return np.array([inverse @ (x, y) for x, y in xy])


def label_at(labels: np.ndarray, pixel: np.ndarray) -> int:
    return int(labels[int(pixel[1]), int(pixel[0])])


def inside(grid: SampleGrid, pixel: np.ndarray, margin: float = 3) -> bool:
    return margin <= pixel[0] < grid.width - margin and margin <= pixel[1] < grid.height - margin


class Objects:
    """Buildings, trees, road and coastline ways of a file, read with plain osmium."""

    def __init__(self, path: Path) -> None:
        self.buildings: list[tuple[int, np.ndarray]] = []
        self.trees: list[np.ndarray] = []
        self.roads: list[np.ndarray] = []
        self.coast: list[np.ndarray] = []
        fp = osmium.FileProcessor(str(path)).with_locations().with_filter(
            osmium.filter.KeyFilter("building", "natural", "highway"))
        for obj in fp:
            tags = dict(obj.tags)
            if HIDDEN & set(tags) or tags.get("building") == "no":
                continue
            if obj.is_node() and tags.get("natural") == "tree":
                self.trees.append(np.array([obj.location.lon, obj.location.lat]))
            if not obj.is_way():
                continue
            located = [n.location.valid() for n in obj.nodes]
            coords = np.array([(n.location.lon, n.location.lat) if ok else (np.nan, np.nan)
                               for n, ok in zip(obj.nodes, located)])
            if tags.get("natural") == "coastline":  # keep the runs of located nodes (cut extract)
                runs = [r[~np.isnan(r[:, 0])] for r in np.split(coords, np.flatnonzero(~np.array(located)))]
                self.coast.extend(r for r in runs if len(r) >= 2)
            if not all(located):
                continue
            if "building" in tags and obj.is_closed() and len(coords) >= 4:
                self.buildings.append((obj.id, coords))
            elif tags.get("highway") in ("primary", "secondary", "tertiary", "residential") \
                    and tags.get("surface", "asphalt") in PAVED and tags.get("area") != "yes":
                self.roads.append(coords)


@pytest.fixture(scope="module")
def helsinki_objects() -> Objects:
    return Objects(helsinki())


def read(path: Path, grid: SampleGrid) -> tuple[np.ndarray, float, float]:
    t0 = time.perf_counter()
    features = read_features([path], grid, T13)
    t1 = time.perf_counter()
    labels = rasterize(features, grid, T13)
    return labels, t1 - t0, time.perf_counter() - t1


def check_buildings(grid: SampleGrid, labels: np.ndarray, buildings: list[tuple[int, np.ndarray]]) -> int:
    """Every building well inside the box has building pixels at a point 1.5 px inside its outline."""
    checked = 0
    for way_id, coords in buildings:
        outline = shapely.make_valid(shapely.Polygon(to_pixels(grid, coords)))
        core = outline.buffer(-1.5)
        if core.is_empty or not all(inside(grid, np.array(p)) for p in shapely.get_coordinates(outline)):
            continue
        point = np.array(core.representative_point().coords[0])
        assert label_at(labels, point) == ID["building"], f"building way {way_id} at pixel {point.round()}"
        checked += 1
    return checked


def test_helsinki_centre_classes_and_objects(helsinki_objects: Objects) -> None:
    grid = sample_grid(*HELSINKI_CENTRE, zoom=18)
    labels, parse_s, raster_s = read(helsinki(), grid)
    print(f"Helsinki centre: parse {parse_s:.3f} s, rasterise {raster_s:.3f} s")
    share = {name: float((labels == i).mean()) for name, i in ID.items()}
    for name in ("building", "highway", "footway", "tree", "park", "grass"):
        assert share[name] > 0.001, f"{name} missing: {share}"
    assert share["building"] > 0.2 and share["highway"] > 0.05
    assert check_buildings(grid, labels, helsinki_objects.buildings) >= 20
    # trees: a crown at every tree node, unless something drawn above trees covers it
    above_trees = {i for i, c in T13.by_id.items() if c.order > T13.by_name["tree"].order}
    pixels = [p for p in to_pixels(grid, np.array(helsinki_objects.trees)) if inside(grid, p)]
    assert len(pixels) >= 20
    hits = [label_at(labels, p) for p in pixels]
    assert all(h == ID["tree"] or h in above_trees for h in hits)
    assert hits.count(ID["tree"]) > 0.5 * len(hits)
    # roads: the middle of each road segment in the box is highway (or a building over it)
    mids = [m for coords in helsinki_objects.roads
            for m in to_pixels(grid, (coords[1:] + coords[:-1]) / 2) if inside(grid, m)]
    assert len(mids) >= 30
    on_road = [label_at(labels, m) in (ID["highway"], ID["building"]) for m in mids]
    assert np.mean(on_road) > 0.95


def test_helsinki_bay_sea_from_coastline(helsinki_objects: Objects) -> None:
    grid = sample_grid(*HELSINKI_BAY, zoom=18)
    features = read_features([helsinki()], grid, T13)
    assert [f.kind for f in features if f.kind == "sea"] == ["sea"]
    labels = rasterize(features, grid, T13)
    assert (labels == ID["water"]).mean() > 0.15
    # 10 m right of every coastline segment (OSM: water on the right) is water, 10 m left is not
    step = 10 / grid.ground_resolution
    right_hits, left_hits = [], []
    for coords in helsinki_objects.coast:
        px = to_pixels(grid, coords)
        for a, b in zip(px[:-1], px[1:]):
            d = b - a
            if np.hypot(*d) < 2 * step:
                continue
            mid = (a + b) / 2
            normal = np.array([-d[1], d[0]]) / np.hypot(*d)  # pixel rows grow southwards: this is right
            for side, hits in ((1, right_hits), (-1, left_hits)):
                p = mid + side * step * normal
                if inside(grid, p):
                    hits.append(label_at(labels, p) == ID["water"])
    assert len(right_hits) >= 10
    assert np.mean(right_hits) > 0.8 and np.mean(left_hits) < 0.2


def test_oakland_xml() -> None:
    path = shared_path("oakland-osm", "west-oakland.osm")
    grid = sample_grid(-122.3004, 37.8076, zoom=19)
    labels, parse_s, raster_s = read(path, grid)
    print(f"West Oakland: parse {parse_s:.3f} s, rasterise {raster_s:.3f} s")
    present = {T13.by_id[i].name for i in np.unique(labels)}
    assert {"building", "highway", "footway", "parking", "construction"} <= present
    assert check_buildings(grid, labels, Objects(path).buildings) >= 5


# -- Kampala: building masks on real roofs --------------------------------------------------

#: A 5x5 z21 block inside the complete x 1238448-1238459, y 1046528-1046535 tile block.
KAMPALA_CENTRE_TILE = mercantile.Tile(1238453, 1046531, 21)


def geojson_to_osm(geojson: Path, out: Path) -> Path:
    """Footprint polygons (no tags) to OSM XML ways tagged building=yes."""
    nodes, ways, next_node = [], [], 1
    for way_id, feature in enumerate(json.loads(geojson.read_text())["features"], start=1):
        refs = []
        for lon, lat in feature["geometry"]["coordinates"][0][:-1]:  # outer ring; none have holes
            nodes.append(f'  <node id="{next_node}" version="1" lat="{lat:.7f}" lon="{lon:.7f}"/>')
            refs.append(next_node)
            next_node += 1
        nds = "".join(f'<nd ref="{r}"/>' for r in [*refs, refs[0]])
        ways.append(f'  <way id="{way_id}" version="1">{nds}<tag k="building" v="yes"/></way>')
    out.write_text("<?xml version='1.0' encoding='UTF-8'?>\n<osm version=\"0.6\" generator=\"osmseg test\">\n"
                   + "\n".join(nodes + ways) + "\n</osm>\n", encoding="utf-8")
    return out


def mosaic(tiles_dir: Path, grid: SampleGrid) -> np.ndarray:
    image = Image.new("RGB", (grid.width, grid.height))
    for i, t in enumerate(grid.tiles):
        with Image.open(tiles_dir / f"OAM-{t.x}-{t.y}-{t.z}.png") as tile:
            image.paste(tile.convert("RGB"), grid.tile_offset(i))
    return np.asarray(image)


def test_kampala_buildings_sit_on_roofs(tmp_path: Path) -> None:
    root = shared_path("kampala-oam")
    b = mercantile.bounds(KAMPALA_CENTRE_TILE)
    grid = sample_grid((b.west + b.east) / 2, (b.south + b.north) / 2, zoom=21)
    assert grid.tiles[12] == KAMPALA_CENTRE_TILE
    osm = geojson_to_osm(root / "osm-buildings.geojson", tmp_path / "kampala-buildings.osm")
    labels = rasterize(read_features([osm], grid, T13), grid, T13)
    mask = labels == ID["building"]
    assert 0.05 < mask.mean() < 0.6
    rgb = mosaic(root / "tiles", grid)
    fit = edge_alignment(rgb, mask)
    overlay = rgb.copy()
    overlay[outline(mask)] = (255, 0, 0)
    Image.fromarray(overlay).save(tmp_path / "kampala-overlay.png")
    print(f"edge strength along outlines: at 0 shift {fit.at_zero:.1f}, shifted 5-6 px {fit.far:.1f} "
          f"(best shift {fit.best}); overlay {tmp_path / 'kampala-overlay.png'}")
    assert abs(fit.best[0]) <= 1 and abs(fit.best[1]) <= 1
    assert fit.at_zero > 1.3 * fit.far
    # and the roofs inside the outlines differ from the ground just outside them
    ring = outline(~mask) & ~mask
    assert np.abs(rgb[mask].mean(axis=0) - rgb[ring].mean(axis=0)).max() > 10
