"""The figure sets of ``docs/figures.py`` on the region search (``docs/localization.md``, "A
region, from OpenStreetMap alone"): its table and what a user's command costs (``region``), the
open horizon (``vista``, ``nullvista``, ``null90vista``), the "not found here" verdict on views of
three towns (``null``, ``sidebyside``, ``null90``, ``null90compass``) and where the search's wrong
answers are lost (``regionceiling``). Each runs a ``benchmarks/bench_region*.py`` on the real
extracts of ``../shared/data``: minutes to an hour of CPU each; ``docs/figures.py --keep DIR
--reuse`` re-renders from the JSON a run left in DIR.

May import ``figures``, ``figure_sets``, ``figure_sets_external`` and ``osmseg``; nothing imports it
but ``figure_sets`` (which registers it).
"""

from __future__ import annotations

import json
import math
from typing import Any

from figure_sets import F, table
from figure_sets_external import KOTKA, benchmark
from figures import REPO_ROOT, Figure, Workspace, figure_set

from localization.profile.profiles import MASK_MIN_CONFIDENCE
from localization.region.search import NULL_MIN_LIFT
from osmseg.units import count, metres, ratio, seconds

#: the rows of docs/localization.md's region table: (label, bench_region.py options)
#: the region table's last kind (heading unknown) also runs its first views through `osmseg localize-region`
REGION_COMMANDS = 3
REGION_KINDS = (
    ("panoramas, camera 2 m and level, heading known", ()),
    ("camera height 1.5-2.5 m, tilt ±2°, the method assumes 2 m and level", ("--eye", "1.5,2.5", "--tilt", "2")),
    ("the same, `--camera-height unknown --tilt 2`", ("--eye", "1.5,2.5", "--tilt", "2", "--search-pose")),
    ("the same, and `--heading unknown`", ("--eye", "1.5,2.5", "--tilt", "2", "--search-pose", "--heading",
                                           "unknown", "--command", str(REGION_COMMANDS))),
)


@figure_set("region", "expensive", needs="shared data")
def region(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/bench_region.py: 30 views of the geometry renderer at Kotka street points, each searched for in the whole Kotka extract"""
    rows, first = [], None
    for label, extra in REGION_KINDS:
        out = ws.root / f"region-{len(rows)}.json"
        ws.run(str(REPO_ROOT / "benchmarks" / "bench_region.py"), *extra, "--json", str(out), python=True)
        s = json.loads(out.read_text(encoding="utf-8"))["summary"]
        first = first or s
        rows.append([label, metres(s["median_error_m"]), ratio(s["within_10m"]), ratio(s["within_25m"]),
                     ratio(s["auc_confidence"]), ratio(s["auc_kappa"]), ratio(s["accepted"]),
                     ratio(s["false_accept"]), seconds(s["median_query_s"]), count(round(s["peak_rss_mb"]))])
    assert first is not None
    return {
        "region.table": F(table(["views", "median", "within 10 m", "25 m", "AUC confidence", "AUC kappa",
                                 "answered at 0.04", "of them wrong", "s/query", "peak MB"], rows),
                          r"(?m)\| [\d.,]+ s \| [\d,]+ \|$"),
        "region.command": F(f"{seconds(s['command_median_cpu_s'])} of CPU per query (median) and at most "
                            f"{count(round(s['command_peak_rss_mb']))} MB resident, giving the same answer as the "
                            f"table's search for {count(s['command_same_answer'])} of its first "
                            f"{count(s['command_runs'])} views"),
        "region.blocks": F(count(first["blocks"])),
        "region.baseline": F(metres(first["baseline_random_street_median_m"])),
    }


#: the open horizon's views: the region table's last kind, drawn at another seed (none of them were looked at
#: while the vista was designed), searched without and with it
VISTA_VIEWS = ("--seed", "1", "--queries", "20", "--eye", "1.5,2.5", "--tilt", "2", "--search-pose", "--heading",
               "unknown")


@figure_set("vista", "expensive", needs="shared data")
def vista(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/bench_region.py --seed 1 --heading unknown --vista-weight 0 | 4: 20 held-out Kotka views searched
    in the whole extract, without and with the open horizon"""
    rows, runs = [], []
    for label, weight in (("heading unknown, no vista", "0"), ("the same, `--vista-weight 4`", "4")):
        s = benchmark(ws, "bench_region.py", *VISTA_VIEWS, "--vista-weight", weight,
                      name=f"bench_region-vista-{weight}")["summary"]
        runs.append(s)
        rows.append([label, count(s["queries"]), metres(s["median_error_m"]), ratio(s["within_10m"]),
                     ratio(s["within_25m"]), ratio(s["auc_confidence"]), ratio(s["accepted_by_verdict"]),
                     ratio(s["false_accept_by_verdict"] or 0.0), seconds(s["median_query_cpu_s"]),
                     count(round(s["peak_rss_mb"]))])
    return {
        "vista.table": F(table(["views", "n", "median", "within 10 m", "25 m", "AUC confidence", "verdict here",
                                "of them wrong", "CPU s/query", "peak MB"], rows),
                         r"(?m)\| [\d.,]+ s \| [\d,]+ \|$"),
        "vista.gain": F(f"{ratio(runs[0]['within_10m'])} to {ratio(runs[1]['within_10m'])}"),
    }


#: the searches of docs/localization.md's "not found here" table: (label, which searches, accepted by)
NULL_ROWS = (("own town, right answers (within 10 m)", "own town, right answers"),
             ("own town, all", "own town"),
             ("another town", "other town"))


def null_rows(summary: dict[str, Any], label: str) -> list[list[str]]:
    """The rows of a "not found here" table for one run of bench_region_null.py (``label`` leads each row)."""
    rows = []
    for name, key in NULL_ROWS:
        alone, verdict = summary["confidence_only"][key], summary["verdict_here"][key]
        rows.append([f"{label}: {name}", count(alone["n"]),
                     f"{alone['accepted']} ({ratio(alone['accepted'] / max(1, alone['n']))})",
                     count(alone["accepted_wrong"]),
                     f"{verdict['accepted']} ({ratio(verdict['accepted'] / max(1, verdict['n']))})",
                     count(verdict["accepted_wrong"])])
    return rows


NULL_COLUMNS = ["searches", "n", "accepted by confidence ≥ 0.04 alone", "of them wrong", "accepted by the verdict",
                "of them wrong"]


@figure_set("null", "expensive", needs="shared data")
def null(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/bench_region_null.py, seeds 0 (threshold chosen on it) and 1 (held out): views of Kotka, Helsinki and West Oakland searched in each town"""
    rows = []
    found, searches = {}, {}
    for seed, role in ((0, "chosen on"), (1, "held out")):
        run = benchmark(ws, "bench_region_null.py", "--queries", "6", "--seed", str(seed), "--renderer", "geometry",
                        name=f"bench_region_null-{seed}")
        s = found[seed] = run["summary"]["geometry"]
        searches[seed] = run["searches"]
        rows += null_rows(s, f"seed {seed} ({role})")
    auc = found[1]["auc_right_vs_other_town"]
    confident = [r for r in searches[0] if (r["confidence"] or 0) >= 0.04 and r["lift"] is not None]
    return {
        "null.other_top": F(" and ".join(ratio(v) for v in sorted(r["lift"] for r in confident
                                                                   if r["from"] != r["in"])[-2:])),
        "null.table": F(table(NULL_COLUMNS, rows)),
        "null.auc": F(f"{ratio(auc['lift over the null'])} (kappa {ratio(auc['kappa'])}, confidence "
                      f"{ratio(auc['confidence'])})"),
    }


@figure_set("nullvista", "expensive", needs="shared data")
def nullvista(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/bench_region_null.py --seed 1 --vista-weight 4: the held-out views of the three towns with the open
    horizon, heading known and unknown"""
    rows, found = [], {}
    for heading in ("known", "unknown"):
        run = benchmark(ws, "bench_region_null.py", "--queries", "6", "--seed", "1", "--renderer", "geometry",
                        "--heading", heading, "--vista-weight", "4", name=f"bench_region_null-vista4-{heading}")
        found[heading] = run["summary"]["geometry"]
        rows += null_rows(found[heading], f"heading {heading}, `--vista-weight 4`")
    auc = found["known"]["auc_right_vs_other_town"]
    return {
        "nullvista.table": F(table(NULL_COLUMNS, rows)),
        "nullvista.auc": F(f"{ratio(auc['lift over the null'])} (kappa {ratio(auc['kappa'])}, confidence "
                           f"{ratio(auc['confidence'])})"),
    }


def lift_needed(searches: list[dict[str, Any]], renderer: str, share: float = 0.05, lift: float = NULL_MIN_LIFT,
                confidence: float = MASK_MIN_CONFIDENCE) -> tuple[float, int, int, int]:
    """What the verdict's lift threshold would have to be for at most ``share`` of the other towns'
    views to be accepted (the verdict also asks a confidence of at least ``confidence``), read off
    ``searches`` (bench_region_null.py's): (the lift the threshold must pass, -inf when any would
    do; of the right answers (own town, within 10 m) with that confidence, how many it keeps and
    how many ``lift``, the default, keeps; the right answers).

    >>> runs = [{"renderer": "g", "from": "A", "in": "B", "confidence": 0.1, "lift": 0.3},
    ...         {"renderer": "g", "from": "A", "in": "A", "confidence": 0.2, "lift": 0.4, "error_m": 1.0},
    ...         {"renderer": "g", "from": "B", "in": "B", "confidence": 0.2, "lift": 0.2, "error_m": 2.0}]
    >>> lift_needed(runs, "g")
    (0.3, 1, 2, 2)
    """
    mine = [s for s in searches if s["renderer"] == renderer]
    others = [s for s in mine if s["from"] != s["in"]]
    confident = sorted((s["lift"] for s in others if s["lift"] is not None and (s["confidence"] or 0.0) >= confidence),
                       reverse=True)
    allowed = int(share * len(others))   # at most: 1 of 36 (2 of 36 is 5.6 %)
    needed = confident[allowed] if len(confident) > allowed else -math.inf
    right = [s for s in mine if s["from"] == s["in"] and s["error_m"] is not None and s["error_m"] <= 10]
    sure = [s for s in right if s["lift"] is not None and (s["confidence"] or 0.0) >= confidence]
    return needed, sum(s["lift"] > needed for s in sure), sum(s["lift"] >= lift for s in sure), len(right)


@figure_set("sidebyside", "expensive", needs="shared data")
def sidebyside(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/bench_region_null.py --renderer both, heading known and unknown: both renderers' views of three towns, each searched in every town"""
    rows, needed = [], []
    for heading in ("known", "unknown"):
        run = benchmark(ws, "bench_region_null.py", "--queries", "6", "--seed", "1", "--renderer", "both",
                        "--heading", heading, name=f"bench_region_both-{heading}")
        for renderer, s in run["summary"].items():
            own, mine, other = s["own_town"], s["verdict_here"]["own town"], s["verdict_here"]["other town"]
            auc = own["auc_right_vs_wrong"]
            rows.append([f"panoramas, heading {heading}" if renderer == "geometry" else "", renderer, count(own["n"]),
                         metres(own["median_error_m"]), ratio(own["within_10m"]), ratio(own["within_25m"]),
                         "-" if auc is None else ratio(auc), f"{mine['accepted']} / {mine['accepted_wrong']}",
                         f"{other['accepted']} of {other['n']}"])
            if heading == "unknown":
                lift, kept, default, right = lift_needed(run["searches"], renderer)
                above = "any lift" if lift == -math.inf else f"above {lift:.3f}"
                needed.append(f"{above} for the {renderer} renderer's views, which keeps {kept} of their {right} "
                              f"right answers ({NULL_MIN_LIFT:g} keeps {default})")
    return {"sidebyside.table": F(table(["views", "renderer", "n", "median", "within 10 m", "within 25 m",
                                         "right/wrong AUC", "own town: accepted / wrong",
                                         "other towns: accepted"], rows)),
            "sidebyside.needed": F("; ".join(needed))}


@figure_set("regionceiling", "expensive", needs="shared data")
def regionceiling(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/bench_region_ceiling.py --heading unknown --vista-weight 0 4: where the region search's wrong
    answers are lost, without and with the open horizon"""
    run = benchmark(ws, "bench_region_ceiling.py", "--queries", "10", "--heading", "unknown", "--vista-weight", "0",
                    "4", name="bench_region_ceiling-unknown-vista")
    by = run["by_vista_weight"]
    gaps = sorted(r["answer_score"] - r["truth_score"] for r in run["rows"]
                  if r["kind"] == "look-alike" and r["vista_weight"] == 0)
    flipped = [r["view"] for r in run["rows"] if r["vista_weight"] == 4 and r["kind"] == "right"
               and any(o["view"] == r["view"] and o["vista_weight"] == 0 and o["kind"] != "right" for o in run["rows"])]
    lost = [r["view"] for r in run["rows"] if r["vista_weight"] == 4 and r["kind"] != "right"
            and any(o["view"] == r["view"] and o["vista_weight"] == 0 and o["kind"] == "right" for o in run["rows"])]
    import osmium

    buildings = levels = heights = 0
    for obj in osmium.FileProcessor(str(ws.shared.joinpath(*KOTKA)), osmium.osm.WAY | osmium.osm.RELATION):
        if "building" in obj.tags:
            buildings += 1
            levels += "building:levels" in obj.tags
            heights += "height" in obj.tags
    return {
        "regionceiling.heights": F(f"{levels} of Kotka's {buildings} carry `building:levels`, "
                                   f"{heights or 'none'} `height`"),
        "regionceiling.table": F(table(["views", "n", "right (within 10 m)", "lost at the coarse stage",
                                        "lost at the fine stage", "a look-alike fits better", "recall", "ceiling"],
                                       [[label, count(s["queries"]), count(s["right"]),
                                         count(s["lost at the coarse stage"]), count(s["lost at the fine stage"]),
                                         count(s["look-alike"]), ratio(s["recall"]), ratio(s["ceiling"])]
                                        for label, s in (("panoramas, heading unknown", by["0"]),
                                                         ("the same, `--vista-weight 4`", by["4"]))])),
        "regionceiling.gaps": F(f"{gaps[0]:.4f} to {gaps[-1]:.4f}" if gaps else "none"),
        "regionceiling.vista": F(f"{len(flipped)} of the {by['0']['queries'] - by['0']['right']} wrong answers right "
                                 f"with it, {len(lost)} right answers lost"),
    }


def _null90_photos(ws: Workspace, key: str, label: str, extra: tuple[str, ...], name: str) -> dict[str, Figure]:
    """The 90° photos of the three towns (seed 0, heading unknown) searched with ``extra`` options:
    ``KEY.table``, ``KEY.recall`` (own town) and ``KEY.auc`` (right answers against other towns)."""
    run = benchmark(ws, "bench_region_null.py", "--queries", "6", "--seed", "0", "--fov", "90", "--heading",
                    "unknown", *extra, "--renderer", "geometry", name=name)
    s = run["summary"]["geometry"]
    auc, own = s["auc_right_vs_other_town"], s["own_town"]
    return {
        f"{key}.table": F(table(NULL_COLUMNS, null_rows(s, label))),
        f"{key}.recall": F(f"{ratio(own['within_10m'])} within 10 m and {ratio(own['within_25m'])} within 25 m"),
        f"{key}.auc": F(f"{ratio(auc['lift over the null'])} (kappa {ratio(auc['kappa'])}, confidence "
                        f"{ratio(auc['confidence'])})"),
    }


@figure_set("null90compass", "expensive", needs="shared data")
def null90compass(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/bench_region_null.py --fov 90 --heading unknown --compass 25: the 90° photos with a compass good to ±25°"""
    return _null90_photos(ws, "null90compass", "90° photos, compass ±25°", ("--compass", "25"),
                          "bench_region_null90-compass-0")


@figure_set("null90", "expensive", needs="shared data")
def null90(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/bench_region_null.py --fov 90 --heading unknown: 90° photos of the three towns, each searched in every town"""
    run = benchmark(ws, "bench_region_null.py", "--queries", "6", "--seed", "0", "--fov", "90", "--heading",
                    "unknown", "--renderer", "geometry", name="bench_region_null90-0")
    s = run["summary"]["geometry"]
    auc = s["auc_right_vs_other_town"]
    return {
        "null90.table": F(table(NULL_COLUMNS, null_rows(s, "90° photos, heading unknown"))),
        "null90.auc": F(f"{ratio(auc['lift over the null'])} (kappa {ratio(auc['kappa'])}, confidence "
                        f"{ratio(auc['confidence'])})"),
    }


@figure_set("null90vista", "expensive", needs="shared data")
def null90vista(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/bench_region_null.py --fov 90 --heading unknown --vista-weight 4: the null90 photos with the open horizon"""
    return _null90_photos(ws, "null90vista", "90° photos, heading unknown, `--vista-weight 4`", ("--vista-weight", "4"),
                          "bench_region_null90-vista4")
