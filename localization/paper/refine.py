"""The dissertation's refinements of the matching: a window hierarchy, and edges removed by features.

* :func:`localize_hierarchical` -- eq. 3.8 of T. Resek's dissertation: localize with the
  aerial windows 400 -> 200 -> 100 px (:data:`~localization.paper.config.HIERARCHY`) in turn and multiply each fine
  candidate's posterior by the best one it inherits from the coarser level (:func:`inherit`).
* :func:`feature_edge_mask` -- §5.3.2: graph edges between landmarks whose image features
  (a network's encoder, optionally reduced by PCA or UMAP) are closer than a threshold ``T``
  are removed; pass the mask as ``aerial_drop``/``query_drop`` to
  :func:`~localization.paper.match.localize`. :mod:`localization.paper.features` computes the features.
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
from osmseg.errors import ConfigError

logger = logging.getLogger(__name__)

__all__ = ["MAX_FEATURE_LANDMARKS", "feature_edge_mask", "inherit", "localize_hierarchical"]

#: Landmarks above which the K x K feature distances (8 bytes each) are refused: 10,000 is 800 MB.
MAX_FEATURE_LANDMARKS = 10_000


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


def feature_edge_mask(features: np.ndarray, threshold: float, *, metric: str = "euclidean",
                      reduce: str | None = None, components: int = 8, seed: int = 0) -> np.ndarray:
    """§5.3.2: landmark pairs whose image features are closer than ``threshold`` lose their edge.

    ``features`` is ``(K, d)``, one vector per landmark (e.g. a segmentation network's encoder
    output averaged over the landmark's pixels): two landmarks that look alike (two parts of
    one building) carry little information together. ``reduce`` first projects the features
    to ``components`` dimensions: "pca" (centred SVD) or "umap" (needs ``umap-learn``).
    ``metric`` is "euclidean" or "cosine" (``1 -`` cosine similarity). Returns ``(K, K)`` bool,
    symmetric, False on the diagonal: pass it as ``aerial_drop``/``query_drop``.

    >>> feature_edge_mask(np.array([[0.0, 0.0], [0.0, 0.1], [5.0, 5.0]]), 0.5).astype(int).tolist()
    [[0, 1, 0], [1, 0, 0], [0, 0, 0]]
    """
    x = np.asarray(features, dtype=np.float64)
    if x.ndim != 2 or not np.isfinite(x).all():
        raise ConfigError(f"features must be a finite (K, d) array, one row per landmark; got shape {x.shape}")
    if len(x) > MAX_FEATURE_LANDMARKS:  # K x K distances, 8 bytes each
        raise ConfigError(f"{len(x):,} landmarks are too many for feature edges (a {len(x):,}² distance matrix): "
                          f"keep at most {MAX_FEATURE_LANDMARKS:,} (a larger --min-size, --mode centroid)")
    if reduce == "pca":
        centred = x - x.mean(axis=0)
        u, sv, _ = np.linalg.svd(centred, full_matrices=False)
        x = u[:, :components] * sv[:components]
    elif reduce == "umap":
        try:
            import umap
        except ImportError:
            raise ConfigError("reduce='umap' needs umap-learn: pip install umap-learn (or use 'pca')") from None
        x = umap.UMAP(n_components=components, random_state=seed).fit_transform(x)
    elif reduce is not None:
        raise ConfigError(f"reduce must be None, 'pca' or 'umap', got {reduce!r}")
    if metric == "euclidean":
        sq = (x * x).sum(axis=1)
        dist = np.sqrt(np.maximum(sq[:, None] + sq[None, :] - 2 * x @ x.T, 0.0))
    elif metric == "cosine":
        norm = np.linalg.norm(x, axis=1)
        unit = np.divide(x, norm[:, None], out=np.zeros_like(x), where=norm[:, None] > 0)
        dist = 1.0 - unit @ unit.T
    else:
        raise ConfigError(f"metric must be 'euclidean' or 'cosine', got {metric!r}")
    close = dist < threshold
    np.fill_diagonal(close, False)
    return cast("np.ndarray", close)
