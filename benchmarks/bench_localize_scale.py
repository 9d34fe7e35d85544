"""Localization at city size: time and peak memory against image size, with the reference beside.

Run: ``.venv/bin/python benchmarks/bench_localize_scale.py [--repeat 3] [--big 7500]``. Every
figure is measured in this run, on the seeded street-grid masks of bench_localize_graph.py
(as dense at every size: 50 buildings and 25 trees per 750 x 750 px), centroid landmarks:

* **graph + candidates** (the paper method's aerial cliques, then the candidates of a
  rendered panorama's query: :func:`localization.paper.match.localize`): the banded hash sweep
  of :func:`localization.paper.graph.cliques_fast` against the K-bit-set cells it replaced
  (``_point_planes`` + ``_distinct``, still the component-landmark path), same cliques
  asserted; 750, 1500 and 3000 px;
* **profile method**, one view: a 1280 x 1280 mask (the demo's size) and a ``--big`` one
  (7500 px: about 2 km at 0.3 m/px) of a less regular seeded city (:func:`city_mask`),
  heading known and unknown: time, peak memory and the error of the answer.

Peak memory is tracemalloc's (numpy's buffers are traced) in one more run, above what was
allocated before the call; times are medians of ``--repeat`` untraced runs. ``--json PATH``
also writes every figure there (what ``docs/figures.py`` quotes).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_localize_graph import aerial_mask  # noqa: E402

from localization.bench.render import RenderConfig, render_panorama  # noqa: E402
from localization.common.landmarks import landmarks_from_mask, load_landmark_classes  # noqa: E402
from localization.common.views import Camera, semantic_map  # noqa: E402
from localization.paper import cells, graph, windows  # noqa: E402
from localization.paper.config import PaperConfig  # noqa: E402
from localization.paper.match import localize  # noqa: E402
from localization.profile.method import profile_index, profile_query, run_profile  # noqa: E402
from localization.profile.search import ProfileConfig  # noqa: E402
from osmseg.classes import load_class_table  # noqa: E402

#: every figure printed (written by --json): graphs by mask size, profile runs by "SIZE HEADING"
FIGURES: dict[str, dict[str, Any]] = {"graphs": {}, "profile": {}}
TABLE = load_class_table("classes13.toml")
CLASSES = load_landmark_classes("aerial13")
RES = 0.3


def measured(fn: Callable[[], Any], repeat: int) -> tuple[float, float, Any]:
    """(median seconds of ``repeat`` plain runs, peak MB above the start in one traced run, its result)."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    tracemalloc.start()
    out = fn()
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    return statistics.median(times), peak, out


def city_mask(seed: int, size: int) -> np.ndarray:
    """A less regular city for the profile method: streets every 120-260 px of 8-16 px, buildings, trees.

    (The street grid of bench_localize_graph.py repeats every 180 px: every block looks like
    the next, which no method can tell apart.)
    """
    from bench_localize_graph import BUILDING, FOOTWAY, GRASS, HIGHWAY, TREE

    rng = np.random.default_rng(seed)
    mask = np.full((size, size), GRASS, np.uint8)
    for axis in (0, 1):
        at = 40
        while at < size:
            half = int(rng.integers(4, 9))
            sl = slice(max(at - half - 4, 0), at + half + 4)
            road = slice(max(at - half, 0), at + half)
            if axis == 0:
                mask[sl, :] = np.where(mask[sl, :] == HIGHWAY, HIGHWAY, FOOTWAY)
                mask[road, :] = HIGHWAY
            else:
                mask[:, sl] = np.where(mask[:, sl] == HIGHWAY, HIGHWAY, FOOTWAY)
                mask[:, road] = HIGHWAY
            at += int(rng.integers(120, 260))
    n = int(120 * (size / 750) ** 2)
    xs, ys = rng.integers(0, size - 45, n), rng.integers(0, size - 45, n)
    ws, hs = rng.integers(10, 45, n), rng.integers(10, 45, n)
    for x, y, w, h in zip(xs, ys, ws, hs):
        if (mask[y:y + h, x:x + w] == GRASS).all():
            mask[y:y + h, x:x + w] = BUILDING
    tx, ty = rng.integers(0, size, n), rng.integers(0, size, n)
    for x, y in zip(tx, ty):
        if mask[y, x] == GRASS:
            mask[max(y - 4, 0):y + 5, max(x - 4, 0):x + 5] = np.where(
                mask[max(y - 4, 0):y + 5, max(x - 4, 0):x + 5] == GRASS, TREE, mask[max(y - 4, 0):y + 5, max(x - 4, 0):x + 5])
    return mask


def bitset_cliques(lm: Any, w: int) -> Any:
    """The replaced point path: a K-bit set per cell of the cut grid."""
    g = windows._geometry(lm, w, 1)
    planes, cx, cy = cells._point_planes(lm, g)
    return cells._distinct(planes, cx, cy, len(lm), g)


def query_at(mask: np.ndarray, xy: tuple[float, float]) -> Any:
    pano = render_panorama(mask, TABLE, RES, xy, RenderConfig())
    return pano, landmarks_from_mask(pano.labels, pano.table, CLASSES, panorama=True)


def graphs(repeat: int) -> None:
    print("graph + candidates (paper method), centroid landmarks:")
    print(f"{'size':>6} {'K':>6} {'cliques':>8} {'banded s':>9} {'MB':>6} {'bit-set s':>10} {'MB':>6} "
          f"{'ratio':>6} {'+ candidates s':>15} {'MB':>6}")
    for size in (750, 1500, 3000):
        mask = aerial_mask(0, size)
        lm = landmarks_from_mask(mask, TABLE, CLASSES)
        w = graph.window_size_auto(lm)
        t_new, m_new, new = measured(lambda: graph.cliques_fast(lm, w), repeat)
        t_old, m_old, old = measured(lambda: bitset_cliques(lm, w), 1)
        assert (new.members == old.members).all() and (new.centers == old.centers).all(), "cliques differ"
        _, query = query_at(mask, (size / 2 + 7, size / 2 + 3))
        t_loc, m_loc, _ = measured(lambda: localize(lm, query, PaperConfig(window=w)), repeat)
        FIGURES["graphs"][str(size)] = {"landmarks": len(lm), "cliques": len(new), "banded_s": t_new, "banded_mb": m_new,
                                        "bitset_s": t_old, "bitset_mb": m_old, "localize_s": t_loc,
                                        "localize_mb": m_loc}
        print(f"{size:>6} {len(lm):>6} {len(new):>8} {t_new:>9.3f} {m_new:>6.0f} {t_old:>10.3f} {m_old:>6.0f} "
              f"{t_old / t_new:>5.1f}x {t_loc:>15.3f} {m_loc:>6.0f}")


def profile(size: int, repeat: int) -> None:
    mask = city_mask(0, size)
    sem = semantic_map(mask, TABLE, CLASSES)
    xy = (size / 2 + 7.0, size / 2 + 3.0)
    pano, _ = query_at(mask, xy)
    camera = Camera(pano.labels.shape[1], pano.labels.shape[0])
    qsem = semantic_map(pano.labels, pano.table, CLASSES)
    t_index, m_index, index = measured(lambda: profile_index(sem, RES), 1)
    for heading in (0.0, None):
        config = ProfileConfig(heading_deg=heading)
        query = profile_query(qsem, camera, config)
        t, m, loc = measured(lambda: run_profile(config, index, query), repeat)
        err = float(np.hypot(loc.map_xy[0] - xy[0], loc.map_xy[1] - xy[1])) * RES
        FIGURES["profile"][f"{size} {'known' if heading is not None else 'unknown'}"] = {
            "s_per_view": t, "peak_mb": m, "error_m": err, "index_s": t_index}
        print(f"{size:>6} {'known' if heading is not None else 'unknown':>8} {t:>8.2f} {m:>7.0f} {err:>8.2f} "
              f"{t_index:>8.2f} {mask.nbytes / 2**20:>8.0f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--big", type=int, default=7500, help="side of the city-size mask (pixels at 0.3 m)")
    parser.add_argument("--json", type=Path, help="also write every figure to this JSON file")
    args = parser.parse_args()
    graphs(args.repeat)
    print("\nprofile method, one rendered view (0.3 m/px):")
    print(f"{'size':>6} {'heading':>8} {'s/view':>8} {'peak MB':>7} {'error m':>8} {'index s':>8} {'mask MB':>8}")
    for size in (1280, args.big):
        profile(size, args.repeat if size <= 1280 else 1)
    if args.json:
        args.json.write_text(json.dumps(FIGURES, indent=2, sort_keys=True))


if __name__ == "__main__":
    main()
