"""``osmseg localize-bench``: localize rendered panoramas in their aerial mask and report the errors."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from osmseg.cli.common import parse_size, report_errors
from osmseg.errors import ConfigError


def _heights(values: tuple[str, ...]) -> dict[str, float]:
    """``("building=12", "tree=5")`` -> the default heights updated with these."""
    from localization.render import DEFAULT_HEIGHTS

    heights = dict(DEFAULT_HEIGHTS)
    for item in values:
        name, eq, metres = item.partition("=")
        try:
            heights[name.strip()] = float(metres)
        except ValueError:
            raise ConfigError(f"--class-height {item!r}: write CLASS=METRES, e.g. building=12") from None
        if not eq or not name.strip():
            raise ConfigError(f"--class-height {item!r}: write CLASS=METRES, e.g. building=12")
    return heights


#: Options that only make sense for one kind of SOURCE (a mistake to give for the other).
RENDER_ONLY = ("viewpoints", "seed", "table", "mode", "min_size", "stride", "margin", "stand_on", "width", "height",
               "camera_height", "max_range", "class_height", "confusion", "miss_small", "miss_prob", "offset",
               "query_landmarks", "visible_min_px", "save_panoramas", "pictures")
PAIRS_ONLY = ("aerial_size", "ground_size")


def _given(ctx: click.Context, names: tuple[str, ...]) -> list[str]:
    """The options among ``names`` that were typed on the command line, as ``--option-names``."""
    from click.core import ParameterSource

    by_name = {p.name: p for p in ctx.command.params}
    return [max(by_name[n].opts, key=len) for n in names if ctx.get_parameter_source(n) == ParameterSource.COMMANDLINE]


@click.command("localize-bench")
@click.argument("source", type=click.Path(exists=True, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Folder for results.json, errors.png and classes.png.")
@click.option("-n", "--viewpoints", type=int, default=20, show_default=True, help="Rendered panoramas to localize.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seeds viewpoints and noise.")
@click.option("--table", default="classes13.toml", show_default=True,
              help="Class table of a mask file (a dataset folder brings its own).")
@click.option("--resolution", type=float, help="Ground resolution of a mask file in m/px (a dataset brings its own).")
@click.option("--landmarks", "landmark_dict", help="Landmark class dictionary (data_manifests/landmarks-*.toml); "
              "default: the one for the class table.")
@click.option("--mode", type=click.Choice(["centroid", "grid", "component"]), default="centroid", show_default=True,
              help="Landmarks as component centroids, grid points or whole components.")
@click.option("--min-size", type=int, default=50, show_default=True, help="Smallest landmark component (pixels).")
@click.option("--grid-stride", "stride", type=click.IntRange(min=1), default=50, show_default=True,
              help="Grid step for --mode grid (pixels), as osmseg localize's --grid-stride.")
@click.option("--window", type=int, help="Aerial covisibility window (pixels); default mu + 5 sigma of "
              "nearest-neighbour distances.")
@click.option("--p", "p", type=float, default=0.5, show_default=True, help="Covisibility parameter of candidates.")
@click.option("--top-k", type=int, default=5, show_default=True)
@click.option("--margin", type=float, default=20.0, show_default=True,
              help="Viewpoints stay this many metres from the mask border.")
@click.option("--stand-on", multiple=True, help="Classes viewpoints may stand on (repeatable); default every "
              "flat class but unlabeled and water.")
@click.option("--subsets/--no-subsets", default=True, show_default=True,
              help="Also localize with every subset of 2, 3... landmark classes.")
@click.option("--width", type=int, default=1232, show_default=True, help="Panorama width (pixels, 360 degrees).")
@click.option("--height", type=int, default=224, show_default=True, help="Panorama height (pixels).")
@click.option("--camera-height", type=float, default=2.0, show_default=True, help="Metres above the ground.")
@click.option("--max-range", type=float, default=100.0, show_default=True, help="How far the camera sees (m).")
@click.option("--class-height", multiple=True, metavar="CLASS=METRES",
              help="Height of a class that occludes (repeatable); default building=10, tree=6, others 0.")
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
@click.pass_context
@report_errors
def localize_bench_command(ctx: click.Context, source: Path, out_dir: Path, viewpoints: int, seed: int, table: str,
                           resolution: float | None, landmark_dict: str | None, mode: str, min_size: int, stride: int,
                           window: int | None, p: float, top_k: int, margin: float, stand_on: tuple[str, ...],
                           subsets: bool, width: int, height: int, camera_height: float, max_range: float,
                           class_height: tuple[str, ...], confusion: float, miss_small: int, miss_prob: float,
                           offset: float, query_landmarks: str, visible_min_px: int, save_panoramas: int,
                           pictures: int, plots: bool, aerial_size: str | None,
                           ground_size: str | None) -> None:
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
    from localization.bench import BenchConfig, load_dataset_scenes, load_mask_scene, run_bench
    from localization.pairs import PairsConfig, is_pairs_folder, load_pairs, run_pairs
    from localization.render import NoiseConfig, RenderConfig

    verbosity = ctx.obj["verbosity"] if ctx.obj else 0
    progress = bool(ctx.obj.get("progress", False)) if ctx.obj else False
    pairs = source.is_dir() and is_pairs_folder(source)
    misplaced = _given(ctx, RENDER_ONLY if pairs else PAIRS_ONLY)
    if misplaced:
        what = "rendered panoramas (a dataset or a mask file)" if pairs else "annotated pairs (aerial/ + ground/)"
        raise ConfigError(f"{', '.join(misplaced)} apply only to {what}; {source} is "
                          f"{'a folder of annotated pairs' if pairs else 'not one'}: leave them out")
    if pairs:
        pairs_config = PairsConfig(landmarks=landmark_dict or "camvid", window=window, p=p, top_k=top_k,
                                   subsets=subsets, resolution_m=resolution, aerial_size=parse_size(aerial_size, "--aerial-size"),
                                   ground_size=parse_size(ground_size, "--ground-size"))
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
                            heights=_heights(class_height)),
        noise=NoiseConfig(confusion=confusion, miss_small_px=miss_small, miss_prob=miss_prob, offset_m=offset),
        save_panoramas=save_panoramas, pictures=pictures, query_landmarks=query_landmarks, visible_min_px=visible_min_px,
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
    results = run_bench(scenes, config, out_dir, progress=progress, plots=plots, source=str(source))
    if verbosity >= 0:
        click.echo(format_summary(results), err=True)
    click.echo(str(out_dir / "results.json"))


def format_summary(results: dict[str, Any]) -> str:
    """A few lines for the terminal: the full-class summary and the classes trend."""
    s, b, u = results["summary"], results["baselines"], results.get("unit", "m")
    in_px = "" if u == "px" else f" (mean {s['mean_error_px']} px)"
    rec = ", ".join(f"@{r} {u} {v}" for r, v in s["recall_at"].items())
    second = list(s["recall_at"])[1]
    lines = [
        f"{s['n']} {results.get('queries', 'queries')}, classes {'+'.join(results['classes'])}: {s['answered']} "
        f"answered, {s['unanswered']} unanswered, {s['tied']} tied",
        f"error: mean {s['mean_error']} {u} / median {s['median_error']} {u}"
        f"{in_px}; top-5 mean distance {s['top5_mean_distance']} {u}",
        f"recall {rec}; a random candidate: median {b['random_candidate_median']} {u}; "
        f"blind guesses: image centre {b['centre_guess_mean']} {u}, random {b['random_guess_mean']} {u}",
    ]
    for k, entry in sorted(results["by_num_classes"].items(), key=lambda kv: int(kv[0])):
        e = entry["summary"]
        lines.append(f"  {k} classes ({len(entry['subsets'])} subsets): median {e['median_error']} {u}, "
                     f"recall@{second} {u} {e['recall_at'][second]}, unanswered {e['unanswered']}/{e['n']}")
    return "\n".join(lines)
