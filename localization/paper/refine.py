"""The dissertation's window hierarchy (eq. 3.8 of T. Resek's dissertation).

:func:`localize_hierarchical` localizes with the aerial windows 400 -> 200 -> 100 px
(:data:`~localization.paper.config.HIERARCHY`) in turn and multiplies each fine candidate's
posterior by the best one it inherits from the coarser level (:func:`inherit`). The other
refinement, edges removed between look-alike landmarks, is :mod:`localization.paper.edges`.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import cast

import numpy as np

from localization.common.landmarks import Landmarks
from localization.common.result import answered
from localization.paper.config import PaperConfig
from localization.paper.match import Localization, localize

logger = logging.getLogger(__name__)

__all__ = ["inherit", "localize_hierarchical"]


def inherit(fine: np.ndarray, coarse: np.ndarray, coarse_scores: np.ndarray, coarse_window: int) -> np.ndarray:
    """For each fine centre, the best score among coarse candidates whose window contains it.

    A coarse window of side ``w`` centred at ``c`` covers ``[c - w/2, c + w/2]`` in x and y
    (bounds included, as the covisibility windows). A centre no coarse window contains gets 0.

    >>> inherit(np.array([[10.0, 10.0], [90.0, 10.0]]), np.array([[0.0, 0.0], [20.0, 20.0]]), np.array([0.2, 0.7]), 20)
    array([0.7, 0. ])
    """
    if len(fine) == 0 or len(coarse) == 0:
        return np.zeros(len(fine))
    inside = np.all(np.abs(fine[:, None, :] - coarse[None, :, :]) <= coarse_window / 2.0 + 1e-9, axis=2)
    return cast("np.ndarray", np.where(inside, coarse_scores[None, :], 0.0).max(axis=1))


def localize_hierarchical(aerial: Landmarks, query: Landmarks, config: PaperConfig = PaperConfig(), *,
                          aerial_drop: np.ndarray | None = None, query_drop: np.ndarray | None = None
                          ) -> Localization:
    """Eq. 3.8: localize with each aerial window in turn (coarse to fine) and multiply probabilities.

    Level 0 scores are its posteriors. A candidate of level ``l`` scores its own posterior
    times the score it inherits from level ``l-1``: the best among the coarser candidates
    whose window contains its centre (:func:`inherit`), 0 when none does. Refinement stops at
    the last level that is answered and leaves some candidate with a non-zero score (finer
    windows may be too small to hold every query class); the result is that level's
    candidates with the combined scores, and ``levels`` keeps every level's own result.
    """
    levels: list[Localization] = []
    best: Localization | None = None
    for w in config.windows:
        level = localize(aerial, query, replace(config, window=int(w)), aerial_drop=aerial_drop, query_drop=query_drop)
        levels.append(level)
        if level.unanswered:
            break
        if best is None:
            best = level
            continue
        scores = level.posteriors * inherit(level.candidates, best.candidates, best.posteriors, best.window)
        if not scores.any():
            logger.info("hierarchical: no %d px candidate inside a %d px one; stopping", w, best.window)
            break
        best = answered(level.candidates, level.likelihoods, scores, config.top_k, relevant=level.relevant,
                        clique_likelihoods=level.clique_likelihoods,
                        window=level.window, query_window=level.query_window, p=config.p, n_cliques=level.n_cliques)
    if best is None:
        return Localization(**{**levels[0].__dict__, "levels": tuple(levels)})
    return Localization(**{**best.__dict__, "levels": tuple(levels)})

