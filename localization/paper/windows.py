"""Window positions of the covisibility graph: where windows sit, and which window corners hold a coordinate.

The arithmetic both clique algorithms of :mod:`localization.paper.graph` share, so they agree bit
for bit: :class:`Cliques` (their result), the window grid of an image (:func:`_geometry`, in
osmseg's or the authors' conventions), the containment tests (:func:`_in_linear`,
:func:`_in_cyclic`) and, for the sweep, the interval of corner indices whose windows hold a
coordinate (:func:`_intervals`) and the cut of the corner axes at every interval end
(:func:`_cuts`). See the module docstring of :mod:`localization.paper.graph` for the definitions.

Imports: numpy, osmseg.errors, localization.common.landmarks.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from localization.common.landmarks import Landmarks
from osmseg.errors import ConfigError

__all__ = ["CONVENTIONS", "Cliques"]


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
    origin: int = 0  # corner of index 0: 0 (osmseg), 1 (the authors' MATLAB grid: corners 1, 1 + s, ...)

    def first_centers(self, first_i: np.ndarray, first_j: np.ndarray) -> np.ndarray:
        """The authors' candidate positions: the centre ``corner + w / 2`` of the first producing window."""
        cx = self.origin + np.asarray(first_i, dtype=np.int64) * self.s + self.w / 2
        cy = (np.full(cx.shape, self.height / 2) if self.panorama
              else self.origin + np.asarray(first_j, dtype=np.int64) * self.s + self.w / 2)
        return np.stack([cx % self.width if self.panorama else cx, cy], axis=-1)

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


#: How windows are placed and cliques ordered: ``osmseg`` (the default, see the module docstring)
#: or ``authors`` (their published MATLAB ``covgraph.m``: see :func:`cliques_fast`).
CONVENTIONS = ("osmseg", "authors")


def _geometry(lm: Landmarks, w: int, stride: int, conventions: str = "osmseg") -> _Geometry:
    for value, what in ((w, "window size"), (stride, "stride")):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ConfigError(f"the {what} must be a positive integer (pixels), got {value!r}")
    if conventions not in CONVENTIONS:
        raise ConfigError(f"conventions must be one of {', '.join(CONVENTIONS)}, got {conventions!r}")
    if conventions == "authors" and lm.pixels is not None:
        raise ConfigError("the authors' conventions are those of point landmarks (their code takes points): "
                          "use centroid or grid landmarks")
    w, s, origin = int(w), int(stride), int(conventions == "authors")
    if lm.panorama:
        return _Geometry(w, s, (lm.width - 1) // s + 1, 1, lm.width, lm.height, True, origin)
    return _Geometry(w, s, max(lm.width - w, 0) // s + 1, max(lm.height - w, 0) // s + 1,
                     lm.width, lm.height, False, origin)


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


def _row_runs(nonempty: np.ndarray, changes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Runs of equal non-empty cells along each row of a cell grid: ``(row, first column, end column)``.

    ``changes[r, c]`` (c >= 1) says cell ``(r, c)`` differs from its left neighbour; runs are
    listed in raster order, ``end`` one past their last cell.
    """
    start = nonempty.copy()
    start[:, 1:] &= changes
    flat = np.flatnonzero(start)
    stops = np.append(np.flatnonzero(start | ~nonempty), start.size)  # column 0 is always one of these
    end = stops[np.searchsorted(stops, flat, side="right")]
    row, col = np.divmod(flat, start.shape[1])
    return row, col, end - row * start.shape[1]


def _run_cliques(first: np.ndarray, inverse: np.ndarray, ey: np.ndarray, ex: np.ndarray, ex_end: np.ndarray,
                 cuts_x: np.ndarray, cuts_y: np.ndarray, g: _Geometry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """From runs labelled by clique (``np.unique``'s ``first`` and ``inverse``): each clique's first run,
    its centre, and its first window's corner indices ``(M, 2)``, cliques by first run in raster order.

    A run is a rectangle of window corners (indices ``cuts[a] .. cuts[a + 1] - 1`` per axis), so a
    clique's corner-index sums and count add up over its runs, in integers (arithmetic series).
    """
    order = np.argsort(first)
    clique = np.empty(len(order), dtype=np.int64)
    clique[order] = np.arange(len(order))
    clique = clique[np.asarray(inverse).ravel()]  # each run's clique
    x_bound = np.append(np.asarray(cuts_x, dtype=np.int64), g.nx)
    y_bound = np.append(np.asarray(cuts_y, dtype=np.int64), g.ny)
    x_lo, y_lo = x_bound[ex], y_bound[ey]
    n_x, n_y = x_bound[ex_end] - x_lo, y_bound[ey + 1] - y_lo
    sums = np.zeros((3, len(order)), dtype=np.int64)
    for which, values in enumerate(((2 * x_lo + n_x - 1) * n_x // 2 * n_y, (2 * y_lo + n_y - 1) * n_y // 2 * n_x,
                                    n_x * n_y)):
        np.add.at(sums[which], clique, values)
    firsts = first[order]
    centers = g.centers(x_lo[firsts], sums[0], sums[1], sums[2])
    return firsts, centers, np.stack([x_lo[firsts], y_lo[firsts]], axis=1)


def _empty_from(k: int, g: _Geometry) -> Cliques:
    return Cliques(np.zeros((0, k), dtype=bool), np.zeros((0, 2)), g.w, g.s)
