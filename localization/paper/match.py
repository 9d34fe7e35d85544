"""Where was the query taken? Matching the query's landmark graph to sub-graphs of the aerial one.

This is section 3.2 of T. Resek's dissertation and section II of Verde, Resek, Milani & Rocha,
"Ground-to-Aerial Viewpoint Localization via Landmark Graphs Matching" (IEEE SPL 2020); where
the text leaves a choice open we follow the authors' MATLAB code (``virtualLocations.m``,
``classAdjacencyMatrix.m``, ``bayesianProbabilities.m``). Steps, for an aerial clique matrix
``C`` (M cliques x K landmarks, from :mod:`localization.paper.graph`) and a query graph:

1. **Relevant cliques.** An inverted index maps each landmark class to the cliques holding a
   landmark of that class; the relevant cliques are the intersection of the lists of every
   class seen in the query (:func:`inverted_index`, :func:`relevant_cliques`).
2. **Candidates** (the paper's "virtual locations"). Each relevant clique ``C_i`` is extended
   with every clique ``C_j`` (``j = i`` included) sharing at least a fraction ``p`` of its
   landmarks: ``|C_i ⊙ C_j|_0 / |C_i|_0 >= p`` (``>=`` as the authors' code). The candidate's
   graph is the *union of the complete graphs of those cliques*: two landmarks are joined when
   some included clique holds both (the authors' ``H(E^T E)``), not every pair of the union of
   their landmarks. Its position is the window centre of ``C_i``
   (:attr:`Cliques.centers <localization.paper.graph.Cliques.centers>`).
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

:mod:`localization.paper.refine` adds the dissertation's options: the window hierarchy 400 -> 200 ->
100 (eq. 3.8) and the removal of edges between landmarks with close image features (§5.3.2),
which :func:`localize` takes as ``aerial_drop``/``query_drop``.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import cast

import numpy as np
from scipy import sparse

from localization.common.landmarks import Landmarks
from localization.common.result import DEFAULT_P, Localization, answered, rank, unanswered
from localization.paper.config import PaperConfig
from localization.paper.graph import Cliques, window_size_auto
from osmseg.errors import ConfigError

logger = logging.getLogger(__name__)

__all__ = [
    "DEFAULT_P", "AerialGraph", "Candidates", "Localization", "aerial_graph", "candidates", "class_adjacency",
    "extend_cliques", "inverted_index", "likelihood", "localize", "match_cliques", "posteriors", "rank",
    "relevant_cliques", "unanswered",
]

#: Relevant cliques whose overlaps are computed at once (bounds memory to CHUNK x M floats).
CHUNK = 512
#: Landmark pairs held by all cliques together above which matching would not fit in memory
#: (about 16 bytes each while the edge table is built): refused with advice instead.
MAX_CLIQUE_PAIRS = 50_000_000


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
              drop: np.ndarray | None = None) -> _EdgeTable:
        """``drop``: optional ``(K, K)`` bool, landmark pairs whose edge is removed.

        See :func:`localization.paper.edges.feature_edge_mask`.
        """
        if drop is not None and np.shape(drop) != (c.shape[1], c.shape[1]):
            raise ConfigError(f"an edge mask must be ({c.shape[1]}, {c.shape[1]}) for {c.shape[1]} landmarks, "
                              f"got {np.shape(drop)}")
        c = c.tocsr()
        c.sort_indices()
        k = c.shape[1]
        sizes = np.diff(c.indptr)
        pairs = int((sizes * (sizes - 1) // 2).sum())
        if pairs > MAX_CLIQUE_PAIRS:
            raise ConfigError(f"the graph's windows hold {pairs:,} landmark pairs ({k:,} landmarks, up to "
                              f"{int(sizes.max()):,} in one window): too many to match; use fewer landmarks "
                              "(a larger --min-size, --landmark-mode centroid) or a smaller --window")
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
    return cast("np.ndarray", np.divide(counts, total, out=np.zeros_like(counts), where=total > 0))


def _symmetric(lower: np.ndarray, n: int) -> np.ndarray:
    """The symmetric ``(n, n)`` matrix whose flattened lower triangle is ``lower``."""
    w = np.zeros((n, n), dtype=np.float64)
    w[np.tril_indices(n)] = lower
    return cast("np.ndarray", w + np.tril(w, k=-1).T)


def class_adjacency(members: np.ndarray, lm: Landmarks, classes: Sequence[str] | None = None,
                    drop: np.ndarray | None = None) -> np.ndarray:
    """Algorithm 1: the class adjacency matrix of the graph made by the cliques ``members``.

    ``members`` is one clique (a length-K boolean vector) or several (``(m, K)``); landmarks
    ``i < j`` are joined when some clique holds both. ``W[a, b] = W[b, a]`` is the number of
    edges between classes ``a`` and ``b`` (``W[a, a]``: within ``a``) over the number of edges,
    so the lower triangle including the diagonal sums to 1. Rows and columns follow
    ``classes`` (default ``lm.classes``). No edge (fewer than two landmarks): all zeros.
    ``drop`` removes the edges of chosen landmark pairs (:func:`~localization.paper.edges.feature_edge_mask`).

    >>> from localization.common.landmarks import Landmarks
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
    return cast("np.ndarray", np.minimum(1.0, np.divide(num, den, out=np.zeros(len(candidates)), where=den > 0)))


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
    return cast("np.ndarray", np.divide(num, den, out=np.zeros(n), where=den > 0))


# --------------------------------------------------------------------------- localize


@dataclass(frozen=True)
class Candidates:
    """What matching needs of an aerial graph that depends only on the query's classes, not its edges.

    Built once per aerial graph and class set (:attr:`AerialGraph.memo`): a benchmark matches
    many views of one scene that see the same classes, and only the last step (eq. 3.3 against
    the query's matrix) differs between them.
    """

    relevant: np.ndarray                  # the relevant cliques (step 1); empty: nothing to match
    extended: tuple[np.ndarray, ...]      # each chunk of candidates' normalised class adjacency (steps 2-3)
    own: np.ndarray | None                # each relevant clique's alone, before extension (the tie-breaker)


def candidates(aerial: Landmarks, aerial_cliques: Cliques, names: tuple[str, ...], query_classes: np.ndarray,
               p: float, aerial_drop: np.ndarray | None = None) -> Candidates:
    """Steps 1-3 of the module docstring for a query whose landmarks are of ``query_classes`` (indices into ``names``)."""
    aerial_idx = class_indices(aerial, names)
    c = _sparse(aerial_cliques.members)
    relevant = relevant_cliques(inverted_index(c, aerial_idx, len(names)), query_classes.tolist())
    if relevant.size == 0:
        return Candidates(relevant, (), None)
    table = _EdgeTable.build(c, aerial_idx, len(names), aerial_drop)
    extended = tuple(_normalise(table.counts(_extension(c, relevant[i:i + CHUNK], p)))
                     for i in range(0, len(relevant), CHUNK))
    own = sparse.csr_matrix((np.ones(len(relevant)), (np.arange(len(relevant)), relevant)),
                            shape=(len(relevant), c.shape[0]))
    return Candidates(relevant, extended, _normalise(table.counts(own)))


def match_cliques(aerial: Landmarks, aerial_cliques: Cliques, query: Landmarks, query_cliques: Cliques,
                  config: PaperConfig = PaperConfig(), *, aerial_drop: np.ndarray | None = None,
                  query_drop: np.ndarray | None = None,
                  memo: dict[tuple[object, ...], Candidates] | None = None) -> Localization:
    """Steps 1-6 of the module docstring on graphs already built (no window choice here).

    ``conventions="authors"``: ties go to the first candidate in the cliques' order, as the
    authors' ``maxk`` (with cliques built with the same conventions: lexicographic order).

    ``config`` gives ``p``, ``top_k`` and the conventions; the windows recorded in the result are
    the cliques' own. ``aerial_drop``/``query_drop`` remove edges from the graphs
    (:func:`~localization.paper.edges.feature_edge_mask`). ``memo`` keeps the aerial side's
    :class:`Candidates` of these cliques between calls (unused with an ``aerial_drop``).
    """
    p, top_k, conventions = config.p, config.top_k, config.conventions
    settings = {"window": aerial_cliques.window, "query_window": query_cliques.window,
                "p": p, "n_cliques": int(len(aerial_cliques.members))}
    names = shared_classes(aerial, query)
    query_w = class_adjacency(query_cliques.members, query, names, query_drop)
    if not query_w.any():
        return unanswered("the query's landmarks form no edge (a single landmark, or none covisible): "
                          "nothing to match", **settings)
    query_classes = np.unique(class_indices(query, names))
    kept = memo if aerial_drop is None else None  # dropped edges change the candidates: never kept
    key = (names, tuple(query_classes.tolist()), p)
    cand = kept.get(key) if kept is not None else None
    if cand is None:
        cand = candidates(aerial, aerial_cliques, names, query_classes, p, aerial_drop)
        if kept is not None:
            kept[key] = cand
    if cand.own is None:
        seen = ", ".join(names[c] for c in query_classes)
        return unanswered(f"no aerial clique holds every class seen in the query ({seen})", **settings)
    query_vec = query_w[np.tril_indices(len(names))]
    lik = np.concatenate([_ncc(query_vec, chunk) for chunk in cand.extended])
    if not lik.any():
        return unanswered("no candidate's graph has an edge between classes the query's edges join", **settings)
    clique_lik = _ncc(query_vec, cand.own)  # tie-breaker: the clique before extension
    centers = np.asarray(aerial_cliques.centers, dtype=np.float64)[cand.relevant]
    return answered(centers, lik, posteriors(lik), top_k, clique_likelihoods=clique_lik, relevant=cand.relevant,
                    by_index=conventions == "authors", **settings)


@dataclass(frozen=True)
class AerialGraph:
    """An aerial image's landmarks with their cliques at one window: built once, matched many times."""

    landmarks: Landmarks
    window: int
    cliques: Cliques | None  # None when the image has no landmark
    #: each class set's :class:`Candidates`, kept as queries are matched (a cache: same answers)
    memo: dict[tuple[object, ...], Candidates] = field(default_factory=dict, compare=False, repr=False)


def aerial_graph(lm: Landmarks, config: PaperConfig = PaperConfig()) -> AerialGraph:
    """The graph of ``lm`` at ``config.window``, or the automatic one (no graph without landmarks)."""
    if len(lm.xy) == 0:
        return AerialGraph(lm, 0, None)
    w = int(config.window) if config.window is not None else window_size_auto(lm)
    return AerialGraph(lm, w, config.cliques(lm, w))


def localize(aerial: Landmarks | AerialGraph, query: Landmarks, config: PaperConfig = PaperConfig(), *,
             aerial_drop: np.ndarray | None = None, query_drop: np.ndarray | None = None) -> Localization:
    """Localize ``query`` (a panorama's or an aerial crop's landmarks) in ``aerial``, at one window.

    Args:
        aerial: landmarks of the aerial image, or their :class:`AerialGraph` built once for
            many queries (its window then overrides ``config.window``).
        query: landmarks of the ground panorama (``panorama=True``) or of an aerial crop.
        config: the windows, ``p``, stride, ``top_k``, clique builder and conventions
            (:class:`~localization.paper.config.PaperConfig`; ``hierarchical`` is
            :func:`~localization.paper.refine.localize_hierarchical`'s).
        aerial_drop, query_drop: ``(K, K)`` landmark pairs whose edges are removed (§5.3.2,
            :func:`~localization.paper.edges.feature_edge_mask`); None keeps every edge.

    Returns an unanswered :class:`Localization` (not an exception) when either image has no
    landmark, the query graph has no edge, no aerial clique holds all the query's classes, or
    no candidate correlates at all with the query.
    """
    lm = aerial.landmarks if isinstance(aerial, AerialGraph) else aerial
    if len(lm.xy) == 0:
        return unanswered("the aerial image has no landmarks", p=config.p)
    if len(query.xy) == 0:
        return unanswered("the query has no landmarks", p=config.p)
    graph = aerial if isinstance(aerial, AerialGraph) else aerial_graph(lm, config)
    if graph.cliques is None:
        return unanswered("the aerial image has no landmarks", p=config.p)
    qw = config.query_window_for(query, graph.window)
    result = match_cliques(lm, graph.cliques, query, config.cliques(query, qw), config,
                           aerial_drop=aerial_drop, query_drop=query_drop, memo=graph.memo)
    logger.debug("localize: window %d, query window %d, %d cliques, %d candidates, ties %d",
                 graph.window, qw, result.n_cliques, len(result.candidates), result.ties)
    return result
