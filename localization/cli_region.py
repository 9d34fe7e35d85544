"""``osmseg localize --ground QUERY --osm FILE --bbox W,S,E,N``: the command line of a region search.

Parses what :func:`localization.cli.localize_command` hands over in region mode, builds a
:class:`~localization.region.RegionRequest` and :class:`~localization.region.RegionConfig`,
calls :func:`~localization.region.localize_region` and prints the answers (a table, or the
GeoJSON with ``--json``). Imports: osmseg core and localization (never localization.cli).
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from localization.inputs import SideOptions
from localization.region import RegionConfig, RegionRequest, RegionResult, distance_m, localize_region
from localization.search import ProfileConfig
from osmseg.cli.common import parse_size, progress_bars
from osmseg.errors import ConfigError
from osmseg.units import degrees, metres, ratio

__all__ = ["parse_bbox", "parse_lonlat", "run_region", "answers_table"]


def parse_bbox(text: str | None) -> tuple[float, float, float, float]:
    """``--bbox W,S,E,N`` in degrees.

    >>> parse_bbox("26.94,60.53,26.95,60.535")
    (26.94, 60.53, 26.95, 60.535)
    """
    if text is None:
        raise ConfigError("a region search needs the region: add --bbox WEST,SOUTH,EAST,NORTH in degrees")
    try:
        w, s, e, n = (float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"--bbox must be four numbers WEST,SOUTH,EAST,NORTH in degrees, got {text!r}") from None
    return w, s, e, n


def parse_lonlat(text: str | None) -> tuple[float, float] | None:
    """``--truth LON,LAT`` of a region search, or None."""
    if text is None:
        return None
    try:
        lon, lat = (float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"with --osm, --truth is LON,LAT in degrees, got {text!r}") from None
    return lon, lat


def answers_table(result: RegionResult) -> str:
    """The answers, best first, as a fixed-width table."""
    lines = [f"{'rank':>4}  {'lon':>12}  {'lat':>12}  {'score':>7}  {'confidence':>10}"]
    for rank, a in enumerate(result.answers, start=1):
        lines.append(f"{rank:>4}  {a.lon:>12.7f}  {a.lat:>12.7f}  {ratio(a.score):>7}  {ratio(a.confidence):>10}")
    return "\n".join(lines)


def run_region(ctx: click.Context, ground: Path | None, osm: tuple[Path, ...], bbox_text: str | None, zoom: int,
               method: str, ground_classes: str, ground_table: str | None, ground_size: str | None,
               ground_checkpoint: Path | None, aerial_classes: str, aerial_table: str, mode: str, min_size: int,
               grid_stride: int, heading_deg: float | None, fov_deg: float, camera_height: float, top_k: int,
               truth_text: str | None, out_dir: Path | None, as_json: bool, verbosity: int,
               stray: list[str]) -> None:
    """Region mode of ``osmseg localize`` (``stray``: options that belong to an aerial image)."""
    if not osm:
        raise ConfigError("give the aerial image (--aerial FILE), or a region to search: --osm FILE --bbox W,S,E,N")
    if stray:
        verb = "applies" if len(stray) == 1 else "apply"
        raise ConfigError(f"{', '.join(stray)} {verb} to an aerial image; a region search (--osm) has none: "
                          "leave out one or the other")
    if method != "profile":
        raise ConfigError("a region search uses the profile method: drop --method paper")
    if ground is None:
        raise ConfigError("give the ground view to localize: --ground FILE")
    config = RegionConfig(bbox=parse_bbox(bbox_text), zoom=zoom, top_k=top_k)
    request = RegionRequest(
        ground=ground, osm=tuple(osm), table=aerial_table, aerial_classes=aerial_classes, fov_deg=fov_deg,
        camera_height_m=camera_height, truth=parse_lonlat(truth_text),
        ground_options=SideOptions("ground", ground_classes, ground_table, parse_size(ground_size, "--ground-size"),
                                   ground_checkpoint, fov_deg >= 360, mode=mode, min_size=min_size,
                                   grid_stride=grid_stride))
    bars = bool((ctx.obj or {}).get("progress", False))
    with progress_bars(bars) as progress:
        result = localize_region(request, config, ProfileConfig(heading_deg=heading_deg), out_dir, progress)
    if as_json:
        click.echo(json.dumps(result.to_geojson(), indent=2))
    elif not result.answers:
        click.echo("unanswered: no block of the region holds a place that fits the query")
    else:
        click.echo(answers_table(result))
    if verbosity >= 0 and not as_json and result.best is not None:
        alt = result.alternative
        if alt is not None:
            click.echo(f"best distinct alternative ({config.distinct_m:g} m or more away): {alt.lon:.7f}, "
                       f"{alt.lat:.7f}, {metres(distance_m(result.best, alt))} from the answer; score margin "
                       f"{ratio(result.margin)}", err=True)
        if result.best.heading_deg is not None and heading_deg is None:
            click.echo(f"heading of the answer: {degrees(result.best.heading_deg)}", err=True)
        if request.truth is not None:
            click.echo(f"error of the answer: {metres(distance_m(result.best, request.truth))}", err=True)
        click.echo(f"{result.blocks} blocks of {config.size}x{config.size} tiles at zoom {zoom} searched", err=True)
        if out_dir is not None:
            written = [f for f in ("region.geojson", "region.png") if (out_dir / f).is_file()]
            click.echo(f"written: {', '.join(written)} in {out_dir}/", err=True)
