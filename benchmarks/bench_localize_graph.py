"""Landmark-graph speed: :func:`cliques_fast` beside the paper's plain sliding window.

Run: ``.venv/bin/python benchmarks/bench_localize_graph.py [--repeat 5]`` (prints; asserts
only that both algorithms give the same cliques). Every figure is measured in this run:

* a 750 x 750 aerial label mask (classes13 ids) drawn with a fixed seed: a street grid (one
  road network) with footways cut at the crossings, 50 buildings and 25 trees -- about 100
  landmarks with the ``aerial13`` dictionary, like the paper's annotated aerial images;
* a 1232 x 224 semantic panorama (CamVid ids, read with the ``camvid`` dictionary): road and
  pavement bands all around, building facades and trees above them;
* for each: landmark extraction (:func:`landmarks_from_mask`, centroid mode), the automatic
  window (:func:`window_size_auto`), then the cliques by :func:`cliques_fast` (median of
  ``--repeat`` runs) and by :func:`cliques_reference` (one run), and their ratio;
* end to end, the issue's target: :func:`localize` of the panorama in the aerial image (both
  graphs, candidates, matching; landmarks already extracted), fast against ``fast=False``
  (the reference cliques), with the same answer asserted;
* ``--real``: also the Helsinki extract of ../shared/data rasterised at z18 and cut to
  750 x 750, in grid mode (stride 50), when present;
* component landmarks (any pixel in the window) by :func:`cliques_fast`; the reference is run
  only on the panorama (on the aerial mask it tests every pixel of every component in each of
  the ~400,000 windows: hours).

``--json PATH`` also writes every printed figure there (what ``docs/figures.py`` quotes).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from localization.common.landmarks import Landmarks, landmarks_from_mask, load_landmark_classes  # noqa: E402
from localization.paper.config import PaperConfig  # noqa: E402
from localization.paper.graph import Cliques, cliques_fast, cliques_reference, window_size_auto  # noqa: E402
from localization.paper.match import localize  # noqa: E402
from osmseg.classes import load_class_table  # noqa: E402

HELSINKI = ROOT.parent / "shared" / "data" / "helsinki-osm" / "helsinki.osm.pbf"
# classes13 ids
BUILDING, HIGHWAY, FOOTWAY, TREE, GRASS = 1, 2, 9, 13, 3
# CamVid ids
SKY, CV_BUILDING, CV_ROAD, CV_PAVEMENT, CV_TREE = 0, 1, 3, 4, 5
#: every figure printed, by scene and measurement (written by --json)
FIGURES: dict[str, dict[str, Any]] = {}


def timed(fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    """Median wall time of ``repeat`` calls, and the last result."""
    times, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), result


def aerial_mask(seed: int = 0, size: int = 750) -> np.ndarray:
    """Street grid (roads 14 px, footways 4 px beside them), buildings in the blocks, trees on grass.

    50 buildings and 25 trees per 750 x 750 px: a larger mask is a larger city, as dense.
    """
    rng = np.random.default_rng(seed)
    mask = np.full((size, size), GRASS, np.uint8)
    streets = np.arange(60, size, 180)
    for s in streets:
        mask[s - 11:s - 7, :] = mask[s + 7:s + 11, :] = FOOTWAY
        mask[:, s - 11:s - 7] = mask[:, s + 7:s + 11] = FOOTWAY
    for s in streets:
        mask[s - 7:s + 7, :] = HIGHWAY
        mask[:, s - 7:s + 7] = HIGHWAY
    free = mask == GRASS
    scale = (size / 750) ** 2
    placed = 0
    while placed < round(50 * scale):
        x, y = rng.integers(0, size - 40, 2)
        w, h = rng.integers(15, 40, 2)
        if free[y - 3:y + h + 3, x - 3:x + w + 3].all() and y >= 3 and x >= 3:
            mask[y:y + h, x:x + w] = BUILDING
            free[y - 3:y + h + 3, x - 3:x + w + 3] = False
            placed += 1
    placed = 0
    while placed < round(25 * scale):
        x, y, r = *rng.integers(8, size - 8, 2), rng.integers(5, 8)
        yy, xx = np.mgrid[y - r - 3:y + r + 4, x - r - 3:x + r + 4]   # the disc's neighbourhood only
        yy, xx = np.clip(yy, 0, size - 1), np.clip(xx, 0, size - 1)
        disc = (xx - x) ** 2 + (yy - y) ** 2 <= r * r
        if free[yy[disc], xx[disc]].all():
            mask[yy[disc], xx[disc]] = TREE
            ring = (xx - x) ** 2 + (yy - y) ** 2 <= (r + 3) ** 2
            free[yy[ring], xx[ring]] = False
            placed += 1
    return mask


def panorama_mask(seed: int = 0, width: int = 1232, height: int = 224) -> np.ndarray:
    """Sky above, facades and trees on the horizon, pavement and road bands below, all around."""
    rng = np.random.default_rng(seed)
    mask = np.full((height, width), SKY, np.uint8)
    horizon = height // 2
    x = int(rng.integers(0, 40))
    while x < width - 20:
        w = int(rng.integers(25, 80))
        top = horizon - int(rng.integers(15, 70))
        mask[top:horizon + 10, x:min(x + w, width)] = CV_BUILDING if rng.random() < 0.7 else CV_TREE
        x += w + int(rng.integers(4, 30))
    mask[horizon + 10:horizon + 25, :] = CV_PAVEMENT
    mask[horizon + 25:, :] = CV_ROAD
    mask[horizon + 30:, 300:360] = CV_PAVEMENT  # a crossing footway splits the road once
    return mask


def compare(name: str, lm: Landmarks, repeat: int, reference: bool = True) -> dict[str, Any]:
    t_auto, w = timed(lambda: window_size_auto(lm), repeat)
    t_fast, fast = timed(lambda: cliques_fast(lm, w), repeat)
    figures: dict[str, Any] = {"landmarks": len(lm), "window": w, "cliques": len(fast), "auto_s": t_auto,
                               "fast_s": t_fast}
    line = (f"{name:<34} K={len(lm):4d} w={w:4d}  cliques {len(fast):5d}  window_size_auto {t_auto * 1000:6.2f} ms  "
            f"fast {t_fast * 1000:7.2f} ms")
    if reference:
        t_ref, ref = timed(lambda: cliques_reference(lm, w), 1)
        same = _same(ref, fast)
        line += f"  reference {t_ref:7.3f} s  ratio {t_ref / t_fast:7.0f}x  identical: {same}"
        if not same:
            raise SystemExit(f"{name}: cliques_fast differs from cliques_reference")
        figures.update(reference_s=t_ref, ratio=t_ref / t_fast)
    else:
        line += "  reference skipped (every pixel in every window)"
    print(line)
    return figures


def _same(a: Cliques, b: Cliques) -> bool:
    return a.members.shape == b.members.shape and bool((a.members == b.members).all()) and \
        np.array_equal(a.centers, b.centers)


def helsinki_mask() -> np.ndarray | None:
    if not HELSINKI.exists():
        return None
    from osmseg.grid import sample_grid
    from osmseg.osm.features import read_features
    from osmseg.rasterize import rasterize
    table = load_class_table("classes13.toml")
    grid = sample_grid(24.944, 60.1715, 18)
    return rasterize(read_features([HELSINKI], grid, table), grid, table)[265:1015, 265:1015]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--real", action="store_true", help="also the Helsinki mask of ../shared/data")
    parser.add_argument("--json", type=Path, help="also write every figure to this JSON file")
    args = parser.parse_args()
    table13 = load_class_table("classes13.toml")
    aerial13, camvid = load_landmark_classes("aerial13"), load_landmark_classes("camvid")

    scenes = [("aerial 750x750 (synthetic)", aerial_mask(), table13, aerial13, False),
              ("panorama 1232x224 (synthetic)", panorama_mask(), None, camvid, True)]
    if args.real:
        real = helsinki_mask()
        if real is None:
            print(f"skipped the real mask: {HELSINKI} is absent (../shared/data)")
        else:
            scenes.append(("aerial 750x750 (Helsinki OSM, grid 50)", real, table13, aerial13, False))
    extracted = {}
    for name, mask, table, classes, panorama in scenes:
        mode = "grid" if "grid" in name else "centroid"
        t_extract, lm = timed(lambda: landmarks_from_mask(mask, table, classes, mode=mode, panorama=panorama),
                              args.repeat)
        counts = ", ".join(f"{c} {int((lm.cls == i).sum())}" for i, c in enumerate(lm.classes))
        print(f"{name}: {len(lm)} landmarks ({counts}); extraction {t_extract * 1000:.1f} ms")
        FIGURES[name] = {"landmarks": len(lm), "extract_s": t_extract, mode: compare(f"  {mode}", lm, args.repeat)}
        comp = landmarks_from_mask(mask, table, classes, mode="component", panorama=panorama)
        FIGURES[name]["component"] = compare("  component", comp, args.repeat, reference=panorama)
        extracted[name] = (lm, t_extract)
    end_to_end(extracted, args.repeat)
    if args.json:
        args.json.write_text(json.dumps(FIGURES, indent=2, sort_keys=True))


def end_to_end(extracted: dict[str, tuple[Landmarks, float]], repeat: int) -> None:
    """localize(panorama in each aerial image): fast beside the reference cliques, same answer."""
    (pano, t_pano), = [v for k, v in extracted.items() if k.startswith("panorama")]
    for name, (aerial, t_aerial) in extracted.items():
        if name.startswith("panorama"):
            continue
        t_fast, fast = timed(lambda: localize(aerial, pano), repeat)
        t_ref, ref = timed(lambda: localize(aerial, pano, PaperConfig(fast=False)), 1)
        if (fast.map_xy, fast.ties, len(fast.candidates)) != (ref.map_xy, ref.ties, len(ref.candidates)):
            raise SystemExit(f"{name}: localize differs between fast and reference cliques")
        FIGURES[name]["localize"] = {"candidates": len(fast.candidates), "fast_s": t_fast,
                                     "with_extraction_s": t_fast + t_aerial + t_pano, "reference_s": t_ref,
                                     "ratio": t_ref / t_fast}
        print(f"localize panorama in {name}: {len(fast.candidates)} candidates, fast {t_fast * 1000:.1f} ms "
              f"(+ landmark extraction {(t_aerial + t_pano) * 1000:.1f} ms = {(t_fast + t_aerial + t_pano) * 1000:.1f} ms)"
              f"  reference {t_ref:.2f} s  ratio {t_ref / t_fast:.0f}x  same answer: True")


if __name__ == "__main__":
    main()
