"""The ``profile`` method: score a dense grid of aerial positions by their angular profile, coarse to fine.

For every position ``p`` of a grid over the aerial image, the aerial side predicts the profile
``P_p`` (:mod:`localization.profile.profiles`: per landmark class, ground distance and azimuth, what a
camera at ``p`` would see first) and the score is the share of the query's profile mass that
the prediction agrees with::

    S(p, s) = sum_{c,k,a} Q[c, k, a] P_p[c, k, a + s]  /  sum_{c,k,a} Q[c, k, a] V_p[k, a + s]

``V_p`` marks the cells the aerial image can predict (a ray that leaves the image predicts
nothing, so positions near the border are not punished for it). With the heading known the
query is built in compass azimuths and ``s = 0``; with the heading unknown ``S(p, s)`` is a
circular cross-correlation over ``s``, one FFT per profile row, and the best ``s`` is the
heading (to a fraction of a bin by a parabola through the peak). A photo of limited field of
view is a query whose profile is empty outside it: the same formula, nothing else changes.

Search (:mod:`localization.profile.locate`): positions every ``coarse_m`` metres, then around the
``keep`` best ones a 3 x 3 grid a third as wide, ``levels`` times (4 m -> 1.3 m -> 0.44 m by
default); this module scores the positions of one level. Work and memory grow with
the number of grid positions (the image area), in chunks of ``chunk`` positions scored on
``threads`` threads (numpy releases the GIL in its gathers, reductions and FFTs), and the
aerial side is never held at more than one chunk's profiles per thread. Each chunk's scores
depend on that chunk alone, so the answer is the same at any chunk size and thread count.

**Is it here at all?** The best score ``S*`` is compared with the agreement a position drawn
at random would have: ``S0 = sum_{c,k} q[c, k] pbar[c, k]`` with ``pbar`` the mean aerial
profile over the coarse grid and all azimuths. ``kappa = (S* - S0) / (1 - S0)`` (Cohen's kappa
of the best match) is 0 for a query that fits no better than chance, and the answer is "not in
this image" below ``min_kappa``.

**Is it here, or somewhere that looks the same?** A look-alike place fits as well as the
right one, so kappa is high for wrong answers too. The **best distinct alternative** is the
best place at least ``distinct_m`` (50 m) from the answer (the best coarse positions that far
away, refined as the answer was), and the **confidence** is the share of the answer's lead
over chance that no such place reaches::

    confidence = (S* - S_alt) / (S* - S0)

0 when another place fits as well, larger the more the answer stands out (kappa where no place
lies ``distinct_m`` away). Below ``min_confidence`` the answer is "not sure": the result keeps
it, with the alternative. docs/localization.md gives how well it ranks wrong answers below
right ones, per kind of query, and how the default threshold was chosen.

Imports: numpy, osmseg core, localization.profile.profiles.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import sys
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar, cast, runtime_checkable

import numpy as np
from threadpoolctl import ThreadpoolController

from localization.profile.profiles import QueryProfile
from osmseg.errors import ConfigError

__all__ = ["UNKNOWN_HEIGHTS", "AerialIndex", "ProfileConfig", "RayIndex", "allowed_shifts", "class_prior", "grid_positions",
           "score_poses",
           "score_positions"]


#: the camera heights tried when the height is not known (m): a hand-held camera to a car-mounted one
UNKNOWN_HEIGHTS = (1.5, 1.75, 2.0, 2.25, 2.5)


@dataclass(frozen=True)
class ProfileConfig:
    """Settings of the ``profile`` method (see the module docstring)."""

    bins: int | None = None        # azimuth bins [72 (5 deg) for a query mask; for landmark points half the
                                   # bearing kernel, 90 (4 deg) at 8 deg]
    radii: int = 16                # ground distances, log-spaced from min_range_m to max_range_m
    min_range_m: float = 3.0
    max_range_m: float = 60.0
    coarse_m: float | None = None  # coarse grid spacing [the aerial side's: 4 m for a mask, 1.25 m for points]
    keep: int = 40                 # positions refined at each level
    levels: int | None = None      # refinements, each a third of the previous spacing [2 for a mask, 1 for points]
    heading_deg: float | None = 0.0  # compass azimuth of the query's centre column; None: unknown (searched)
    heading_prior_deg: float | None = None  # heading unknown: search only within heading_within_deg of this
    heading_within_deg: float = 180.0       # (a photo's compass heading, good to so many degrees)
    top_k: int = 5
    min_confidence: float | None = None  # confidence below this: "not sure" [the aerial side's: 0.04 for a mask,
                                         # none for landmark points (docs/localization.md: how chosen)]
    min_kappa: float | None = None  # kappa below this: "not in this image" [the aerial side's: 0.6 for a mask,
                                    # 0.3 for landmark points]
    chunk: int = 1024              # positions scored at once (memory)
    samples: int = 24              # aerial ray samples between 0.6 m and the farthest radius
    sigma_deg: float = 8.0         # aerial landmark points: bearing kernel
    distance_sd: float = 1.0       # aerial landmark points: log-distance kernel (sd of ln d)
    d0_m: float = 200.0            # aerial landmark points: weight 1 / (1 + d / d0), 0 behind a building
    weighted: bool | None = None   # weigh each class and radius by -log of how often the aerial image shows it
                                   # [a mask: yes; points: no, their soft kernels have no such frequencies]
    min_prior: float = 0.01
    threads: int = 0               # chunks scored at once on threads; 0: one per core (the answer is the same)
    distinct_m: float = 50.0       # the best distinct alternative lies at least this far from the answer
    camera_heights: tuple[float, ...] = ()  # camera heights (m) to try when it is not known [the camera's own]
    tilt_deg: float = 0.0          # the camera may be tilted this much in pitch and roll: its tilt is read from
                                   # where the query's sky ends and its ground begins (localization.profile.horizon) [0: level]
    vista_weight: float = 0.0      # a query mask with a sky: the mass (in radii) of its vista cell, where the sky
                                   # comes down to the horizon and nothing stands (localization.profile.profiles)
                                   # [0: none; docs/localization.md measures 4]
    vista_m: float = 75.0          # how far an open horizon says nothing stands (beyond max_range_m, or no vista)
    vista_deg: float = 1.0         # how close to the horizon the sky must come down for that

    def __post_init__(self) -> None:
        if ((self.bins is not None and self.bins < 8) or self.radii < 1 or self.keep < 1 or (self.levels is not None and self.levels < 0)
                or self.top_k < 1 or self.chunk < 1 or self.threads < 0):
            raise ConfigError("profile method: bins >= 8, radii >= 1, keep >= 1, levels >= 0, top_k >= 1")
        if not (0 < self.min_range_m < self.max_range_m and (self.coarse_m is None or self.coarse_m > 0)):
            raise ConfigError("profile method: ranges must satisfy 0 < min < max and the grid spacing be > 0")
        if self.heading_deg is not None and not math.isfinite(self.heading_deg):
            raise ConfigError(f"heading must be a number of degrees or unknown, got {self.heading_deg}")
        if self.heading_prior_deg is not None and not math.isfinite(self.heading_prior_deg):
            raise ConfigError(f"heading prior must be a number of degrees, got {self.heading_prior_deg}")
        if not 0 < self.heading_within_deg <= 180:
            raise ConfigError(f"the heading's uncertainty must be 0-180 degrees, got {self.heading_within_deg:g}")
        if not 0 <= self.tilt_deg <= 10:
            raise ConfigError(f"camera tilt must be 0-10 degrees, got {self.tilt_deg:g}")
        if not (self.vista_weight >= 0 and self.vista_m > 0 and 0 < self.vista_deg <= 10):
            raise ConfigError("profile method: vista weight >= 0, vista distance > 0 m, vista angle 0-10 degrees")
        if any(not (0 < h < 100) for h in self.camera_heights):
            raise ConfigError(f"camera heights must be positive metres, got {self.camera_heights}")


class AerialIndex(Protocol):
    """What the search needs of the aerial side: its shape, resolution, classes and predicted profiles."""

    resolution_m: float
    classes: tuple[str, ...]
    grid_m: float       # the coarse grid spacing that suits it
    levels: int         # and the refinements
    weighted: bool      # whether class-frequency weights suit it
    min_confidence: float  # the "not sure" threshold that suits it (confidence: see the module docstring)
    min_kappa: float       # the "not in this image" threshold that suits it

    @property
    def shape(self) -> tuple[int, int]: ...

    def profiles(self, xy: np.ndarray, radii_m: np.ndarray, bins: int,
                 need: np.ndarray | None = None, *, vista: bool = False) -> tuple[np.ndarray, np.ndarray]: ...


@runtime_checkable
class RayIndex(AerialIndex, Protocol):
    """An aerial side whose rays name the class seen in each cell (a mask's, :class:`AerialMaskIndex`):
    the search then looks each predicted class up in the query instead of building one-hot profiles."""

    def labels(self, xy: np.ndarray, radii_m: np.ndarray, bins: int, *,
               vista: bool = False) -> tuple[np.ndarray, np.ndarray]: ...


def grid_positions(shape: tuple[int, int], spacing_px: float) -> np.ndarray:
    """Cell centres of a grid of ``spacing_px`` over an image of ``shape`` (rows, cols), as (x, y).

    >>> grid_positions((10, 20), 10).tolist()
    [[4.5, 4.5], [14.5, 4.5]]
    """
    h, w = shape
    xs = np.arange(spacing_px / 2 - 0.5, w - 0.5, spacing_px)
    ys = np.arange(spacing_px / 2 - 0.5, h - 0.5, spacing_px)
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


def score_positions(index: AerialIndex, query: QueryProfile, xy: np.ndarray, config: ProfileConfig,
                    prior: np.ndarray, weights: np.ndarray | None = None,
                    keep: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Best score and its azimuth shift (in bins) at each position ``xy`` (N, 2).

    A cell the aerial image cannot predict (its ray left the image) is credited with the
    agreement chance gives it, ``prior`` (C, R + 1) (:func:`class_prior`): a position near the
    border neither gains nor loses for what lies outside.

    ``keep`` (heading unknown, mask index): only the ``keep`` best positions are needed, so
    positions are scored in decreasing order of a rotation-free upper bound of their score
    (:func:`_bounds`) and the search stops once no remaining bound beats the ``keep``-th best
    score: the same ``keep`` best, exactly; the others get ``-inf``.
    """
    q = query.q.astype(np.float32)
    if weights is not None:
        q = q * weights[:, :, None].astype(np.float32)
    total = max(float(q.sum()), 1e-9)
    u = np.einsum("cra,cr->ra", q, prior.astype(np.float32))         # chance agreement per cell (R + 1, A)
    n = len(xy)
    best, shift = np.zeros(n), np.zeros(n)
    known = query.heading_deg is not None
    if not known:
        qf = np.conj(np.fft.rfft(q, axis=-1))
        uf = np.conj(np.fft.rfft(u, axis=-1))
    need = q.sum(axis=2) > 0
    if keep is not None and not known and isinstance(index, RayIndex) and not float(q[:, -1, :].sum()) and n > keep:
        return _pruned(index, query, xy, config, q, u, total, qf, uf, keep, need)
    gather = known and isinstance(index, RayIndex) and not float(q[:, -1, :].sum())
    if gather:  # one-hot profiles never built: look each predicted class up in the query
        n_r = len(query.radii_m)
        table = np.concatenate([q[:, :n_r, :], np.zeros((1, n_r, query.bins), np.float32)])  # class -1: row C
        cells = np.arange(n_r * query.bins).reshape(n_r, query.bins)
        u_seen = u[:n_r]

    def one(part: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        if gather:
            lab, valid = index.labels(part, query.radii_m, query.bins, vista=query.vista)  # type: ignore[attr-defined]
            lab = np.where(lab < 0, len(table) - 1, lab).astype(np.int64)
            num = table.reshape(len(table), -1)[lab.reshape(len(part), -1), cells.ravel()[None, :]].sum(axis=1)
            return (num + float(u.sum()) - (valid * u_seen[None]).sum(axis=(1, 2)) - float(u[n_r:].sum())) / total, None
        P, V = index.profiles(part, query.radii_m, query.bins, need, vista=query.vista)
        if known:
            return (np.einsum("ncra,cra->n", P, q) + float(u.sum()) - np.einsum("nra,ra->n", V, u)) / total, None
        return _rotations(P, V, qf, uf, u, total, query.bins, allowed_shifts(config, query.bins))

    for start, (b, s) in zip(range(0, n, config.chunk), _map(one, [xy[i:i + config.chunk] for i in range(0, n, config.chunk)],
                                                             config.threads)):
        best[start:start + len(b)] = b
        if s is not None:
            shift[start:start + len(b)] = s
    return best, shift


def score_poses(index: AerialIndex, query: QueryProfile, xy: np.ndarray, config: ProfileConfig,
                prior: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`score_positions` of the best of ``query.variants`` (camera heights) at each position:
    ``(score, shift, variant index)``. The aerial profiles of a chunk are built once for all of them."""
    variants = query.variants
    qs = np.stack([v.q for v in variants]).astype(np.float32)                     # (H, C, R + 1, A)
    if weights is not None:
        qs = qs * weights[None, :, :, None].astype(np.float32)
    totals = np.maximum(qs.sum(axis=(1, 2, 3)), 1e-9)                              # (H,)
    u = np.einsum("hcra,cr->hra", qs, prior.astype(np.float32))                   # (H, R + 1, A)
    known = query.heading_deg is not None
    allowed = allowed_shifts(config, query.bins)
    need = qs.sum(axis=(0, 3)) > 0
    if not known:
        qf, uf = np.conj(np.fft.rfft(qs, axis=-1)), np.conj(np.fft.rfft(u, axis=-1))
    # a mask's rays name the class seen in each cell: look it up in the queries, no one-hot profiles
    # (slot R is empty for a query mask, and so is its chance credit)
    lookup = isinstance(index, RayIndex) and not float(qs[:, :, -1, :].sum())
    n_r, bins = len(query.radii_m), query.bins
    rows_c, rows_r = np.nonzero(need[:, :n_r])
    by_class = [(c, np.ascontiguousarray(qs[:, c, :n_r, :].reshape(len(qs), -1).T))   # (R * A, H) per class
                for c in range(qs.shape[1]) if need[c, :n_r].any()]
    base = u.sum(axis=(1, 2))

    def looked_up(part: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        lab, valid = index.labels(part, query.radii_m, bins, vista=query.vista)  # type: ignore[attr-defined]
        if known:
            seen_as = lab.reshape(len(part), -1)
            num = np.zeros((len(part), len(qs)), np.float32)                                # (N, H)
            for c, table in by_class:  # the cells that see class c, times every height's query there
                num += (seen_as == c).astype(np.float32) @ table
            s = (num + base[None] - np.einsum("nra,hra->nh", valid.astype(np.float32), u[:, :n_r])) / totals[None]
            pose = s.argmax(axis=1)
            return s[np.arange(len(s)), pose], np.zeros(len(s)), pose
        onehot = (lab[:, rows_r, :] == rows_c[None, :, None].astype(lab.dtype)).astype(np.float32)   # (N, K, A)
        agree = np.einsum("nkf,hkf->nhf", np.fft.rfft(onehot, axis=-1), qf[:, rows_c, rows_r])
        seen = np.einsum("nrf,hrf->nhf", np.fft.rfft(valid.astype(np.float32), axis=-1), uf[:, :n_r])
        s = (np.fft.irfft(agree - seen, n=bins, axis=-1) + base[None, :, None]) / totals[None, :, None]
        pose = _within(s, allowed).max(axis=2).argmax(axis=1)
        best, shift = _peak(s[np.arange(len(s)), pose], allowed)
        return best, shift, pose

    def one(part: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if lookup:
            return looked_up(part)
        P, V = index.profiles(part, query.radii_m, query.bins, need, vista=query.vista)
        if known:
            s = (np.einsum("ncra,hcra->nh", P, qs) + u.sum(axis=(1, 2))[None]
                 - np.einsum("nra,hra->nh", V, u)) / totals[None]
            pose = s.argmax(axis=1)
            return s[np.arange(len(s)), pose], np.zeros(len(s)), pose
        agree = np.fft.irfft(np.einsum("ncrf,hcrf->nhf", np.fft.rfft(P, axis=-1), qf), n=query.bins, axis=-1)
        seen = np.fft.irfft(np.einsum("nrf,hrf->nhf", np.fft.rfft(V, axis=-1), uf), n=query.bins, axis=-1)
        s = (agree + u.sum(axis=(1, 2))[None, :, None] - seen) / totals[None, :, None]   # (N, H, A)
        pose = _within(s, allowed).max(axis=2).argmax(axis=1)
        best, shift = _peak(s[np.arange(len(s)), pose], allowed)
        return best, shift, pose

    chunk = max(1, config.chunk // max(1, len(variants) // 8))  # (N, H, A) stays near one chunk's profiles
    parts = _map(one, [xy[i:i + chunk] for i in range(0, len(xy), chunk)], config.threads)
    if not parts:
        return np.zeros(0), np.zeros(0), np.zeros(0, dtype=np.int64)
    return (np.concatenate([b for b, _, _ in parts]), np.concatenate([s for _, s, _ in parts]),
            np.concatenate([p for _, _, p in parts]))


def allowed_shifts(config: ProfileConfig, bins: int) -> np.ndarray | None:
    """The azimuth shifts (bins; shift ``k`` is heading ``k * 360 / bins``) an unknown heading may take:
    those within ``heading_within_deg`` of ``heading_prior_deg``, or None for all of them.

    >>> allowed_shifts(ProfileConfig(heading_deg=None, heading_prior_deg=350, heading_within_deg=10), 36).nonzero()
    (array([ 0, 34, 35]),)
    >>> allowed_shifts(ProfileConfig(heading_deg=None, heading_prior_deg=92.5, heading_within_deg=2), 72).nonzero()
    (array([18]),)
    >>> allowed_shifts(ProfileConfig(heading_deg=None), 36) is None
    True
    """
    if config.heading_prior_deg is None or config.heading_within_deg >= 180:
        return None
    off = (np.arange(bins) * 360.0 / bins - config.heading_prior_deg + 180.0) % 360.0 - 180.0
    allowed = np.abs(off) <= config.heading_within_deg + 1e-9
    allowed[int(np.abs(off).argmin())] = True  # a window narrower than a bin still holds the bin nearest the prior
    return allowed


def _within(s: np.ndarray, allowed: np.ndarray | None) -> np.ndarray:
    """``s`` (..., shifts) with the shifts not allowed at -inf, for picking the best allowed one."""
    return s if allowed is None else np.where(allowed, s, -np.inf)


def _rotations(P: np.ndarray, V: np.ndarray, qf: np.ndarray, uf: np.ndarray, u: np.ndarray, total: float,
               bins: int, allowed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Best score over the (allowed) azimuth shifts, and the shift (sub-bin), by circular cross-correlation."""
    agree = np.fft.irfft(np.einsum("ncrf,crf->nf", np.fft.rfft(P, axis=-1), qf), n=bins, axis=-1)
    seen = np.fft.irfft(np.einsum("nrf,rf->nf", np.fft.rfft(V, axis=-1), uf), n=bins, axis=-1)
    return _peak((agree + float(u.sum()) - seen) / total, allowed)


def _peak(s: np.ndarray, allowed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Each row's best score over the (allowed) shifts, and its shift refined to a fraction of a bin."""
    k = _within(s, allowed).argmax(axis=1)
    return s[np.arange(len(s)), k], k + _parabola(s, k)


def _bounds(lab: np.ndarray, valid: np.ndarray, q: np.ndarray, u: np.ndarray, total: float) -> np.ndarray:
    """An upper bound of each position's score over every rotation, from its class counts per radius.

    At any shift, class ``c`` at radius ``k`` agrees on at most ``min(sum_a q, n_c * max_a q)``
    (``n_c`` cells of the position show ``c``; each query cell weighs at most its maximum), and
    the chance credit of the cells the image cannot predict is at most
    ``min(sum_a u, n_invalid * max_a u)``.
    """
    n_r = lab.shape[1]
    q_sum, q_max = q[:, :n_r].sum(axis=2), q[:, :n_r].max(axis=2)        # (C, R)
    bound = np.zeros(len(lab))
    for c in range(q.shape[0]):
        if q_sum[c].any():
            count = (lab == c).sum(axis=2)                                  # (N, R)
            bound += np.minimum(q_sum[c][None], count * q_max[c][None]).sum(axis=1)
    invalid = (~valid).sum(axis=2)
    bound += np.minimum(u[:n_r].sum(axis=1)[None], invalid * u[:n_r].max(axis=1)[None]).sum(axis=1)
    return bound / total


def _pruned(index: Any, query: QueryProfile, xy: np.ndarray, config: ProfileConfig, q: np.ndarray, u: np.ndarray,
            total: float, qf: np.ndarray, uf: np.ndarray, keep: int, need: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`score_positions` for the ``keep`` best of many positions, best bounds first (see there)."""
    n = len(xy)
    starts = range(0, n, config.chunk)

    def bounds_of(part: np.ndarray) -> np.ndarray:
        lab, valid = index.labels(part, query.radii_m, query.bins, vista=query.vista)
        return _bounds(lab, valid, q, u, total)

    bound = np.concatenate(_map(bounds_of, [xy[i:i + config.chunk] for i in starts], config.threads))
    order = np.argsort(-bound, kind="stable")
    best, shift = np.full(n, -np.inf), np.zeros(n)

    # one-hot rows only where the query has mass (slot R has none on this path, so neither has u)
    n_r = len(query.radii_m)
    rows_c, rows_r = np.nonzero(need[:, :n_r])
    q_rows = qf[rows_c, rows_r]                                                   # (K, F)
    u_rows = np.flatnonzero(u[:n_r].any(axis=1))
    allowed = allowed_shifts(config, query.bins)  # the bounds hold over every shift, so over these too

    def rotations_of(part: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lab, valid = index.labels(xy[part], query.radii_m, query.bins, vista=query.vista)
        onehot = (lab[:, rows_r, :] == rows_c[None, :, None].astype(lab.dtype)).astype(np.float32)
        agree = np.einsum("nkf,kf->nf", np.fft.rfft(onehot, axis=-1), q_rows)
        seen = np.einsum("nrf,rf->nf", np.fft.rfft(valid[:, u_rows, :].astype(np.float32), axis=-1), uf[u_rows])
        return _peak((np.fft.irfft(agree - seen, n=query.bins, axis=-1) + float(u.sum())) / total, allowed)

    # a batch of chunks at a time, one per thread; then accepted chunk by chunk exactly as one
    # thread would: a chunk that starts below the keep-th best so far ends the search (within
    # float32 rounding of the FFT scores), and it and the rest of its batch stay -inf
    scored, batch, done = 0, _threads(config.threads), False
    for first in range(0, n, config.chunk * batch):
        parts = [order[i:i + config.chunk] for i in range(first, min(first + config.chunk * batch, n), config.chunk)]
        for part, (b, s) in zip(parts, _map(rotations_of, parts, config.threads)):
            if scored >= keep:
                kth = np.partition(best[order[:scored]], scored - keep)[scored - keep]
                if bound[part[0]] < kth - 1e-5:
                    done = True
                    break  # no later position can beat the keep-th best
            best[part], shift[part] = b, s
            scored += len(part)
        if done:
            break
    return best, shift


def class_prior(index: AerialIndex, query: QueryProfile, xy: np.ndarray, n: int = 512) -> np.ndarray:
    """How often each class is predicted at each radius (C, R + 1), over ``n`` evenly picked positions of ``xy``."""
    pick = xy[np.linspace(0, len(xy) - 1, min(n, len(xy))).astype(np.int64)]
    P, V = index.profiles(pick, query.radii_m, query.bins, vista=query.vista)
    return cast("np.ndarray", P.sum(axis=(0, 3)) / np.maximum(V.sum(axis=(0, 2)), 1.0)[None, :])


def _threads(threads: int) -> int:
    """How many threads ``threads`` means (0: one per core)."""
    return threads if threads > 0 else max(1, os.cpu_count() or 1)


T = TypeVar("T")
R = TypeVar("R")


def _map(fn: Callable[[T], R], items: list[T], threads: int) -> list[R]:
    """``[fn(x) for x in items]`` on ``threads`` threads (numpy's gathers, reductions and FFTs let go of
    the GIL), in order: the result does not depend on the thread count.

    While these threads run, the BLAS under numpy's matrix products runs on one thread in each
    (as scikit-learn limits it under its own threads): the products here are small, and BLAS
    threads of its own beside ours, waiting for work, took the cores they ran on. On 2 cores a
    region query over Kotka (``benchmarks/bench_region.py``) took twice the CPU and 1.9x the
    wall time without the limit, for the same answers.
    """
    n = min(_threads(threads), len(items))
    if n <= 1:
        return [fn(x) for x in items]
    with _blas_one_thread(), ThreadPoolExecutor(n) as pool:
        return list(pool.map(fn, items))


@functools.lru_cache(maxsize=1)
def _blas(modules: int) -> ThreadpoolController:
    """The BLAS libraries loaded, looked up again only when ``modules`` (how many modules are
    imported) changed: threadpoolctl inspects the process's libraries, a millisecond a time."""
    return ThreadpoolController()


def _blas_one_thread() -> Any:
    """A context in which every BLAS library loaded (numpy's, and torch's or scipy's when they are)
    runs on one thread: on the main thread only. The limit is the process's, and threadpoolctl
    lets one thread at a time set it; searches run on a caller's own threads leave BLAS alone,
    so that two of them at once cannot leave the process limited when they are done."""
    if threading.current_thread() is not threading.main_thread():
        return contextlib.nullcontext()
    return _blas(len(sys.modules)).limit(limits=1, user_api="blas")


def _parabola(s: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Sub-bin offset of each row's peak at ``k`` from a parabola through its neighbours (circular)."""
    a = s.shape[1]
    rows = np.arange(len(s))
    y0, y1, y2 = s[rows, (k - 1) % a], s[rows, k], s[rows, (k + 1) % a]
    den = y0 - 2 * y1 + y2
    return np.where(np.abs(den) > 1e-12, np.clip(0.5 * (y0 - y2) / np.where(den == 0, 1, den), -0.5, 0.5), 0.0)

