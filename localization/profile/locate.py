"""The profile method's search, coarse to fine, and how sure its answer is.

Positions every ``coarse_m`` metres are scored (:func:`~localization.profile.search.score_positions`,
or :func:`~localization.profile.search.score_poses` over unknown camera heights), then around
the ``keep`` best ones a 3 x 3 grid a third as wide, ``levels`` times (4 m -> 1.3 m -> 0.44 m by
default). :class:`Scoring` holds what every level is scored with (the grid, the class
frequencies and weights). The answer's kappa says whether the query is in the image at all, and
its confidence whether a look-alike place 50 m or more away fits as well (the best distinct
alternative): :mod:`localization.profile.search`'s docstring gives the formulas.

Imports: numpy, osmseg core, localization.common.result and the profile wing's own modules.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from localization.common.result import Localization, unanswered
from localization.profile.profiles import QueryProfile, without_vista
from localization.profile.search import (
    AerialIndex,
    ProfileConfig,
    RayIndex,
    class_prior,
    grid_positions,
    score_poses,
    score_positions,
)
from osmseg.errors import ConfigError

__all__ = ["Scoring", "localize_profile"]


def _level(query: QueryProfile) -> bool:
    """Whether ``query`` was read as a level camera's (its pose's pitch and roll 0, or no pose)."""
    return query.pose is None or query.pose[1:] == (0.0, 0.0)


def _nms(xy: np.ndarray, order: np.ndarray, radius: float, k: int) -> list[int]:
    """The first ``k`` of ``order`` that are at least ``radius`` from every one kept before them.

    Kept positions are filed in cells ``radius`` wide, so each is compared only with those of
    the 3 x 3 cells around it (the same answer as comparing with all of them).

    >>> _nms(np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0], [3.5, 0.0]]), np.arange(4), 2.0, 3)
    [0, 2]
    """
    kept: list[int] = []
    cells: dict[tuple[int, int], list[int]] = {}
    for i in order:
        x, y = float(xy[i, 0]), float(xy[i, 1])
        cx, cy = math.floor(x / radius), math.floor(y / radius)
        if all(math.hypot(x - xy[j, 0], y - xy[j, 1]) >= radius
               for dx in (-1, 0, 1) for dy in (-1, 0, 1) for j in cells.get((cx + dx, cy + dy), ())):
            kept.append(int(i))
            cells.setdefault((cx, cy), []).append(int(i))
            if len(kept) == k:
                break
    return kept


def _around(xy: np.ndarray, spacing: float, shape: tuple[int, int]) -> np.ndarray:
    """A 3 x 3 grid of ``spacing`` around each of ``xy``, without duplicates, inside an image of ``shape``."""
    h, w = shape
    offsets = np.array([(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1)], dtype=np.float64) * spacing
    cand = np.unique(np.round((xy[:, None, :] + offsets[None]).reshape(-1, 2), 6), axis=0)
    return cand[(cand[:, 0] >= -0.5) & (cand[:, 0] < w - 0.5) & (cand[:, 1] >= -0.5) & (cand[:, 1] < h - 0.5)]


@dataclass(frozen=True)
class Scoring:
    """What every level of one query's search shares: the aerial side, the query, its settings,
    the class frequencies it is compared with and weighed by, the coarse grid spacing (m) and the
    number of refinements. :meth:`of` makes it as :func:`localize_profile` does, so a benchmark
    scores any positions exactly as the search would (benchmarks/bench_ceiling.py)."""

    index: AerialIndex
    query: QueryProfile
    config: ProfileConfig
    mean: np.ndarray
    weights: np.ndarray | None
    levels: int
    coarse_m: float

    @classmethod
    def of(cls, index: AerialIndex, query: QueryProfile, config: ProfileConfig,
           prior: np.ndarray | None = None) -> Scoring:
        """The settings' or else the aerial side's grid, refinements and weighting; the class
        frequencies ``prior``, or else this image's over the coarse grid (:func:`class_prior`)."""
        if query.vista and not isinstance(index, RayIndex):  # points cannot say that nothing stands
            if prior is not None and prior.shape[1] == query.q.shape[1]:
                prior = np.delete(prior, len(query.radii_m) - 1, axis=1)
            query = without_vista(query)
        coarse_m = config.coarse_m if config.coarse_m is not None else index.grid_m
        weighted = config.weighted if config.weighted is not None else index.weighted
        mean = (class_prior(index, query, grid_positions(index.shape, coarse_m / index.resolution_m))
                if prior is None else prior)
        return cls(index, query, config, mean, -np.log(np.clip(mean, config.min_prior, 1.0)) if weighted else None,
                   config.levels if config.levels is not None else index.levels, coarse_m)

    @property
    def finest_px(self) -> float:
        """The spacing (pixels) of the finest level's positions."""
        return float(self.coarse_m / 3 ** self.levels / self.index.resolution_m)

    def score(self, xy: np.ndarray, keep: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(score, shift, pose)`` at positions ``xy``: the best camera pose at each when the query has several."""
        if self.query.variants:  # each position scored with the camera pose that fits it best
            return score_poses(self.index, self.query, xy, self.config, self.mean, self.weights)
        score, shift = score_positions(self.index, self.query, xy, self.config, self.mean, self.weights, keep=keep)
        return score, shift, np.zeros(len(xy), dtype=np.int64)

    def refine(self, xy: np.ndarray, score: np.ndarray, shift: np.ndarray, pose: np.ndarray, keep: int,
               spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Around the ``keep`` best of ``xy``, a 3 x 3 grid a third as wide, ``levels`` times."""
        for _ in range(self.levels):
            top = np.argsort(-score, kind="stable")[:keep]
            spacing /= 3.0
            xy = _around(xy[top], spacing, self.index.shape)
            if self.query.variants:
                score, shift, pose = self.score(xy)
            else:
                score, shift, _ = self.score(xy)
        return xy, score, shift, pose


def _heading_at(query: QueryProfile, shifts: np.ndarray | None, i: int) -> float:
    """The heading (degrees) at place ``i``: the given one, or its best azimuth shift (in bins)."""
    if query.heading_deg is not None or shifts is None:
        return round(float(query.heading_deg or 0.0), 3) % 360.0
    return round(float(shifts[i] * 360.0 / query.bins) % 360.0, 3) % 360.0


def _alternative(s: Scoring, coarse: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], answer: np.ndarray,
                 coarse_m: float, spacing: float) -> tuple[tuple[float, float, float] | None, float | None]:
    """The best distinct alternative ``((x, y, score), heading)``: the best place at least ``distinct_m``
    from ``answer``, found among the 5 best spaced coarse positions that far away and refined as the
    answer was; ``(None, None)`` when no place lies that far."""
    coarse_xy, coarse_score, coarse_shift, coarse_poses = coarse
    resolution = s.index.resolution_m
    far = np.hypot(*(coarse_xy - answer).T) * resolution >= s.config.distinct_m
    if not (far.any() and np.isfinite(coarse_score[far]).any()):
        return None, None
    rivals = np.flatnonzero(far)[_nms(coarse_xy[far], np.argsort(-coarse_score[far], kind="stable"),
                                      coarse_m / resolution, 5)]
    rivals = rivals[np.isfinite(coarse_score[rivals])]
    r_xy, r_score, r_shift, _ = s.refine(coarse_xy[rivals], coarse_score[rivals], coarse_shift[rivals],
                                         coarse_poses[rivals], len(rivals), spacing)
    r_far = np.hypot(*(r_xy - answer).T) * resolution >= s.config.distinct_m
    if not r_far.any():
        return None, None
    i = int(np.flatnonzero(r_far)[np.argmax(r_score[r_far])])
    return (float(r_xy[i, 0]), float(r_xy[i, 1]), float(r_score[i])), _heading_at(s.query, r_shift, i)


def _gated(result: Localization, kappa: float, confidence: float, config: ProfileConfig, index: AerialIndex,
           answer: np.ndarray) -> Localization:
    """``result`` left unanswered when its ``kappa`` says "not in this image" or its ``confidence`` "not
    sure" (both unrounded: the result holds them rounded)."""
    min_kappa = config.min_kappa if config.min_kappa is not None else index.min_kappa
    if kappa < min_kappa:
        return replace(result, unanswered=True, map_xy=None,
                       reason=f"not in this image: kappa {kappa:.3f} is below {min_kappa:g}")
    threshold = config.min_confidence if config.min_confidence is not None else index.min_confidence
    if confidence < threshold:
        where = ""
        if result.alternative is not None:
            away = math.hypot(result.alternative[0] - answer[0], result.alternative[1] - answer[1]) * index.resolution_m
            where = f" (another place {away:.0f} m away fits almost as well)"
        return replace(result, unanswered=True, map_xy=None,
                       reason=f"not sure: confidence {confidence:.3f} is below {threshold:g}{where}")
    return result


def localize_profile(index: AerialIndex, query: QueryProfile, config: ProfileConfig,
                     prior: np.ndarray | None = None,
                     within: tuple[float, float, float, float] | None = None) -> Localization:
    """Where ``query`` was taken in the aerial ``index``: the ``profile`` method's answer.

    The result is a :class:`~localization.common.result.Localization` whose candidates are the
    positions of the finest level, ``likelihoods`` and ``posteriors`` their scores, ``top_k``
    distinct places (at least one coarse cell apart), ``heading_deg`` the estimated (or given)
    heading and ``confidence`` the kappa of the best match. ``prior``: the class frequencies
    (:func:`class_prior`) to weigh and to compare with, when they should be another area's than
    this image's (a region searched in blocks scores every block against the region's).
    ``within`` (pixels ``x0, y0, x1, y1``): only the coarse positions inside this box are searched; the
    rays still read the whole image (a region's block is searched in its core alone). The best
    distinct alternative, and so the confidence, are then the box's: a look-alike outside it is
    another search's to find (the region ranks every block's candidates together).
    """
    if tuple(index.classes) != tuple(query.classes):
        raise ConfigError(f"aerial classes {index.classes} and query classes {query.classes} differ: use landmark "
                          "dictionaries with the same landmark classes")
    if query.mass <= 0:
        return unanswered("the query shows no landmark class on the ground rows or at any azimuth", method="profile")
    s = Scoring.of(index, query, config, prior)
    query, coarse_m, mean = s.query, s.coarse_m, s.mean
    spacing = coarse_m / index.resolution_m
    xy = grid_positions(index.shape, spacing)
    if within is not None:
        x0, y0, x1, y1 = within
        xy = xy[(xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1)]
        if not len(xy):
            return unanswered(f"no position of the {coarse_m:g} m grid lies within {within}", method="profile")
    score, shift, poses = s.score(xy, keep=config.keep)
    coarse = (xy, score, shift, poses)
    xy, score, shift, poses = s.refine(xy, score, shift, poses, config.keep, spacing)
    order = np.lexsort((xy[:, 0], xy[:, 1], -score))
    best = int(order[0])
    pose_query = query.variants[int(poses[best])] if query.variants else query
    alternative, alternative_heading = _alternative(s, coarse, xy[best], coarse_m, spacing)
    qw = pose_query.q.sum(axis=2) * (s.weights if s.weights is not None else 1.0)
    chance = float((qw * mean).sum() / max(qw.sum(), 1e-9))
    kappa = (float(score[best]) - chance) / max(1e-9, 1.0 - chance)
    lead = float(score[best]) - chance
    confidence = (kappa if alternative is None
                  else min(1.0, max(0.0, (float(score[best]) - alternative[2]) / lead)) if lead > 0 else 0.0)
    picked = _nms(xy, order, coarse_m / index.resolution_m, config.top_k)
    top_k = tuple((float(xy[i, 0]), float(xy[i, 1]), float(score[i])) for i in picked)
    ties = int(np.isclose(score, score[best], rtol=1e-9, atol=1e-12).sum())
    result = Localization(candidates=xy, likelihoods=score, posteriors=score, order=order.astype(np.int64),
                          top_k=top_k, map_xy=(top_k[0][0], top_k[0][1]), ties=ties, unanswered=False,
                          method="profile", heading_deg=_heading_at(query, shift, best),
                          confidence=round(confidence, 4), kappa=round(kappa, 4), chance=round(chance, 4),
                          alternative=alternative,
                          camera_pose=pose_query.pose if query.variants or not _level(query) else None,
                          headings=tuple(_heading_at(query, shift, i) for i in picked),
                          alternative_heading=alternative_heading)
    return _gated(result, kappa, confidence, config, index, xy[best])
