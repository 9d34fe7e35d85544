"""Region search in a real town's OpenStreetMap: views ray-cast by the independent renderer at
seeded street points, each searched for in the whole region.

Run: ``.venv/bin/python benchmarks/bench_region.py [--queries 30] [--fov 360] [--heading
known|unknown] [--eye 1.5,2.5] [--tilt 2] [--json PATH]``. Defaults: the Kotka extract of
``../shared/data/helsinki-osm`` (its ``--bbox``), 30 queries, seed 0.

* **Queries** are drawn by :mod:`localization.bench.georender` (3-D ray casting over the OSM
  geometry, heights from the tags; it shares no code with the profile method or with the
  rasteriser the region is drawn by): at a street point (a ``highway`` pixel of a seeded block),
  a seeded compass heading, an eye height drawn from ``--eye`` and pitch and roll from
  ``±--tilt`` degrees. The method is told none of these: it assumes a 2 m camera, level, and
  (with ``--heading unknown``) searches the heading; with ``--search-pose`` it is told that
  height and tilt are unknown: it reads the tilt from the view's horizon (within ``±--tilt``,
  :mod:`localization.profile.horizon`) and searches the height (1.5 to 2.5 m). The view keeps its sky,
  as a segmented photo shows it.
* **Search**: :func:`localization.region.search.search_region` over the whole ``--bbox``, the drawn
  blocks cached in a temporary folder, so the first query draws the region and the others
  read it (``s/query`` is reported for both).
* **Scores**: top-1 error; recall at 10 and 25 m; how well the confidence ranks right answers
  (within 10 m) above wrong ones (more than 50 m off), as ROC AUC, beside kappa's (the
  confidence before the best distinct alternative was used); the share of queries answered at
  the default threshold (0.04) and the share of those answers that are wrong; the same for the
  verdict ("here": the confidence and the lift over the null), and the share of right answers
  it keeps.
* **Baseline**: a random street point of the region (what a guess gives), its median error.

Peak memory is the process's maximum resident set (``ru_maxrss``), which includes Python and
the libraries, and also the views' renderer (the whole town's geometry). **What a user's command
costs** (``--command N``): the first N views, saved as class-id PNGs, are searched again by
``osmseg localize-region`` as a user runs it, each in its own process reading the blocks the
first search cached: its maximum resident set and CPU seconds from the kernel (``os.wait4``,
that process alone, imports included), and whether it gives the same answer.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from localization.bench.compare import photo_columns, roc_auc  # noqa: E402
from localization.bench.georender import Camera as GeoCamera, render  # noqa: E402
from localization.bench.georender_osm import scene_from_osm  # noqa: E402
from localization.bench.render import RenderConfig, panorama_table, render_panorama  # noqa: E402
from localization.common.landmarks import load_landmark_classes  # noqa: E402
from localization.common.views import Camera, semantic_map  # noqa: E402
from localization.profile.profiles import MASK_MIN_CONFIDENCE  # noqa: E402
from localization.profile.search import UNKNOWN_HEIGHTS, ProfileConfig  # noqa: E402
from localization.region.cache import BlockMasks  # noqa: E402
from localization.region.search import (  # noqa: E402
    HERE,
    RegionConfig,
    distance_m,
    pixel_lonlat,
    region_blocks,
    search_region,
)
from osmseg.classes import load_class_table  # noqa: E402
from osmseg.grid import ground_resolution  # noqa: E402

KOTKA = ROOT.parent / "shared" / "data" / "helsinki-osm" / "kotka.osm.pbf"
KOTKA_BBOX = (26.93, 60.52, 26.97, 60.54)
TABLE = load_class_table("classes13.toml")
CLASSES = load_landmark_classes("aerial13")
PANO = panorama_table(TABLE)   # the views' classes: the table's and the sky


@dataclass(frozen=True)
class View:
    """One benchmark view: where it stands (degrees), how the camera was held, and its pixels (PANO ids)."""

    lon: float
    lat: float
    heading: float
    eye_m: float
    pitch: float
    roll: float
    pixels: np.ndarray


def draw_views(osm: Path, points: list[tuple[float, float]], rng: np.random.Generator, seed: int,
               eye: tuple[float, ...], tilt: float, fov: float) -> Iterator[View]:
    """The view at each of ``points``, drawn by the geometry renderer as it is asked for: a seeded
    compass heading, an eye height in ``eye`` (MIN, MAX) and pitch and roll in ``±tilt``, drawn
    from ``rng`` in that order, view by view; a ``fov``-degree image 224 rows high."""
    width = int(round(1232 * fov / 360))
    sky = PANO.by_name["sky"].id
    for i, (lon, lat) in enumerate(points):
        heading = float(rng.uniform(0, 360))
        h = float(rng.uniform(eye[0], eye[1]))
        pitch, roll = (float(v) for v in rng.uniform(-tilt, tilt, 2))
        scene = scene_from_osm([osm], lon, lat, TABLE, radius_m=160, seed=seed + i)
        pixels = render(scene.scene, GeoCamera(0.0, 0.0, eye_m=h, heading_deg=heading, pitch_deg=pitch, roll_deg=roll,
                                               hfov_deg=fov, width=width, height=224), sky, TABLE.unlabeled.id)
        yield View(lon, lat, heading, h, pitch, roll, pixels)


def mask_views(masks: BlockMasks, blocks: list[Any], spots: list[StreetSpot], rng: np.random.Generator,
               eye: tuple[float, ...], fov: float) -> Iterator[View]:
    """The view at each of ``spots`` as osmseg's own renderer draws it (:mod:`localization.bench.render`:
    the method's model of a street, every class at its height, over the block's drawn mask, level):
    a seeded compass heading and an eye height in ``eye``, drawn from ``rng`` in that order; a
    ``fov``-degree image 224 rows high. The renderer sees the block only (the spot is at least 256
    px, about 75 m, inside it); beyond, the ground is unlabeled."""
    width = int(round(1232 * fov / 360))
    for spot in spots:
        heading = float(rng.uniform(0, 360))
        h = float(rng.uniform(eye[0], eye[1]))
        grid = blocks[spot.block][0]
        pano = render_panorama(masks.mask(spot.block), TABLE, ground_resolution(grid.lat, grid.zoom),
                               (spot.x, spot.y), RenderConfig(camera_height_m=h, heading_deg=heading))
        cols = photo_columns(pano.labels.shape[1], fov)
        assert cols.stop - cols.start == width  # the photo faces the panorama's heading
        yield View(spot.lon, spot.lat, heading, h, 0.0, 0.0, np.ascontiguousarray(pano.labels[:, cols]))


@dataclass(frozen=True)
class StreetSpot:
    """A street point: degrees, and the block and pixel of the block's mask it was drawn from."""

    lon: float
    lat: float
    block: int
    x: int
    y: int


def street_points(masks: BlockMasks, blocks: list[Any], n: int, rng: np.random.Generator,
                  bbox: tuple[float, float, float, float]) -> list[tuple[float, float]]:
    """``n`` seeded street points (lon, lat): a highway pixel in the core of a seeded block."""
    return [(s.lon, s.lat) for s in street_spots(masks, blocks, n, rng, bbox)]


def street_spots(masks: BlockMasks, blocks: list[Any], n: int, rng: np.random.Generator,
                 bbox: tuple[float, float, float, float]) -> list[StreetSpot]:
    """:func:`street_points` with the block and pixel each was drawn from."""
    road = TABLE.by_name["highway"].id
    out: list[StreetSpot] = []
    while len(out) < n:
        b = int(rng.integers(len(blocks)))
        grid = blocks[b][0]
        mask = masks.mask(b)
        core = np.zeros_like(mask, dtype=bool)
        core[256:-256, 256:-256] = True
        ys, xs = np.nonzero((mask == road) & core)
        if not len(xs):
            continue
        i = int(rng.integers(len(xs)))
        bb = grid.xy_bounds
        lon, lat = pixel_lonlat((bb.left, bb.bottom, bb.right, bb.top), mask.shape, (float(xs[i]), float(ys[i])))
        if bbox[0] <= lon <= bbox[2] and bbox[1] <= lat <= bbox[3]:
            out.append(StreetSpot(lon, lat, b, int(xs[i]), int(ys[i])))
    return out


def view_options(ap: argparse.ArgumentParser, eye: str, tilt: float) -> None:
    """The options that say which views are drawn (:func:`draw_views`), with these defaults."""
    ap.add_argument("--osm", type=Path, default=KOTKA)
    ap.add_argument("--bbox", default=",".join(f"{v:g}" for v in KOTKA_BBOX))
    ap.add_argument("--queries", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--fov", type=float, default=360.0)
    ap.add_argument("--eye", default=eye, help="eye height range MIN,MAX in metres the views are drawn at")
    ap.add_argument("--tilt", type=float, default=tilt, help="pitch and roll drawn from +-TILT degrees")


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    view_options(ap, eye="2,2", tilt=0.0)
    ap.add_argument("--heading", choices=["known", "unknown"], default="known")
    ap.add_argument("--search-pose", action="store_true",
                    help="tell the method the camera height and tilt are unknown (osmseg localize-region --camera-height "
                         "unknown --tilt TILT): it reads the tilt from the horizon and tries 1.5 to 2.5 m")
    ap.add_argument("--vista-weight", type=float, default=ProfileConfig.vista_weight,
                    help="the open horizon's weight (osmseg localize-region --vista-weight; 0: none)")
    ap.add_argument("--command", type=int, default=0, metavar="N",
                    help="search the first N views again with `osmseg localize-region`, each in its own process: "
                         "its peak memory and CPU as a user's command")
    ap.add_argument("--json", type=Path, help="also write every figure here")
    args = ap.parse_args(argv)
    if not args.osm.is_file():
        print(f"skipped: {args.osm} is absent (../shared/data holds the Kotka extract)")
        return {}
    west, south, east, north = (float(v) for v in args.bbox.split(","))
    bbox = (west, south, east, north)
    eye = tuple(float(v) for v in args.eye.split(","))
    config = RegionConfig(bbox=bbox)
    blocks = region_blocks(config)
    rng = np.random.default_rng(args.seed)
    width = int(round(1232 * args.fov / 360))
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as cache:
        masks = BlockMasks([args.osm], TABLE, [g for g, _ in blocks], Path(cache))
        masks.prepare(range(len(blocks)))  # the region's OSM cut once for every block
        points = street_points(masks, blocks, args.queries, rng, bbox)   # draws the blocks it picks, once
        guesses = street_points(masks, blocks, args.queries, rng, bbox)  # the baseline: a random street point
        print(f"{len(blocks)} blocks; {args.queries} views at street points, fov {args.fov:g}°, heading "
              f"{args.heading}, eye {eye[0]:g}-{eye[1]:g} m, tilt ±{args.tilt:g}°", flush=True)
        print(f"{'#':>3} {'error m':>9} {'conf':>6} {'kappa':>6} {'s':>6} verdict")
        for i, v in enumerate(draw_views(args.osm, points, rng, args.seed, eye, args.tilt, args.fov)):
            lon, lat, heading, h, pitch, roll = v.lon, v.lat, v.heading, v.eye_m, v.pitch, v.roll
            query = semantic_map(v.pixels, PANO, CLASSES)  # with its sky, as a segmented photo shows it
            camera = Camera(width, 224, hfov_deg=args.fov, camera_height_m=2.0)
            profile = ProfileConfig(heading_deg=heading if args.heading == "known" else None,
                                    camera_heights=UNKNOWN_HEIGHTS if args.search_pose else (),
                                    tilt_deg=args.tilt if args.search_pose else 0.0, vista_weight=args.vista_weight)
            t0, c0 = time.perf_counter(), time.process_time()
            result = search_region(query, camera, [args.osm], TABLE, CLASSES, config, profile, cache_dir=Path(cache))
            seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
            best = result.best
            error = distance_m(best, (lon, lat)) if best is not None else math.inf
            rows.append({"lon": lon, "lat": lat, "heading": heading, "eye_m": h, "pitch": pitch, "roll": roll,
                         "error_m": error, "confidence": best.confidence if best else None,
                         "kappa": best.kappa if best else None, "seconds": seconds, "cpu_s": cpu,
                         "verdict": result.verdict, "lift": result.lift})
            if i < args.command:  # the same search as a user's command, in its own process
                rows[-1]["command"] = as_command(v.pixels, heading, args, Path(cache), best)
            print(f"{i:>3} {error:>9.2f} {rows[-1]['confidence'] or 0:>6.3f} {rows[-1]['kappa'] or 0:>6.3f} "
                  f"{seconds:>6.1f} {result.verdict}"
                  + (" | command: {cpu_s:.1f} CPU s, {peak_mb:.0f} MB, same answer: {same}".format(**rows[-1]["command"])
                     if "command" in rows[-1] else ""), flush=True)
    right = [r for r in rows if r["error_m"] <= 10]
    wrong = [r for r in rows if r["error_m"] > 50]
    accepted = [r for r in rows if (r["confidence"] or 0) >= MASK_MIN_CONFIDENCE]
    here = [r for r in rows if r["verdict"] == HERE]  # the verdict: the confidence and the null's lift
    baseline = statistics.median(distance_m(p, g) for p, g in zip(points, guesses))
    summary = {
        "queries": len(rows), "fov": args.fov, "heading": args.heading, "eye_m": list(eye), "tilt_deg": args.tilt,
        "search_pose": args.search_pose, "vista_weight": args.vista_weight,
        "blocks": len(blocks),
        "median_error_m": round(statistics.median(r["error_m"] for r in rows), 2),
        "within_10m": round(len(right) / len(rows), 3),
        "within_25m": round(sum(r["error_m"] <= 25 for r in rows) / len(rows), 3),
        "auc_confidence": roc_auc([r["confidence"] or 0 for r in right], [r["confidence"] or 0 for r in wrong]),
        "auc_kappa": roc_auc([r["kappa"] or 0 for r in right], [r["kappa"] or 0 for r in wrong]),
        "threshold": MASK_MIN_CONFIDENCE,
        "accepted": round(len(accepted) / len(rows), 3),
        "false_accept": round(sum(r["error_m"] > 50 for r in accepted) / len(accepted), 3) if accepted else None,
        "accepted_by_verdict": round(len(here) / len(rows), 3),
        "false_accept_by_verdict": round(sum(r["error_m"] > 50 for r in here) / len(here), 3) if here else None,
        "right_kept_by_verdict": round(sum(r["error_m"] <= 10 for r in here) / len(right), 3) if right else None,
        "first_query_s": round(rows[0]["seconds"], 1),
        "median_query_s": round(statistics.median(r["seconds"] for r in rows[1:] or rows), 1),
        "first_query_cpu_s": round(rows[0]["cpu_s"], 1),
        "median_query_cpu_s": round(statistics.median(r["cpu_s"] for r in rows[1:] or rows), 1),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 0),
        **command_summary([r["command"] for r in rows if "command" in r]),
        "baseline_random_street_median_m": round(baseline, 1),
    }
    print(json.dumps(summary, indent=2))
    if args.json:
        args.json.write_text(json.dumps({"summary": summary, "queries": rows}, indent=2) + "\n")
    return summary


def as_command(pixels: np.ndarray, heading: float, args: argparse.Namespace, cache: Path, best: Any) -> dict[str, Any]:
    """Search ``pixels`` (PANO ids, the view's compass ``heading``) again with ``osmseg localize-region`` in a process of its own, as
    ``args`` asked, reading the blocks cached in ``cache``: ``{"cpu_s", "peak_mb", "same"}`` from the
    kernel's account of that process (``os.wait4``), and whether its answer is ``best``'s."""
    from PIL import Image

    with tempfile.TemporaryDirectory() as work:
        view = Path(work) / "view.png"
        Image.fromarray(pixels.astype(np.uint8)).save(view)
        cmd = [sys.executable, "-m", "osmseg", "localize-region", "--ground", str(view),
               "--ground-landmarks", "aerial13", "--ground-table", "classes13.toml", "--osm", str(args.osm),
               "--bbox", args.bbox, "--fov", f"{args.fov:g}", "--vista-weight", f"{args.vista_weight:g}",
               "--cache-dir", str(cache), "--out", str(Path(work) / "out"), "--json", "--no-progress"]
        cmd += ["--heading", "unknown" if args.heading == "unknown" else f"{heading!r}"]
        if args.search_pose:
            cmd += ["--camera-height", "unknown", "--tilt", f"{args.tilt:g}"]
        with open(Path(work) / "stderr.txt", "w+b") as said:  # a file: warnings must not fill a pipe
            proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=said, cwd=ROOT)
            out = proc.stdout.read() if proc.stdout else b""  # before waiting: a full pipe would block it
            _, status, usage = os.wait4(proc.pid, 0)
            proc.returncode = os.waitstatus_to_exitcode(status)
            said.seek(0)
            err = said.read()
    if proc.returncode != 0:
        raise SystemExit(f"osmseg localize-region failed ({proc.returncode}): {err.decode()[-800:]}")
    features = json.loads(out)["features"]
    answer = next((f["geometry"]["coordinates"] for f in features if f["properties"].get("rank") == 1), None)
    apart = distance_m(best, (answer[0], answer[1])) if best is not None and answer is not None else math.inf
    return {"cpu_s": usage.ru_utime + usage.ru_stime, "peak_mb": usage.ru_maxrss / 1024, "same": apart < 0.01,
            "apart_m": apart}


def command_summary(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The commands' figures (:func:`as_command`): the highest peak, the median CPU, how many agreed."""
    if not runs:
        return {}
    return {"command_runs": len(runs), "command_peak_rss_mb": round(max(r["peak_mb"] for r in runs), 0),
            "command_median_cpu_s": round(statistics.median(r["cpu_s"] for r in runs), 1),
            "command_same_answer": sum(bool(r["same"]) for r in runs)}


if __name__ == "__main__":
    logging.getLogger("osmseg").setLevel(logging.ERROR)  # the extract's clipped ways: said once per way, not here
    main()
