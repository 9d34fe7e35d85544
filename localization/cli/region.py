"""``osmseg localize-region``: where in a region drawn from OpenStreetMap alone a ground view was taken.

The command builds one :class:`RegionQuery` from its options (the ground view, the region's OSM
files and box, how the view was taken) and calls its :meth:`~RegionQuery.run`, which builds a
:class:`~localization.region.files.RegionRequest` and :class:`~localization.region.search.RegionConfig`
and calls :func:`~localization.region.files.localize_region`; the command prints the answers (a
table, or the GeoJSON with ``--json``). An aerial image is ``osmseg localize``'s
(:mod:`localization.cli.localize`). Imports: osmseg core and localization (never another command's
module).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from localization.cli.options import (
    AERIAL_LANDMARKS,
    CAMERA_HEIGHT,
    FOV,
    GRID_STRIDE,
    GROUND_LANDMARKS,
    GROUND_SIZE,
    HEADING,
    LANDMARK_MODE,
    MIN_SIZE,
    TOP_K,
    osm_files,
    parse_pair,
    typed_flags,
)
from localization.cli.query import (
    AERIAL_TABLE,
    GROUND,
    GROUND_CHECKPOINT,
    GROUND_MODEL,
    GROUND_MODEL_CLASSES,
    GROUND_TABLE,
    HEADING_WITHIN,
    JSON,
    PHOTO,
    TILT,
    TRUTH,
    VISTA,
    GroundQuery,
    LandmarkOptions,
    ViewOptions,
    apply_photo,
    say_photo,
)
from localization.common.photo import PhotoFacts
from osmseg import places
from osmseg.cli.common import default_cache_dir, output_options, report_errors
from osmseg.cli.drawers import progress_drawer
from osmseg.cli.options import BBOX, CACHE_DIR, LAT, LON, OSM, OUT, RADIUS_KM, SHARD, ZOOM, moved, moved_each
from osmseg.cli.requests import make_request
from osmseg.errors import ConfigError
from osmseg.places import check_centre
from osmseg.runtime.shard import Shard
from osmseg.texttable import text_table
from osmseg.units import degrees, metres, plural, ratio

if TYPE_CHECKING:
    from localization.region.files import RegionRequest, RegionRun
    from localization.region.search import RegionConfig, RegionResult
    from osmseg.runtime.progress import Progress


__all__ = ["RegionArea", "RegionQuery", "localize_region_command", "parse_bbox", "parse_lonlat", "disc_bbox",
           "answers_table"]


@dataclass(frozen=True)
class RegionArea:
    """The region searched: its OSM files, its box (or disc), the zoom it is drawn at, the shard and the cache."""

    osm: tuple[str, ...]
    bbox_text: str | None
    lat: float | None
    lon: float | None
    radius_km: float | None
    zoom: int
    shard_text: str | None
    cache_dir: Path | None

    def bbox(self) -> tuple[float, float, float, float]:
        """The region in degrees: --bbox, or the square around --lat/--lon's disc of --radius-km."""
        disc = self.lat is not None or self.lon is not None or self.radius_km is not None
        if self.bbox_text is not None and disc:
            raise ConfigError("give the region once: --bbox W,S,E,N, or --lat/--lon with --radius-km")
        if not disc:
            return parse_bbox(self.bbox_text)
        if self.lat is None or self.lon is None or self.radius_km is None:
            missing = " and ".join(f for f, v in (("--lat", self.lat), ("--lon", self.lon),
                                                  ("--radius-km", self.radius_km)) if v is None)
            raise ConfigError(f"--lat, --lon and --radius-km go together (the centre of the region and its radius): "
                              f"add {missing}")
        return disc_bbox(self.lon, self.lat, self.radius_km)


#: what ``osmseg localize-region`` says to an option of an aerial image (click would suggest --aerial-table)
_AERIAL = ("{flag} is for an aerial image: osmseg localize-region draws the aerial side from --osm; to search an "
           "aerial image, run osmseg localize --aerial FILE --ground FILE")


#: The aerial image's options, refused by ``osmseg localize-region`` in one line naming localize.
aerial_moved = moved_each(("--aerial", "--aerial-resolution", "--aerial-size", "--aerial-checkpoint", "--aerial-image"), _AERIAL)


@click.command("localize-region")
@output_options
@GROUND()
@PHOTO()
@OSM(required=True, detail=": the files (.osm, .osm.pbf) the region is drawn from, in --aerial-table's classes.")
@BBOX(dest="bbox_text", detail=": the region to search (or --lat/--lon/--radius-km).")
@LAT(detail=": the centre of the region (with --lon, --radius-km).")
@LON(detail=": the centre of the region (with --lat, --radius-km).")
@RADIUS_KM(detail=": search the square around this disc.")
@ZOOM(default=18, show_default=True, detail=": the zoom the region is drawn at, 14 to 21.")
@SHARD(dest="shard_text", detail=": the region's blocks (docs/scale.md); every shard writes its part to --out, the "
                                  "last one writes the answers.")
@CACHE_DIR(show_default="$OSMSEG_CACHE_DIR or ~/.cache/osmseg",
           detail=": the drawn region, so the next query of it is not drawn again.")
@AERIAL_LANDMARKS(default="aerial13", show_default=True)
@AERIAL_TABLE(default="classes13.toml", show_default=True, detail=": the classes the region is drawn in.")
@GROUND_LANDMARKS(default="camvid", show_default=True)
@GROUND_TABLE(show_default="the dictionary's own")
@GROUND_SIZE()
@GROUND_CHECKPOINT()
@GROUND_MODEL()
@GROUND_MODEL_CLASSES()
@LANDMARK_MODE(dest="mode", default="centroid", show_default=True)
@MIN_SIZE(default=50, show_default=True)
@GRID_STRIDE(default=50, show_default=True)
@TOP_K(default=5, show_default=True)
@TRUTH(detail=", as LON,LAT in degrees.")
@JSON()
@OUT(detail=" of region.geojson, region.png and region.html (a map to pan, opens offline).")
@HEADING(default="0", show_default=True)
@HEADING_WITHIN()
@FOV(default=360.0, show_default=True)
@CAMERA_HEIGHT(default="2", show_default=True)
@TILT(default=0.0, show_default="level")
@VISTA(default=0.0, show_default="0, none")
@aerial_moved
@moved("--method", "--method is osmseg localize's: a region search uses the profile method; leave --method out")
@click.pass_context
@report_errors
def localize_region_command(ctx: click.Context, /, **params: Any) -> None:
    """Find where the GROUND view was taken anywhere in a region drawn from OpenStreetMap alone
    (--osm FILE --bbox W,S,E,N), with angular profiles. An aerial image is osmseg localize's."""
    if not 14 <= params["zoom"] <= 21:
        raise click.UsageError(f"--zoom {params['zoom']}: a region is drawn at zoom 14 to 21", ctx)
    typed = typed_flags(ctx)
    facts = apply_photo(params, typed)
    if facts is not None:
        _photo_centre(params, facts, ctx)
        say_photo(facts, params, quiet=(ctx.obj or {}).get("verbosity", 0) < 0)
    request = make_request(RegionQuery, params, typed=typed)
    with progress_drawer((ctx.obj or {}).get("progress")) as progress:
        run = request.run(progress)
    _say(request, run, verbosity=(ctx.obj or {}).get("verbosity", 0))


def _photo_centre(params: dict[str, Any], facts: PhotoFacts, ctx: click.Context) -> None:
    """The region around the photo's GPS fix when no region is given: ``--radius-km`` around it."""
    if facts.lonlat is None or params.get("bbox_text") is not None or params.get("lat") is not None \
            or params.get("lon") is not None:
        return
    if params.get("radius_km") is None:
        raise click.UsageError(f"--photo carries a GPS fix ({facts.lonlat[0]:.6f},{facts.lonlat[1]:.6f}): give "
                               "--radius-km KM to search around it, or the region as --bbox W,S,E,N", ctx)
    params["lon"], params["lat"] = facts.lonlat


@dataclass(frozen=True)
class RegionQuery:
    """What ``osmseg localize-region`` was asked, typed and frozen (``typed``: the options given)."""

    ground: GroundQuery
    area: RegionArea
    aerial_classes: str
    aerial_table: str
    landmarks: LandmarkOptions
    view: ViewOptions
    top_k: int
    truth_text: str | None
    as_json: bool
    out_dir: Path | None
    typed: Mapping[str, str] = field(default_factory=dict)

    def config(self) -> RegionConfig:
        """The search's :class:`~localization.region.search.RegionConfig`."""
        from localization.region.search import RegionConfig

        return RegionConfig(bbox=self.area.bbox(), zoom=self.area.zoom, top_k=self.top_k)

    def request(self) -> RegionRequest:
        """The files' :class:`~localization.region.files.RegionRequest`."""
        from localization.region.files import RegionRequest

        view = self.view
        return RegionRequest(
            ground=self.ground.ground_path, osm=osm_files(self.area.osm), table=self.aerial_table,
            aerial_classes=self.aerial_classes, fov_deg=view.fov_deg, camera_height_m=view.camera_height,
            truth=parse_lonlat(self.truth_text),
            ground_options=self.ground.side(self.landmarks, panorama=view.fov_deg >= 360),
            shard=Shard.parse(self.area.shard_text) if self.area.shard_text else Shard(1, 1),
            cache_dir=self.area.cache_dir if self.area.cache_dir is not None else default_cache_dir())

    def run(self, progress: Progress | None = None) -> RegionRun:
        """Search the region; with ``out_dir``, write region.geojson, region.png and region.html (or this shard's part)."""
        from localization.region.files import localize_region

        config, request = self.config(), self.request()
        return localize_region(request, config, self.view.profile(), self.out_dir, progress)


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


def _say(query: RegionQuery, run: RegionRun, verbosity: int) -> None:
    """What ``osmseg localize-region`` prints: the answers on stdout (a table, or the GeoJSON), how
    they were found on stderr."""
    result = run.result
    if result is None:
        shard = Shard.parse(query.area.shard_text) if query.area.shard_text else Shard(1, 1)
        click.echo(f"shard {shard.index}/{shard.count} done; {run.parts} of {run.shards} parts in "
                   f"{run.parts_dir}: the last shard to finish writes the answers", err=True)
        return
    if query.as_json:
        click.echo(json.dumps(result.to_geojson(), indent=2))
    elif not result.answers:
        click.echo("unanswered: no block of the region holds a place that fits the query")
    else:
        click.echo(answers_table(result))
    if verbosity < 0 or query.as_json or result.best is None:
        return
    from localization.profile.profiles import MASK_MIN_CONFIDENCE
    from localization.region.search import NOT_HERE, NOT_SURE, NULL_MIN_LIFT, distance_m

    config = query.config()
    alt = result.alternative
    if alt is not None:
        click.echo(f"best distinct alternative ({config.distinct_m:g} m or more away): {alt.lon:.7f}, "
                   f"{alt.lat:.7f}, {metres(distance_m(result.best, alt))} from the answer; score margin "
                   f"{ratio(result.margin)}", err=True)
    if result.verdict == NOT_HERE:
        click.echo(f"not found here: the view fits this region no better than a scrambled copy of itself does (lift "
                   f"{ratio(result.lift)}, below {NULL_MIN_LIFT:g}): it was most likely taken somewhere else "
                   "(docs/localization.md)", err=True)
    elif result.verdict == NOT_SURE:
        click.echo(f"not sure: the answer's confidence {ratio(result.best.confidence or 0.0)} is below "
                   f"{MASK_MIN_CONFIDENCE:g}: the alternative fits almost as well (docs/localization.md)", err=True)
    else:
        why = [f"from the other places of the region (confidence {ratio(result.best.confidence)}, at least "
               f"{MASK_MIN_CONFIDENCE:g})" if result.best.confidence is not None else "",
               f"from scrambled copies of the view (lift {ratio(result.lift)}, at least {NULL_MIN_LIFT:g})"
               if result.lift is not None else ""]
        said = " and ".join(w for w in why if w)
        click.echo(f"here: the answer stands out {said}" if said else
                   "here: the only answer (neither its confidence nor its lift could be measured)", err=True)
    if result.best.heading_deg is not None and query.view.profile().heading_deg is None:
        click.echo(f"heading of the answer: {degrees(result.best.heading_deg)}", err=True)
    if (truth := parse_lonlat(query.truth_text)) is not None:
        click.echo(f"error of the answer: {metres(distance_m(result.best, truth))}", err=True)
    click.echo(f"{plural(result.blocks, 'block')} of {config.size}x{config.size} tiles at zoom {config.zoom} searched "
               f"({run.drawn} drawn from OSM, {run.cached} read from the cache)", err=True)
    if query.out_dir is not None:
        written = [f for f in ("region.geojson", "region.png", "region.html") if (query.out_dir / f).is_file()]
        click.echo(f"written: {', '.join(written)} in {query.out_dir}/", err=True)
