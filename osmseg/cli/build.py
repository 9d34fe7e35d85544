"""``osmseg build``: make a segmentation dataset from OpenStreetMap and aerial imagery.

The options land in :class:`BuildOptions`, the one table of what each option is: the
:class:`~osmseg.builder.config.BuildConfig` is made from it (:func:`build_config`), the command
recorded in the manifest reads each content option back from the config through it
(:func:`content_options`, :func:`recorded_command`, flags spelled as click knows them), and
the options that never change what is built are its plain fields (:data:`NOT_CONTENT`), so
none of the three can drift from the others.
"""

from __future__ import annotations

import errno
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import click

from osmseg.builder.filters import FilterConfig
from osmseg.builder.run import DEFAULT_ZOOM, NO_IMAGERY_REASONS, SAMPLE_TILES, BuildConfig, BuildSummary, Shard, build
from osmseg.cli.common import command_line_of, default_cache_dir, output_options, report_errors
from osmseg.cli.drawers import Mode, progress_drawer
from osmseg.cli.options import BBOX, CACHE_DIR, CLASSES, LAT, LON, OSM, OUT, RADIUS_KM, SEED, SHARD, ZOOM, declare
from osmseg.errors import ConfigError, DatasetError
from osmseg.imagery import BING_KEY_ENV, KEYLESS_DEFAULT, missing_bing_key
from osmseg.output import command_line
from osmseg.places import Area, check_centre, find_preset, parse_bbox
from osmseg.redact import redact


def resolve_area(city: str | None, lat: float | None, lon: float | None, bbox: str | None, radius_km: float | None) -> Area:
    """The sampling area from exactly one of --city, --lat/--lon, --bbox."""
    given = sum(x is not None for x in (city, bbox)) + (lat is not None or lon is not None)
    if given != 1:
        raise ConfigError("give exactly one of --city NAME, --lat/--lon, or --bbox W,S,E,N")
    if radius_km is not None and not math.isfinite(radius_km):
        raise ConfigError(f"--radius-km {radius_km}: give a finite radius in kilometres, e.g. 5")
    if city is not None:
        p = find_preset(city)
        return Area(name=p.name, lat=p.lat, lon=p.lon, radius_km=radius_km or p.radius_km, kind=p.kind)
    if bbox is not None:
        b = parse_bbox(bbox)
        return Area(name="bbox", lat=(b.south + b.north) / 2, lon=(b.west + b.east) / 2, bbox=b)
    if lat is None or lon is None:
        raise ConfigError("--lat and --lon go together")
    check_centre(lat, lon)
    name = f"{abs(lat):.4f}{'N' if lat >= 0 else 'S'}_{abs(lon):.4f}{'E' if lon >= 0 else 'W'}"
    return Area(name=name, lat=lat, lon=lon, radius_km=radius_km or 2.0)


def run_build(config: BuildConfig, verbosity: int, progress: Mode | None,
              env: dict[str, str] | None = None) -> BuildSummary:
    """Run a build (its progress drawn as ``progress`` says: :func:`osmseg.cli.drawers.progress_mode`)
    and print the summary (stderr) and output path (stdout)."""
    try:
        with progress_drawer(progress) as bars:
            summary = build(config, env=env, progress=bars, command_line=command_line(recorded_command(config)))
    except OSError as exc:
        if exc.errno != errno.ENOSPC:
            raise
        where = exc.filename or f"{config.out_dir} or the cache {config.cache_dir}"
        raise DatasetError(f"the disk is full (writing {where}): free disk space, or give --out/--cache-dir on a "
                           "disk with room, then run the same command again (finished samples are kept)") from None
    if verbosity >= 0:
        for line in summary.lines():
            click.echo(line, err=True)
        if not summary.finalized and not summary.failed:
            click.echo("manifest not written yet: it is written when every shard has finished", err=True)
    if summary.failed:
        slot, reason = summary.failed[0]
        done = summary.accepted + summary.gave_up
        failed = len(summary.failed)
        raise DatasetError(f"{failed} of {done + failed} sample{'s' if done + failed != 1 else ''} could not be "
                           f"fetched (sample {slot}: {reason}); {done} done: run the same command again to retry "
                           f"{'it' if failed == 1 else 'them'}")
    click.echo(str(config.out_dir / "manifest.json") if summary.finalized else str(config.out_dir))
    if summary.finalized and summary.dataset_accepted == 0:
        raise no_sample_error(summary, config)
    return summary


def no_sample_error(summary: BuildSummary, config: BuildConfig) -> DatasetError:
    """The error of a finished build without any sample: the source that has nothing over the
    area when every attempt says so (every one rejected for missing imagery, or every OSM answer
    without an object of a class), else the filters to loosen."""
    attempts = sum(summary.rejected.values())
    zoom = f" at --zoom {config.zoom}"
    if attempts and sum(summary.rejected[r] for r in NO_IMAGERY_REASONS) == attempts:
        return DatasetError(f"no sample was accepted: all {attempts} attempts were rejected for missing imagery, so "
                            f"--imagery {redact(config.imagery)} has no imagery over the sampling area{zoom}: sample "
                            "where it has imagery (--bbox/--lat/--lon), or give another --zoom or --imagery")
    if attempts and summary.osm_empty == attempts:
        return DatasetError(f"no sample was accepted: --osm {redact(config.osm)} had no object of any class in any of "
                            f"the {attempts} attempts' areas, so it has no data there: sample where it has data "
                            "(--bbox/--lat/--lon), or give another --osm source")
    more = "widen the area (--no-overlap ran out of tile blocks)" if summary.exhausted else "raise --max-tries"
    return DatasetError("no sample was accepted (see the rejection reasons above and in manifest.json): "
                        f"loosen the filters, {more}, or sample another area")


CITY = declare("--city", help="A preset area (data_manifests/cities.toml), e.g. Berlin, 'São Paulo'; any case/accents.")
SAMPLES = declare("--samples", "-n", type=int, help="Accepted samples wanted.")
SAMPLE_TILES_OPTION = declare("--sample-tiles", type=click.Choice([str(n) for n in SAMPLE_TILES]),
                              help="Tiles per side of a sample (256 px each): 5 = 1280 px, the dissertation's; fewer "
                                   "for a small orthophoto or tile folder, so that several samples fit without "
                                   "overlapping.")
IMAGERY = declare("--imagery", help="A provider name (Esri.WorldImagery, GeoportailFrance.orthos, USGS.USImagery, ...; "
                                    "docs/imagery.md) | xyz:TEMPLATE | geotiff:PATH | bing (needs BING_MAPS_KEY).")
TILE_SIZE = declare("--tile-size", type=click.Choice(["256", "512", "1024"]),
                    help="Px of the tile server's tiles, when the provider does not say (a 512-px or @2x server); "
                         "every tile is checked against it.")
IMAGE_FORMAT = declare("--image-format", type=click.Choice(["png", "jpg", "cog"]),
                       help="cog: images/NAME.tif, a Cloud-Optimized GeoTIFF on the label GeoTIFF's grid (GIS, "
                            "torchgeo); png/jpg: the dissertation's layout.")
MAX_UNLABELED = declare("--max-unlabeled", type=click.FloatRange(0, 1),
                        help="Reject samples with at least this unlabeled share.")
MIN_CLASSES = declare("--min-classes", type=click.IntRange(min=0), help="Reject samples with fewer classes.")
MIN_CONTRAST = declare("--min-contrast", type=click.FloatRange(0, 255),
                       help="Reject images whose grey-level standard deviation (0-255) is below this.")
MAX_MISSING = declare("--max-missing-imagery", type=click.FloatRange(0, 1),
                      help="Reject samples with more than this share of pixels without imagery.")
MAX_PLACEHOLDERS = declare("--max-placeholder-tiles", type=click.IntRange(0, None),
                           help="Reject samples with more provider 'no imagery' tiles than this.")
MAX_TRIES = declare("--max-tries", type=click.IntRange(min=1), help="Centres tried per sample before giving up on it.")
NO_OVERLAP = declare("--no-overlap", is_flag=True,
                     help="Samples never share a pixel: each attempt takes its own block of the area's tile grid "
                          "(seeded).")
TIMEOUT = declare("--timeout", dest="http_timeout", type=click.FloatRange(min=0.1),
                  help="Seconds to wait for a server to connect or send more bytes before retrying.")
RETRIES = declare("--retries", dest="http_retries", type=click.IntRange(min=0),
                  help="Further attempts of a request that timed out, was cut off, or got 429/5xx or an unusable body.")
RETRY_DELAY = declare("--retry-delay", dest="http_retry_delay", type=click.FloatRange(min=0),
                      help="Seconds before the first retry, doubling with each (a server's Retry-After comes first).")
OFFLINE = declare("--offline", is_flag=True, help="Use only the cache; fail on anything not cached.")
BUILD_WORKERS = declare("--workers", type=click.IntRange(min=0),
                        help="Processes building samples at once; the dataset's bytes are the same for any number.")
ZIP = declare("--zip", dest="make_zip", is_flag=True, help="Also write OUT.zip.")
RECORD = declare("--record", type=click.Path(dir_okay=False, path_type=Path),
                 help="Record all HTTP traffic to a cassette (keys removed).")
REPLAY = declare("--replay", type=click.Path(dir_okay=False, exists=True, path_type=Path),
                 help="Serve all HTTP from a recorded cassette.")


@click.command("build")
@output_options
@CITY()
@LAT(detail=" for an area anywhere.")
@LON()
@RADIUS_KM(show_default="the preset's, or 2 km", detail=": the sampling disc.")
@BBOX(detail=": sample uniformly inside it instead of a disc.")
@SAMPLES(default=30, show_default=True)
@SEED(default=0, show_default=True)
@ZOOM(default=DEFAULT_ZOOM, show_default=True, detail=" (see docs).")
@SAMPLE_TILES_OPTION(default="5", show_default=True)
@IMAGERY(show_default="bing")
@TILE_SIZE(default=None, show_default="256; 512 for an @2x template")
@OSM(default=("api",), show_default="api")
@CLASSES(default="classes13.toml", show_default=True)
@IMAGE_FORMAT(default="png", show_default=True)
@MAX_UNLABELED(default=0.70, show_default=True)
@MIN_CLASSES(default=2, show_default=True)
@MIN_CONTRAST(default=FilterConfig.min_contrast, show_default=True)
@MAX_MISSING(default=0.0, show_default=True)
@MAX_PLACEHOLDERS(default=0, show_default=True)
@MAX_TRIES(default=10, show_default=True)
@NO_OVERLAP()
@OUT(required=True, detail=" (rerun to resume).")
@CACHE_DIR(default=None, show_default="$OSMSEG_CACHE_DIR, else $XDG_CACHE_HOME/osmseg, else ~/.cache/osmseg",
           detail=": the HTTP and OSM cache.")
@TIMEOUT(default=30.0, show_default=True)
@RETRIES(default=5, show_default=True)
@RETRY_DELAY(default=0.5, show_default=True)
@OFFLINE()
@BUILD_WORKERS(default=0, show_default="0: every core this process may use")
@SHARD(detail=" (samples).")
@ZIP()
@RECORD()
@REPLAY()
@click.pass_context
@report_errors
def build_command(ctx: click.Context, /, **params: Any) -> None:
    """Build a segmentation dataset: aerial images + OSM label masks + manifest.

    \b
    Examples:
      osmseg build --city Paris --imagery GeoportailFrance.orthos --samples 30 --out data/paris
      osmseg build --city Berlin --imagery Esri.WorldImagery --samples 30 --out data/berlin
      osmseg build --lat 0.35 --lon 32.59 --zoom 21 --imagery 'xyz:file:///data/tiles/{z}/{x}/{y}.png' \\
                   --osm buildings.osm.pbf --out data/kampala
    """
    options = BuildOptions.from_params(params)
    config = build_config(options)  # usage errors (area, shard, cassette) before anything else is said
    imagery = options.imagery
    env = dict(os.environ)
    if options.replay and not env.get(BING_KEY_ENV):
        env[BING_KEY_ENV] = "replayed-without-key"  # recorded requests are matched without their key
    if (imagery or "bing").strip().lower().split(":")[0] == "bing" and not env.get(BING_KEY_ENV):
        # Bing Maps Basic keys no longer exist: say so, and give a command that works as it is
        raise ConfigError(f"{missing_bing_key(imagery is not None)}; run instead: "
                          f"{command_line_of(ctx, imagery=KEYLESS_DEFAULT)}  (keyless; other providers: docs/imagery.md)")
    run_build(config, ctx.obj["verbosity"], ctx.obj.get("progress"), env=env)


def _content(read: Callable[[BuildConfig], object]) -> dict[str, Callable[[BuildConfig], object]]:
    """The metadata of a field of :class:`BuildOptions` that changes what is built: ``read`` gives
    its value back from a config, for the recorded command (None or False: the option is left out)."""
    return {"recorded": read}


def _area_is(kind: str) -> Callable[[BuildConfig], bool]:
    """Whether a config's area was given as a ``city``, a ``bbox`` or a centre (``point``)."""
    def given(config: BuildConfig) -> bool:
        a = config.area
        return {"city": a.kind != "custom", "bbox": a.kind == "custom" and a.bbox is not None,
                "point": a.kind == "custom" and a.bbox is None}[kind]
    return given


_CITY, _BBOX, _POINT = _area_is("city"), _area_is("bbox"), _area_is("point")


@dataclass(frozen=True)
class BuildOptions:
    """``osmseg build``'s options by parameter name: the one table the config, the recorded command
    and the list of options that never change what is built all come from.

    A field whose metadata is :func:`_content`'s changes the dataset and says how its value reads
    back from a :class:`BuildConfig` (the manifest's command, :func:`recorded_command`); a plain field
    (where the output goes, how it is fetched, how many processes) does not, so every shard,
    every resumed run and the same dataset built elsewhere record one command.
    """

    city: str | None = field(metadata=_content(lambda c: c.area.name if _CITY(c) else None))
    lat: float | None = field(metadata=_content(lambda c: c.area.lat if _POINT(c) else None))
    lon: float | None = field(metadata=_content(lambda c: c.area.lon if _POINT(c) else None))
    radius_km: float | None = field(metadata=_content(lambda c: None if _BBOX(c) else c.area.radius_km))
    bbox: str | None = field(metadata=_content(
        lambda c: ",".join(repr(v) for v in c.area.bbox) if _BBOX(c) and c.area.bbox else None))
    samples: int = field(metadata=_content(lambda c: c.samples))
    seed: int = field(metadata=_content(lambda c: c.seed))
    zoom: int = field(metadata=_content(lambda c: c.zoom))
    imagery: str | None = field(metadata=_content(lambda c: redact(c.imagery)))
    tile_size: str | None = field(metadata=_content(lambda c: c.tile_size))
    osm: str = field(metadata=_content(lambda c: redact(c.osm)))
    classes: str = field(metadata=_content(lambda c: c.classes))
    image_format: str = field(metadata=_content(lambda c: c.image_format))
    max_unlabeled: float = field(metadata=_content(lambda c: c.filters.max_unlabeled))
    min_classes: int = field(metadata=_content(lambda c: c.filters.min_classes))
    min_contrast: float = field(metadata=_content(lambda c: c.filters.min_contrast))
    max_missing_imagery: float = field(metadata=_content(lambda c: c.filters.max_invalid_imagery))
    max_placeholder_tiles: int = field(metadata=_content(lambda c: c.filters.max_placeholder_tiles))
    max_tries: int = field(metadata=_content(lambda c: c.max_tries))
    no_overlap: bool = field(metadata=_content(lambda c: c.no_overlap))
    sample_tiles: str = field(metadata=_content(lambda c: str(c.grid_size) if c.grid_size != 5 else None))
    out_dir: Path
    cache_dir: Path | None
    http_timeout: float
    http_retries: int
    http_retry_delay: float
    offline: bool
    workers: int
    shard: str | None
    make_zip: bool
    record: Path | None
    replay: Path | None

    @classmethod
    def from_params(cls, params: dict[str, Any]) -> BuildOptions:
        """The options of ``osmseg build``'s parsed parameters: ``--osm`` (which every command
        may give more than once) names one source here."""
        sources = params["osm"]
        if len(sources) != 1:
            raise ConfigError(f"--osm is given {len(sources)} times: a build reads one OpenStreetMap source")
        return cls(**{**params, "osm": sources[0]})


def build_config(options: BuildOptions) -> BuildConfig:
    """The :class:`BuildConfig` that ``osmseg build``'s options describe."""
    o = options
    if o.record and o.replay:
        raise ConfigError("--record and --replay exclude each other")
    if o.record and o.workers > 1:
        raise ConfigError("--record writes one cassette from one process: give --workers 1 (or leave --workers out)")
    filters = FilterConfig(max_unlabeled=o.max_unlabeled, min_classes=o.min_classes, min_contrast=o.min_contrast,
                           max_invalid_imagery=o.max_missing_imagery, max_placeholder_tiles=o.max_placeholder_tiles)
    config = BuildConfig(
        out_dir=o.out_dir, area=resolve_area(o.city, o.lat, o.lon, o.bbox, o.radius_km), imagery=o.imagery or "bing",
        osm=o.osm, samples=o.samples, seed=o.seed, zoom=o.zoom, classes=o.classes, image_format=o.image_format,
        filters=filters, max_tries=o.max_tries, cache_dir=o.cache_dir or default_cache_dir(), offline=o.offline,
        http_timeout=o.http_timeout, http_retries=o.http_retries, http_retry_delay=o.http_retry_delay,
        shard=Shard.parse(o.shard) if o.shard else None, zip=o.make_zip,
        no_overlap=o.no_overlap, workers=o.workers, tile_size=int(o.tile_size) if o.tile_size else None,
        grid_size=int(o.sample_tiles),
    )
    if o.record or o.replay:
        config = replace(config, cassette=o.record or o.replay, cassette_mode="record" if o.record else "replay")
    return config


#: ``osmseg build`` options that never change what is built, left out of the recorded command (the
#: plain fields of :class:`BuildOptions`, and the output options every command takes).
NOT_CONTENT = frozenset({f.name for f in fields(BuildOptions) if "recorded" not in f.metadata}
                        | {"verbose", "quiet", "progress"})


def content_options(config: BuildConfig) -> dict[str, Any]:
    """The value of every content option of ``osmseg build`` that gives ``config`` (the inverse of
    :func:`build_config`; None or False: the option is left out)."""
    return {f.name: f.metadata["recorded"](config) for f in fields(BuildOptions) if "recorded" in f.metadata}


def _number(value: float, exact: bool) -> str:
    """A float as short text that reads back as the same value (``%g`` when that loses nothing).

    >>> _number(0.7, False), _number(2.0, True), _number(0.123456789, False)
    ('0.7', '2.0', '0.123456789')
    """
    short = f"{value:g}"
    return repr(value) if exact or float(short) != value else short


def recorded_command(config: BuildConfig) -> list[str]:
    """The canonical ``osmseg build`` command that makes ``config``'s dataset, in the option
    table's order with its own flag names (recorded in the manifest; secrets redacted)."""
    values = content_options(config)
    words = ["osmseg", "build"]
    for param in build_command.params:
        if not isinstance(param, click.Option) or param.name in NOT_CONTENT:
            continue
        value = values[str(param.name)]  # a new option must say here what it records
        if value is None or value is False:
            continue
        flag = max(param.opts, key=len)
        if value is True:
            words.append(flag)
        elif isinstance(value, float):  # the area's coordinates as typed (repr), thresholds short
            words += [flag, _number(value, exact=param.name in ("lat", "lon", "radius_km"))]
        else:
            words += [flag, str(value)]
    return words
