"""``osmseg localize``: where in the aerial image was the ground view taken (the benchmarks: :mod:`localization.cli.bench`).

Registered on the ``osmseg`` group as plugins (entry points ``osmseg.commands``), so the core
package never imports this one. Imports: osmseg core, training (through
:mod:`localization.common.inputs`, for segmenting RGB inputs) and localization.

Each side (``--aerial``, ``--ground``) is a label mask (PNG/TIFF of class ids), a landmark file
(``x y Class`` lines, ``.csv`` or ``.npy``), or an RGB image with ``--*-checkpoint`` to segment
it first. A mask's class table is ``--*-table``, else the ``manifest.json`` of the osmseg
dataset it belongs to (``DATASET/labels/NAME.png``), else the one the landmark dictionary names
(``mask_table``/``mask_classes`` in ``data_manifests/landmarks-*.toml``). A landmark file's
image size is ``--*-size``, else that of an image beside it with the same name (also drawn
under the pictures), else the extent of its landmarks (with a warning).

``--feature-threshold T`` removes the graph edges between landmarks whose encoder features
are closer than T (§5.3.2, :mod:`localization.paper.features`) on each side that is an RGB image or
has its photo as ``--*-image``; result.json's ``feature_edges`` says how many went per side.

The top-k locations go to stdout (a table, or JSON with ``--json``); "unanswered" (no place
in the aerial image shows every class the ground sees) is a normal outcome: exit 0. Bad input
(an unreadable file, no landmarks, a window larger than the image, landmarks of a single
class on both sides) is a one-line error, exit 1 (2 for options).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from localization.cli.options import (
    AERIAL_LANDMARKS,
    AERIAL_RESOLUTION,
    AERIAL_SIZE,
    CAMERA_HEIGHT,
    CONVENTIONS,
    FOV,
    GRID_STRIDE,
    GROUND_LANDMARKS,
    GROUND_SIZE,
    HEADING,
    LANDMARK_MODE,
    METHOD,
    MIN_SIZE,
    TOP_K,
    WINDOW,
    P,
    given,
    misplaced,
    parse_camera_height,
    parse_heading,
    parse_point,
    parse_window,
    parse_windows,
)
from localization.cli.region import RegionArgs, region_options, run_region
from localization.common.inputs import SideOptions
from osmseg.cli.common import output_options, parse_size, report_errors
from osmseg.cli.options import OUT, declare, moved
from osmseg.errors import ConfigError
from osmseg.texttable import text_table
from osmseg.units import degrees, metres, number, pixels, plural, ratio

if TYPE_CHECKING:  # the command imports the pipeline only when it runs
    from localization.pipeline import LocalizeReport

logger = logging.getLogger(__name__)

# --------------------------------------------------------------------------- checks and output


def _table(result: Any) -> str:
    """The top-k as a fixed-width table."""
    return text_table(["rank", "x", "y", "posterior", "likelihood"],
                      [[str(rank), number(x, "px"), number(y, "px"), ratio(post), ratio(float(result.likelihoods[i]))]
                       for rank, ((x, y, post), i) in enumerate(zip(result.top_k, result.order), start=1)], left=0)


AERIAL = declare("--aerial", dest="aerial_path", type=click.Path(exists=True, dir_okay=False, path_type=Path),
                 help="Aerial label mask (PNG/TIFF of class ids), landmark file (x y Class, .csv, .npy) or RGB image "
                      "with --aerial-checkpoint. Or no aerial image at all: a region's OSM with --osm and --bbox.")
GROUND = declare("--ground", dest="ground_path", type=click.Path(exists=True, dir_okay=False, path_type=Path),
                 help="Ground panorama: label mask, landmark file, or RGB image with --ground-checkpoint.")
AERIAL_TABLE = declare("--aerial-table", help="Class table of the aerial mask, e.g. classes13.toml.")
GROUND_TABLE = declare("--ground-table", help="Class table of the ground mask.")
AERIAL_CHECKPOINT = declare("--aerial-checkpoint", type=click.Path(exists=True, path_type=Path),
                            help="Segment the aerial RGB image with this checkpoint first (needs PyTorch).")
GROUND_CHECKPOINT = declare("--ground-checkpoint", type=click.Path(exists=True, path_type=Path),
                            help="Segment the ground RGB image with this checkpoint first (needs PyTorch).")
NO_PANORAMA = declare("--panorama/--no-panorama",
                      help="The ground image is a 360-degree panorama (x wraps around); --no-panorama for an aerial "
                           "crop.")
GROUND_WINDOW = declare("--ground-window", type=click.IntRange(min=1), help="Ground window in pixels.")
STRIDE = declare("--stride", type=click.IntRange(min=1), help="Window stride in pixels.")
HIERARCHICAL = declare("--hierarchical", is_flag=True,
                       help="Refine over --windows, multiplying probabilities (eq. 3.8).")
WINDOWS = declare("--windows", dest="windows_text", help="Hierarchical windows, coarse to fine.")
REFERENCE = declare("--reference", is_flag=True,
                    help="Build graphs with the paper's plain sliding window (slow; a check).")
TRUTH = declare("--truth", dest="truth_text",
                help="Ground-truth viewpoint X,Y in aerial pixels (with --osm: LON,LAT): reports the error.")
JSON = declare("--json", dest="as_json", is_flag=True, help="Print the result as JSON instead of a table.")
AERIAL_IMAGE = declare("--aerial-image", type=click.Path(exists=True, dir_okay=False, path_type=Path),
                       help="RGB photo of the aerial mask or landmark file: for --feature-threshold, and drawn under "
                            "the graph.")
GROUND_IMAGE = declare("--ground-image", type=click.Path(exists=True, dir_okay=False, path_type=Path),
                       help="RGB photo of the ground mask or landmark file.")
FEATURE_THRESHOLD = declare("--feature-threshold", type=click.FloatRange(min=0, min_open=True),
                            help="Remove edges between landmarks whose encoder features are closer than this "
                                 "(§5.3.2).")
FEATURE_METRIC = declare("--feature-metric", type=click.Choice(["euclidean", "cosine"]),
                         help="Distance between two landmarks' encoder features.")
FEATURE_REDUCE = declare("--feature-reduce", type=click.Choice(["none", "pca", "umap"]),
                         help="Reduce the features first (umap needs umap-learn). PCA centres them: with 2 landmarks "
                              "their cosine distance is 2, so nothing is dropped.")
FEATURE_COMPONENTS = declare("--feature-components", type=click.IntRange(min=1),
                             help="Dimensions --feature-reduce keeps.")
FEATURE_CHECKPOINT = declare("--feature-checkpoint", type=click.Path(exists=True, path_type=Path),
                             help="Checkpoint whose encoder gives the features.")
TILT = declare("--tilt", dest="tilt_deg", type=click.FloatRange(0, 10),
               help="Profile method: the camera may be tilted up to this many degrees in pitch and roll; the tilt is "
                    "read from the ground mask's horizon, where its sky ends and its ground begins (give the sky as "
                    "a class: the ground table's 'sky', id 14 for classes13).")
MIN_CONFIDENCE = declare("--min-confidence", type=click.FloatRange(-1, 1),
                         help="Profile method: below this confidence (how far the answer stands out from the best "
                              "place 50 m or more away) the answer is 'not sure'.")
MIN_KAPPA = declare("--min-kappa", type=click.FloatRange(-1, 1),
                    help="Profile method: below this kappa (the best match against chance) the answer is 'not in "
                         "this image'; lower it for segmented RGB queries.")


@click.command("localize")
@output_options
@AERIAL()
@region_options
@GROUND(required=True)
@AERIAL_LANDMARKS(default="aerial13", show_default=True)
@GROUND_LANDMARKS(default="camvid", show_default=True)
@AERIAL_TABLE(show_default="its dataset's manifest")
@GROUND_TABLE(show_default="the dictionary's own")
@AERIAL_SIZE(show_default="an image beside it")
@GROUND_SIZE()
@AERIAL_CHECKPOINT()
@GROUND_CHECKPOINT()
@NO_PANORAMA(default=True, show_default=True)
@WINDOW(default="auto", show_default=True)
@GROUND_WINDOW(show_default="a panorama's height; otherwise the aerial window")
@P(default=0.5, show_default=True)
@TOP_K(default=5, show_default=True)
@STRIDE(default=1, show_default=True)
@HIERARCHICAL()
@WINDOWS(default="400,200,100", show_default=True)
@LANDMARK_MODE(dest="mode", default="centroid", show_default=True)
@MIN_SIZE(default=50, show_default=True)
@GRID_STRIDE(default=50, show_default=True)
@REFERENCE()
@TRUTH()
@AERIAL_RESOLUTION(dest="resolution", show_default="a GeoTIFF's, or the dataset manifest's")
@JSON()
@OUT(detail=" of localization.png, aerial_graph.png, ground_graph.png and result.json.")
@AERIAL_IMAGE()
@GROUND_IMAGE()
@FEATURE_THRESHOLD(show_default="off")
@FEATURE_METRIC(default="cosine", show_default=True)
@FEATURE_REDUCE(default="pca", show_default=True)
@FEATURE_COMPONENTS(default=8, show_default=True)
@FEATURE_CHECKPOINT(show_default="the side's --aerial-checkpoint/--ground-checkpoint")
@CONVENTIONS(default="osmseg", show_default=True)
@METHOD(default="profile", show_default=True)
@HEADING(default="0", show_default=True)
@FOV(default=360.0, show_default=True)
@CAMERA_HEIGHT(default="2", show_default=True)
@TILT(default=0.0, show_default="level")
@MIN_CONFIDENCE(show_default="0.04 for an aerial mask, none for aerial landmark points")
@MIN_KAPPA(show_default="0.6 for an aerial mask, 0.3 for aerial landmark points")
@moved("--mode", "--mode is predict's (split-join or rescale): osmseg localize's landmarks are --landmark-mode "
                 "centroid|grid|component")
@moved("--resolution", "--resolution is predict's (resample the input): osmseg localize takes the aerial "
                       "image's metres per pixel as --aerial-resolution")
@moved("--aerial-classes", "--aerial-classes is now --aerial-landmarks (a landmark dictionary; --aerial-table is "
                           "the class table)")
@moved("--ground-classes", "--ground-classes is now --ground-landmarks (a landmark dictionary; --ground-table is "
                           "the class table)")
@click.pass_context
@report_errors
def localize_command(ctx: click.Context, aerial_path: Path, ground_path: Path, aerial_classes: str,
                     ground_classes: str, aerial_table: str | None, ground_table: str | None, aerial_size: str | None,
                     ground_size: str | None, aerial_checkpoint: Path | None, ground_checkpoint: Path | None,
                     panorama: bool, window_text: str, ground_window: int | None, p: float, top_k: int, stride: int,
                     hierarchical: bool, windows_text: str, mode: str, min_size: int, grid_stride: int,
                     reference: bool, truth_text: str | None, resolution: float | None, as_json: bool,
                     out_dir: Path | None, aerial_image: Path | None, ground_image: Path | None,
                     feature_threshold: float | None, feature_metric: str, feature_reduce: str,
                     feature_components: int, feature_checkpoint: Path | None, conventions: str, method: str,
                     heading_text: str,
                     fov_deg: float, camera_height_text: str, tilt_deg: float, min_confidence: float | None,
                     min_kappa: float | None,
                     region: RegionArgs) -> None:
    """Find where the GROUND panorama was taken in the AERIAL image (landmark graphs, or angular profiles),
    or anywhere in a region's OpenStreetMap (--osm FILE --bbox W,S,E,N)."""
    from localization.paper.config import PaperConfig
    from localization.paper.features import FeatureEdges
    from localization.pipeline import LocalizeConfig, LocalizeFiles, localize_files
    from localization.profile.search import ProfileConfig

    verbosity = (ctx.obj or {}).get("verbosity", 0)
    camera_height, heights = parse_camera_height(camera_height_text)
    if region.given or aerial_path is None:  # a region of OSM, no aerial image
        stray = given(ctx, ("aerial_path", "aerial_size", "aerial_checkpoint", "aerial_image", "resolution",
                             "window_text", "ground_window", "p", "stride", "hierarchical", "windows_text",
                             "reference", "feature_threshold", "conventions", "min_confidence", "min_kappa",
                             "panorama"))
        run_region(ctx, ground_path, region, method, ground_classes, ground_table, ground_size,
                   ground_checkpoint, aerial_classes, aerial_table or "classes13.toml", mode, min_size, grid_stride,
                   ProfileConfig(heading_deg=parse_heading(heading_text), camera_heights=heights, tilt_deg=tilt_deg),
                   fov_deg, camera_height, top_k, truth_text, out_dir, as_json, verbosity, stray)
        return
    if stray := given(ctx, ("zoom", "cache_dir")):
        raise ConfigError(f"{', '.join(stray)} is for a region (--osm FILE --bbox W,S,E,N): add them, or leave "
                          "it out")
    window, windows, truth = parse_window(window_text), parse_windows(windows_text), parse_point(truth_text)
    if feature_threshold is None and (stray := given(ctx, ("feature_checkpoint", "feature_metric", "feature_reduce",
                                                            "feature_components"))):
        raise ConfigError(f"{', '.join(stray)} set how --feature-threshold removes edges: add --feature-threshold "
                          "T, or leave them out")
    features = (None if feature_threshold is None else
                FeatureEdges(feature_threshold, feature_metric, feature_reduce, feature_components))
    only = {"profile": ("heading_text", "fov_deg", "camera_height_text", "tilt_deg", "min_confidence", "min_kappa"),
            "paper": ("window_text", "ground_window", "p", "stride", "hierarchical", "windows_text", "reference",
                      "feature_threshold", "conventions")}
    for name, options in only.items():
        if method != name and (stray := given(ctx, options)):
            raise misplaced(stray, f"--method {name}", f"--method {name}")
    paper = PaperConfig(window=window, query_window=ground_window, p=p, stride=stride, top_k=top_k,
                        fast=not reference, hierarchical=hierarchical, windows=windows, conventions=conventions)
    config = LocalizeConfig(method=method, paper=paper, features=features, fov_deg=fov_deg, camera_height_m=camera_height,
                            profile=ProfileConfig(heading_deg=parse_heading(heading_text), top_k=top_k,
                                                  min_confidence=min_confidence, min_kappa=min_kappa,
                                                  camera_heights=heights, tilt_deg=tilt_deg))

    def side(name: str, classes: str, table: str | None, size: str | None, checkpoint: Path | None,
             is_panorama: bool) -> SideOptions:
        return SideOptions(name, classes, table, parse_size(size, f"--{name}-size"), checkpoint, is_panorama,
                           mode=mode, min_size=min_size, grid_stride=grid_stride)

    request = LocalizeFiles(
        aerial=aerial_path, ground=ground_path,
        aerial_options=side("aerial", aerial_classes, aerial_table, aerial_size, aerial_checkpoint, False),
        ground_options=side("ground", ground_classes, ground_table, ground_size, ground_checkpoint, panorama),
        aerial_image=aerial_image, ground_image=ground_image, feature_checkpoint=feature_checkpoint,
        truth=truth, resolution_m=resolution)
    report = localize_files(request, config, out_dir)
    _say(report, as_json=as_json, quiet=verbosity < 0, hierarchical=hierarchical, auto_window=window is None,
         out_dir=out_dir)


def _say(report: LocalizeReport, *, as_json: bool, quiet: bool, hierarchical: bool, auto_window: bool,
         out_dir: Path | None) -> None:
    """What ``osmseg localize`` prints: the answer on stdout (a table, or JSON), how it was found on stderr."""
    result = report.result
    if as_json:
        click.echo(json.dumps({**report.summary, **result.to_dict(all_candidates=False),
                               "files": [str(f) for f in report.written]}, indent=2, sort_keys=True))
    elif result.unanswered:
        click.echo(f"unanswered: {result.reason}")
    else:
        click.echo(_table(result))
    if not quiet and not as_json:
        if result.method == "profile" and result.confidence is not None:
            alt = (f"; best place 50 m or more away scores {ratio(result.margin)} less" if result.margin is not None
                   else "")
            pose = ""
            if result.camera_pose is not None:
                h, pitch, roll = result.camera_pose
                pose = f", camera {metres(h)} up, pitch {degrees(pitch)}, roll {degrees(roll)}"
            click.echo(f"profile method: heading {degrees(result.heading_deg)}{pose}, confidence "
                       f"{ratio(result.confidence)} (kappa {ratio(result.kappa)} against chance "
                       f"{ratio(result.chance)}{alt}), {plural(len(result.candidates), 'position')} at the finest level", err=True)
        elif not result.unanswered:
            ties = f", {result.ties} tied at the top (broken as documented)" if result.ties > 1 else ""
            used = (f"windows {', '.join(str(lv.window) for lv in result.levels)} px (hierarchical)" if hierarchical
                    else f"window {result.window} px{' (auto)' if auto_window else ''}")
            click.echo(f"{used}, ground window {result.query_window} px, {plural(result.n_cliques, 'clique')}, "
                       f"{plural(len(result.candidates), 'candidate')}{ties}", err=True)
        if "map_lonlat" in report.summary:
            where = report.summary["map_lonlat"]
            click.echo(f"the answer in degrees (the aerial image's georeference): {where['lon']:.7f}, "
                       f"{where['lat']:.7f}", err=True)
        if report.error_px is not None:
            click.echo(f"error of the best location: {pixels(report.error_px)}"
                       + (f" ({metres(report.error_m)})" if report.error_m is not None else ""), err=True)
        if report.written:
            click.echo(f"written: {', '.join(f.name for f in report.written)} in {out_dir}/", err=True)
