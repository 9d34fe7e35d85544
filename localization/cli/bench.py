"""The two benchmark protocols, one command each: ``osmseg localize-bench`` and ``osmseg localize-pairs``.

``localize-bench`` renders ground views at seeded viewpoints of a dataset or mask and
localizes them in it (:func:`~localization.bench.rendered.run_bench`); ``localize-pairs``
scores annotated aerial/ground pairs, the paper's own evaluation
(:func:`~localization.bench.pairs.run_pairs`). The options both take are declared once
(:func:`bench_options`); each command takes only its own besides, so a rendering option given
to the pairs (or a pairs option to the renderer) is click's usual "no such option".

Imports: osmseg core (its command-line helpers) and localization.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import click

from localization.cli.options import (
    AERIAL_RESOLUTION,
    AERIAL_SIZE,
    CAMERA_HEIGHT,
    CONVENTIONS,
    FOV,
    GRID_STRIDE,
    GROUND_SIZE,
    LANDMARK_MODE,
    LANDMARKS,
    MIN_SIZE,
    TOP_K,
    WINDOW,
    P,
    misplaced,
    osm_files,
    parse_camera_height,
    parse_heights,
    parse_window,
    typed_flags,
)
from localization.cli.summary import format_summary
from osmseg.cli.common import output_options, parse_size, report_errors
from osmseg.cli.drawers import Mode, progress_drawer
from osmseg.cli.options import CLASSES, OSM, OUT, SEED, declare, moved
from osmseg.errors import ConfigError

if TYPE_CHECKING:
    from localization.bench.rendered import BenchConfig
    from localization.bench.scores import BenchResults
    from osmseg.runtime.progress import Progress

__all__ = ["bench_options", "localize_bench_command", "localize_pairs_command"]

F = TypeVar("F", bound=Callable[..., object])


def bench_options(func: F) -> F:
    """The options of both protocols: where the results go, the landmark classes, the paper
    method's graph settings, the camera height, the methods compared and the heading."""
    options = [
        OUT(required=True, detail=" of results.json, errors.png and classes.png."),
        AERIAL_RESOLUTION(dest="resolution", detail=" (a dataset records its own; pairs without it are scored in "
                                                    "pixels)."),
        LANDMARKS(show_default="the one for the class table; camvid for annotated pairs"),
        WINDOW(dest="window_text", default="auto", show_default=True),
        P(default=0.5, show_default=True),
        TOP_K(default=5, show_default=True),
        NO_SUBSETS(default=True, show_default=True),
        CAMERA_HEIGHT(dest="camera_height", default="2", show_default=True,
                      detail=" (a benchmark's views are of a known height: metres)"),
        METHODS(default="profile,paper", show_default=True),
        VIEW_HEADING(dest="heading", default="known", show_default=True),
        NO_PLOTS(default=True, show_default=True),
        moved("--resolution", "--resolution is predict's (resample the input): give the aerial side's metres per "
                              "pixel as --aerial-resolution"),
        moved("--method", "--method is osmseg localize's (one method): the benchmarks compare --methods "
                          "profile,paper"),
        moved("--heading", "--heading is osmseg localize's (the query's degrees or unknown): the benchmarks turn "
                           "their views with --view-heading known|unknown"),
    ]
    for option in reversed(options):
        func = option(func)
    return func


def _methods(methods_text: str, typed: Mapping[str, str]) -> tuple[str, ...]:
    """The methods of --methods; the paper method's options refused when it does not run."""
    methods = tuple(m.strip() for m in methods_text.split(",") if m.strip())
    stray = [typed[n] for n in ("window_text", "p", "conventions", "subsets") if n in typed]
    if "paper" not in methods and stray:
        raise misplaced(stray, "the paper method", "paper to --methods")
    return methods


def _rendered_height(text: str) -> float:
    """``--camera-height`` of a benchmark: metres (its views are drawn, or were taken, from one known height)."""
    height, unknown = parse_camera_height(text)
    if unknown:
        raise click.BadParameter("the benchmarks score views of a known camera height: give metres, e.g. 2",
                                 param_hint="'--camera-height'")
    return height


def _report(ctx: click.Context, results: BenchResults, out_dir: Path) -> None:
    """The summary on stderr (unless -q), results.json's path on stdout."""
    if (ctx.obj["verbosity"] if ctx.obj else 0) >= 0:
        click.echo(format_summary(results), err=True)
    click.echo(str(out_dir / "results.json"))


def _drawn(ctx: click.Context) -> Mode | None:
    """How the command shows its progress (:func:`osmseg.cli.drawers.progress_mode`)."""
    return ctx.obj.get("progress") if ctx.obj else None


VIEWPOINTS = declare("--viewpoints", type=click.IntRange(min=1),
                     help="Rendered panoramas to localize, placed round-robin over the masks (-n is build's "
                          "--samples).")
MARGIN = declare("--margin", type=click.FloatRange(min=0),
                 help="Viewpoints stay this many metres from the mask border.")
STAND_ON = declare("--stand-on", multiple=True, help="Classes viewpoints may stand on (repeatable).")
MAX_RANGE = declare("--max-range", type=click.FloatRange(min=0, min_open=True), help="How far the camera sees (m).")
CLASS_HEIGHT = declare("--class-height", multiple=True, metavar="CLASS=METRES",
                       help="Height of a class that occludes (repeatable).")
CONFUSION = declare("--confusion", type=click.FloatRange(0, 1),
                    help="Noise: fraction of panorama landmarks relabelled as another landmark class.")
MISS_SMALL = declare("--miss-small", type=click.IntRange(min=0),
                     help="Noise: panorama landmarks under this many pixels are missed.")
MISS_PROB = declare("--miss-prob", type=click.FloatRange(0, 1),
                    help="Noise: every other panorama landmark is missed with this probability.")
OFFSET = declare("--offset", type=click.FloatRange(min=0),
                 help="Noise: render from this many metres away from the true viewpoint.")
QUERY_LANDMARKS = declare("--query-landmarks", type=click.Choice(["mask", "visible"]),
                          help="Panorama landmarks from its rendered mask, or the aerial landmarks the camera sees "
                               "(perfect correspondence, as a person annotating both views: measures the matching "
                               "alone).")
VISIBLE_MIN_PX = declare("--visible-min-px", type=click.IntRange(min=1),
                         help="With --query-landmarks visible: panorama pixels an aerial landmark needs to count as "
                              "seen.")
SAVE_PANORAMAS = declare("--save-panoramas", type=click.IntRange(min=0),
                         help="Write the first K rendered panoramas as PNG under OUT/panoramas/.")
PICTURES = declare("--pictures", type=click.IntRange(min=0),
                   help="Draw the first K localizations under OUT/views/: the mask with candidates, top-k and truth, "
                        "and the panorama with its landmark graph.")
HEIGHT_SPREAD = declare("--height-spread", type=click.FloatRange(0, 1, max_open=True),
                        help="Each building and tree gets its class height times U(1-s, 1+s), seeded: heights the "
                             "methods do not know.")
NO_NEGATIVES = declare("--negatives/--no-negatives",
                       help="Also localize each view in another scene: how well each method's confidence separates "
                            "matching from non-matching pairs (ROC AUC).")
RENDERER = declare("--renderer", type=click.Choice(["mask", "geometry"]),
                   help="mask: panoramas ray-cast over the aerial mask, one height per class (the model the profile "
                        "method scores with) | geometry: ray-cast over the OSM geometry of --osm in 3-D, heights "
                        "from the tags, see-through tree crowns (shares no code with the methods).")
NO_SUBSETS = declare("--subsets/--no-subsets", help="Also localize with every subset of 2, 3... landmark classes.")
NO_PLOTS = declare("--plots/--no-plots", help="Draw errors.png and classes.png.")
METHODS = declare("--methods", dest="methods_text", metavar="METHOD,...",
                  help="Methods to compare, comma-separated, side by side in one run: profile, paper. The first "
                       "fills the summary; the class-subset figure is the paper method's when it comes first.")
VIEW_HEADING = declare("--view-heading", type=click.Choice(["known", "unknown"]),
                       help="known: north-aligned views; unknown: each view turned to a seeded random heading the "
                            "methods are not told (the profile method searches it and its error is reported).")
PANO_WIDTH = declare("--pano-width", type=click.IntRange(min=8), help="Panorama width (pixels, 360 degrees).")
PANO_HEIGHT = declare("--pano-height", type=click.IntRange(min=2), help="Panorama height (pixels).")


@click.command("localize-bench")
@output_options
@click.argument("source", type=click.Path(exists=True, path_type=Path))
@bench_options
@VIEWPOINTS(default=20, show_default=True)
@SEED(default=0, show_default=True, detail=": viewpoints and noise.")
@CLASSES(dest="table", default="classes13.toml", show_default=True, detail=" of a mask file (a dataset folder "
                                                                             "brings its own).")
@LANDMARK_MODE(dest="mode", default="centroid", show_default=True)
@MIN_SIZE(default=50, show_default=True)
@GRID_STRIDE(dest="stride", default=50, show_default=True)
@MARGIN(default=20.0, show_default=True)
@STAND_ON(show_default="every flat class but unlabeled and water")
@PANO_WIDTH(dest="width", default=1232, show_default=True)
@PANO_HEIGHT(dest="height", default=224, show_default=True)
@MAX_RANGE(default=100.0, show_default=True)
@CLASS_HEIGHT(show_default="building=10, tree=6, others 0")
@CONFUSION(default=0.0, show_default=True)
@MISS_SMALL(default=0, show_default=True)
@MISS_PROB(default=0.0, show_default=True)
@OFFSET(default=0.0, show_default=True)
@QUERY_LANDMARKS(default="mask", show_default=True)
@VISIBLE_MIN_PX(default=20, show_default=True)
@SAVE_PANORAMAS(default=0, show_default=True)
@PICTURES(default=0, show_default=True)
@FOV(default=360.0, show_default=True)
@HEIGHT_SPREAD(default=0.0, show_default=True)
@NO_NEGATIVES(default=True, show_default=True)
@RENDERER(default="mask", show_default=True)
@OSM(detail=": with --renderer geometry, the files (.osm, .osm.pbf) the masks were built from.")
@moved("-n", "-n is build's --samples: localize-bench renders --viewpoints N")
@moved("--mode", "--mode is predict's (split-join or rescale): the landmarks are --landmark-mode "
                 "centroid|grid|component")
@moved("--width", "--width is train's (channels): the panorama's is --pano-width")
@moved("--height", "--height is now --pano-height")
@moved("--table", "--table is now --classes (the class table of a mask file)")
@click.pass_context
@report_errors
def localize_bench_command(ctx: click.Context, /, **params: Any) -> None:
    """Render panoramas at seeded viewpoints of SOURCE and localize them in it.

    SOURCE is a dataset folder made by `osmseg build` (its labels/ and manifest.json), or one
    label mask file (PNG/GeoTIFF of class ids) with --classes and --aerial-resolution. (A folder of
    annotated aerial/ground pairs is `osmseg localize-pairs`'s.) Prints the path of
    results.json on stdout and a summary on stderr.
    """
    request = RenderedBench(**params, typed=typed_flags(ctx))
    with progress_drawer(_drawn(ctx)) as progress:
        results = request.run(progress)
    _report(ctx, results, request.out_dir)


@dataclass(frozen=True)
class RenderedBench:
    """What ``osmseg localize-bench`` was asked: its options by parameter name, typed and frozen,
    and ``typed`` (parameter -> flag) the ones given on the command line. :meth:`run` is the one
    library call; the checks of options that do not go together are here, not in the command."""

    source: Path
    out_dir: Path
    viewpoints: int
    seed: int
    table: str
    resolution: float | None
    landmark_dict: str | None
    mode: str
    min_size: int
    stride: int
    window_text: str
    p: float
    top_k: int
    margin: float
    stand_on: tuple[str, ...]
    subsets: bool
    width: int
    height: int
    camera_height: str
    max_range: float
    class_height: tuple[str, ...]
    confusion: float
    miss_small: int
    miss_prob: float
    offset: float
    query_landmarks: str
    visible_min_px: int
    save_panoramas: int
    pictures: int
    plots: bool
    methods_text: str
    heading: str
    fov_deg: float
    height_spread: float
    negatives: bool
    renderer: str
    osm: tuple[str, ...]
    typed: Mapping[str, str] = field(default_factory=dict)

    def config(self) -> BenchConfig:
        """The benchmark's :class:`~localization.bench.rendered.BenchConfig`."""
        from localization.bench.render import NoiseConfig, RenderConfig
        from localization.bench.rendered import BenchConfig

        if self.query_landmarks != "visible" and "visible_min_px" in self.typed:
            raise ConfigError("--visible-min-px applies with --query-landmarks visible only: add it or leave it out")
        return BenchConfig(
            viewpoints=self.viewpoints, seed=self.seed, landmarks=self.landmark_dict, mode=self.mode,
            min_size=self.min_size, stride=self.stride, window=parse_window(self.window_text), p=self.p,
            top_k=self.top_k, margin_m=self.margin, stand_on=tuple(self.stand_on) or None, subsets=self.subsets,
            render=RenderConfig(width=self.width, height=self.height, camera_height_m=_rendered_height(self.camera_height),
                                max_range_m=self.max_range, heights=parse_heights(self.class_height),
                                height_spread=self.height_spread, height_seed=self.seed),
            noise=NoiseConfig(confusion=self.confusion, miss_small_px=self.miss_small, miss_prob=self.miss_prob,
                              offset_m=self.offset),
            save_panoramas=self.save_panoramas, pictures=self.pictures, query_landmarks=self.query_landmarks,
            visible_min_px=self.visible_min_px, methods=_methods(self.methods_text, self.typed), heading=self.heading,
            fov_deg=self.fov_deg, negatives=self.negatives, renderer=self.renderer,
            osm=tuple(str(o) for o in osm_files(self.osm)),
        )

    def run(self, progress: Progress | None = None) -> BenchResults:
        """Render the views, localize them, write results.json and the pictures into ``out_dir``."""
        from localization.bench.pairs import is_pairs_folder
        from localization.bench.rendered import load_dataset_scenes, load_mask_scene, run_bench

        config = self.config()
        if self.source.is_dir() and is_pairs_folder(self.source):
            raise ConfigError(f"{self.source} is a folder of annotated pairs (aerial/ + ground/): score them with "
                              f"osmseg localize-pairs {self.source} --out {self.out_dir}")
        if self.source.is_dir():
            if self.resolution is not None or "table" in self.typed:
                raise ConfigError("--aerial-resolution and --classes are for a mask file; a dataset folder records "
                                  "its own")
            scenes = load_dataset_scenes(self.source)
        else:
            if self.resolution is None:
                raise ConfigError(f"{self.source} is a mask file: give its ground resolution with --aerial-resolution "
                                  "(m/px)")
            scenes = [load_mask_scene(self.source, self.table, self.resolution)]
        return run_bench(scenes, config, self.out_dir, progress=progress, plots=self.plots, source=str(self.source))


@click.command("localize-pairs")
@output_options
@click.argument("folder", type=click.Path(exists=True, file_okay=False, path_type=Path))
@bench_options
@AERIAL_SIZE()
@GROUND_SIZE()
@CONVENTIONS(default="osmseg", show_default=True)
@click.pass_context
@report_errors
def localize_pairs_command(ctx: click.Context, /, **params: Any) -> None:
    """Localize every annotated pair of FOLDER: the paper's own evaluation.

    FOLDER holds aerial/NAME.txt and ground/NAME.txt landmark files (x y Class), images beside
    them or --aerial-size/--ground-size, and the truth in truth.csv (name,x,y) or the aerial
    centre. Nothing is rendered; the landmark dictionary defaults to camvid (Building,
    Pavement, Road, Tree) and errors are in pixels unless --aerial-resolution gives the aerial m/px.
    Prints the path of results.json on stdout and a summary on stderr.
    """
    request = AnnotatedPairs(**params, typed=typed_flags(ctx))
    with progress_drawer(_drawn(ctx)) as progress:
        results = request.run(progress)
    _report(ctx, results, request.out_dir)


@dataclass(frozen=True)
class AnnotatedPairs:
    """What ``osmseg localize-pairs`` was asked (as :class:`RenderedBench`); :meth:`run` is the one
    library call."""

    folder: Path
    out_dir: Path
    resolution: float | None
    landmark_dict: str | None
    window_text: str
    p: float
    top_k: int
    subsets: bool
    camera_height: str
    methods_text: str
    heading: str
    plots: bool
    aerial_size: str | None
    ground_size: str | None
    conventions: str
    typed: Mapping[str, str] = field(default_factory=dict)

    def run(self, progress: Progress | None = None) -> BenchResults:
        """Localize every pair of ``folder``, write results.json and the pictures into ``out_dir``."""
        from localization.bench.pairs import PairsConfig, is_pairs_folder, load_pairs, run_pairs

        methods = _methods(self.methods_text, self.typed)
        if not is_pairs_folder(self.folder):
            raise ConfigError(f"{self.folder} is not a folder of annotated pairs (aerial/NAME.txt + ground/NAME.txt); "
                              f"to render views of a dataset or mask, run osmseg localize-bench {self.folder} --out "
                              f"{self.out_dir}")
        config = PairsConfig(landmarks=self.landmark_dict or "camvid", window=parse_window(self.window_text), p=self.p,
                             top_k=self.top_k, subsets=self.subsets, resolution_m=self.resolution,
                             aerial_size=parse_size(self.aerial_size, "--aerial-size"),
                             ground_size=parse_size(self.ground_size, "--ground-size"), methods=methods,
                             heading=self.heading, camera_height_m=_rendered_height(self.camera_height),
                             conventions=self.conventions)
        return run_pairs(load_pairs(self.folder, config), config, self.out_dir, progress=progress, plots=self.plots,
                         source=str(self.folder))
