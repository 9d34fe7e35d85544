"""The answer of a localization: candidates ranked by score, ties counted, top-k, JSON form.

:func:`rank` orders candidates best first and counts how many share the best score;
:class:`Localization` holds every candidate with its likelihood and posterior, the ranking
and the settings that produced it; :func:`answered` and :func:`unanswered` build one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["DEFAULT_METHOD", "DEFAULT_P", "METHODS", "TIE_ATOL", "TIE_RTOL", "Localization", "answered", "rank", "unanswered"]

#: ``paper``: landmark-graph matching (Verde et al. 2020); ``profile``: angular profiles on a dense grid.
METHODS = ("paper", "profile")
#: the method ``osmseg localize`` runs unless told otherwise; summaries lead with it when it ran
DEFAULT_METHOD = "profile"
#: The covisibility parameter p of the candidate extension (the paper's value).
DEFAULT_P = 0.5
#: Scores within this relative (or absolute) distance of the best one count as tied with it.
TIE_RTOL = 1e-9
TIE_ATOL = 1e-12


def rank(scores: np.ndarray, centers: np.ndarray, second: np.ndarray | None = None,
         by_index: bool = False) -> tuple[np.ndarray, int]:
    """Candidate indices best first, and how many share the best score.

    Scores within ``TIE_RTOL`` (relative) or ``TIE_ATOL`` of the best are tied with it. Ties
    (and exactly equal scores further down) are broken by ``second`` (higher first; the
    likelihood of the candidate's own clique before extension, see :func:`localization.paper.match.match_cliques`),
    then by raster order of the centres (row ``y``, then column ``x``), then by index: the
    same input always gives the same MAP.

    >>> scores, centers = np.array([0.5, 0.9, 0.9]), np.array([[5.0, 9.0], [7.0, 3.0], [1.0, 3.0]])
    >>> order, ties = rank(scores, centers)
    >>> order.tolist(), ties
    ([2, 1, 0], 2)
    >>> rank(scores, centers, second=np.array([0.0, 0.8, 0.7]))[0].tolist()
    [1, 2, 0]
    >>> rank(scores, centers, by_index=True)[0].tolist()   # the authors' MATLAB maxk: first index first
    [1, 2, 0]
    """
    s = np.asarray(scores, dtype=np.float64)
    if s.size == 0:
        return np.zeros(0, dtype=np.int64), 0
    xy = np.asarray(centers, dtype=np.float64).reshape(-1, 2)
    sec = np.zeros(s.size) if second is None else np.asarray(second, dtype=np.float64)
    index = np.arange(s.size)
    if by_index:
        order = np.lexsort((index, -s))
        return order.astype(np.int64), int(np.isclose(s[order], s[order[0]], rtol=TIE_RTOL, atol=TIE_ATOL).sum())
    order = np.lexsort((index, xy[:, 0], xy[:, 1], -sec, -s))
    tied = np.isclose(s[order], s[order[0]], rtol=TIE_RTOL, atol=TIE_ATOL)
    n_tied = int(tied.sum())  # a prefix: scores are sorted
    head = order[:n_tied]
    head = head[np.lexsort((head, xy[head, 0], xy[head, 1], -sec[head]))]
    return np.concatenate([head, order[n_tied:]]).astype(np.int64), n_tied


def _floats(values: np.ndarray, digits: int = 10) -> list[float]:
    return [round(float(v), digits) for v in np.asarray(values).ravel()]


@dataclass(frozen=True, eq=False)
class Localization:
    """The answer to "where was the query taken?": candidates, scores and the best guesses.

    ``candidates`` are window centres ``(x, y)`` in aerial pixels, one per relevant clique;
    ``likelihoods`` are eq. 3.3 and ``posteriors`` eq. 3.6 (hierarchical: their product over
    the levels, eq. 3.8). ``order`` lists candidate indices best first;
    ``top_k`` holds ``(x, y, score)`` of the first ``k``; ``map_xy`` is the best one.
    ``method`` says which method answered (``paper``, ``profile``: :mod:`localization.profile.search`,
    which also sets ``heading_deg``, ``confidence`` and ``chance``).
    ``ties`` is how many candidates share the best score (1: a unique answer); ties are broken
    by ``clique_likelihoods`` (eq. 3.3 for the candidate's clique before extension), then by
    raster order. ``relevant`` gives each candidate's aerial clique index. When the
    question cannot be answered (no landmarks, a query graph without edges, no relevant
    clique, or every candidate with likelihood 0) ``unanswered`` is True, ``reason`` says
    why, and there are no candidates. ``feature_edges``, when set, records the §5.3.2 edge
    removal that was applied (settings and edges dropped per side; see :mod:`localization.paper.features`).
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
    levels: tuple[Localization, ...] = ()
    feature_edges: dict[str, Any] | None = None
    method: str = "paper"
    heading_deg: float | None = None   # the profile method: the query's estimated (or given) heading
    confidence: float | None = None    # the profile method: how far the answer stands out (localization.profile.search)
    kappa: float | None = None         # the profile method: kappa of the best match against chance
    chance: float | None = None        # the profile method: agreement of a random position
    alternative: tuple[float, float, float] | None = None  # the profile method: (x, y, score) of the best
                                                           # place at least distinct_m from the answer
    camera_pose: tuple[float, float, float] | None = None  # the profile method with the camera pose searched:
                                                           # the answer's (height m, pitch, roll degrees)
    headings: tuple[float, ...] = ()   # the profile method: the heading at each of top_k (each place its own)
    alternative_heading: float | None = None  # the profile method: the heading at the alternative

    @property
    def margin(self) -> float | None:
        """The answer's score minus the best distinct alternative's (None: no alternative, or no answer)."""
        if self.alternative is None or not self.top_k:
            return None
        return self.top_k[0][2] - self.alternative[2]

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
            "method": self.method,
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
        for name in ("heading_deg", "confidence", "kappa", "chance", "margin", "camera_pose"):
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        if self.alternative is not None:
            x, y, s = self.alternative
            out["alternative"] = {"x": x, "y": y, "score": round(s, 10)}
        if self.levels:
            out["levels"] = [lv.to_dict(all_candidates=False) for lv in self.levels]
        if self.feature_edges is not None:
            out["feature_edges"] = self.feature_edges
        return out


def unanswered(reason: str, **settings: Any) -> Localization:
    """A result that says the query cannot be localized, and why (not an error)."""
    empty = np.zeros(0)
    return Localization(candidates=np.zeros((0, 2)), likelihoods=empty, posteriors=empty,
                        order=np.zeros(0, dtype=np.int64), top_k=(), map_xy=None, ties=0,
                        unanswered=True, reason=reason, **settings)


def answered(centers: np.ndarray, likelihoods: np.ndarray, scores: np.ndarray, top_k: int, *,
             clique_likelihoods: np.ndarray, by_index: bool = False, **settings: Any) -> Localization:
    """A result over candidates at ``centers``, ranked by ``scores`` then ``clique_likelihoods`` (:func:`rank`)."""
    order, ties = rank(scores, centers, clique_likelihoods, by_index)
    top = tuple((float(centers[i, 0]), float(centers[i, 1]), float(scores[i])) for i in order[:top_k])
    return Localization(candidates=np.asarray(centers, dtype=np.float64), likelihoods=likelihoods, posteriors=scores,
                        order=order, top_k=top, map_xy=(top[0][0], top[0][1]), ties=ties, unanswered=False,
                        clique_likelihoods=clique_likelihoods, **settings)
