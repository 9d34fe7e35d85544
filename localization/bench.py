"""Rendered-panorama benchmark: how well does landmark-graph matching find a panorama's viewpoint?

Real ground panoramas paired with aerial images are not available offline, so we make them:
for each of N seeded viewpoints placed anywhere on standable ground of an aerial label mask
(roads, footways, grass...: not in buildings, trees or water, and at least ``margin_m`` from the
border), :mod:`localization.render` renders the semantic panorama a camera 2 m above the ground
would see, its landmarks are extracted, and it is localized against the landmark graph of the
whole aerial mask (:func:`localization.match.match_cliques`, which is what
:func:`localization.match.localize` runs, with the aerial graph built once per mask).

The viewpoints are *off-centre*: unlike aerial crops centred on the panorama, guessing the
image centre does not help, and the results report that baseline (and a uniform random guess)
beside the method's error.

Reported (``results.json``, :func:`summarize`): mean and median error of the MAP location in
pixels and metres, recall at 10/25/50 m (unanswered count as misses), the paper's top-5 mean
distance (mean distance of the top-5 candidates to the truth), how many answers were ties and
how many unanswered, and the same for every subset of 2, 3, ... landmark classes (the trend of
the dissertation's Figure 5.2). Pictures: ``errors.png`` (the error CDF) and ``classes.png``
(error and recall against the number of classes).
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import logging
import math
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from localization.graph import Cliques, cliques_fast, window_size_auto
from localization.landmarks import LandmarkClasses, Landmarks, landmarks_from_mask, load_landmark_classes
from localization.match import DEFAULT_P, Localization, match_cliques, unanswered
from localization.render import (NoiseConfig, RenderConfig, RenderedView, class_table_from_dict, render_view,
                                 save_panorama_png)
from osmseg import __version__
from osmseg.classes import ClassTable, load_class_table
from osmseg.errors import ConfigError, DatasetError
from osmseg.output.atomic import atomic_write_text

logger = logging.getLogger(__name__)

__all__ = ["Scene", "BenchConfig", "load_dataset_scenes", "load_mask_scene", "place_viewpoints",
           "class_subsets", "summarize", "run_bench", "plot_errors", "plot_classes"]

RECALL_RADII_M = (10, 25, 50)
#: Classes nobody stands on, besides those with a height (buildings, trees).
NOT_STANDABLE = ("unlabeled", "water")
#: Landmark dictionaries for the class tables osmseg builds (data_manifests/).
DEFAULT_LANDMARKS = {"osm13": "aerial13", "osm6": "airsegnet6"}


@dataclass(frozen=True)
class Scene:
    """One aerial label mask with its class table and ground resolution."""

    name: str
    mask: np.ndarray
    table: ClassTable
    resolution_m: float


@dataclass(frozen=True)
class BenchConfig:
    """Every setting of a benchmark run (all recorded in results.json).

    Viewpoints are drawn from ``seed``; viewpoint ``i``'s noise from ``(seed, noise.seed, i)``.
    """

    viewpoints: int = 20
    seed: int = 0
    landmarks: str | None = None        # landmark dictionary; None: the one for the table
    mode: str = "centroid"
    min_size: int = 50
    stride: int = 50
    window: int | None = None           # aerial window in pixels; None: mu + 5 sigma (the paper's)
    p: float = DEFAULT_P
    top_k: int = 5
    margin_m: float = 20.0
    stand_on: tuple[str, ...] | None = None   # None: every flat class but unlabeled and water
    subsets: bool = True                # also every subset of 2.. classes (Figure 5.2)
    render: RenderConfig = field(default_factory=RenderConfig)
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    save_panoramas: int = 0             # write the first K panoramas as PNG

    def __post_init__(self) -> None:
        if self.viewpoints < 1:
            raise ConfigError(f"viewpoints must be at least 1, got {self.viewpoints}")
        if self.margin_m < 0 or self.top_k < 1 or self.save_panoramas < 0:
            raise ConfigError("margin_m and save_panoramas must be >= 0 and top_k >= 1")
        if not 0 < self.p <= 1:
            raise ConfigError(f"p must be in (0, 1], got {self.p}")
        if self.window is not None and self.window < 1:
            raise ConfigError(f"window must be at least 1 pixel, got {self.window}")
        if self.mode not in ("centroid", "grid", "component"):
            raise ConfigError(f"mode must be centroid, grid or component, got {self.mode!r}")

    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["render"]["heights"] = dict(self.render.heights)
        return out


# --------------------------------------------------------------------------- inputs


def _read_mask(path: Path) -> np.ndarray:
    try:
        if path.suffix.lower() in (".tif", ".tiff"):
            import rasterio

            with rasterio.open(path) as src:
                mask = src.read(1)
        else:
            from PIL import Image

            with Image.open(path) as im:
                mask = np.asarray(im)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: cannot read the label mask ({exc}); give a PNG or GeoTIFF of class ids") from None
    if mask.ndim != 2 or not np.issubdtype(mask.dtype, np.integer):
        raise DatasetError(f"{path}: a label mask must be a single-band image of class ids, got shape {mask.shape}")
    return mask


def load_mask_scene(path: Path, table: ClassTable | str, resolution_m: float) -> Scene:
    """A mask file (PNG/GeoTIFF of class ids) with its class table and ground resolution (m/px)."""
    if not (resolution_m and resolution_m > 0):
        raise ConfigError("give the mask's ground resolution in metres per pixel (--resolution)")
    tab = load_class_table(table) if isinstance(table, str) else table
    return Scene(name=Path(path).stem, mask=_read_mask(Path(path)), table=tab, resolution_m=float(resolution_m))


def load_dataset_scenes(folder: Path) -> list[Scene]:
    """The label masks of a dataset made by ``osmseg build`` (labels/ + manifest.json)."""
    folder = Path(folder)
    try:
        manifest = json.loads((folder / "manifest.json").read_text(encoding="utf-8"))
        table = class_table_from_dict(manifest["classes"])
        samples = [(s["name"], float(s["ground_resolution_m"])) for s in manifest["samples"]]
    except FileNotFoundError:
        raise DatasetError(f"{folder}: no manifest.json; give a dataset made by `osmseg build`, "
                           "or a mask file with --table and --resolution") from None
    except (KeyError, TypeError, ValueError):
        raise DatasetError(f"{folder}/manifest.json: not an osmseg dataset manifest (rerun `osmseg build`)") from None
    if not samples:
        raise DatasetError(f"{folder}: the dataset has no samples")
    return [Scene(name, _read_mask(folder / "labels" / f"{name}.png"), table, res) for name, res in samples]


def landmark_classes_for(table: ClassTable, name: str | None) -> LandmarkClasses:
    """The landmark dictionary ``name``, or the one made for ``table`` (classes13 or classes6)."""
    if name is None:
        name = DEFAULT_LANDMARKS.get(table.name.split("+")[0])
        if name is None:
            raise ConfigError(f"no default landmark dictionary for class table {table.name!r}: give --landmarks")
    return load_landmark_classes(name)


# --------------------------------------------------------------------------- viewpoints and classes


def standable_ids(table: ClassTable, config: BenchConfig) -> list[int]:
    """Class ids a viewpoint may stand on."""
    if config.stand_on is not None:
        missing = [n for n in config.stand_on if n not in table.by_name]
        if missing:
            raise ConfigError(f"stand_on classes {missing} are not in the class table {table.name!r}")
        return [table.by_name[n].id for n in config.stand_on]
    return [c.id for c in table.classes if c.name not in NOT_STANDABLE and not config.render.heights.get(c.name, 0)]


def place_viewpoints(mask: np.ndarray, ids: Sequence[int], n: int, margin_px: int,
                     rng: np.random.Generator) -> np.ndarray:
    """``n`` distinct pixels ``(x, y)`` of classes ``ids``, at least ``margin_px`` from the border.

    >>> m = np.zeros((10, 10), np.uint8); m[5, 2:8] = 2
    >>> xy = place_viewpoints(m, [2], 4, 3, np.random.default_rng(0))
    >>> sorted(xy[:, 0].tolist()), set(xy[:, 1].tolist())
    ([3, 4, 5, 6], {5})
    """
    ok = np.isin(mask, list(ids))
    h, w = mask.shape
    ok[:margin_px] = ok[h - margin_px:] = False
    ok[:, :margin_px] = ok[:, w - margin_px:] = False
    ys, xs = np.nonzero(ok)
    if len(xs) < n:
        raise ConfigError(f"only {len(xs)} standable pixels at least {margin_px} px from the border, {n} viewpoints "
                          "asked: lower --viewpoints or --margin, or use another mask")
    pick = rng.choice(len(xs), size=n, replace=False)
    return np.stack([xs[pick], ys[pick]], axis=1)


def class_subsets(names: Sequence[str]) -> list[tuple[str, ...]]:
    """Every subset of two or more classes, smallest first (the order of ``names`` kept).

    >>> [("+".join(s)) for s in class_subsets(("building", "road", "tree"))]
    ['building+road', 'building+tree', 'road+tree', 'building+road+tree']
    """
    return [c for k in range(2, len(names) + 1) for c in itertools.combinations(names, k)]


# --------------------------------------------------------------------------- scoring


def _mean(values: Sequence[float]) -> float | None:
    return round(float(np.mean(values)), 4) if len(values) else None


def summarize(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Error statistics over per-viewpoint records (``error_m``, ``error_px``, ``top5_mean_m``, ...).

    >>> s = summarize([{"error_px": 10.0, "error_m": 5.0, "top5_mean_m": 8.0, "ties": 1, "unanswered": False},
    ...                {"error_px": None, "error_m": None, "top5_mean_m": None, "ties": 0, "unanswered": True}])
    >>> s["mean_error_m"], s["recall_at_m"]["10"], s["unanswered"], s["answered"]
    (5.0, 0.5, 1, 1)
    """
    answered = [r for r in records if not r["unanswered"]]
    err_m = [r["error_m"] for r in answered]
    err_px = [r["error_px"] for r in answered]
    n = len(records)
    return {
        "n": n,
        "answered": len(answered),
        "unanswered": n - len(answered),
        "tied": sum(1 for r in answered if r["ties"] > 1),
        "mean_ties": _mean([r["ties"] for r in answered]),
        "mean_error_px": _mean(err_px),
        "median_error_px": round(float(np.median(err_px)), 4) if err_px else None,
        "mean_error_m": _mean(err_m),
        "median_error_m": round(float(np.median(err_m)), 4) if err_m else None,
        "recall_at_m": {str(r): round(sum(e <= r for e in err_m) / n, 4) if n else None for r in RECALL_RADII_M},
        "top5_mean_distance_m": _mean([r["top5_mean_m"] for r in answered]),
    }


def score(loc: Localization, truth: tuple[float, float], resolution_m: float) -> dict[str, Any]:
    """Error of one localization against the true viewpoint."""
    if loc.unanswered or loc.map_xy is None:
        return {"map": None, "error_px": None, "error_m": None, "top5_mean_m": None, "ties": loc.ties,
                "unanswered": True, "reason": loc.reason, "candidates": 0}
    err = math.hypot(loc.map_xy[0] - truth[0], loc.map_xy[1] - truth[1])
    top = [math.hypot(x - truth[0], y - truth[1]) for x, y, _ in loc.top_k]
    return {"map": [round(loc.map_xy[0], 3), round(loc.map_xy[1], 3)], "error_px": round(err, 4),
            "error_m": round(err * resolution_m, 4), "top5_mean_m": round(float(np.mean(top)) * resolution_m, 4),
            "ties": loc.ties, "unanswered": False, "reason": "", "candidates": int(len(loc.candidates))}


def chance_errors(shape: tuple[int, int], truth: tuple[float, float], resolution_m: float) -> tuple[float, float]:
    """Errors (m) of two blind guesses: the image centre, and a uniformly random pixel (expected)."""
    h, w = shape
    centre = math.hypot(truth[0] - (w - 1) / 2, truth[1] - (h - 1) / 2) * resolution_m
    gx, gy = np.meshgrid(np.linspace(0, w - 1, 64), np.linspace(0, h - 1, 64))
    uniform = float(np.mean(np.hypot(gx - truth[0], gy - truth[1]))) * resolution_m
    return centre, uniform


# --------------------------------------------------------------------------- the run


@dataclass
class _AerialGraph:
    """An aerial mask's landmarks and cliques for one class subset, built once per run."""

    landmarks: Landmarks
    window: int
    cliques: Cliques | None


def _aerial_graph(lm: Landmarks, window: int | None) -> _AerialGraph:
    if len(lm.xy) == 0:
        return _AerialGraph(lm, 0, None)
    w = int(window) if window is not None else (window_size_auto(lm) if len(lm.xy) > 1 else max(lm.width, lm.height))
    return _AerialGraph(lm, w, cliques_fast(lm, w))


def _localize(graph: _AerialGraph, query: Landmarks, config: BenchConfig) -> Localization:
    """:func:`localize` with a prebuilt aerial graph (same defaults: the query window is its height)."""
    if graph.cliques is None:
        return unanswered("the aerial image has no landmarks", p=config.p)
    if len(query.xy) == 0:
        return unanswered("the query has no landmarks", p=config.p)
    qw = query.height if query.panorama else graph.window
    return match_cliques(graph.landmarks, graph.cliques, query, cliques_fast(query, qw), p=config.p,
                         top_k=config.top_k, window=graph.window, query_window=qw)


def run_bench(scenes: Sequence[Scene], config: BenchConfig, out_dir: Path, *, progress: bool = False,
              plots: bool = True, source: str = "") -> dict[str, Any]:
    """Run the benchmark over ``scenes`` (viewpoints spread round-robin) and write results.json + plots."""
    if not scenes:
        raise DatasetError("no aerial masks to benchmark on")
    out_dir = Path(out_dir)
    classes = landmark_classes_for(scenes[0].table, config.landmarks)
    subsets = [tuple(classes.names)] + ([s for s in class_subsets(classes.names) if len(s) < len(classes.names)]
                                        if config.subsets else [])
    graphs: list[dict[tuple[str, ...], _AerialGraph]] = []
    placements: list[np.ndarray] = []
    counts = [config.viewpoints // len(scenes) + (i < config.viewpoints % len(scenes)) for i in range(len(scenes))]
    place_rng = np.random.default_rng([config.seed, 0])
    for scene, count in zip(scenes, counts):
        full = landmarks_from_mask(scene.mask, scene.table, classes, mode=config.mode, min_size=config.min_size,
                                   stride=config.stride)
        graphs.append({s: _aerial_graph(full.of_classes(s), config.window) for s in subsets})
        margin = int(math.ceil(config.margin_m / scene.resolution_m))
        placements.append(place_viewpoints(scene.mask, standable_ids(scene.table, config), count, margin, place_rng)
                          if count else np.zeros((0, 2), dtype=np.int64))
    # round-robin over the masks: viewpoint 0 on mask 0, 1 on mask 1, ...
    jobs = [(si, placements[si][i]) for i in range(max(counts)) for si in range(len(scenes)) if i < counts[si]]

    records: list[dict[str, Any]] = []
    t_start = time.perf_counter()
    for index, (si, xy) in enumerate(tqdm(jobs, desc="viewpoints", unit="view", disable=not progress,
                                          file=sys.stderr, dynamic_ncols=True)):
        scene = scenes[si]
        truth = (float(xy[0]), float(xy[1]))
        seq = np.random.SeedSequence([config.seed, config.noise.seed, index])  # each view its own noise
        noise = dataclasses.replace(config.noise, seed=int(seq.generate_state(1)[0]))
        t0 = time.perf_counter()
        view: RenderedView = render_view(scene.mask, scene.table, scene.resolution_m, truth, classes,
                                         config=config.render, noise=noise, mode=config.mode,
                                         min_size=config.min_size, stride=config.stride)
        t_render = time.perf_counter() - t0
        if index < config.save_panoramas:
            save_panorama_png(out_dir / "panoramas" / f"{index:04d}_{scene.name}.png", view.panorama)
        centre, uniform = chance_errors(scene.mask.shape, truth, scene.resolution_m)
        by_subset: dict[str, dict[str, Any]] = {}
        t_loc = 0.0
        for s in subsets:
            t0 = time.perf_counter()
            loc = _localize(graphs[si][s], view.landmarks.of_classes(s), config)
            if s == subsets[0]:
                t_loc = time.perf_counter() - t0
            by_subset["+".join(s)] = score(loc, truth, scene.resolution_m)
        full_name = "+".join(subsets[0])
        records.append({
            "index": index, "scene": scene.name, "truth": [truth[0], truth[1]],
            "camera": [round(view.panorama.camera[0], 3), round(view.panorama.camera[1], 3)],
            "resolution_m": scene.resolution_m, "query_landmarks": int(len(view.landmarks.xy)),
            "classes_seen": sorted({view.landmarks.classes[c] for c in np.unique(view.landmarks.cls)}),
            **by_subset[full_name], "centre_guess_m": round(centre, 4), "random_guess_m": round(uniform, 4),
            "render_s": round(t_render, 4), "localize_s": round(t_loc, 4),
            "by_subset": {k: v for k, v in by_subset.items() if k != full_name},
        })
    total = time.perf_counter() - t_start

    results = _results(scenes, graphs, subsets, records, config, classes, source, total)
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out_dir / "results.json", json.dumps(results, indent=2, sort_keys=True) + "\n")
    if plots:
        plot_errors(results, out_dir / "errors.png")
        plot_classes(results, out_dir / "classes.png")
    return results


def _results(scenes: Sequence[Scene], graphs: list[dict[tuple[str, ...], _AerialGraph]],
             subsets: list[tuple[str, ...]], records: list[dict[str, Any]], config: BenchConfig,
             classes: LandmarkClasses, source: str, total_s: float) -> dict[str, Any]:
    """The results.json document."""
    by_k: dict[str, Any] = {}
    for k in sorted({len(s) for s in subsets}):
        names = ["+".join(s) for s in subsets if len(s) == k]
        per = {n: summarize([r if n == "+".join(subsets[0]) else r["by_subset"][n] for r in records]) for n in names}
        pooled = [r if n == "+".join(subsets[0]) else r["by_subset"][n] for n in names for r in records]
        by_k[str(k)] = {"summary": summarize(pooled), "subsets": per}
    return {
        "format": "osmseg-localize-bench", "format_version": 1, "tool": f"osmseg {__version__}",
        "seed": config.seed, "settings": config.to_dict(), "source": source,
        "landmark_classes": {"name": classes.name, "names": list(classes.names), "mapping": dict(classes.mapping)},
        "scenes": [{"name": sc.name, "shape": list(sc.mask.shape), "resolution_m": sc.resolution_m,
                    "class_table": sc.table.name, "aerial_landmarks": int(len(g[subsets[0]].landmarks.xy)),
                    "window_px": g[subsets[0]].window} for sc, g in zip(scenes, graphs)],
        "classes": list(subsets[0]),
        "summary": summarize(records),
        "baselines": {"centre_guess_mean_m": _mean([r["centre_guess_m"] for r in records]),
                      "random_guess_mean_m": _mean([r["random_guess_m"] for r in records])},
        "by_num_classes": by_k,
        "timing": {"total_s": round(total_s, 3), "render_mean_s": _mean([r["render_s"] for r in records]),
                   "localize_mean_s": _mean([r["localize_s"] for r in records])},
        "viewpoints": records,
    }


# --------------------------------------------------------------------------- pictures


@contextmanager
def _figure(width: float, height: float) -> Iterator[Any]:
    """A constrained-layout Agg figure (no pyplot state) drawn in our style, cleared on exit."""
    try:
        import matplotlib
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise ConfigError("the benchmark plots need matplotlib: pip install matplotlib (or pass --no-plots)") from None
    with matplotlib.rc_context({"font.size": 9, "axes.titlesize": 10, "figure.titlesize": 11}):
        fig = Figure(figsize=(width, height), dpi=100, layout="constrained")
        FigureCanvasAgg(fig)
        try:
            yield fig
        finally:
            fig.clear()


def _save(fig: Any, path: Path) -> Path:
    import io

    from osmseg.output.atomic import atomic_write_bytes

    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None}, facecolor="white")
    return atomic_write_bytes(path, buf.getvalue())


def _cdf(ax: Any, values: Sequence[float], n: int, **style: Any) -> None:
    """Step CDF of ``values`` over ``n`` trials (missing trials keep the curve below 1)."""
    v = np.sort(np.asarray(values, dtype=float))
    ax.step(np.concatenate([[0.0], v]), np.arange(len(v) + 1) / max(n, 1), where="post", **style)


def plot_errors(results: dict[str, Any], path: Path) -> Path:
    """CDF of the MAP error in metres (all classes), with the blind guesses for comparison."""
    with _figure(6.5, 4.0) as fig:
        return _draw_errors(fig, results, path)


def _draw_errors(fig: Any, results: dict[str, Any], path: Path) -> Path:
    recs, s = results["viewpoints"], results["summary"]
    ax = fig.add_subplot()
    _cdf(ax, [r["error_m"] for r in recs if not r["unanswered"]], len(recs), color="tab:green", lw=2,
         label=f"landmark graphs (MAP), {s['answered']}/{s['n']} answered")
    _cdf(ax, [r["top5_mean_m"] for r in recs if not r["unanswered"]], len(recs), color="tab:green", ls=":",
         label="top-5 mean distance")
    _cdf(ax, [r["centre_guess_m"] for r in recs], len(recs), color="0.5", ls="--", label="guess the image centre")
    _cdf(ax, [r["random_guess_m"] for r in recs], len(recs), color="0.7", ls="-.", label="random guess (expected)")
    for radius in RECALL_RADII_M:
        ax.axvline(radius, color="0.85", lw=1, zorder=0)
    ax.set_xlim(left=0)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("error (m)")
    ax.set_ylabel("fraction of viewpoints")
    median = "n/a" if s["median_error_m"] is None else f"{s['median_error_m']:.1f} m"
    ax.set_title(f"Localization error of {s['n']} rendered panoramas\n{', '.join(results['classes'])}: "
                 f"median {median}, recall@25 m {s['recall_at_m']['25']:.2f}")
    ax.legend(loc="lower right", fontsize=8)
    return _save(fig, path)


def plot_classes(results: dict[str, Any], path: Path) -> Path:
    """Error and recall against the number of landmark classes used (the dissertation's Figure 5.2)."""
    with _figure(9.0, 3.8) as fig:
        return _draw_classes(fig, results, path)


def _draw_classes(fig: Any, results: dict[str, Any], path: Path) -> Path:
    ks = sorted(results["by_num_classes"], key=int)
    ax_err, ax_rec = fig.subplots(1, 2)
    xs = [int(k) for k in ks]
    for stat, style in (("mean_error_m", "-o"), ("median_error_m", "--s")):
        ys = [results["by_num_classes"][k]["summary"][stat] for k in ks]
        ax_err.plot(xs, [np.nan if y is None else y for y in ys], style, label=stat.replace("_", " "))
    for k in ks:
        subs = results["by_num_classes"][k]["subsets"]
        vals = [v["mean_error_m"] for v in subs.values() if v["mean_error_m"] is not None]
        ax_err.scatter([int(k)] * len(vals), vals, color="0.6", s=12, zorder=0)
    ax_err.set_xlabel("landmark classes used")
    ax_err.set_ylabel("error (m); dots: each class subset")
    ax_err.set_xticks(xs)
    ax_err.legend(fontsize=8)
    for radius in RECALL_RADII_M:
        ax_rec.plot(xs, [results["by_num_classes"][k]["summary"]["recall_at_m"][str(radius)] for k in ks], "-o",
                    label=f"recall@{radius} m")
    ax_rec.set_xlabel("landmark classes used")
    ax_rec.set_ylabel("fraction of viewpoints")
    ax_rec.set_ylim(0, 1.02)
    ax_rec.set_xticks(xs)
    ax_rec.legend(fontsize=8)
    fig.suptitle("Effect of the number of landmark classes (subsets pooled)")
    return _save(fig, path)
