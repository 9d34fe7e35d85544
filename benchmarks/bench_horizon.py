"""How well a camera's tilt is read from its view's horizon (localization.profile.horizon), on views the
independent geometry renderer drew with a known tilt at Kotka street points.

Run: ``.venv/bin/python benchmarks/bench_horizon.py [--queries 30] [--eye 1.5,2.5] [--tilt 2]
[--fov 360] [--json PATH]``.

The views are ``bench_region.py``'s with the same options and seed (the same street points,
headings, eye heights, pitches and rolls). Each is read three ways, side by side:

* **with its sky** (the ground table's ``sky`` class, as a segmented photo shows it);
* **without a sky class** (the sky drawn as unlabeled: the horizon is bounded from below only);
* **level**, the baseline: pitch and roll 0, what the profile method assumes without ``--tilt``.

Printed per way: the median and largest tilt error, ``hypot(pitch error, roll error)`` in
degrees, and the share of views read within 0.25°. The renderer (localization/bench/georender.py)
shares no code with the reader.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_region import CLASSES, PANO, TABLE, draw_views, street_points, view_options  # noqa: E402

from localization.common.views import Camera, semantic_map  # noqa: E402
from localization.profile.horizon import estimate_tilt  # noqa: E402
from localization.region.cache import BlockMasks  # noqa: E402
from localization.region.search import RegionConfig, region_blocks  # noqa: E402

WAYS = ("with its sky", "without a sky class", "level (the baseline)")


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    view_options(ap, eye="1.5,2.5", tilt=2.0)   # the tilt is also read within +-TILT
    ap.add_argument("--json", type=Path, help="also write every figure here")
    args = ap.parse_args(argv)
    if not args.osm.is_file():
        print(f"skipped: {args.osm} is absent (../shared/data holds the Kotka extract)")
        return {}
    bbox = tuple(float(v) for v in args.bbox.split(","))
    eye = tuple(float(v) for v in args.eye.split(","))
    blocks = region_blocks(RegionConfig(bbox=(bbox[0], bbox[1], bbox[2], bbox[3])))
    rng = np.random.default_rng(args.seed)
    width = int(round(1232 * args.fov / 360))
    camera = Camera(width, 224, hfov_deg=args.fov)
    sky, unlabeled = PANO.by_name["sky"].id, TABLE.unlabeled.id
    errors: dict[str, list[float]] = {w: [] for w in WAYS}
    rows = []
    with tempfile.TemporaryDirectory() as cache:
        masks = BlockMasks([args.osm], TABLE, [g for g, _ in blocks], Path(cache))
        masks.prepare(range(len(blocks)))  # the region's OSM cut once for every block
        points = street_points(masks, blocks, args.queries, rng, (bbox[0], bbox[1], bbox[2], bbox[3]))
        street_points(masks, blocks, args.queries, rng, (bbox[0], bbox[1], bbox[2], bbox[3]))  # bench_region's guesses
        for v in draw_views(args.osm, points, rng, args.seed, eye, args.tilt, args.fov):
            with_sky = estimate_tilt(semantic_map(v.pixels, PANO, CLASSES), camera, args.tilt)
            no_sky = estimate_tilt(semantic_map(np.where(v.pixels == sky, unlabeled, v.pixels), TABLE, CLASSES),
                                   camera, args.tilt)
            read = {WAYS[0]: (with_sky.pitch_deg, with_sky.roll_deg), WAYS[1]: (no_sky.pitch_deg, no_sky.roll_deg),
                    WAYS[2]: (0.0, 0.0)}
            for way, (p, r) in read.items():
                errors[way].append(math.hypot(p - v.pitch, r - v.roll))
            rows.append({"pitch": v.pitch, "roll": v.roll, "read_with_sky": read[WAYS[0]],
                         "read_without_sky": read[WAYS[1]], "open_columns": with_sky.open_columns})
    summary = {"queries": len(rows), "tilt_deg": args.tilt, "fov": args.fov, "eye_m": list(eye), "ways": {
        way: {"median_deg": round(statistics.median(e), 3), "max_deg": round(max(e), 3),
              "within_0.25": round(sum(x <= 0.25 for x in e) / len(e), 3)} for way, e in errors.items()}}
    print(f"{'tilt read':<22} {'median':>8} {'max':>8} {'within 0.25°':>13}")
    for way, s in summary["ways"].items():
        print(f"{way:<22} {s['median_deg']:>7.3f}° {s['max_deg']:>7.3f}° {s['within_0.25']:>13.3f}")
    if args.json:
        args.json.write_text(json.dumps({"summary": summary, "views": rows}, indent=2) + "\n")
    return summary


if __name__ == "__main__":
    main()
