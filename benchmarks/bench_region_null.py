"""Is a view from this district at all? Region search of views from one town in another town's OpenStreetMap.

Run: ``.venv/bin/python benchmarks/bench_region_null.py [--queries 8] [--heading known|unknown] [--fov 360]
[--json PATH]``. The towns are the real extracts of ``../shared/data``: Kotka (a 1 km box of
``helsinki-osm/kotka.osm.pbf``), Helsinki centre (``helsinki-osm/helsinki.osm.pbf``) and West
Oakland (``oakland-osm/west-oakland.osm``). At seeded street points of each town, views are
drawn by two renderers (``--renderer both``, the default, or one of them): the **geometry**
renderer (:mod:`localization.bench.georender`, independent of the method: 3-D ray casting over
the OSM geometry, heights it draws, camera 1.5-2.5 m, tilt ±1°) and osmseg's own **mask**
renderer (:mod:`localization.bench.render`, the method's model of a street: class heights over
the drawn mask, a level camera 1.5-2.5 m up). Each view is searched for in every town: in its
own town it has a right answer (within 10 m), in the others none.

For each search it records what the region search says (:func:`localization.region.search.search_region`):
the best score, kappa, confidence, and the **verdict** (``here`` / ``not sure`` / ``not found here``),
and prints, per kind of search (own town, other town), how often a view is accepted (its verdict
``here``, at this osmseg's thresholds: ``--summarise JSON`` counts an earlier run's searches again)
and how often an accepted answer is wrong; in its own town also the error (median, within 10
and 25 m) and how well the confidence ranks right answers above wrong ones (ROC AUC). The last
table puts the renderers side by side. Baseline: the confidence threshold alone (``not sure``
below 0.04), the only gate before the verdict existed.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_region import CLASSES, PANO, TABLE, draw_views, mask_views, street_spots  # noqa: E402

from localization.bench.compare import roc_auc  # noqa: E402
from localization.common.views import Camera, semantic_map  # noqa: E402
from localization.profile.profiles import MASK_MIN_CONFIDENCE  # noqa: E402
from localization.profile.search import UNKNOWN_HEIGHTS, ProfileConfig  # noqa: E402
from localization.region.cache import BlockMasks  # noqa: E402
from localization.region.search import (  # noqa: E402
    NULL_MIN_LIFT,
    RegionConfig,
    distance_m,
    region_blocks,
    search_region,
)

DATA = ROOT.parent / "shared" / "data"


@dataclass(frozen=True)
class Town:
    name: str
    osm: Path
    bbox: tuple[float, float, float, float]


TOWNS = (
    Town("Kotka", DATA / "helsinki-osm" / "kotka.osm.pbf", (26.940, 60.523, 26.958, 60.532)),
    Town("Helsinki", DATA / "helsinki-osm" / "helsinki.osm.pbf", (24.936, 60.165, 24.952, 60.178)),
    Town("West Oakland", DATA / "oakland-osm" / "west-oakland.osm", (-122.30258, 37.80615, -122.29825, 37.80914)),
)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--queries", type=int, default=8, help="views drawn in each town")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--heading", choices=["known", "unknown"], default="known")
    ap.add_argument("--fov", type=float, default=360.0, help="the views' field of view in degrees (360: panoramas)")
    ap.add_argument("--compass", type=float, metavar="DEG",
                    help="heading unknown, but a compass says it to within ±DEG: the search keeps within DEG of a "
                         "reading drawn uniformly within ±DEG/2 of the truth (--heading-within DEG)")
    ap.add_argument("--renderer", choices=["geometry", "mask", "both"], default="both",
                    help="which renderer draws the views (both: side by side, the same street points)")
    ap.add_argument("--vista-weight", type=float, default=ProfileConfig.vista_weight,
                    help="the open horizon's weight (osmseg localize-region --vista-weight; 0: none)")
    ap.add_argument("--json", type=Path, help="also write every search here")
    ap.add_argument("--summarise", type=Path, metavar="JSON",
                    help="print the summary of an earlier run's --json at this osmseg's thresholds (no search)")
    args = ap.parse_args(argv)
    if args.summarise:
        doc = json.loads(args.summarise.read_text())
        doc["summary"] = summarise_all(doc["searches"])
        print(json.dumps(doc["summary"], indent=2))
        if args.json:
            args.json.write_text(json.dumps(doc, indent=2) + "\n")
        return dict(doc["summary"])
    missing = [t.osm for t in TOWNS if not t.osm.is_file()]
    if missing:
        print(f"skipped: {', '.join(map(str, missing))} absent (../shared/data holds the extracts)")
        return {}
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as cache:
        renderers = RENDERERS if args.renderer == "both" else (args.renderer,)
        views = {}
        for t in TOWNS:
            config = RegionConfig(bbox=t.bbox)
            blocks = region_blocks(config)
            masks = BlockMasks([t.osm], TABLE, [g for g, _ in blocks], Path(cache))
            masks.prepare(range(len(blocks)))  # the region's OSM cut once for every block
            rng = np.random.default_rng(args.seed)
            spots = street_spots(masks, blocks, args.queries, rng, t.bbox)
            if "geometry" in renderers:
                views["geometry", t.name] = list(draw_views(t.osm, [(p.lon, p.lat) for p in spots], rng, args.seed,
                                                            (1.5, 2.5), 1.0, args.fov))
            if "mask" in renderers:
                views["mask", t.name] = list(mask_views(masks, blocks, spots, np.random.default_rng([args.seed, 1]),
                                                        (1.5, 2.5), args.fov))
            print(f"{t.name}: {len(blocks)} blocks, {len(spots)} street points", flush=True)
        for renderer, origin in ((r, o) for r in renderers for o in TOWNS):
            for place in TOWNS:
                config = RegionConfig(bbox=place.bbox)
                for i, v in enumerate(views[renderer, origin.name]):
                    query = semantic_map(v.pixels, PANO, CLASSES)
                    camera = Camera(v.pixels.shape[1], 224, hfov_deg=args.fov, camera_height_m=2.0)
                    profile = compass(ProfileConfig(heading_deg=v.heading if args.heading == "known" else None,
                                                    camera_heights=UNKNOWN_HEIGHTS, tilt_deg=1.0,
                                                    vista_weight=args.vista_weight),
                                      args.compass, v.heading, args.seed, i)
                    t0 = time.perf_counter()
                    result = search_region(query, camera, [place.osm], TABLE, CLASSES, config, profile,
                                           cache_dir=Path(cache))
                    best = result.best
                    error = distance_m(best, (v.lon, v.lat)) if best and origin is place else None
                    rows.append({"renderer": renderer, "from": origin.name, "in": place.name, "view": i,
                                 "error_m": error,
                                 "score": best.score if best else None, "chance": best.chance if best else None,
                                 "kappa": best.kappa if best else None,
                                 "confidence": best.confidence if best else None,
                                 "verdict": result.verdict, "null": result.null_score,
                                 "coarse": result.coarse_score, "lift": result.lift,
                                 "seconds": round(time.perf_counter() - t0, 1)})
                    r = rows[-1]
                    print(f"{renderer:>8} {origin.name:>12} in {place.name:<12} #{i} error {error if error is None else round(error, 1)}"
                          f" score {r['score'] or 0:.3f} null {r['null'] or 0:.3f} lift {r['lift'] or 0:.3f} "
                          f"kappa {r['kappa'] or 0:.3f} "
                          f"conf {r['confidence'] or 0:.3f} {r['verdict']} {r['seconds']} s", flush=True)
    summary = summarise_all(rows)
    print(json.dumps(summary, indent=2))
    print(side_by_side(summary))
    if args.json:
        args.json.write_text(json.dumps({"summary": summary, "fov": args.fov, "heading": args.heading,
                                         "compass": args.compass, "vista_weight": args.vista_weight,
                                         "searches": rows},
                                        indent=2) + "\n")
    return summary


RENDERERS = ("geometry", "mask")


def compass(profile: ProfileConfig, within: float | None, heading: float, seed: int, view: int) -> ProfileConfig:
    """``profile`` told by a compass good to ``within`` degrees: a reading off the true ``heading``
    by a seeded draw within ±within/2 (the same for a view in every town)."""
    if within is None:
        return profile
    error = float(np.random.default_rng([seed, view, 7]).uniform(-within / 2, within / 2))
    return dataclasses.replace(profile, heading_prior_deg=(heading + error) % 360.0, heading_within_deg=within)


def summarise_all(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """:func:`summarise` for each renderer's searches (an older run's rows, without one: geometry)."""
    names = dict.fromkeys(r.get("renderer", "geometry") for r in rows)
    return {name: summarise([r for r in rows if r.get("renderer", "geometry") == name]) for name in names}


def side_by_side(summary: dict[str, Any]) -> str:
    """The renderers' figures as one plain table, a line per renderer."""
    head = (f"{'renderer':9} {'n':>3} {'median m':>9} {'@10 m':>6} {'@25 m':>6} {'AUC':>6} "
            f"{'accepted/wrong':>15} {'other town accepted/wrong':>26}")
    lines = [head]
    for name, s in summary.items():
        own, other, verdict = s["own_town"], s["verdict_here"]["other town"], s["verdict_here"]["own town"]
        auc = "-" if own["auc_right_vs_wrong"] is None else f"{own['auc_right_vs_wrong']:.3f}"
        median = "-" if own["median_error_m"] is None else f"{own['median_error_m']:.1f}"
        lines.append(f"{name:9} {own['n']:>3} {median:>9} {own['within_10m']:>6.3f} "
                     f"{own['within_25m']:>6.3f} {auc:>6} {verdict['accepted']:>8}/{verdict['accepted_wrong']:<6} "
                     f"{other['accepted']:>12}/{other['accepted_wrong']} of {other['n']}")
    return "\n".join(lines)


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per kind of search (own town, other town): accepted, wrong among accepted, for the verdict
    and for the confidence threshold alone; and the AUC of each score for own-right vs other-town."""
    own = [r for r in rows if r["from"] == r["in"]]
    other = [r for r in rows if r["from"] != r["in"]]
    right = [r for r in own if r["error_m"] is not None and r["error_m"] <= 10]

    def gate(r: dict[str, Any]) -> bool:
        return (r["confidence"] or 0) >= MASK_MIN_CONFIDENCE

    def here(r: dict[str, Any]) -> bool:  # the verdict "here" (RegionResult.verdict) at this osmseg's thresholds
        return r["score"] is not None and gate(r) and r["lift"] is not None and r["lift"] >= NULL_MIN_LIFT

    def rates(group: list[dict[str, Any]], accept: Any) -> dict[str, Any]:
        taken = [r for r in group if accept(r)]
        wrong = [r for r in taken if r["error_m"] is None or r["error_m"] > 50]
        return {"n": len(group), "accepted": len(taken), "accepted_wrong": len(wrong)}

    errors = [r["error_m"] if r["error_m"] is not None else math.inf for r in own]
    wrong = [r for r in own if r["error_m"] is None or r["error_m"] > 50]
    return {
        "own_town": {"n": len(own), "median_error_m": statistics.median(errors) if errors else None,
                     "within_10m": sum(e <= 10 for e in errors) / max(1, len(errors)),
                     "within_25m": sum(e <= 25 for e in errors) / max(1, len(errors)),
                     "auc_right_vs_wrong": roc_auc([r["confidence"] or 0 for r in right],
                                                   [r["confidence"] or 0 for r in wrong]) if right and wrong else None},
        "verdict_here": {"own town": rates(own, here), "own town, right answers": rates(right, here),
                         "other town": rates(other, here)},
        "threshold": {"lift": NULL_MIN_LIFT, "confidence": MASK_MIN_CONFIDENCE},
        "confidence_only": {"own town": rates(own, gate), "own town, right answers": rates(right, gate),
                            "other town": rates(other, gate)},
        "auc_right_vs_other_town": {
            name: roc_auc([f(r) for r in right], [f(r) for r in other]) if right and other else None
            for name, f in (("kappa", lambda r: r["kappa"] or 0), ("confidence", lambda r: r["confidence"] or 0),
                            ("lift over the null", lambda r: r["lift"] if r["lift"] is not None else -1.0))},
        "median_s": statistics.median(r["seconds"] for r in rows) if rows else None,
    }


if __name__ == "__main__":
    logging.getLogger("osmseg").setLevel(logging.ERROR)
    main()
