"""Pictures of a localization benchmark: the error CDF, the number-of-classes trend and the confidence.

Each reads the ``results.json`` document of :func:`localization.bench.rendered.run_bench` (rendered
panoramas, errors in metres) or :func:`localization.bench.pairs.run_pairs` (annotated pairs, errors
in metres given a resolution, else in pixels): ``results["unit"]`` says which, and the recall
radii are the keys of ``summary["recall_at"]``. ``draw_*`` draw a picture on a given figure,
``plot_*`` draw it on a new one and write the PNG. A query a method did not answer is counted as
unanswered, never drawn at a value (results.json records its confidence as
:data:`~localization.bench.scores.UNANSWERED_CONFIDENCE`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, cast

import numpy as np

from localization.bench.scores import UNANSWERED_CONFIDENCE, BenchResults, headline
from osmseg.errors import ConfigError
from osmseg.output.atomic import atomic_write_text
from osmseg.units import quantity, ratio

__all__ = ["CONFIDENCE_NAMES", "METHOD_NAMES", "compared", "confidences", "draw_confidence", "draw_errors", "errors_title",
           "plot_classes", "plot_confidence", "plot_errors"]


def _figures() -> Any:
    """:mod:`osmseg.output.plotting`, or a one-line error when matplotlib is missing."""
    try:
        from osmseg.output import plotting as figures
    except ImportError:
        raise ConfigError("the benchmark plots need matplotlib: pip install matplotlib (or pass --no-plots)") from None
    return figures


def _cdf(ax: Any, values: Sequence[float], n: int, **style: Any) -> None:
    """Step CDF of ``values`` over ``n`` trials (missing trials keep the curve below 1)."""
    v = np.sort(np.asarray(values, dtype=float))
    ax.step(np.concatenate([[0.0], v]), np.arange(len(v) + 1) / max(n, 1), where="post", **style)


#: how the pictures name each method
METHOD_NAMES = {"paper": "landmark graphs (MAP)", "profile": "angular profiles"}


def errors_title(results: Mapping[str, Any]) -> str:
    """errors.png's title: the default method's median and recall when it ran, as the terminal
    summary leads with (:func:`localization.bench.scores.headline`), at :mod:`osmseg.units`' precision."""
    unit = results.get("unit", "m")
    name, lead = headline(results)
    radii = list(lead["recall_at"])
    middle = radii[len(radii) // 2]
    method = f"{METHOD_NAMES.get(name, name)}: " if name else ""
    return (f"Localization error of {lead['n']} {results.get('queries', 'queries')}\n"
            f"{', '.join(results['classes'])}; {method}median {quantity(lead['median_error'], unit)}, "
            f"recall@{middle} {unit} {ratio(lead['recall_at'][middle])}")


def draw_errors(fig: Any, results: BenchResults) -> None:
    """errors.png on ``fig``: the CDF of each method's error (all classes), with the top-5 mean
    distance and two blind guesses; the title gives the default method's median and recall
    (:func:`localization.bench.scores.headline`)."""
    unit = results.get("unit", "m")
    recs, s = results["viewpoints"], results["summary"]
    ax = fig.add_subplot()
    methods = results.get("methods") or {}
    colours = {"paper": "tab:green", "profile": "tab:blue"}
    names = METHOD_NAMES
    for m, summary in methods.items():
        errors = [r["methods"][m]["error"] for r in recs if r["methods"][m]["error"] is not None]
        _cdf(ax, errors, len(recs), color=colours.get(m, "tab:purple"), lw=2,
             label=f"{names.get(m, m)}, {summary['answered']}/{summary['n']} answered")
    if not methods:
        _cdf(ax, [r["error"] for r in recs if not r["unanswered"]], len(recs), color="tab:green", lw=2,
             label=f"landmark graphs (MAP), {s['answered']}/{s['n']} answered")
    first = next(iter(methods), "paper")
    _cdf(ax, [r["top5_mean"] for r in recs if not r["unanswered"]], len(recs), color=colours.get(first, "tab:green"),
         ls=":", label=f"top-5 mean distance ({first})")
    if first == "paper":
        _cdf(ax, [r["candidate_guess"] for r in recs if not r["unanswered"]], len(recs), color="tab:orange",
             ls="--", label="a random candidate (expected)")
    # where the truth was not given it is taken as the image centre, so that guess is no baseline there
    centre = [r["centre_guess"] for r in recs if r.get("truth_given", True)]
    if centre:
        _cdf(ax, centre, len(recs), color="0.5", ls="--", label="guess the image centre")
    _cdf(ax, [r["random_guess"] for r in recs], len(recs), color="0.7", ls="-.", label="random guess (expected)")
    for radius in s["recall_at"]:
        ax.axvline(float(radius), color="0.85", lw=1, zorder=0)
    ax.set_xlim(left=0)
    if methods:
        ax.set_xscale("symlog", linthresh=1.0)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel(f"error ({unit})")
    ax.set_ylabel(f"fraction of {results.get('queries', 'queries')}")
    ax.set_title(errors_title(results))
    # under the axes, where it cannot hide the curves: their lower parts ran under it, at the right
    _figures().legend_below(fig, ax.get_legend_handles_labels()[0], columns=2, fontsize=8)


def plot_errors(results: BenchResults, path: Path) -> Path:
    """errors.png (:func:`draw_errors`)."""
    figures = _figures()
    with figures.figure(6.5, 4.8) as fig:
        draw_errors(fig, results)
        return cast(Path, figures.save_png(fig, path))


def plot_classes(results: BenchResults, path: Path) -> Path:
    """Error and recall against the number of landmark classes used (the dissertation's Figure 5.2)."""
    figures = _figures()
    unit = results.get("unit", "m")
    by_k = results["by_num_classes"]
    ks = sorted(by_k, key=int)
    xs = [int(k) for k in ks]
    with figures.figure(9.0, 3.8) as fig:
        ax_err, ax_rec = fig.subplots(1, 2)
        for stat, style in (("mean_error", "-o"), ("median_error", "--s")):
            ys = [by_k[k]["summary"][stat] for k in ks]
            ax_err.plot(xs, [np.nan if y is None else y for y in ys], style, label=stat.replace("_", " "))
        for k in ks:
            vals = [v["mean_error"] for v in by_k[k]["subsets"].values() if v["mean_error"] is not None]
            ax_err.scatter([int(k)] * len(vals), vals, color="0.6", s=12, zorder=0)
        ax_err.set_xlabel("landmark classes used")
        ax_err.set_ylabel(f"error ({unit}); dots: each class subset")
        ax_err.set_xticks(xs)
        ax_err.legend(fontsize=8)
        for radius in results["summary"]["recall_at"]:
            ax_rec.plot(xs, [by_k[k]["summary"]["recall_at"][radius] for k in ks], "-o",
                        label=f"recall@{radius} {unit}")
        ax_rec.set_xlabel("landmark classes used")
        ax_rec.set_ylabel(f"fraction of {results.get('queries', 'queries')}")
        ax_rec.set_ylim(0, 1.02)
        ax_rec.set_xticks(xs)
        ax_rec.legend(fontsize=8)
        fig.suptitle("Effect of the number of landmark classes (subsets pooled)")
        return cast(Path, figures.save_png(fig, path))


#: x axis of each method's confidence histogram
CONFIDENCE_NAMES = {"paper": "MAP likelihood (eq. 3.3)",
                    "profile": "confidence (lead over the best distinct alternative)"}
#: the two kinds of pair the confidence histograms compare, and their colours
PAIRS = (("confidence", "matching aerial image", "tab:blue"), ("negative_confidence", "another aerial image", "tab:red"))


def confidences(records: Sequence[Mapping[str, Any]], method: str, key: str) -> tuple[list[float], int]:
    """``method``'s answered ``key`` values (``confidence``, ``negative_confidence``) over ``records``,
    and how many queries it did not answer: those recorded as
    :data:`~localization.bench.scores.UNANSWERED_CONFIDENCE`, or without a value although the
    method ran on that kind of pair (a run without non-matching pairs has none at all)."""
    values = [r["methods"][method].get(key) for r in records]
    ran = any(v is not None for v in values)
    answered = [float(v) for v in values if v is not None and v != UNANSWERED_CONFIDENCE]
    return answered, (len(values) - len(answered)) if ran else 0


def compared(results: BenchResults) -> dict[str, dict[str, Any]]:
    """The methods confidence.png shows, with their summaries: those run on non-matching pairs
    too (their records hold a ``negative_confidence``); none in a run without non-matching pairs
    (one scene, ``--no-negatives``)."""
    recs = results["viewpoints"]
    return {m: v for m, v in (results.get("methods") or {}).items()
            if any(r["methods"][m].get("negative_confidence") is not None for r in recs)}


def draw_confidence(fig: Any, results: BenchResults) -> bool:
    """confidence.png on ``fig``: per method, histograms of its confidence on matching and on
    non-matching pairs (ROC AUC in the title, or "no answered view" for a method without one,
    whose AUC would be made of ties alone); the queries it did not answer are counted in a bar
    of their own, labelled "unanswered", beside the values, never drawn as one. One legend of
    the two kinds of pair, under the panels, when a histogram was drawn.

    False (nothing drawn) when the run has no non-matching pair (:func:`compared`).
    """
    from matplotlib.ticker import MaxNLocator

    methods = compared(results)
    if not methods:
        return False
    recs = results["viewpoints"]
    drawn = {m: [confidences(recs, m, key) for key, _, _ in PAIRS] for m in methods}
    unanswered = {m: any(n for _, n in sides) for m, sides in drawn.items()}
    ratios = [r for m in methods for r in ((6, 1) if unanswered[m] else (6,))]
    grid = fig.add_gridspec(1, len(ratios), width_ratios=ratios)
    column = 0
    handles: list[Any] = []
    for m, summary in methods.items():
        ax = fig.add_subplot(grid[0, column])
        values = [v for answered, _ in drawn[m] for v in answered]
        if values:
            lo, hi = min(values), max(values)
            if hi - lo < 1e-3:  # every query alike: bins a few hundredths wide, not 1e-9 under an offset
                lo, hi = lo - 0.05, hi + 0.05
            bins = np.linspace(lo, hi, 25)
            for (answered, _), (_, label, colour) in zip(drawn[m], PAIRS):
                ax.hist(answered, bins=bins, alpha=0.6, color=colour, label=label)
            ax.ticklabel_format(axis="x", style="plain", useOffset=False)
            handles = handles or ax.get_legend_handles_labels()[0]
        else:
            ax.text(0.5, 0.5, "no query answered", transform=ax.transAxes, ha="center", va="center", color="0.4")
        ax.set_xlabel(CONFIDENCE_NAMES.get(m, "confidence"))
        ax.set_ylabel(results.get("queries", "queries"))
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))  # counts of queries
        auc = summary.get("roc_auc")
        ax.set_title(f"{METHOD_NAMES.get(m, m)}: " + ("no answered view" if auc is None else f"ROC AUC {ratio(auc)}"))
        column += 1
        if unanswered[m]:
            side = fig.add_subplot(grid[0, column], sharey=ax)
            counts = [n for _, n in drawn[m]]
            bars = side.bar([0, 1], counts, width=0.8, alpha=0.6, color=[colour for _, _, colour in PAIRS])
            side.bar_label(bars, fontsize=8)
            side.set_xlim(-0.7, 1.7)
            side.set_xticks([0.5], ["unanswered"])
            side.tick_params(axis="y", labelleft=False)
            column += 1
    if handles:  # under the panels, where it hides no bar; none when no histogram was drawn
        _figures().legend_below(fig, handles, fontsize=8)
    fig.suptitle("Does the confidence tell a match from a non-match?")
    return True


def plot_confidence(results: BenchResults, path: Path) -> Path | None:
    """confidence.png (:func:`draw_confidence`); None (nothing written) when the run has no
    non-matching pair (one scene, ``--no-negatives``)."""
    methods = compared(results)
    if not methods:
        return None
    figures = _figures()
    with figures.figure(4.4 * len(methods), 4.0) as fig:
        draw_confidence(fig, results)
        return cast("Path | None", figures.save_png(fig, path))


def write_results(results: BenchResults, out_dir: Path, plots: bool) -> None:
    """results.json, and errors.png + classes.png when ``plots``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out_dir / "results.json", json.dumps(results, indent=2, sort_keys=True) + "\n")
    if plots:
        plot_errors(results, out_dir / "errors.png")
        plot_classes(results, out_dir / "classes.png")
        plot_confidence(results, out_dir / "confidence.png")
