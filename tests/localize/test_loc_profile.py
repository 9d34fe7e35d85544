"""The profile method (localization.profile.profiles, localization.profile.search): known-answer scenes, heading, photos, confidence.

Every scene is a constructed classes13 mask (the seeded town of test_loc_render) and every
query a panorama rendered from it at a known place, so the answer is known: the position to a
metre or two, the heading to a few degrees. The method never reads the renderer's heights: a
scene with per-object heights (height_spread) must localize as well.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image
from test_loc_render import CLASSES, GRASS, RES, ROAD, TABLE, B, town

from localization.bench.compare import photo_view, roc_auc
from localization.bench.render import RenderConfig, object_heights, render_panorama
from localization.cli.bench import localize_bench_command
from localization.cli.localize import localize_command
from localization.common.landmarks import landmarks_from_mask
from localization.common.views import Camera, semantic_map
from localization.profile.method import profile_index, profile_query, run_profile
from localization.profile.profiles import MASK_MIN_CONFIDENCE, query_from_mask, ray_radii
from localization.profile.search import ProfileConfig

TRUTHS = [(137.0, 251.0), (262.0, 118.0), (318.0, 345.0)]  # on a road, on grass, on a road


@pytest.fixture(scope="module")
def scene() -> tuple[np.ndarray, object]:
    mask = town(400, seed=3)
    return mask, profile_index(semantic_map(mask, TABLE, CLASSES), RES)


def _query(mask: np.ndarray, xy: tuple[float, float], heading: float = 0.0, fov: float = 360.0,
           render: RenderConfig = RenderConfig()):
    pano = render_panorama(mask, TABLE, RES, xy, dataclasses.replace(render, heading_deg=heading))
    return photo_view(pano, CLASSES, fov, camera_height_m=2.0, mode="centroid", min_size=50, stride=50)


def _error_m(loc, xy) -> float:
    return math.hypot(loc.map_xy[0] - xy[0], loc.map_xy[1] - xy[1]) * RES


@pytest.mark.parametrize("xy", TRUTHS)
def test_a_panorama_with_known_heading_is_found_within_a_metre(scene, xy) -> None:
    mask, index = scene
    q = _query(mask, xy)
    loc = run_profile(ProfileConfig(), index, q.semantic, q.camera)
    assert not loc.unanswered and loc.method == "profile"
    assert _error_m(loc, xy) <= 1.0
    assert loc.heading_deg == 0.0 and loc.kappa > 0.8 and loc.confidence >= MASK_MIN_CONFIDENCE


@pytest.mark.parametrize("xy,heading", [(TRUTHS[0], 137.0), (TRUTHS[1], 301.5), (TRUTHS[2], 12.0)])
def test_unknown_heading_is_recovered_with_the_position(scene, xy, heading) -> None:
    mask, index = scene
    q = _query(mask, xy, heading)
    loc = run_profile(ProfileConfig(heading_deg=None), index, q.semantic, q.camera)
    assert _error_m(loc, xy) <= 1.5
    assert abs((loc.heading_deg - heading + 180) % 360 - 180) <= 4.0


def test_a_compass_prior_keeps_the_heading_search_within_its_uncertainty(scene) -> None:
    """A photo's compass heading, good to 20°: near the truth the answer is the unknown-heading
    one; a compass 90° off keeps every heading tried within its 20°, so the right one is never
    reached (and the answer says so by its heading)."""
    mask, index = scene
    xy, heading = TRUTHS[1], 301.5
    q = _query(mask, xy, heading, fov=90.0)
    near = run_profile(ProfileConfig(heading_deg=None, heading_prior_deg=315.0, heading_within_deg=20.0,
                                     min_confidence=-1.0), index, q.semantic, q.camera)
    assert _error_m(near, xy) <= 3.0 and abs((near.heading_deg - heading + 180) % 360 - 180) <= 5.0
    off = run_profile(ProfileConfig(heading_deg=None, heading_prior_deg=30.0, heading_within_deg=20.0,
                                    min_confidence=-1.0), index, q.semantic, q.camera)
    assert all(abs((h - 30.0 + 180) % 360 - 180) <= 20.0 + 2.5 for h in off.headings)  # within the prior (+ a bin)


def test_a_90_degree_photo_with_unknown_heading_is_localized(scene) -> None:
    mask, index = scene
    xy, heading = TRUTHS[0], 200.0
    q = _query(mask, xy, heading, fov=90.0)
    assert q.camera.width == 308 and q.camera.hfov_deg == pytest.approx(90.0)
    # a quarter of the view in a town of repeated blocks: right, and barely above its look-alikes
    loc = run_profile(ProfileConfig(heading_deg=None, min_confidence=-1.0), index, q.semantic, q.camera)
    assert _error_m(loc, xy) <= 3.0
    assert abs((loc.heading_deg - heading + 180) % 360 - 180) <= 5.0


def test_object_heights_vary_and_the_method_does_not_need_them(scene) -> None:
    mask, index = scene
    render = RenderConfig(height_spread=0.6, height_seed=4)
    heights = object_heights(mask, TABLE, render)
    building = heights[mask == B]
    assert building.min() < 7.0 and building.max() > 13.0     # 10 m +- 60 %, per building
    plain = render_panorama(mask, TABLE, RES, TRUTHS[1], RenderConfig())
    varied = render_panorama(mask, TABLE, RES, TRUTHS[1], render)
    assert (plain.labels != varied.labels).sum() > 500          # the skyline changed
    q = _query(mask, TRUTHS[1], render=render)
    loc = run_profile(ProfileConfig(), index, q.semantic, q.camera)
    assert _error_m(loc, TRUTHS[1]) <= 1.0


def village(seed: int, size: int = 400) -> np.ndarray:
    """Another kind of place: a field with one road across it and scattered houses and trees."""
    rng = np.random.default_rng(seed)
    m = np.full((size, size), GRASS, np.uint8)
    row = int(rng.integers(100, 300))
    m[row - 6:row + 6, :] = ROAD
    for _ in range(12):
        x, y = rng.integers(10, size - 40, 2)
        if not (m[y:y + 24, x:x + 24] == ROAD).any():
            m[y:y + int(rng.integers(10, 24)), x:x + int(rng.integers(10, 24))] = B
    return m


def test_confidence_separates_matching_from_non_matching_aerial_images(scene) -> None:
    mask, index = scene
    others = [profile_index(semantic_map(village(s), TABLE, CLASSES), RES) for s in (11, 12)]
    match, non = [], []
    for xy in TRUTHS:
        q = _query(mask, xy)
        match.append(run_profile(ProfileConfig(min_kappa=-1.0), index, q.semantic, q.camera).kappa)
        non += [run_profile(ProfileConfig(min_kappa=-1.0), o, q.semantic, q.camera).kappa for o in others]
    assert min(match) > max(non)
    assert roc_auc(match, non) == 1.0
    # below the threshold the answer is "not in this image", with the kappa kept
    q = _query(mask, TRUTHS[0])
    loc = run_profile(ProfileConfig(min_kappa=max(non) + 0.5 * (min(match) - max(non))), others[0], q.semantic,
                      q.camera)
    assert loc.unanswered and loc.map_xy is None and loc.reason.startswith("not in this image")


def test_a_look_alike_place_makes_the_answer_not_sure(scene) -> None:
    """The same query in the town and in an image holding the town twice, side by side: the
    match is as good in both (kappa), but only the single town's answer stands out from every
    place 50 m or more away; with two copies the best distinct alternative is the other copy,
    the confidence is about 0 and the answer is "not sure", naming how far the look-alike is."""
    mask, index = scene
    twice = np.concatenate([mask, np.full((mask.shape[0], 40), GRASS, np.uint8), mask], axis=1)
    twin = profile_index(semantic_map(twice, TABLE, CLASSES), RES)
    q = _query(mask, TRUTHS[0])
    one = run_profile(ProfileConfig(), index, q.semantic, q.camera)
    two = run_profile(ProfileConfig(), twin, q.semantic, q.camera)
    assert not one.unanswered and one.confidence >= MASK_MIN_CONFIDENCE and _error_m(one, TRUTHS[0]) <= 1.0
    assert abs(two.kappa - one.kappa) < 0.05                      # it fits as well as ever...
    assert two.unanswered and two.confidence < 0.01               # ...but so does the other copy
    alt = two.alternative
    copy_x = TRUTHS[0][0] + mask.shape[1] + 40
    best = two.top_k[0]
    assert {round(best[0] / 10), round(alt[0] / 10)} & {round(TRUTHS[0][0] / 10), round(copy_x / 10)}
    assert abs(abs(alt[0] - best[0]) - (mask.shape[1] + 40)) * RES <= 2.0 and abs(alt[1] - best[1]) * RES <= 2.0
    away = abs(alt[0] - best[0]) * RES
    assert two.reason.startswith("not sure") and f"{away:.0f} m away" in two.reason


def test_each_place_found_carries_its_own_heading(scene) -> None:
    """With the heading unknown, every place of the answer (top-k, the alternative) is fitted at its
    own heading: the town beside a copy turned a quarter turn gives headings 90 degrees apart."""
    mask, _ = scene
    assert mask.shape[0] == mask.shape[1]
    turned = np.concatenate([mask, np.full((mask.shape[0], 40), GRASS, np.uint8), np.rot90(mask, k=-1)], axis=1)
    index = profile_index(semantic_map(turned, TABLE, CLASSES), RES)
    q = _query(mask, TRUTHS[0])
    loc = run_profile(ProfileConfig(heading_deg=None), index, q.semantic, q.camera)
    assert len(loc.headings) == len(loc.top_k) and loc.headings[0] == loc.heading_deg
    assert loc.alternative is not None and loc.alternative_heading is not None
    apart = (loc.alternative_heading - loc.heading_deg) % 360.0
    assert min(abs(apart - 90.0), abs(apart - 270.0)) <= 5.0, (loc.heading_deg, loc.alternative_heading)


@pytest.mark.slow  # make test-slow: a profile search from points; masks take the same path in make test
def test_landmark_lists_on_both_sides(scene) -> None:
    """The paper's input, points only: grid points of the aerial mask, grid points of the panorama."""
    mask, _ = scene
    aerial = landmarks_from_mask(mask, TABLE, CLASSES, mode="grid", stride=10, min_size=20)
    index = profile_index(aerial, RES)
    xy = TRUTHS[1]
    pano = render_panorama(mask, TABLE, RES, xy)
    ground = landmarks_from_mask(pano.labels, pano.table, CLASSES, mode="grid", stride=8, min_size=10, panorama=True)
    config = ProfileConfig(min_confidence=-1.0, coarse_m=2.5, levels=2)  # points: a low kappa; a coarser start
    loc = run_profile(config, index, ground, Camera(1232, 224))
    assert _error_m(loc, xy) <= 4.0


def test_query_profile_reads_ground_rows_at_their_distance() -> None:
    """A road patch 10-14 m north and grass elsewhere: it lands in the radius bins of 10-14 m around azimuth 0."""
    mask = np.full((201, 201), GRASS, np.uint8)
    mask[100 - 28:100 - 20, 96:105] = ROAD                      # 10-14 m north at 0.5 m/px, 4.5 m wide: +-13 deg
    pano = render_panorama(mask, TABLE, RES, (100, 100), RenderConfig())
    cam = Camera(1232, 224)
    radii = ray_radii(cam, 16, 3.0, 60.0)
    q = query_from_mask(semantic_map(pano.labels, pano.table, CLASSES), cam, bins=72, radii=radii)
    road = q.q[CLASSES.names.index("road")]
    ks, az = np.nonzero(road[:-1] > 0.5)
    assert set(az.tolist()) <= {70, 71, 0, 1, 2} and ks.size
    assert all(9.0 <= radii[0][k] <= 15.0 for k in ks)


def test_localize_cli_with_the_profile_method(scene, tmp_path: Path) -> None:
    mask, _ = scene
    xy, heading = TRUTHS[1], 75.0
    pano = render_panorama(mask, TABLE, RES, xy, RenderConfig(heading_deg=heading))
    Image.fromarray(mask).save(tmp_path / "aerial.png")
    Image.fromarray(np.where(pano.labels == pano.table.by_name["sky"].id, 0, pano.labels).astype(np.uint8)).save(
        tmp_path / "pano.png")                                 # sky as unlabeled: classes13 has no sky
    base = ["--aerial", str(tmp_path / "aerial.png"), "--aerial-table", "classes13.toml",
            "--ground", str(tmp_path / "pano.png"), "--ground-landmarks", "aerial13", "--ground-table", "classes13.toml",
            "--aerial-resolution", str(RES), "--truth", f"{xy[0]},{xy[1]}"]
    res = CliRunner().invoke(localize_command, [*base, "--method", "profile", "--heading", "unknown", "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["method"] == "profile" and out["truth"]["error_m"] <= 1.5
    assert abs((out["heading_deg"] - heading + 180) % 360 - 180) <= 4.0 and out["kappa"] > 0.5 and out["confidence"] >= MASK_MIN_CONFIDENCE
    bad = CliRunner().invoke(localize_command, [*base, "--method", "paper", "--heading", "unknown"])
    assert bad.exit_code == 2 and "--method profile" in bad.output
    default = CliRunner().invoke(localize_command, [*base, "--json"])  # the profile method is the default
    assert default.exit_code == 0 and json.loads(default.stdout)["method"] == "profile"
    bad = CliRunner().invoke(localize_command, [*base, "--window", "50"])
    assert bad.exit_code == 2 and "--window applies to --method paper: add --method paper" in bad.output
    no_resolution = [a for a in base if a not in ("--aerial-resolution", str(RES))]
    bad = CliRunner().invoke(localize_command, no_resolution)
    assert bad.exit_code == 2 and "--aerial-resolution" in bad.output and "--method paper" in bad.output
    paper = CliRunner().invoke(localize_command, [*base, "--method", "paper", "--out", str(tmp_path / "loc")])
    assert paper.exit_code == 0 and (tmp_path / "loc" / "aerial_graph.png").is_file(), paper.output
    res = CliRunner().invoke(localize_command, [*base, "--method", "profile", "--out", str(tmp_path / "loc")])
    assert res.exit_code == 0, res.output
    assert not (tmp_path / "loc" / "aerial_graph.png").exists()  # not left over from the paper run
    assert "confidence" in res.stderr and (tmp_path / "loc" / "localization.png").is_file()
    assert json.loads((tmp_path / "loc" / "result.json").read_text())["method"] == "profile"


def test_bench_compares_methods_side_by_side(tmp_path: Path) -> None:
    for seed in (3, 11):
        Image.fromarray(town(400, seed=seed)).save(tmp_path / f"town{seed}.png")
    res = CliRunner().invoke(localize_bench_command, [
        str(tmp_path / "town3.png"), "--aerial-resolution", str(RES), "--out", str(tmp_path / "bench"), "--viewpoints", "4",
        "--methods", "paper,profile", "--view-heading", "unknown", "--height-spread", "0.5", "--no-plots"])
    assert res.exit_code == 0, res.output
    results = json.loads((tmp_path / "bench" / "results.json").read_text())
    assert results["format_version"] == 3 and list(results["methods"]) == ["paper", "profile"]
    prof = results["methods"]["profile"]
    assert prof["median_error"] <= 2.0 and prof["median_heading_error_deg"] <= 5.0
    headings = [v["heading_deg"] for v in results["viewpoints"]]
    assert len(set(headings)) == 4 and results["methods"]["paper"]["median_heading_error_deg"] is None
    assert prof["roc_auc"] is None  # one scene: no non-matching pair
    assert all(set(v["methods"]) == {"paper", "profile"} for v in results["viewpoints"])
    assert "profile" in res.stderr and "AUC" in res.stderr
    bad = CliRunner().invoke(localize_bench_command, [str(tmp_path / "town3.png"), "--aerial-resolution", str(RES),
                                                      "--out", str(tmp_path / "b2"), "--methods", "paper,nope"])
    assert bad.exit_code == 2 and "methods must be" in bad.output
    # the default: the profile method first (it fills the summary; the paper method has no random
    # candidate to report then), with plots, and again into the same folder
    for _ in range(2):
        res = CliRunner().invoke(localize_bench_command, [str(tmp_path / "town3.png"), "--aerial-resolution", str(RES),
                                                          "--out", str(tmp_path / "default"), "--viewpoints", "3"])
        assert res.exit_code == 0, res.output
        results = json.loads((tmp_path / "default" / "results.json").read_text())
        assert results["settings"]["methods"] == ["profile", "paper"]
        assert results["summary"]["median_error"] == results["methods"]["profile"]["median_error"] <= 2.0
        assert results["baselines"]["random_candidate_mean"] is None and "None" not in res.stderr
        with Image.open(tmp_path / "default" / "errors.png") as im:
            assert im.format == "PNG"


def test_scores_do_not_depend_on_the_chunk_size(scene) -> None:
    """Memory is bounded by scoring positions a chunk at a time: the answer must not change with the chunk."""
    mask, index = scene
    q = _query(mask, TRUTHS[0], heading=75.0)
    answers = [run_profile(ProfileConfig(heading_deg=heading, chunk=chunk, min_confidence=-1.0), index, q.semantic,
                           q.camera) for heading in (None, 75.0) for chunk in (7, 4096)]
    for a, b in (answers[:2], answers[2:]):
        assert a.map_xy == b.map_xy and a.heading_deg == b.heading_deg and a.confidence == b.confidence


def test_pruned_search_keeps_the_exhaustive_best(scene) -> None:
    """Heading unknown, the coarse grid is scored best bound first and stops early: the kept best must be
    exactly those of scoring every position (the bound is an upper bound of every rotation's score)."""
    from localization.profile.search import class_prior, grid_positions, score_positions

    mask, index = scene
    q = _query(mask, TRUTHS[2], heading=222.0)
    config = ProfileConfig(heading_deg=None, chunk=64)
    query = profile_query(q.semantic, q.camera, config)
    xy = grid_positions(index.shape, 4.0 / RES)
    prior = class_prior(index, query, xy)
    weights = -np.log(np.clip(prior, config.min_prior, 1.0))
    full, full_shift = score_positions(index, query, xy, config, prior, weights)
    pruned, pruned_shift = score_positions(index, query, xy, config, prior, weights, keep=40)
    assert np.isinf(pruned).sum() > len(xy) // 5            # many positions were never scored
    best = np.argsort(-full, kind="stable")[:40]
    assert set(best.tolist()) == set(np.argsort(-pruned, kind="stable")[:40].tolist())
    assert np.allclose(pruned[best], full[best], atol=1e-5)
    assert np.allclose(pruned_shift[best], full_shift[best], atol=1e-3)


@pytest.mark.parametrize("heading", [75.0, None])
def test_several_heights_score_each_position_as_the_best_of_them_alone(scene, heading) -> None:
    """score_poses (the heights of --camera-height unknown, from class lookups and matrix products)
    gives each position the best of the scores each height's profile gets by itself from
    score_positions (one-hot profiles), and says which height that was."""
    from localization.profile.profiles import query_poses
    from localization.profile.search import class_prior, grid_positions, score_poses, score_positions

    mask, index = scene
    q = _query(mask, TRUTHS[0], heading=75.0)
    config = ProfileConfig(heading_deg=heading, chunk=256)
    radii = ray_radii(q.camera, config.radii, config.min_range_m, config.max_range_m)
    query = query_poses(q.semantic, q.camera, bins=72, radii=radii, heading_deg=heading, heights=(1.5, 2.0, 2.5))
    xy = grid_positions(index.shape, 4.0 / RES)
    prior = class_prior(index, query, xy)
    weights = -np.log(np.clip(prior, config.min_prior, 1.0))
    score, shift, which = score_poses(index, query, xy, config, prior, weights)
    alone = np.stack([score_positions(index, v, xy, config, prior, weights)[0] for v in query.variants], axis=1)
    assert np.allclose(score, alone.max(axis=1), atol=1e-5)
    clear = np.sort(alone, axis=1)[:, -1] - np.sort(alone, axis=1)[:, -2] > 1e-4   # no near tie between heights
    assert clear.sum() > len(xy) // 2 and np.array_equal(which[clear], alone.argmax(axis=1)[clear])
    assert {int(w) for w in which} == {0, 1, 2}   # each height fits somewhere best


@pytest.mark.parametrize("heading,levels", [(None, None), (None, 0), (30.0, None)])
def test_answers_do_not_depend_on_the_thread_count(scene, heading, levels) -> None:
    """Also every coarse score (levels 0): the pruned search accepts chunks as one thread would."""
    mask, index = scene
    q = _query(mask, TRUTHS[1], heading=30.0)
    a, b = (run_profile(ProfileConfig(heading_deg=heading, threads=t, chunk=64, levels=levels), index, q.semantic,
                        q.camera) for t in (1, 3))
    assert a.map_xy == b.map_xy and a.heading_deg == b.heading_deg and a.confidence == b.confidence
    assert np.array_equal(a.likelihoods, b.likelihoods)


def test_a_building_point_hides_the_building_behind_it() -> None:
    """Landmark points: an opaque building point in front hides one of another class behind it."""
    from localization.profile.profiles import first_hits

    bearing = np.radians(np.array([[0.0, 2.0, 90.0]]))           # north, just east of north, east
    dist = np.array([[10.0, 40.0, 40.0]])
    hits = first_hits(bearing, dist, np.array([0, 1, 1]), 2, 72, (4.0,))
    assert hits[0, 0, 0] == pytest.approx(1.0) and hits[0, 1, 0] == 0.0  # the near one wins bin 0
    assert hits[0, 1, 18] == pytest.approx(1.0)                          # alone in the east
    assert (hits[0, :, 36:54] == 0).all()                                # nothing south-west
    # 4 m wide at 10 m: atan(0.4) = 21.8 deg, so bins up to 20 deg (4 bins of 5) are covered
    assert hits[0, 0, 4] > 0 and hits[0, 0, 5] == 0


def test_landmark_points_behind_a_building_are_not_predicted() -> None:
    """Aerial points: a tree straight behind a building cannot be seen, one off to the side can."""
    from localization.common.landmarks import Landmarks
    from localization.profile.profiles import AerialLandmarkIndex

    classes = ("building", "road", "vegetation", "footway")
    lm = Landmarks(xy=np.array([[50.0, 40.0], [50.0, 10.0], [90.0, 50.0]]), cls=np.array([0, 2, 2]),
                   classes=classes, width=100, height=100)
    index = AerialLandmarkIndex(lm, 1.0)            # 1 m/px: the building 10 m north, trees 40 m N and E
    radii = np.array([5.0, 10.0])
    P, _ = index.profiles(np.array([[50.0, 50.0]]), radii, 72)
    tree, slot = classes.index("vegetation"), len(radii)
    north, east = 0, 18
    assert P[0, 0, slot, north] > 0.9                    # the building, first hit to the north
    assert P[0, tree, slot, east] > 0.5                  # the tree in the open to the east
    assert P[0, tree, slot, north] < 0.05                # the one behind the building: hidden
    # from the west of the building's façade the northern tree is in the open again
    P, _ = index.profiles(np.array([[20.0, 10.0]]), radii, 72)
    assert P[0, tree, slot, east] > 0.5


def test_numpys_blas_runs_on_one_thread_under_the_searchs_threads_and_is_given_back() -> None:
    from threadpoolctl import threadpool_info

    from localization.profile.search import _map

    def blas_threads() -> list[int]:
        return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]

    before = blas_threads()
    assert before, "numpy's BLAS is not found"
    inside = _map(lambda _: blas_threads(), [0, 1, 2, 3], 2)
    assert inside == [[1] * len(before)] * 4
    assert blas_threads() == before
    assert _map(lambda _: blas_threads(), [0], 1) == [before]  # one thread of ours: BLAS keeps its own


def test_searches_on_a_callers_threads_leave_the_blas_limit_as_it_was() -> None:
    import threading
    import time

    from threadpoolctl import threadpool_info

    from localization.profile.search import _map

    def blas_threads() -> list[int]:
        return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]

    before = blas_threads()
    seen = {}

    def search(name: str, seconds: float) -> None:
        _map(lambda _: time.sleep(seconds), [0, 1], 2)

    first = threading.Thread(target=search, args=("first", 0.3))
    second = threading.Thread(target=search, args=("second", 0.8))
    first.start()
    time.sleep(0.1)
    second.start()
    time.sleep(0.05)
    seen["both running"] = blas_threads()
    first.join()
    seen["first done, second running"] = blas_threads()
    second.join()
    # the limit is the process's and one thread at a time may set it: on a caller's threads it is left alone
    assert seen == {"both running": before, "first done, second running": before}
    assert blas_threads() == before
