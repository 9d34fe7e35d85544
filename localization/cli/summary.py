"""What ``osmseg localize-bench`` and ``localize-pairs`` print on the terminal: a few lines and the methods side by side.

Imports: osmseg.units, osmseg.texttable and localization.bench's scores and compare (never the commands).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from localization.bench.scores import BenchResults

from osmseg.texttable import text_table
from osmseg.units import column, number, pixels, plural, quantity, ratio

__all__ = ["format_summary", "method_table"]

#: the one of each kind of query results.json names in the plural (``queries``)
ONE_QUERY = {"rendered panoramas": "rendered panorama", "annotated pairs": "annotated pair", "queries": "query"}


def format_summary(results: BenchResults) -> str:
    """A few lines for the terminal: the default method's result when it ran (else the first
    method's: :func:`localization.bench.scores.headline`), the blind baselines, the first method's
    class-subset trend when it was computed (the paper method's), and every method side by side.
    Figures at the one precision of :mod:`osmseg.units`."""
    from localization.bench.scores import headline

    u = results.get("unit", "m")
    b = results["baselines"]
    name, s = headline(results)
    methods = results.get("methods") or {}
    first = (results.get("settings", {}).get("methods") or list(methods) or [name])[0]  # the subsets' method
    rec = ", ".join(f"@{r} {u} {ratio(v)}" for r, v in s["recall_at"].items())
    second = list(s["recall_at"])[1]
    in_px = "" if u == "px" else f" ({pixels(s['mean_error_px'])})"
    queries = results.get("queries", "queries")
    lines = [
        f"{plural(s['n'], ONE_QUERY.get(queries, queries), queries)}, classes {'+'.join(results['classes'])}",
        f"{name + ' method' if name else 'result'}: {s['answered']} answered, {s['unanswered']} unanswered, "
        f"{s['tied']} tied; error median {quantity(s['median_error'], u)}, mean {quantity(s['mean_error'], u)}"
        f"{in_px}; top-5 mean distance {quantity(s['top5_mean_distance'], u)}",
        f"recall {rec}; blind guesses: {_blind_guesses(b, u)}",
    ]
    random_median = b.get("random_candidate_median")
    if random_median is not None:
        own = (methods.get(first) or results["summary"]).get("median_error")
        lines.append(_candidate_baseline(first, random_median, own, u))
    by_k = results["by_num_classes"]
    if len(by_k) > 1:
        lines.append(f"{first} method by number of landmark classes:")
        for k, entry in sorted(by_k.items(), key=lambda kv: int(kv[0])):
            e = entry["summary"]
            lines.append(f"  {plural(int(k), 'class')} ({plural(len(entry['subsets']), 'subset')}): median "
                         f"{quantity(e['median_error'], u)}, "
                         f"recall@{second} {u} {ratio(e['recall_at'][second])}, unanswered {e['unanswered']}/{e['n']}")
    if methods:
        lines.append(method_table(methods, u))
    return "\n".join(lines)


def _candidate_baseline(method: str, random_median: float, median: float | None, unit: str) -> str:
    """The line that measures ``method``'s answers against a random one of its own candidates: the
    baseline that says whether its scoring of the candidates helps at all.

    >>> _candidate_baseline("paper", 162.791, 138.72, "m")
    "baseline of the paper method, one of its own candidates taken at random: median error 162.79 m (the method's answers: 138.72 m)"
    """
    return (f"baseline of the {method} method, one of its own candidates taken at random: median error "
            f"{quantity(random_median, unit)} (the method's answers: {quantity(median, unit)})")


def _blind_guesses(b: dict[str, Any], unit: str) -> str:
    """The blind guesses' mean errors; no image centre's where it is the truth itself (annotated
    pairs without truth.csv): there is no truth to compare it to.

    >>> _blind_guesses({"centre_guess_mean": None, "random_guess_mean": 291.08}, "px")
    'random 291.1 px (the image centre is no baseline: without truth.csv it is taken as the truth)'
    """
    random = f"random {quantity(b['random_guess_mean'], unit)}"
    if b.get("centre_guess_mean") is None:
        return f"{random} (the image centre is no baseline: without truth.csv it is taken as the truth)"
    return f"image centre {quantity(b['centre_guess_mean'], unit)}, {random}"


def method_table(methods: dict[str, Any], unit: str) -> str:
    """The methods side by side (the numbers of results.json's ``methods``), in two tables of one
    label per column: how near the answers are (errors in ``unit``, recall as ratios, heading error
    in degrees, seconds per view), then how well each method's confidence tells good answers from
    bad ones (ROC AUCs, and the share of views answered at the method's confidence threshold)."""
    from localization.bench.compare import RIGHT_WRONG

    radii = list(next(iter(methods.values()))["recall_at"])
    per_view = column([m["localize_mean_s"] for m in methods.values()], "s")  # one precision in the column
    errors = text_table(
        ["method", "answered", f"median {unit}", f"mean {unit}", *(f"@{r} {unit}" for r in radii), "heading error °",
         "s/view"],
        [[name, f"{m['answered']}/{m['n']}", number(m["median_error"], unit), number(m["mean_error"], unit),
          *(number(m["recall_at"][r], "ratio") for r in radii), number(m["median_heading_error_deg"], "deg"),
          seconds] for (name, m), seconds in zip(methods.items(), per_view)])
    right, wrong = (f"{v:g} m" for v in RIGHT_WRONG)
    judged = any("right_wrong_auc" in m for m in methods.values())  # errors in metres (pairs in pixels: none)
    legend = ("confidence (match/other AUC: a view in its own scene vs in another"
              + (f"; right/wrong AUC: within {right} vs beyond {wrong}" if judged else "") + "):")
    confidence = text_table(
        ["method", "match/other AUC", "right/wrong AUC", "threshold", "accepted", "of them wrong"],
        [[name, number(m["roc_auc"], "ratio"), number(m.get("right_wrong_auc"), "ratio"),
          "-" if m.get("threshold") is None else f"{m['threshold']:g}", number(m.get("accepted"), "ratio"),
          number(m.get("false_accept"), "ratio")] for name, m in methods.items()])
    return "\n".join([errors, legend, confidence])
