"""The geometry renderer (``localization/georender.py``) against angles computed by hand.

Each scene is built so that the answer is one ``atan``: where a wall's top edge lies, where a
taller building behind a lower one shows, where a camera's tilt moves a roof line. The last
test renders one scene with both renderers (the mask one and this one), which were written
separately and agree where their models coincide.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from shapely.geometry import box

from localization.georender import Camera, GroundPatch, Scene, Solid, pixel_directions, render, tree_crown
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
    from localization.render import RenderConfig, panorama_table, render_panorama
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
