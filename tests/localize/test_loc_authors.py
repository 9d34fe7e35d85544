"""The authors' conventions (``conventions="authors"``): what their published MATLAB demo computes.

``matlab_covgraph`` below is a line-by-line transliteration of ``covgraph.m`` from
github.com/sebagreen/landmark-graph-matching (1-based window corners ``1 .. W - w + 1``, a
window at ``x`` covering ``[x, x + w]``, ``unique(cliques, 'rows')`` sorting the cliques and
keeping each one's first window, the circular case by copying the left landmarks to the
right). osmseg's fast sweep with the authors' conventions must give the same cliques in the
same order, at the first window's centre, and the match must break ties as ``maxk`` does.
"""

from __future__ import annotations

import numpy as np
import pytest

from localization.common.landmarks import Landmarks
from localization.common.result import rank
from localization.paper.config import PaperConfig
from localization.paper.graph import cliques_fast, cliques_reference
from localization.paper.match import localize


def matlab_covgraph(xy: np.ndarray, width: int, height: int, w: int, circular: bool = False
                    ) -> tuple[np.ndarray, np.ndarray]:
    """covgraph.m: (cliques sorted as MATLAB's unique rows, upper-left corner of each one's first window)."""
    landmarks = np.asarray(xy, dtype=float)
    n = len(landmarks)
    wx, wy = (w, height) if circular else (w, w)
    img_w = width
    repeat = np.zeros(0, dtype=int)
    if circular:
        repeat = np.flatnonzero(landmarks[:, 0] < wx)
        landmarks = np.vstack([landmarks, np.c_[landmarks[repeat, 0] + width, landmarks[repeat, 1]]])
        img_w = width + wx - 1
    xs = range(1, img_w - wx + 2)
    ys = range(1, height - wy + 2)
    rows, locs = [], []
    for y in ys:
        for x in xs:
            rows.append((landmarks[:, 0] >= x) & (landmarks[:, 0] <= x + wx)
                        & (landmarks[:, 1] >= y) & (landmarks[:, 1] <= y + wy))
            locs.append((x, y))
    cliques = np.array(rows, dtype=int)
    if circular:
        cliques[:, repeat] += cliques[:, n:]
        cliques = (cliques[:, :n] > 0).astype(int)
    keys = [tuple(r) for r in cliques]
    first: dict[tuple[int, ...], int] = {}
    for i, k in enumerate(keys):
        first.setdefault(k, i)
    order = sorted(first)                     # unique(..., 'rows'): ascending, first occurrence
    if not any(order[0]):
        order = order[1:]
    return np.array(order, dtype=bool), np.array([locs[first[k]] for k in order], dtype=float)


@pytest.mark.parametrize("seed", range(6))
def test_aerial_cliques_are_those_of_covgraph_m(seed: int) -> None:
    rng = np.random.default_rng(seed)
    size, k = 60, int(rng.integers(4, 14))
    xy = rng.integers(0, size, size=(k, 2)).astype(float)      # integer pixels, as the annotations
    w = int(rng.integers(8, 30))
    lm = Landmarks(xy, rng.integers(0, 2, k), ("a", "b"), size, size)
    members, corners = matlab_covgraph(xy, size, size, w)
    for build in (cliques_fast, cliques_reference):
        c = build(lm, w, conventions="authors")
        assert c.members.shape == members.shape and (c.members == members).all()
        assert np.array_equal(c.centers, corners + w / 2)     # the rectangle [corner, w]'s centre
    # and they differ from osmseg's own when a landmark sits on the 0-based window edges
    ours = cliques_fast(lm, w)
    assert ours.members.shape[1] == members.shape[1]


@pytest.mark.parametrize("seed", range(4))
def test_panorama_cliques_are_those_of_covgraph_m(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    width, height, k = 90, 20, int(rng.integers(4, 12))
    x = rng.integers(0, width, k)
    x[x == height] = height + 1      # the one documented difference: a landmark exactly at x = w
    xy = np.c_[x, rng.integers(0, height, k)].astype(float)
    lm = Landmarks(xy, rng.integers(0, 2, k), ("a", "b"), width, height, panorama=True)
    members, _ = matlab_covgraph(xy, width, height, height, circular=True)
    for build in (cliques_fast, cliques_reference):
        c = build(lm, height, conventions="authors")
        assert c.members.shape == members.shape and (c.members == members).all()


def test_ties_go_to_the_first_candidate_as_maxk() -> None:
    scores = np.array([0.2, 0.7, 0.7, 0.1])
    centers = np.array([[9.0, 9.0], [8.0, 8.0], [1.0, 1.0], [0.0, 0.0]])
    assert rank(scores, centers, by_index=True)[0].tolist() == [1, 2, 0, 3]   # maxk: first index
    assert rank(scores, centers)[0].tolist() == [2, 1, 0, 3]                  # osmseg: raster order


def test_a_worked_example_answers_at_the_first_window() -> None:
    """Two houses, each with its road; the query sees a house and a road: a tie, broken differently."""
    xy = np.array([[10.0, 10], [14, 12], [40, 40], [44, 41]])
    aerial = Landmarks(xy, np.array([0, 1, 0, 1]), ("building", "road"), 60, 60)
    query = Landmarks(np.array([[5.0, 10], [20, 12]]), np.array([0, 1]), ("building", "road"), 120, 24,
                      panorama=True)
    ours = localize(aerial, query, PaperConfig(window=10))
    authors = localize(aerial, query, PaperConfig(window=10, conventions="authors"))
    members, corners = matlab_covgraph(xy, 60, 60, 10)
    relevant = [i for i, m in enumerate(members) if (m[[0, 2]].any() and m[[1, 3]].any())]
    # both houses-with-a-road tie; maxk takes the first relevant clique in unique()'s order,
    # which lists cliques without landmark 1 first: the pair at (40, 40), from its first window
    expect = corners[relevant[0]] + 5.0
    assert members[relevant[0]].tolist() == [False, False, True, True]
    assert authors.map_xy == (float(expect[0]), float(expect[1])) and authors.ties == 2
    assert ours.ties == 2 and ours.map_xy[1] < 20      # osmseg: the tie goes to raster order, up-left


@pytest.mark.parametrize("conventions", ["osmseg", "authors"])
def test_the_banded_sweep_gives_the_same_cliques_with_one_row_per_band(monkeypatch: pytest.MonkeyPatch,
                                                                         conventions: str) -> None:
    """The key-sum sweep works band by band of cell rows (bounded memory): bands of one row change nothing."""
    from localization.paper import graph

    rng = np.random.default_rng(7)
    xy = rng.integers(0, 80, size=(30, 2)).astype(float)
    lm = Landmarks(xy, rng.integers(0, 3, 30), ("a", "b", "c"), 80, 80)
    whole = cliques_fast(lm, 17, 2, conventions)
    monkeypatch.setattr(graph, "BAND_BYTES", 1)
    banded = cliques_fast(lm, 17, 2, conventions)
    reference = cliques_reference(lm, 17, 2, conventions)
    for c in (banded, reference):
        assert (c.members == whole.members).all() and np.array_equal(c.centers, whole.centers)
