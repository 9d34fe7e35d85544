"""Where was the query taken? Matching the query's landmark graph to sub-graphs of the aerial one.

This is section 3.2 of T. Resek's dissertation and section II of Verde, Resek, Milani & Rocha,
"Ground-to-Aerial Viewpoint Localization via Landmark Graphs Matching" (IEEE SPL 2020); where
the text leaves a choice open we follow the authors' MATLAB code (``virtualLocations.m``,
``classAdjacencyMatrix.m``, ``bayesianProbabilities.m``). Steps, for an aerial clique matrix
``C`` (M cliques x K landmarks, from :mod:`localization.graph`) and a query graph:

1. **Relevant cliques.** An inverted index maps each landmark class to the cliques holding a
   landmark of that class; the relevant cliques are the intersection of the lists of every
   class seen in the query (:func:`inverted_index`, :func:`relevant_cliques`).
2. **Candidates** (the paper's "virtual locations"). Each relevant clique ``C_i`` is extended
   with every clique ``C_j`` (``j = i`` included) sharing at least a fraction ``p`` of its
   landmarks: ``|C_i ⊙ C_j|_0 / |C_i|_0 >= p`` (``>=`` as the authors' code). The candidate's
   graph is the *union of the complete graphs of those cliques*: two landmarks are joined when
   some included clique holds both (the authors' ``H(E^T E)``), not every pair of the union of
   their landmarks. Its position is the window centre of ``C_i``
   (:attr:`Cliques.centers <localization.graph.Cliques.centers>`).
3. **Class adjacency** (Algorithm 1): ``W[a, b]`` = number of edges ``{i, j}`` (``i < j``) joining
   a landmark of class ``a`` to one of class ``b``, divided by the number of edges; mirrored so
   ``W`` is symmetric and its lower triangle (diagonal included) sums to 1. A graph with no
   edge has ``W = 0`` (:func:`class_adjacency`). The query's ``W`` is that of its whole graph.
4. **Likelihood** (eq. 3.3): normalised cross-correlation of the lower triangles, diagonal
   included, uncentred as in the paper and the authors' code (:func:`likelihood`):
   ``P(Z|L) = sum_{u>=v} Wq[u,v] Wc[u,v] / sqrt(sum Wq[u,v]^2 * sum Wc[u,v]^2)``, in [0, 1]
   because every ``W >= 0``; 0 when either matrix is all zero (nothing to correlate).
5. **Posterior** (eqs. 3.4-3.6) with a uniform prior over the N candidates (:func:`posteriors`).
   When every likelihood is 0 nothing points anywhere: the result is "unanswered".
6. **Ranking**: MAP and top-k. Candidates whose posteriors agree within ``TIE_RTOL`` of the
   best are tied and counted. Extension makes ties common: in a group of cliques that are all
   subsets of one clique, every member extends to the same graph. Ties are broken by the
   likelihood of the candidate's own clique before extension (how well the window alone
   matches), then by raster order of the centres (:func:`rank`).

:func:`localize_hierarchical` repeats this with windows 400 -> 200 -> 100 and multiplies the
probabilities (eq. 3.8). :func:`feature_edge_mask` gives the dissertation's §5.3.2 option: edges
between landmarks whose image features are closer than T are removed from the graphs
(``aerial_drop``/``query_drop``); computing the features (a network's encoder) is the caller's.
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import sparse

from localization.graph import Cliques, cliques_fast, cliques_reference, window_size_auto
from localization.landmarks import Landmarks
from osmseg.errors import ConfigError

logger = logging.getLogger(__name__)

__all__ = [
    "DEFAULT_P", "HIERARCHY", "Localization", "class_adjacency", "extend_cliques", "feature_edge_mask",
    "inverted_index", "likelihood", "localize", "localize_hierarchical", "match_cliques", "posteriors", "rank",
    "relevant_cliques",
]

#: The covisibility parameter p of the candidate extension (the paper's value).
DEFAULT_P = 0.5
#: The dissertation's hierarchy of aerial windows, coarse to fine (pixels).
HIERARCHY = (400, 200, 100)
#: Scores within this relative (or absolute) distance of the best one count as tied with it.
TIE_RTOL = 1e-9
TIE_ATOL = 1e-12
#: Relevant cliques whose overlaps are computed at once (bounds memory to CHUNK x M floats).
CHUNK = 512


# --------------------------------------------------------------------------- classes


def shared_classes(aerial: Landmarks, query: Landmarks) -> tuple[str, ...]:
    """The class names both graphs are compared over: the aerial's, then any the query adds.

    The aerial and query landmarks may come from different class dictionaries (an aerial
    mask and a CamVid-like ground mask) that name the same landmark classes in another order.
    """
    return tuple(aerial.classes) + tuple(c for c in query.classes if c not in aerial.classes)


def class_indices(lm: Landmarks, classes: Sequence[str]) -> np.ndarray:
    """Each landmark's class as an index into ``classes`` (which must hold all of ``lm.classes``)."""
    pos = {name: i for i, name in enumerate(classes)}
    missing = [c for c in lm.classes if c not in pos]
    if missing:
        raise ConfigError(f"landmark classes {missing} are not among {list(classes)}")
    lut = np.array([pos[c] for c in lm.classes], dtype=np.int64)
    return lut[np.asarray(lm.cls, dtype=np.int64)] if len(lut) else np.zeros(0, dtype=np.int64)


# --------------------------------------------------------------------------- candidates


def inverted_index(members: np.ndarray, cls: np.ndarray, n_classes: int) -> list[np.ndarray]:
    """For each class, the sorted indices of the cliques that hold a landmark of that class.

    >>> members = np.array([[1, 1, 0], [0, 1, 1], [0, 0, 1]], bool)
    >>> [ix.tolist() for ix in inverted_index(members, np.array([0, 1, 1]), 3)]
    [[0], [0, 1, 2], []]
    """
    c = members if sparse.issparse(members) else _sparse(members)
    onehot = sparse.csr_matrix((np.ones(len(cls)), (np.arange(len(cls)), cls)), shape=(len(cls), n_classes))
    has = (c @ onehot).tocsc()  # (M, n_classes): how many landmarks of each class a clique holds
    return [np.sort(has.indices[has.indptr[k]:has.indptr[k + 1]]) for k in range(n_classes)]


def relevant_cliques(index: Sequence[np.ndarray], query_classes: Sequence[int]) -> np.ndarray:
    """Cliques holding every class in ``query_classes``: the intersection of their index lists.

    >>> relevant_cliques([np.array([0, 2]), np.array([0, 1, 2]), np.array([])], [0, 1]).tolist()
    [0, 2]
    >>> relevant_cliques([np.array([0, 2]), np.array([0, 1, 2]), np.array([])], [0, 2]).tolist()
    []
    """
    if len(query_classes) == 0:
        return np.zeros(0, dtype=np.int64)
    lists = [np.asarray(index[c], dtype=np.int64) for c in query_classes]
    return functools.reduce(np.intersect1d, lists).astype(np.int64)


def _sparse(members: np.ndarray) -> sparse.csr_matrix:
    """The clique matrix as a sparse ``(M, K)`` float matrix (cliques hold few of the K landmarks)."""
    return sparse.csr_matrix(np.asarray(members, dtype=bool), dtype=np.float64)


def _extension(c: sparse.csr_matrix, rows: np.ndarray, p: float) -> sparse.csr_matrix:
    """``(len(rows), M)`` 0/1: clique ``j`` shares at least ``p`` of the landmarks of clique ``rows[r]``."""
    sizes = np.asarray(c[rows].sum(axis=1)).ravel()
    overlap = (c[rows] @ c.T).tocoo()  # exact: counts are small integers
    keep = overlap.data >= p * sizes[overlap.row] - 1e-9
    return sparse.csr_matrix((np.ones(int(keep.sum())), (overlap.row[keep], overlap.col[keep])),
                             shape=(len(rows), c.shape[0]))


def extend_cliques(members: np.ndarray, relevant: np.ndarray, p: float = DEFAULT_P) -> list[np.ndarray]:
    """For each relevant clique ``C_i``, the cliques ``C_j`` with ``|C_i ⊙ C_j|_0 / |C_i|_0 >= p``.

    ``C_i`` itself is always included (its ratio is 1). The comparison allows 1e-9 of rounding,
    so ``p = 2/3`` accepts an overlap of exactly two landmarks out of three.

    >>> members = np.array([[1, 1, 0, 1, 0, 0], [0, 1, 1, 1, 0, 0], [0, 0, 0, 1, 1, 1]], bool)
    >>> [e.tolist() for e in extend_cliques(members, np.array([0, 1, 2]), 0.5)]
    [[0, 1], [0, 1], [2]]
    """
    c = _sparse(members)
    out: list[np.ndarray] = []
    for start in range(0, len(relevant), CHUNK):
        ext = _extension(c, np.asarray(relevant[start:start + CHUNK], dtype=np.int64), p)
        out.extend(np.sort(ext.indices[ext.indptr[r]:ext.indptr[r + 1]]) for r in range(ext.shape[0]))
    return out


# --------------------------------------------------------------------------- matching
#
# A class adjacency matrix is symmetric, so the work is done on its lower triangle (diagonal
# included) flattened in ``np.tril_indices`` order: T = n (n + 1) / 2 class pairs.


def _dedupe(codes: np.ndarray, bound: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(codes, return_inverse=True)`` for integers in ``[0, bound)``, by a lookup table when small.

    >>> [a.tolist() for a in _dedupe(np.array([7, 3, 7, 1]), 10)]
    [[1, 3, 7], [2, 1, 2, 0]]
    """
    if bound > 1 << 24:  # a table of this many entries would cost more than sorting
        values, inverse = np.unique(codes, return_inverse=True)
        return values, inverse.ravel()
    present = np.zeros(bound, dtype=bool)
    present[codes] = True
    rank_of = np.cumsum(present) - 1
    return np.flatnonzero(present), rank_of[codes]


@dataclass(frozen=True)
class _EdgeTable:
    """Every edge of a clique matrix's graph, the cliques holding it, and its class pair.

    Sparse, because a clique holds few landmarks: ``holders`` has one entry per (clique, pair
    of its landmarks), and counting a candidate's edges costs what its cliques' pairs number.
    """

    holders: sparse.csr_matrix  # (M, E): clique m holds both ends of edge e
    pairs: sparse.csr_matrix    # (E, T): edge e joins the class pair t (lower-triangle index)

    @classmethod
    def build(cls, c: sparse.csr_matrix, cls_idx: np.ndarray, n_classes: int,
              drop: np.ndarray | None = None) -> "_EdgeTable":
        """``drop``: optional ``(K, K)`` bool, landmark pairs whose edge is removed (:func:`feature_edge_mask`)."""
        if drop is not None and np.shape(drop) != (c.shape[1], c.shape[1]):
            raise ConfigError(f"an edge mask must be ({c.shape[1]}, {c.shape[1]}) for {c.shape[1]} landmarks, "
                              f"got {np.shape(drop)}")
        c = c.tocsr()
        c.sort_indices()
        k = c.shape[1]
        sizes = np.diff(c.indptr)
        clique_of, code_of = [], []
        for size in np.unique(sizes[sizes >= 2]):  # cliques of one size: a rectangular block of indices
            rows = np.flatnonzero(sizes == size)
            lm = c.indices[c.indptr[rows][:, None] + np.arange(size)]  # (n, size), sorted per row
            i, j = np.triu_indices(int(size), k=1)
            a, b = lm[:, i].ravel(), lm[:, j].ravel()
            keep = np.ones(len(a), dtype=bool) if drop is None else ~np.asarray(drop, dtype=bool)[a, b]
            clique_of.append(np.repeat(rows, len(i))[keep])
            code_of.append(a[keep].astype(np.int64) * k + b[keep])  # pair (a < b) as a*K + b
        t = n_classes * (n_classes + 1) // 2
        if not code_of or not sum(len(x) for x in code_of):
            return cls(sparse.csr_matrix((c.shape[0], 0)), sparse.csr_matrix((0, t)))
        codes, edge_of = _dedupe(np.concatenate(code_of), k * k)
        holders = sparse.csr_matrix((np.ones(len(edge_of)), (np.concatenate(clique_of), edge_of.ravel())),
                                    shape=(c.shape[0], len(codes)))
        tri = np.full((n_classes, n_classes), -1, dtype=np.int64)
        tri[np.tril_indices(n_classes)] = np.arange(t)
        a, b = cls_idx[codes // k], cls_idx[codes % k]
        pair = tri[np.maximum(a, b), np.minimum(a, b)]
        pairs = sparse.csr_matrix((np.ones(len(codes)), (np.arange(len(codes)), pair)), shape=(len(codes), t))
        return cls(holders, pairs)

    def counts(self, include: sparse.spmatrix) -> np.ndarray:
        """``(N, T)`` edge counts per class pair of the graphs made by the cliques ``include`` (N, M)."""
        has_edge = (sparse.csr_matrix(include) @ self.holders).tocsr()  # (N, E): how many cliques hold it
        has_edge.data[:] = 1.0  # an edge counts once however many cliques hold it (the H of H(E^T E))
        return np.asarray((has_edge @ self.pairs).todense(), dtype=np.float64)


def _normalise(counts: np.ndarray) -> np.ndarray:
    """Rows of edge counts divided by their sums (rows without edges stay 0)."""
    total = counts.sum(axis=-1, keepdims=True)
    return np.divide(counts, total, out=np.zeros_like(counts), where=total > 0)


def _symmetric(lower: np.ndarray, n: int) -> np.ndarray:
    """The symmetric ``(n, n)`` matrix whose flattened lower triangle is ``lower``."""
    w = np.zeros((n, n), dtype=np.float64)
    w[np.tril_indices(n)] = lower
    return w + np.tril(w, k=-1).T


def class_adjacency(members: np.ndarray, lm: Landmarks, classes: Sequence[str] | None = None,
                    drop: np.ndarray | None = None) -> np.ndarray:
    """Algorithm 1: the class adjacency matrix of the graph made by the cliques ``members``.

    ``members`` is one clique (a length-K boolean vector) or several (``(m, K)``); landmarks
    ``i < j`` are joined when some clique holds both. ``W[a, b] = W[b, a]`` is the number of
    edges between classes ``a`` and ``b`` (``W[a, a]``: within ``a``) over the number of edges,
    so the lower triangle including the diagonal sums to 1. Rows and columns follow
    ``classes`` (default ``lm.classes``). No edge (fewer than two landmarks): all zeros.
    ``drop`` removes the edges of chosen landmark pairs (:func:`feature_edge_mask`).

    >>> from localization.landmarks import Landmarks
    >>> lm = Landmarks(xy=np.zeros((3, 2)), cls=np.array([0, 1, 1]), classes=("a", "b"), width=9, height=9)
    >>> class_adjacency(np.array([True, True, True]), lm).tolist()   # edges a-b, a-b, b-b
    [[0.0, 0.6666666666666666], [0.6666666666666666, 0.3333333333333333]]
    """
    names = tuple(lm.classes) if classes is None else tuple(classes)
    m = np.atleast_2d(np.asarray(members, dtype=bool))
    if m.shape[1] != len(lm.xy):
        raise ConfigError(f"cliques over {m.shape[1]} landmarks given for {len(lm.xy)} landmarks")
    table = _EdgeTable.build(_sparse(m), class_indices(lm, names), len(names), drop)
    return _symmetric(_normalise(table.counts(np.ones((1, len(m)))))[0], len(names))


def _ncc(query: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """Eq. 3.3 of one lower-triangle vector against rows of others; 0 where either is all zero."""
    num = candidates @ query
    den = np.sqrt(np.dot(query, query) * np.einsum("ij,ij->i", candidates, candidates))
    return np.minimum(1.0, np.divide(num, den, out=np.zeros(len(candidates)), where=den > 0))


def likelihood(query_w: np.ndarray, candidate_w: np.ndarray) -> float:
    """Eq. 3.3: normalised cross-correlation of two class adjacency matrices' lower triangles.

    ``sum_{u>=v} q[u,v] c[u,v] / sqrt(sum_{u>=v} q[u,v]^2 * sum_{u>=v} c[u,v]^2)``, uncentred
    (as in the paper and the authors' code), so with non-negative matrices it lies in [0, 1]
    and is a usable likelihood. Degenerate case: when either matrix is all zero (a graph with
    no edge) there is nothing to correlate and the likelihood is 0.

    >>> w = np.array([[0.5, 0.25], [0.25, 0.25]])
    >>> likelihood(w, w), likelihood(w, np.zeros((2, 2)))
    (1.0, 0.0)
    >>> round(likelihood(w, w[::-1, ::-1]), 4)   # the two classes swapped
    0.8333
    """
    q, c = np.asarray(query_w, dtype=np.float64), np.asarray(candidate_w, dtype=np.float64)
    if q.shape != c.shape or q.ndim != 2 or q.shape[0] != q.shape[1]:
        raise ConfigError(f"class adjacency matrices must be square and alike, got {q.shape} and {c.shape}")
    low = np.tril_indices(q.shape[0])
    return float(_ncc(q[low], c[low][None, :])[0])


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
    if reduce == "pca":
        centred = x - x.mean(axis=0)
        u, sv, _ = np.linalg.svd(centred, full_matrices=False)
        x = u[:, :components] * sv[:components]
    elif reduce == "umap":
        try:
            import umap  # type: ignore[import-not-found]
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
    return close


def posteriors(likelihoods: np.ndarray) -> np.ndarray:
    """Eqs. 3.4-3.6: each candidate's posterior against all the others, with a uniform prior.

    With N candidates, ``P(L_k) = 1/N`` and ``P(Z|¬L_k) = mean_{j != k} P(Z|L_j)``::

        P(L_k|Z) = P(Z|L_k) P(L_k) / (P(Z|L_k) P(L_k) + P(Z|¬L_k) (1 - P(L_k)))

    Posteriors need not sum to 1 (each is "here" against "elsewhere"). Degenerate cases: a
    zero denominator (this and every other likelihood 0) gives 0; a single candidate gets 1
    when its likelihood is positive (``1 - P(L) = 0``), else 0.

    >>> posteriors(np.array([0.9, 0.5, 0.1])).round(4).tolist()
    [0.6, 0.3333, 0.0667]
    >>> posteriors(np.array([0.7])).tolist(), posteriors(np.array([0.0, 0.0])).tolist()
    ([1.0], [0.0, 0.0])
    """
    lik = np.asarray(likelihoods, dtype=np.float64)
    n = lik.size
    if n == 0:
        return np.zeros(0)
    if n == 1:
        return np.array([1.0 if lik[0] > 0 else 0.0])
    prior = 1.0 / n
    others = (lik.sum() - lik) / (n - 1)
    num = lik * prior
    den = num + others * (1.0 - prior)
    return np.divide(num, den, out=np.zeros(n), where=den > 0)


def rank(scores: np.ndarray, centers: np.ndarray, second: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Candidate indices best first, and how many share the best score.

    Scores within ``TIE_RTOL`` (relative) or ``TIE_ATOL`` of the best are tied with it. Ties
    (and exactly equal scores further down) are broken by ``second`` (higher first; the
    likelihood of the candidate's own clique before extension, see :func:`match_cliques`),
    then by raster order of the centres (row ``y``, then column ``x``), then by index: the
    same input always gives the same MAP.

    >>> scores, centers = np.array([0.5, 0.9, 0.9]), np.array([[5.0, 9.0], [7.0, 3.0], [1.0, 3.0]])
    >>> order, ties = rank(scores, centers)
    >>> order.tolist(), ties
    ([2, 1, 0], 2)
    >>> rank(scores, centers, second=np.array([0.0, 0.8, 0.7]))[0].tolist()
    [1, 2, 0]
    """
    s = np.asarray(scores, dtype=np.float64)
    if s.size == 0:
        return np.zeros(0, dtype=np.int64), 0
    xy = np.asarray(centers, dtype=np.float64).reshape(-1, 2)
    sec = np.zeros(s.size) if second is None else np.asarray(second, dtype=np.float64)
    index = np.arange(s.size)
    order = np.lexsort((index, xy[:, 0], xy[:, 1], -sec, -s))
    tied = np.isclose(s[order], s[order[0]], rtol=TIE_RTOL, atol=TIE_ATOL)
    n_tied = int(tied.sum())  # a prefix: scores are sorted
    head = order[:n_tied]
    head = head[np.lexsort((head, xy[head, 0], xy[head, 1], -sec[head]))]
    return np.concatenate([head, order[n_tied:]]).astype(np.int64), n_tied


# --------------------------------------------------------------------------- result


def _floats(values: np.ndarray, digits: int = 10) -> list[float]:
    return [round(float(v), digits) for v in np.asarray(values).ravel()]


@dataclass(frozen=True, eq=False)
class Localization:
    """The answer to "where was the query taken?": candidates, scores and the best guesses.

    ``candidates`` are window centres ``(x, y)`` in aerial pixels, one per relevant clique;
    ``likelihoods`` are eq. 3.3 and ``posteriors`` eq. 3.6 (hierarchical: their product over
    the levels, eq. 3.8). ``order`` lists candidate indices best first;
    ``top_k`` holds ``(x, y, score)`` of the first ``k``; ``map_xy`` is the best one.
    ``ties`` is how many candidates share the best score (1: a unique answer); ties are broken
    by ``clique_likelihoods`` (eq. 3.3 for the candidate's clique before extension), then by
    raster order. ``relevant`` gives each candidate's aerial clique index. When the
    question cannot be answered (no landmarks, a query graph without edges, no relevant
    clique, or every candidate with likelihood 0) ``unanswered`` is True, ``reason`` says
    why, and there are no candidates.
    """

    candidates: np.ndarray
    likelihoods: np.ndarray
    posteriors: np.ndarray
    order: np.ndarray
    top_k: tuple[tuple[float, float, float], ...]
    map_xy: tuple[float, float] | None
    ties: int
    unanswered: bool
    reason: str = ""
    window: int = 0
    query_window: int = 0
    p: float = DEFAULT_P
    n_cliques: int = 0
    relevant: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    clique_likelihoods: np.ndarray = field(default_factory=lambda: np.zeros(0))
    levels: tuple["Localization", ...] = ()

    def error(self, truth: tuple[float, float] | None, resolution: float | None = None
              ) -> tuple[float | None, float | None]:
        """Distance from the MAP to ``truth`` in pixels, and in metres given ``resolution`` (m/px).

        (None, None) without a truth or an answer.
        """
        if truth is None or self.map_xy is None:
            return None, None
        px = math.hypot(self.map_xy[0] - truth[0], self.map_xy[1] - truth[1])
        return px, (px * resolution if resolution else None)

    def to_dict(self, all_candidates: bool = True) -> dict[str, Any]:
        """A JSON-able summary: settings, top-k with ranks, and (optionally) every candidate."""
        top = [{"rank": r + 1, "x": float(x), "y": float(y), "posterior": round(float(s), 10),
                "likelihood": round(float(self.likelihoods[i]), 10)}
               for r, ((x, y, s), i) in enumerate(zip(self.top_k, self.order))]
        out: dict[str, Any] = {
            "unanswered": self.unanswered,
            "reason": self.reason,
            "window": self.window,
            "query_window": self.query_window,
            "p": self.p,
            "n_cliques": self.n_cliques,
            "n_candidates": int(len(self.candidates)),
            "ties": self.ties,
            "map": None if self.map_xy is None else {"x": self.map_xy[0], "y": self.map_xy[1],
                                                      "posterior": top[0]["posterior"]},
            "top_k": top,
        }
        if all_candidates:
            out["candidates"] = [{"x": float(x), "y": float(y), "likelihood": lk, "posterior": s}
                                 for (x, y), lk, s in zip(self.candidates.tolist(), _floats(self.likelihoods),
                                                          _floats(self.posteriors))]
        if self.levels:
            out["levels"] = [lv.to_dict(all_candidates=False) for lv in self.levels]
        return out


def unanswered(reason: str, **settings: Any) -> Localization:
    """A result that says the query cannot be localized, and why (not an error)."""
    empty = np.zeros(0)
    return Localization(candidates=np.zeros((0, 2)), likelihoods=empty, posteriors=empty,
                        order=np.zeros(0, dtype=np.int64), top_k=(), map_xy=None, ties=0,
                        unanswered=True, reason=reason, **settings)


def answered(centers: np.ndarray, likelihoods: np.ndarray, scores: np.ndarray, top_k: int, *,
             clique_likelihoods: np.ndarray, **settings: Any) -> Localization:
    """A result over candidates at ``centers``, ranked by ``scores`` then ``clique_likelihoods`` (:func:`rank`)."""
    order, ties = rank(scores, centers, clique_likelihoods)
    top = tuple((float(centers[i, 0]), float(centers[i, 1]), float(scores[i])) for i in order[:top_k])
    return Localization(candidates=np.asarray(centers, dtype=np.float64), likelihoods=likelihoods, posteriors=scores,
                        order=order, top_k=top, map_xy=(top[0][0], top[0][1]), ties=ties, unanswered=False,
                        clique_likelihoods=clique_likelihoods, **settings)


# --------------------------------------------------------------------------- localize


def _check(p: float, top_k: int, stride: int) -> None:
    if not 0 < p <= 1:
        raise ConfigError(f"p must be in (0, 1], got {p}")
    if top_k < 1:
        raise ConfigError(f"top_k must be at least 1, got {top_k}")
    if stride < 1:
        raise ConfigError(f"stride must be at least 1 pixel, got {stride}")


def match_cliques(aerial: Landmarks, aerial_cliques: Cliques, query: Landmarks, query_cliques: Cliques, *,
                  p: float = DEFAULT_P, top_k: int = 5, window: int = 0, query_window: int = 0,
                  aerial_drop: np.ndarray | None = None, query_drop: np.ndarray | None = None) -> Localization:
    """Steps 1-6 of the module docstring on graphs already built (no window choice here).

    ``window`` and ``query_window`` are only recorded in the result (default: the cliques' own).
    ``aerial_drop``/``query_drop`` remove edges from the graphs (:func:`feature_edge_mask`).
    """
    settings = {"window": window or aerial_cliques.window, "query_window": query_window or query_cliques.window,
                "p": p, "n_cliques": int(len(aerial_cliques.members))}
    names = shared_classes(aerial, query)
    query_w = class_adjacency(query_cliques.members, query, names, query_drop)
    if not query_w.any():
        return unanswered("the query's landmarks form no edge (a single landmark, or none covisible): "
                          "nothing to match", **settings)
    query_classes = np.unique(class_indices(query, names))
    aerial_idx = class_indices(aerial, names)
    c = _sparse(aerial_cliques.members)
    relevant = relevant_cliques(inverted_index(c, aerial_idx, len(names)), query_classes.tolist())
    if relevant.size == 0:
        seen = ", ".join(names[c] for c in query_classes)
        return unanswered(f"no aerial clique holds every class seen in the query ({seen})", **settings)
    query_vec = query_w[np.tril_indices(len(names))]
    table = _EdgeTable.build(c, aerial_idx, len(names), aerial_drop)
    lik = np.concatenate([_ncc(query_vec, _normalise(table.counts(_extension(c, relevant[i:i + CHUNK], p))))
                          for i in range(0, len(relevant), CHUNK)])
    if not lik.any():
        return unanswered("no candidate's graph has an edge between classes the query's edges join", **settings)
    own = sparse.csr_matrix((np.ones(len(relevant)), (np.arange(len(relevant)), relevant)),
                            shape=(len(relevant), c.shape[0]))
    clique_lik = _ncc(query_vec, _normalise(table.counts(own)))  # tie-breaker: the clique before extension
    centers = np.asarray(aerial_cliques.centers, dtype=np.float64)[relevant]
    return answered(centers, lik, posteriors(lik), top_k, clique_likelihoods=clique_lik, relevant=relevant,
                    **settings)


def localize(aerial: Landmarks, query: Landmarks, *, window: int | None = None, query_window: int | None = None,
             p: float = DEFAULT_P, stride: int = 1, top_k: int = 5, fast: bool = True,
             aerial_drop: np.ndarray | None = None, query_drop: np.ndarray | None = None) -> Localization:
    """Localize ``query`` (a panorama's or an aerial crop's landmarks) in ``aerial``.

    Args:
        aerial: landmarks of the aerial image.
        query: landmarks of the ground panorama (``panorama=True``) or of an aerial crop.
        window: aerial covisibility window in pixels; None = :func:`window_size_auto`.
        query_window: the query's window; None = the image height for a panorama (the paper's
            square window as tall as the image), else the aerial window (a crop has the
            aerial's scale).
        p: covisibility parameter of the candidate extension.
        stride: window stride in pixels (1 = every position, as the paper).
        top_k: how many best candidates ``top_k`` holds.
        fast: exact event-sweep cliques (:func:`cliques_fast`) instead of the plain sliding window.
        aerial_drop, query_drop: ``(K, K)`` landmark pairs whose edges are removed (§5.3.2,
            :func:`feature_edge_mask`); None keeps every edge.

    Returns an unanswered :class:`Localization` (not an exception) when either image has no
    landmark, the query graph has no edge, no aerial clique holds all the query's classes, or
    no candidate correlates at all with the query.
    """
    _check(p, top_k, stride)
    for name, value in (("window", window), ("query_window", query_window)):
        if value is not None and value < 1:
            raise ConfigError(f"{name} must be at least 1 pixel, got {value}")
    if len(aerial.xy) == 0:
        return unanswered("the aerial image has no landmarks", p=p)
    if len(query.xy) == 0:
        return unanswered("the query has no landmarks", p=p)
    w = int(window) if window is not None else window_size_auto(aerial)
    qw = int(query_window) if query_window is not None else (query.height if query.panorama else w)
    build = cliques_fast if fast else cliques_reference
    result = match_cliques(aerial, build(aerial, w, stride), query, build(query, qw, stride),
                           p=p, top_k=top_k, window=w, query_window=qw, aerial_drop=aerial_drop, query_drop=query_drop)
    logger.debug("localize: window %d, query window %d, %d cliques, %d candidates, ties %d",
                 w, qw, result.n_cliques, len(result.candidates), result.ties)
    return result


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
    return np.where(inside, coarse_scores[None, :], 0.0).max(axis=1)


def localize_hierarchical(aerial: Landmarks, query: Landmarks, windows: Sequence[int] = HIERARCHY, *,
                          query_window: int | None = None, p: float = DEFAULT_P, stride: int = 1, top_k: int = 5,
                          fast: bool = True, aerial_drop: np.ndarray | None = None,
                          query_drop: np.ndarray | None = None) -> Localization:
    """Eq. 3.8: localize with each aerial window in turn (coarse to fine) and multiply probabilities.

    Level 0 scores are its posteriors. A candidate of level ``l`` scores its own posterior
    times the score it inherits from level ``l-1``: the best among the coarser candidates
    whose window contains its centre (:func:`inherit`), 0 when none does. Refinement stops at
    the last level that is answered and leaves some candidate with a non-zero score (finer
    windows may be too small to hold every query class); the result is that level's
    candidates with the combined scores, and ``levels`` keeps every level's own result.
    """
    if not windows or any(int(w) < 1 for w in windows):
        raise ConfigError(f"windows must be positive pixel sizes, coarse to fine, got {list(windows)}")
    levels: list[Localization] = []
    best: Localization | None = None
    for w in windows:
        level = localize(aerial, query, window=int(w), query_window=query_window, p=p, stride=stride,
                         top_k=top_k, fast=fast, aerial_drop=aerial_drop, query_drop=query_drop)
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
        best = answered(level.candidates, level.likelihoods, scores, top_k, relevant=level.relevant,
                        clique_likelihoods=level.clique_likelihoods,
                        window=level.window, query_window=level.query_window, p=p, n_cliques=level.n_cliques)
    if best is None:
        return Localization(**{**levels[0].__dict__, "levels": tuple(levels)})
    return Localization(**{**best.__dict__, "levels": tuple(levels)})
