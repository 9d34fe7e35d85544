"""Is a wrong answer the search's fault or the view's? The profile method's answers to a
``localize-bench`` run, each set beside the best score near the truth.

Run: ``.venv/bin/python benchmarks/bench_ceiling.py BENCH_DIR MASK [--resolution M] [--right 25]
[--json PATH]``, where BENCH_DIR is the ``--out`` of ``osmseg localize-bench MASK --methods profile
--save-panoramas N ...`` (N at least its ``--viewpoints``).

Each saved view is localized again with the run's settings, and the place within ``--right``
metres of the truth that scores best is found by scoring every position of a fine grid there
(the method's finest spacing). A perfect search over the method's own scores answers within
``--right`` exactly when that place scores at least as well as every place farther away, so
each view is one of:

* **right**: the method's answer is within ``--right`` m;
* **lost by the search**: a place near the truth scores higher than the answer (the coarse
  grid dropped it): a better search would find it;
* **a tie**: a place near the truth scores the same as the answer: the view cannot tell them apart;
* **a look-alike fits better**: the answer, far away, scores higher than any place near the
  truth: the view (drawn by a renderer the method does not share) fits another place better;
* **nothing to read**: the method gives no answer at all (the view shows none of its landmark
  classes on the ground, e.g. a wall filling a narrow photo): no search could place it.

The **ceiling** is the share right plus lost by the search: the recall a perfect search would
reach with these scores. Below a target, only more information in the query (or a different
score) can reach it. Printed as a table, and as JSON with ``--json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from localization.bench.compare import photo_view  # noqa: E402
from localization.bench.render import Panorama  # noqa: E402
from localization.common.landmarks import load_landmark_classes, panorama_table  # noqa: E402
from localization.common.views import semantic_map  # noqa: E402
from localization.profile.locate import Scoring, localize_profile  # noqa: E402
from localization.profile.method import profile_query  # noqa: E402
from localization.profile.profiles import AerialMaskIndex  # noqa: E402
from localization.profile.search import ProfileConfig  # noqa: E402
from osmseg.classes import load_class_table  # noqa: E402
from osmseg.images import read_label  # noqa: E402

KINDS = ("right", "lost by the search", "a tie", "a look-alike fits better", "nothing to read")


def profile_config(settings: dict[str, Any]) -> ProfileConfig:
    """The run's profile settings (results.json ``settings.profile``) as a :class:`ProfileConfig`."""
    values = dict(settings["profile"])
    values["camera_heights"] = tuple(values.get("camera_heights") or ())
    return ProfileConfig(**values)


def classify(answer: float, near: float, error_m: float, right_m: float, tol: float = 1e-4) -> str:
    """One view's kind (see the module docstring) from its answer's score, the best score within
    ``right_m`` of the truth and the answer's error.

    >>> classify(0.95, 0.97, 120.0, 25.0), classify(1.0, 1.0, 80.0, 25.0), classify(1.0, 0.9, 80.0, 25.0)
    ('lost by the search', 'a tie', 'a look-alike fits better')
    """
    if error_m <= right_m:
        return KINDS[0]
    if near > answer + tol:
        return KINDS[1]
    return KINDS[2] if near > answer - tol else KINDS[3]


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bench", type=Path, help="a localize-bench --out folder (--method profile, --save-panoramas)")
    ap.add_argument("mask", type=Path, help="the mask file the bench localized in")
    ap.add_argument("--table", default="classes13.toml", help="its class table (as localize-bench's --classes)")
    ap.add_argument("--resolution", type=float, help="its m/px [the bench's]")
    ap.add_argument("--right", type=float, default=25.0, help="an answer within this many metres is right")
    ap.add_argument("--json", type=Path, help="also write every figure here")
    args = ap.parse_args(argv)
    try:
        results = json.loads((args.bench / "results.json").read_text())
    except (OSError, ValueError) as exc:
        ap.error(f"{args.bench}/results.json cannot be read ({exc}): give a localize-bench --out folder")
    settings, views = results["settings"], results["viewpoints"]
    if settings["methods"][0] != "profile":
        ap.error("the bench ran --method paper first: rerun it with --method profile")
    missing = [v["index"] for v in views if not (args.bench / "panoramas" / f"{v['index']:04d}_{v['scene']}.png").is_file()]
    if missing:
        ap.error(f"{len(missing)} views have no saved panorama: rerun localize-bench with --save-panoramas "
                 f"{len(views)}")
    table = load_class_table(args.table)
    classes = load_landmark_classes(settings["landmarks"] or "aerial13")
    resolution = args.resolution or views[0]["resolution_m"]
    index = AerialMaskIndex(semantic_map(read_label(args.mask), table, classes), resolution)
    base = profile_config(settings)
    known = settings["heading"] == "known"
    kinds: list[str] = []
    rows: list[dict[str, Any]] = []
    for v in views:
        labels = np.asarray(Image.open(args.bench / "panoramas" / f"{v['index']:04d}_{v['scene']}.png"))
        pano = Panorama(labels, panorama_table(table), tuple(v["camera"]), v["heading_deg"], resolution)
        query = photo_view(pano, classes, settings["fov_deg"], camera_height_m=settings["render"]["camera_height_m"],
                           mode=settings["mode"], min_size=settings["min_size"], stride=settings["stride"])
        cfg = replace(base, heading_deg=query.heading_deg if known else None)
        profile = profile_query(query.semantic, query.camera, cfg)
        loc = localize_profile(index, profile, cfg)
        if not len(loc.order):   # no landmark class to score: unanswerable, whatever the search
            kinds.append(KINDS[4])
            rows.append({"index": v["index"], "error_m": None, "answer_score": None, "best_near_truth": None,
                         "kind": KINDS[4], "reason": loc.reason})
            continue
        scoring = Scoring.of(index, profile, cfg)   # positions scored as the search scores them
        spacing = scoring.finest_px
        truth = np.asarray(v["truth"], dtype=np.float64)
        r = args.right / resolution
        grid = np.arange(-r, r + 1e-9, spacing)
        near = np.stack(np.meshgrid(grid, grid), -1).reshape(-1, 2)
        near = near[np.hypot(near[:, 0], near[:, 1]) <= r] + truth
        near_score = scoring.score(near)[0]
        answer = float(loc.likelihoods[loc.order[0]])
        error = float(np.hypot(*(np.asarray(loc.map_xy) - truth))) * resolution if loc.map_xy else float("inf")
        kind = classify(answer, float(near_score.max()), error, args.right)
        kinds.append(kind)
        rows.append({"index": v["index"], "error_m": round(error, 2), "answer_score": round(answer, 4),
                     "best_near_truth": round(float(near_score.max()), 4), "kind": kind})
    count = Counter(kinds)
    out = {"bench": str(args.bench), "views": len(views), "right_m": args.right,
           "shares": {k: round(count[k] / len(views), 3) for k in KINDS},
           "ceiling": round((count[KINDS[0]] + count[KINDS[1]]) / len(views), 3), "rows": rows}
    print(f"{len(views)} views of {args.bench}, right within {args.right:g} m")
    for k in KINDS:
        print(f"  {k:<26} {out['shares'][k]:.3f}")
    print(f"  ceiling (a perfect search)  {out['ceiling']:.3f}")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1) + "\n")
    return out


if __name__ == "__main__":
    main()
