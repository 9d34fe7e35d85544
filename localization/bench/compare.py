"""Methods side by side in one benchmark run: views as each method sees them, scores, ROC AUC.

:mod:`localization.bench.rendered` renders each view once and hands it to every method asked for
(``paper``, ``profile``). This module holds what differs per method and what compares them:

* :func:`photo_view` cuts a limited field of view out of a rendered panorama (a photo of
  ``fov_deg`` degrees centred on the camera's heading) and gives its landmarks;
* :func:`run_method` localizes one view with one method and scores it, also against a
  *non-matching* aerial image (another scene) for the confidence;
* :func:`roc_auc` and :func:`method_summary` turn the records into the numbers the bench
  prints: error statistics, heading error, and how well each method's confidence separates
  matching from non-matching pairs (the ``paper`` method's confidence is its MAP likelihood,
  eq. 3.3; the ``profile`` method's is how far its answer stands out from the best distinct
  alternative, :mod:`localization.profile.search`), and how well it ranks right answers (within 10 m)
  above wrong ones (more than 50 m off: a look-alike place), with the share of answers a
  threshold accepts and how many of those are wrong.

Imports: numpy, osmseg core, localization.common, both methods (paper, profile), localization.pipeline and the
bench wing's render and scores.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from localization.bench.render import Panorama
from localization.bench.scores import UNANSWERED_CONFIDENCE, error_fields, heading_error, score
from localization.common.landmarks import LandmarkClasses, Landmarks, landmarks_from_mask
from localization.common.result import Localization
from localization.common.views import Camera, SemanticMap, semantic_map
from localization.paper.config import PaperConfig
from localization.paper.match import AerialGraph, aerial_graph
from localization.pipeline import LocalizeConfig, run
from localization.profile.method import run_profile
from localization.profile.search import AerialIndex, ProfileConfig

__all__ = ["Query", "aerial_graphs", "class_subsets", "confidence_of", "localize_subsets", "photo_columns", "photo_view",
           "run_method", "roc_auc", "method_summary", "subsets_of"]


@dataclass(frozen=True)
class Query:
    """One view as the methods get it: its mask in landmark classes, its landmarks and its camera."""

    semantic: SemanticMap
    landmarks: Landmarks
    camera: Camera
    heading_deg: float   # the true heading (compass azimuth of the centre column)


def photo_columns(width: int, fov_deg: float) -> slice:
    """The columns of a ``width``-pixel 360° panorama that a photo of ``fov_deg`` facing its centre sees.

    >>> photo_columns(1232, 90), photo_columns(1232, 360)
    (slice(462, 770, None), slice(0, 1232, None))
    """
    if fov_deg >= 360:
        return slice(0, width)
    n = max(2, int(round(width * fov_deg / 360.0)))
    start = (width - n) // 2
    return slice(start, start + n)


def photo_view(panorama: Panorama, classes: LandmarkClasses, fov_deg: float, *, camera_height_m: float,
               mode: str, min_size: int, stride: int, landmarks: Landmarks | None = None) -> Query:
    """The query a camera of ``fov_deg`` (360: the whole panorama) pointing at the panorama's heading sees."""
    labels = panorama.labels
    h, w = labels.shape
    step = 360.0 / w
    if fov_deg >= 360:
        lm = landmarks if landmarks is not None else landmarks_from_mask(
            labels, panorama.table, classes, mode=mode, min_size=min_size, stride=stride, panorama=True)
        cam = Camera(w, h, hfov_deg=360.0, row_step_deg=step, camera_height_m=camera_height_m)
    else:
        cols = photo_columns(w, fov_deg)
        start, n = cols.start, cols.stop - cols.start
        labels = np.ascontiguousarray(labels[:, cols])
        lm = landmarks_from_mask(labels, panorama.table, classes, mode=mode, min_size=min_size, stride=stride)
        cam = Camera(n, h, hfov_deg=n * step, row_step_deg=step, camera_height_m=camera_height_m)
        # the photo's centre looks along the panorama's heading, half a column off when n and w differ in parity
        heading = (panorama.heading_deg + step * (start + n / 2 - w / 2)) % 360.0
        return Query(semantic_map(labels, panorama.table, classes), lm, cam, heading)
    return Query(semantic_map(labels, panorama.table, classes), lm, cam, panorama.heading_deg)


#: Right answers are within RIGHT_WRONG[0] of the truth, wrong ones more than RIGHT_WRONG[1] (metres).
RIGHT_WRONG = (10.0, 50.0)


def confidence_of(loc: Localization) -> float:
    """A method's confidence in its answer: the profile method's (how far the answer stands out), the
    MAP likelihood (paper), :data:`~localization.bench.scores.UNANSWERED_CONFIDENCE` (-1) unanswered."""
    if loc.method == "profile":
        return float(loc.confidence) if loc.confidence is not None else UNANSWERED_CONFIDENCE
    if loc.unanswered or not len(loc.order):
        return UNANSWERED_CONFIDENCE
    return float(loc.likelihoods[loc.order[0]])


def run_method(method: str, query: Query, truth: tuple[float, float], scale: float, *,
               paper: Callable[[], tuple[AerialGraph, AerialGraph | None]],
               profile: Callable[[], tuple[AerialIndex, AerialIndex | None]],
               paper_config: LocalizeConfig, profile_config: ProfileConfig, heading_known: bool
               ) -> tuple[dict[str, Any], Localization]:
    """One method on one view: its error, heading error, time, and confidence on the match and a non-match,
    and its answer (for a picture).

    ``paper``/``profile`` give the aerial side of the view's scene and of a non-matching scene
    (None with a single scene), built once per scene by the caller.
    """
    t0 = time.perf_counter()
    if method == "paper":
        graph, other = paper()
        loc = run(paper_config, graph, query.landmarks)
        seconds = time.perf_counter() - t0
        negative = run(paper_config, other, query.landmarks) if other is not None else None
        turned: float | None = None
    else:
        index, other_index = profile()
        cfg = replace(profile_config, heading_deg=query.heading_deg if heading_known else None)
        loc = run_profile(cfg, index, query.semantic, query.camera)
        seconds = time.perf_counter() - t0
        negative = run_profile(cfg, other_index, query.semantic, query.camera) if other_index is not None else None
        turned = (None if heading_known or loc.heading_deg is None or loc.unanswered
                  else heading_error(loc.heading_deg, query.heading_deg))
    out = error_fields(loc, truth, scale)
    out.update({"localize_s": round(seconds, 4), "confidence": round(confidence_of(loc), 6),
                "negative_confidence": None if negative is None else round(confidence_of(negative), 6),
                "heading_error_deg": turned,
                "margin": None if loc.margin is None else round(loc.margin, 6),
                "kappa": loc.kappa, "chance": loc.chance,
                "negative_kappa": None if negative is None else negative.kappa,
                "score": round(loc.top_k[0][2], 6) if loc.top_k else None})
    return out, loc


def roc_auc(positive: Sequence[float], negative: Sequence[float]) -> float | None:
    """Probability that a matching pair scores above a non-matching one (ties count half).

    >>> roc_auc([0.9, 0.8], [0.1, 0.8])
    0.875
    """
    if not len(positive) or not len(negative):
        return None
    pos, neg = np.asarray(positive, dtype=np.float64), np.asarray(negative, dtype=np.float64)
    greater = (pos[:, None] > neg[None, :]).sum()
    equal = (pos[:, None] == neg[None, :]).sum()
    return round(float((greater + 0.5 * equal) / (len(pos) * len(neg))), 4)


def method_summary(records: Sequence[dict[str, Any]], method: str,
                   summarize: Callable[[Sequence[dict[str, Any]]], dict[str, Any]], *,
                   right_wrong: tuple[float, float] | None = RIGHT_WRONG, threshold: float | None = None
                   ) -> dict[str, Any]:
    """Error statistics (``summarize``), heading error, ROC AUC and time of ``method`` over the records.

    ``roc_auc`` (a matching pair's confidence against a non-matching one's; an unanswered query
    counts as :data:`~localization.bench.scores.UNANSWERED_CONFIDENCE`, below every answer) is
    None without non-matching pairs, and when the method answered no view: its confidences
    would all be that stand-in, and their ties alone would make an AUC of 0.5 out of nothing.

    With ``right_wrong`` (``(right, wrong)`` in the run's unit): ``right_wrong_auc``, the chance
    that a right answer (error <= right) has a higher confidence than a wrong one (error >
    wrong, or none); with ``threshold``, the share of views answered at that confidence
    (``accepted``) and the share of those answers that are wrong (``false_accept``).
    """
    rows = [r["methods"][method] for r in records]
    headings = [r["heading_error_deg"] for r in rows if r["heading_error_deg"] is not None]
    negatives = [r["negative_confidence"] for r in rows if r["negative_confidence"] is not None]
    positives = [r["confidence"] for r in rows if r["confidence"] is not None]
    out = summarize(rows)
    out.update({
        "median_heading_error_deg": round(float(np.median(headings)), 3) if headings else None,
        "roc_auc": roc_auc(positives, negatives) if out["answered"] else None,
        "localize_mean_s": round(float(np.mean([r["localize_s"] for r in rows])), 4) if rows else None,
    })
    if right_wrong is not None:
        near, far = right_wrong
        right = [r["confidence"] for r in rows if r["error"] is not None and r["error"] <= near]
        wrong = [r["confidence"] for r in rows if r["error"] is None or r["error"] > far]
        out["right_wrong_auc"] = roc_auc(right, wrong)
        if threshold is not None:
            kept = [r for r in rows if r["error"] is not None and r["confidence"] >= threshold]
            out["threshold"] = threshold
            out["accepted"] = round(len(kept) / len(rows), 4) if rows else None
            out["false_accept"] = round(sum(r["error"] > far for r in kept) / len(kept), 4) if kept else None
    return out


def class_subsets(names: Sequence[str]) -> list[tuple[str, ...]]:
    """Every subset of two or more classes, smallest first (the order of ``names`` kept).

    >>> [("+".join(s)) for s in class_subsets(("building", "road", "tree"))]
    ['building+road', 'building+tree', 'road+tree', 'building+road+tree']
    """
    return [c for k in range(2, len(names) + 1) for c in itertools.combinations(names, k)]


def aerial_graphs(lm: Landmarks, subsets: Sequence[tuple[str, ...]], config: PaperConfig
                  ) -> dict[tuple[str, ...], AerialGraph]:
    """The aerial landmarks' graph for every class subset, each with its own automatic window."""
    return {s: aerial_graph(lm.of_classes(s), config) for s in subsets}


def localize_subsets(graphs: dict[tuple[str, ...], AerialGraph], query: Landmarks, truth: tuple[float, float],
                     scale: float, config: PaperConfig) -> tuple[dict[str, Any], float]:
    """Score the query against every subset's graph: the full set's record (with ``by_subset``) and its time (s)."""
    subsets = list(graphs)
    by_subset: dict[str, dict[str, Any]] = {}
    seconds = 0.0
    for s in subsets:
        t0 = time.perf_counter()
        loc = run(LocalizeConfig(method="paper", paper=config), graphs[s], query.of_classes(s))
        if s == subsets[0]:
            seconds = time.perf_counter() - t0
        by_subset["+".join(s)] = score(loc, truth, scale)
    full = by_subset.pop("+".join(subsets[0]))
    return {**full, "by_subset": by_subset}, seconds


def subsets_of(classes: LandmarkClasses, all_subsets: bool) -> list[tuple[str, ...]]:
    """The full class set first, then (when asked) every smaller subset of two or more classes."""
    full = tuple(classes.names)
    return [full] + ([s for s in class_subsets(full) if len(s) < len(full)] if all_subsets else [])
