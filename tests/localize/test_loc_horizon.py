"""The horizon of a ground view (localization.profile.horizon), read from views the independent
geometry renderer drew (localization.bench.georender: 3-D ray casting, its own camera model) with a
known pitch and roll."""

from __future__ import annotations

import math

import numpy as np
from shapely.geometry import box

from localization.bench.georender import Camera as GeoCamera, Scene, Solid, render, tree_crown
from localization.common.landmarks import load_landmark_classes, panorama_table
from localization.common.views import Camera, semantic_map
from localization.profile.horizon import estimate_tilt, horizon_bounds
from osmseg.classes import load_class_table

TABLE = load_class_table("classes13.toml")
PANO = panorama_table(TABLE)
CLASSES = load_landmark_classes("aerial13")
SKY, FAR = PANO.by_name["sky"].id, TABLE.unlabeled.id
BUILDING, TREE, ROAD = TABLE.by_name["building"].id, TABLE.by_name["tree"].id, TABLE.by_name["highway"].id


def square() -> Scene:
    """An open square 60 m across with a few buildings and trees round it: the far ground shows
    in most directions."""
    solids = (Solid(box(35, -10, 50, 10), 0.0, 12.0, BUILDING), Solid(box(-20, 40, 5, 55), 0.0, 9.0, BUILDING),
              Solid(box(-60, -30, -45, -5), 0.0, 15.0, BUILDING), tree_crown(15, -25, 8.0, TREE),
              tree_crown(-10, 20, 6.0, TREE))
    return Scene(solids=solids, ground_class=ROAD, seed=3)


def street() -> Scene:
    """A street running north-south between two rows of 10 m buildings 8 m from its middle: the
    far ground shows only to the north and south."""
    solids = tuple(Solid(box(side * 8, y, side * 30, y + 18), 0.0, 10.0, BUILDING)
                   for side in (-1, 1) for y in range(-200, 200, 20))
    return Scene(solids=solids, ground_class=ROAD)


def view(scene: Scene, **camera: float) -> np.ndarray:
    settings = dict(x=0.0, y=0.0, eye_m=1.8, width=1232, height=224, max_range_m=300.0)
    settings.update(camera)
    return render(scene, GeoCamera(**settings), SKY, FAR)  # type: ignore[arg-type]


def test_a_tilted_panorama_of_an_open_square_gives_its_pitch_and_roll_to_a_tenth_of_a_degree() -> None:
    for heading, pitch, roll in ((0.0, 1.4, -0.9), (125.0, -1.8, 0.6), (250.0, 0.3, 1.9)):
        sem = semantic_map(view(square(), heading_deg=heading, pitch_deg=pitch, roll_deg=roll), PANO, CLASSES)
        tilt = estimate_tilt(sem, Camera(1232, 224), max_deg=3.0)
        assert abs(tilt.pitch_deg - pitch) <= 0.1 and abs(tilt.roll_deg - roll) <= 0.1, (heading, tilt)
        assert tilt.open_columns > 600  # most directions see the far ground meet the sky


def test_a_street_pins_the_tilt_along_it_and_takes_the_least_across_it() -> None:
    """Only north and south show the horizon: the tilt along the street is read; across it the
    view says little, and the smallest tilt its bounds allow is taken."""
    heading, pitch, roll = 30.0, 1.2, 0.7
    sem = semantic_map(view(street(), heading_deg=heading, pitch_deg=pitch, roll_deg=roll), PANO, CLASSES)
    tilt = estimate_tilt(sem, Camera(1232, 224), max_deg=3.0)

    def drop(p: float, r: float, azimuth: float) -> float:
        """How far the horizon lies below the camera's looking along ``azimuth``, degrees."""
        t = math.radians(azimuth - heading)
        return p * math.cos(t) - r * math.sin(t)

    assert abs(drop(tilt.pitch_deg, tilt.roll_deg, 0.0) - drop(pitch, roll, 0.0)) <= 0.1       # along the street
    assert abs(drop(tilt.pitch_deg, tilt.roll_deg, 90.0)) <= abs(drop(pitch, roll, 90.0)) + 0.1  # across it
    assert 0 < tilt.open_columns < 300


def test_a_photo_of_ninety_degrees_gives_its_tilt_too() -> None:
    sem = semantic_map(view(square(), heading_deg=200.0, pitch_deg=-1.1, roll_deg=0.8, hfov_deg=90.0, width=308),
                       PANO, CLASSES)
    tilt = estimate_tilt(sem, Camera(308, 224, hfov_deg=90.0), max_deg=2.0)
    assert abs(tilt.pitch_deg + 1.1) <= 0.15 and abs(tilt.roll_deg - 0.8) <= 0.15


def test_without_a_sky_class_every_ground_pixel_stays_under_the_horizon_read() -> None:
    """A mask whose table has no sky (sky drawn as unlabeled) bounds the horizon from below only."""
    pixels = view(square(), heading_deg=40.0, pitch_deg=1.0, roll_deg=-1.0)
    sem = semantic_map(np.where(pixels == SKY, FAR, pixels), TABLE, CLASSES)
    assert sem.sky is None
    tilt = estimate_tilt(sem, Camera(1232, 224), max_deg=3.0)
    assert tilt.excess_rows == 0
    _, below = horizon_bounds(sem)
    line = Camera(1232, 224, pitch_deg=tilt.pitch_deg, roll_deg=tilt.roll_deg)
    assert (below > line.horizon + line.tilt_rows(np.arange(1232))).all()
    assert math.hypot(tilt.pitch_deg - 1.0, tilt.roll_deg + 1.0) < math.hypot(1.0, 1.0)  # nearer than level


def test_a_view_that_never_shows_the_horizon_is_read_as_level() -> None:
    """Inside a closed courtyard every column's sky and ground are a building apart: nothing
    pins the horizon, and no tilt is made up."""
    ring = box(-20, -20, 20, 20).difference(box(-12, -12, 12, 12))
    scene = Scene(solids=(Solid(ring, 0.0, 12.0, BUILDING),), ground_class=ROAD)
    sem = semantic_map(view(scene, pitch_deg=1.5, roll_deg=1.0), PANO, CLASSES)
    tilt = estimate_tilt(sem, Camera(1232, 224), max_deg=3.0)
    assert tilt.open_columns == 0 and (tilt.pitch_deg, tilt.roll_deg) == (0.0, 0.0)
