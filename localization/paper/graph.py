"""Landmark graphs: which landmarks a sliding covisibility window sees together.

A square window of side ``w`` slides over the image with stride ``s``; the landmarks inside
each position form a *clique* (a binary vector over the K landmarks). Empty and duplicate
cliques are dropped. Stacked, the cliques are the ``(M, K)`` matrix ``C`` of
:class:`Cliques`; the landmark graph is ``A = H(Cᵀ C)`` (:func:`adjacency`).

Window positions, exactly (``W x H`` image, integers ``w >= 1``, ``s >= 1``):

* **aerial** image: corners ``x in {0, s, 2s, ...} ∩ [0, max(W - w, 0)]`` and likewise ``y`` in
  ``[0, max(H - w, 0)]`` -- every position where the window fits, as the paper slides it
  (a window at least as wide as the image has the single corner 0 on that axis, so if
  ``w >= W`` and ``w >= H`` all landmarks form one clique). With ``s > 1`` a strip at the
  right/bottom edge narrower than ``s`` may be in no window, as in the paper.
* **panorama** (a 360° cylinder): the window is as tall as the image, its corner ``x`` takes
  every value in ``{0, s, 2s, ...} ∩ [0, W - 1]`` and it covers ``x .. x + w`` modulo ``W``.

A window at corner ``(x, y)`` covers ``[x, x + w] x [y, y + w]``, bounds included. A point
landmark is in it when its ``xy`` is; a component landmark (``Landmarks.pixels``) when any
of its pixels is.

Each clique's centre is the mean of the centres of *all* the window positions that produce it
(the match step uses centres as candidate positions: the first window in raster order would
bias them up and left by up to ``w / 2``). A window's centre is that of its part inside the
image, ``(x + min(w, W) / 2, y + min(w, H) / 2)``, so the clique's centre is
``(s * mean(i) + min(w, W) / 2, s * mean(j) + min(w, H) / 2)`` over the corner indices
``(i, j)`` producing it, computed from integer sums (corner indices and their count) so both
algorithms give bit-identical floats. A panorama's centre is ``(x, H / 2)`` where ``x`` is the
centre ``(x + min(w, W) / 2) mod W`` of the first producing window: on a circle a mean of
positions is ill-defined, and panorama centres are never used as positions. Cliques are
ordered by their first window in raster order (rows top to bottom, then left to right).

Two algorithms give identical results (same cliques, same order, same centres):

* :func:`cliques_reference` -- the paper's plain loop over every window position,
  O(positions x K), seconds on a 750 x 750 image;
* :func:`cliques_fast` -- the default. Along each axis, a landmark (or a component's pixel
  column/row) is inside exactly the windows whose corner index lies in an interval (two for
  a panorama's wrap-around); the clique can only change at the ends of those intervals. The
  corner axes are cut at all interval ends into elementary intervals, each cell of the
  resulting grid gets its landmarks as a bit set (``uint64`` words: a point sets a rectangle
  of cells, a component the cells where prefix sums over its bounding box count one of its
  pixels in the window), and the distinct bit sets are the cliques, each with the sums of
  the corner indices of all its cells (a cell is a rectangle of corners: closed-form
  arithmetic-series sums) and its first cell in raster order. Interval ends are computed from
  the very same comparisons as the reference, so boundary cases (a landmark exactly on a
  window edge) agree bit for bit. For point landmarks the cells do not hold K-bit sets but two
  64-bit sums of random keys of the landmarks covering them, built band by band of cell rows
  (:func:`_point_cliques`): memory per cell is constant instead of K / 8 bytes, so a 3000 x
  3000 image with 1,500 landmarks needs about 100 MB instead of 700 MB (two different sets
  share both sums with probability 2^-128; ``benchmarks/bench_localize_scale.py``).

**The authors' conventions** (``conventions="authors"``), to reproduce the figures of their
published MATLAB demo (``covgraph.m``): window corners on MATLAB's 1-based grid (``1, 1 + s,
...``: the same number of positions, one pixel right and down; a panorama's windows also
start at row 1, so a landmark on row 0 is in none), the cliques in the order of
``unique(C, 'rows')`` (lexicographic: landmark 1's column first, absent before present) and
each clique at the centre ``corner + w / 2`` of its *first* window. One case differs still: in
a panorama, a landmark at exactly ``x = w`` is copied across the seam by their code only when
``x < w``, so it misses the last window there (osmseg's cyclic test includes it).

>>> lm = Landmarks(np.array([[1.0, 1], [4, 1], [8, 1]]), np.array([0, 1, 0]), ("a", "b"), width=10, height=3)
>>> c = cliques_fast(lm, 4)  # corners x = 0..6: {l1, l2} at 0-1, {l2} at 2-3, {l2, l3} at 4, {l3} at 5-6
>>> c.members.astype(int).tolist(), c.centers.tolist()
([[1, 1, 0], [0, 1, 0], [0, 1, 1], [0, 0, 1]], [[2.5, 1.5], [4.5, 1.5], [6.0, 1.5], [7.5, 1.5]])
>>> bool((cliques_reference(lm, 4).members == c.members).all())
True
>>> adjacency(c).astype(int).tolist()
[[1, 1, 0], [1, 1, 1], [0, 1, 1]]
"""

from __future__ import annotations

import math
from typing import cast

import numpy as np
from scipy.spatial import cKDTree

from localization.common.landmarks import Landmarks
from localization.paper.cells import _component_planes, _distinct
from localization.paper.windows import (
    CONVENTIONS,
    Cliques,
    _cuts,
    _empty_from,
    _Geometry,
    _geometry,
    _in_cyclic,
    _in_linear,
    _intervals,
    _row_runs,
    _run_cliques,
)

__all__ = ["CONVENTIONS", "Cliques", "adjacency", "cliques_fast", "cliques_reference", "window_size_auto"]

#: Sigmas above the mean nearest-neighbour distance for the automatic window (Resek 2022, §3).
AUTO_SIGMAS = 5.0


def window_size_auto(lm: Landmarks) -> int:
    """Window side ``round(mu + 5 sigma)`` of the landmarks' nearest-neighbour distances.

    ``sigma`` is the sample standard deviation (``ddof=1``) and halves round up, as the
    authors' ``autoWindowSize.m`` (MATLAB's ``std`` and ``round``); in a panorama distances
    wrap around in x. With fewer than two landmarks there is no distance, and every window
    gives the same cliques, so the answer is the image size ``max(width, height)``.

    >>> lm = Landmarks(np.array([[0.0, 0], [3, 4], [3, 0]]), np.zeros(3, int), ("a",), 10, 10)
    >>> window_size_auto(lm)  # distances 3, 3, 4: mu = 3.33, sigma = 0.577, mu + 5 sigma = 6.22
    6
    """
    if len(lm) < 2:
        return max(lm.width, lm.height)
    xy = lm.xy.copy()
    if lm.panorama:
        xy[:, 0] %= lm.width
        xy[:, 0][xy[:, 0] >= lm.width] = 0.0  # -tiny % W rounds to W
        tree = cKDTree(xy, boxsize=(lm.width, 2 * lm.height))  # y never wraps: |dy| < H
    else:
        tree = cKDTree(xy)
    dist = tree.query(xy, k=2)[0][:, 1]
    value = float(dist.mean() + AUTO_SIGMAS * dist.std(ddof=1))
    return max(1, math.floor(value + 0.5))


def adjacency(cliques: Cliques) -> np.ndarray:
    """The landmark graph ``A = H(Cᵀ C)``: ``(K, K)`` bool, True when two landmarks share a clique.

    ``H`` is the Heaviside step (``> 0``). As in the formula the diagonal is kept: ``A[k, k]``
    is True when landmark k is in some clique (the class adjacency of the dissertation's
    Algorithm 1 counts only pairs ``i < j``, so the diagonal never enters the matching).
    """
    members = np.asarray(cliques.members, dtype=bool)
    if members.shape[0] == 0:
        return np.zeros((members.shape[1], members.shape[1]), dtype=bool)
    c = members.astype(np.float32)  # counts <= M are exact in float32 up to 2**24 cliques
    return cast("np.ndarray", (c.T @ c) > 0)


# ------------------------------------------------------------------------------ window geometry


def _authors_order(c: Cliques, first_centers: np.ndarray) -> Cliques:
    """The authors' order and positions: rows sorted as MATLAB's ``unique(C, 'rows')`` (lexicographic,
    landmark 1 first, absent before present), each at its first window's centre."""
    order = np.lexsort(c.members.T[::-1]) if len(c) else np.zeros(0, dtype=np.int64)
    return Cliques(c.members[order], first_centers[order], c.window, c.stride)


def _empty(lm: Landmarks, g: _Geometry) -> Cliques:
    return Cliques(np.zeros((0, len(lm)), dtype=bool), np.zeros((0, 2)), g.w, g.s)


# ------------------------------------------------------------------------------------- reference


def cliques_reference(lm: Landmarks, w: int, stride: int = 1, conventions: str = "osmseg") -> Cliques:
    """The cliques by the paper's plain sliding window: every position tested, O(positions x K).

    Kept as the reference :func:`cliques_fast` is tested against; the landmark test of each
    position is vectorised over the landmarks (or over all component pixels).
    """
    g = _geometry(lm, w, stride, conventions)
    if len(lm) == 0:
        return _empty(lm, g)
    if lm.pixels is not None:
        px = np.concatenate([p[:, 0] for p in lm.pixels]).astype(np.int64)
        py = np.concatenate([p[:, 1] for p in lm.pixels]).astype(np.int64)
        starts = np.cumsum([0] + [len(p) for p in lm.pixels[:-1]])
    else:
        px, py, starts = lm.xy[:, 0], lm.xy[:, 1], None
    index_of: dict[bytes, int] = {}
    members: list[np.ndarray] = []
    sums: list[list[int]] = []  # per clique: first x index, sum of x indices, sum of y indices, count, first y
    for j in range(g.ny):
        y = g.origin + j * g.s
        in_y = (_in_linear(py, y, g.height) if g.origin else True) if g.panorama else _in_linear(py, y, g.w)
        for i in range(g.nx):
            x = g.origin + i * g.s
            in_x = _in_cyclic(px, x, g.w, g.width) if g.panorama else _in_linear(px, x, g.w)
            inside = in_x & in_y
            if starts is not None:
                inside = np.logical_or.reduceat(inside, starts)
            key = inside.tobytes()
            if key in index_of:
                acc = sums[index_of[key]]
                acc[1] += i
                acc[2] += j
                acc[3] += 1
            elif inside.any():
                index_of[key] = len(members)
                members.append(inside)
                sums.append([i, i, j, 1, j])
    if not members:
        return _empty(lm, g)
    first_i, sum_i, sum_j, count, first_j = np.array(sums, dtype=np.int64).T
    out = Cliques(np.array(members, dtype=bool), g.centers(first_i, sum_i, sum_j, count), g.w, g.s)
    return _authors_order(out, g.first_centers(first_i, first_j)) if g.origin else out


# ------------------------------------------------------------------------------------------ fast


def cliques_fast(lm: Landmarks, w: int, stride: int = 1, conventions: str = "osmseg") -> Cliques:
    """The same cliques as :func:`cliques_reference`, exactly, from the interval ends only.

    See the module docstring. Cost: O(K log K + cells x K / 64) for points, where the cells
    (at most ``(2K + 1)²``, ``4K + 1`` for a panorama) are the grid cut by the interval ends;
    components add their pixels and, per component, the cells its windows can reach
    (about ``(w / s + size)²``).
    """
    g = _geometry(lm, w, stride, conventions)
    if len(lm) == 0:
        return _empty(lm, g)
    if lm.pixels is None:
        return _point_cliques(lm, g)
    planes, cuts_x, cuts_y = _component_planes(lm, g)
    return _distinct(planes, cuts_x, cuts_y, len(lm), g)


def _spans(start: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(which, value)``: span ``i`` of ``start[i] .. start[i] + count[i] - 1`` expanded, all spans in order.

    >>> [v.tolist() for v in _spans(np.array([5, 0, 7]), np.array([2, 0, 1]))]
    [[0, 0, 2], [5, 6, 7]]
    """
    count = np.maximum(count, 0)
    which = np.repeat(np.arange(len(count)), count)
    return which, start[which] + (np.arange(len(which)) - np.repeat(np.cumsum(count) - count, count))


#: Memory for one band of cells of :func:`_point_cliques` (two 8-byte planes per cell).
BAND_BYTES = 32 << 20


def _point_cliques(lm: Landmarks, g: _Geometry) -> Cliques:
    """The cliques of point landmarks in memory that does not grow with K per cell.

    Each landmark covers a rectangle of cells of the cut grid. Instead of a K-bit set per cell,
    a cell keeps two 64-bit sums of random odd keys of the landmarks covering it, built band by band of cell rows with 2-D difference arrays: cells with equal sums
    hold the same landmarks (two distinct sets agree on both sums with probability 2^-128).
    Runs of equal cells along a row are compared, as in :func:`_distinct`; each clique's members
    are read back from its first cell. Same cliques, order and centres as :func:`_distinct`.
    """
    k = len(lm)
    kx, x0, x1 = _intervals(lm.xy[:, 0] - g.origin, g, 0)  # corners at origin + i s: shift the points instead
    if g.panorama:  # one row of windows as tall as the image (the authors': rows 1 .. 1 + H, so row 0 is out)
        ky = np.arange(k) if not g.origin else np.flatnonzero(_in_linear(lm.xy[:, 1], g.origin, g.height))
        y0, y1 = np.zeros(len(ky), np.int64), np.zeros(len(ky), np.int64)
    else:
        ky, y0, y1 = _intervals(lm.xy[:, 1] - g.origin, g, 1)
    cuts_x, cuts_y = _cuts(x0, x1, g.nx), _cuts(y0, y1, g.ny)
    nx, ny = len(cuts_x), len(cuts_y)
    # one rectangle per (x interval, y interval) pair of a landmark: [ry0, ry1) x [rx0, rx1) in cells
    y_of = {int(a): (int(b), int(c)) for a, b, c in zip(ky, np.searchsorted(cuts_y, y0),
                                                         np.searchsorted(cuts_y, y1 + 1))}
    rect = np.array([(int(o), *y_of[int(o)], int(a), int(b)) for o, a, b in
                     zip(kx, np.searchsorted(cuts_x, x0), np.searchsorted(cuts_x, x1 + 1)) if int(o) in y_of],
                    dtype=np.int64).reshape(-1, 5)
    if len(rect) == 0:
        return _empty_from(k, g)
    keys = np.random.default_rng(0x5EED).integers(0, 2**63, size=(2, k), dtype=np.int64).astype(np.uint64) * 2 + 1
    band = max(1, BAND_BYTES // (16 * (nx + 1)))
    runs: list[np.ndarray] = []
    for b0 in range(0, ny, band):
        b1 = min(ny, b0 + band)
        on = rect[(rect[:, 1] < b1) & (rect[:, 2] > b0)]
        if len(on) == 0:
            continue
        r0, r1 = np.maximum(on[:, 1], b0) - b0, np.minimum(on[:, 2], b1) - b0
        planes = np.zeros((2, b1 - b0 + 1, nx + 1), dtype=np.uint64)
        for row, col, sign in ((r0, on[:, 3], 1), (r0, on[:, 4], -1), (r1, on[:, 3], -1), (r1, on[:, 4], 1)):
            for p in range(2):
                w = keys[p, on[:, 0]]
                np.add.at(planes[p], (row, col), w if sign > 0 else (~w + np.uint64(1)))
        planes = planes.cumsum(axis=1, dtype=np.uint64).cumsum(axis=2, dtype=np.uint64)[:, :-1, :-1]
        nonempty = planes[0] != 0  # a non-empty set's sum of odd keys is 0 with probability 2^-64
        ry, rx, rend = _row_runs(nonempty, (planes[:, :, 1:] != planes[:, :, :-1]).any(axis=0))
        if len(ry) == 0:
            continue
        flat = ry * nx + rx
        runs.append(np.stack([planes[0].ravel()[flat].view(np.int64), planes[1].ravel()[flat].view(np.int64),
                              ry + b0, rx, rend], axis=1))
    if not runs:
        return _empty_from(k, g)
    run = np.concatenate(runs)                        # raster order: bands in order, raster within a band
    ey, ex, ex_end = run[:, 2], run[:, 3], run[:, 4]
    _, first, inverse = np.unique(run[:, 0], return_index=True, return_inverse=True)
    if (run[first[inverse.ravel()], 1] != run[:, 1]).any():  # the first sums collided: both (never seen)
        _, first, inverse = np.unique(run[:, :2], axis=0, return_index=True, return_inverse=True)
    firsts, centers, corners = _run_cliques(first, inverse, ey, ex, ex_end, cuts_x, cuts_y, g)
    cy, cx = ey[firsts], ex[firsts]                   # each clique's first cell: who covers it
    members = np.zeros((len(firsts), k), dtype=bool)
    # each rectangle's cliques: per cell row of it, the first cells in [c, d) of a sorted raster key
    key = cy * nx + cx
    by_key = np.argsort(key, kind="stable")
    o, a, b, c, d = rect.T
    of_row, y = _spans(a, b - a)
    lo = np.searchsorted(key[by_key], y * nx + c[of_row])
    hi = np.searchsorted(key[by_key], y * nx + d[of_row])
    of_hit, at = _spans(lo, hi - lo)
    members[by_key[at], o[of_row[of_hit]]] = True
    out = Cliques(members, centers, g.w, g.s)
    return _authors_order(out, g.first_centers(corners[:, 0], corners[:, 1])) if g.origin else out

