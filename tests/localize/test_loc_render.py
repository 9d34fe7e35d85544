"""Rendered panoramas (localization.bench.render) and the rendered-panorama benchmark (localization.bench.rendered).

Scenes are constructed masks in the classes13 ids, so each expected pixel follows from the
camera geometry: a building of height h whose near face is d metres away tops out at
elevation atan((h - 2) / d), spans 2 atan(half width / d) of azimuth, and hides what is behind
it unless that rises higher.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import write_dataset_manifest
from PIL import Image

from localization.bench.render import (
    NoiseConfig,
    RenderConfig,
    apply_noise,
    azimuth_to_column,
    elevation_to_row,
    panorama_table,
    render_panorama,
    render_view,
)
from localization.bench.rendered import BenchConfig, Scene, load_dataset_scenes, run_bench
from localization.bench.visible import landmark_cells, visible_landmarks
from localization.cli.bench import localize_bench_command
from localization.common.landmarks import landmarks_from_mask, load_landmark_classes
from localization.paper.config import PaperConfig
from localization.paper.match import aerial_graph, localize
from localization.pipeline import LocalizeConfig, run
from osmseg.classes import load_class_table
from osmseg.errors import ConfigError

TABLE = load_class_table("classes13.toml")
ID = {c.name: c.id for c in TABLE.classes}
B, ROAD, GRASS, TREE, FOOT = ID["building"], ID["highway"], ID["grass"], ID["tree"], ID["footway"]
SKY = panorama_table(TABLE).by_name["sky"].id
CLASSES = load_landmark_classes("aerial13")
CFG = RenderConfig()  # 1232 x 224, camera 2 m, range 100 m, building 10 m, tree 6 m
RES = 0.5             # m/px of the constructed masks
W = CFG.width


def field(size: int = 401) -> np.ndarray:
    return np.full((size, size), GRASS, np.uint8)


def columns_of(labels: np.ndarray, cid: int) -> np.ndarray:
    return np.flatnonzero((labels == cid).any(axis=0))


def town(size: int = 400, seed: int = 0) -> np.ndarray:
    """A small seeded town: a road grid with footways, buildings in the blocks, trees on the grass."""
    rng = np.random.default_rng(seed)
    m = np.full((size, size), GRASS, np.uint8)
    for c in range(50, size, 100):
        m[:, c - 8:c + 8] = FOOT
        m[c - 8:c + 8, :] = FOOT
        m[:, c - 5:c + 5] = ROAD
        m[c - 5:c + 5, :] = ROAD
    for by in range(50, size - 50, 100):
        for bx in range(50, size - 50, 100):
            for _ in range(rng.integers(1, 4)):
                w, h = rng.integers(15, 35, size=2)
                x, y = bx + rng.integers(12, 88 - w), by + rng.integers(12, 88 - h)
                m[y:y + h, x:x + w] = B
    yy, xx = np.mgrid[:size, :size]
    for _ in range(12):
        x, y = rng.integers(10, size - 10, size=2)
        if m[y, x] == GRASS:
            m[(xx - x) ** 2 + (yy - y) ** 2 <= rng.integers(9, 30)] = TREE
    return m


# --------------------------------------------------------------------------- geometry


def test_building_north_is_centred_with_its_angular_width_and_height() -> None:
    mask = field()
    mask[121:161, 180:221] = B  # 41 px wide, near face at row 160 (edge 160.5): 39.5 px = 19.75 m north
    pano = render_panorama(mask, TABLE, RES, (200, 200), CFG)
    cols = columns_of(pano.labels, B)
    centre = azimuth_to_column(0.0, W)
    half = math.degrees(math.atan(20.5 / 39.5)) / 360 * W  # half the angular width, in columns
    assert abs(cols.min() - math.ceil(centre - half)) <= 1 and abs(cols.max() - math.floor(centre + half)) <= 1
    assert len(cols) == pytest.approx(2 * half, abs=2) and cols.mean() == pytest.approx(centre, abs=1)
    north = pano.labels[:, int(centre)]
    rows = np.flatnonzero(north == B)
    top = elevation_to_row(math.degrees(math.atan((10 - 2) / 19.75)), CFG)
    base = elevation_to_row(-math.degrees(math.atan(2 / 19.75)), CFG)
    assert abs(rows.min() - math.ceil(top)) <= 1 and abs(rows.max() - math.floor(base)) <= 1
    assert np.all(np.diff(rows) == 1)  # one solid facade
    assert pano.table.by_id[int(north[0])].name == "sky" and north[-1] == GRASS
    south = pano.labels[:, int(azimuth_to_column(180.0, W) + 1)]
    assert B not in south


def test_building_behind_a_taller_one_is_hidden_but_a_tower_shows() -> None:
    near = field()
    near[150:171, 180:221] = B  # 29.5 px = 14.75 m away: tops out at atan(8 / 14.75) = 28.5 deg
    behind = near.copy()
    behind[100:121, 190:211] = B  # 79.5 px = 39.75 m away: atan(8 / 39.75) = 11.4 deg, narrower too
    view = lambda m, cfg=CFG: render_panorama(m, TABLE, RES, (200, 200), cfg).labels  # noqa: E731
    assert np.array_equal(view(near), view(behind))
    # the same far block 30 m tall rises above the near roof: atan(28 / 39.75) = 35.2 deg > 28.5 deg
    tower = RenderConfig(heights={"building": 10.0, "construction": 30.0}, vfov_deg=90)
    behind[100:121, 190:211] = ID["construction"]
    seen = view(behind, tower)
    col = int(azimuth_to_column(0.0, W))
    rows = np.flatnonzero(seen[:, col] == ID["construction"])
    assert len(rows) and rows.max() < np.flatnonzero(seen[:, col] == B).min()
    assert abs(rows.min() - math.ceil(elevation_to_row(math.degrees(math.atan(28 / 39.75)), tower))) <= 1


def test_road_is_visible_up_to_the_first_occluder() -> None:
    mask = field()
    mask[0:200, 195:206] = ROAD  # a road running north from the viewpoint to the mask edge
    col = int(azimuth_to_column(0.0, W))
    open_road = render_panorama(mask, TABLE, RES, (200, 200), CFG).labels[:, col]
    horizon_far = elevation_to_row(-math.degrees(math.atan(2 / 100)), CFG)  # ground at the 100 m range
    road_rows = np.flatnonzero(open_road == ROAD)
    assert road_rows.max() == CFG.height - 1 and abs(road_rows.min() - horizon_far) <= 1
    assert open_road[CFG.height // 2 - 1] == SKY and open_road[CFG.height // 2] == 0  # beyond range: "far"
    mask[121:141, 150:251] = B  # a building across the road, near face 59.5 px = 29.75 m away
    blocked = render_panorama(mask, TABLE, RES, (200, 200), CFG).labels[:, col]
    base = elevation_to_row(-math.degrees(math.atan(2 / 29.75)), CFG)
    road_rows = np.flatnonzero(blocked == ROAD)
    assert abs(road_rows.min() - base) <= 1 and road_rows.max() == CFG.height - 1
    assert np.all(blocked[: road_rows.min()][blocked[: road_rows.min()] != SKY] == B)  # road behind it: hidden


def test_wrap_around_at_azimuth_zero_and_heading() -> None:
    mask = field()
    mask[240:261, 190:211] = B  # due south, 20 m away
    pano = render_panorama(mask, TABLE, RES, (200, 200), CFG)
    cols = columns_of(pano.labels, B)
    left, right = cols[cols < W // 2], cols[cols >= W // 2]
    assert left.min() == 0 and right.max() == W - 1 and len(left) == len(right)  # split evenly at the seam
    lm = render_view(mask, TABLE, RES, (200, 200), CLASSES, min_size=1).landmarks
    x = lm.xy[[lm.classes[c] == "building" for c in lm.cls], 0]
    assert len(x) == 1 and min(x[0], W - x[0]) <= 1  # one landmark across the seam, centred on it
    turned = render_panorama(mask, TABLE, RES, (200, 200), RenderConfig(heading_deg=180)).labels
    assert columns_of(turned, B).mean() == pytest.approx(azimuth_to_column(180.0, W, 180.0), abs=1)


def test_render_is_fast_enough_and_checks_its_input() -> None:
    mask = np.tile(town(), (4, 4))[:1280, :1280]
    start = time.perf_counter()
    pano = render_panorama(mask, TABLE, 0.3, (640, 650), CFG)
    assert time.perf_counter() - start < 1.0
    assert pano.labels.shape == (224, 1232) and pano.labels.dtype == np.uint8 and pano.rgb().shape == (224, 1232, 3)
    with pytest.raises(ConfigError, match="outside"):
        render_panorama(mask, TABLE, 0.3, (2000, 5), CFG)
    with pytest.raises(ConfigError, match="resolution"):
        render_panorama(mask, TABLE, 0.0, (5, 5), CFG)
    with pytest.raises(ConfigError, match="not in the class table"):
        render_panorama(mask, TABLE, 0.3, (5, 5), RenderConfig(far="lava"))


# --------------------------------------------------------------------------- noise


def _landmark_class_of(labels: np.ndarray) -> np.ndarray:
    lut = np.full(256, -1)
    for c in (TABLE.unlabeled, *TABLE.classes):
        if c.name in CLASSES.mapping:
            lut[c.id] = CLASSES.names.index(CLASSES.mapping[c.name])
    return lut[labels]


def _scene_view(**noise: float) -> tuple[np.ndarray, np.ndarray]:
    mask = town()
    clean = render_panorama(mask, TABLE, RES, (150, 148), CFG)
    noisy = apply_noise(clean.labels, clean.table, CLASSES, NoiseConfig(seed=3, **noise))  # type: ignore[arg-type]
    return clean.labels, noisy


def test_confusion_relabels_the_given_fraction_of_components() -> None:
    clean, noisy = _scene_view(confusion=1.0)
    comps = landmarks_from_mask(clean, panorama_table(TABLE), CLASSES, mode="component", min_size=1, panorama=True)
    assert len(comps) >= 8
    before, after = _landmark_class_of(clean), _landmark_class_of(noisy)
    for k, pix in enumerate(comps.pixels or ()):
        now = np.unique(after[pix[:, 1], pix[:, 0]])
        assert len(now) == 1 and now[0] not in (-1, comps.cls[k])  # another landmark class, whole component
    assert np.array_equal(clean[before < 0], noisy[before < 0])  # sky, grass, far: untouched
    _, half = _scene_view(confusion=0.5)
    changed = sum(int(np.any(_landmark_class_of(half)[p[:, 1], p[:, 0]] != comps.cls[k]))
                  for k, p in enumerate(comps.pixels or ()))
    assert changed == round(0.5 * len(comps))


def test_missed_landmarks_become_unlabeled() -> None:
    clean, _ = _scene_view()
    table = panorama_table(TABLE)
    comps = landmarks_from_mask(clean, table, CLASSES, mode="component", min_size=1, panorama=True)
    sizes = np.array([len(p) for p in comps.pixels or ()])
    cut = int(np.median(sizes))
    _, noisy = _scene_view(miss_small_px=cut)
    for pix, size in zip(comps.pixels or (), sizes):
        values = noisy[pix[:, 1], pix[:, 0]]
        assert np.all(values == 0) if size < cut else np.array_equal(values, clean[pix[:, 1], pix[:, 0]])
    after = landmarks_from_mask(noisy, table, CLASSES, mode="centroid", min_size=1, panorama=True)
    assert len(after) == int((sizes >= cut).sum())
    _, none_left = _scene_view(miss_prob=1.0)
    assert len(landmarks_from_mask(none_left, table, CLASSES, min_size=1, panorama=True)) == 0
    _, untouched = _scene_view(miss_prob=0.0)
    assert np.array_equal(untouched, clean)


def test_viewpoint_offset_moves_the_camera_not_the_truth() -> None:
    mask = town()
    view = render_view(mask, TABLE, RES, (150, 148), CLASSES, noise=NoiseConfig(offset_m=5.0, seed=1))
    assert view.truth == (150.0, 148.0)
    cx, cy = view.panorama.camera
    assert math.hypot(cx - 150, cy - 148) * RES == pytest.approx(5.0)
    assert np.array_equal(view.panorama.labels, render_panorama(mask, TABLE, RES, (cx, cy), CFG).labels)


def test_views_are_deterministic_for_a_seed() -> None:
    mask = town()
    noise = NoiseConfig(confusion=0.5, miss_prob=0.3, offset_m=3.0, seed=7)
    a = render_view(mask, TABLE, RES, (150, 148), CLASSES, noise=noise)
    b = render_view(mask, TABLE, RES, (150, 148), CLASSES, noise=noise)
    assert np.array_equal(a.panorama.labels, b.panorama.labels) and np.array_equal(a.landmarks.xy, b.landmarks.xy)
    c = render_view(mask, TABLE, RES, (150, 148), CLASSES, noise=NoiseConfig(confusion=0.5, miss_prob=0.3,
                                                                                 offset_m=3.0, seed=8))
    assert not np.array_equal(a.panorama.labels, c.panorama.labels)


# --------------------------------------------------------------------------- benchmark


def _check_results(results: dict, n: int, out: Path) -> None:
    s = results["summary"]
    assert s["n"] == n == len(results["viewpoints"]) and s["answered"] + s["unanswered"] == n
    recall = [s["recall_at"][k] for k in ("10", "25", "50")]
    assert all(0 <= r <= 1 for r in recall) and recall == sorted(recall)
    assert results["seed"] == results["settings"]["seed"] and results["settings"]["render"]["width"] == 1232
    assert results["unit"] == "m" and results["format_version"] == 3
    assert sorted(results["by_num_classes"]) == ["2", "3", "4"]
    assert [len(results["by_num_classes"][k]["subsets"]) for k in "234"] == [6, 4, 1]
    for rec in results["viewpoints"]:
        if not rec["unanswered"]:
            dx, dy = rec["map"][0] - rec["truth"][0], rec["map"][1] - rec["truth"][1]
            assert rec["error_px"] == pytest.approx(math.hypot(dx, dy), abs=1e-3)
            assert rec["error"] == pytest.approx(rec["error_px"] * rec["resolution_m"], abs=1e-3)
            assert rec["top5_mean"] >= 0 and rec["ties"] >= 1 and rec["candidate_guess"] >= 0
    if s["answered"]:
        assert s["mean_error"] >= 0 and s["median_error"] >= 0
    on_disk = json.loads((out / "results.json").read_text())
    assert on_disk["summary"] == s
    for png in ("errors.png", "classes.png"):
        with Image.open(out / png) as im:
            assert im.format == "PNG" and im.size[0] > 300


def test_bench_end_to_end_on_a_constructed_town(tmp_path: Path) -> None:
    scene = Scene("town", town(), TABLE, RES)
    config = BenchConfig(viewpoints=3, seed=5, margin_m=10.0, save_panoramas=1, pictures=2)
    results = run_bench([scene], config, tmp_path)
    _check_results(results, 3, tmp_path)
    assert len(list((tmp_path / "panoramas").glob("*.png"))) == 1
    # the saved panorama holds the class ids (so it can be a query mask) and shows the class colours
    first = results["viewpoints"][0]
    drawn = render_view(scene.mask, TABLE, RES, tuple(first["truth"]), CLASSES).panorama
    with Image.open(tmp_path / "panoramas" / "0000_town.png") as im:
        assert im.mode == "P" and np.array_equal(np.asarray(im), drawn.labels)
        assert np.array_equal(np.asarray(im.convert("RGB")), panorama_table(TABLE).colorize(drawn.labels))
    views = sorted(p.name for p in (tmp_path / "views").glob("*.png"))
    assert views == ["0000_town_map.png", "0000_town_panorama.png", "0001_town_map.png", "0001_town_panorama.png"]
    with Image.open(tmp_path / "views" / "0000_town_map.png") as im:  # the 400 px mask, drawn with its legend
        assert im.format == "PNG" and im.size[0] > 400 and im.size[1] > im.size[0]
    for rec in results["viewpoints"]:  # off-centre, on standable ground, away from the border
        x, y = rec["truth"]
        assert scene.mask[int(y), int(x)] in (ROAD, FOOT, GRASS) and 20 <= x < 380 and 20 <= y < 380
    # the prebuilt aerial graph gives what localize() gives on the same rendered view
    rec = results["viewpoints"][0]
    view = render_view(scene.mask, TABLE, RES, tuple(rec["truth"]), CLASSES)
    aerial = landmarks_from_mask(scene.mask, TABLE, CLASSES)
    direct = localize(aerial, view.landmarks)
    cached = run(LocalizeConfig(paper=PaperConfig(p=config.p, top_k=config.top_k)), aerial_graph(aerial), view.landmarks)
    assert direct.map_xy == cached.map_xy and rec["map"] == (None if direct.map_xy is None else list(direct.map_xy))
    again = run_bench([scene], config, tmp_path / "again", plots=False)
    def strip(value):  # everything but the timings
        if isinstance(value, dict):
            return {k: strip(v) for k, v in value.items() if not k.endswith("_s")}
        return [strip(v) for v in value] if isinstance(value, list) else value
    assert strip(again["viewpoints"]) == strip(results["viewpoints"])  # same seed, same viewpoints and answers


def test_pictures_of_a_photo_show_the_photo_not_the_whole_panorama(tmp_path: Path) -> None:
    """--fov 90 --pictures: the landmarks are in the photo's 308 columns, and so is the picture under them."""
    scene = Scene("town", town(), TABLE, RES)
    config = BenchConfig(viewpoints=1, seed=5, margin_m=10.0, pictures=1, fov_deg=90.0, methods=("profile",),
                         negatives=False)
    run_bench([scene], config, tmp_path, plots=False)
    with Image.open(tmp_path / "views" / "0000_town_panorama.png") as photo:
        photo_aspect = photo.size[0] / photo.size[1]
    run_bench([scene], BenchConfig(viewpoints=1, seed=5, margin_m=10.0, pictures=1, methods=("profile",),
                                   negatives=False), tmp_path / "pano", plots=False)
    with Image.open(tmp_path / "pano" / "views" / "0000_town_panorama.png") as pano:
        assert photo_aspect < 0.5 * pano.size[0] / pano.size[1]   # 308x224 drawn, not 1232x224


def test_cli_on_a_mask_file_and_on_a_dataset_folder(tmp_path: Path) -> None:
    mask_file = tmp_path / "town.png"
    Image.fromarray(town()).save(mask_file)
    runner = CliRunner()
    args = ["--viewpoints", "3", "--seed", "2", "--margin", "10", "--confusion", "0.2", "--offset", "2", "--methods", "paper"]
    res = runner.invoke(localize_bench_command, [str(mask_file), "--aerial-resolution", "0.5", "--out", str(tmp_path / "a"),
                                                 *args], obj={"verbosity": 0})
    assert res.exit_code == 0, res.output
    assert res.stdout.strip() == str(tmp_path / "a" / "results.json")
    assert "recall @10 m" in res.stderr and "2 classes (6 subsets)" in res.stderr
    results = json.loads((tmp_path / "a" / "results.json").read_text())
    _check_results(results, 3, tmp_path / "a")
    assert results["settings"]["noise"]["confusion"] == 0.2 and results["settings"]["noise"]["offset_m"] == 2.0
    # a dataset folder as `osmseg build` writes it: labels/ + manifest.json (classes, resolutions)
    ds = tmp_path / "ds"
    (ds / "labels").mkdir(parents=True)
    Image.fromarray(town(seed=1)).save(ds / "labels" / "s0.png")
    Image.fromarray(town(seed=2)).save(ds / "labels" / "s1.png")
    write_dataset_manifest(ds, TABLE.to_dict(), [{"name": "s0", "ground_resolution_m": 0.5},
                                                 {"name": "s1", "ground_resolution_m": 0.5}])
    assert [s.name for s in load_dataset_scenes(ds)] == ["s0", "s1"]
    res = runner.invoke(localize_bench_command, [str(ds), "--out", str(tmp_path / "b"), *args, "--no-plots"],
                        obj={"verbosity": -1})
    assert res.exit_code == 0, res.output
    results = json.loads((tmp_path / "b" / "results.json").read_text())
    assert [r["scene"] for r in results["viewpoints"]] == ["s0", "s1", "s0"]  # round-robin over the masks
    assert not (tmp_path / "b" / "errors.png").exists()


def test_cli_bad_input_is_one_line(tmp_path: Path) -> None:
    mask_file = tmp_path / "town.png"
    Image.fromarray(town()).save(mask_file)
    runner = CliRunner()
    res = runner.invoke(localize_bench_command, [str(mask_file), "--out", str(tmp_path / "o")], obj={"verbosity": 0})
    assert res.exit_code == 2 and "--aerial-resolution" in res.stderr and "Traceback" not in res.output
    res = runner.invoke(localize_bench_command, [str(tmp_path), "--out", str(tmp_path / "o")], obj={"verbosity": 0})
    assert res.exit_code == 1 and "manifest.json" in res.stderr
    res = runner.invoke(localize_bench_command, [str(mask_file), "--aerial-resolution", "0.5", "--viewpoints", "100000",
                                                 "--out", str(tmp_path / "o")], obj={"verbosity": 0})
    assert res.exit_code == 2 and "pixels of the standable classes" in res.stderr and "100,000 viewpoints asked" in res.stderr
    res = runner.invoke(localize_bench_command, [str(mask_file), "--aerial-resolution", "0.5", "--class-height", "tall",
                                                 "--out", str(tmp_path / "o")], obj={"verbosity": 0})
    assert res.exit_code == 2 and "CLASS=METRES" in res.stderr
    res = runner.invoke(localize_bench_command, [str(mask_file), "--aerial-resolution", "0.5", "--aerial-size", "9x9",
                                                 "--out", str(tmp_path / "o")], obj={"verbosity": 0})
    assert res.exit_code == 2 and "No such option '--aerial-size'" in res.stderr  # a pairs option: localize-pairs's
    res = runner.invoke(localize_bench_command, [str(mask_file), "--aerial-resolution", "0.5", "--visible-min-px", "5",
                                                 "--out", str(tmp_path / "o")], obj={"verbosity": 0})
    assert res.exit_code == 2 and "--query-landmarks visible only" in res.stderr


@pytest.mark.slow
def test_bench_on_the_demo_dataset(tmp_path: Path) -> None:
    from osmseg.cli.main import cli

    assert CliRunner().invoke(cli, ["-q", "demo", "--out", str(tmp_path / "demo"), "--no-train"]).exit_code == 0
    scenes = load_dataset_scenes(tmp_path / "demo" / "dataset")
    results = run_bench(scenes, BenchConfig(viewpoints=8, seed=0), tmp_path / "bench")
    _check_results(results, 8, tmp_path / "bench")
    assert results["scenes"][0]["resolution_m"] == pytest.approx(0.297, abs=0.001)


# --------------------------------------------------------------------------- visible landmarks (the oracle)


@pytest.mark.parametrize("mode", ["centroid", "grid", "component"])
def test_landmark_cells_give_the_mask_landmarks_and_own_their_pixels(mode: str) -> None:
    mask = town(seed=3)
    lm, cells = landmark_cells(mask, TABLE, CLASSES, mode=mode, stride=40)
    plain = landmarks_from_mask(mask, TABLE, CLASSES, mode=mode, stride=40)
    assert np.array_equal(lm.xy, plain.xy) and np.array_equal(lm.cls, plain.cls)
    comps = landmarks_from_mask(mask, TABLE, CLASSES, mode="component", stride=40)
    comp_cls = np.full(mask.shape, -1)
    for p, c in zip(comps.pixels, comps.cls):
        comp_cls[p[:, 1], p[:, 0]] = c
    owned = comp_cls >= 0
    assert np.array_equal(cells >= 0, owned)  # every landmark pixel has a cell, nothing else
    assert np.array_equal(lm.cls[cells[owned]], comp_cls[owned])  # ... a cell of its own class
    if mode == "grid":  # a cell is the part of its component nearest to its node
        rng = np.random.default_rng(0)
        for k in rng.choice(len(comps), size=min(6, len(comps)), replace=False):
            p = comps.pixels[k]
            mine = np.unique(cells[p[:, 1], p[:, 0]])
            d = np.hypot(p[:, None, 0] - lm.xy[None, mine, 0], p[:, None, 1] - lm.xy[None, mine, 1])
            got = cells[p[:, 1], p[:, 0]]
            assert np.allclose(d[np.arange(len(p)), np.searchsorted(mine, got)], d.min(axis=1))


def test_visible_landmarks_are_the_aerial_ones_the_camera_sees() -> None:
    mask = field()
    mask[121:161, 180:221] = B   # north, 19.75 m away: seen
    mask[60:81, 190:211] = B     # right behind it, lower than its roof: hidden
    mask[190:211, 300:321] = B   # east, 50 m: seen
    aerial, cells = landmark_cells(mask, TABLE, CLASSES, mode="centroid")
    pano = render_panorama(mask, TABLE, RES, (200, 200), CFG, sources=True)
    assert pano.sources.shape == pano.labels.shape
    shows = pano.sources >= 0
    assert np.array_equal(mask.ravel()[pano.sources[shows]], pano.labels[shows])  # the source has the pixel's class
    shown, index = visible_landmarks(pano, cells, aerial, min_px=20)
    north = int(np.argmin(np.hypot(aerial.xy[:, 0] - 200, aerial.xy[:, 1] - 140.5)))
    east = int(np.argmin(np.hypot(aerial.xy[:, 0] - 310, aerial.xy[:, 1] - 200)))
    hidden = int(np.argmin(np.hypot(aerial.xy[:, 0] - 200, aerial.xy[:, 1] - 70)))
    assert north in index and east in index and hidden not in index
    at = dict(zip(index.tolist(), shown.xy.tolist()))
    assert at[north][0] == pytest.approx(azimuth_to_column(0.0, W), abs=1.5)
    assert at[east][0] == pytest.approx(azimuth_to_column(math.degrees(math.atan2(110, 0)), W), abs=1.5)
    assert shown.panorama and all(shown.classes[c] == "building" for c in shown.cls[np.isin(index, [north, east])])
    with pytest.raises(ConfigError, match="sources=True"):
        visible_landmarks(render_panorama(mask, TABLE, RES, (200, 200), CFG), cells, aerial)


def test_bench_with_visible_query_landmarks(tmp_path: Path) -> None:
    scene = Scene("town", town(), TABLE, RES)
    config = BenchConfig(viewpoints=3, seed=5, margin_m=10.0, query_landmarks="visible", mode="grid", stride=40)
    results = run_bench([scene], config, tmp_path, plots=False)
    assert results["settings"]["query_landmarks"] == "visible" and results["summary"]["n"] == 3
    lm, cells = landmark_cells(scene.mask, TABLE, CLASSES, mode="grid", stride=40)
    rec = results["viewpoints"][0]
    pano = render_panorama(scene.mask, TABLE, RES, tuple(rec["truth"]), CFG, sources=True)
    assert rec["query_landmarks"] == len(visible_landmarks(pano, cells, lm)[0])
    with pytest.raises(ConfigError, match="mask landmarks"):
        BenchConfig(query_landmarks="visible", noise=NoiseConfig(confusion=0.2))


def test_aerial_landmarks_of_a_byte_mask_are_those_of_the_same_mask_in_int64() -> None:
    """The one-byte path for large masks (row-block centroids, a byte lookup) finds the same points."""
    mask = np.tile(town(400, seed=3), (2, 3))  # more rows than one block of centroid sums
    for mode in ("centroid", "grid"):
        small = landmarks_from_mask(mask, TABLE, CLASSES, mode=mode)
        wide = landmarks_from_mask(mask.astype(np.int64), TABLE, CLASSES, mode=mode)
        assert len(small.xy) > 50 and np.array_equal(small.xy, wide.xy) and np.array_equal(small.cls, wide.cls)
    strip = np.full((4, 600), B, np.uint8)
    strip[0] = GRASS  # apart from the town above: rows 597-599 alone
    one = landmarks_from_mask(np.vstack([mask[:596, :600], strip]), TABLE, CLASSES)
    assert any(np.allclose(p, (299.5, 598.0)) for p in one.xy)  # the bottom strip's centre, by hand


def test_a_saved_panorama_is_a_query_the_localize_command_takes(tmp_path: Path) -> None:
    """What a user does next: the bench's saved panorama (sky and all) given to ``osmseg localize``."""
    from localization.cli.localize import localize_command

    mask_file = tmp_path / "town.png"
    Image.fromarray(town(seed=4)).save(mask_file)
    runner = CliRunner()
    res = runner.invoke(localize_bench_command, [str(mask_file), "--aerial-resolution", str(RES), "--out", str(tmp_path / "b"),
                                                 "--viewpoints", "1", "--methods", "profile", "--no-negatives",
                                                 "--no-plots", "--save-panoramas", "1"], obj={"verbosity": -1})
    assert res.exit_code == 0, res.output
    truth = json.loads((tmp_path / "b" / "results.json").read_text())["viewpoints"][0]["truth"]
    pano = tmp_path / "b" / "panoramas" / "0000_town.png"
    with Image.open(pano) as im:
        assert SKY in np.asarray(im)  # a class the aerial table does not have
    tables = ["--aerial-landmarks", "aerial13", "--aerial-table", "classes13.toml",
              "--ground-landmarks", "aerial13", "--ground-table", "classes13.toml"]
    res = runner.invoke(localize_command, ["--ground", str(pano), "--aerial", str(mask_file), "--aerial-resolution", str(RES),
                                           *tables, "--out", str(tmp_path / "loc")], obj={"verbosity": -1})
    assert res.exit_code == 0, res.output
    answer = json.loads((tmp_path / "loc" / "result.json").read_text())["map"]
    assert math.dist((answer["x"], answer["y"]), truth) * RES < 2.0
