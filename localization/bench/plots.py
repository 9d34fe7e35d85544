"""Pictures of a localization benchmark: the error CDF and the number-of-classes trend.

Both read the ``results.json`` document of :func:`localization.bench.rendered.run_bench` (rendered
panoramas, errors in metres) or :func:`localization.bench.pairs.run_pairs` (annotated pairs, errors
in metres given a resolution, else in pixels): ``results["unit"]`` says which, and the recall
radii are the keys of ``summary["recall_at"]``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, cast

import numpy as np

from localization.bench.scores import BenchResults, headline
from osmseg.errors import ConfigError
from osmseg.output.atomic import atomic_write_text
from osmseg.units import quantity, ratio

__all__ = ["METHOD_NAMES", "errors_title", "plot_errors", "plot_classes", "plot_confidence"]


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


def plot_errors(results: BenchResults, path: Path) -> Path:
    """CDF of each method's error (all classes), with the top-5 mean distance and two blind guesses;
    the title gives the default method's median and recall (:func:`localization.bench.scores.headline`)."""
    figures = _figures()
    unit = results.get("unit", "m")
    recs, s = results["viewpoints"], results["summary"]
    with figures.figure(6.5, 4.0) as fig:
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
        _cdf(ax, [r["centre_guess"] for r in recs], len(recs), color="0.5", ls="--", label="guess the image centre")
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
        ax.legend(loc="lower right", fontsize=8)
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


def plot_confidence(results: BenchResults, path: Path) -> Path | None:
    """Each method's confidence on matching and on non-matching pairs (histograms, ROC AUC in the title).

    None (nothing drawn) when the run has no non-matching pair (one scene, ``--no-negatives``).
    """
    methods = {m: v for m, v in (results.get("methods") or {}).items() if v.get("roc_auc") is not None}
    if not methods:
        return None
    figures = _figures()
    recs = results["viewpoints"]
    with figures.figure(4.2 * len(methods), 3.6) as fig:
        axes = np.atleast_1d(fig.subplots(1, len(methods)))
        for ax, (m, summary) in zip(axes, methods.items()):
            pos = [r["methods"][m]["confidence"] for r in recs if r["methods"][m]["confidence"] is not None]
            neg = [r["methods"][m]["negative_confidence"] for r in recs
                   if r["methods"][m]["negative_confidence"] is not None]
            bins = np.linspace(min(pos + neg), max(pos + neg) + 1e-9, 25)
            ax.hist(pos, bins=bins, alpha=0.6, color="tab:blue", label="matching aerial image")
            ax.hist(neg, bins=bins, alpha=0.6, color="tab:red", label="another aerial image")
            ax.set_xlabel("kappa of the best match" if m == "profile" else "MAP likelihood (eq. 3.3)")
            ax.set_ylabel(results.get("queries", "queries"))
            ax.set_title(f"{m}: ROC AUC {ratio(summary['roc_auc'])}")
            ax.legend(fontsize=8)
        fig.suptitle("Does the confidence tell a match from a non-match?")
        return cast("Path | None", figures.save_png(fig, path))


def write_results(results: BenchResults, out_dir: Path, plots: bool) -> None:
    """results.json, and errors.png + classes.png when ``plots``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out_dir / "results.json", json.dumps(results, indent=2, sort_keys=True) + "\n")
    if plots:
        plot_errors(results, out_dir / "errors.png")
        plot_classes(results, out_dir / "classes.png")
        plot_confidence(results, out_dir / "confidence.png")
