"""Rasterising tinycity: the right class at known pixels, line widths, holes, draw order, clipping.

tinycity (tests/data/tinycity/data.py) places every feature at known pixel positions of its
grid, so each check here reads "the pixel at (col, row) has class X" as a user would.
"""

from __future__ import annotations

import doctest
import importlib.util
import sys
from types import ModuleType

import numpy as np
import pytest
from conftest import TEST_DATA

import osmseg.rasterize
from osmseg.classes import load_class_table
from osmseg.errors import ClassTableError
from osmseg.osm.features import FeatureSet, read_features
from osmseg.rasterize import rasterize, to_table

T13 = load_class_table("classes13.toml")
T6 = load_class_table("classes6.toml")


def load_tinycity() -> ModuleType:
    """tests/data/tinycity/data.py as a module (layout constants, grid(), OsmWriter)."""
    if "tinycity_data" not in sys.modules:
        spec = importlib.util.spec_from_file_location("tinycity_data", TEST_DATA / "tinycity" / "data.py")
        assert spec and spec.loader
        module = importlib.util.module_from_spec(spec)
        sys.modules["tinycity_data"] = module
        spec.loader.exec_module(module)
    return sys.modules["tinycity_data"]


D = load_tinycity()


@pytest.fixture(scope="module")
def features() -> FeatureSet:
    return read_features([D.OSM_FILE], D.grid(), T13)


@pytest.fixture(scope="module")
def labels(features: FeatureSet) -> np.ndarray:
    return rasterize(features, D.grid(), T13)


def at(labels: np.ndarray, pixel: tuple[float, float]) -> str:
    """Class name of the pixel whose corner is (col, row)."""
    col, row = int(pixel[0]), int(pixel[1])
    return T13.by_id[int(labels[row, col])].name


def centre(box: tuple[int, int, int, int]) -> tuple[float, float]:
    return (box[0] + box[2]) / 2, (box[1] + box[3]) / 2


def px(metres: float) -> float:
    """Ground metres in pixels of the tinycity grid."""
    return metres / D.grid().ground_resolution


def test_mask_shape_and_dtype(labels: np.ndarray) -> None:
    g = D.grid()
    assert labels.shape == (g.height, g.width) == (1280, 1280)
    assert labels.dtype == np.uint8


@pytest.mark.parametrize(("name", "pixel", "expected"), [
    ("courtyard building ring", (130, 200), "building"),
    ("courtyard", centre(D.COURTYARD_INNER), "unlabeled"),
    ("building standing in the park", centre(D.PARK_BUILDING), "building"),
    ("park around it", (600, 300), "park"),
    ("residential road", (300, D.ROAD_ROW), "highway"),
    ("primary road", (D.PRIMARY_COL, 800), "highway"),
    ("footway", (D.FOOTWAY_COL, 380), "footway"),
    ("track", (300, D.TRACK_ROW), "dirt road"),
    ("gravel residential road", (300, D.GRAVEL_ROW), "dirt road"),
    ("grass", centre(D.GRASS), "grass"),
    ("wood", centre(D.WOOD), "natural"),
    ("lake", (100, 850), "water"),
    ("island in the lake", centre(D.ISLAND), "unlabeled"),
    ("river", (D.RIVER_COL, 700), "water"),
    ("parking", centre(D.PARKING), "parking"),
    ("construction", centre(D.CONSTRUCTION), "construction"),
    ("industrial", centre(D.INDUSTRIAL), "industrial"),
    ("beach", centre(D.BEACH), "beach"),
    ("tree crown centre", D.TREE, "tree"),
    ("big tree crown centre", D.BIG_TREE, "tree"),
    ("tree row", (865, 700), "tree"),
    ("pedestrian square (highway=pedestrian area=yes)", centre(D.SQUARE), "footway"),
    ("inside a closed footway without area=yes", centre(D.LOOP), "unlabeled"),
    ("closed footway loop itself", (D.LOOP[0], 950), "footway"),
    ("between features", (700, 200), "unlabeled"),
])
def test_class_at_known_pixel(labels: np.ndarray, name: str, pixel: tuple[float, float], expected: str) -> None:
    assert at(labels, pixel) == expected, name


def test_holes_courtyard_and_island(labels: np.ndarray) -> None:
    c0, r0, c1, r1 = D.COURTYARD_INNER
    assert (labels[r0 + 2:r1 - 2, c0 + 2:c1 - 2] == 0).all(), "courtyard must be a hole"
    o0, q0, o1, q1 = D.COURTYARD_OUTER
    ring = labels[q0 + 2:q1 - 2, o0 + 2:o1 - 2].copy()
    ring[r0 - q0 - 4:r1 - q0, c0 - o0 - 4:c1 - o0] = 1  # blank out the courtyard (+ its edge)
    assert (ring == T13.by_name["building"].id).all()
    i0, j0, i1, j1 = D.ISLAND
    assert (labels[j0 + 2:j1 - 2, i0 + 2:i1 - 2] == 0).all(), "island must not be water"
    water = T13.by_name["water"].id
    lake = labels[D.LAKE[1] + 2:D.LAKE[3] - 2, D.LAKE[0] + 2:D.LAKE[2] - 2]
    assert (lake == water).sum() == pytest.approx(lake.size - (i1 - i0) * (j1 - j0), rel=0.01)


def run_length(values: np.ndarray, class_name: str, through: int) -> int:
    """Length of the run of ``class_name`` pixels in a 1-D array that contains index ``through``."""
    hit = values == T13.by_name[class_name].id
    assert hit[through], f"{class_name} expected at index {through}"
    lo = through
    while lo > 0 and hit[lo - 1]:
        lo -= 1
    hi = through
    while hi + 1 < len(hit) and hit[hi + 1]:
        hi += 1
    return hi - lo + 1


@pytest.mark.parametrize(("what", "metres", "cut"), [
    ("residential lanes=2 x 3.5 m", 7.0, lambda lab: (lab[:, 300], "highway", D.ROAD_ROW)),
    ("primary width=12 m", 12.0, lambda lab: (lab[800, :], "highway", D.PRIMARY_COL)),
    ("footway default 2 m", 2.0, lambda lab: (lab[380, :], "footway", D.FOOTWAY_COL)),
    ("river width=8", 8.0, lambda lab: (lab[700, :], "water", D.RIVER_COL)),
    ("track 3 m", 3.0, lambda lab: (lab[:, 300], "dirt road", D.TRACK_ROW)),
    ("gravel residential 5 m (dirt road widths)", 5.0, lambda lab: (lab[:, 300], "dirt road", D.GRAVEL_ROW)),
    ("tree row 6 m", 6.0, lambda lab: (lab[:, 865], "tree", D.TREE_ROW[0][1])),
    ("tree crown default 5 m", 5.0, lambda lab: (lab[D.TREE[1], :], "tree", D.TREE[0])),
    ("tree crown diameter_crown=8", D.BIG_TREE_CROWN, lambda lab: (lab[D.BIG_TREE[1], :], "tree", D.BIG_TREE[0])),
])
def test_line_widths_in_ground_metres(labels: np.ndarray, what: str, metres: float, cut) -> None:
    values, name, through = cut(labels)
    assert abs(run_length(values, name, through) - px(metres)) <= 1.0, what


def test_draw_order(labels: np.ndarray) -> None:
    # the road is drawn over the footway that crosses it, buildings over parks, bridges over rivers
    assert at(labels, (D.FOOTWAY_COL, D.ROAD_ROW)) == "highway"
    assert at(labels, (D.FOOTWAY_COL, D.ROAD_ROW - px(7) / 2 - 4)) == "footway"
    assert at(labels, centre(D.PARK_BUILDING)) == "building"
    assert at(labels, (D.RIVER_COL, D.BRIDGE_ROW)) == "highway"
    assert at(labels, (D.RIVER_COL, D.BRIDGE_ROW + 20)) == "water"
    assert at(labels, (D.PRIMARY_COL, D.ROAD_ROW)) == "highway"


def test_tunnel_is_not_drawn(labels: np.ndarray) -> None:
    col = D.TUNNEL_COL
    assert not (labels[D.TUNNEL_ROWS[0]:D.TUNNEL_ROWS[1], col - 5:col + 5] == T13.by_name["highway"].id).any()


def test_features_are_clipped_at_the_box_edge(features: FeatureSet, labels: np.ndarray) -> None:
    b = D.grid().xy_bounds
    for f in features:
        x0, y0, x1, y1 = f.geometry.bounds
        assert b.left - 5 <= x0 and x1 <= b.right + 5 and b.bottom - 5 <= y0 and y1 <= b.top + 5, f.osm_id
    # roads that run beyond the box reach its edges
    assert at(labels, (0, D.ROAD_ROW)) == at(labels, (1279, D.ROAD_ROW)) == "highway"
    assert at(labels, (D.PRIMARY_COL, 0)) == at(labels, (D.PRIMARY_COL, 1279)) == "highway"


def test_sea_from_coastline_on_the_right_side(labels: np.ndarray) -> None:
    # the coast runs from (400, 1930) to (1930, 400), north-east: pixels with col + row > 2330 are sea
    assert at(labels, (1250, 1250)) == "water"
    assert at(labels, (1270, 1150)) == "water"
    assert at(labels, (1200, 1080)) == "unlabeled"
    rows, cols = np.mgrid[900:1280, 1170:1280]
    sea = labels[900:1280, 1170:1280] == T13.by_name["water"].id
    expected = (cols + rows + 1) > 2330  # pixel centres beyond the line
    assert (sea == expected).mean() > 0.99


def test_six_class_mapping(labels: np.ndarray) -> None:
    six = to_table(labels, T13, T6)
    assert six.dtype == np.uint8
    name6 = {c.id: c.name for c in (T6.unlabeled, *T6.classes)}
    assert name6[int(six[int(centre(D.CONSTRUCTION)[1]), int(centre(D.CONSTRUCTION)[0])])] == "unlabeled"
    assert name6[int(six[int(centre(D.INDUSTRIAL)[1]), int(centre(D.INDUSTRIAL)[0])])] == "unlabeled"
    assert name6[int(six[int(centre(D.PARKING)[1]), int(centre(D.PARKING)[0])])] == "unlabeled"
    for box in (D.BEACH, D.PARK, D.GRASS, D.WOOD):
        assert name6[int(six[int(centre(box)[1]) + 40, int(centre(box)[0]) + 40])] == "natural"
    assert name6[int(six[D.TREE[1], D.TREE[0]])] == "natural"
    assert name6[int(six[D.ROAD_ROW, 300])] == "highway"
    assert name6[int(six[D.TRACK_ROW, 300])] == "dirt road"
    assert name6[int(six[380, D.FOOTWAY_COL])] == "footway"
    assert name6[int(six[850, 100])] == "water"
    assert name6[int(six[200, 130])] == "building"
    assert set(np.unique(six)) <= set(name6)
    assert (to_table(labels, T13, T13) == labels).all()
    with pytest.raises(ClassTableError):
        to_table(six, T6, T13)


def test_rasterize_nothing_is_all_unlabeled() -> None:
    g = D.grid()
    empty = rasterize(FeatureSet((), g.xy_bounds), g, T13)
    assert empty.shape == (1280, 1280) and not empty.any()


def test_rasterize_rejects_features_of_another_table(features: FeatureSet) -> None:
    with pytest.raises(ClassTableError, match="not in table"):
        rasterize(features, D.grid(), T6)


def test_doctests() -> None:
    assert doctest.testmod(osmseg.rasterize).failed == 0
