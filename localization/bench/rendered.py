"""Evaluate localization on rendered panoramas (``osmseg localize-bench``): how well does
landmark-graph matching find a panorama's viewpoint? (The speed scripts are in ``benchmarks/``.)

Real ground panoramas paired with aerial images are not available offline, so we make them:
for each of N seeded viewpoints placed anywhere on standable ground of an aerial label mask
(roads, footways, grass...: not in buildings, trees or water, and at least ``margin_m`` from the
border), :mod:`localization.bench.render` renders the semantic panorama a camera 2 m above the ground
would see, its landmarks are extracted, and it is localized against the landmark graph of the
whole aerial mask (:func:`localization.paper.match.match_cliques`, which is what
:func:`localization.paper.match.localize` runs, with the aerial graph built once per mask).

The viewpoints are *off-centre*: unlike aerial crops centred on the panorama, guessing the
image centre does not help, and the results report that baseline (and a uniform random guess)
beside the method's error.

Reported (``results.json``, :func:`summarize`): mean and median error of the MAP location in
pixels and metres, recall at 10/25/50 m (unanswered count as misses), the paper's top-5 mean
distance (mean distance of the top-5 candidates to the truth), how many answers were ties and
how many unanswered, and the same for every subset of 2, 3, ... landmark classes (the trend of
the dissertation's Figure 5.2). Pictures: ``errors.png`` (the error CDF) and ``classes.png``
(error and recall against the number of classes).

Every view is rendered once (with per-object heights when ``render.height_spread`` is set, a
seeded heading when ``heading`` is unknown, cut to a photo of ``fov_deg``) and localized by each
method of ``methods`` (:mod:`localization.bench.compare`); with ``negatives`` and several scenes, also
in the next scene. ``results["methods"]`` holds each method's summary side by side, with its
heading error and the ROC AUC of its confidence; ``confidence.png`` draws the latter. The
record fields of a view are the first method's; the scoring lives in :mod:`localization.bench.scores`.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import logging
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from localization.bench.compare import (
    Query,
    aerial_graphs,
    localize_subsets,
    method_summary,
    photo_columns,
    photo_view,
    run_method,
    subsets_of,
)
from localization.bench.geobench import geometry_view, geotiff_bounds_3857, scene_for_mask
from localization.bench.georender_osm import OsmScene
from localization.bench.plots import write_results
from localization.bench.render import (
    NoiseConfig,
    RenderConfig,
    RenderedView,
    object_heights,
    render_view,
    save_panorama_png,
)
from localization.bench.scores import (
    RenderedResults,
    _mean,
    baselines,
    by_num_classes,
    chance_errors,
    summarize,
)
from localization.bench.visible import landmark_cells, visible_landmarks
from localization.common.landmarks import (
    LandmarkClasses,
    Landmarks,
    landmark_colours,
    landmarks_from_mask,
    load_landmark_classes,
)
from localization.common.result import Localization
from localization.common.views import semantic_map
from localization.paper.config import PaperConfig
from localization.paper.graph import cliques_fast
from localization.paper.match import DEFAULT_P, AerialGraph
from localization.pipeline import METHODS, LocalizeConfig
from localization.profile.method import profile_index
from localization.profile.profiles import MASK_MIN_CONFIDENCE
from localization.profile.search import AerialIndex, ProfileConfig
from osmseg import __version__
from osmseg.classes import ClassTable, load_class_table
from osmseg.errors import ConfigError, DatasetError
from osmseg.grid import pixel_lonlat
from osmseg.output.manifest import dataset_class_table, manifest_path, read_manifest, refuse_busy
from osmseg.runtime.progress import Progress, track
from osmseg.units import plural

logger = logging.getLogger(__name__)

__all__ = ["Scene", "BenchConfig", "load_dataset_scenes", "load_mask_scene", "place_viewpoints", "run_bench"]

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
    bounds_3857: tuple[float, float, float, float] | None = None  # where it lies: for --renderer geometry
    path: str = ""  # the mask file it was read from (messages name it)


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
    pictures: int = 0                   # draw the first K localizations (map + panorama graph) under views/
    query_landmarks: str = "mask"       # "mask": from the rendered panorama; "visible": the aerial ones it shows
    visible_min_px: int = 20            # "visible": panorama pixels an aerial landmark needs to count as seen
    methods: tuple[str, ...] = ("paper",)   # localized by each, side by side; the first one fills the summary
    profile: ProfileConfig = field(default_factory=lambda: ProfileConfig(min_confidence=-1.0, min_kappa=-1.0))
    heading: str = "known"              # "known": north-aligned panoramas; "unknown": a seeded random heading per view
    fov_deg: float = 360.0              # < 360: each view is a photo of this field of view, not a panorama
    negatives: bool = True              # also localize each view in another scene (confidence: ROC AUC)
    renderer: str = "mask"              # "mask": render.py over the aerial mask; "geometry": georender.py over --osm
    osm: tuple[str, ...] = ()           # the OSM file(s) the geometry renderer draws from

    def __post_init__(self) -> None:
        if self.viewpoints < 1:
            raise ConfigError(f"viewpoints must be at least 1, got {self.viewpoints}")
        if self.margin_m < 0 or self.top_k < 1 or self.save_panoramas < 0 or self.pictures < 0:
            raise ConfigError("margin_m, save_panoramas and pictures must be >= 0 and top_k >= 1")
        if not 0 < self.p <= 1:
            raise ConfigError(f"p must be in (0, 1], got {self.p}")
        if self.window is not None and self.window < 1:
            raise ConfigError(f"window must be at least 1 pixel, got {self.window}")
        if self.mode not in ("centroid", "grid", "component"):
            raise ConfigError(f"mode must be centroid, grid or component, got {self.mode!r}")
        if self.query_landmarks not in ("mask", "visible"):
            raise ConfigError(f"query landmarks must be 'mask' or 'visible', got {self.query_landmarks!r}")
        if not self.methods or any(m not in METHODS for m in self.methods) or len(set(self.methods)) != len(self.methods):
            raise ConfigError(f"methods must be distinct names among {', '.join(METHODS)}, got {list(self.methods)}")
        if self.heading not in ("known", "unknown"):
            raise ConfigError(f"heading must be 'known' or 'unknown', got {self.heading!r}")
        if not 10 <= self.fov_deg <= 360:
            raise ConfigError(f"field of view must be between 10 and 360 degrees, got {self.fov_deg:g}")
        if self.query_landmarks == "visible" and (self.fov_deg < 360 or "profile" in self.methods):
            raise ConfigError("visible query landmarks are for the paper method on whole panoramas: "
                              "drop --query-landmarks visible, or --fov and the profile method")
        if self.renderer not in ("mask", "geometry"):
            raise ConfigError(f"renderer must be 'mask' or 'geometry', got {self.renderer!r}")
        if self.renderer == "geometry" and not self.osm:
            raise ConfigError("the geometry renderer draws from OpenStreetMap: give the OSM file of the area with --osm")
        if self.renderer == "mask" and self.osm:
            raise ConfigError("--osm is for --renderer geometry; the mask renderer draws from the mask alone")
        if self.renderer == "geometry" and (self.query_landmarks == "visible" or self.render.height_spread > 0):
            raise ConfigError("the geometry renderer takes heights from the OSM tags and knows no aerial landmarks: "
                              "drop --height-spread and --query-landmarks visible")
        if self.query_landmarks == "visible" and self.noise.active:
            raise ConfigError("class confusion and missed landmarks apply to mask landmarks: drop them with "
                              "visible query landmarks (the viewpoint offset still applies)")

    @property
    def subsets_on(self) -> bool:
        """Class subsets (Figure 5.2) are the paper method's, on whole panoramas."""
        return self.subsets and self.methods[0] == "paper"

    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["render"]["heights"] = dict(self.render.heights)
        out["osm"] = [Path(o).name for o in self.osm]  # names, not this machine's paths
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
    return cast("np.ndarray", mask)


def load_mask_scene(path: Path, table: ClassTable | str, resolution_m: float) -> Scene:
    """A mask file (PNG/GeoTIFF of class ids) with its class table and ground resolution (m/px)."""
    if not (resolution_m and resolution_m > 0):
        raise ConfigError("give the mask's ground resolution in metres per pixel (--aerial-resolution)")
    refuse_busy(path)  # a label a build is writing
    tab = load_class_table(table) if isinstance(table, str) else table
    bounds = geotiff_bounds_3857(Path(path)) if Path(path).suffix.lower() in (".tif", ".tiff") else None
    return Scene(name=Path(path).stem, mask=_read_mask(Path(path)), table=tab, resolution_m=float(resolution_m),
                 bounds_3857=bounds, path=str(path))


def load_dataset_scenes(folder: Path) -> list[Scene]:
    """The label masks of a dataset made by ``osmseg build`` (labels/ + manifest.json)."""
    folder = Path(folder)
    refuse_busy(folder)  # a build's first run has no manifest yet to refuse it
    if not manifest_path(folder).is_file():
        raise DatasetError(f"{folder}: no manifest.json; give a dataset made by `osmseg build`, "
                           "or a mask file with --classes and --aerial-resolution")
    manifest = read_manifest(folder)
    table = dataset_class_table(manifest, folder)  # with its OSM rules when at hand (--renderer geometry)
    if not manifest.samples:
        raise DatasetError(f"{folder}: the dataset has no samples")
    unplaced = [s.name for s in manifest.samples if s.ground_resolution_m is None]
    if unplaced:
        raise DatasetError(f"{folder}: sample {unplaced[0]} records no ground_resolution_m; give a dataset made by "
                           "`osmseg build`, or its masks one by one with --aerial-resolution")
    return [Scene(s.name, _read_mask(folder / "labels" / f"{s.name}.png"), table, float(s.ground_resolution_m or 0),
                  s.bounds(), str(folder / "labels" / f"{s.name}.png"))
            for s in manifest.samples]


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
            raise ConfigError(f"--stand-on {', '.join(missing)}: not a class of the table {table.name!r}; use some of "
                              f"{', '.join(c.name for c in table.classes)}")
        return [table.by_name[n].id for n in config.stand_on]
    return [c.id for c in table.classes if c.name not in NOT_STANDABLE and not config.render.heights.get(c.name, 0)]


def place_viewpoints(mask: np.ndarray, ids: Sequence[int], n: int, margin_px: int,
                     rng: np.random.Generator) -> np.ndarray:
    """``n`` distinct pixels ``(x, y)`` of classes ``ids``, at least ``margin_px`` from the border
    (:func:`scene_viewpoints` says why when there are fewer such pixels).

    >>> m = np.zeros((10, 10), np.uint8); m[5, 2:8] = 2
    >>> xy = place_viewpoints(m, [2], 4, 3, np.random.default_rng(0))
    >>> sorted(xy[:, 0].tolist()), set(xy[:, 1].tolist())
    ([3, 4, 5, 6], {5})
    """
    ys, xs = np.nonzero(_standable(mask, ids, margin_px))
    if len(xs) < n:
        raise ConfigError(f"only {len(xs)} standable pixels at least {margin_px} px from the border, {n} viewpoints "
                          "asked")
    pick = rng.choice(len(xs), size=n, replace=False)
    return np.stack([xs[pick], ys[pick]], axis=1)


def _standable(mask: np.ndarray, ids: Sequence[int], margin_px: int) -> np.ndarray:
    """Where a viewpoint may stand: pixels of classes ``ids`` at least ``margin_px`` from the border."""
    ok = np.isin(mask, list(ids))
    h, w = mask.shape
    ok[:margin_px] = ok[h - margin_px:] = False
    ok[:, :margin_px] = ok[:, w - margin_px:] = False
    return ok


def scene_viewpoints(scene: Scene, config: BenchConfig, n: int, rng: np.random.Generator,
                     masks: int = 1) -> np.ndarray:
    """``n`` of the ``config.viewpoints`` asked (spread over ``masks`` masks) placed on ``scene``
    (:func:`place_viewpoints`), or a ConfigError that says why they do not fit, first what to
    change: the mask holds no pixel of the classes viewpoints stand on (give ``--stand-on`` one it
    holds, each named with its share), or too few of them lie ``--margin`` metres from its border."""
    ids = standable_ids(scene.table, config)
    names = ", ".join(scene.table.by_id[i].name for i in ids)
    which = "--stand-on" if config.stand_on is not None else "standable"
    where = scene.path or scene.name
    counts = np.bincount(scene.mask.ravel(), minlength=256)
    if not counts[list(ids)].any():
        held = [(c.name, counts[c.id] / scene.mask.size) for c in scene.table.by_id.values()
                if c.id < len(counts) and counts[c.id]]
        shares = ", ".join(f"{name} ({share:.0%})" for name, share in sorted(held, key=lambda h: -h[1]))
        raise ConfigError(f"no pixel of the {which} classes ({names}) in {where}: give --stand-on CLASS with a "
                          f"class it holds: {shares or 'none'}")
    margin_px = int(math.ceil(config.margin_m / scene.resolution_m))
    room = int(_standable(scene.mask, ids, margin_px).sum())
    if room < n:
        spread = (f"{n} of the {plural(config.viewpoints, 'viewpoint')} asked, spread over {masks} masks"
                  if masks > 1 else f"{plural(n, 'viewpoint')} asked")
        raise ConfigError(f"{'only ' + plural(room, 'pixel') if room else 'no pixel'} of the {which} classes "
                          f"({names}) at least {config.margin_m:g} m ({margin_px} px) from the border of {where}, "
                          f"for {spread}: lower --margin or --viewpoints")
    return place_viewpoints(scene.mask, ids, n, margin_px, rng)


# --------------------------------------------------------------------------- the run


class _Bench:
    """One benchmark run over ``scenes``: what is built once per scene (aerial landmarks and their
    graphs, object heights, profile indexes, 3-D scenes), and each view rendered and localized."""

    def __init__(self, scenes: Sequence[Scene], config: BenchConfig) -> None:
        self.scenes, self.config = scenes, config
        self.classes = landmark_classes_for(scenes[0].table, config.landmarks)
        self.subsets = subsets_of(self.classes, config.subsets_on)
        self.graphs: list[dict[tuple[str, ...], AerialGraph]] = []
        self.aerial: list[tuple[Landmarks, np.ndarray]] = []  # each scene's landmarks and the cell each pixel is in
        self.heights = [object_heights(sc.mask, sc.table,
                                       dataclasses.replace(config.render, height_seed=config.render.height_seed + i))
                        if config.render.height_spread > 0 else None for i, sc in enumerate(scenes)]
        self.indexes: dict[int, AerialIndex] = {}
        self.solids: dict[int, OsmScene] = {}  # --renderer geometry: each scene's 3-D scene, built once
        for scene in scenes:
            if config.query_landmarks == "visible":  # the cells say which aerial landmark a panorama pixel shows
                full, cells = landmark_cells(scene.mask, scene.table, self.classes, mode=config.mode,
                                             min_size=config.min_size, stride=config.stride)
            else:
                full = landmarks_from_mask(scene.mask, scene.table, self.classes, mode=config.mode,
                                           min_size=config.min_size, stride=config.stride)
                cells = np.zeros((0, 0), dtype=np.int64)
            self.aerial.append((full, cells))
            self.graphs.append(aerial_graphs(full, self.subsets, PaperConfig(window=config.window)))
        self.other = ({si: (si + 1) % len(scenes) for si in range(len(scenes))}
                      if config.negatives and len(scenes) > 1 else {})

    def solid_scene(self, si: int) -> OsmScene:
        if si not in self.solids:
            bounds = self.scenes[si].bounds_3857
            if bounds is None:
                raise ConfigError(f"{self.scenes[si].name}: the geometry renderer needs to know where the mask lies: "
                                  "give a dataset made by `osmseg build` or a GeoTIFF mask in EPSG:3857")
            self.solids[si] = scene_for_mask(self.config.osm, bounds, self.scenes[si].table,
                                             self.config.render.max_range_m, self.config.seed)
        return self.solids[si]

    def index_of(self, si: int) -> AerialIndex:
        if si not in self.indexes:
            sc = self.scenes[si]
            self.indexes[si] = profile_index(semantic_map(sc.mask, sc.table, self.classes), sc.resolution_m,
                                             self.config.profile)
        return self.indexes[si]

    def render(self, si: int, index: int, truth: tuple[float, float]) -> tuple[RenderedView, Query, float, float]:
        """View ``index`` at ``truth`` in scene ``si``: ``(view, query, its heading, seconds to render)``."""
        config, scene = self.config, self.scenes[si]
        seq = np.random.SeedSequence([config.seed, config.noise.seed, index])  # each view its own noise
        noise_seed, heading_seed = (int(v) for v in seq.generate_state(2))
        noise = dataclasses.replace(config.noise, seed=noise_seed)
        heading = (float(np.random.default_rng(heading_seed).uniform(0.0, 360.0)) if config.heading == "unknown"
                   else config.render.heading_deg)
        t0 = time.perf_counter()
        visible = config.query_landmarks == "visible"
        camera = dataclasses.replace(config.render, heading_deg=heading)
        view: RenderedView
        if config.renderer == "geometry":
            view = geometry_view(self.solid_scene(si), scene.bounds_3857 or (0, 0, 0, 0), scene.mask.shape,
                                 scene.resolution_m, scene.table, truth, self.classes, config=camera, noise=noise,
                                 mode=config.mode, min_size=config.min_size, stride=config.stride)
        else:
            view = render_view(scene.mask, scene.table, scene.resolution_m, truth, self.classes, config=camera,
                               noise=noise, mode=config.mode, min_size=config.min_size, stride=config.stride,
                               sources=visible, heights=self.heights[si])
        if visible:
            shown, _ = visible_landmarks(view.panorama, self.aerial[si][1], self.aerial[si][0], config.visible_min_px)
            view = dataclasses.replace(view, landmarks=shown)
        query = photo_view(view.panorama, self.classes, config.fov_deg, camera_height_m=config.render.camera_height_m,
                           mode=config.mode, min_size=config.min_size, stride=config.stride,
                           landmarks=view.landmarks)
        return dataclasses.replace(view, landmarks=query.landmarks), query, heading, time.perf_counter() - t0

    def record(self, si: int, index: int, truth: tuple[float, float], out_dir: Path) -> dict[str, Any]:
        """View ``index`` rendered, saved and drawn as asked, localized by every method: its results.json record."""
        config, scene = self.config, self.scenes[si]
        view, query, heading, t_render = self.render(si, index, truth)
        if index < config.save_panoramas:
            save_panorama_png(out_dir / "panoramas" / f"{index:04d}_{scene.name}.png", view.panorama)
        centre, uniform = chance_errors(scene.mask.shape, truth, scene.resolution_m)
        photo = config.fov_deg < 360
        paper_config = LocalizeConfig(method="paper", paper=PaperConfig(
            p=config.p, top_k=config.top_k, query_window=query.camera.height if photo else None))
        full, other = self.subsets[0], self.other
        by_method: dict[str, dict[str, Any]] = {}
        answers: dict[str, Localization] = {}
        for method in config.methods:
            by_method[method], answers[method] = run_method(
                method, query, truth, scene.resolution_m,
                paper=lambda: (self.graphs[si][full], self.graphs[other[si]][full] if si in other else None),
                profile=lambda: (self.index_of(si), self.index_of(other[si]) if si in other else None),
                paper_config=paper_config, profile_config=config.profile, heading_known=config.heading == "known")
        first = config.methods[0]
        if index < config.pictures:  # the first method's answer on the map
            draw_view(out_dir / "views" / f"{index:04d}_{scene.name}", scene, view, self.graphs[si][full],
                      answers[first], config, landmark_colours(self.classes, view.panorama.table))
        if first == "paper":
            scored, t_loc = localize_subsets(self.graphs[si], view.landmarks, truth, scene.resolution_m,
                                             paper_config.paper)
        else:
            scored, t_loc = {**by_method[first], "candidate_guess": None, "candidates": 0}, by_method[first]["localize_s"]
        return {
            "index": index, "scene": scene.name, "truth": [truth[0], truth[1]],
            "camera": [round(view.panorama.camera[0], 3), round(view.panorama.camera[1], 3)],
            # where the camera stood in degrees, for a georeferenced mask (a region search's --truth)
            "camera_lonlat": None if scene.bounds_3857 is None else
            [round(v, 7) for v in pixel_lonlat(scene.bounds_3857, scene.mask.shape, view.panorama.camera)],
            "heading_deg": round(heading, 3), "resolution_m": scene.resolution_m,
            "query_landmarks": int(len(view.landmarks.xy)),
            "classes_seen": sorted({view.landmarks.classes[c] for c in np.unique(view.landmarks.cls)}),
            "centre_guess": round(centre, 4), "random_guess": round(uniform, 4),
            "render_s": round(t_render, 4), "localize_s": round(t_loc, 4), **scored, "methods": by_method,
        }


def run_bench(scenes: Sequence[Scene], config: BenchConfig, out_dir: Path, *, progress: Progress | None = None,
              plots: bool = True, source: str = "") -> RenderedResults:
    """Run the benchmark over ``scenes`` (viewpoints spread round-robin) and write results.json + plots.

    Each view is rendered once and localized by every method of ``config.methods``; with
    ``negatives`` and two or more scenes, also in the next scene (a non-matching pair).
    """
    if not scenes:
        raise DatasetError("no aerial masks to benchmark on")
    if config.pictures and importlib.util.find_spec("matplotlib") is None:
        raise ConfigError("--pictures needs matplotlib: pip install matplotlib (or leave --pictures out)")
    out_dir = Path(out_dir)
    bench = _Bench(scenes, config)
    counts = [config.viewpoints // len(scenes) + (i < config.viewpoints % len(scenes)) for i in range(len(scenes))]
    place_rng = np.random.default_rng([config.seed, 0])
    placements = [scene_viewpoints(scene, config, count, place_rng, len(scenes))
                  if count else np.zeros((0, 2), dtype=np.int64) for scene, count in zip(scenes, counts)]
    # round-robin over the masks: viewpoint 0 on mask 0, 1 on mask 1, ...
    jobs = [(si, placements[si][i]) for i in range(max(counts)) for si in range(len(scenes)) if i < counts[si]]
    t_start = time.perf_counter()
    records = [bench.record(si, index, (float(xy[0]), float(xy[1])), out_dir)
               for index, (si, xy) in enumerate(track(jobs, progress, "viewpoints", unit="view"))]
    results = _results(scenes, bench.graphs, bench.subsets, records, config, bench.classes, source,
                       time.perf_counter() - t_start)
    write_results(results, out_dir, plots)
    return results


def draw_view(stem: Path, scene: Scene, view: RenderedView, graph: AerialGraph, loc: Localization,
              config: BenchConfig, colours: Mapping[str, Sequence[int]] | None = None) -> list[Path]:
    """``STEM_map.png`` (the mask with ``loc``'s answer and the truth) and ``STEM_panorama.png``
    (the view's landmark graph over it, each landmark class in ``colours``, its class-table colour)."""
    from localization.common.figures import graph_png, localization_png
    from localization.paper.graph import adjacency

    query = view.landmarks
    pano_graph = adjacency(cliques_fast(query, query.height)) if len(query) else np.zeros((0, 0), bool)
    rgb = view.panorama.rgb()
    cols = photo_columns(rgb.shape[1], config.fov_deg)   # a photo's landmarks are in its own columns
    what = "rendered panorama" if config.fov_deg >= 360 else f"{config.fov_deg:g}° photo"
    return [localization_png(stem.with_name(stem.name + "_map.png"), loc, graph.landmarks,
                             image=scene.table.colorize(scene.mask), truth=view.truth, resolution=scene.resolution_m,
                             classes=drawn_classes(scene.table, scene.mask)),
            graph_png(stem.with_name(stem.name + "_panorama.png"), query, pano_graph, image=rgb[:, cols],
                      title=f"{what} at ({view.truth[0]:.0f}, {view.truth[1]:.0f}): {plural(len(query), 'landmark')}",
                      colours=colours, classes=drawn_classes(view.panorama.table, view.panorama.labels[:, cols]))]


def drawn_classes(table: ClassTable, mask: np.ndarray) -> list[tuple[str, tuple[int, int, int]]]:
    """``(name, rgb)`` of each class of ``table`` that ``mask`` holds, unlabeled (black) and a
    panorama table's sky included: a picture's legend names every colour it draws."""
    present = set(np.unique(mask).tolist())
    return [(c.name, c.color) for c in (table.unlabeled, *table.classes) if c.id in present]


def _results(scenes: Sequence[Scene], graphs: list[dict[tuple[str, ...], AerialGraph]],
             subsets: list[tuple[str, ...]], records: list[dict[str, Any]], config: BenchConfig,
             classes: LandmarkClasses, source: str, total_s: float) -> RenderedResults:
    """The results.json document (errors in metres)."""
    return {
        "format": "osmseg-localize-bench", "format_version": 3, "tool": f"osmseg {__version__}",
        "kind": "rendered panoramas", "queries": "rendered panoramas", "unit": "m",
        "seed": config.seed, "settings": config.to_dict(), "source": source,
        "landmark_classes": {"name": classes.name, "names": list(classes.names), "mapping": dict(classes.mapping)},
        "scenes": [{"name": sc.name, "shape": list(sc.mask.shape), "resolution_m": sc.resolution_m,
                    "class_table": sc.table.name, "aerial_landmarks": int(len(g[subsets[0]].landmarks.xy)),
                    "window_px": g[subsets[0]].window} for sc, g in zip(scenes, graphs)],
        "classes": list(subsets[0]),
        "summary": summarize(records),
        "baselines": baselines(records),
        "by_num_classes": by_num_classes(subsets, records),
        "methods": {m: method_summary(records, m, summarize, threshold=MASK_MIN_CONFIDENCE if m == "profile" else None)
                    for m in config.methods},
        "timing": {"total_s": round(total_s, 3), "render_mean_s": _mean([r["render_s"] for r in records]),
                   "localize_mean_s": _mean([r["localize_s"] for r in records])},
        "viewpoints": records,
    }
