"""The horizon of a ground view: how a hand-held camera was tilted, read from the view itself.

The profile method turns each row under the horizon into a ground distance
(:class:`~localization.common.views.Camera`), so it must know where the horizon is. A level camera
sees it on one row; a camera pitched or rolled by a degree or two sees it as a sinusoid across
the columns (:meth:`~localization.common.views.Camera.tilt_rows`), and at 60 m the ground lies only
1.9° below it: a tilt the method does not know moves far rows by tens of metres.

On flat land the sky is seen only above the horizon and the ground only below it, so in every
column the horizon lies between the lowest sky pixel and the highest ground pixel (ground:
anything that is neither sky nor a standing class). Where the view is open (the far end of a
street, a square) the two meet and pin the horizon to a row; where a building stands in front,
the column bounds it only loosely, and says little. The tilt is the pitch and roll whose
sinusoid crosses these bounds by the fewest rows in all (each column's excess, summed):
a convex function of pitch and roll (a sum of hinges of linear functions), searched on a
grid within ``±max_deg``, 0.25° then 0.05°, the smallest tilt winning ties.

A view without a sky class is bounded from below only (every ground pixel lies under the
horizon); the smallest tilt that keeps it so is taken, which is less precise. Measured on the
geometry renderer's views of the Kotka extract (``benchmarks/bench_region.py``): docs/localization.md.

Imports: numpy, localization.common.views.
"""

from __future__ import annotations

from typing import NamedTuple, cast

import numpy as np

from localization.common.views import Camera, SemanticMap

__all__ = ["Tilt", "horizon_bounds", "estimate_tilt"]

#: the grids searched: a coarse one over the whole range, then a fine one around its best
COARSE_STEP_DEG, FINE_STEP_DEG = 0.25, 0.05


class Tilt(NamedTuple):
    """A camera's estimated ``pitch_deg`` and ``roll_deg`` (as :class:`~localization.common.views.Camera`
    takes them), ``open_columns``: columns where sky and ground meet within a row of each other
    (what pins it), and ``excess_rows``: rows by which the horizon crosses the bounds, summed."""

    pitch_deg: float
    roll_deg: float
    open_columns: int
    excess_rows: float


def horizon_bounds(sem: SemanticMap) -> tuple[np.ndarray, np.ndarray]:
    """``(above, below)`` per column: the lowest sky row (-1 where none, or no sky class) and the
    highest ground row (the height where none). The horizon lies between them.

    >>> sky = np.zeros((6, 3), bool); sky[:2] = True; sky[:4, 2] = True
    >>> labels = np.full((6, 3), -1, np.int8); labels[4:] = 0; labels[3, 0] = 0
    >>> sem = SemanticMap(labels, np.zeros((6, 3), bool), ("road", "other"), sky)
    >>> [b.tolist() for b in horizon_bounds(sem)]
    [[1, 1, 3], [2, 2, 4]]
    """
    h = sem.shape[0]
    if sem.sky is not None:
        sky = sem.sky
        ground = ~sky & ~sem.standing
        above = np.where(sky.any(axis=0), h - 1 - np.argmax(sky[::-1], axis=0), -1)
    else:
        ground = (sem.labels >= 0) & ~sem.standing
        above = np.full(sem.shape[1], -1)
    below = np.where(ground.any(axis=0), np.argmax(ground, axis=0), h)
    return above.astype(np.int64), below.astype(np.int64)


def _excess(above: np.ndarray, below: np.ndarray, camera: Camera, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """Rows by which each (pitch, roll)'s horizon crosses the bounds, summed over the columns."""
    cols = np.arange(camera.width)
    t = np.radians(camera.hfov_deg * ((cols + 0.5) / camera.width - 0.5))
    row = camera.horizon + (pitch[:, None] * np.cos(t)[None] - roll[:, None] * np.sin(t)[None]) / camera.step
    # a horizon between pixel rows: the sky row's centre lies half a row above it, the ground's below
    excess = np.maximum(0.0, above[None] + 0.5 - row) + np.maximum(0.0, row - (below[None] - 0.5))
    return cast("np.ndarray", excess.sum(axis=1))


def _best(above: np.ndarray, below: np.ndarray, camera: Camera, pitches: np.ndarray, rolls: np.ndarray
          ) -> tuple[float, float, float]:
    p, r = (a.ravel() for a in np.meshgrid(pitches, rolls, indexing="ij"))
    excess = _excess(above, below, camera, p, r)
    tied = np.flatnonzero(excess <= excess.min() + 1e-9)
    i = tied[np.argmin(p[tied] ** 2 + r[tied] ** 2)]
    return float(p[i]), float(r[i]), float(excess[i])


def estimate_tilt(sem: SemanticMap, camera: Camera, max_deg: float) -> Tilt:
    """The tilt of the camera that saw ``sem`` (its pixel rows and columns as ``camera`` says),
    within ``±max_deg`` in pitch and in roll (see the module docstring).

    >>> from localization.profile.profiles import Camera
    >>> cam = Camera(360, 90, pitch_deg=1.5, roll_deg=-0.5)
    >>> rows = np.arange(90)[:, None]; line = cam.horizon + cam.tilt_rows(np.arange(360))[None, :]
    >>> sky = rows < line
    >>> labels = np.where(sky, -1, 0).astype(np.int8)
    >>> t = estimate_tilt(SemanticMap(labels, np.zeros_like(sky), ("road", "other"), sky), Camera(360, 90), 3.0)
    >>> round(t.pitch_deg, 2), round(t.roll_deg, 2), t.open_columns
    (1.5, -0.5, 360)
    """
    level = Camera(camera.width, camera.height, camera.hfov_deg, camera.row_step_deg, camera.horizon_row,
                   camera.camera_height_m)
    above, below = horizon_bounds(sem)
    open_columns = int(((below - above) <= 2).sum())
    if max_deg <= 0 or not ((above >= 0).any() or (below < sem.shape[0]).any()):
        return Tilt(0.0, 0.0, open_columns, 0.0)
    n = int(np.floor(max_deg / COARSE_STEP_DEG + 1e-9))
    coarse = np.unique(np.clip(np.append(np.arange(-n, n + 1) * COARSE_STEP_DEG, [-max_deg, max_deg]), -max_deg,
                               max_deg))
    p0, r0, _ = _best(above, below, level, coarse, coarse)
    fine = np.arange(-5, 6) * FINE_STEP_DEG
    p, r, excess = _best(above, below, level, np.clip(p0 + fine, -max_deg, max_deg),
                         np.clip(r0 + fine, -max_deg, max_deg))
    return Tilt(round(p, 4), round(r, 4), open_columns, round(excess, 3))
