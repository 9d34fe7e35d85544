"""Where a region search loses its wrong answers: the search's stages, or a look-alike the view cannot tell apart.

Run: ``.venv/bin/python benchmarks/bench_region_ceiling.py [--queries 10] [--heading unknown]
[--fov 360] [--bbox W,S,E,N] [--json PATH]``. The views are those of ``bench_region.py --eye
1.5,2.5 --tilt 1 --search-pose`` (the geometry renderer at seeded street points of the Kotka
extract, camera 1.5-2.5 m, tilt ±1°, the method told both are unknown), the same seed giving
the same views.

For each view the region search runs as ``osmseg localize-region`` runs it
(:func:`localization.region.search.search_part` and ``merge_parts``), and the view is then
scored where it was taken: the best score of every position within ``--right`` metres (10) of
the truth, on a 0.5 m grid, every heading and camera height — what a perfect search over the
method's scores would reach there. Each answer more than ``--right`` metres off is then

* **a look-alike fits better**: the answer scores at least what the truth's surroundings reach.
  No search finds the truth: the view must say more (issue 34's item 3);
* **lost at the coarse stage**: the truth scores higher, but its block was not among those the
  coarse pass (one score every ``coarse_m``, a few candidates kept per block) sent to refinement;
* **lost at the fine stage**: the truth's block was refined, and the refinement missed it.

The *ceiling* is the share right plus those lost: the recall a perfect search would reach.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
from pathlib import Path
from typing import Any

import mercantile
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_region import KOTKA, KOTKA_BBOX, PANO, TABLE, draw_views, street_points  # noqa: E402

from localization.common.landmarks import LandmarkClasses, load_landmark_classes  # noqa: E402
from localization.common.views import Camera, semantic_map  # noqa: E402
from localization.profile.locate import Scoring  # noqa: E402
from localization.profile.method import profile_index, profile_query  # noqa: E402
from localization.profile.search import UNKNOWN_HEIGHTS, ProfileConfig, class_prior, grid_positions  # noqa: E402
from localization.region.cache import BlockMasks  # noqa: E402
from localization.region.search import (  # noqa: E402
    RegionConfig,
    distance_m,
    merge_parts,
    prior_blocks,
    region_blocks,
    search_part,
)
from osmseg.grid import ground_resolution  # noqa: E402
from osmseg.runtime.shard import Shard  # noqa: E402


def truth_score(lon: float, lat: float, q: Any, masks: BlockMasks, blocks: list[Any], profile: ProfileConfig,
                prior: np.ndarray, right_m: float, classes: LandmarkClasses) -> tuple[float, int]:
    """The best score within ``right_m`` of (lon, lat) on a 0.5 m grid, and the block it lies in the core of."""
    tile = mercantile.tile(lon, lat, blocks[0][0].zoom)
    b = next(i for i, (_, core) in enumerate(blocks) if (tile.x, tile.y) in core)
    grid = blocks[b][0]
    mask = masks.mask(b)
    res = ground_resolution(grid.lat, grid.zoom)
    index = profile_index(semantic_map(mask, TABLE, classes), res, profile)
    bb = grid.xy_bounds
    x, y = mercantile.xy(lon, lat)
    px = (x - bb.left) / (bb.right - bb.left) * mask.shape[1] - 0.5
    py = (bb.top - y) / (bb.top - bb.bottom) * mask.shape[0] - 0.5
    steps = np.arange(-right_m, right_m + 1e-9, 0.5)
    dx, dy = (a.ravel() for a in np.meshgrid(steps, steps))
    near = np.hypot(dx, dy) <= right_m
    xy = np.stack([px + dx[near] / res, py + dy[near] / res], axis=1)
    score, _, _ = Scoring.of(index, q, profile, prior).score(xy)
    return float(score.max()), b


def classify(query: Any, camera: Camera, v: Any, masks: BlockMasks, blocks: list[Any], config: RegionConfig,
             profile: ProfileConfig, classes: LandmarkClasses, right_m: float) -> dict[str, Any]:
    """Search one view as ``osmseg localize-region`` does, score it where it was taken, and class the answer."""
    part = search_part(query, camera, masks, TABLE, classes, config, profile, Shard(1, 1))
    result = merge_parts([part], config)
    fine = dataclasses.replace(profile, top_k=config.per_block, min_confidence=-1.0, min_kappa=-1.0)
    q = profile_query(query, camera, fine)
    priors = []
    for b in prior_blocks(len(blocks)):
        grid = blocks[b][0]
        index = profile_index(semantic_map(masks.mask(b), TABLE, classes), ground_resolution(grid.lat, grid.zoom), fine)
        priors.append(class_prior(index, q, grid_positions(index.shape, index.grid_m / index.resolution_m)))
    best = result.best
    error = distance_m(best, (v.lon, v.lat)) if best else float("inf")
    truth, b = truth_score(v.lon, v.lat, q, masks, blocks, fine, np.mean(priors, axis=0), right_m, classes)
    answer = best.score if best else -1.0
    kind = ("right" if error <= right_m else "look-alike" if answer >= truth
            else "lost at the fine stage" if b in part.refined else "lost at the coarse stage")
    return {"error_m": error, "answer_score": answer, "truth_score": truth, "refined": b in part.refined, "kind": kind}


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Counts of each kind of answer, the recall and the ceiling (right plus lost by the search)."""
    kinds = ["right", "lost at the coarse stage", "lost at the fine stage", "look-alike"]
    n = max(1, len(rows))
    counts = {k: sum(r["kind"] == k for r in rows) for k in kinds}
    return {"queries": len(rows), **counts, "recall": round(counts["right"] / n, 3),
            "ceiling": round((counts["right"] + counts["lost at the coarse stage"]
                              + counts["lost at the fine stage"]) / n, 3)}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--osm", type=Path, default=KOTKA)
    ap.add_argument("--bbox", default=",".join(map(str, KOTKA_BBOX)))
    ap.add_argument("--queries", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--fov", type=float, default=360.0)
    ap.add_argument("--heading", choices=["known", "unknown"], default="unknown")
    ap.add_argument("--right", type=float, default=10.0, help="metres from the truth an answer is right within")
    ap.add_argument("--landmarks", default="aerial13",
                    help="the landmark dictionary (the classes the method matches): a name or a TOML file")
    ap.add_argument("--max-range", type=float, default=ProfileConfig.max_range_m,
                    help="metres of ground the method reads around the camera (its max_range_m)")
    ap.add_argument("--vista-weight", type=float, nargs="+", default=[ProfileConfig.vista_weight],
                    help="the vista cell's mass (0: none); several: each view searched with each, side by side")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    if not args.osm.is_file():
        print(f"skipped: {args.osm} absent (../shared/data holds the extracts)")
        return {}
    classes = load_landmark_classes(args.landmarks)
    bbox = tuple(float(v) for v in args.bbox.split(","))
    config = RegionConfig(bbox=(bbox[0], bbox[1], bbox[2], bbox[3]))
    blocks = region_blocks(config)
    masks = BlockMasks([args.osm], TABLE, [g for g, _ in blocks])
    masks.prepare(range(len(blocks)))  # the region's OSM cut once for every block
    rng = np.random.default_rng(args.seed)
    points = street_points(masks, blocks, args.queries, rng, config.bbox)   # as bench_region draws them
    street_points(masks, blocks, args.queries, rng, config.bbox)            # bench_region's baseline guesses
    rows: list[dict[str, Any]] = []
    print(f"{'#':>3} {'vista':>5} {'error m':>9} {'answer':>7} {'truth':>7} {'refined':>7}  kind", flush=True)
    for i, v in enumerate(draw_views(args.osm, points, rng, args.seed, (1.5, 2.5), 1.0, args.fov)):
        query = semantic_map(v.pixels, PANO, classes)
        camera = Camera(v.pixels.shape[1], 224, hfov_deg=args.fov, camera_height_m=2.0)
        for weight in args.vista_weight:
            profile = ProfileConfig(heading_deg=v.heading if args.heading == "known" else None,
                                    camera_heights=UNKNOWN_HEIGHTS, tilt_deg=1.0, max_range_m=args.max_range,
                                    vista_weight=weight)
            row = classify(query, camera, v, masks, blocks, config, profile, classes, args.right)
            rows.append({"view": i, "vista_weight": weight, **row})
            print(f"{i:>3} {weight:>5g} {row['error_m']:>9.1f} {row['answer_score']:>7.4f} {row['truth_score']:>7.4f} "
                  f"{str(row['refined']):>7}  {row['kind']}", flush=True)
    by_weight = {f"{w:g}": summarise([r for r in rows if r["vista_weight"] == w]) for w in args.vista_weight}
    summary = by_weight[f"{args.vista_weight[0]:g}"]
    print(json.dumps(by_weight, indent=2))
    if args.json:
        args.json.write_text(json.dumps({"summary": summary, "by_vista_weight": by_weight, "rows": rows}, indent=2)
                             + "\n")
    return summary


if __name__ == "__main__":
    logging.getLogger("osmseg").setLevel(logging.ERROR)
    main()
