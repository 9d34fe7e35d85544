"""Does a label mask line up with its image? An edge-alignment check.

OSM outlines and aerial imagery can be offset from each other by metres (imagery
misregistration, old tracing). Object outlines in a good mask run along strong edges in the
image; shifting the mask by a few pixels moves them off those edges. :func:`edge_alignment`
measures the mean image edge strength along a class's outline for every shift in a window
and reports the best one: (0, 0) means the mask sits on the image; :func:`dataset_alignment`
does it for every sample of a dataset (``osmseg verify --alignment CLASS``).

>>> import numpy as np
>>> img = np.zeros((64, 64, 3), np.uint8); img[20:40, 20:40] = 200
>>> mask = np.zeros((64, 64), bool); mask[20:40, 20:40] = True
>>> edge_alignment(img, mask).best
(0, 0)
>>> edge_alignment(img, np.roll(mask, 3, axis=1)).best
(-3, 0)
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any, NamedTuple, cast

import numpy as np

from osmseg.errors import ConfigError
from osmseg.images import read_label, read_rgb
from osmseg.output.manifest import read_manifest


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
    return cast("np.ndarray", mask & ~core)


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


def dataset_alignment(dataset: Path, class_name: str, skip: Iterable[str] = ()) -> dict[str, dict[str, Any]]:
    """Per sample of an ``osmseg build`` dataset, how ``class_name``'s outlines sit on the image edges.

    Sample name -> ``{"dx", "dy", "edge_at_zero", "edge_far", "outline_pixels"}`` (see
    :class:`Alignment`); a sample without that class says so (``dx``/``dy`` None and a
    ``note``) instead of a (0, 0) that would read as "lined up". Samples whose image or label
    file is in ``skip`` (relative paths, e.g. files :func:`osmseg.output.verify` found broken)
    are left out. ConfigError when the dataset has no such class.
    """
    manifest = read_manifest(dataset)
    table = manifest.classes
    wanted = table.by_name.get(class_name)
    if wanted is None:
        names = ", ".join(c.name for c in table.classes)
        raise ConfigError(f"--alignment {class_name!r}: not a class of this dataset; use one of {names}")
    skipped = set(skip)
    offsets: dict[str, dict[str, Any]] = {}
    for sample in manifest.samples:
        image, label = sample.file_in("images"), sample.file_in("labels")
        if image is None or label is None or image in skipped or label in skipped:
            continue
        mask = read_label(Path(dataset) / label) == wanted.id
        if not mask.any():
            offsets[sample.name] = {"dx": None, "dy": None, "outline_pixels": 0,
                                       "note": f"no {class_name} pixels in this sample"}
            continue
        fit = edge_alignment(read_rgb(Path(dataset) / image), mask)
        offsets[sample.name] = {"dx": fit.best[0], "dy": fit.best[1], "edge_at_zero": round(fit.at_zero, 1),
                                   "edge_far": round(fit.far, 1), "outline_pixels": fit.outline_pixels}
    return offsets
