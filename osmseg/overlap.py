"""Which samples overlap: groups of boxes that share ground.

Two samples overlap when their tile blocks share pixels (boxes that only touch along an edge
do not). Random centres drawn independently can land near each other, and in a small area
often do. Samples that overlap show the same ground, so a test split that holds one of them
and a training split that holds the other measures memory, not generalisation:
:func:`overlap_groups` gives the connected groups of overlapping samples, which the builder
records in the manifest and training keeps together in one split.

>>> overlap_groups([(0, 0, 2, 2), (1, 1, 3, 3), (2.5, 0, 4, 1.5), (3, 3, 4, 4)])  # the last only touches
[0, 0, 0, 1]

Imports: numpy.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

__all__ = ["overlap_groups"]


def overlap_groups(boxes: Sequence[Sequence[float]]) -> list[int]:
    """Group index of each box (left, bottom, right, top): boxes sharing area are in one group.

    Groups are numbered in order of their first box. Touching edges are not overlap.

    Linear in the number of boxes when they are equally sized (a build's samples all are): boxes
    are bucketed in cells of one box size, so a box can only overlap boxes of its own cell and
    the eight around it, and a cell whose boxes all lie within one box size of each other is one
    group without a test per pair. Other boxes get the sweep along x.

    >>> overlap_groups([(0, 0, 1, 1), (1, 0, 2, 1), (0.5, 0.5, 1.5, 1.5), (5, 5, 6, 6)])
    [0, 0, 0, 1]
    """
    n = len(boxes)
    arr = np.asarray(boxes, dtype=float).reshape(n, 4) if n else np.zeros((0, 4))
    parent = list(range(n))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    def union(i: int, j: int) -> None:
        a, b = root(i), root(j)
        if a != b:
            parent[max(a, b)] = min(a, b)

    width, height = arr[:, 2] - arr[:, 0], arr[:, 3] - arr[:, 1]
    if n and (width == width[0]).all() and (height == height[0]).all() and width[0] > 0 and height[0] > 0:
        _cell_unions(arr, float(width[0]), float(height[0]), union, root)
    else:
        order = np.argsort(arr[:, 0], kind="stable")
        for k, i in enumerate(order):  # sweep along x: only boxes starting before i ends can overlap it
            for j in order[k + 1:]:
                if arr[j, 0] >= arr[i, 2]:
                    break
                if arr[j, 1] < arr[i, 3] and arr[i, 1] < arr[j, 3]:
                    union(int(i), int(j))
    labels: dict[int, int] = {}
    return [labels.setdefault(root(i), len(labels)) for i in range(n)]


def _overlaps(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(len(a), len(b))`` bool: which boxes of ``a`` share area with which of ``b``."""
    return ((a[:, None, 0] < b[None, :, 2]) & (b[None, :, 0] < a[:, None, 2])
            & (a[:, None, 1] < b[None, :, 3]) & (b[None, :, 1] < a[:, None, 3]))


def _cell_unions(arr: np.ndarray, w: float, h: float, union: Callable[[int, int], None],
                 root: Callable[[int], int]) -> None:
    """Union every overlapping pair of equally sized boxes, cell by cell (see :func:`overlap_groups`)."""
    cx, cy = np.floor(arr[:, 0] / w).astype(np.int64), np.floor(arr[:, 1] / h).astype(np.int64)
    cells: dict[tuple[int, int], list[int]] = {}
    for i, key in enumerate(zip(cx.tolist(), cy.tolist())):
        cells.setdefault(key, []).append(i)
    members = {key: np.array(ids) for key, ids in cells.items()}
    for (x, y), ids in members.items():
        box = arr[ids]
        if np.ptp(box[:, 0]) < w and np.ptp(box[:, 1]) < h:  # every pair is within a box size: all overlap
            for j in ids[1:]:
                union(int(ids[0]), int(j))
        else:  # a cell edge met rounding: test its pairs
            for a, b in zip(*np.nonzero(np.triu(_overlaps(box, box), 1))):
                union(int(ids[a]), int(ids[b]))
        for dx, dy in ((1, 0), (-1, 1), (0, 1), (1, 1)):  # each neighbouring pair of cells once
            other = members.get((x + dx, y + dy))
            if other is None:
                continue
            a, b = np.nonzero(_overlaps(box, arr[other]))
            if len(a):  # join the groups of the overlapping pairs, each pair of groups once
                ra = np.array([root(int(i)) for i in ids])
                rb = np.array([root(int(j)) for j in other])
                n = len(arr)
                for key in np.unique(ra[a] * n + rb[b]).tolist():
                    union(key // n, key % n)
