"""The parts of ``benchmarks/bench_region.py`` its figures rest on (real Kotka OSM in
``../shared/data``; skipped without it).

* Street points are on streets: every drawn point lies on a ``highway`` pixel of the region as
  the builder draws it, read back at the point's own tile, and inside the region.
* A short run localizes clean views drawn by the geometry renderer in a part of the region
  (16 blocks), far better than the random street point beside it.
"""

from __future__ import annotations

import sys

import mercantile
import numpy as np
import pytest
from conftest import REPO_ROOT, shared_path

sys.path.insert(0, str(REPO_ROOT / "benchmarks"))


#: a part of the Kotka extract (16 blocks)
BBOX = (26.940, 60.530, 26.955, 60.537)


def kotka_part(tmp_path) -> tuple:
    """The real Kotka OSM, the blocks of :data:`BBOX` and their masks (drawn into ``tmp_path``)."""
    import bench_region

    from localization.region.cache import BlockMasks
    from localization.region.search import RegionConfig, region_blocks

    osm = shared_path("helsinki-osm", "kotka.osm.pbf")
    blocks = region_blocks(RegionConfig(bbox=BBOX))
    return osm, blocks, BlockMasks([osm], bench_region.TABLE, [g for g, _ in blocks], tmp_path)


def test_street_points_lie_on_highway_pixels_inside_the_region(tmp_path) -> None:
    import bench_region

    from osmseg.grid import sample_grid
    from osmseg.osm.features import read_features
    from osmseg.rasterize import rasterize

    osm, blocks, masks = kotka_part(tmp_path)
    bbox = BBOX
    points = bench_region.street_points(masks, blocks, 12, np.random.default_rng(5), bbox)
    road = bench_region.TABLE.by_name["highway"].id
    for lon, lat in points:
        assert bbox[0] <= lon <= bbox[2] and bbox[1] <= lat <= bbox[3]
        grid = sample_grid(lon, lat, 18, 3)  # the point's own tile, drawn again: a highway pixel there
        tile = mercantile.tile(lon, lat, 18)
        b = mercantile.xy_bounds(tile)
        x, y = mercantile.xy(lon, lat)
        col = int((x - b.left) / (b.right - b.left) * 256) + 256
        row = int((b.top - y) / (b.top - b.bottom) * 256) + 256
        mask = rasterize(read_features([osm], grid, bench_region.TABLE), grid, bench_region.TABLE)
        assert (mask[row - 1:row + 2, col - 1:col + 2] == road).any(), (lon, lat)


@pytest.mark.slow  # make test-slow: benchmarks/bench_region.py on real OSM
def test_a_short_run_finds_clean_views_in_a_region(tmp_path) -> None:
    import bench_region

    osm = shared_path("helsinki-osm", "kotka.osm.pbf")
    summary = bench_region.main(["--osm", str(osm), "--bbox", "26.940,60.530,26.955,60.537", "--queries", "2",
                                 "--json", str(tmp_path / "r.json")])
    assert summary["queries"] == 2 and summary["blocks"] == 16
    assert summary["within_10m"] >= 0.5 and summary["baseline_random_street_median_m"] > 50


def test_the_mask_renderer_stands_on_the_street_it_was_asked_for(tmp_path) -> None:
    import bench_region

    _, blocks, masks = kotka_part(tmp_path)
    bbox = BBOX
    spots = bench_region.street_spots(masks, blocks, 6, np.random.default_rng(5), bbox)
    assert [(s.lon, s.lat) for s in spots] == bench_region.street_points(masks, blocks, 6, np.random.default_rng(5),
                                                                         bbox)
    road, sky = bench_region.PANO.by_name["highway"].id, bench_region.PANO.by_name["sky"].id
    for fov in (360.0, 90.0):
        views = list(bench_region.mask_views(masks, blocks, spots, np.random.default_rng(1), (1.5, 2.5), fov))
        assert [v.pixels.shape for v in views] == [(224, round(1232 * fov / 360))] * len(spots)
        for v in views:
            assert (v.pixels[:20] == sky).mean() > 0.5  # the sky above
            assert 0 <= v.heading < 360 and 1.5 <= v.eye_m <= 2.5
    # the rows under the camera, a few metres around it all ways: the street it stands on (half of
    # them at least: a point on a road's edge sees the verge on one side)
    for v in bench_region.mask_views(masks, blocks, spots, np.random.default_rng(1), (1.5, 2.5), 360.0):
        ground = v.pixels[-10:]
        assert (ground == road).mean() > 0.3, (v.lon, v.lat, np.unique(ground, return_counts=True))
