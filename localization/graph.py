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
  window edge) agree bit for bit.

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
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from localization.landmarks import Landmarks
from osmseg.errors import ConfigError

__all__ = ["Cliques", "adjacency", "cliques_fast", "cliques_reference", "window_size_auto"]

#: Sigmas above the mean nearest-neighbour distance for the automatic window (Resek 2022, §3).
AUTO_SIGMAS = 5.0


@dataclass(frozen=True, eq=False)  # arrays: compare fields, not objects
class Cliques:
    """The cliques of a landmark graph: ``members[j, k]`` is True when clique j holds landmark k.

    ``centers[j]`` is the ``(x, y)`` mean of the centres of all the windows that produce
    clique j (a panorama: ``x`` of the first such window, ``y = H / 2``; see the module
    docstring); ``window`` and ``stride`` are the window side and stride used.
    """

    members: np.ndarray  # (M, K) bool
    centers: np.ndarray  # (M, 2) float
    window: int = 0
    stride: int = 1

    def __len__(self) -> int:
        return len(self.members)


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
    return (c.T @ c) > 0


# ------------------------------------------------------------------------------ window geometry


def _in_linear(p: np.ndarray, lo: np.ndarray | int, w: int) -> np.ndarray:
    """Is coordinate ``p`` inside ``[lo, lo + w]``? (the one test both algorithms use)."""
    return (lo <= p) & (p <= lo + w)


def _in_cyclic(p: np.ndarray, lo: np.ndarray | int, w: int, period: int) -> np.ndarray:
    """Is ``p`` inside ``[lo, lo + w]`` on a circle of circumference ``period``?"""
    d = p - lo
    return np.where(d < 0, d + period, d) <= w


@dataclass(frozen=True)
class _Geometry:
    """Window positions of one image: corner indices ``0..nx-1`` x ``0..ny-1``, corner = index * s."""

    w: int
    s: int
    nx: int
    ny: int
    width: int
    height: int
    panorama: bool

    def centers(self, first_i: np.ndarray, sum_i: np.ndarray, sum_j: np.ndarray, count: np.ndarray) -> np.ndarray:
        """Clique centres from integer corner-index data (both algorithms call this, so they agree exactly).

        ``first_i``: x index of the first producing window (used by a panorama only);
        ``sum_i``/``sum_j``: sums of the x/y corner indices of all producing windows, ``count``
        their number. Aerial: the mean window centre; panorama: the first window's, at ``H / 2``.
        """
        if self.panorama:
            cx = np.asarray(first_i, dtype=np.int64) * self.s + min(self.w, self.width) / 2
            return np.stack([cx % self.width, np.full(cx.shape, self.height / 2)], axis=-1)
        n = np.asarray(count, dtype=np.int64)
        cx = np.asarray(sum_i, dtype=np.int64) * self.s / n + min(self.w, self.width) / 2
        cy = np.asarray(sum_j, dtype=np.int64) * self.s / n + min(self.w, self.height) / 2
        return np.stack([cx, cy], axis=-1)


def _geometry(lm: Landmarks, w: int, stride: int) -> _Geometry:
    for value, what in ((w, "window size"), (stride, "stride")):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ConfigError(f"the {what} must be a positive integer (pixels), got {value!r}")
    w, s = int(w), int(stride)
    if lm.panorama:
        return _Geometry(w, s, (lm.width - 1) // s + 1, 1, lm.width, lm.height, True)
    return _Geometry(w, s, max(lm.width - w, 0) // s + 1, max(lm.height - w, 0) // s + 1,
                     lm.width, lm.height, False)


def _empty(lm: Landmarks, g: _Geometry) -> Cliques:
    return Cliques(np.zeros((0, len(lm)), dtype=bool), np.zeros((0, 2)), g.w, g.s)


# ------------------------------------------------------------------------------------- reference


def cliques_reference(lm: Landmarks, w: int, stride: int = 1) -> Cliques:
    """The cliques by the paper's plain sliding window: every position tested, O(positions x K).

    Kept as the reference :func:`cliques_fast` is tested against; the landmark test of each
    position is vectorised over the landmarks (or over all component pixels).
    """
    g = _geometry(lm, w, stride)
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
    sums: list[list[int]] = []  # per clique: first x index, sum of x indices, sum of y indices, count
    for j in range(g.ny):
        y = j * g.s
        in_y = True if g.panorama else _in_linear(py, y, g.w)
        for i in range(g.nx):
            x = i * g.s
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
                sums.append([i, i, j, 1])
    if not members:
        return _empty(lm, g)
    first_i, sum_i, sum_j, count = np.array(sums, dtype=np.int64).T
    return Cliques(np.array(members, dtype=bool), g.centers(first_i, sum_i, sum_j, count), g.w, g.s)


# ------------------------------------------------------------------------------------------ fast


def cliques_fast(lm: Landmarks, w: int, stride: int = 1) -> Cliques:
    """The same cliques as :func:`cliques_reference`, exactly, from the interval ends only.

    See the module docstring. Cost: O(K log K + cells x K / 64) for points, where the cells
    (at most ``(2K + 1)²``, ``4K + 1`` for a panorama) are the grid cut by the interval ends;
    components add their pixels and, per component, the cells its windows can reach
    (about ``(w / s + size)²``).
    """
    g = _geometry(lm, w, stride)
    if len(lm) == 0:
        return _empty(lm, g)
    if lm.pixels is None:
        planes, cuts_x, cuts_y = _point_planes(lm, g)
    else:
        planes, cuts_x, cuts_y = _component_planes(lm, g)
    return _distinct(planes, cuts_x, cuts_y, len(lm), g)


def _lowest_true(pred: Callable[[np.ndarray], np.ndarray], estimate: np.ndarray,
                 lo: np.ndarray | int, hi: np.ndarray | int) -> np.ndarray:
    """Per element, the lowest ``i`` in ``[lo, hi]`` where ``pred(i)`` holds (``hi + 1`` if none).

    ``pred`` must be monotone (False then True) on ``[lo, hi]``; ``estimate`` is a guess a step
    or two off (from float arithmetic), corrected with ``pred`` itself so the answer agrees
    exactly with evaluating ``pred`` everywhere.
    """
    i = np.clip(np.asarray(estimate, dtype=np.int64), lo, np.asarray(hi) + 1)
    while True:  # step down while the index below also holds
        down = (i > lo) & pred(i - 1)
        if not down.any():
            break
        i = i - down
    while True:  # step up while this index does not hold
        up = (i <= hi) & ~pred(i)
        if not up.any():
            break
        i = i + up
    return i


def _intervals(p: np.ndarray, g: _Geometry, axis: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For coordinates ``p`` on ``axis`` (0: x, 1: y): ``(owner, first, last)`` corner-index intervals.

    Interval ``r`` says coordinate ``p[owner[r]]`` is inside the windows with corner index
    ``first[r] .. last[r]`` on this axis, and in no other. One interval per coordinate (two
    when a panorama window wraps around), empty ones left out.
    """
    p = np.asarray(p)
    s, w = g.s, g.w
    n = g.nx if axis == 0 else g.ny
    idx = np.arange(len(p))
    after = _lowest_true(lambda i: i * s > p, np.floor(p / s) + 1, 0, n - 1)  # first corner right of p
    if not (g.panorama and axis == 0):
        first = _lowest_true(lambda i: i * s + w >= p, np.ceil((p - w) / s), 0, n - 1)
        owners, firsts, lasts = [idx], [first], [np.minimum(after - 1, n - 1)]
    else:
        period = g.width
        # corners left of (or at) p: no wrap, d = p - x; corners right of p: d = p - x + period
        first = _lowest_true(lambda i: p - i * s <= w, np.ceil((p - w) / s), 0, after - 1)
        wrapped = _lowest_true(lambda i: (p - i * s) + period <= w, np.ceil((p + period - w) / s), after, n - 1)
        owners, firsts, lasts = [idx, idx], [first, wrapped], [after - 1, np.full(len(p), n - 1)]
    owner, lo, hi = (np.concatenate(a) for a in (owners, firsts, lasts))
    keep = lo <= hi
    return owner[keep], lo[keep], hi[keep]


def _cuts(first: np.ndarray, last: np.ndarray, n: int) -> np.ndarray:
    """Starts of the elementary intervals of ``0..n-1`` cut at every interval's ends."""
    ends = np.concatenate([[0], first, last + 1])
    return np.unique(ends[ends < n])


def _new_planes(k: int, ny: int, nx: int) -> np.ndarray:
    return np.zeros(((k + 63) // 64, ny, nx), dtype=np.uint64)


def _set_bit(planes: np.ndarray, k: int, rows: slice, cols: slice, where: np.ndarray | None = None) -> None:
    bit = np.uint64(1) << np.uint64(k % 64)
    view = planes[k // 64, rows, cols]
    if where is None:
        view |= bit
    else:
        np.bitwise_or(view, bit, out=view, where=where)


def _point_planes(lm: Landmarks, g: _Geometry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bit planes over the cut grid for point landmarks: each sets its rectangle(s) of cells."""
    kx, x0, x1 = _intervals(lm.xy[:, 0], g, 0)
    if g.panorama:
        ky, y0, y1 = np.arange(len(lm)), np.zeros(len(lm), np.int64), np.zeros(len(lm), np.int64)
    else:
        ky, y0, y1 = _intervals(lm.xy[:, 1], g, 1)
    cuts_x, cuts_y = _cuts(x0, x1, g.nx), _cuts(y0, y1, g.ny)
    ex0, ex1 = np.searchsorted(cuts_x, x0), np.searchsorted(cuts_x, x1 + 1)
    ey0, ey1 = np.searchsorted(cuts_y, y0), np.searchsorted(cuts_y, y1 + 1)
    rows_of = {int(k): (int(a), int(b)) for k, a, b in zip(ky, ey0, ey1)}  # one y interval per landmark
    planes = _new_planes(len(lm), len(cuts_y), len(cuts_x))
    for k, a, b in zip(kx, ex0, ex1):
        if int(k) in rows_of:
            r0, r1 = rows_of[int(k)]
            _set_bit(planes, int(k), slice(r0, r1), slice(int(a), int(b)))
    return planes, cuts_x, cuts_y


def _component_planes(lm: Landmarks, g: _Geometry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bit planes over the cut grid for component landmarks (any pixel in the window)."""
    pixels = lm.pixels or ()
    cols = np.unique(np.concatenate([p[:, 0] for p in pixels])).astype(np.int64)
    _, x0, x1 = _intervals(cols, g, 0)
    cuts_x = _cuts(x0, x1, g.nx)
    if g.panorama:
        cuts_y = np.zeros(1, dtype=np.int64)
    else:
        rows = np.unique(np.concatenate([p[:, 1] for p in pixels])).astype(np.int64)
        _, y0, y1 = _intervals(rows, g, 1)
        cuts_y = _cuts(y0, y1, g.ny)
    planes = _new_planes(len(lm), len(cuts_y), len(cuts_x))
    for k, pix in enumerate(pixels):
        if g.panorama:
            _panorama_component(planes, k, pix, cuts_x, g)
        else:
            _aerial_component(planes, k, pix, cuts_x, cuts_y, g)
    return planes, cuts_x, cuts_y


def _panorama_component(planes: np.ndarray, k: int, pix: np.ndarray, cuts_x: np.ndarray, g: _Geometry) -> None:
    """Cells whose windows hold a column of the component: a difference array over the cuts."""
    _, lo, hi = _intervals(np.unique(pix[:, 0]).astype(np.int64), g, 0)
    diff = np.zeros(len(cuts_x) + 1, dtype=np.int64)
    np.add.at(diff, np.searchsorted(cuts_x, lo), 1)
    np.add.at(diff, np.searchsorted(cuts_x, hi + 1), -1)
    covered = np.cumsum(diff[:-1]) > 0
    _set_bit(planes, k, slice(0, 1), slice(None), covered[None, :])


def _aerial_component(planes: np.ndarray, k: int, pix: np.ndarray, cuts_x: np.ndarray, cuts_y: np.ndarray,
                      g: _Geometry) -> None:
    """Cells whose window holds a pixel of the component: box counts, one axis after the other."""
    x, y = pix[:, 0].astype(np.int64), pix[:, 1].astype(np.int64)
    xmin, xmax, ymin, ymax = x.min(), x.max(), y.min(), y.max()
    # cells whose window can reach the component's box: corner <= max and corner + w >= min
    cx, cy = cuts_x * g.s, cuts_y * g.s
    a, b = np.searchsorted(cx + g.w, xmin), np.searchsorted(cx, xmax, side="right")
    c, d = np.searchsorted(cy + g.w, ymin), np.searchsorted(cy, ymax, side="right")
    if a >= b or c >= d:
        return
    box = np.zeros((ymax - ymin + 1, xmax - xmin + 2), dtype=np.int32)
    box[y - ymin, x - xmin + 1] = 1
    bh, bw = box.shape[0], box.shape[1] - 1
    row_sum = box.cumsum(axis=1, dtype=np.int32)  # row_sum[r, i] = pixels of row r left of column i
    lx = np.clip(cx[a:b] - xmin, 0, bw)
    hx = np.clip(cx[a:b] + g.w - xmin + 1, 0, bw)
    row_hit = np.zeros((bh + 1, b - a), dtype=np.int32)  # row_hit[r] = rows above r with a pixel in the window
    row_hit[1:] = ((row_sum[:, hx] - row_sum[:, lx]) > 0).cumsum(axis=0, dtype=np.int32)
    ly = np.clip(cy[c:d] - ymin, 0, bh)
    hy = np.clip(cy[c:d] + g.w - ymin + 1, 0, bh)
    _set_bit(planes, k, slice(c, d), slice(a, b), row_hit[hy] > row_hit[ly])


def _distinct(planes: np.ndarray, cuts_x: np.ndarray, cuts_y: np.ndarray, k: int, g: _Geometry) -> Cliques:
    """Distinct non-empty cell bit sets as Cliques, ordered by their first cell in raster order.

    Cells equal to their left neighbour are merged into horizontal runs first (a run is a
    rectangle of window corners: indices ``cuts[a] .. cuts[a + 1] - 1`` per cell and axis);
    only runs are compared, and a clique's corner-index sums and count add up over its runs,
    in integers.
    """
    ny, nx = planes.shape[1:]
    nonempty = (planes != 0).any(axis=0)
    start = nonempty.copy()
    start[:, 1:] &= (planes[:, :, 1:] != planes[:, :, :-1]).any(axis=0)
    flat_start = np.flatnonzero(start)  # raster order
    if len(flat_start) == 0:
        return _empty_from(k, g)
    stops = np.append(np.flatnonzero(start | ~nonempty), ny * nx)  # column 0 is always one of these
    flat_end = stops[np.searchsorted(stops, flat_start, side="right")]  # one past the run's last cell
    ey, ex = np.divmod(flat_start, nx)
    ex_end = flat_end - ey * nx
    words = np.ascontiguousarray(planes[:, ey, ex].T)  # (runs, words)
    keys = words.view(np.dtype((np.void, words.itemsize * words.shape[1]))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    order = np.argsort(first)  # cliques by first run in raster order
    clique = np.empty(len(order), dtype=np.int64)
    clique[order] = np.arange(len(order))
    clique = clique[inverse.ravel()]  # each run's clique
    x_bound = np.append(np.asarray(cuts_x, dtype=np.int64), g.nx)
    y_bound = np.append(np.asarray(cuts_y, dtype=np.int64), g.ny)
    x_lo, y_lo = x_bound[ex], y_bound[ey]
    n_x, n_y = x_bound[ex_end] - x_lo, y_bound[ey + 1] - y_lo
    run_sum_i = (2 * x_lo + n_x - 1) * n_x // 2 * n_y  # sum of the x indices of the run's corners
    run_sum_j = (2 * y_lo + n_y - 1) * n_y // 2 * n_x
    sums = np.zeros((3, len(order)), dtype=np.int64)
    for row, values in enumerate((run_sum_i, run_sum_j, n_x * n_y)):
        np.add.at(sums[row], clique, values)
    firsts = first[order]
    shifts = np.arange(64, dtype=np.uint64)
    bits = (words[firsts][:, :, None] >> shifts) & np.uint64(1)
    members = bits.reshape(len(firsts), -1)[:, :k].astype(bool)
    centers = g.centers(x_lo[firsts], sums[0], sums[1], sums[2])
    return Cliques(members, centers, g.w, g.s)


def _empty_from(k: int, g: _Geometry) -> Cliques:
    return Cliques(np.zeros((0, k), dtype=bool), np.zeros((0, 2)), g.w, g.s)
