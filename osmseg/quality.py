"""Does a label mask line up with its image? An edge-alignment check.

OSM outlines and aerial imagery can be offset from each other by metres (imagery
misregistration, old tracing). Object outlines in a good mask run along strong edges in the
image; shifting the mask by a few pixels moves them off those edges. :func:`edge_alignment`
measures the mean image edge strength along a class's outline for every shift in a window
and reports the best one: (0, 0) means the mask sits on the image.

>>> import numpy as np
>>> img = np.zeros((64, 64, 3), np.uint8); img[20:40, 20:40] = 200
>>> mask = np.zeros((64, 64), bool); mask[20:40, 20:40] = True
>>> edge_alignment(img, mask).best
(0, 0)
>>> edge_alignment(img, np.roll(mask, 3, axis=1)).best
(-3, 0)
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Alignment(NamedTuple):
    """Result of :func:`edge_alignment`.

    Attributes:
        best: the (dx, dy) pixel shift to apply to the mask to put its outline on the strongest
            edges; (0, 0) when it lines up (x to the right, y down).
        at_zero: mean edge strength along the unshifted outline.
        far: mean edge strength for shifts of ``max_shift - 1`` pixels or more (the background).
        outline_pixels: how many outline pixels were measured.
    """

    best: tuple[int, int]
    at_zero: float
    far: float
    outline_pixels: int


def sobel_magnitude(grey: np.ndarray) -> np.ndarray:
    """Gradient magnitude of a 2-D array with the 3x3 Sobel operator (zero on the border)."""
    g = grey.astype(np.float32)
    gx = np.zeros_like(g)
    gy = np.zeros_like(g)
    gx[1:-1, 1:-1] = (g[:-2, 2:] + 2 * g[1:-1, 2:] + g[2:, 2:]) - (g[:-2, :-2] + 2 * g[1:-1, :-2] + g[2:, :-2])
    gy[1:-1, 1:-1] = (g[2:, :-2] + 2 * g[2:, 1:-1] + g[2:, 2:]) - (g[:-2, :-2] + 2 * g[:-2, 1:-1] + g[:-2, 2:])
    return np.hypot(gx, gy)


def outline(mask: np.ndarray) -> np.ndarray:
    """Pixels of ``mask`` with a 4-neighbour outside it."""
    core = mask.copy()
    core[1:] &= mask[:-1]
    core[:-1] &= mask[1:]
    core[:, 1:] &= mask[:, :-1]
    core[:, :-1] &= mask[:, 1:]
    return mask & ~core


def edge_alignment(rgb: np.ndarray, mask: np.ndarray, max_shift: int = 6) -> Alignment:
    """Which shift of ``mask`` (a bool array) best matches the edges of ``rgb`` (H, W, 3)."""
    edges = sobel_magnitude(rgb.mean(axis=2) if rgb.ndim == 3 else rgb)
    rows, cols = np.nonzero(outline(mask))
    h, w = mask.shape
    m = max_shift + 2
    keep = (rows >= m) & (rows < h - m) & (cols >= m) & (cols < w - m)
    rows, cols = rows[keep], cols[keep]
    if rows.size == 0:
        return Alignment(best=(0, 0), at_zero=0.0, far=0.0, outline_pixels=0)
    shifts = range(-max_shift, max_shift + 1)
    score = np.array([[edges[rows + dy, cols + dx].mean() for dx in shifts] for dy in shifts])
    iy, ix = np.unravel_index(int(score.argmax()), score.shape)
    far = [score[i, j] for i, dy in enumerate(shifts) for j, dx in enumerate(shifts)
           if max(abs(dx), abs(dy)) >= max_shift - 1]
    # the outline sampled at +(dx, dy) hits the edges: moving the mask by (dx, dy) lines it up
    return Alignment(best=(int(ix) - max_shift, int(iy) - max_shift), at_zero=float(score[max_shift, max_shift]),
                     far=float(np.mean(far)), outline_pixels=int(rows.size))
