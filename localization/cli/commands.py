"""The localization package's commands: ``osmseg localize`` and ``osmseg localize-bench``.

Registered on the ``osmseg`` group as plugins (entry points ``osmseg.commands``), so the core
package never imports this one. Imports: osmseg core, training (through
:mod:`localization.common.inputs`, for segmenting RGB inputs) and localization.

``osmseg localize``: where in the aerial image was the ground panorama taken?

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
    parse_camera_height,
    parse_heading,
    parse_heights,
    parse_point,
    parse_window,
    parse_windows,
)
from localization.cli.region import RegionArgs, region_options, run_region
from localization.cli.summary import format_summary
from localization.common.inputs import SideOptions
from osmseg.cli.common import output_options, parse_size, progress_bars, renamed_option, report_errors, typed_options
from osmseg.errors import ConfigError
from osmseg.units import degrees, metres, number, pixels, ratio

if TYPE_CHECKING:  # the command imports the pipeline only when it runs
    from localization.pipeline import LocalizeReport

logger = logging.getLogger(__name__)

# --------------------------------------------------------------------------- checks and output


def _table(result: Any) -> str:
    """The top-k as a fixed-width table."""
    lines = [f"{'rank':>4}  {'x':>8}  {'y':>8}  {'posterior':>10}  {'likelihood':>10}"]
    for rank, ((x, y, post), i) in enumerate(zip(result.top_k, result.order), start=1):
        lines.append(f"{rank:>4}  {number(x, 'px'):>8}  {number(y, 'px'):>8}  {ratio(post):>10}  "
                     f"{ratio(float(result.likelihoods[i])):>10}")
    return "\n".join(lines)


@click.command("localize")
@output_options
@click.option("--aerial", "aerial_path", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Aerial label mask (PNG/TIFF of class ids), landmark file (x y Class, .csv, .npy) or RGB image "
                   "with --aerial-checkpoint. Or no aerial image at all: a region's OSM with --osm and --bbox.")
@region_options
@click.option("--ground", "ground_path", required=True,
              type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Ground panorama: label mask, landmark file, or RGB image with --ground-checkpoint.")
@click.option("--aerial-classes", default="aerial13", show_default=True,
              help="Landmark class dictionary of the aerial side (data_manifests/landmarks-NAME.toml, or a path).")
@click.option("--ground-classes", default="camvid", show_default=True,
              help="Landmark class dictionary of the ground side.")
@click.option("--aerial-table", show_default="its dataset's manifest",
              help="Class table of the aerial mask, e.g. classes13.toml.")
@click.option("--ground-table", show_default="the dictionary's own", help="Class table of the ground mask.")
@click.option("--aerial-size", show_default="an image beside it", help="WIDTHxHEIGHT of the aerial landmark file's image.")
@click.option("--ground-size", help="WIDTHxHEIGHT of the ground landmark file's image, e.g. 1232x224.")
@click.option("--aerial-checkpoint", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Segment the aerial RGB image with this checkpoint first (needs PyTorch).")
@click.option("--ground-checkpoint", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Segment the ground RGB image with this checkpoint first (needs PyTorch).")
@click.option("--panorama/--no-panorama", default=True, show_default=True,
              help="The ground image is a 360-degree panorama (x wraps around); --no-panorama for an aerial crop.")
@click.option("--window", "window_text", default="auto", show_default=True,
              help="Aerial covisibility window in pixels, or auto: mean + 5 sd of nearest-neighbour distances.")
@click.option("--ground-window", type=click.IntRange(min=1), show_default="a panorama's height; otherwise the aerial window",
              help="Ground window in pixels.")
@click.option("--p", "p", type=click.FloatRange(0, 1, min_open=True), default=0.5, show_default=True,
              help="Candidate extension: add cliques sharing at least this fraction of a relevant clique's landmarks.")
@click.option("--top-k", type=click.IntRange(min=1), default=5, show_default=True)
@click.option("--stride", type=click.IntRange(min=1), default=1, show_default=True, help="Window stride in pixels.")
@click.option("--hierarchical", is_flag=True, help="Refine over --windows, multiplying probabilities (eq. 3.8).")
@click.option("--windows", "windows_text", default="400,200,100", show_default=True,
              help="Hierarchical windows, coarse to fine.")
@click.option("--mode", type=click.Choice(["centroid", "grid", "component"]), default="centroid", show_default=True,
              help="Landmarks of a mask: component centroids, grid points, or whole components.")
@click.option("--min-size", type=click.IntRange(min=0), default=50, show_default=True,
              help="Mask components smaller than this (pixels) are no landmarks.")
@click.option("--grid-stride", type=click.IntRange(min=1), default=50, show_default=True,
              help="Spacing of --mode grid.")
@click.option("--reference", is_flag=True, help="Build graphs with the paper's plain sliding window (slow; a check).")
@click.option("--truth", "truth_text", help="Ground-truth viewpoint X,Y in aerial pixels (with --osm: LON,LAT): "
              "reports the error.")
@click.option("--resolution", type=click.FloatRange(min=0, min_open=True),
              show_default="a GeoTIFF's, or the dataset manifest's",
              help="Metres per aerial pixel, for errors in metres.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON instead of a table.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Folder for localization.png, aerial_graph.png, ground_graph.png and result.json.")
@click.option("--aerial-image", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="RGB photo of the aerial mask or landmark file: for --feature-threshold, and drawn under the graph.")
@click.option("--ground-image", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="RGB photo of the ground mask or landmark file.")
@click.option("--feature-threshold", type=click.FloatRange(min=0, min_open=True),
              show_default="off", help="Remove edges between landmarks whose encoder features are closer than this (§5.3.2).")
@click.option("--feature-metric", type=click.Choice(["euclidean", "cosine"]), default="cosine", show_default=True)
@click.option("--feature-reduce", type=click.Choice(["none", "pca", "umap"]), default="pca", show_default=True,
              help="Reduce the features first (umap needs umap-learn). PCA centres them: with 2 landmarks their cosine distance is 2, so nothing is dropped.")
@click.option("--feature-components", type=click.IntRange(min=1), default=8, show_default=True,
              help="Dimensions --feature-reduce keeps.")
@click.option("--feature-checkpoint", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              show_default="the side's --aerial-checkpoint/--ground-checkpoint",
              help="Checkpoint whose encoder gives the features.")
@click.option("--conventions", type=click.Choice(["osmseg", "authors"]), default="osmseg", show_default=True,
              help="Paper method: osmseg's (windows from pixel 0, each candidate at the mean of its windows, ties "
                   "by the clique's own likelihood) or the authors' MATLAB demo's (windows from pixel 1, the first "
                   "window, ties to the first clique in lexicographic order), to reproduce their figures.")
@click.option("--method", type=click.Choice(["profile", "paper"]), default="profile", show_default=True,
              help="profile: angular profiles on a dense grid (docs/localization.md), which also gives the heading "
                   "and a confidence, and needs the aerial resolution; paper: landmark-graph matching (Verde et "
                   "al. 2020).")
@click.option("--heading", "heading_text", default="0", show_default=True,
              help="Profile method: compass azimuth (degrees) of the ground image's centre column, or 'unknown' "
                   "to search it. CVUSA-style panoramas are north-aligned: 0.")
@click.option("--fov", "fov_deg", type=click.FloatRange(10, 360), default=360.0, show_default=True,
              help="Profile method: horizontal field of view of the ground image in degrees (a photo: 60-120).")
@click.option("--camera-height", "camera_height_text", default="2", show_default=True,
              help="Profile method: metres of the ground camera above the ground, or 'unknown' to try 1.5 to "
                   "2.5 m in 0.25 m steps (a hand-held camera to a car's), each place with the height that fits it.")
@click.option("--tilt", "tilt_deg", type=click.FloatRange(0, 10), default=0.0, show_default="level",
              help="Profile method: the camera may be tilted up to this many degrees in pitch and roll; the tilt is "
                   "read from the ground mask's horizon, where its sky ends and its ground begins (give the sky as a "
                   "class: the ground table's 'sky', id 14 for classes13).")
@click.option("--min-confidence", type=click.FloatRange(-1, 1), show_default="0.04 for an aerial mask, none for aerial "
              "landmark points", help="Profile method: below this confidence (how far the answer stands out from "
              "the best place 50 m or more away) the answer is 'not sure'.")
@click.option("--min-kappa", type=click.FloatRange(-1, 1), show_default="0.6 for an aerial mask, 0.3 for aerial landmark "
              "points", help="Profile method: below this kappa (the best match against chance) the answer is 'not in "
              "this image'; lower it for segmented RGB queries.")
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
        stray = _given(ctx, ("aerial_path", "aerial_size", "aerial_checkpoint", "aerial_image", "resolution",
                             "window_text", "ground_window", "p", "stride", "hierarchical", "windows_text",
                             "reference", "feature_threshold", "conventions", "min_confidence", "min_kappa",
                             "panorama"))
        run_region(ctx, ground_path, region, method, ground_classes, ground_table, ground_size,
                   ground_checkpoint, aerial_classes, aerial_table or "classes13.toml", mode, min_size, grid_stride,
                   ProfileConfig(heading_deg=parse_heading(heading_text), camera_heights=heights, tilt_deg=tilt_deg),
                   fov_deg, camera_height, top_k, truth_text, out_dir, as_json, verbosity, stray)
        return
    if stray := _given(ctx, ("zoom", "cache_dir")):
        raise ConfigError(f"{', '.join(stray)} is for a region (--osm FILE --bbox W,S,E,N): add them, or leave "
                          "it out")
    window, windows, truth = parse_window(window_text), parse_windows(windows_text), parse_point(truth_text)
    if feature_threshold is None and (stray := _given(ctx, ("feature_checkpoint", "feature_metric", "feature_reduce",
                                                            "feature_components"))):
        raise ConfigError(f"{', '.join(stray)} set how --feature-threshold removes edges: add --feature-threshold "
                          "T, or leave them out")
    features = (None if feature_threshold is None else
                FeatureEdges(feature_threshold, feature_metric, feature_reduce, feature_components))
    only = {"profile": ("heading_text", "fov_deg", "camera_height_text", "tilt_deg", "min_confidence", "min_kappa"),
            "paper": ("window_text", "ground_window", "p", "stride", "hierarchical", "windows_text", "reference",
                      "feature_threshold", "conventions")}
    for name, options in only.items():
        if method != name and (stray := _given(ctx, options)):
            raise _misplaced(stray, f"--method {name}", f"--method {name}")
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
                       f"{ratio(result.chance)}{alt}), {len(result.candidates)} positions at the finest level", err=True)
        elif not result.unanswered:
            ties = f", {result.ties} tied at the top (broken as documented)" if result.ties > 1 else ""
            used = (f"windows {', '.join(str(lv.window) for lv in result.levels)} px (hierarchical)" if hierarchical
                    else f"window {result.window} px{' (auto)' if auto_window else ''}")
            click.echo(f"{used}, ground window {result.query_window} px, {result.n_cliques} cliques, "
                       f"{len(result.candidates)} candidates{ties}", err=True)
        if "map_lonlat" in report.summary:
            where = report.summary["map_lonlat"]
            click.echo(f"the answer in degrees (the aerial image's georeference): {where['lon']:.7f}, "
                       f"{where['lat']:.7f}", err=True)
        if report.error_px is not None:
            click.echo(f"error of the best location: {pixels(report.error_px)}"
                       + (f" ({metres(report.error_m)})" if report.error_m is not None else ""), err=True)
        if report.written:
            click.echo(f"written: {', '.join(f.name for f in report.written)} in {out_dir}/", err=True)


def _misplaced(stray: list[str], owner: str, fix: str) -> ConfigError:
    """The one-line error for options that belong to another method than the one run.

    >>> str(_misplaced(["--window"], "the paper method", "paper to --method"))
    '--window applies to the paper method: add paper to --method, or leave it out'
    """
    verb, them = ("applies", "it") if len(stray) == 1 else ("apply", "them")
    return ConfigError(f"{', '.join(stray)} {verb} to {owner}: add {fix}, or leave {them} out")


#: Options that only make sense for one kind of SOURCE (a mistake to give for the other).
RENDER_ONLY = ("viewpoints", "seed", "table", "mode", "min_size", "stride", "margin", "stand_on", "width", "height",
               "max_range", "class_height", "confusion", "miss_small", "miss_prob", "offset",
               "query_landmarks", "visible_min_px", "save_panoramas", "pictures", "fov_deg",
               "height_spread", "negatives", "renderer", "osm")
PAIRS_ONLY = ("aerial_size", "ground_size", "conventions")


def _given(ctx: click.Context, names: tuple[str, ...]) -> list[str]:
    """The options among ``names`` that were typed on the command line, as ``--option-names``."""
    by_name = {p.name: p for p in ctx.command.params}
    typed = typed_options(ctx)
    return [max(by_name[n].opts, key=len) for n in names if n in typed]


@click.command("localize-bench")
@output_options
@click.argument("source", type=click.Path(exists=True, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Folder for results.json, errors.png and classes.png.")
@click.option("--viewpoints", type=click.IntRange(min=1), default=20, show_default=True,
              help="Rendered panoramas to localize, placed round-robin over the masks (-n is build's --samples).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seeds viewpoints and noise.")
@click.option("--table", default="classes13.toml", show_default=True,
              help="Class table of a mask file (a dataset folder brings its own).")
@click.option("--resolution", type=float, show_default="a dataset's own",
              help="Ground resolution of a mask file in m/px.")
@click.option("--landmarks", "landmark_dict", show_default="the one for the class table; camvid for annotated pairs",
              help="Landmark class dictionary (data_manifests/landmarks-*.toml).")
@click.option("--mode", type=click.Choice(["centroid", "grid", "component"]), default="centroid", show_default=True,
              help="Landmarks as component centroids, grid points or whole components.")
@click.option("--min-size", type=int, default=50, show_default=True, help="Smallest landmark component (pixels).")
@click.option("--grid-stride", "stride", type=click.IntRange(min=1), default=50, show_default=True,
              help="Grid step for --mode grid (pixels), as osmseg localize's --grid-stride.")
@click.option("--window", type=int, show_default="mu + 5 sigma of nearest-neighbour distances",
              help="Aerial covisibility window (pixels).")
@click.option("--p", "p", type=float, default=0.5, show_default=True, help="Covisibility parameter of candidates.")
@click.option("--top-k", type=int, default=5, show_default=True)
@click.option("--margin", type=float, default=20.0, show_default=True,
              help="Viewpoints stay this many metres from the mask border.")
@click.option("--stand-on", multiple=True, show_default="every flat class but unlabeled and water",
              help="Classes viewpoints may stand on (repeatable).")
@click.option("--subsets/--no-subsets", default=True, show_default=True,
              help="Also localize with every subset of 2, 3... landmark classes.")
@click.option("--width", type=int, default=1232, show_default=True, help="Panorama width (pixels, 360 degrees).")
@click.option("--height", type=int, default=224, show_default=True, help="Panorama height (pixels).")
@click.option("--camera-height", type=float, default=2.0, show_default=True, help="Metres above the ground.")
@click.option("--max-range", type=float, default=100.0, show_default=True, help="How far the camera sees (m).")
@click.option("--class-height", multiple=True, metavar="CLASS=METRES", show_default="building=10, tree=6, others 0",
              help="Height of a class that occludes (repeatable).")
@click.option("--confusion", type=float, default=0.0, show_default=True,
              help="Noise: fraction of panorama landmarks relabelled as another landmark class.")
@click.option("--miss-small", type=int, default=0, show_default=True,
              help="Noise: panorama landmarks under this many pixels are missed.")
@click.option("--miss-prob", type=float, default=0.0, show_default=True,
              help="Noise: every other panorama landmark is missed with this probability.")
@click.option("--offset", type=float, default=0.0, show_default=True,
              help="Noise: render from this many metres away from the true viewpoint.")
@click.option("--query-landmarks", type=click.Choice(["mask", "visible"]), default="mask", show_default=True,
              help="Panorama landmarks from its rendered mask, or the aerial landmarks the camera sees "
              "(perfect correspondence, as a person annotating both views: measures the matching alone).")
@click.option("--visible-min-px", type=click.IntRange(min=1), default=20, show_default=True,
              help="With --query-landmarks visible: panorama pixels an aerial landmark needs to count as seen.")
@click.option("--save-panoramas", type=int, default=0, show_default=True,
              help="Write the first K rendered panoramas as PNG under OUT/panoramas/.")
@click.option("--pictures", type=click.IntRange(min=0), default=0, show_default=True,
              help="Draw the first K localizations under OUT/views/: the mask with candidates, top-k and truth, "
              "and the panorama with its landmark graph.")
@click.option("--plots/--no-plots", default=True, show_default=True, help="Draw errors.png and classes.png.")
@click.option("--aerial-size", help="Annotated pairs: WIDTHxHEIGHT of the aerial images when no image lies beside "
              "the landmark files, e.g. 750x750.")
@click.option("--ground-size", help="Annotated pairs: WIDTHxHEIGHT of the panoramas, e.g. 1232x224.")
@click.option("--conventions", type=click.Choice(["osmseg", "authors"]), default="osmseg", show_default=True,
              help="Annotated pairs, paper method: osmseg's conventions or the authors' MATLAB demo's "
                   "(see osmseg localize --help); the truth then defaults to (W/2, H/2) as their [375 375].")
@click.option("--method", "methods_text", default="profile,paper", show_default=True,
              help="Methods to compare, comma-separated, side by side in one run: profile, paper. The first fills "
                   "the summary; the class-subset figure is the paper method's when it comes first.")
@click.option("--heading", type=click.Choice(["known", "unknown"]), default="known", show_default=True,
              help="known: north-aligned panoramas; unknown: each view turned to a seeded random heading the "
                   "methods are not told (the profile method searches it and its error is reported).")
@click.option("--fov", "fov_deg", type=click.FloatRange(10, 360), default=360.0, show_default=True,
              help="Horizontal field of view of each view: 360 for panoramas, 60-120 for photos.")
@click.option("--height-spread", type=click.FloatRange(0, 1, max_open=True), default=0.0, show_default=True,
              help="Each building and tree gets its class height times U(1-s, 1+s), seeded: heights the methods "
                   "do not know.")
@click.option("--negatives/--no-negatives", default=True, show_default=True,
              help="Also localize each view in another scene: how well each method's confidence separates "
                   "matching from non-matching pairs (ROC AUC).")
@click.option("--renderer", type=click.Choice(["mask", "geometry"]), default="mask", show_default=True,
              help="mask: panoramas ray-cast over the aerial mask, one height per class (the model the profile "
                   "method scores with) | geometry: ray-cast over the OSM geometry of --osm in 3-D, heights from "
                   "the tags, see-through tree crowns (shares no code with the methods).")
@click.option("--osm", "osm", multiple=True, type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="With --renderer geometry: the OSM file(s) (.osm, .osm.pbf) the masks were built from.")
@renamed_option("-n", "viewpoints", type=click.IntRange(min=1), note=" here (-n is build's --samples)")
@click.pass_context
@report_errors
def localize_bench_command(ctx: click.Context, source: Path, out_dir: Path, viewpoints: int, seed: int, table: str,
                           resolution: float | None, landmark_dict: str | None, mode: str, min_size: int, stride: int,
                           window: int | None, p: float, top_k: int, margin: float, stand_on: tuple[str, ...],
                           subsets: bool, width: int, height: int, camera_height: float, max_range: float,
                           class_height: tuple[str, ...], confusion: float, miss_small: int, miss_prob: float,
                           offset: float, query_landmarks: str, visible_min_px: int, save_panoramas: int,
                           pictures: int, plots: bool, aerial_size: str | None,
                           ground_size: str | None, methods_text: str, heading: str, fov_deg: float,
                           height_spread: float, negatives: bool, conventions: str, renderer: str,
                           osm: tuple[Path, ...]) -> None:
    """Render panoramas at seeded viewpoints of SOURCE and localize them in it.

    SOURCE is a dataset folder made by `osmseg build` (its labels/ and manifest.json), or one
    label mask file (PNG/GeoTIFF of class ids) with --table and --resolution. Or SOURCE is a
    folder of annotated pairs, the paper's own evaluation: aerial/NAME.txt and ground/NAME.txt
    landmark files (x y Class), images beside them or --aerial-size/--ground-size, the truth
    in truth.csv (name,x,y) or the aerial centre; then nothing is rendered, the landmark
    dictionary defaults to camvid (Building, Pavement, Road, Tree) and errors are in pixels
    unless --resolution gives the aerial m/px. Prints the path of results.json on stdout and a
    summary on stderr.
    """
    from localization.bench.pairs import PairsConfig, is_pairs_folder, load_pairs, run_pairs
    from localization.bench.render import NoiseConfig, RenderConfig
    from localization.bench.rendered import BenchConfig, load_dataset_scenes, load_mask_scene, run_bench

    verbosity = ctx.obj["verbosity"] if ctx.obj else 0
    bars = bool(ctx.obj.get("progress", False)) if ctx.obj else False
    methods = tuple(m.strip() for m in methods_text.split(",") if m.strip())
    if "paper" not in methods and (stray := _given(ctx, ("window", "p", "conventions", "subsets"))):
        raise _misplaced(stray, "the paper method", "paper to --method")
    pairs = source.is_dir() and is_pairs_folder(source)
    misplaced = _given(ctx, RENDER_ONLY if pairs else PAIRS_ONLY)
    if misplaced:
        what = "rendered panoramas (a dataset or a mask file)" if pairs else "annotated pairs (aerial/ + ground/)"
        raise ConfigError(f"{', '.join(misplaced)} apply only to {what}; {source} is "
                          f"{'a folder of annotated pairs' if pairs else 'not one'}: leave them out")
    if pairs:
        pairs_config = PairsConfig(landmarks=landmark_dict or "camvid", window=window, p=p, top_k=top_k,
                                   subsets=subsets, resolution_m=resolution, aerial_size=parse_size(aerial_size, "--aerial-size"),
                                   ground_size=parse_size(ground_size, "--ground-size"), methods=methods,
                                   heading=heading, camera_height_m=camera_height, conventions=conventions)
        with progress_bars(bars) as progress:
            results = run_pairs(load_pairs(source, pairs_config), pairs_config, out_dir, progress=progress,
                                plots=plots, source=str(source))
        if verbosity >= 0:
            click.echo(format_summary(results), err=True)
        click.echo(str(out_dir / "results.json"))
        return

    config = BenchConfig(
        viewpoints=viewpoints, seed=seed, landmarks=landmark_dict, mode=mode, min_size=min_size, stride=stride,
        window=window, p=p, top_k=top_k, margin_m=margin, stand_on=tuple(stand_on) or None, subsets=subsets,
        render=RenderConfig(width=width, height=height, camera_height_m=camera_height, max_range_m=max_range,
                            heights=parse_heights(class_height), height_spread=height_spread, height_seed=seed),
        noise=NoiseConfig(confusion=confusion, miss_small_px=miss_small, miss_prob=miss_prob, offset_m=offset),
        save_panoramas=save_panoramas, pictures=pictures, query_landmarks=query_landmarks, visible_min_px=visible_min_px,
        methods=methods, heading=heading, fov_deg=fov_deg, negatives=negatives, renderer=renderer,
        osm=tuple(str(o) for o in osm),
    )
    if query_landmarks != "visible" and _given(ctx, ("visible_min_px",)):
        raise ConfigError("--visible-min-px applies with --query-landmarks visible only: add it or leave it out")
    if source.is_dir():
        if resolution is not None or _given(ctx, ("table",)):
            raise ConfigError("--resolution and --table are for a mask file; a dataset folder records its own")
        scenes = load_dataset_scenes(source)
    else:
        if resolution is None:
            raise ConfigError(f"{source} is a mask file: give its ground resolution with --resolution (m/px)")
        scenes = [load_mask_scene(source, table, resolution)]
    with progress_bars(bars) as progress:
        results = run_bench(scenes, config, out_dir, progress=progress, plots=plots, source=str(source))
    if verbosity >= 0:
        click.echo(format_summary(results), err=True)
    click.echo(str(out_dir / "results.json"))
