"""The figure sets of ``docs/figures.py``: what runs behind each marker of README.md and docs/*.md.

The sets on osmseg's own code and the demo's masks are here, with the helpers; those that need
the authors' pairs, ``../shared/data`` or minutes of benchmarks are in :mod:`figure_sets_external`,
the region search's in :mod:`figure_sets_region`, the 90° photos over seeds in
:mod:`figure_sets_photos` and training on real held-out imagery in :mod:`figure_sets_heldout`.
Each function measures the figures of one set (keys ``SET.*``) in a :class:`figures.Workspace`
and returns them as text at :mod:`osmseg.units`' precision. Commands run as the docs print them
(the transcript blocks show exactly these); analyses the commands do not print read their
results.json or call the library the commands call.
"""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Any

from figures import DEMO_BUILD, Figure, Workspace, figure_set, transcript

from osmseg.units import count, degrees, factor, metres, number, ratio, seconds

#: the s/view column of localize-bench's method table (the last number of a row, and the label over it, with
#: the spaces that pad them to the column's width): never the same twice
TIMING_COLUMN = r"(?m) +(?:\d[\d.]*|s/view)$"


def F(text: Any, volatile: str | None = None) -> Figure:
    return Figure(str(text), volatile)


def of(counted: int, total: int) -> str:
    """``"31 of 40"``."""
    return f"{counted} of {total}"


def relation(a: float, b: float) -> str:
    """How ``a`` stands to ``b``: "about" within 5 %, else "above" or "below"."""
    return "about" if abs(a - b) <= 0.05 * abs(b) else ("above" if a > b else "below")


def by_classes(results: dict[str, Any], kind: str) -> str:
    """``"155.89, 126.24, 119.32 m with 2, 3 and 4"``: the median error with each number of classes."""
    by_k = {k: v["summary"] for k, v in results["by_num_classes"].items()}
    ks = sorted(by_k, key=int)
    return (", ".join(number(by_k[k]["median_error"], kind) for k in ks) + f" {kind} with "
            + (f"{', '.join(ks[:-1])} and {ks[-1]}" if len(ks) > 1 else ks[0]))


# --------------------------------------------------------------------------- cheap


@figure_set("zoom", "cheap")
def zoom(ws: Workspace) -> dict[str, Figure]:
    """ground pixel size and sample span at the default zoom (osmseg.grid.ground_resolution, the city presets)"""
    from osmseg.builder.run import DEFAULT_ZOOM
    from osmseg.grid import ground_resolution, sample_grid
    from osmseg.places import find_preset

    side = sample_grid(0.0, 0.0, DEFAULT_ZOOM).width
    sf, london, berlin = (find_preset(n) for n in ("San Francisco", "London", "Berlin"))
    at = {p.name: ground_resolution(p.lat, DEFAULT_ZOOM) for p in (sf, london, berlin)}
    equator = ground_resolution(0.0, DEFAULT_ZOOM)
    north = min(at[london.name], at[berlin.name])
    return {
        "zoom.examples": F(f"{number(equator, 'm')} m/px at the equator, {metres(at[sf.name])} at "
                           f"{degrees(sf.lat)} (San Francisco), {number(north, 'm')}–"
                           f"{metres(max(at[london.name], at[berlin.name]))} at {number(london.lat, 'deg')}–"
                           f"{degrees(berlin.lat)} (London, Berlin)"),
        "zoom.span": F(f"{number(side * north, 'm')}–{metres(side * equator)}"),
    }


@figure_set("model", "cheap", needs="torch")
def model(ws: Workspace) -> dict[str, Figure]:
    """parameters of AirSegNet13 at width 1.0 (training.models.networks)"""
    from training.models.networks import build_model, model_spec

    net = build_model(model_spec("airsegnet13", 1.0))
    return {"model.parameters": F(count(sum(p.numel() for p in net.parameters())))}


@figure_set("demo", "cheap")
def demo(ws: Workspace) -> dict[str, Figure]:
    """what osmseg demo builds, localizes and trains (osmseg.demo, localization.cli.demo)"""
    from localization.cli.demo import DEMO_TRAINING, DEMO_VIEWPOINTS
    from osmseg.demo import demo_config

    config = demo_config(Path("demo"))
    return {"demo.samples": F(config.samples), "demo.viewpoints": F(DEMO_VIEWPOINTS),
            "demo.width": F(DEMO_TRAINING["width"]), "demo.epochs": F(DEMO_TRAINING["epochs"])}


@figure_set("providers", "cheap")
def providers(ws: Workspace) -> dict[str, Figure]:
    """the zoom range of each recommended aerial provider in the installed xyzservices (osmseg.imagery)"""
    from osmseg.imagery import aerial_providers
    from osmseg.imagery.providers import find_tile_provider

    out = {}
    for p in aerial_providers():
        entry = find_tile_provider(p.name) or {}
        low, high = entry.get("min_zoom"), entry.get("max_zoom")
        out[f"providers.zoom.{p.name}"] = F("no limit given" if high is None else f"{low or 0}–{high}")
    return out


#: the benchmark the README and docs/localization.md quote: both methods on 40 views of the demo masks
DEMO40 = ("localize-bench", "demo/dataset", "--out", "bench/", "--viewpoints", "40", "--methods", "paper,profile")


@figure_set("demo40", "cheap")
def demo40(ws: Workspace) -> dict[str, Figure]:
    """osmseg demo --no-train --no-localize, then localize-bench demo/dataset --viewpoints 40 --methods paper,profile"""
    ws.demo_dataset()
    built, _ = ws.run(*DEMO_BUILD)
    printed, r = ws.bench(*DEMO40[1:])
    paper, profile, b = r["methods"]["paper"], r["methods"]["profile"], r["baselines"]
    versus = relation(paper["mean_error"], b["centre_guess_mean"])
    verdict = {"above": "worse than", "about": "no better than", "below": "better than"}[versus]
    return {
        "demo40.transcript": F(transcript((DEMO_BUILD, built), (DEMO40, printed)), TIMING_COLUMN),
        "demo40.resolution": F(metres(r["scenes"][0]["resolution_m"])),
        "demo40.paper.median": F(metres(paper["median_error"])),
        "demo40.paper.answered": F(of(paper["answered"], paper["n"])),
        "demo40.paper.unanswered": F(of(paper["unanswered"], paper["n"])),
        "demo40.paper.recall25": F(ratio(paper["recall_at"]["25"])),
        "demo40.paper.by_classes": F(by_classes(r, "m")),
        "demo40.verdict": F(f"{verdict} guessing the image centre: its mean error ({metres(paper['mean_error'])}) is "
                            f"{versus} the centre's ({metres(b['centre_guess_mean'])})"),
        "demo40.median_vs_candidate": F(f"{relation(paper['median_error'], b['random_candidate_median'])} that of a "
                                        f"random candidate ({metres(b['random_candidate_median'])})"),
        "demo40.centre": F(metres(b["centre_guess_mean"])),
        "demo40.profile.median": F(metres(profile["median_error"])),
        "demo40.profile.recall10": F(ratio(profile["recall_at"]["10"])),
        "demo40.profile.auc": F(ratio(profile["roc_auc"])),
    }


# --------------------------------------------------------------------------- helpers for tables and prose


def table(header: list[str], rows: list[list[str]]) -> str:
    """A Markdown table, with blank lines around it so that the markers stay blocks of their own."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n\n" + "\n".join(lines) + "\n\n"


def change(before: float, after: float, kind: str = "ratio") -> str:
    """``"falls from 0.975 to 0.950"`` (or rises, or stays), at ``kind``'s precision."""
    a, b = number(before, kind), number(after, kind)
    if a == b:
        return f"stays at {a}"
    return f"{'falls' if after < before else 'rises'} from {a} to {b}"


def span(values: list[float], kind: str) -> str:
    """``"0.32 to 0.71"``: the smallest and largest of ``values`` at ``kind``'s precision."""
    return f"{number(min(values), kind)} to {number(max(values), kind)}"


def px_stats(records: list[dict[str, Any]], method: str, radii: tuple[int, ...] = (25, 50, 100)) -> dict[str, Any]:
    """Mean, median and recall (unanswered count as misses) of ``method``'s pixel errors."""
    errors = [r["methods"][method]["error_px"] for r in records if r["methods"][method]["error_px"] is not None]
    n = len(records)
    return {"mean": statistics.fmean(errors) if errors else None, "median": statistics.median(errors) if errors else None,
            "recall": {k: sum(e <= k for e in errors) / n for k in radii}}


# --------------------------------------------------------------------------- expensive: the demo masks


NOISE = ("--confusion", "0.1", "--miss-prob", "0.2", "--offset", "2", "--height-spread", "0.5")
#: the rows of docs/localization.md's "Methods side by side": (label, options added to DEMO40)
SETTINGS = (
    ("panoramas, heading known (default)", ()),
    ("`--view-heading unknown`", ("--view-heading", "unknown")),
    ("noise: `" + " ".join(NOISE) + "`", NOISE),
    ("the same noise, `--view-heading unknown`", (*NOISE, "--view-heading", "unknown")),
    ("90° photos, `--fov 90 --view-heading unknown`", ("--fov", "90", "--view-heading", "unknown")),
)
#: the profile method's default "not in this image" kappa threshold for an aerial mask (localization.profile.search)
MASK_THRESHOLD = 0.6


@figure_set("settings", "expensive")
def settings(ws: Workspace) -> dict[str, Figure]:
    """localize-bench demo/dataset --viewpoints 40 --methods paper,profile under five settings; the profile weights off"""
    ws.demo_dataset()
    rows, runs = [], []
    for i, (label, extra) in enumerate(SETTINGS):
        args = DEMO40[1:] if not extra else (*DEMO40[1:3], f"bench-{i}/", *DEMO40[4:], *extra)
        _, r = ws.bench(*args)
        runs.append(r)
        for name in ("paper", "profile"):
            m = r["methods"][name]
            rows.append([label if name == "paper" else "", name, metres(m["median_error"]), metres(m["mean_error"]),
                         *(ratio(m["recall_at"][k]) for k in ("10", "25", "50")),
                         degrees(m["median_heading_error_deg"]), ratio(m["roc_auc"]), seconds(m["localize_mean_s"])])
    header = ["views", "method", "median", "mean", "recall@10 m", "@25 m", "@50 m", "heading error", "ROC AUC",
              "s/view"]
    within = [v["methods"]["profile"] for r in runs for v in r["viewpoints"]
              if v["methods"]["profile"]["error"] is not None and v["methods"]["profile"]["error"] <= 10]
    lost = sum(1 for v in within if v["kappa"] < MASK_THRESHOLD)
    rejected = []
    for i, what in ((0, "with the heading known"), (1, "with it unknown"), (4, "with 90° photos")):
        negatives = [v["methods"]["profile"]["negative_kappa"] for v in runs[i]["viewpoints"]
                     if v["methods"]["profile"]["negative_kappa"] is not None]
        rejected.append(f"{of(sum(c < MASK_THRESHOLD for c in negatives), len(negatives))} {what}")
    weights = profile_weights(ws)
    return {
        "settings.table": F(table(header, rows), r"(?m)(?<=\| )[\d.,]+ s(?= \|$)"),
        "settings.unknown.profile.median": F(metres(runs[1]["methods"]["profile"]["median_error"])),
        "settings.kept": F(f"every answer within 10 m is kept in the {len(runs)} settings" if not lost else
                           f"{of(lost, len(within))} answers within 10 m in the {len(runs)} settings fall below it"),
        "settings.rejected": F(", ".join(rejected)),
        "settings.weights": F(f"{change(weights['on', 'known'], weights['off', 'known'])} with the heading known and "
                              f"{change(weights['on', 'unknown'], weights['off', 'unknown'])} with it unknown"),
    }


def profile_weights(ws: Workspace) -> dict[tuple[str, str], float]:
    """Recall at 10 m of the profile method on 40 other views (seed 1) with and without its class
    weights, heading known and unknown (library calls: localize-bench has no option for them)."""
    from localization.bench.rendered import BenchConfig, load_dataset_scenes, run_bench
    from localization.profile.search import ProfileConfig

    scenes = load_dataset_scenes(ws.root / ws.demo_dataset())
    out = {}
    for weighted in ("on", "off"):
        for heading in ("known", "unknown"):
            config = BenchConfig(viewpoints=40, seed=1, methods=("profile",), subsets=False, negatives=False,
                                 heading=heading, profile=ProfileConfig(min_confidence=-1.0, min_kappa=-1.0,
                                                                        weighted=None if weighted == "on" else False))
            r = run_bench(scenes, config, ws.root / f"weights-{weighted}-{heading}", plots=False)
            out[weighted, heading] = r["methods"]["profile"]["recall_at"]["10"]
    return out


#: the rows of the perfect-correspondence table: (aerial landmarks, view range, options)
VISIBLE = (
    ("centroid", "100 m", ()),
    ("grid, stride 50", "100 m", ("--landmark-mode", "grid", "--grid-stride", "50")),
    ("grid, stride 50", "40 m", ("--landmark-mode", "grid", "--grid-stride", "50", "--max-range", "40")),
    ("component", "100 m", ("--landmark-mode", "component")),
)


@figure_set("visible", "expensive")
def visible(ws: Workspace) -> dict[str, Figure]:
    """localize-bench demo/dataset --viewpoints 40 --methods paper --query-landmarks visible --no-subsets, four landmark modes"""
    ws.demo_dataset()
    rows, factors = [], []
    for i, (landmarks, reach, extra) in enumerate(VISIBLE):
        _, r = ws.bench("demo/dataset", "--out", f"visible-{i}/", "--viewpoints", "40", "--methods", "paper",
                        "--query-landmarks", "visible", "--no-subsets", *extra)
        s, b = r["summary"], r["baselines"]
        rows.append([landmarks, reach, metres(s["median_error"]), ratio(s["recall_at"]["25"]),
                     ratio(s["recall_at"]["50"]), metres(b["random_candidate_median"])])
        factors.append(b["random_candidate_median"] / s["median_error"])
    return {
        "visible.table": F(table(["aerial landmarks", "view range", "median error", "recall@25 m", "@50 m",
                                  "a random candidate"], rows)),
        "visible.factors": F(f"{factor(min(factors))} to {factor(max(factors))}"),
    }


import figure_sets_external  # noqa: E402,F401  (registers the pairs, benchmark and shared-data sets)
import figure_sets_heldout  # noqa: E402,F401  (registers the held-out training sets)
import figure_sets_photos  # noqa: E402,F401  (registers the 90° photos over seeds)
import figure_sets_region  # noqa: E402,F401  (registers the region search's sets)


@figure_set("recipes", "cheap", needs="torch")
def recipes(ws: Workspace) -> dict[str, Figure]:
    """the settings of the shipped training recipes (training.run.recipe.RECIPES)"""
    from training.run.recipe import MIN_STEPS_PER_EPOCH, RECIPES

    def shown(name: str, value: Any) -> str:
        if name == "steps_per_epoch" and value is None:
            return f"cover the training pixels once, at least {MIN_STEPS_PER_EPOCH}"
        return "-" if value is None else str(value)

    recipes = [r.to_dict() for r in RECIPES.values()]
    grid = "(grid: 360x480 patches)"
    rows = [[f"`{k}`", *(grid if r["sampling"] == "grid" and k in ("crop", "steps_per_epoch") else shown(k, r[k])
                          for r in recipes)] for k in recipes[0] if k != "name"]
    return {"recipes.table": F(table(["setting", *(f"{r['name']}" for r in recipes)], rows))}
