"""Scores of a localization benchmark: errors, recall, blind-guess baselines, the class-subset trend.

Shared by the rendered-panorama benchmark (:mod:`localization.bench.rendered`) and the annotated
pairs (:mod:`localization.bench.pairs`): a record per query (``error``, ``error_px``, ``top5_mean``,
``ties``, ``unanswered``, ...), summarised into the numbers ``results.json`` reports.

Imports: numpy and localization.common.result.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, TypedDict

import numpy as np

from localization.common.result import DEFAULT_METHOD, Localization

__all__ = ["BenchResults", "RECALL_RADII_M", "UNANSWERED_CONFIDENCE", "RenderedResults", "summarize", "error_fields", "score", "heading_error", "chance_errors", "by_num_classes",
           "baselines"]

RECALL_RADII_M = (10, 25, 50)
#: the confidence results.json records for a query a method did not answer: below every real one
#: (so ROC AUC ranks it last), and no value of any method's scale, so pictures show it as unanswered
UNANSWERED_CONFIDENCE = -1.0


def _mean(values: Sequence[float]) -> float | None:
    return round(float(np.mean(values)), 4) if len(values) else None


def _median(values: Sequence[float]) -> float | None:
    return round(float(np.median(values)), 4) if len(values) else None


class BenchResults(TypedDict):
    """The results.json of localize-bench or localize-pairs: what was measured, how, each method's
    summary side by side, and every query's record (docs/localization.md)."""

    format: str
    format_version: int
    tool: str
    kind: str                       # "rendered panoramas" or "annotated pairs"
    queries: str
    unit: str                       # "m", or "px" for pairs of unknown resolution
    settings: dict[str, Any]
    source: str
    landmark_classes: dict[str, Any]
    classes: list[str]
    summary: dict[str, Any]         # the first method's, over the full class set (:func:`summarize`)
    baselines: dict[str, float | None]
    by_num_classes: dict[str, Any]
    methods: dict[str, dict[str, Any]]
    timing: dict[str, float | None]
    viewpoints: list[dict[str, Any]]


class RenderedResults(BenchResults):
    """The rendered-views protocol's results.json: also the seed and the aerial scenes."""

    seed: int
    scenes: list[dict[str, Any]]


def summarize(records: Sequence[dict[str, Any]], radii: Sequence[float] = RECALL_RADII_M) -> dict[str, Any]:
    """Error statistics over per-query records (``error``, ``error_px``, ``top5_mean``, ``ties``, ``unanswered``).

    ``error`` and ``top5_mean`` are in the run's unit (metres, or pixels without a resolution);
    recall at each radius counts unanswered queries as misses.

    >>> s = summarize([{"error_px": 10.0, "error": 5.0, "top5_mean": 8.0, "ties": 1, "unanswered": False},
    ...                {"error_px": None, "error": None, "top5_mean": None, "ties": 0, "unanswered": True}])
    >>> s["mean_error"], s["recall_at"]["10"], s["unanswered"], s["answered"]
    (5.0, 0.5, 1, 1)
    """
    answered = [r for r in records if not r["unanswered"]]
    err = [r["error"] for r in answered]
    err_px = [r["error_px"] for r in answered]
    n = len(records)
    return {
        "n": n,
        "answered": len(answered),
        "unanswered": n - len(answered),
        "tied": sum(1 for r in answered if r["ties"] > 1),
        "mean_ties": _mean([r["ties"] for r in answered]),
        "mean_error_px": _mean(err_px),
        "median_error_px": _median(err_px),
        "mean_error": _mean(err),
        "median_error": _median(err),
        "recall_at": {f"{r:g}": round(sum(e <= r for e in err) / n, 4) if n else None for r in radii},
        "top5_mean_distance": _mean([r["top5_mean"] for r in answered]),
    }


def error_fields(loc: Localization, truth: tuple[float, float], scale: float = 1.0) -> dict[str, Any]:
    """The error record of one answer: MAP, error in pixels and in units (``scale`` per pixel), top-k mean."""
    if loc.unanswered or loc.map_xy is None:
        return {"map": None, "error_px": None, "error": None, "top5_mean": None, "ties": loc.ties,
                "unanswered": True, "reason": loc.reason}
    err = math.hypot(loc.map_xy[0] - truth[0], loc.map_xy[1] - truth[1])
    top = [math.hypot(x - truth[0], y - truth[1]) for x, y, _ in loc.top_k]
    return {"map": [round(loc.map_xy[0], 3), round(loc.map_xy[1], 3)], "error_px": round(err, 4),
            "error": round(err * scale, 4), "top5_mean": round(float(np.mean(top)) * scale, 4), "ties": loc.ties,
            "unanswered": False, "reason": ""}


def score(loc: Localization, truth: tuple[float, float], scale: float = 1.0) -> dict[str, Any]:
    """Error of one localization against the true viewpoint; ``scale``: units per pixel (m/px, or 1).

    :func:`error_fields`, and ``candidate_guess``: the expected error of picking one of the
    candidates at random, what the candidate selection alone achieves, so ``error`` below it is
    what the matching adds.
    """
    out = error_fields(loc, truth, scale)
    if out["unanswered"]:
        return {**out, "candidate_guess": None, "candidates": 0}
    anyone = float(np.mean(np.hypot(loc.candidates[:, 0] - truth[0], loc.candidates[:, 1] - truth[1])))
    return {**out, "candidate_guess": round(anyone * scale, 4), "candidates": int(len(loc.candidates))}


def heading_error(estimate_deg: float, truth_deg: float) -> float:
    """Absolute angle between two compass headings, in [0, 180] degrees.

    >>> heading_error(359.0, 2.0), heading_error(90.0, 270.0)
    (3.0, 180.0)
    """
    return round(abs((estimate_deg - truth_deg + 180.0) % 360.0 - 180.0), 3)


def chance_errors(shape: tuple[int, int], truth: tuple[float, float], scale: float = 1.0) -> tuple[float, float]:
    """Errors of two blind guesses: the image centre, and a uniformly random pixel (expected).

    >>> [round(e, 1) for e in chance_errors((101, 101), (50.0, 50.0))]   # random: ~0.38 x side
    [0.0, 38.9]
    """
    h, w = shape
    centre = math.hypot(truth[0] - (w - 1) / 2, truth[1] - (h - 1) / 2) * scale
    gx, gy = np.meshgrid(np.linspace(0, w - 1, 64), np.linspace(0, h - 1, 64))
    uniform = float(np.mean(np.hypot(gx - truth[0], gy - truth[1]))) * scale
    return centre, uniform


def by_num_classes(subsets: Sequence[tuple[str, ...]], records: Sequence[dict[str, Any]],
                   radii: Sequence[float] = RECALL_RADII_M) -> dict[str, Any]:
    """Summaries per class subset, pooled by subset size (the dissertation's Figure 5.2).

    ``subsets[0]`` is the full class set, scored in each record itself; the others are in
    ``record["by_subset"]["a+b"]``.
    """
    full = "+".join(subsets[0])

    def of(record: dict[str, Any], name: str) -> dict[str, Any]:
        return record if name == full else record["by_subset"][name]

    out: dict[str, Any] = {}
    for k in sorted({len(s) for s in subsets}):
        names = ["+".join(s) for s in subsets if len(s) == k]
        per = {n: summarize([of(r, n) for r in records], radii) for n in names}
        out[str(k)] = {"summary": summarize([of(r, n) for n in names for r in records], radii), "subsets": per}
    return out


def baselines(records: Sequence[dict[str, Any]]) -> dict[str, float | None]:
    """Mean errors of the blind guesses over the records, and of a random candidate of the paper
    method (answered records that have one: None when the summary's method has no candidates)."""
    picks = [r["candidate_guess"] for r in records if not r["unanswered"] and r.get("candidate_guess") is not None]
    return {"centre_guess_mean": _mean([r["centre_guess"] for r in records]),
            "random_guess_mean": _mean([r["random_guess"] for r in records]),
            "random_candidate_mean": _mean(picks), "random_candidate_median": _median(picks)}


def headline(results: Mapping[str, Any]) -> tuple[str, dict[str, Any]]:
    """The method a benchmark's summary leads with, and its summary: the default method
    (``profile``) when it ran, else the first one run. ``results["summary"]`` stays the first
    method's (the records' fields and the class subsets are its), so a run of ``--methods
    paper,profile`` still headlines with the method a user of ``osmseg localize`` gets.

    >>> headline({"summary": {"n": 1}, "methods": {"paper": {"n": 2}, "profile": {"n": 3}}})
    ('profile', {'n': 3})
    >>> headline({"summary": {"n": 1}, "methods": {}})
    ('', {'n': 1})
    """
    methods = results.get("methods") or {}
    if DEFAULT_METHOD in methods:
        return DEFAULT_METHOD, methods[DEFAULT_METHOD]
    if methods:
        name = next(iter(methods))
        return name, methods[name]
    return "", results["summary"]
