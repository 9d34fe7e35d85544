"""What ``osmseg localize-bench`` and ``localize-pairs`` print on the terminal: a few lines and the methods side by side.

Imports: osmseg.units and localization.bench.scores (never the commands).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from localization.bench.scores import BenchResults

from osmseg.units import number, pixels, quantity, ratio

__all__ = ["format_summary", "method_table"]


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
    lines = [
        f"{s['n']} {results.get('queries', 'queries')}, classes {'+'.join(results['classes'])}",
        f"{name + ' method' if name else 'result'}: {s['answered']} answered, {s['unanswered']} unanswered, "
        f"{s['tied']} tied; error median {quantity(s['median_error'], u)}, mean {quantity(s['mean_error'], u)}"
        f"{in_px}; top-5 mean distance {quantity(s['top5_mean_distance'], u)}",
        f"recall {rec}; blind guesses: image centre {quantity(b['centre_guess_mean'], u)}, "
        f"random {quantity(b['random_guess_mean'], u)}",
    ]
    if b.get("random_candidate_median") is not None:
        lines.append(f"{first} method, a random candidate: median {quantity(b['random_candidate_median'], u)}")
    by_k = results["by_num_classes"]
    if len(by_k) > 1:
        lines.append(f"{first} method by number of landmark classes:")
        for k, entry in sorted(by_k.items(), key=lambda kv: int(kv[0])):
            e = entry["summary"]
            lines.append(f"  {k} classes ({len(entry['subsets'])} subsets): median {quantity(e['median_error'], u)}, "
                         f"recall@{second} {u} {ratio(e['recall_at'][second])}, unanswered {e['unanswered']}/{e['n']}")
    if methods:
        lines.append(method_table(methods, u))
    return "\n".join(lines)


def method_table(methods: dict[str, Any], unit: str) -> str:
    """The methods side by side: one row each (the numbers of results.json's ``methods``), errors
    in ``unit``, recall and AUC as ratios, heading error in degrees, time in seconds per view."""
    radii = list(next(iter(methods.values()))["recall_at"])
    head = (f"{'method':<8} {'answered':>8} {'median ' + unit:>9} {'mean ' + unit:>9} "
            + " ".join(f"{'@' + r + unit:>6}" for r in radii) + f" {'heading°':>8} {'AUC':>6} {'s/view':>7}")
    rows = [head]
    for name, m in methods.items():
        rows.append(f"{name:<8} {str(m['answered']) + '/' + str(m['n']):>8} {number(m['median_error'], unit):>9} "
                    f"{number(m['mean_error'], unit):>9} "
                    + " ".join(f"{number(m['recall_at'][r], 'ratio'):>6}" for r in radii)
                    + f" {number(m['median_heading_error_deg'], 'deg'):>8} {number(m['roc_auc'], 'ratio'):>6} "
                    f"{number(m.get('right_wrong_auc'), 'ratio'):>7} {number(m.get('accepted'), 'ratio'):>8} "
                    f"{number(m.get('false_accept'), 'ratio'):>6} {number(m['localize_mean_s'], 's'):>7}")
    return "\n".join(rows)
