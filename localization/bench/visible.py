"""Visible landmarks: the panorama an annotator would mark, for separating detection from matching.

In the paper a person marks the same houses, trees and road points in the aerial image and in
the panorama. Landmarks extracted automatically from two masks need not correspond (a block
of touching houses is one aerial component but several facades). This module builds the
panorama's landmarks *from the aerial ones*: every aerial landmark the camera sees (at least
``min_px`` panorama pixels show it) becomes a panorama landmark of the same class, at the
circular-mean column and mean row of those pixels. With it, ``osmseg localize-bench
--query-landmarks visible`` measures the matching alone, with perfect correspondence.

An aerial landmark owns a *cell* of the mask (:func:`landmark_cells`): its whole component in
centroid and component modes; in grid mode the part of its component nearer to its grid node
than to the component's other nodes.

>>> from localization.common.landmarks import LandmarkClasses
>>> mask = np.zeros((6, 8), np.uint8); mask[1:5, 1:7] = 1
>>> lm, cells = landmark_cells(mask, {0: "x", 1: "house"}, LandmarkClasses(("building",), {"house": "building"}),
...                            mode="grid", stride=4, min_size=1)
>>> lm.xy.tolist(), cells[2].tolist()
([[2.0, 2.0], [6.0, 2.0]], [-1, 0, 0, 0, 0, 1, 1, -1])
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.spatial import cKDTree

from localization.bench.render import Panorama
from localization.common.landmarks import LandmarkClasses, Landmarks, circular_x, landmarks_from_mask
from osmseg.classes import ClassTable
from osmseg.errors import ConfigError

__all__ = ["landmark_cells", "visible_landmarks"]


def landmark_cells(mask: np.ndarray, table: ClassTable | Mapping[int, str] | None, classes: LandmarkClasses, *,
                   mode: str = "centroid", stride: int = 50, min_size: int = 50) -> tuple[Landmarks, np.ndarray]:
    """The landmarks of :func:`landmarks_from_mask` (same order and positions) and the cell each pixel is in.

    Returns ``(landmarks, cells)``; ``cells`` is ``(H, W)`` int64, the index of the landmark
    owning each pixel, -1 where none does.
    """
    comp = landmarks_from_mask(mask, table, classes, mode="component", stride=stride, min_size=min_size)
    cells = np.full(np.shape(mask), -1, dtype=np.int64)
    pixels = comp.pixels or ()
    if mode in ("centroid", "component"):
        for k, p in enumerate(pixels):
            cells[p[:, 1], p[:, 0]] = k
        return (comp if mode == "component" else landmarks_from_mask(
            mask, table, classes, mode="centroid", min_size=min_size)), cells
    if mode != "grid":
        raise ConfigError(f"landmark mode must be centroid, grid or component, got {mode!r}")
    off = stride // 2
    node_xy, node_cls, node_comp = [], [], []
    for k, p in enumerate(pixels):  # nodes of each component in raster order, else its centroid
        on = ((p[:, 0] - off) % stride == 0) & ((p[:, 1] - off) % stride == 0)
        nodes = p[on].astype(np.float64) if on.any() else comp.xy[k:k + 1]
        node_xy.append(nodes)
        node_cls.append(np.full(len(nodes), comp.cls[k]))
        node_comp.append(np.full(len(nodes), k))
    if not node_xy:
        return landmarks_from_mask(mask, table, classes, mode="grid", stride=stride, min_size=min_size), cells
    xy, owner = np.concatenate(node_xy), np.concatenate(node_comp)
    # nearest node *of the same component*: the component index as a third, far-apart coordinate
    far = 4.0 * (mask.shape[0] + mask.shape[1])
    tree = cKDTree(np.column_stack([xy, owner * far]))
    px = np.concatenate(pixels)
    px_comp = np.repeat(np.arange(len(pixels)), [len(p) for p in pixels])
    _, nearest = tree.query(np.column_stack([px.astype(np.float64), px_comp * far]))
    cells[px[:, 1], px[:, 0]] = nearest
    lm = Landmarks(xy=xy, cls=np.concatenate(node_cls), classes=comp.classes, width=comp.width, height=comp.height)
    return lm, cells


def visible_landmarks(panorama: Panorama, cells: np.ndarray, aerial: Landmarks,
                      min_px: int = 20) -> tuple[Landmarks, np.ndarray]:
    """The aerial landmarks the panorama shows by at least ``min_px`` pixels, as panorama landmarks.

    ``panorama`` must be rendered with ``sources=True`` over the mask ``cells`` was made from.
    Returns the panorama's landmarks (``panorama=True``, ordered by aerial index) and the
    aerial index of each.
    """
    if panorama.sources is None:
        raise ConfigError("render the panorama with sources=True to find the aerial landmarks it shows")
    src = panorama.sources.ravel()
    height, width = panorama.sources.shape
    seen = np.flatnonzero(src >= 0)
    owner = cells.ravel()[src[seen]]
    keep = owner >= 0
    seen, owner = seen[keep], owner[keep]
    k = len(aerial)
    counts = np.bincount(owner, minlength=k)
    shown = np.flatnonzero(counts >= max(min_px, 1))
    rows, cols = np.divmod(seen, width)
    angle = 2 * np.pi * cols / width
    sin = np.bincount(owner, weights=np.sin(angle), minlength=k)[shown]
    cos = np.bincount(owner, weights=np.cos(angle), minlength=k)[shown]
    cy = np.bincount(owner, weights=rows, minlength=k)[shown] / counts[shown]
    lm = Landmarks(xy=np.column_stack([circular_x(sin, cos, width), cy]), cls=aerial.cls[shown],
                   classes=aerial.classes, width=width, height=height, panorama=True)
    return lm, shown
