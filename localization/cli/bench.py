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

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import click

from localization.cli.options import given, misplaced, parse_heights
from localization.cli.summary import format_summary
from osmseg.cli.common import output_options, parse_size, renamed_option, report_errors
from osmseg.cli.drawers import Mode, progress_drawer
from osmseg.errors import ConfigError

if TYPE_CHECKING:
    from localization.bench.scores import BenchResults

__all__ = ["bench_options", "localize_bench_command", "localize_pairs_command"]

F = TypeVar("F", bound=Callable[..., object])


def bench_options(func: F) -> F:
    """The options of both protocols: where the results go, the landmark classes, the paper
    method's graph settings, the camera height, the methods compared and the heading."""
    options = [
        click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True,
                     help="Folder for results.json, errors.png and classes.png."),
        click.option("--resolution", type=click.FloatRange(min=0, min_open=True),
                     help="Ground resolution of the aerial side in m/px (a dataset records its own; pairs without "
                          "it are scored in pixels)."),
        click.option("--landmarks", "landmark_dict",
                     show_default="the one for the class table; camvid for annotated pairs",
                     help="Landmark class dictionary (data_manifests/landmarks-*.toml)."),
        click.option("--window", type=click.IntRange(min=1), show_default="mu + 5 sigma of nearest-neighbour distances",
                     help="Aerial covisibility window (pixels)."),
        click.option("--p", "p", type=click.FloatRange(0, 1, min_open=True), default=0.5, show_default=True,
                     help="Covisibility parameter of candidates."),
        click.option("--top-k", type=click.IntRange(min=1), default=5, show_default=True),
        click.option("--subsets/--no-subsets", default=True, show_default=True,
                     help="Also localize with every subset of 2, 3... landmark classes."),
        click.option("--camera-height", type=click.FloatRange(min=0, min_open=True), default=2.0, show_default=True, help="Metres above the ground."),
        click.option("--method", "methods_text", default="profile,paper", show_default=True,
                     help="Methods to compare, comma-separated, side by side in one run: profile, paper. The first "
                          "fills the summary; the class-subset figure is the paper method's when it comes first."),
        click.option("--heading", type=click.Choice(["known", "unknown"]), default="known", show_default=True,
                     help="known: north-aligned panoramas; unknown: each view turned to a seeded random heading the "
                          "methods are not told (the profile method searches it and its error is reported)."),
        click.option("--plots/--no-plots", default=True, show_default=True, help="Draw errors.png and classes.png."),
    ]
    for option in reversed(options):
        func = option(func)
    return func


def _methods(ctx: click.Context, methods_text: str) -> tuple[str, ...]:
    """The methods of --method; the paper method's options refused when it does not run."""
    methods = tuple(m.strip() for m in methods_text.split(",") if m.strip())
    if "paper" not in methods and (stray := given(ctx, ("window", "p", "conventions", "subsets"))):
        raise misplaced(stray, "the paper method", "paper to --method")
    return methods


def _report(ctx: click.Context, results: BenchResults, out_dir: Path) -> None:
    """The summary on stderr (unless -q), results.json's path on stdout."""
    if (ctx.obj["verbosity"] if ctx.obj else 0) >= 0:
        click.echo(format_summary(results), err=True)
    click.echo(str(out_dir / "results.json"))


def _drawn(ctx: click.Context) -> Mode | None:
    """How the command shows its progress (:func:`osmseg.cli.drawers.progress_mode`)."""
    return ctx.obj.get("progress") if ctx.obj else None


@click.command("localize-bench")
@output_options
@click.argument("source", type=click.Path(exists=True, path_type=Path))
@bench_options
@click.option("--viewpoints", type=click.IntRange(min=1), default=20, show_default=True,
              help="Rendered panoramas to localize, placed round-robin over the masks (-n is build's --samples).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True, help="Seeds viewpoints and noise.")
@click.option("--table", default="classes13.toml", show_default=True,
              help="Class table of a mask file (a dataset folder brings its own).")
@click.option("--mode", type=click.Choice(["centroid", "grid", "component"]), default="centroid", show_default=True,
              help="Landmarks as component centroids, grid points or whole components.")
@click.option("--min-size", type=click.IntRange(min=0), default=50, show_default=True, help="Smallest landmark component (pixels).")
@click.option("--grid-stride", "stride", type=click.IntRange(min=1), default=50, show_default=True,
              help="Grid step for --mode grid (pixels), as osmseg localize's --grid-stride.")
@click.option("--margin", type=click.FloatRange(min=0), default=20.0, show_default=True,
              help="Viewpoints stay this many metres from the mask border.")
@click.option("--stand-on", multiple=True, show_default="every flat class but unlabeled and water",
              help="Classes viewpoints may stand on (repeatable).")
@click.option("--width", type=click.IntRange(min=8), default=1232, show_default=True, help="Panorama width (pixels, 360 degrees).")
@click.option("--height", type=click.IntRange(min=2), default=224, show_default=True, help="Panorama height (pixels).")
@click.option("--max-range", type=click.FloatRange(min=0, min_open=True), default=100.0, show_default=True, help="How far the camera sees (m).")
@click.option("--class-height", multiple=True, metavar="CLASS=METRES", show_default="building=10, tree=6, others 0",
              help="Height of a class that occludes (repeatable).")
@click.option("--confusion", type=click.FloatRange(0, 1), default=0.0, show_default=True,
              help="Noise: fraction of panorama landmarks relabelled as another landmark class.")
@click.option("--miss-small", type=click.IntRange(min=0), default=0, show_default=True,
              help="Noise: panorama landmarks under this many pixels are missed.")
@click.option("--miss-prob", type=click.FloatRange(0, 1), default=0.0, show_default=True,
              help="Noise: every other panorama landmark is missed with this probability.")
@click.option("--offset", type=click.FloatRange(min=0), default=0.0, show_default=True,
              help="Noise: render from this many metres away from the true viewpoint.")
@click.option("--query-landmarks", type=click.Choice(["mask", "visible"]), default="mask", show_default=True,
              help="Panorama landmarks from its rendered mask, or the aerial landmarks the camera sees "
              "(perfect correspondence, as a person annotating both views: measures the matching alone).")
@click.option("--visible-min-px", type=click.IntRange(min=1), default=20, show_default=True,
              help="With --query-landmarks visible: panorama pixels an aerial landmark needs to count as seen.")
@click.option("--save-panoramas", type=click.IntRange(min=0), default=0, show_default=True,
              help="Write the first K rendered panoramas as PNG under OUT/panoramas/.")
@click.option("--pictures", type=click.IntRange(min=0), default=0, show_default=True,
              help="Draw the first K localizations under OUT/views/: the mask with candidates, top-k and truth, "
              "and the panorama with its landmark graph.")
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
                           pictures: int, plots: bool, methods_text: str, heading: str, fov_deg: float,
                           height_spread: float, negatives: bool, renderer: str, osm: tuple[Path, ...]) -> None:
    """Render panoramas at seeded viewpoints of SOURCE and localize them in it.

    SOURCE is a dataset folder made by `osmseg build` (its labels/ and manifest.json), or one
    label mask file (PNG/GeoTIFF of class ids) with --table and --resolution. (A folder of
    annotated aerial/ground pairs is `osmseg localize-pairs`'s.) Prints the path of
    results.json on stdout and a summary on stderr.
    """
    from localization.bench.pairs import is_pairs_folder
    from localization.bench.render import NoiseConfig, RenderConfig
    from localization.bench.rendered import BenchConfig, load_dataset_scenes, load_mask_scene, run_bench

    methods = _methods(ctx, methods_text)
    if source.is_dir() and is_pairs_folder(source):
        raise ConfigError(f"{source} is a folder of annotated pairs (aerial/ + ground/): score them with "
                          f"osmseg localize-pairs {source} --out {out_dir}")
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
    if query_landmarks != "visible" and given(ctx, ("visible_min_px",)):
        raise ConfigError("--visible-min-px applies with --query-landmarks visible only: add it or leave it out")
    if source.is_dir():
        if resolution is not None or given(ctx, ("table",)):
            raise ConfigError("--resolution and --table are for a mask file; a dataset folder records its own")
        scenes = load_dataset_scenes(source)
    else:
        if resolution is None:
            raise ConfigError(f"{source} is a mask file: give its ground resolution with --resolution (m/px)")
        scenes = [load_mask_scene(source, table, resolution)]
    with progress_drawer(_drawn(ctx)) as progress:
        results = run_bench(scenes, config, out_dir, progress=progress, plots=plots, source=str(source))
    _report(ctx, results, out_dir)


@click.command("localize-pairs")
@output_options
@click.argument("folder", type=click.Path(exists=True, file_okay=False, path_type=Path))
@bench_options
@click.option("--aerial-size", help="WIDTHxHEIGHT of the aerial images when no image lies beside "
              "the landmark files, e.g. 750x750.")
@click.option("--ground-size", help="WIDTHxHEIGHT of the panoramas, e.g. 1232x224.")
@click.option("--conventions", type=click.Choice(["osmseg", "authors"]), default="osmseg", show_default=True,
              help="The paper method: osmseg's conventions or the authors' MATLAB demo's "
                   "(see osmseg localize --help); the truth then defaults to (W/2, H/2) as their [375 375].")
@click.pass_context
@report_errors
def localize_pairs_command(ctx: click.Context, folder: Path, out_dir: Path, resolution: float | None,
                           landmark_dict: str | None, window: int | None, p: float, top_k: int, subsets: bool,
                           camera_height: float, methods_text: str, heading: str, plots: bool,
                           aerial_size: str | None, ground_size: str | None, conventions: str) -> None:
    """Localize every annotated pair of FOLDER: the paper's own evaluation.

    FOLDER holds aerial/NAME.txt and ground/NAME.txt landmark files (x y Class), images beside
    them or --aerial-size/--ground-size, and the truth in truth.csv (name,x,y) or the aerial
    centre. Nothing is rendered; the landmark dictionary defaults to camvid (Building,
    Pavement, Road, Tree) and errors are in pixels unless --resolution gives the aerial m/px.
    Prints the path of results.json on stdout and a summary on stderr.
    """
    from localization.bench.pairs import PairsConfig, is_pairs_folder, load_pairs, run_pairs

    methods = _methods(ctx, methods_text)
    if not is_pairs_folder(folder):
        raise ConfigError(f"{folder} is not a folder of annotated pairs (aerial/NAME.txt + ground/NAME.txt); "
                          f"to render views of a dataset or mask, run osmseg localize-bench {folder} --out {out_dir}")
    config = PairsConfig(landmarks=landmark_dict or "camvid", window=window, p=p, top_k=top_k, subsets=subsets,
                         resolution_m=resolution, aerial_size=parse_size(aerial_size, "--aerial-size"),
                         ground_size=parse_size(ground_size, "--ground-size"), methods=methods, heading=heading,
                         camera_height_m=camera_height, conventions=conventions)
    with progress_drawer(_drawn(ctx)) as progress:
        results = run_pairs(load_pairs(folder, config), config, out_dir, progress=progress, plots=plots,
                            source=str(folder))
    _report(ctx, results, out_dir)
