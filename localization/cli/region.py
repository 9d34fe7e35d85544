"""``osmseg localize --ground QUERY --osm FILE --bbox W,S,E,N``: the command line of a region search.

:func:`region_options` declares the region's options once (``--osm``, ``--bbox`` or
``--lat/--lon/--radius-km``, ``--zoom``, ``--shard``, ``--cache-dir``) and hands them to the
command as one :class:`RegionArgs`. :func:`run_region` takes what
:func:`localization.cli.commands.localize_command` hands over in region mode, builds a
:class:`~localization.region.files.RegionRequest` and :class:`~localization.region.search.RegionConfig`,
calls :func:`~localization.region.files.localize_region` and prints the answers (a table, or the
GeoJSON with ``--json``). Imports: osmseg core and localization (never localization.cli.commands).
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from localization.cli.options import osm_files, parse_pair
from localization.common.inputs import SideOptions
from osmseg import places
from osmseg.cli.common import default_cache_dir, parse_size
from osmseg.cli.drawers import progress_drawer
from osmseg.cli.options import BBOX, CACHE_DIR, LAT, LON, OSM, RADIUS_KM, SHARD, ZOOM
from osmseg.errors import ConfigError
from osmseg.places import check_centre
from osmseg.runtime.shard import Shard
from osmseg.texttable import text_table
from osmseg.units import degrees, metres, plural, ratio

if TYPE_CHECKING:
    from localization.profile.search import ProfileConfig
    from localization.region.search import RegionResult

__all__ = ["RegionArgs", "region_options", "parse_bbox", "parse_lonlat", "disc_bbox", "run_region", "answers_table"]


@dataclass(frozen=True)
class RegionArgs:
    """The region options of ``osmseg localize``, as given."""

    osm: tuple[Path, ...]
    bbox_text: str | None
    lat: float | None
    lon: float | None
    radius_km: float | None
    zoom: int
    shard_text: str | None
    cache_dir: Path | None

    @property
    def given(self) -> bool:
        """Whether any option says "search a region" (rather than an aerial image)."""
        return bool(self.osm) or any(v is not None for v in (self.bbox_text, self.lat, self.lon, self.radius_km,
                                                             self.shard_text))

    def bbox(self) -> tuple[float, float, float, float]:
        """The region in degrees: --bbox, or the square around --lat/--lon's disc of --radius-km."""
        disc = self.lat is not None or self.lon is not None or self.radius_km is not None
        if self.bbox_text is not None and disc:
            raise ConfigError("give the region once: --bbox W,S,E,N, or --lat/--lon with --radius-km")
        if not disc:
            return parse_bbox(self.bbox_text)
        if self.lat is None or self.lon is None or self.radius_km is None:
            raise ConfigError("--lat, --lon and --radius-km go together: the centre of the region and its radius")
        return disc_bbox(self.lon, self.lat, self.radius_km)


REGION_KEYS = ("osm", "bbox_text", "lat", "lon", "radius_km", "zoom", "shard_text", "cache_dir")


def region_options(command: Callable[..., Any]) -> Callable[..., Any]:
    """Add the region options to a click command; it receives them as ``region=RegionArgs(...)``."""
    @functools.wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        kwargs["osm"] = osm_files(kwargs["osm"])
        if not 14 <= kwargs["zoom"] <= 21:
            raise click.UsageError(f"--zoom {kwargs['zoom']}: a region is drawn at zoom 14 to 21")
        kwargs["region"] = RegionArgs(**{k: kwargs.pop(k) for k in REGION_KEYS})
        return command(*args, **kwargs)

    options = [
        OSM(detail=": with files (.osm, .osm.pbf), search a whole region of them instead of an aerial image, drawn "
                   "in --aerial-table's classes, with --bbox or --lat/--lon/--radius-km."),
        BBOX(dest="bbox_text", detail=": with --osm, the region to search."),
        LAT(detail=": with --osm, the centre of the region (with --lon, --radius-km)."),
        LON(detail=": with --osm, the centre of the region (with --lat, --radius-km)."),
        RADIUS_KM(detail=": with --osm, --lat, --lon, search the square around this disc."),
        ZOOM(default=18, show_default=True, detail=": with --osm, the zoom the region is drawn at, 14 to 21."),
        SHARD(dest="shard_text", detail=": with --osm, the region's blocks (docs/scale.md); every shard writes its "
                                        "part to --out, the last one writes the answers."),
        CACHE_DIR(show_default="$OSMSEG_CACHE_DIR or ~/.cache/osmseg",
                  detail=": with --osm, the drawn region, so the next query of it is not drawn again."),
    ]
    for option in reversed(options):
        wrapper = option(wrapper)
    return wrapper


def disc_bbox(lon: float, lat: float, radius_km: float) -> tuple[float, float, float, float]:
    """The square (W, S, E, N in degrees) around the disc of ``radius_km`` centred on ``lon, lat``.

    >>> [round(v, 4) for v in disc_bbox(26.95, 60.53, 1.0)]
    [26.9317, 60.521, 26.9683, 60.539]
    """
    check_centre(lat, lon)
    if not (math.isfinite(radius_km) and radius_km > 0):
        raise ConfigError(f"--radius-km {radius_km}: give a finite radius in kilometres, e.g. 1")
    dlat = radius_km / 111.31949
    dlon = dlat / max(math.cos(math.radians(lat)), 1e-6)
    return (max(-180.0, lon - dlon), max(-85.05, lat - dlat), min(180.0, lon + dlon), min(85.05, lat + dlat))


def parse_bbox(text: str | None) -> tuple[float, float, float, float]:
    """``--bbox W,S,E,N`` in degrees, as every command reads it (:func:`osmseg.places.parse_bbox`);
    a region search cannot go without one.

    >>> parse_bbox("26.94,60.53,26.95,60.535")
    (26.94, 60.53, 26.95, 60.535)
    """
    if text is None:
        raise ConfigError("a region search needs the region: add --bbox WEST,SOUTH,EAST,NORTH in degrees")
    w, s, e, n = places.parse_bbox(text)
    return w, s, e, n


def parse_lonlat(text: str | None) -> tuple[float, float] | None:
    """``--truth LON,LAT`` of a region search, or None."""
    if text is None:
        return None
    return parse_pair(text, f"with --osm, --truth is LON,LAT in degrees, got {text!r}",
                      f"with --osm, --truth is LON,LAT in finite degrees, got {text!r}")


def answers_table(result: RegionResult) -> str:
    """The answers, best first, as a fixed-width table."""
    return text_table(["rank", "lon", "lat", "score", "kappa", "confidence"],
                      [[str(rank), f"{a.lon:.7f}", f"{a.lat:.7f}", ratio(a.score), ratio(a.kappa), ratio(a.confidence)]
                       for rank, a in enumerate(result.answers, start=1)], left=0)


def run_region(ctx: click.Context, ground: Path | None, region: RegionArgs, method: str, ground_classes: str,
               ground_table: str | None, ground_size: str | None, ground_checkpoint: Path | None,
               aerial_classes: str, aerial_table: str, mode: str, min_size: int, grid_stride: int,
               profile: ProfileConfig, fov_deg: float, camera_height: float, top_k: int,
               truth_text: str | None, out_dir: Path | None, as_json: bool, verbosity: int,
               stray: list[str]) -> None:
    """Region mode of ``osmseg localize`` (``stray``: options that belong to an aerial image)."""
    from localization.region.files import RegionRequest, localize_region
    from localization.region.search import RegionConfig

    if not region.osm:
        raise ConfigError("give the aerial image (--aerial FILE), or a region to search: --osm FILE --bbox W,S,E,N")
    if stray:
        verb = "applies" if len(stray) == 1 else "apply"
        raise ConfigError(f"{', '.join(stray)} {verb} to an aerial image; a region search (--osm) has none: "
                          "leave out one or the other")
    if method != "profile":
        raise ConfigError("a region search uses the profile method: drop --method paper")
    if ground is None:
        raise ConfigError("give the ground view to localize: --ground FILE")
    config = RegionConfig(bbox=region.bbox(), zoom=region.zoom, top_k=top_k)
    request = RegionRequest(
        ground=ground, osm=tuple(region.osm), table=aerial_table, aerial_classes=aerial_classes, fov_deg=fov_deg,
        camera_height_m=camera_height, truth=parse_lonlat(truth_text),
        ground_options=SideOptions("ground", ground_classes, ground_table, parse_size(ground_size, "--ground-size"),
                                   ground_checkpoint, fov_deg >= 360, mode=mode, min_size=min_size,
                                   grid_stride=grid_stride),
        shard=Shard.parse(region.shard_text) if region.shard_text else Shard(1, 1),
        cache_dir=region.cache_dir if region.cache_dir is not None else default_cache_dir())
    with progress_drawer((ctx.obj or {}).get("progress")) as progress:
        run = localize_region(request, config, profile, out_dir, progress)
    result = run.result
    if result is None:
        click.echo(f"shard {request.shard.index}/{request.shard.count} done; {run.parts} of {run.shards} parts in "
                   f"{run.parts_dir}: the last shard to finish writes the answers", err=True)
        return
    if as_json:
        click.echo(json.dumps(result.to_geojson(), indent=2))
    elif not result.answers:
        click.echo("unanswered: no block of the region holds a place that fits the query")
    else:
        click.echo(answers_table(result))
    if verbosity >= 0 and not as_json and result.best is not None:
        from localization.region.search import distance_m

        alt = result.alternative
        if alt is not None:
            click.echo(f"best distinct alternative ({config.distinct_m:g} m or more away): {alt.lon:.7f}, "
                       f"{alt.lat:.7f}, {metres(distance_m(result.best, alt))} from the answer; score margin "
                       f"{ratio(result.margin)}", err=True)
        from localization.profile.profiles import MASK_MIN_CONFIDENCE

        if result.best.confidence is not None and result.best.confidence < MASK_MIN_CONFIDENCE:
            click.echo(f"not sure: the answer's confidence {ratio(result.best.confidence)} is below "
                       f"{MASK_MIN_CONFIDENCE:g}: the alternative fits almost as well (docs/localization.md)", err=True)
        if result.best.heading_deg is not None and profile.heading_deg is None:
            click.echo(f"heading of the answer: {degrees(result.best.heading_deg)}", err=True)
        if request.truth is not None:
            click.echo(f"error of the answer: {metres(distance_m(result.best, request.truth))}", err=True)
        click.echo(f"{plural(result.blocks, 'block')} of {config.size}x{config.size} tiles at zoom {config.zoom} searched "
                   f"({run.drawn} drawn from OSM, {run.cached} read from the cache)", err=True)
        if out_dir is not None:
            written = [f for f in ("region.geojson", "region.png") if (out_dir / f).is_file()]
            click.echo(f"written: {', '.join(written)} in {out_dir}/", err=True)
