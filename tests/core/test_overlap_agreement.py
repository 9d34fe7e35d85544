"""Overlapping samples agree on every shared ground pixel: a pixel's class depends on the ground alone.

Two sample grids that overlap are drawn from the same OSM data the way a build draws a sample
(:func:`read_features`, then :func:`rasterize`), and every pixel both cover must get one class.
Lines and tree crowns are buffered from ground metres to Web Mercator metres (``1/cos(lat)``);
with the scale taken at the *sample's* centre latitude, a road's edge moved by a fraction of a
millimetre from one sample to the next, enough to move a pixel whose centre lies that close to
it: two real Helsinki samples disagreed on a few pixels (highway/unlabeled, footway/park,
tree/park), so torchgeo's merge of an overlapping COG build differed from labels/NAME.png.

* A generated fixture shows it on every pixel of a row: roads (and a tree crown over a park)
  whose edges are placed, for two grids 3 tiles apart, between where the two samples' scales
  would put them (checked with shapely when the fixture is made);
* the real Helsinki extract (``../shared/data``; skipped without it): pairs of overlapping
  samples that disagreed by 8-9 pixels;
* torchgeo over an overlapping ``--image-format cog`` build of the Helsinki extract: the mask it
  merges at each sample's box is that sample's labels/NAME.png, pixel for pixel.

Measured over 40 random pairs per zoom: ``benchmarks/overlap_agreement.py``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import mercantile
import numpy as np
import pytest
import shapely
from click.testing import CliRunner
from conftest import shared_path
from PIL import Image

from osmseg.classes import load_class_table
from osmseg.cli.main import cli
from osmseg.grid import SampleGrid, sample_grid
from osmseg.osm.features import read_features
from osmseg.rasterize import rasterize

TABLE = load_class_table("classes13.toml")
HIGHWAY, PARK, TREE = (TABLE.by_name[n].id for n in ("highway", "park", "tree"))


def tile_centred(tile: mercantile.Tile) -> SampleGrid:
    """The 5x5 grid a build draws around a centre point in the middle of ``tile``."""
    w, s, e, n = mercantile.bounds(tile)
    return sample_grid((w + e) / 2, (s + n) / 2, tile.z)


def shared(a: SampleGrid, b: SampleGrid, la: np.ndarray, lb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The labels of ``a`` and of ``b`` on the pixels both cover (tile-aligned grids of one zoom)."""
    ox, oy = (b.tiles[0].x - a.tiles[0].x) * 256, (b.tiles[0].y - a.tiles[0].y) * 256
    c0, c1, r0, r1 = max(0, ox), min(a.width, ox + b.width), max(0, oy), min(a.height, oy + b.height)
    assert c0 < c1 and r0 < r1, "the grids do not overlap"
    return la[r0:r1, c0:c1], lb[r0 - oy:r1 - oy, c0 - ox:c1 - ox]


def labels_of(paths: list[Path], grid: SampleGrid) -> np.ndarray:
    return rasterize(read_features(paths, grid, TABLE), grid, TABLE)


# --- a generated fixture -------------------------------------------------------------------

def old_scale(grid: SampleGrid) -> float:
    """Web Mercator metres per ground metre at the grid's centre latitude (what lines were scaled by)."""
    return 1 / math.cos(math.radians(grid.lat))


def lonlat(x: float, y: float) -> tuple[float, float]:
    """(lon, lat) of a Web Mercator point, to OSM's 7 decimals."""
    lon, lat = mercantile.lnglat(x, y)
    return round(lon, 7), round(lat, 7)


def straddling_radius(geometry: shapely.Geometry, centre: shapely.Point, scales: tuple[float, float]) -> float:
    """A ground buffer radius that puts ``centre`` inside ``geometry`` buffered at one of ``scales``
    and outside at the other: the radius that just reaches ``centre`` (bisection), over their mean."""
    lo, hi = 0.0, 100.0
    for _ in range(80):
        mid = (lo + hi) / 2
        lo, hi = (lo, mid) if shapely.buffer(geometry, mid).contains(centre) else (mid, hi)
    radius = hi / (sum(scales) / 2)
    inside = [bool(shapely.buffer(geometry, radius * s).contains(centre)) for s in scales]
    assert inside in ([True, False], [False, True]), "the fixture does not straddle the two scales"
    return radius


def write_fixture(path: Path, a: SampleGrid, b: SampleGrid) -> list[int]:
    """OSM XML of 3 east-west roads and a tree on a park in the rows ``a`` and ``b`` share, sized
    so that each edge falls between the two grids' old scales; returns the rows (of ``a``) the
    road edges pass next to."""
    scales = (old_scale(a), old_scale(b))
    res, (left, _, right, top) = a.pixel_size, a.xy_bounds
    nodes: list[tuple[int, float, float, dict[str, str]]] = []
    ways: list[tuple[list[int], dict[str, str]]] = []

    def node(x: float, y: float, tags: dict[str, str] | None = None) -> int:
        lon, lat = lonlat(x, y)
        nodes.append((len(nodes) + 1, lon, lat, tags or {}))
        return len(nodes)

    rows = [850, 1000, 1150]  # in a's overlap with b: rows 768-1279 of a are rows 0-511 of b
    for k, row in enumerate(rows):
        centre_y = top - (row + 0.5) * res  # a pixel-centre row; the road runs some metres south of it
        lon0, lat0 = lonlat(left - 20, centre_y - (3 + 2 * k) * 2)
        road_y = mercantile.xy(lon0, lat0)[1]
        line = shapely.LineString([(left - 20, road_y), (right + 20, road_y)])
        half = straddling_radius(line, shapely.Point(left + 100.5 * res, centre_y), scales)
        ids = [node(left - 20, road_y), node(right + 20, road_y)]
        ways.append((ids, {"highway": "residential", "width": f"{2 * half:.9f}"}))
    # a park across columns 200-500 of rows 800-1200, a tree in it whose crown top reaches a pixel centre
    park = [node(left + x * res, top - y * res) for x, y in ((200, 800), (500, 800), (500, 1200), (200, 1200))]
    ways.append((park + park[:1], {"leisure": "park"}))
    tree_x, tree_y = mercantile.xy(*lonlat(left + 350.5 * res, top - 1100.5 * res))
    top_centre = shapely.Point(tree_x, top - 1090.5 * res)  # the pixel centre 10 rows above the tree
    radius = straddling_radius(shapely.Point(tree_x, tree_y), top_centre, scales)
    node(tree_x, tree_y, {"natural": "tree", "diameter_crown": f"{2 * radius:.9f}"})
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', '<osm version="0.6" generator="osmseg test">']
    for nid, lon, lat, tags in nodes:
        inner = "".join(f'<tag k="{k}" v="{v}"/>' for k, v in tags.items())
        lines.append(f'<node id="{nid}" version="1" lat="{lat:.7f}" lon="{lon:.7f}">{inner}</node>')
    for wid, (ids, tags) in enumerate(ways, start=1):
        inner = "".join(f'<nd ref="{i}"/>' for i in ids) + "".join(f'<tag k="{k}" v="{v}"/>' for k, v in tags.items())
        lines.append(f'<way id="{wid}" version="1">{inner}</way>')
    path.write_text("\n".join([*lines, "</osm>", ""]), encoding="utf-8")
    return rows


def test_roads_and_crowns_get_the_same_pixels_in_every_sample_that_sees_them(tmp_path: Path) -> None:
    tile = mercantile.tile(24.94, 60.17, 18)
    a, b = tile_centred(tile), tile_centred(mercantile.Tile(tile.x, tile.y + 3, 18))
    rows = write_fixture(tmp_path / "edges.osm", a, b)
    la, lb = labels_of([tmp_path / "edges.osm"], a), labels_of([tmp_path / "edges.osm"], b)
    sa, sb = shared(a, b, la, lb)
    assert sa.shape == (512, 1280)
    # the fixture draws what it says: three roads, a park, a crown on it
    assert {HIGHWAY, PARK, TREE} <= set(np.unique(sa).tolist())
    assert all((la[r - 12:r + 2] == HIGHWAY).any() for r in rows)
    differ = sa != sb
    assert int(differ.sum()) == 0, f"{int(differ.sum())} shared pixels differ, in rows {np.unique(np.nonzero(differ)[0] + 768)}"


# --- the real Helsinki extract --------------------------------------------------------------

#: (zoom, centre of sample a, centre of sample b): overlapping pairs that disagreed by 8-9 pixels
#: (highway/unlabeled, footway/park, tree/park) when lines were scaled at the sample's centre.
HELSINKI_PAIRS = [
    (18, (24.94462405317819, 60.168239857564046), (24.94552549347193, 60.16632365525025)),
    (18, (24.940651925065637, 60.173234571872364), (24.941594327304703, 60.17428465609604)),
    (19, (24.94465242828666, 60.17379190845972), (24.94552558053555, 60.17296056537225)),
]


@pytest.mark.shared_data
@pytest.mark.parametrize("zoom, centre_a, centre_b", HELSINKI_PAIRS)
def test_overlapping_helsinki_samples_agree_on_every_shared_pixel(
        zoom: int, centre_a: tuple[float, float], centre_b: tuple[float, float]) -> None:
    helsinki = shared_path("helsinki-osm", "helsinki.osm.pbf")
    a, b = sample_grid(*centre_a, zoom), sample_grid(*centre_b, zoom)
    sa, sb = shared(a, b, labels_of([helsinki], a), labels_of([helsinki], b))
    assert sa.size >= 256 * 256 and len(np.unique(sa)) >= 5  # a real overlap of a busy street scene
    differ = sa != sb
    pairs = sorted({(int(x), int(y)) for x, y in zip(sa[differ], sb[differ])})
    assert int(differ.sum()) == 0, f"{int(differ.sum())} shared pixels differ (class pairs {pairs})"


@pytest.mark.shared_data
def test_torchgeo_merge_of_an_overlapping_helsinki_cog_build_is_each_samples_labels_png(tmp_path: Path) -> None:
    """An overlapping COG build from the real Helsinki extract (imagery painted from the same OSM in
    EPSG:3857), read by torchgeo alone: the mask it merges at each sample's box, whichever of the
    overlapping files each pixel comes from, is exactly that sample's labels/NAME.png."""
    pytest.importorskip("torchgeo")
    import rasterio
    from torchgeo.datasets import RasterDataset

    from osmseg.demo.render import render_aerial

    helsinki = shared_path("helsinki-osm", "helsinki.osm.pbf")
    lon, lat = 24.9445, 60.1712
    cover = sample_grid(lon, lat, 18, size=11)
    painted = render_aerial(labels_of([helsinki], cover), seed=2).transpose(2, 0, 1)
    imagery = tmp_path / "painted.tif"
    with rasterio.open(imagery, "w", driver="GTiff", width=cover.width, height=cover.height, count=3,
                       dtype="uint8", crs="EPSG:3857", transform=cover.transform) as dst:
        dst.write(painted)
    out = tmp_path / "ds"
    result = CliRunner().invoke(cli, [
        "-q", "build", "--lat", str(lat), "--lon", str(lon), "--radius-km", "0.1", "--samples", "4", "--seed", "2",
        "--image-format", "cog", "--imagery", f"geotiff:{imagery}", "--osm", str(helsinki), "--out", str(out),
        "--cache-dir", str(tmp_path / "cache")], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    samples = sorted(json.loads((out / "manifest.json").read_text())["samples"], key=lambda s: s["name"])
    assert len(samples) == 4

    class Masks(RasterDataset):
        filename_glob = "*.tif"
        is_image = False

    masks = Masks(out / "geo")
    overlapping = 0
    for i, s in enumerate(samples):
        xmin, ymin, xmax, ymax = s["bounds_3857"]
        overlapping += any(max(xmin, o["bounds_3857"][0]) < min(xmax, o["bounds_3857"][2])
                           and max(ymin, o["bounds_3857"][1]) < min(ymax, o["bounds_3857"][3])
                           for o in samples[:i])
        merged = masks[xmin:xmax, ymin:ymax]["mask"].numpy()
        png = np.asarray(Image.open(out / "labels" / f"{s['name']}.png"))
        assert merged.shape == png.shape == (1280, 1280)
        assert int((merged != png).sum()) == 0, f"{s['name']}: {int((merged != png).sum())} pixels differ"
    assert overlapping >= 2  # most samples overlap an earlier one: the merge has a choice there
