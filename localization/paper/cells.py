"""K-bit-set cells of the cut window grid: the sweep for component landmarks.

Each cell of the grid cut at every interval end (:func:`localization.paper.windows._cuts`) gets the
landmarks its windows hold as a bit set (``uint64`` words): a point sets a rectangle of cells,
a component the cells where prefix sums over its bounding box count one of its pixels in the
window. The distinct bit sets are the cliques (:func:`_distinct`). Point landmarks take the
key-sum sweep of :func:`localization.paper.graph._point_cliques` instead, whose memory per cell does
not grow with K; :func:`_point_planes` is the point path it replaced, kept for
``benchmarks/bench_localize_scale.py``.

Imports: numpy, localization.common.landmarks, localization.paper.windows.
"""

from __future__ import annotations

import numpy as np

from localization.common.landmarks import Landmarks
from localization.paper.windows import Cliques, _cuts, _empty_from, _Geometry, _intervals, _row_runs, _run_cliques

__all__: list[str] = []


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

    Cells equal to their left neighbour are merged into horizontal runs first
    (:func:`~localization.paper.windows._row_runs`); only runs are compared
    (:func:`~localization.paper.windows._run_cliques` adds up their corners).
    """
    nonempty = (planes != 0).any(axis=0)
    ey, ex, ex_end = _row_runs(nonempty, (planes[:, :, 1:] != planes[:, :, :-1]).any(axis=0))
    if len(ey) == 0:
        return _empty_from(k, g)
    words = np.ascontiguousarray(planes[:, ey, ex].T)  # (runs, words)
    keys = words.view(np.dtype((np.void, words.itemsize * words.shape[1]))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    firsts, centers, _ = _run_cliques(first, inverse, ey, ex, ex_end, cuts_x, cuts_y, g)
    shifts = np.arange(64, dtype=np.uint64)
    bits = (words[firsts][:, :, None] >> shifts) & np.uint64(1)
    members = bits.reshape(len(firsts), -1)[:, :k].astype(bool)
    return Cliques(members, centers, g.w, g.s)
