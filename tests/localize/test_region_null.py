"""Is the view from this district at all? The region search's null hypothesis, on OSM towns built here.

A view from one town searched in another still has a best place there: the region search
compares it with the best a scrambled copy of the same view reaches (its sectors in another
order, :mod:`localization.profile.null`), and answers "not found here" when the view fits the
district no better than that. Views are drawn by the geometry renderer from the towns' OSM.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image
from test_loc_georender import LAT0, LON0, lonlat, square, town, write_osm

from localization.bench.georender import Camera, render
from localization.bench.georender_osm import scene_from_osm
from localization.bench.render import panorama_table
from localization.common.landmarks import load_landmark_classes
from localization.common.views import Camera as QueryCamera, semantic_map
from localization.profile.null import scrambled
from localization.profile.profiles import QueryProfile
from localization.region.search import HERE, NOT_HERE, RegionConfig, distance_m, search_region
from osmseg.classes import load_class_table
from osmseg.cli.main import cli

TABLE = load_class_table("classes13.toml")
CLASSES = load_landmark_classes("aerial13")


def parkland(folder: Path) -> Path:
    """Another town: a park of scattered trees crossed by footpaths, one small building (nothing
    like :func:`town`'s street grid lined with buildings)."""
    rng = np.random.default_rng(5)
    objects = [("way", [(-150, 150), (-150, -150), (150, -150), (150, 150)], {"leisure": "park"})]
    objects += [("way", [(-150, y), (150, y)], {"highway": "footway"}) for y in (-60, 70)]
    objects += [("way", [(x, -150), (x, 150)], {"highway": "path"}) for x in (-40, 90)]
    for _ in range(160):
        x, y = (float(v) for v in rng.uniform(-145, 145, 2))
        if min(abs(y + 60), abs(y - 70), abs(x + 40), abs(x - 90)) > 4:
            objects.append(("node", [(x, y)], {"natural": "tree", "height": f"{rng.uniform(6, 14):.0f}"}))
    objects.append(("way", square(20.0, 5.0, 8.0), {"building": "yes", "height": "6"}))
    folder.mkdir(parents=True, exist_ok=True)
    write_osm(folder / "town.osm", objects)
    return folder / "town.osm"


def view(osm: Path, at: tuple[float, float], heading: float = 0.0) -> np.ndarray:
    scene = scene_from_osm([osm], LON0, LAT0, TABLE, radius_m=200, seed=0)
    return render(scene.scene, Camera(*scene.to_local(*lonlat(*at)), eye_m=1.7, heading_deg=heading, width=1232,
                                      height=224), panorama_table(TABLE).by_name["sky"].id, TABLE.unlabeled.id)


def region() -> RegionConfig:
    w, s = lonlat(-140, -140)
    e, n = lonlat(140, 140)
    return RegionConfig(bbox=(w, s, e, n))


@pytest.fixture(scope="module")
def towns(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("towns")
    (root / "here").mkdir()
    return town(root / "here"), parkland(root / "park")


def test_a_view_of_a_park_is_not_found_in_a_built_up_town_though_its_confidence_alone_would_accept_it(
        towns: tuple[Path, Path], tmp_path: Path) -> None:
    """In a town of streets and buildings, a view from a park of trees still has a best place, one
    that leads its best distinct alternative by far (the confidence accepts it: the old gate); but a
    scrambled copy of the view fits some place as well, so it is not found here. A view from the
    town itself rises well above its scrambled copies and is found."""
    here, park = towns
    from localization.profile.profiles import MASK_MIN_CONFIDENCE
    from localization.profile.search import ProfileConfig
    from localization.region.search import NULL_MIN_LIFT

    def search(pixels: np.ndarray):
        query = semantic_map(pixels, panorama_table(TABLE), CLASSES)
        return search_region(query, QueryCamera(1232, 224), [here], TABLE, CLASSES, region(),
                             ProfileConfig(heading_deg=0.0), cache_dir=tmp_path / "cache")

    found = search(view(here, (10.0, -25.0)))
    assert distance_m(found.best, lonlat(10.0, -25.0)) < 5.0
    assert found.verdict == HERE and found.lift is not None and found.lift > NULL_MIN_LIFT + 0.1, found.lift
    for at in ((-40.0, 0.0), (0.0, -60.0)):  # on the park's paths
        elsewhere = search(view(park, at))
        assert elsewhere.best is not None and elsewhere.best.confidence is not None
        assert elsewhere.best.confidence >= MASK_MIN_CONFIDENCE  # the confidence alone: "here"...
        assert elsewhere.verdict == NOT_HERE, (at, elsewhere.lift)  # ...the null: no better than scrambled
        assert elsewhere.lift is not None and elsewhere.lift < 0.05


def test_not_found_here_is_said_in_the_geojson_and_on_the_terminal(towns: tuple[Path, Path], tmp_path: Path) -> None:
    here, park = towns
    Image.fromarray(view(park, (0.0, -60.0)).astype(np.uint8)).save(tmp_path / "query.png")
    w, s, e, n = region().bbox
    args = ["localize-region", "--ground", str(tmp_path / "query.png"), "--ground-landmarks", "aerial13",
            "--ground-table", "classes13.toml", "--osm", str(here), "--bbox", f"{w},{s},{e},{n}", "--heading", "0",
            "--out", str(tmp_path / "out"), "--cache-dir", str(tmp_path / "cache")]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert "not found here:" in result.stderr, result.stderr
    doc = json.loads((tmp_path / "out" / "region.geojson").read_text())
    assert doc["properties"]["verdict"] == NOT_HERE and doc["properties"]["lift"] < 0.05
    assert doc["properties"]["null_score"] > 0 and (tmp_path / "out" / "region.png").is_file()
    as_json = CliRunner().invoke(cli, [*args, "--json"])
    assert json.loads(as_json.stdout)["properties"]["verdict"] == NOT_HERE
    # a view of the town itself: its "here" is said too, with what it rests on
    Image.fromarray(view(here, (10.0, -25.0)).astype(np.uint8)).save(tmp_path / "query.png")
    found = CliRunner().invoke(cli, [*args[:-4], "--out", str(tmp_path / "found"), *args[-2:]])
    assert found.exit_code == 0, found.output
    said = [line for line in found.stderr.splitlines() if line.startswith("here: ")]
    assert len(said) == 1 and "confidence" in said[0] and "lift" in said[0], found.stderr
    assert "not found here" not in found.stderr and "not sure" not in found.stderr
    doc = json.loads((tmp_path / "found" / "region.geojson").read_text())
    assert doc["properties"]["verdict"] == HERE and f"lift {doc['properties']['lift']:.3f}" in said[0]


def test_a_scrambled_query_keeps_what_the_view_holds_but_not_where() -> None:
    q = np.random.default_rng(0).random((4, 17, 72))
    query = QueryProfile(q, np.arange(16.0), ("a", "b", "c", "d"), None, 360.0,
                         variants=(QueryProfile(q * 2, np.arange(16.0), ("a", "b", "c", "d"), None, 360.0),))
    mixed = scrambled(query, 0)
    assert np.allclose(np.sort(mixed.q, axis=-1), np.sort(q, axis=-1))      # each ring: the same values...
    assert np.allclose(mixed.q.sum(axis=-1), q.sum(axis=-1))                # ...so the same class mass per distance
    for shift in range(72):                                                  # and no rotation of the view
        assert not np.allclose(mixed.q, np.roll(q, shift, axis=-1))
        assert not np.allclose(mixed.q, np.roll(q[..., ::-1], shift, axis=-1))  # nor of its mirror image
    assert np.allclose(mixed.variants[0].q, mixed.q * 2) and scrambled(query, 0).q.tobytes() == mixed.q.tobytes()


def street_view(osm: Path, bbox: tuple[float, float, float, float], cache: Path) -> tuple[np.ndarray, tuple[float, float]]:
    """A panorama drawn by the geometry renderer at the street pixel nearest the centre of the first
    block of ``bbox`` (camera 2 m up, level, heading 0), and where it stands."""
    from localization.region.cache import BlockMasks
    from localization.region.search import pixel_lonlat, region_blocks

    grid = region_blocks(RegionConfig(bbox=bbox))[0][0]
    mask = BlockMasks([osm], TABLE, [grid], cache).mask(0)
    ys, xs = np.nonzero(mask == TABLE.by_name["highway"].id)
    i = int(np.argmin(np.hypot(xs - mask.shape[1] / 2, ys - mask.shape[0] / 2)))
    b = grid.xy_bounds
    lon, lat = pixel_lonlat((b.left, b.bottom, b.right, b.top), mask.shape, (float(xs[i]), float(ys[i])))
    scene = scene_from_osm([osm], lon, lat, TABLE, radius_m=160, seed=0)
    pixels = render(scene.scene, Camera(0.0, 0.0, eye_m=2.0, width=1232, height=224),
                    panorama_table(TABLE).by_name["sky"].id, TABLE.unlabeled.id)
    return pixels, (lon, lat)


@pytest.mark.slow
def test_a_helsinki_view_is_not_found_in_west_oakland_and_a_west_oakland_one_is(tmp_path: Path) -> None:
    """Real OpenStreetMap of two towns (../shared/data): a street view of Helsinki searched in West
    Oakland is not found there; a street view of West Oakland is found where it was drawn."""
    from conftest import shared_path

    from localization.profile.search import ProfileConfig

    helsinki, oakland = shared_path("helsinki-osm", "helsinki.osm.pbf"), shared_path("oakland-osm", "west-oakland.osm")
    box = (-122.30258, 37.80615, -122.29825, 37.80914)
    for osm, bbox, home in ((helsinki, (24.940, 60.168, 24.948, 60.173), False), (oakland, box, True)):
        pixels, where = street_view(osm, bbox, tmp_path / "cache")
        query = semantic_map(pixels, panorama_table(TABLE), CLASSES)
        result = search_region(query, QueryCamera(1232, 224), [oakland], TABLE, CLASSES, RegionConfig(bbox=box),
                               ProfileConfig(heading_deg=0.0), cache_dir=tmp_path / "cache")
        if home:
            assert result.verdict == HERE and distance_m(result.best, where) < 10.0, (result.lift, result.best)
        else:
            assert result.verdict == NOT_HERE, (result.lift, result.best)


def test_the_scrambles_searched_as_one_query_score_what_each_copy_scores_alone() -> None:
    """A query read at several camera heights: its scrambled copies searched as one query (every copy's
    heights as its variants, the rays read once) give each position the best of the copies' scores."""
    from test_loc_render import CLASSES, RES, TABLE
    from test_profile_vista import CENTRE, district, view

    from localization.common.views import semantic_map
    from localization.profile.method import profile_index, profile_query
    from localization.profile.null import null_queries
    from localization.profile.search import ProfileConfig, class_prior, grid_positions, score_poses

    mask = district()
    index = profile_index(semantic_map(mask, TABLE, CLASSES), RES)
    sem, camera = view(mask, CENTRE)
    xy = grid_positions(index.shape, 14.0)
    for heading in (0.0, None):
        config = ProfileConfig(heading_deg=heading, camera_heights=(1.5, 2.0, 2.5))
        q = profile_query(sem, camera, config)
        prior = class_prior(index, q, xy)
        [both] = null_queries(q)
        alone = np.max([score_poses(index, scrambled(q, seed), xy, config, prior)[0] for seed in (0, 1)], axis=0)
        assert len(both.variants) == 2 * len(q.variants) == 6
        assert np.allclose(score_poses(index, both, xy, config, prior)[0], alone, rtol=0, atol=1e-6), heading
