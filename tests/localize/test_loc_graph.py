"""Landmarks and landmark graphs (localization/common/landmarks.py, localization/paper/graph.py).

The graph tests check the cliques a user would read off a drawing (the dissertation's Figure
3.1), and that the fast algorithm gives exactly the cliques of the paper's plain sliding
window on random, real-sized and panorama inputs.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from localization.common.landmark_files import read_landmarks
from localization.common.landmarks import (
    PAPER_CLASSES,
    LandmarkClasses,
    Landmarks,
    landmarks_from_mask,
    load_landmark_classes,
)
from localization.paper.graph import Cliques, adjacency, cliques_fast, cliques_reference, window_size_auto
from osmseg.classes import load_class_table
from osmseg.errors import ClassTableError, ConfigError, DatasetError

ABC = ("a", "b", "c")
REPO = Path(__file__).resolve().parents[2]


def points(xy, width: int, height: int, panorama: bool = False, cls=None) -> Landmarks:
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    cls = np.zeros(len(xy), dtype=int) if cls is None else np.asarray(cls)
    return Landmarks(xy, cls, ABC, width, height, panorama=panorama)


def sets(c: Cliques) -> list[set[int]]:
    """Cliques as sets of 1-based landmark numbers (l1, l2, ...), in order."""
    return [{int(k) + 1 for k in np.flatnonzero(row)} for row in c.members]


def assert_same(a: Cliques, b: Cliques) -> None:
    assert a.members.shape == b.members.shape
    assert (a.members == b.members).all()
    assert np.array_equal(a.centers, b.centers)


# ------------------------------------------------------------------------------------ Figure 3.1

# Six landmarks on a 16 x 16 image, window 10, stride 6: corners (0,0), (6,0), (0,6), (6,6).
FIG31 = [(2, 2), (8, 2), (13, 3), (8, 8), (8, 13), (7, 14)]


@pytest.mark.parametrize("algorithm", [cliques_fast, cliques_reference])
def test_figure_3_1_cliques(algorithm):
    c = algorithm(points(FIG31, 16, 16), 10, stride=6)
    assert sets(c) == [{1, 2, 4}, {2, 3, 4}, {4, 5, 6}]  # the 4th window repeats C3: dropped
    # centres: mean over the windows producing each clique (C3: corners (0, 6) and (6, 6))
    assert c.centers.tolist() == [[5.0, 5.0], [11.0, 5.0], [8.0, 11.0]]
    a = adjacency(c)
    edges = {(i + 1, j + 1) for i, j in zip(*np.nonzero(np.triu(a, 1)))}
    assert edges == {(1, 2), (1, 4), (2, 4), (2, 3), (3, 4), (4, 5), (4, 6), (5, 6)}  # the figure's 8 edges
    assert a.diagonal().all() and (a == a.T).all()
    # the example's p = 0.5 extension: C1 shares 2/3 of its landmarks with C2, 1/3 with C3
    m = c.members
    assert (m[0] & m[1]).sum() / m[0].sum() >= 0.5 > (m[0] & m[2]).sum() / m[0].sum()


# -------------------------------------------------------------------------- fast == reference


def random_case(rng: np.random.Generator) -> tuple[Landmarks, int, int]:
    """A small random image: points (integer, half/third, or float coordinates) or components."""
    width, height = int(rng.integers(3, 40)), int(rng.integers(3, 30))
    panorama, component = bool(rng.integers(2)), bool(rng.integers(2))
    k = int(rng.integers(0, 12)) if rng.random() < 0.9 else int(rng.integers(60, 140))  # > 64: several words
    w, stride = int(rng.integers(1, 50)), int(rng.integers(1, 8))  # w often larger than the image
    cls = rng.integers(0, 3, k)
    if component:
        pixels = []
        for _ in range(k):
            n = int(rng.integers(1, 15))
            x = rng.integers(0, width) + rng.integers(-4, 5, n)
            x = x % width if panorama else np.clip(x, 0, width - 1)
            y = np.clip(rng.integers(0, height) + rng.integers(-4, 5, n), 0, height - 1)
            pixels.append(np.unique(np.stack([x, y], 1), axis=0))
        xy = np.array([p.mean(0) for p in pixels]).reshape(-1, 2)
        return Landmarks(xy, cls, ABC, width, height, tuple(pixels), panorama), w, stride
    kind = rng.integers(3)
    if kind == 0:  # integer coordinates: many landmarks exactly on window edges
        xy = np.stack([rng.integers(0, width, k), rng.integers(0, height, k)], 1)
    elif kind == 1:
        xy = np.stack([rng.integers(0, 2 * width, k) / 2, rng.integers(0, 3 * height, k) / 3], 1)
    else:
        xy = np.stack([rng.uniform(0, width, k), rng.uniform(0, height, k)], 1)
    return Landmarks(xy, cls, ABC, width, height, None, panorama), w, stride


def test_fast_equals_reference_random():
    rng = np.random.default_rng(2024)
    kinds = set()
    for case in range(250):
        lm, w, stride = random_case(rng)
        kinds.add((lm.panorama, lm.pixels is not None, w >= max(lm.width, lm.height), stride > 1))
        ref, fast = cliques_reference(lm, w, stride), cliques_fast(lm, w, stride)
        assert ref.members.shape == fast.members.shape, (case, lm, w, stride)
        assert (ref.members == fast.members).all(), (case, lm, w, stride)
        assert np.array_equal(ref.centers, fast.centers), (case, lm, w, stride)
    assert len(kinds) == 16  # every combination was drawn


def test_fast_equals_reference_tenths_on_edges():
    """Coordinates in tenths (and one ulp off) land exactly on, or just beside, window edges."""
    rng = np.random.default_rng(7)
    for _ in range(40):
        width, height, k = int(rng.integers(5, 30)), int(rng.integers(5, 30)), int(rng.integers(5, 80))
        xy = np.stack([rng.integers(0, width * 10, k) * 0.1, rng.integers(0, height * 10, k) * 0.1], 1)
        xy[::2, 0] = np.nextafter(xy[::2, 0], np.inf)
        xy = np.minimum(xy, [np.nextafter(width, 0), np.nextafter(height, 0)])
        lm = points(xy, width, height, panorama=bool(rng.integers(2)))
        w, stride = int(rng.integers(1, 35)), int(rng.integers(1, 5))
        assert_same(cliques_reference(lm, w, stride), cliques_fast(lm, w, stride))


def test_fast_equals_reference_medium():
    rng = np.random.default_rng(1)
    lm = points(rng.uniform(0, 200, (40, 2)), 200, 200, cls=rng.integers(0, 3, 40))
    ref = cliques_reference(lm, 60)
    assert len(ref) > 50
    assert_same(ref, cliques_fast(lm, 60))
    assert_same(cliques_reference(lm, 60, stride=7), cliques_fast(lm, 60, stride=7))


def test_fast_equals_reference_real_sized():
    """750 x 750 with 100 landmarks (a large window keeps the reference near a second) and a panorama."""
    rng = np.random.default_rng(5)
    lm = points(rng.uniform(0, 750, (100, 2)), 750, 750, cls=rng.integers(0, 3, 100))
    ref = cliques_reference(lm, 400)
    assert_same(ref, cliques_fast(lm, 400))
    pano = points(np.c_[rng.uniform(0, 1232, 60), rng.uniform(0, 224, 60)], 1232, 224, panorama=True)
    w = window_size_auto(pano)
    assert_same(cliques_reference(pano, w), cliques_fast(pano, w))


@pytest.mark.slow
def test_fast_equals_reference_real_sized_auto_window():
    rng = np.random.default_rng(6)
    lm = points(rng.uniform(0, 750, (100, 2)), 750, 750, cls=rng.integers(0, 3, 100))
    w = window_size_auto(lm)
    start = time.perf_counter()
    fast = cliques_fast(lm, w)
    t_fast = time.perf_counter() - start
    start = time.perf_counter()
    ref = cliques_reference(lm, w)
    t_ref = time.perf_counter() - start
    assert_same(ref, fast)
    assert t_fast * 20 < t_ref  # typically ~300x


def blob_mask(rng: np.random.Generator, height: int, width: int, n: int, wrap: bool = False) -> np.ndarray:
    """A label mask (values 0..2) of random rectangles and discs, some crossing the right edge if ``wrap``."""
    mask = np.zeros((height, width), np.uint8)
    yy, xx = np.mgrid[:height, :width]
    for i in range(n):
        x, y, r = rng.integers(0, width), rng.integers(0, height), rng.integers(2, 9)
        x = width - 2 if wrap and i == 0 else x
        dx = np.abs(xx - x)
        if wrap:
            dx = np.minimum(dx, width - dx)
        shape = (dx <= r) & (np.abs(yy - y) <= r) if rng.integers(2) else dx ** 2 + (yy - y) ** 2 <= r * r
        mask[shape] = rng.integers(1, 3)
    return mask


TABLE3 = {0: "unlabeled", 1: "house", 2: "street"}
DICT3 = LandmarkClasses(("building", "road"), {"house": "building", "street": "road"})


def test_fast_equals_reference_components_medium():
    rng = np.random.default_rng(3)
    lm = landmarks_from_mask(blob_mask(rng, 96, 110, 25), TABLE3, DICT3, mode="component", min_size=5)
    assert len(lm) > 10 and max(len(p) for p in lm.pixels) > 100
    for w, stride in ((30, 1), (45, 4)):
        assert_same(cliques_reference(lm, w, stride), cliques_fast(lm, w, stride))
    pano = landmarks_from_mask(blob_mask(rng, 40, 300, 30, wrap=True), TABLE3, DICT3, mode="component",
                               min_size=5, panorama=True)
    wrapped = [p for p in pano.pixels if p[:, 0].min() == 0 and p[:, 0].max() == 299]
    assert wrapped  # some component crosses the seam
    for w, stride in ((25, 1), (60, 3)):
        assert_same(cliques_reference(pano, w, stride), cliques_fast(pano, w, stride))


# ------------------------------------------------------------------------------ window geometry


def test_panorama_window_wraps_around():
    lm = points([(98, 5), (1, 30), (50, 10)], 100, 40, panorama=True)
    for algorithm in (cliques_fast, cliques_reference):
        c = algorithm(lm, 5)
        assert {1, 2} in sets(c)  # x = 98 and x = 1 are 3 px apart across the seam
        first = sets(c).index({1, 2})
        assert c.centers[first].tolist() == [(96 + 2.5) % 100, 20.0]  # window 96..101 (mod 100)
        plain = algorithm(points([(98, 5), (1, 30), (50, 10)], 100, 40), 5)
        assert {1, 2} not in sets(plain)  # an aerial image does not wrap


def test_centre_is_the_mean_of_every_producing_window():
    """A lone landmark's clique is centred on it, not up-left of it (the first window's centre)."""
    lm = points([(40, 30)], 100, 80)
    for algorithm in (cliques_fast, cliques_reference):
        for w, stride in ((20, 1), (21, 1), (20, 3)):
            c = algorithm(lm, w, stride)
            assert sets(c) == [{1}]
            # corners 20..40 (x) and 10..30 (y), or their multiples of 3: symmetric around the landmark
            expect_x = np.mean([i + w / 2 for i in range(0, 81, stride) if i <= 40 <= i + w])
            expect_y = np.mean([j + w / 2 for j in range(0, 61, stride) if j <= 30 <= j + w])
            assert c.centers.tolist() == [[expect_x, expect_y]]
        assert algorithm(lm, 20).centers.tolist() == [[40.0, 30.0]]
    # two landmarks: brute force over every window position, averaging the centres per clique
    two = points([(30, 30), (45, 38)], 90, 70)
    c = cliques_fast(two, 25, 2)
    by_clique: dict[frozenset[int], list[tuple[float, float]]] = {}
    for y in range(0, 70 - 25 + 1, 2):
        for x in range(0, 90 - 25 + 1, 2):
            inside = frozenset(k + 1 for k, (px, py) in enumerate(two.xy) if x <= px <= x + 25 and y <= py <= y + 25)
            if inside:
                by_clique.setdefault(inside, []).append((x + 12.5, y + 12.5))
    assert {frozenset(s) for s in sets(c)} == set(by_clique)
    for members, centre in zip(sets(c), c.centers):
        np.testing.assert_allclose(centre, np.mean(by_clique[frozenset(members)], axis=0), rtol=0, atol=1e-12)


def test_window_larger_than_image_is_one_clique():
    lm = points([(1, 1), (9, 2), (4, 6)], 10, 7)
    for algorithm in (cliques_fast, cliques_reference):
        c = algorithm(lm, 25, stride=3)
        assert sets(c) == [{1, 2, 3}] and c.centers.tolist() == [[5.0, 3.5]]
        pano = algorithm(points([(1, 1), (9, 2), (4, 6)], 10, 7, panorama=True), 10)
        assert sets(pano) == [{1, 2, 3}] and pano.centers.tolist() == [[5.0, 3.5]]


def test_bounds_included_and_stride_gap():
    # window [0, 4] holds x = 4 (bound included); width 11, stride 3: corners 0, 3, 6 (<= 11 - 4)
    lm = points([(4, 0), (7, 0), (9.5, 0)], 11, 1)
    assert sets(cliques_fast(lm, 4, stride=3)) == [{1}, {1, 2}, {2, 3}]
    # width 9: corners 0 and 3 only (6 > 9 - 4), so x = 8.5 is in no window
    short = points([(1, 0), (8.5, 0)], 9, 1)
    c = cliques_fast(short, 4, stride=3)
    assert sets(c) == [{1}] and not adjacency(c)[1, 1]  # a landmark in no window: A's diagonal is 0
    assert_same(cliques_reference(short, 4, stride=3), c)


def test_no_landmarks_and_bad_windows():
    empty = points(np.zeros((0, 2)), 20, 20)
    for algorithm in (cliques_fast, cliques_reference):
        c = algorithm(empty, 5)
        assert c.members.shape == (0, 0) and c.centers.shape == (0, 2)
    assert adjacency(cliques_fast(empty, 5)).shape == (0, 0)
    lm = points([(1, 1)], 20, 20)
    for w, stride in ((0, 1), (5, 0), (5.5, 1), (True, 1), (-3, 1)):
        with pytest.raises(ConfigError, match="positive integer"):
            cliques_fast(lm, w, stride)


def test_window_size_auto():
    # nearest-neighbour distances 3, 3, 10: mu = 5.33, sample sigma = 4.04 -> 25.5 -> 26
    lm = points([(0, 0), (0, 3), (10, 0)], 50, 50)
    assert window_size_auto(lm) == 26
    # a panorama measures across the seam: x = 1 and 98 are 3 px apart, not 97
    pano = points([(1, 10), (98, 10)], 100, 20, panorama=True)
    assert window_size_auto(pano) == 3 and window_size_auto(points([(1, 10), (98, 10)], 100, 20)) == 97
    # fewer than two landmarks: no distances; any window gives the same cliques -> image size
    assert window_size_auto(points([(5, 5)], 30, 40)) == 40
    assert window_size_auto(points(np.zeros((0, 2)), 30, 40)) == 40


# ---------------------------------------------------------------------------- landmarks from masks


def test_landmarks_from_mask_centroids_and_min_size():
    mask = np.zeros((40, 60), np.uint8)
    mask[2:12, 3:13] = 1  # 100 px building
    mask[20:22, 30:60] = 2  # 60 px road
    mask[30:35, 5:10] = 1  # 25 px building: below min_size
    mask[12, 13] = 1  # 8-connected to the first building (diagonal): same component
    lm = landmarks_from_mask(mask, TABLE3, DICT3, min_size=50)
    assert [lm.classes[c] for c in lm.cls] == ["building", "road"]
    assert lm.xy[1].tolist() == [44.5, 20.5]
    assert np.allclose(lm.xy[0], [(7.5 * 100 + 13) / 101, (6.5 * 100 + 12) / 101])
    assert len(landmarks_from_mask(mask, TABLE3, DICT3, min_size=1)) == 3
    assert lm.pixels is None and not lm.panorama and (lm.width, lm.height) == (60, 40)


def test_landmarks_from_mask_grid_strides():
    mask = np.zeros((120, 200), np.uint8)
    mask[0:100, 0:100] = 1
    mask[110:115, 150:160] = 2  # small: covers no node at stride 50 -> its centroid
    for stride in (20, 50, 100):
        lm = landmarks_from_mask(mask, TABLE3, DICT3, mode="grid", stride=stride, min_size=10)
        nodes = np.arange(stride // 2, 100, stride)
        building = lm.xy[lm.cls == 0]
        expected = np.array([(x, y) for y in nodes for x in nodes], dtype=float)
        assert np.array_equal(building, expected)
        road = lm.xy[lm.cls == 1]
        if stride == 20:  # nodes at x = 150, 170..; y = 110: (150, 110) is in the road
            assert road.tolist() == [[150.0, 110.0]]
        else:
            assert road.tolist() == [[154.5, 112.0]]


def test_landmarks_from_mask_component_mode():
    mask = np.zeros((10, 10), np.uint8)
    mask[1:3, 1:4] = 1
    lm = landmarks_from_mask(mask, TABLE3, DICT3, mode="component", min_size=1)
    assert len(lm.pixels) == 1
    assert sorted(map(tuple, lm.pixels[0].tolist())) == [(x, y) for x in (1, 2, 3) for y in (1, 2)]
    assert lm.xy.tolist() == [[2.0, 1.5]]


def test_component_mode_with_every_component_of_a_class_too_small():
    mask = np.zeros((20, 30), np.uint8)
    mask[2:12, 2:12] = 1  # a building of 100 px
    mask[15, 20:23] = 2  # a road of 3 px: below min_size, so no road landmark
    for panorama in (False, True):
        lm = landmarks_from_mask(mask, TABLE3, DICT3, mode="component", min_size=10, panorama=panorama)
        assert len(lm) == 1 and len(lm.pixels) == 1 and len(lm.pixels[0]) == 100


def test_panorama_merges_components_across_the_seam():
    mask = np.zeros((20, 100), np.uint8)
    mask[5:15, 95:100] = 1
    mask[5:15, 0:3] = 1  # continues across x = 0
    mask[16:18, 99] = 2
    mask[18, 0] = 2  # diagonal neighbour across the seam
    pano = landmarks_from_mask(mask, TABLE3, DICT3, min_size=1, panorama=True, mode="component")
    assert len(pano) == 2
    assert pano.xy[0, 1] == 9.5 and abs(pano.xy[0, 0] - 98.5) < 0.05  # circular mean across the seam
    assert len(pano.pixels[0]) == 80 and len(pano.pixels[1]) == 3
    flat = landmarks_from_mask(mask, TABLE3, DICT3, min_size=1)
    assert len(flat) == 4 and flat.xy[0].tolist() == [1.0, 9.5]


def test_landmarks_from_mask_errors():
    mask = np.zeros((5, 5), np.uint8)
    with pytest.raises(ConfigError, match="mode"):
        landmarks_from_mask(mask, TABLE3, DICT3, mode="blob")
    with pytest.raises(ConfigError, match="stride"):
        landmarks_from_mask(mask, TABLE3, DICT3, mode="grid", stride=0)
    mask[0, 0] = 7
    with pytest.raises(ConfigError, match=r"label values \[7\]"):
        landmarks_from_mask(mask, TABLE3, DICT3)
    with pytest.raises(ConfigError, match="maps classes"):
        landmarks_from_mask(np.zeros((5, 5), np.uint8), load_class_table("classes6.toml"),
                            load_landmark_classes("aerial13"))
    with pytest.raises(ConfigError, match="2-D integer"):
        landmarks_from_mask(np.zeros((5, 5)), TABLE3, DICT3)
    assert len(landmarks_from_mask(np.zeros((5, 5), np.uint8), TABLE3, DICT3)) == 0  # empty mask: no landmarks


def test_class_dictionaries():
    for name, table in (("aerial13", "classes13.toml"), ("airsegnet6", "classes6.toml")):
        d = load_landmark_classes(name)
        assert d.names == PAPER_CLASSES and d.mask_table == table
        known = {c.name for c in load_class_table(table).classes}
        assert set(d.mapping) <= known and set(d.mapping.values()) == set(PAPER_CLASSES)
    camvid = load_landmark_classes("landmarks-camvid.toml")
    for spelling in ("landmarks-camvid", "camvid", "camvid.toml", "data_manifests/landmarks-camvid.toml"):
        assert load_landmark_classes(str(REPO / spelling) if "/" in spelling else spelling) == camvid
    assert camvid.mapping == {"Building": "building", "Road": "road", "Tree": "vegetation", "Pavement": "footway"}
    assert camvid.mask_ids()[4] == "Pavement" and len(camvid.mask_classes) == 12
    # a CamVid label mask, read with the dictionary's own class list (mask_table=None)
    mask = np.full((30, 30), 0, np.uint8)  # Sky
    mask[10:30, 0:10] = 1  # Building
    mask[20:30, 10:30] = 3  # Road
    mask[5:15, 20:28] = 5  # Tree
    lm = landmarks_from_mask(mask, None, camvid)
    assert [lm.classes[c] for c in lm.cls] == ["building", "road", "vegetation"]


def test_class_dictionary_errors(tmp_path: Path):
    with pytest.raises(ClassTableError, match="not landmark classes"):
        LandmarkClasses(("building",), {"house": "tree"})
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "bad"\n[mapping]\nhouse = "building"\n')
    with pytest.raises(ClassTableError, match="malformed"):
        load_landmark_classes(str(bad))
    for missing in ("nosuchdictionary", "landmarks-nosuch.toml", str(tmp_path / "landmarks-aerial13.toml")):
        with pytest.raises(ConfigError, match="not found: give one of .*aerial13"):
            load_landmark_classes(missing)
    with pytest.raises(ConfigError, match="names no mask table"):
        landmarks_from_mask(np.zeros((3, 3), np.uint8), None, DICT3)


# ------------------------------------------------------------------------------- landmark files


def test_read_landmarks_text_csv_npy(tmp_path: Path):
    camvid = load_landmark_classes("camvid")
    text = tmp_path / "pano.txt"
    text.write_text("# x y Class, as annotated\nx y class\n12 30 Building\n\n40.5 7 road  # a comment\n"
                    "100 2 Sky\n7 8 Tree\n3 4 Pavement\n5 6 2\n")
    lm = read_landmarks(text, camvid, 1232, 224, panorama=True)
    assert lm.xy.tolist() == [[12, 30], [40.5, 7], [7, 8], [3, 4], [5, 6]]  # Sky dropped
    assert [lm.classes[c] for c in lm.cls] == ["building", "road", "vegetation", "footway", "vegetation"]
    assert lm.panorama and (lm.width, lm.height) == (1232, 224)

    table = tmp_path / "aerial.csv"
    table.write_text("class,x,y\nbuilding,1,2\nroad,3.5,4\n")
    lm = read_landmarks(table, PAPER_CLASSES, 10, 10)
    assert lm.xy.tolist() == [[1, 2], [3.5, 4]] and lm.cls.tolist() == [0, 1]

    array = tmp_path / "aerial.npy"
    np.save(array, np.array([[1, 2, 3], [4.5, 5, 0]]))
    lm = read_landmarks(array, PAPER_CLASSES, 10, 10)
    assert lm.xy.tolist() == [[1, 2], [4.5, 5]] and lm.cls.tolist() == [3, 0]
    assert len(read_landmarks(_write(tmp_path / "none.txt", "# nothing\n"), PAPER_CLASSES, 10, 10)) == 0


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.mark.parametrize("name, content, message", [
    ("a.txt", "1 2 building\n3 road\n", r"a.txt:2: expected 'x y Class'"),
    ("b.txt", "1 2 building\nx1 2 road\n", r"b.txt:2: x must be a number"),
    ("c.txt", "1 2 castle\n", r"c.txt:1: unknown landmark class 'castle'"),
    ("d.txt", "1 2 building\n\n10 2 road\n", r"d.txt line 3: \(10, 2\) is outside the 10x10 image"),
    ("e.txt", "1 nan building\n", r"e.txt line 1: coordinates must be finite"),
    ("f.csv", "x,y\n1,2\n", r"f.csv:1: a landmark CSV needs a header"),
    ("g.csv", "x,y,class\n1,2,road\n3,4\n", r"g.csv:3: expected 3 fields"),
    ("h.txt", "1 2 9\n", r"h.txt:1: unknown landmark class '9'"),
])
def test_read_landmarks_errors(tmp_path: Path, name: str, content: str, message: str):
    with pytest.raises(DatasetError, match=message):
        read_landmarks(_write(tmp_path / name, content), PAPER_CLASSES, 10, 10)


def test_read_landmarks_bad_files(tmp_path: Path):
    with pytest.raises(DatasetError, match="not found"):
        read_landmarks(tmp_path / "missing.txt", PAPER_CLASSES, 10, 10)
    np.save(tmp_path / "wide.npy", np.zeros((3, 4)))
    with pytest.raises(DatasetError, match=r"\(K, 3\)"):
        read_landmarks(tmp_path / "wide.npy", PAPER_CLASSES, 10, 10)
    np.save(tmp_path / "cls.npy", np.array([[1, 1, 1.5]]))
    with pytest.raises(DatasetError, match="row 0: class index 1.5"):
        read_landmarks(tmp_path / "cls.npy", PAPER_CLASSES, 10, 10)
    (tmp_path / "junk.npy").write_bytes(b"not numpy")
    with pytest.raises(DatasetError, match="not a readable .npy"):
        read_landmarks(tmp_path / "junk.npy", PAPER_CLASSES, 10, 10)
    (tmp_path / "binary.txt").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(DatasetError, match="cannot read"):
        read_landmarks(tmp_path / "binary.txt", PAPER_CLASSES, 10, 10)


def test_landmarks_validation():
    with pytest.raises(ConfigError, match="outside"):
        points([(10, 1)], 10, 10)
    with pytest.raises(ConfigError, match="shape"):
        Landmarks(np.zeros((3, 3)), np.zeros(3, int), ABC, 10, 10)
    with pytest.raises(ConfigError, match="class indices"):
        Landmarks(np.zeros((1, 2)), np.array([3]), ABC, 10, 10)
    with pytest.raises(ConfigError, match="pixels"):
        Landmarks(np.zeros((1, 2)), np.array([0]), ABC, 10, 10, pixels=(np.array([[11, 0]]),))
    lm = points([(1, 1), (2, 2), (3, 3)], 10, 10, cls=[0, 2, 0])
    assert lm.of_classes(["a"]).xy[:, 0].tolist() == [1.0, 3.0] and lm.of_classes(["a"]).classes == ABC
