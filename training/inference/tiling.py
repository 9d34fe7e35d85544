"""Window geometry for inference: window grids, crop-join keep regions, blend weights, blocks.

Everything here is pure integer/numpy arithmetic (no torch, no I/O) so it can be checked by
hand.  An image of any size is covered by fixed-size windows (the model's training patch,
360x480).  Along each axis the windows advance by ``size - overlap`` and the last window is
shifted back so that it ends exactly at the border; an image shorter than a window gets one
window that starts at 0 and is padded by the caller.

Two ways to join overlapping windows:

* **crop** (the dissertation's): each overlap is split in the middle and every window keeps
  only its central part, so the *keep* regions tile the image exactly;
* **blend**: every window's class probabilities are weighted by a linear ramp that rises over
  ``overlap`` pixels from each window edge (never exactly 0) and summed; in a regular overlap
  the two ramps cross-fade and add up to 1, so there is no seam.

Large images are processed in *blocks*: groups of consecutive windows whose output regions
tile the image; a block reads the union of the windows it needs (its halo) and keeps only its
own region, so block-wise output equals whole-image output.

>>> axis_starts(1000, 360, 96)
[0, 264, 528, 640]
>>> axis_cuts([0, 264, 528, 640], 360, 1000)
[0, 312, 576, 764, 1000]
>>> g = WindowGrid.build(1000, 733, (360, 480), 96)
>>> len(g), g.window(0), g.keep(0)
(8, (0, 360, 0, 480), (0, 312, 0, 366))
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from osmseg.errors import ConfigError

#: (top, bottom, left, right), bottom/right exclusive, in image pixels.
Box = tuple[int, int, int, int]


def axis_starts(length: int, size: int, overlap: int) -> list[int]:
    """Window starts along one axis: every ``size - overlap``, the last one ending at ``length``.

    >>> axis_starts(480, 480, 64), axis_starts(200, 480, 64), axis_starts(481, 480, 0)
    ([0], [0], [0, 1])
    >>> axis_starts(1280, 360, 0)
    [0, 360, 720, 920]
    """
    if length < 1:
        raise ConfigError(f"image side must be at least 1 pixel, got {length}")
    if not 0 <= overlap < size:
        raise ConfigError(f"overlap must be in 0..{size - 1} pixels for {size}-pixel windows, got {overlap}")
    if length <= size:
        return [0]
    stride = size - overlap
    starts = list(range(0, length - size, stride))
    return starts + [length - size]


def axis_cuts(starts: Sequence[int], size: int, length: int) -> list[int]:
    """Crop-join boundaries: window ``i`` keeps ``[cuts[i], cuts[i+1])``, split mid-overlap.

    >>> axis_cuts([0], 480, 200), axis_cuts([0, 360], 360, 720), axis_cuts([0, 1], 480, 481)
    ([0, 200], [0, 360, 720], [0, 240, 481])
    """
    middles = [(starts[i + 1] + starts[i] + size) // 2 for i in range(len(starts) - 1)]
    return [0, *middles, length]


def ramp(size: int, overlap: int) -> np.ndarray:
    """1-D blend weight: rises linearly over ``overlap`` pixels from each end, 1 in between.

    Values are ``(i + 1) / (overlap + 1)`` near an edge, so never 0; two windows that overlap
    by exactly ``overlap`` pixels have weights summing to 1 across their overlap.

    >>> [round(float(v), 3) for v in ramp(6, 2)]
    [0.333, 0.667, 1.0, 1.0, 0.667, 0.333]
    >>> w = ramp(8, 3); (w[-3:] + w[:3]).tolist()
    [1.0, 1.0, 1.0]
    """
    i = np.arange(size, dtype=np.float64)
    return np.minimum(1.0, np.minimum(i + 1, size - i) / (overlap + 1)).astype(np.float32)


def blend_weight(size: tuple[int, int], overlap: tuple[int, int]) -> np.ndarray:
    """2-D blend weight of one window: the outer product of the two axis ramps (all > 0)."""
    return np.outer(ramp(size[0], overlap[0]), ramp(size[1], overlap[1]))


def _intersects(a0: int, a1: int, b0: int, b1: int) -> bool:
    return a0 < b1 and b0 < a1


@dataclass(frozen=True)
class Block:
    """A part of the output computed in one go.

    ``box`` is the output region (the blocks of a grid tile the image); ``windows`` are the
    indices (row-major, ascending) of the windows whose predictions it needs; ``read`` is the
    union of those windows clipped to the image: the pixels to read (block plus halo).
    """

    box: Box
    windows: tuple[int, ...]
    read: Box


@dataclass(frozen=True)
class WindowGrid:
    """Windows of ``size`` (H, W) covering a ``height`` x ``width`` image, in row-major order."""

    height: int
    width: int
    size: tuple[int, int]
    overlap: tuple[int, int]
    row_starts: tuple[int, ...]
    col_starts: tuple[int, ...]

    @classmethod
    def build(cls, height: int, width: int, size: tuple[int, int] = (360, 480),
              overlap: int | tuple[int, int] = 96) -> WindowGrid:
        """The grid for an image; ``overlap`` is the minimum overlap in pixels (rows, cols)."""
        ov = (overlap, overlap) if isinstance(overlap, int) else (int(overlap[0]), int(overlap[1]))
        return cls(height, width, (int(size[0]), int(size[1])), ov,
                   tuple(axis_starts(height, size[0], ov[0])), tuple(axis_starts(width, size[1], ov[1])))

    def __len__(self) -> int:
        return len(self.row_starts) * len(self.col_starts)

    def _rc(self, index: int) -> tuple[int, int]:
        return divmod(index, len(self.col_starts))

    def window(self, index: int) -> Box:
        """The window's extent; it may pass the bottom/right border when the image is smaller."""
        r, c = self._rc(index)
        top, left = self.row_starts[r], self.col_starts[c]
        return (top, top + self.size[0], left, left + self.size[1])

    def keep(self, index: int) -> Box:
        """The region this window contributes in crop-join (keep regions tile the image)."""
        r, c = self._rc(index)
        rows = axis_cuts(self.row_starts, self.size[0], self.height)
        cols = axis_cuts(self.col_starts, self.size[1], self.width)
        return (rows[r], rows[r + 1], cols[c], cols[c + 1])

    def blocks(self, block_size: int | None, join: str) -> list[Block]:
        """Split the output into blocks of about ``block_size`` pixels a side (None: one block).

        Block edges follow the window grid so little is computed twice: for ``crop`` they lie
        on the keep boundaries (no window is needed by two blocks), for ``blend`` at window
        starts (one window per block edge is computed twice).  A block needs every window
        that touches its region, which is what makes block-wise output equal to whole-image
        output.
        """
        row_groups = self._axis_groups(self.row_starts, self.size[0], self.height, block_size, join)
        col_groups = self._axis_groups(self.col_starts, self.size[1], self.width, block_size, join)
        blocks = []
        for top, bottom, rows in row_groups:
            for left, right, cols in col_groups:
                ids = tuple(r * len(self.col_starts) + c for r in rows for c in cols)
                reads = [self.window(i) for i in ids]
                read = (min(b[0] for b in reads), min(self.height, max(b[1] for b in reads)),
                        min(b[2] for b in reads), min(self.width, max(b[3] for b in reads)))
                blocks.append(Block((top, bottom, left, right), ids, read))
        return blocks

    @staticmethod
    def _axis_groups(starts: Sequence[int], size: int, length: int, block_size: int | None,
                     join: str) -> list[tuple[int, int, list[int]]]:
        """Per axis: (start, stop, window indices needed) of each block."""
        if block_size is None:
            bounds = [0, length]
        else:
            edges = axis_cuts(starts, size, length) if join == "crop" else [*starts, length]
            bounds = [0]
            for i in range(1, len(edges)):
                # close the current block before edge i if including it would exceed block_size
                if edges[i] - bounds[-1] > block_size and edges[i - 1] > bounds[-1]:
                    bounds.append(edges[i - 1])
            bounds.append(length)
        groups = []
        for a, b in zip(bounds[:-1], bounds[1:]):
            if join == "crop":
                cuts = axis_cuts(starts, size, length)
                needed = [i for i in range(len(starts)) if _intersects(cuts[i], cuts[i + 1], a, b)]
            else:
                needed = [i for i, s in enumerate(starts) if _intersects(s, s + size, a, b)]
            groups.append((a, b, needed))
        return groups


def letterbox(height: int, width: int, size: tuple[int, int] = (360, 480)) -> Box:
    """Where an image scaled to fit ``size`` keeping its aspect ratio sits on the canvas.

    Returns the content box (top, bottom, left, right) inside the ``size`` canvas; the rest
    are the (black) bars, split evenly between the two sides.

    >>> letterbox(1280, 1280), letterbox(720, 960), letterbox(100, 2000)
    ((0, 360, 60, 420), (0, 360, 0, 480), (168, 192, 0, 480))
    """
    scale = min(size[0] / height, size[1] / width)
    h = min(size[0], max(1, round(height * scale)))
    w = min(size[1], max(1, round(width * scale)))
    top, left = (size[0] - h) // 2, (size[1] - w) // 2
    return (top, top + h, left, left + w)


def nearest_index(out_length: int, in_length: int, start: int = 0, stop: int | None = None) -> np.ndarray:
    """Source indices of output pixels ``start..stop`` when resampling by nearest neighbour.

    Pixel centres are matched (``floor((i + 0.5) * in / out)``), as PIL's NEAREST does, and
    any slice of the output can be computed on its own (block-wise upscaling).

    >>> nearest_index(6, 3).tolist(), nearest_index(2, 5).tolist(), nearest_index(6, 3, 4).tolist()
    ([0, 0, 1, 1, 2, 2], [1, 3], [2, 2])
    """
    i = np.arange(start, out_length if stop is None else stop, dtype=np.float64)
    return np.minimum(((i + 0.5) * in_length / out_length).astype(np.int64), in_length - 1)


def pixel_blocks(height: int, width: int, block_size: int | None) -> list[Box]:
    """Plain square blocks tiling an image (for writing a rescaled mask piece by piece).

    >>> pixel_blocks(5, 7, 4)
    [(0, 4, 0, 4), (0, 4, 4, 7), (4, 5, 0, 4), (4, 5, 4, 7)]
    """
    step = max(height, width) if block_size is None else block_size
    return [(r, min(height, r + step), c, min(width, c + step))
            for r in range(0, height, step) for c in range(0, width, step)]
