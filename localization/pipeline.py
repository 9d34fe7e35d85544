"""Localize one query in one aerial image: where the two methods meet, and ``osmseg localize``'s library call.

A :class:`LocalizeConfig` names the method and carries each method's own settings down
(:class:`~localization.paper.config.PaperConfig`, :class:`~localization.profile.search.ProfileConfig`).
:func:`run` localizes a query's landmarks by the paper's method
(:func:`~localization.paper.match.localize`, or the window hierarchy), in an aerial image's
landmarks or its :class:`~localization.paper.match.AerialGraph` built once for many queries;
the profile method's entry points are :mod:`localization.profile.method`'s.
:func:`localize_files` is ``osmseg localize``: it reads both sides, runs the method the config
names, and writes ``result.json`` and pictures. The benchmarks (:mod:`localization.bench`)
call the same functions, so a change to how a pair is localized is made once.

Imports: osmseg core, and localization's common wing and both methods (training only through
:mod:`localization.common.inputs` and :mod:`localization.paper.features`, when an RGB side is
segmented or features are asked for).
"""

from __future__ import annotations

import dataclasses
import json
import logging
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from localization.common.inputs import Side, SideOptions, load_side, with_photo
from localization.common.landmarks import Landmarks
from localization.common.result import DEFAULT_METHOD, METHODS
from localization.common.views import Camera, check_view_shape
from localization.paper.config import PaperConfig
from localization.paper.features import FeatureEdges
from localization.paper.graph import adjacency
from localization.paper.match import AerialGraph, Localization, localize
from localization.paper.refine import localize_hierarchical
from localization.profile.method import profile_index, run_profile
from localization.profile.search import ProfileConfig
from osmseg.errors import ConfigError, DatasetError
from osmseg.output.atomic import atomic_write_text
from osmseg.output.manifest import refuse_busy

logger = logging.getLogger(__name__)

__all__ = ["DEFAULT_METHOD", "METHODS", "LocalizeConfig", "LocalizeFiles", "LocalizeReport",
           "localize_files", "run"]


@dataclass(frozen=True)
class LocalizeConfig:
    """How to localize: which method, and its settings (the papers' defaults).

    ``paper`` holds the landmark-graph method's windows, candidate extension, hierarchy and
    conventions (:class:`~localization.paper.config.PaperConfig`), ``features`` its edges
    removed between look-alike landmarks (§5.3.2); ``profile`` the profile method's settings,
    which also needs the query's field of view and camera height.
    """

    method: str = DEFAULT_METHOD    # or "paper" (Verde et al. 2020); the profile method needs the resolution
    paper: PaperConfig = field(default_factory=PaperConfig)
    features: FeatureEdges | None = None
    profile: ProfileConfig = field(default_factory=ProfileConfig)  # the profile method's settings
    fov_deg: float = 360.0          # the query's horizontal field of view (profile method)
    camera_height_m: float = 2.0    # the query camera's height above the ground (profile method)

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ConfigError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.paper.conventions == "authors" and self.features is not None:
            raise ConfigError("the authors' conventions are those of their demo: one window, no feature edges")


def run(config: LocalizeConfig, aerial: Landmarks | AerialGraph, query: Landmarks, *,
        aerial_drop: np.ndarray | None = None, query_drop: np.ndarray | None = None) -> Localization:
    """Localize ``query`` (a panorama's or an aerial crop's landmarks) in ``aerial`` by the paper's method.

    ``aerial`` is the aerial image's landmarks, or their graph built once for many queries
    (:func:`~localization.paper.match.aerial_graph`). ``aerial_drop``/``query_drop`` are
    ``(K, K)`` landmark pairs whose edges are removed (:meth:`FeatureEdges.drop`). An
    unanswered :class:`Localization` (not an exception) says why when nothing can be matched.
    """
    if config.paper.hierarchical:
        lm = aerial.landmarks if isinstance(aerial, AerialGraph) else aerial
        return localize_hierarchical(lm, query, config.paper, aerial_drop=aerial_drop, query_drop=query_drop)
    return localize(aerial, query, config.paper, aerial_drop=aerial_drop, query_drop=query_drop)


# --------------------------------------------------------------------------- a pair of files


@dataclass(frozen=True)
class LocalizeFiles:
    """``osmseg localize``'s inputs: the two files, how to read each, and where the truth is."""

    aerial: Path
    ground: Path
    aerial_options: SideOptions
    ground_options: SideOptions
    aerial_image: Path | None = None  # the RGB photo of a mask or landmark file (features, pictures)
    ground_image: Path | None = None
    feature_checkpoint: Path | None = None  # whose encoder gives the features [each side's checkpoint]
    truth: tuple[float, float] | None = None  # aerial pixels
    resolution_m: float | None = None  # metres per aerial pixel [the aerial side's own, if known]


@dataclass(frozen=True)
class TruthError:
    """``--truth`` (aerial pixels) and the error of the best answer from it."""

    x: float
    y: float
    error_px: float | None
    error_m: float | None


@dataclass(frozen=True)
class LocalizeSummary:
    """What result.json says of the inputs beside the result: the files, their landmarks, which
    were masks (profile method), the truth's error and the answer in degrees when georeferenced."""

    aerial: str
    ground: str
    aerial_landmarks: int
    ground_landmarks: int
    inputs: tuple[tuple[str, str], ...] | None = None  # (side, "mask" | "landmarks")
    truth: TruthError | None = None
    map_lonlat: tuple[float, float] | None = None  # lon, lat (7 decimals)

    def to_json(self) -> dict[str, object]:
        """The summary's part of result.json."""
        doc: dict[str, object] = {"aerial": self.aerial, "ground": self.ground,
                                  "aerial_landmarks": self.aerial_landmarks, "ground_landmarks": self.ground_landmarks}
        if self.inputs is not None:
            doc["inputs"] = dict(self.inputs)
        if self.truth is not None:
            doc["truth"] = dataclasses.asdict(self.truth)
        if self.map_lonlat is not None:
            doc["map_lonlat"] = {"lon": self.map_lonlat[0], "lat": self.map_lonlat[1]}
        return doc


@dataclass(frozen=True)
class LocalizeReport:
    """What :func:`localize_files` found, and the files it wrote."""

    result: Localization
    aerial: Side
    ground: Side
    error_px: float | None
    error_m: float | None
    summary: LocalizeSummary
    written: list[Path] = field(default_factory=list)


def answer_lonlat(aerial: Path, xy: tuple[float, float]) -> tuple[float, float] | None:
    """Longitude and latitude of aerial pixel ``xy`` when the aerial file is georeferenced: a
    GeoTIFF with a CRS, or a mask of an osmseg dataset (its manifest's ``bounds_3857``); else None."""
    if aerial.suffix.lower() in (".tif", ".tiff"):
        import rasterio
        from rasterio.warp import transform as warp

        try:
            with rasterio.open(aerial) as ds:
                if ds.crs is None:
                    return None
                x, y = ds.transform * (xy[0] + 0.5, xy[1] + 0.5)
                lon, lat = warp(ds.crs, "EPSG:4326", [x], [y])
                return float(lon[0]), float(lat[0])
        except rasterio.errors.RasterioIOError:
            return None
    from localization.common.inputs import manifest_bounds_3857
    from osmseg.grid import pixel_lonlat

    found = manifest_bounds_3857(aerial)
    if found is None:
        return None
    bounds, shape = found
    return pixel_lonlat(bounds, shape, xy)


def localize_files(request: LocalizeFiles, config: LocalizeConfig, out_dir: Path | None = None) -> LocalizeReport:
    """Read both sides, localize, and (with ``out_dir``) write ``result.json`` and the pictures."""
    refuse_busy(request.aerial, request.ground, request.aerial_image, request.ground_image)  # a build writes them
    aerial = load_side(request.aerial, request.aerial_options)
    ground = load_side(request.ground, request.ground_options)
    _check_ground_shape(ground, request, config)
    _check_sides(aerial, ground, request)
    aerial = with_photo(aerial, request.aerial_image, "aerial")
    ground = with_photo(ground, request.ground_image, "ground")
    a, truth = aerial.landmarks, request.truth
    window = config.paper.window
    if window is not None and not config.paper.hierarchical and window >= max(a.width, a.height):
        raise ConfigError(f"--window {window} is not smaller than the aerial image ({a.width}x{a.height}): "
                          f"every landmark would be in one window; give less than {max(a.width, a.height)}, or auto")
    if truth is not None and not (0 <= truth[0] < a.width and 0 <= truth[1] < a.height):
        raise ConfigError(f"--truth {truth[0]:g},{truth[1]:g} is outside the aerial image ({a.width}x{a.height})")
    inputs = None
    if config.method == "profile":
        result = _profile_result(request, config, aerial, ground)
        inputs = tuple((side, "mask" if s.semantic is not None else "landmarks")
                       for side, s in (("aerial", aerial), ("ground", ground)))
    else:
        result = _paper_result(request, config, aerial, ground)
    resolution = request.resolution_m or aerial.resolution
    error_px, error_m = result.error(truth, resolution)
    where = answer_lonlat(request.aerial, result.map_xy) if result.map_xy is not None else None
    summary = LocalizeSummary(
        aerial=str(request.aerial), ground=str(request.ground), aerial_landmarks=len(a),
        ground_landmarks=len(ground.landmarks), inputs=inputs,
        truth=None if truth is None else TruthError(truth[0], truth[1], error_px, error_m),
        map_lonlat=None if where is None else (round(where[0], 7), round(where[1], 7)))
    report = LocalizeReport(result, aerial, ground, error_px, error_m, summary)
    if out_dir is not None:
        report.written.extend(_pictures(out_dir, report, config, resolution))
        full = {**summary.to_json(), **result.to_dict(all_candidates=config.method == "paper")}
        report.written.append(atomic_write_text(out_dir / "result.json",
                                                json.dumps(full, indent=2, sort_keys=True) + "\n"))
    return report


def _paper_result(request: LocalizeFiles, config: LocalizeConfig, aerial: Side, ground: Side) -> Localization:
    """The paper method on both sides' landmarks (with the §5.3.2 feature edges when asked)."""
    a = aerial.landmarks
    drops: dict[str, np.ndarray | None] = {}
    if config.features is not None:
        drops = config.features.masks({
            "aerial": (aerial.photo, a, request.feature_checkpoint or request.aerial_options.checkpoint),
            "ground": (ground.photo, ground.landmarks, request.feature_checkpoint or request.ground_options.checkpoint)})
    result = run(config, a, ground.landmarks, aerial_drop=drops.get("aerial"), query_drop=drops.get("ground"))
    if (config.paper.window is None and not config.paper.hierarchical and not result.unanswered
            and result.window >= max(a.width, a.height)):
        logger.warning("the automatic window (%d px) covers the whole aerial image, so there is one candidate: "
                       "give a smaller --window", result.window)
    if config.features is not None:
        graphs = {"aerial": (a, result.window), "ground": (ground.landmarks, result.query_window)}
        result = replace(result, feature_edges=config.features.summary(drops, graphs, config.paper.cliques))
    return result


def _profile_result(request: LocalizeFiles, config: LocalizeConfig, aerial: Side, ground: Side) -> Localization:
    """The profile method: masks where given, else the landmark lists."""
    if not request.ground_options.panorama and config.fov_deg >= 360:
        raise ConfigError("the profile method localizes ground views: a panorama, or a photo with --fov DEGREES")
    index = profile_index(aerial.semantic if aerial.semantic is not None else aerial.landmarks,
                          request.resolution_m or aerial.resolution, config.profile)
    g = ground.landmarks
    camera = Camera(g.width, g.height, hfov_deg=config.fov_deg, camera_height_m=config.camera_height_m)
    return run_profile(config.profile, index, ground.semantic if ground.semantic is not None else g, camera)


def _check_ground_shape(ground: Side, request: LocalizeFiles, config: LocalizeConfig) -> None:
    """ConfigError when the ground image cannot be the view the command takes it for: a 360° panorama
    (``--panorama``, the default), or with the profile method a photo of ``--fov`` degrees. An
    aerial crop (the paper method with ``--no-panorama``) has no such shape."""
    opts, g = request.ground_options, ground.landmarks
    photo = config.method == "profile" and config.fov_deg < 360
    if not (opts.panorama or photo):
        return
    hfov = config.fov_deg if config.method == "profile" else 360.0
    fixes = ["give the photo" if photo else "give the panorama"]
    if config.method == "profile":
        fixes.append(f"{'its true' if photo else 'for a photo its'} field of view (--fov DEGREES, at most "
                     f"{180 * g.width / g.height:.0f} for this shape)")
    else:
        fixes.append("--no-panorama for an aerial crop")
    if ground.semantic is None:  # a landmark file: its size may be a guess
        fixes.append("the size of its image (--ground-size WIDTHxHEIGHT)")
    check_view_shape(g.width, g.height, hfov, f"--ground {request.ground.name}", ", or ".join(fixes))


def _check_sides(aerial: Side, ground: Side, request: LocalizeFiles) -> None:
    """One-line errors for inputs no localization can use."""
    for side, path, name in ((aerial, request.aerial, "aerial"), (ground, request.ground, "ground")):
        lm = side.landmarks
        if len(lm) == 0:
            raise DatasetError(f"{path}: no landmarks of classes {', '.join(lm.classes)} found; check "
                               f"--{name}-classes and --{name}-table (or lower --min-size)")
    aerial_classes = {aerial.landmarks.classes[c] for c in np.unique(aerial.landmarks.cls)}
    ground_classes = {ground.landmarks.classes[c] for c in np.unique(ground.landmarks.cls)}
    if len(aerial_classes) == 1 and ground_classes <= aerial_classes:
        raise DatasetError(f"both images have landmarks of one class only ({aerial_classes.pop()}): every place would "
                           "match equally; use masks or landmark files with more classes")


def _pictures(out_dir: Path, report: LocalizeReport, config: LocalizeConfig, resolution: float | None) -> list[Path]:
    """localization.png in ``out_dir``, and for the paper method aerial_graph.png and ground_graph.png."""
    try:
        from localization.common import figures
    except ImportError:
        raise ConfigError("pictures need matplotlib: pip install matplotlib (or leave out --out)") from None
    result, aerial, ground = report.result, report.aerial, report.ground
    known = report.summary.truth
    truth = None if known is None else (known.x, known.y)
    paths = [figures.localization_png(out_dir / "localization.png", result, aerial.landmarks,
                                       image=aerial.picture(), truth=truth, resolution=resolution)]
    if config.method != "paper":  # no landmark graphs to draw: none of an earlier paper run stays to mislead
        for name in ("aerial_graph.png", "ground_graph.png"):
            (out_dir / name).unlink(missing_ok=True)
        return paths
    for name, side, w in (("aerial", aerial, result.window), ("ground", ground, result.query_window)):
        if w:
            graph = adjacency(config.paper.cliques(side.landmarks, w))
            title = f"{name}: {len(side.landmarks)} landmarks, window {w} px"
            paths.append(figures.graph_png(out_dir / f"{name}_graph.png", side.landmarks, graph,
                                            image=side.picture(), title=title, colours=side.colours))
    return paths
