"""The figure set of ``docs/figures.py`` on 90° photos, heading unknown, in the renderers table's
1280² mask of Kotka (376 m a side, views at least 20 m inside it) over several seeds
(``photoseeds``): that table's 90° row is one seed of 40 street points, and another draw of them
moves the recall by more than the target's margin.

May import ``figures``, ``figure_sets``, ``figure_sets_external`` and ``osmseg``; nothing imports it
but ``figure_sets`` (which registers it).
"""

from __future__ import annotations

import json
import statistics
from collections.abc import Callable
from typing import Any

from figure_sets import F, of, table
from figure_sets_external import QUERY_KINDS, benchmark, kotka_mask
from figures import Figure, Workspace, figure_set

from localization.profile.profiles import MASK_MIN_CONFIDENCE
from osmseg.units import metres, ratio

#: the seeds of the photos' street points; seed 0 is the renderers and ceiling tables' run
PHOTO_SEEDS = (0, 1, 2, 3, 4)


def spread(values: list[float], show: Callable[[float], str] = ratio) -> str:
    """``mean ± sd (min–max)`` over seeds.

    >>> spread([0.5, 0.6, 0.7])
    '0.600 ± 0.100 (0.500–0.700)'
    """
    if len(values) < 2:
        raise ValueError(f"a spread needs two seeds or more, not {len(values)}")
    return f"{show(statistics.mean(values))} ± {show(statistics.stdev(values))} ({show(min(values))}–{show(max(values))})"


def share_interval(counted: int, total: int) -> str:
    """``counted`` of ``total`` as a share with its 95 % Wilson interval (scipy): what a few dozen
    answers can say about a rate.

    >>> share_interval(3, 46)
    '3 of 46 (0.065; 95 % interval 0.022–0.175)'
    """
    from scipy.stats import binomtest

    ci = binomtest(counted, total).proportion_ci(confidence_level=0.95, method="wilson")
    return f"{of(counted, total)} ({ratio(counted / total)}; 95 % interval {ratio(ci.low)}–{ratio(ci.high)})"


def bench_results(ws: Workspace, out: str, *args: str) -> dict[str, Any]:
    """``osmseg localize-bench ... --out OUT/ ARGS``'s results.json; with ``--reuse``, the one a
    run left in the workspace."""
    done = ws.root / out / "results.json"
    if ws.reuse and done.is_file():
        return dict(json.loads(done.read_text(encoding="utf-8")))
    return ws.bench("kotka.tif", "--out", f"{out}/", *args)[1]


@figure_set("photoseeds", "expensive", needs="shared data")
def photoseeds(ws: Workspace) -> dict[str, Figure]:
    """localize-bench --fov 90 --view-heading unknown on the 1280² Kotka mask, seeds 0-4, both renderers, each run's ceiling (bench_ceiling.py) beside it"""
    osm, res = kotka_mask(ws)
    rows, found = [], {}
    for renderer in ("mask", "geometry"):
        more = ("--renderer", "geometry", "--osm", osm) if renderer == "geometry" else ()
        per: dict[str, list[float]] = {"10": [], "25": [], "ceiling": [], "centre": []}
        accepted = wrong = unread = 0
        for seed in PHOTO_SEEDS:
            out = f"photo90-{renderer}-{seed}"
            r = bench_results(ws, out, "--aerial-resolution", res.strip(), "--viewpoints", "40", "--methods",
                              "profile", "--no-negatives", "--save-panoramas", "40", "--seed", str(seed), *more,
                              *QUERY_KINDS[2][1])
            c = benchmark(ws, "bench_ceiling.py", str(ws.root / out), str(ws.root / "kotka.tif"), "--right", "25",
                          name=f"bench_ceiling-{out}")
            m, views = r["methods"]["profile"], [v["methods"]["profile"] for v in r["viewpoints"]]
            took = [v for v in views if v["confidence"] is not None and v["confidence"] >= m["threshold"]]
            bad = sum(v["error"] is None or v["error"] > 50 for v in took)
            nothing = round(c["shares"]["nothing to read"] * c["views"])
            accepted, wrong, unread = accepted + len(took), wrong + bad, unread + nothing
            for key in ("10", "25"):
                per[key].append(m["recall_at"][key])
            per["ceiling"].append(c["ceiling"])
            per["centre"].append(r["baselines"]["centre_guess_mean"])
            rows.append([renderer if seed == PHOTO_SEEDS[0] else "", str(seed), ratio(m["recall_at"]["10"]),
                         ratio(m["recall_at"]["25"]), ratio(c["ceiling"]), str(nothing), f"{len(took)} / {bad}",
                         metres(r["baselines"]["centre_guess_mean"])])
        rows.append(["", f"**{len(PHOTO_SEEDS)} seeds**", spread(per["10"]), spread(per["25"]), spread(per["ceiling"]),
                     str(unread), f"{accepted} / {wrong} ({ratio(wrong / max(1, accepted))})",
                     metres(statistics.mean(per["centre"]))])
        found[renderer] = {"per": per, "accepted": accepted, "wrong": wrong}
    geo, mask = found["geometry"], found["mask"]
    return {
        "photoseeds.table": F(table(["renderer", "seed", "within 10 m", "within 25 m", "ceiling (25 m)",
                                     "nothing to read", f"accepted at {MASK_MIN_CONFIDENCE:g} / wrong",
                                     "image centre guess"], rows)),
        "photoseeds.recall": F(spread(geo["per"]["25"])),
        "photoseeds.ceiling": F(spread(geo["per"]["ceiling"])),
        "photoseeds.wrong": F(share_interval(geo["wrong"], geo["accepted"])),
        "photoseeds.wrong.mask": F(share_interval(mask["wrong"], mask["accepted"])),
    }
