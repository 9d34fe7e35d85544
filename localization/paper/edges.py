"""§5.3.2 of the dissertation: graph edges removed between landmarks that look alike.

Two landmarks whose image features (a network's encoder output, optionally reduced by PCA or
UMAP) are closer than a threshold ``T`` carry little information together (two parts of one
building): :func:`feature_edge_mask` marks those pairs, and the matching
(:func:`~localization.paper.match.localize`'s ``aerial_drop``/``query_drop``) removes their
edges. :mod:`localization.paper.features` computes the features.

Imports: numpy, osmseg.errors.
"""

from __future__ import annotations

from typing import cast

import numpy as np

from osmseg.errors import ConfigError

__all__ = ["MAX_FEATURE_LANDMARKS", "feature_edge_mask"]


#: Landmarks above which the K x K feature distances (8 bytes each) are refused: 10,000 is 800 MB.
MAX_FEATURE_LANDMARKS = 10_000


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
                          f"keep at most {MAX_FEATURE_LANDMARKS:,} (a larger --min-size, --landmark-mode centroid)")
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
