"""The geometry renderer (``localization/bench/georender.py``) against angles computed by hand.

Each scene is built so that the answer is one ``atan``: where a wall's top edge lies, where a
taller building behind a lower one shows, where a camera's tilt moves a roof line. The last
test renders one scene with both renderers (the mask one and this one), which were written
separately and agree where their models coincide.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from conftest import table_rows
from PIL import Image
from shapely.geometry import box

from localization.bench.georender import Camera, GroundPatch, Scene, Solid, pixel_directions, render, tree_crown
from osmseg.errors import ConfigError

SKY, FAR, GROUND, ROAD, BUILDING, WALL, TREE = 14, 0, 5, 6, 1, 2, 4
STEP = 0.1  # degrees a pixel: 3600 columns around


def camera(**kw: float) -> Camera:
    settings = dict(x=0.0, y=0.0, eye_m=2.0, width=3600, height=900, max_range_m=150.0)
    settings.update(kw)
    return Camera(**settings)  # type: ignore[arg-type]


def row_of(elevation_deg: float, cam: Camera) -> float:
    """The (fractional) row looking at ``elevation_deg`` when the camera is level."""
    return cam.height / 2 - 0.5 - elevation_deg / cam.step_deg


def column_of(azimuth_deg: float, cam: Camera) -> int:
    return int(round(((azimuth_deg - cam.heading_deg + 180) % 360 - 180) / cam.step_deg + cam.width / 2 - 0.5))


def classes_up_a_column(view: np.ndarray, col: int) -> list[tuple[int, int, int]]:
    """(class, first row, last row) runs from the top of ``col`` down."""
    runs: list[tuple[int, int, int]] = []
    for r, c in enumerate(view[:, col].tolist()):
        if runs and runs[-1][0] == c:
            runs[-1] = (c, runs[-1][1], r)
        else:
            runs.append((c, r, r))
    return runs


def test_a_building_fills_the_rows_from_its_foot_to_its_top_edge() -> None:
    cam = camera()
    scene = Scene(solids=(Solid(box(-10, 20, 10, 30), 0.0, 10.0, BUILDING),), ground_class=GROUND)
    view = render(scene, cam, SKY, FAR)
    col = column_of(0.0, cam)
    top, foot = math.degrees(math.atan(8 / 20)), -math.degrees(math.atan(2 / 20))  # 21.80° and -5.71°
    runs = classes_up_a_column(view, col)
    assert [c for c, _, _ in runs] == [SKY, BUILDING, GROUND]
    (_, first, last) = runs[1]
    assert abs(first - row_of(top, cam)) <= 1 and abs(last - row_of(foot, cam)) <= 1
    # the building's corners: 26.6° either side of north at the near face
    half = math.degrees(math.atan(10 / 20))
    assert view[int(row_of(0, cam)), column_of(half - 0.3, cam)] == BUILDING
    assert view[int(row_of(0, cam)), column_of(half + 0.3, cam)] == SKY
    assert (view[: int(row_of(0, cam)), column_of(180.0, cam)] == SKY).all()  # nothing south


def test_a_near_low_wall_hides_a_far_tall_building_only_below_the_walls_top() -> None:
    cam = camera()
    wall = Solid(box(-40, 10, 40, 10.5), 0.0, 3.0, WALL)
    tower = Solid(box(-5, 30, 5, 40), 0.0, 20.0, BUILDING)
    view = render(Scene(solids=(wall, tower), ground_class=GROUND), cam, SKY, FAR)
    runs = classes_up_a_column(view, column_of(0.0, cam))
    assert [c for c, _, _ in runs] == [SKY, BUILDING, WALL, GROUND]
    tower_top = math.degrees(math.atan(18 / 30))         # 30.96°
    wall_top = math.degrees(math.atan(1 / 10))           # above the eye: its near top edge, 5.71°
    assert abs(runs[1][1] - row_of(tower_top, cam)) <= 1
    assert abs(runs[2][1] - row_of(wall_top, cam)) <= 1
    # beside the tower the wall has only sky above it
    beside = classes_up_a_column(view, column_of(30.0, cam))
    assert [c for c, _, _ in beside] == [SKY, WALL, GROUND]


def test_a_wall_lower_than_the_eye_shows_its_top_and_the_ground_beyond_it() -> None:
    cam = camera()
    wall = Solid(box(-40, 10, 40, 11), 0.0, 1.0, WALL)
    road = GroundPatch(box(-40, 25, 40, 35), ROAD)  # the wall hides the ground from 11 to 22 m
    view = render(Scene(solids=(wall,), ground=(road,), ground_class=GROUND), cam, SKY, FAR)
    runs = classes_up_a_column(view, column_of(0.0, cam))
    # sky, far ground beyond range, grass, the road 25-35 m out, grass, the wall, grass at the feet
    assert [c for c, _, _ in runs] == [SKY, FAR, GROUND, ROAD, GROUND, WALL, GROUND]
    assert abs(runs[5][1] - row_of(-math.degrees(math.atan(1 / 11)), cam)) <= 1  # its far top edge
    assert abs(runs[5][2] - row_of(-math.degrees(math.atan(2 / 10)), cam)) <= 1  # its foot
    assert abs(runs[3][1] - row_of(-math.degrees(math.atan(2 / 35)), cam)) <= 1  # the road's far edge
    assert abs(runs[4][2] - row_of(-math.degrees(math.atan(1 / 11)), cam)) <= 1  # grass seen just over it
    assert abs(runs[1][1] - row_of(0.0, cam)) <= 1  # the horizon


def test_a_crown_lets_a_share_of_the_rays_through_drawn_from_the_seed() -> None:
    cam = camera(width=1800, height=450)
    wall = Solid(box(-100, 40, 100, 41), 0.0, 30.0, BUILDING)
    shares = []
    for opacity in (1.0, 0.5):
        crown = Solid(box(-20, 10, 20, 14), 0.0, 30.0, TREE, opacity)
        views = [render(Scene(solids=(wall, crown), seed=s), cam, SKY, FAR) for s in (0, 0, 1)]
        assert (views[0] == views[1]).all()          # the same seed draws the same leaves
        behind = np.zeros_like(views[0], bool)
        behind[int(row_of(20, cam)):int(row_of(5, cam)), column_of(-30, cam):column_of(30, cam)] = True
        shares.append(float((views[0][behind] == TREE).mean()))
        if opacity < 1:
            assert (views[0] != views[2]).any()      # another seed, other leaves
        assert set(np.unique(views[0][behind]).tolist()) <= {TREE, BUILDING}
    assert shares[0] == 1.0 and 0.45 < shares[1] < 0.55


def test_pitching_up_moves_the_scene_down_and_roll_tilts_the_horizon() -> None:
    scene = Scene(solids=(Solid(box(-10, 20, 10, 30), 0.0, 10.0, BUILDING),), ground_class=GROUND)
    level = camera()
    up = camera(pitch_deg=2.0)
    col = column_of(0.0, level)
    top_level = classes_up_a_column(render(scene, level, SKY, FAR), col)[1][1]
    top_up = classes_up_a_column(render(scene, up, SKY, FAR), col)[1][1]
    assert abs((top_up - top_level) - 2.0 / STEP) <= 1.5
    # right side down by 2°: a pixel on the camera's horizon looking east (the right) looks 2°
    # lower in the world, one looking west 2° higher; north and south are unchanged
    _, elevation = pixel_directions(camera(roll_deg=2.0, width=360, height=90))
    row = 44  # 0.5° above the camera's horizon; column c looks along c - 179.5°
    assert elevation[row, 269] == pytest.approx(0.5 - 2.0, abs=0.05)   # 89.5°
    assert elevation[row, 89] == pytest.approx(0.5 + 2.0, abs=0.05)    # 269.5°
    assert elevation[row, 179] == pytest.approx(0.5, abs=0.05)         # 359.5°


def test_both_renderers_agree_where_their_models_coincide() -> None:
    """A building of one height on flat ground, at 1 m a pixel: the mask renderer and this one."""
    from localization.bench.render import RenderConfig, panorama_table, render_panorama
    from osmseg.classes import load_class_table

    table = load_class_table("classes13.toml")
    pano = panorama_table(table)
    b, road, sky = table.by_name["building"].id, table.by_name["highway"].id, pano.by_name["sky"].id
    mask = np.full((201, 201), road, np.uint8)
    mask[40:60, 90:111] = b  # rows 40-59 (41-60 m north of the camera's row 100), columns 90-110
    config = RenderConfig(width=720, height=180, camera_height_m=2.0, max_range_m=100.0, heights={"building": 10.0})
    by_mask = render_panorama(mask, table, 1.0, (100, 100), config).labels
    # the same building in metres: pixel (col, row) covers x col-100 ± 0.5, y 100-row ± 0.5
    solid = Solid(box(90 - 100 - 0.5, 100 - 59 - 0.5, 110 - 100 + 0.5, 100 - 40 + 0.5), 0.0, 10.0, b)
    by_geometry = render(Scene(solids=(solid,), ground_class=road),
                         Camera(0.0, 0.0, eye_m=2.0, width=720, height=180, max_range_m=100.0), sky, FAR)
    assert (by_geometry == b).sum() == pytest.approx((by_mask == b).sum(), rel=0.05)
    assert (by_geometry == by_mask).mean() > 0.98


def test_bad_cameras_and_solids_are_refused() -> None:
    with pytest.raises(ConfigError, match="above the ground"):
        Camera(0, 0, eye_m=0)
    with pytest.raises(ConfigError, match="more than 180"):
        Camera(0, 0, width=224, height=1232)
    with pytest.raises(ConfigError, match="base < top"):
        Solid(box(0, 0, 1, 1), 5.0, 5.0, BUILDING)
    assert tree_crown(0, 0, 3.0, TREE).polygon.area == pytest.approx(math.pi * 1.5 ** 2, rel=0.02)


# ------------------------------------------------------------------ a scene from OSM tags
LON0, LAT0 = 26.95, 60.53  # Kotka


def lonlat(dx: float, dy: float) -> tuple[float, float]:
    """A point ``dx`` m east and ``dy`` m north of (LON0, LAT0)."""
    return LON0 + dx / (111_319.49 * math.cos(math.radians(LAT0))), LAT0 + dy / 111_319.49


def write_osm(path, objects) -> None:
    lines = ["<?xml version='1.0' encoding='UTF-8'?>", "<osm version='0.6' generator='test'>"]
    ways = []
    node_id = 1
    for kind, points, tags in objects:
        ids = []
        for dx, dy in points:
            lon, lat = lonlat(dx, dy)
            node_tags = "".join(f"<tag k='{k}' v='{v}'/>" for k, v in tags.items()) if kind == "node" else ""
            lines.append(f"<node id='{node_id}' version='1' lat='{lat:.8f}' lon='{lon:.8f}'>{node_tags}</node>")
            ids.append(node_id)
            node_id += 1
        if kind == "way":
            ways.append((ids + [ids[0]] if tags.get("highway") is None else ids, tags))
    for way_id, (ids, tags) in enumerate(ways, start=1):
        nds = "".join(f"<nd ref='{i}'/>" for i in ids)
        tag_xml = "".join(f"<tag k='{k}' v='{v}'/>" for k, v in tags.items())
        lines.append(f"<way id='{way_id}' version='1'>{nds}{tag_xml}</way>")
    lines.append("</osm>")
    path.write_text("\n".join(lines), encoding="utf-8")


def square(cx: float, cy: float, half: float) -> list[tuple[float, float]]:
    return [(cx - half, cy - half), (cx + half, cy - half), (cx + half, cy + half), (cx - half, cy + half)]


def test_a_scene_from_osm_takes_heights_from_the_tags_and_draws_the_rest_from_the_seed(tmp_path) -> None:
    from localization.bench.georender_osm import scene_from_osm
    from localization.bench.render import panorama_table
    from osmseg.classes import load_class_table

    table = load_class_table("classes13.toml")
    path = tmp_path / "scene.osm"
    write_osm(path, [
        ("way", square(0, 40, 10), {"building": "yes", "height": "20"}),          # north, 30-50 m
        ("way", square(40, 0, 5), {"building": "house", "building:levels": "2"}),  # east: 7 m
        ("way", square(-40, 0, 5), {"building": "yes"}),                          # west: no height
        ("node", [(0, -30)], {"natural": "tree", "height": "12"}),                # south
        ("way", [(-60, -10), (60, -10)], {"highway": "residential"}),
        ("way", square(0, -80, 15), {"natural": "wood"}),
    ])
    scenes = [scene_from_osm([path], LON0, LAT0, table, radius_m=120, seed=s) for s in (0, 0, 1)]
    solids = scenes[0].scene.solids
    b, tree = table.by_name["building"].id, table.by_name["tree"].id
    buildings = sorted((s for s in solids if s.class_id == b), key=lambda s: s.polygon.centroid.x)
    assert [round(s.top_m, 1) for s in buildings[1:]] == [20.0, 7.0]           # north (x 0), east (x 40)
    assert 4.0 <= buildings[0].top_m <= 16.0                                    # west: drawn
    north = buildings[1].polygon
    assert north.centroid.y == pytest.approx(40, abs=0.5) and north.area == pytest.approx(400, rel=0.02)
    crowns = [s for s in solids if s.class_id == tree]
    single = min(crowns, key=lambda s: abs(s.polygon.centroid.y + 30))
    assert single.top_m == 12.0 and single.base_m == pytest.approx(4.0) and single.opacity < 1
    assert sum(1 for s in crowns if s.polygon.centroid.y < -60) >= 4               # the wood stands
    assert scenes[0].scene == scenes[1].scene and scenes[0].scene != scenes[2].scene
    assert {g.class_id for g in scenes[0].scene.ground} >= {table.by_name["highway"].id}
    # the view from the centre: the 20 m building's top edge at atan((20 - 1.7) / 30) = 31.4°
    cam = camera(eye_m=1.7)
    view = render(scenes[0].scene, cam, panorama_table(table).by_name["sky"].id, table.unlabeled.id)
    runs = classes_up_a_column(view, column_of(0.0, cam))
    first_building = next(r for r in runs if r[0] == b)
    assert abs(first_building[1] - row_of(math.degrees(math.atan(18.3 / 30)), cam)) <= 2
    south = classes_up_a_column(view, column_of(180.0, cam))
    assert tree in [c for c, _, _ in south]


# ------------------------------------------------------------------ localize-bench --renderer geometry
def osm_mask(osm_path, out, lon: float, lat: float, zoom: int = 19, size: int = 3):
    """The builder's label mask of ``osm_path`` around (lon, lat), as a GeoTIFF in EPSG:3857."""
    import rasterio
    from rasterio.transform import from_bounds

    from osmseg.classes import load_class_table
    from osmseg.grid import sample_grid
    from osmseg.osm.features import read_features
    from osmseg.rasterize import rasterize

    table = load_class_table("classes13.toml")
    grid = sample_grid(lon, lat, zoom, size)
    mask = rasterize(read_features([osm_path], grid, table), grid, table)
    b = grid.xy_bounds
    with rasterio.open(out, "w", driver="GTiff", width=mask.shape[1], height=mask.shape[0], count=1, dtype="uint8",
                       crs="EPSG:3857", transform=from_bounds(b.left, b.bottom, b.right, b.top, *mask.shape[::-1])) as d:
        d.write(mask, 1)
    return out, grid.ground_resolution


def building_top_rows(png) -> int:
    """The highest row of building colour (yellow) in a saved panorama."""
    from PIL import Image

    rgb = np.asarray(Image.open(png).convert("RGB"))
    from osmseg.classes import load_class_table

    colour = np.array(load_class_table("classes13.toml").by_name["building"].color, np.uint8)
    rows = np.nonzero((rgb == colour).all(axis=2).any(axis=1))[0]
    return int(rows.min())


def test_localize_bench_draws_its_views_from_the_osm_geometry_with_the_heights_of_the_tags(tmp_path) -> None:
    import json

    from click.testing import CliRunner

    from osmseg.cli.main import cli

    # a 30 m tower in a square of streets: the mask renderer draws every building 10 m high
    write_osm(tmp_path / "town.osm", [
        ("way", square(0, 0, 12), {"building": "yes", "height": "30"}),
        ("way", square(0, 0, 60), {"landuse": "grass"}),
        *[("way", [(-70, y), (70, y)], {"highway": "residential"}) for y in (-30, 30)],
        *[("way", [(x, -70), (x, 70)], {"highway": "residential"}) for x in (-30, 30)],
    ])
    mask, resolution = osm_mask(tmp_path / "town.osm", tmp_path / "town.tif", LON0, LAT0)
    common = [str(mask), "--aerial-resolution", f"{resolution:.4f}", "--viewpoints", 2, "--methods", "profile",
              "--no-negatives", "--no-plots", "--save-panoramas", 1, "--stand-on", "highway", "--margin", 30,
              "--pano-width", 720, "--pano-height", 160]
    runner = CliRunner()
    tops = {}
    for renderer, extra in (("mask", []), ("geometry", ["--osm", tmp_path / "town.osm"])):
        out = tmp_path / renderer
        result = runner.invoke(cli, ["-q", "localize-bench", *map(str, common), "--out", str(out),
                                     "--renderer", renderer, *map(str, extra)])
        assert result.exit_code == 0, result.output
        results = json.loads((out / "results.json").read_text())
        assert results["settings"]["renderer"] == renderer
        assert results["settings"]["osm"] == (["town.osm"] if extra else [])
        tops[renderer] = building_top_rows(next((out / "panoramas").glob("0000_*.png")))
        assert results["methods"]["profile"]["answered"] == 2
        # where each camera stood, in degrees (what a region search takes as --truth), as rasterio reads the mask
        import rasterio
        from rasterio.warp import transform

        with rasterio.open(mask) as ds:
            for v in results["viewpoints"]:
                x, y = ds.xy(v["camera"][1], v["camera"][0])   # row, col of the pixel's centre
                lon, lat = transform(ds.crs, "EPSG:4326", [x], [y])
                assert v["camera_lonlat"] == pytest.approx([lon[0], lat[0]], abs=2e-7)
    assert tops["geometry"] < tops["mask"] - 5  # the tower's own 30 m, not the class's 10 m
    bad = runner.invoke(cli, ["localize-bench", *map(str, common), "--out", str(tmp_path / "bad"),
                              "--renderer", "geometry"])
    assert bad.exit_code == 2 and "--osm" in bad.output
    assert not (tmp_path / "bad" / "results.json").exists()


def test_geometry_views_of_real_osm_are_localized_by_the_profile_method(tmp_path) -> None:
    """Kotka (real OSM, ../shared/data): views from the geometry renderer, whose heights and
    crowns the method does not model, are still found within metres."""
    import json

    from click.testing import CliRunner
    from conftest import shared_path

    from osmseg.cli.main import cli

    pbf = shared_path("helsinki-osm", "kotka.osm.pbf")
    mask, resolution = osm_mask(pbf, tmp_path / "kotka.tif", 26.9475, 60.5337, zoom=18, size=3)
    result = CliRunner().invoke(cli, ["-q", "localize-bench", str(mask), "--aerial-resolution", f"{resolution:.4f}",
                                      "--viewpoints", 4, "--methods", "profile", "--no-negatives", "--no-plots",
                                      "--renderer", "geometry", "--osm", str(pbf), "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    profile = json.loads((tmp_path / "out" / "results.json").read_text())["methods"]["profile"]
    assert profile["answered"] == 4 and profile["recall_at"]["10"] >= 0.75


# ------------------------------------------------------------------ region search: osmseg localize-region --osm --bbox
def town(tmp_path):
    """An OSM town: a grid of streets lined by buildings of drawn lengths, depths, gaps and
    heights (seeded), so that no two stretches of street look alike."""
    xs, ys = (-150, -100, 10, 120, 150), (-150, -80, 0, 90, 150)
    objects = [("way", [(-150, y), (150, y)], {"highway": "residential"}) for y in ys[1:-1]]
    objects += [("way", [(x, -150), (x, 150)], {"highway": "residential"}) for x in xs[1:-1]]
    rng = np.random.default_rng(7)

    def row(a: float, b: float, side: float, along_x: bool, inward: float) -> None:
        t = a + float(rng.uniform(0, 10))
        while t < b - 8:
            length, depth = float(rng.uniform(8, 25)), float(rng.uniform(8, 14))
            length = min(length, b - t)
            near, far = side + inward * 5, side + inward * (5 + depth)
            lo, hi = min(near, far), max(near, far)
            corners = ([(t, lo), (t + length, lo), (t + length, hi), (t, hi)] if along_x
                       else [(lo, t), (hi, t), (hi, t + length), (lo, t + length)])
            objects.append(("way", corners, {"building": "yes", "height": f"{rng.uniform(4, 22):.1f}"}))
            t += length + float(rng.uniform(3, 20))

    for x0, x1 in zip(xs, xs[1:]):
        for y0, y1 in zip(ys, ys[1:]):
            row(x0 + 6, x1 - 6, y0, True, +1)
            row(x0 + 6, x1 - 6, y1, True, -1)
            row(y0 + 25, y1 - 25, x0, False, +1)
            row(y0 + 25, y1 - 25, x1, False, -1)
    # one place unlike the others: a park with a footpath and a row of trees east of the truth
    objects = [o for o in objects if not (o[2].get("building") and 15 < o[1][0][0] < 100 and -75 < o[1][0][1] < -5)]
    objects.append(("way", [(16, -74), (104, -74), (104, -6), (16, -6)], {"leisure": "park"}))
    objects.append(("way", [(16, -40), (104, -40)], {"highway": "footway"}))
    objects += [("node", [(25 + 9 * i, -30)], {"natural": "tree", "height": "9"}) for i in range(8)]
    write_osm(tmp_path / "town.osm", objects)
    return tmp_path / "town.osm"


def test_localize_finds_a_view_in_a_region_of_osm_alone_and_writes_geojson(tmp_path) -> None:
    import json

    import shapely
    from click.testing import CliRunner
    from PIL import Image
    from shapely.geometry import shape

    from localization.bench.georender_osm import scene_from_osm
    from localization.bench.render import panorama_table
    from osmseg.classes import load_class_table
    from osmseg.cli.main import cli

    osm = town(tmp_path)
    table = load_class_table("classes13.toml")
    scene = scene_from_osm([osm], LON0, LAT0, table, radius_m=200, seed=0)
    at = (10.0, -25.0)  # on the north-south street x = 10, between two blocks
    view = render(scene.scene, Camera(*at, eye_m=1.7, width=1232, height=224),
                  panorama_table(table).by_name["sky"].id, table.unlabeled.id)
    Image.fromarray(view.astype(np.uint8)).save(tmp_path / "query.png")  # id 14: the sky of the ground table
    truth = lonlat(*at)
    w, s = lonlat(-140, -140)
    e, n = lonlat(140, 140)
    args = ["localize-region", "--ground", str(tmp_path / "query.png"), "--ground-landmarks", "aerial13", "--ground-table",
            "classes13.toml", "--osm", str(osm), "--bbox", f"{w},{s},{e},{n}", "--truth", f"{truth[0]},{truth[1]}",
            "--out", str(tmp_path / "out"), "--cache-dir", str(tmp_path / "cache")]
    runs = [CliRunner().invoke(cli, args) for _ in range(2)]
    assert runs[0].exit_code == 0, runs[0].output
    assert runs[0].stdout == runs[1].stdout  # the same answers every time...
    answers = table_rows(runs[0].stdout.splitlines())  # one label over each column
    assert list(answers[0]) == ["rank", "lon", "lat", "score", "kappa", "confidence"] and answers[0]["rank"] == "1"
    assert " 0 read from the cache" in runs[0].stderr and "(0 drawn from OSM" in runs[1].stderr  # ...drawn once
    doc = json.loads((tmp_path / "out" / "region.geojson").read_text())
    with Image.open(tmp_path / "out" / "region.png") as picture:  # the map: the region, the answers, a legend
        assert picture.format == "PNG" and min(picture.size) > 200
    points = [shape(f["geometry"]) for f in doc["features"]]  # GeoJSON a GIS reads: shapely parses it
    best = doc["features"][0]
    assert best["properties"]["role"] == "answer" and doc["properties"]["truth"]["error_m"] < 5.0
    alternative = [f for f in doc["features"] if f["properties"]["role"] == "best distinct alternative"]
    assert alternative and alternative[0]["properties"]["distance_m"] >= 50.0
    assert doc["properties"]["margin"] >= 0 and all(shapely.box(w, s, e, n).buffer(1e-3).contains(p) for p in points)
    # a region search has no aerial image: its options name the command that takes them, in one line
    for option, value in (("--aerial-resolution", "0.3"), ("--aerial", str(tmp_path / "query.png"))):
        bad = CliRunner().invoke(cli, [*args, option, value])
        assert bad.exit_code == 2 and f"{option} is for an aerial image" in bad.output, bad.output
        assert "run osmseg localize --aerial FILE --ground FILE" in bad.output
    # the former spelling, osmseg localize --osm, names the command to use in one line
    old = CliRunner().invoke(cli, ["localize", *args[1:]])
    assert old.exit_code == 2 and "osmseg localize-region --ground FILE --osm FILE --bbox" in old.output, old.output
    no_box = CliRunner().invoke(cli, ["localize-region", "--ground", str(tmp_path / "query.png"), "--osm", str(osm)])
    assert no_box.exit_code == 2 and "--bbox" in no_box.output
    # the region as a centre and a radius: the square around the disc, the same answers
    centre = lonlat(0.0, 0.0)
    disc = [a for a in args if a not in ("--bbox", f"{w},{s},{e},{n}")]
    disc[disc.index("--out") + 1] = str(tmp_path / "disc")
    by_disc = CliRunner().invoke(cli, [*disc, "--lon", str(centre[0]), "--lat", str(centre[1]), "--radius-km", "0.14"])
    assert by_disc.exit_code == 0, by_disc.output
    assert by_disc.stdout.splitlines()[1].split()[1:3] == runs[0].stdout.splitlines()[1].split()[1:3]
    both = CliRunner().invoke(cli, [*args, "--lat", str(centre[1]), "--lon", str(centre[0]), "--radius-km", "1"])
    assert both.exit_code == 2 and "give the region once" in both.output
    half = CliRunner().invoke(cli, [*disc, "--lat", str(centre[1]), "--radius-km", "1"])
    assert half.exit_code == 2 and "go together" in half.output and "add --lon" in half.output


def test_a_region_split_into_shards_answers_as_one_process(tmp_path) -> None:
    """--shard K/N: each shard writes its part, the last one merges; any number of shards gives
    the bytes of one process's region.geojson, and a finished shard run again does not search."""
    from click.testing import CliRunner

    from localization.bench.georender_osm import scene_from_osm
    from localization.bench.render import panorama_table
    from osmseg.classes import load_class_table
    from osmseg.cli.main import cli

    osm = town(tmp_path)
    table = load_class_table("classes13.toml")
    scene = scene_from_osm([osm], LON0, LAT0, table, radius_m=200, seed=0)
    view = render(scene.scene, Camera(10.0, -25.0, eye_m=1.7, width=1232, height=224, heading_deg=40.0),
                  panorama_table(table).by_name["sky"].id, table.unlabeled.id)
    Image.fromarray(view.astype(np.uint8)).save(tmp_path / "query.png")  # id 14: the sky of the ground table
    w, s = lonlat(-140, -140)
    e, n = lonlat(140, 140)

    def run(out: str, *extra: str):
        return CliRunner().invoke(cli, ["localize-region", "--ground", str(tmp_path / "query.png"), "--ground-landmarks",
                                        "aerial13", "--ground-table", "classes13.toml", "--osm", str(osm), "--bbox",
                                        f"{w},{s},{e},{n}", "--heading", "unknown", "--out", str(tmp_path / out),
                                        "--cache-dir", str(tmp_path / "cache"), *extra])

    one = run("one")
    assert one.exit_code == 0, one.output
    expected = (tmp_path / "one" / "region.geojson").read_bytes()
    assert json.loads(expected)["properties"]["blocks"] >= 2
    for count in (2, 3):
        for k in range(1, count + 1):
            res = run(f"split{count}", "--shard", f"{k}/{count}")
            assert res.exit_code == 0, res.output
            done = (tmp_path / f"split{count}" / "region.geojson").is_file()
            assert done == (k == count), res.output             # only the last shard writes the answers
            if k < count:
                assert f"{k} of {count} parts" in res.stderr
        assert (tmp_path / f"split{count}" / "region.geojson").read_bytes() == expected
        for page in ("region.html", "region.png"):  # the map and the picture too
            assert (tmp_path / f"split{count}" / page).read_bytes() == (tmp_path / "one" / page).read_bytes(), page
    parts = sorted((tmp_path / "split2" / "region-parts").glob("*/1-of-2.json"))
    stamp = parts[0].stat().st_mtime_ns
    again = run("split2", "--shard", "1/2")
    assert again.exit_code == 0 and parts[0].stat().st_mtime_ns == stamp  # its part was kept, not searched again
    assert (tmp_path / "split2" / "region.geojson").read_bytes() == expected
    no_out = CliRunner().invoke(cli, ["localize-region", "--ground", str(tmp_path / "query.png"), "--osm", str(osm),
                                      "--bbox", f"{w},{s},{e},{n}", "--shard", "1/2"])
    assert no_out.exit_code == 2 and "--shard 1/2 needs --out" in no_out.output


def test_a_tilted_camera_of_unknown_height_is_found_with_its_pose(tmp_path) -> None:
    """A view of the OSM town drawn by a camera 2.25 m up, pitched up 1.7° and rolled 0.8° (right
    side down): told the height and tilt are unknown, the profile method reads the tilt from where
    the view's sky meets its ground, tries 1.5 to 2.5 m, and answers with the pose the camera had,
    at the place it stood. Told the camera is level and 2 m up, it reads distances wrongly."""
    import mercantile
    import rasterio

    from localization.bench.georender_osm import scene_from_osm
    from localization.bench.render import panorama_table
    from localization.common.landmarks import load_landmark_classes
    from localization.common.result import Localization
    from localization.common.views import Camera as QueryCamera, semantic_map
    from localization.profile.method import profile_index, run_profile
    from localization.profile.search import UNKNOWN_HEIGHTS, ProfileConfig
    from osmseg.classes import load_class_table

    osm = town(tmp_path)
    table, classes = load_class_table("classes13.toml"), load_landmark_classes("aerial13")
    tif, res = osm_mask(osm, tmp_path / "town.tif", LON0, LAT0, zoom=19, size=5)
    with rasterio.open(tif) as ds:
        mask, b = ds.read(1), ds.bounds
    index = profile_index(semantic_map(mask, table, classes), res)
    scene = scene_from_osm([osm], LON0, LAT0, table, radius_m=250, seed=0)
    lon, lat = lonlat(10.0, -25.0)                              # on the street x = 10, between two blocks
    mx, my = mercantile.xy(lon, lat)
    truth_px = ((mx - b.left) / (b.right - b.left) * mask.shape[1] - 0.5,
                (b.top - my) / (b.top - b.bottom) * mask.shape[0] - 0.5)
    x, y = scene.to_local(lon, lat)
    sky = panorama_table(table).by_name["sky"].id
    view = render(scene.scene, Camera(x, y, eye_m=2.25, heading_deg=0.0, pitch_deg=1.7, roll_deg=0.8), sky,
                  table.unlabeled.id)
    query = semantic_map(view, panorama_table(table), classes)
    assert query.sky is not None and query.sky.any()
    config = ProfileConfig(camera_heights=UNKNOWN_HEIGHTS, tilt_deg=2.0, min_confidence=-1.0, min_kappa=-1.0)
    loc = run_profile(config, index, query, QueryCamera(1232, 224))
    assert math.hypot(loc.map_xy[0] - truth_px[0], loc.map_xy[1] - truth_px[1]) * res <= 2.0
    assert loc.camera_pose is not None
    height, pitch, roll = loc.camera_pose
    assert height == 2.25 and abs(pitch - 1.7) <= 0.2 and abs(roll - 0.8) <= 0.2
    level = run_profile(ProfileConfig(min_confidence=-1.0, min_kappa=-1.0), index, query, QueryCamera(1232, 224))
    def error_m(result: Localization) -> float:
        return math.hypot(result.map_xy[0] - truth_px[0], result.map_xy[1] - truth_px[1]) * res

    # read as a level camera 2 m up, the view fits its own place worse (0.79 against 0.88) and lands farther off
    assert float(loc.likelihoods[loc.order[0]]) > float(level.likelihoods[level.order[0]]) + 0.05
    assert error_m(level) > error_m(loc)
    # the same through the command line, on the GeoTIFF: the answer also in degrees
    from click.testing import CliRunner

    from localization.region.search import distance_m
    from osmseg.cli.main import cli

    Image.fromarray(view.astype(np.uint8)).save(tmp_path / "query.png")  # id 14: the sky of the ground table
    res = CliRunner().invoke(cli, ["localize", "--aerial", str(tif), "--aerial-table", "classes13.toml", "--ground",
                                   str(tmp_path / "query.png"), "--ground-landmarks", "aerial13", "--ground-table",
                                   "classes13.toml", "--camera-height", "unknown", "--tilt", "2",
                                   "--min-confidence", "-1", "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert distance_m((out["map_lonlat"]["lon"], out["map_lonlat"]["lat"]), (lon, lat)) <= 2.0
    assert out["camera_pose"][0] == 2.25 and abs(out["camera_pose"][1] - 1.7) <= 0.2
    bad = CliRunner().invoke(cli, ["localize", "--aerial", str(tif), "--ground", str(tmp_path / "query.png"),
                                   "--camera-height", "tall"])
    assert bad.exit_code == 2 and "'unknown'" in bad.output
