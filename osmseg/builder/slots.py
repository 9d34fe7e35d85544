"""One slot of a build: its seeded attempts, run in whichever process the build gives it.

The pipeline for one attempt (see :func:`run_attempt`):

    centre --grid--> SampleGrid --imagery--> RGB 1280x1280
                             \\--osm-------> OSM file --features--> polygons --rasterize--> labels
    (RGB, labels) --filters--> accepted: images/, segmented/, labels/, geo/   |  rejected: reason

:func:`run_slot` tries a slot's centres until one is accepted (see :mod:`osmseg.builder.state` for
why slots make a build resumable and shardable). Everything here depends only on the
:class:`~osmseg.builder.config.BuildConfig`, the slot number and the data, never on which
process runs it or in what order: that is what lets :mod:`osmseg.builder.workers` spread slots over
processes and still write the bytes of a single-process build. Imports: osmseg core below it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from osmseg.builder.config import BuildConfig, sampling_box
from osmseg.builder.filters import FilterConfig, check_imagery, check_labels
from osmseg.builder.records import Attempt, SlotOutcome
from osmseg.builder.sampling import block_attempt_centre
from osmseg.builder.state import BuildState
from osmseg.classes import ClassTable, load_class_table
from osmseg.errors import RetriesExhausted
from osmseg.grid import (
    LngLatBBox,
    SampleGrid,
    ground_resolution,
    pad_bbox,
    resolution_mismatch,
    sample_grid,
    zoom_for_resolution,
)
from osmseg.imagery import make_provider
from osmseg.imagery.base import CoveringImagery, ImageryProvider, LocalRaster, ZoomRange
from osmseg.images import read_rgb
from osmseg.net.http import DEFAULT_HOST_LIMITS, HttpClient, HttpConfig
from osmseg.osm.base import CoveringSource, OsmSource
from osmseg.osm.features import read_features
from osmseg.osm.sources import make_osm_source
from osmseg.output import rejection_entry, sample_entry, write_sample
from osmseg.output.manifest import Provenance, RejectionRecord
from osmseg.output.overview import write_thumbnails
from osmseg.rasterize import rasterize, to_table

logger = logging.getLogger(__name__)

__all__ = ["HOST_LIMITS", "BuildContext", "Pipeline", "attempt_centre", "attempt_rng", "http_config", "open_pipeline",
           "osm_regions", "run_attempt", "run_slot", "warn_upsampling"]

#: Per-host request limits: the OSM API and Overpass ask for at most 2 concurrent connections.
HOST_LIMITS = {**DEFAULT_HOST_LIMITS, "dev.virtualearth.net": 2}
#: Sampling areas up to this size (square degrees) are cut from a local OSM file as one region.
PREPARE_AREA_MAX_DEG2 = 1.0


def attempt_rng(seed: int, slot: int, attempt: int) -> np.random.Generator:
    """The random generator of one attempt: depends only on (seed, slot, attempt)."""
    return np.random.default_rng([seed, slot, attempt])


def attempt_centre(config: BuildConfig, slot: int, attempt: int) -> tuple[float, float] | None:
    """Seeded (lon, lat) centre of attempt ``attempt`` of slot ``slot``.

    With ``--no-overlap`` the centre of that attempt's own tile block (None once the area has
    no block left for it: the slot gives up); else a random point of the area.
    """
    if config.no_overlap:
        return block_attempt_centre(config.area, config.zoom, config.grid_size, config.seed, config.samples,
                                    slot, attempt)
    return config.area.random_centres(attempt_rng(config.seed, slot, attempt), 1)[0]


def attempt_grid(config: BuildConfig, slot: int, attempt: int) -> SampleGrid | None:
    """The sample grid of one attempt (None when ``--no-overlap`` has no block left for it)."""
    centre = attempt_centre(config, slot, attempt)
    return None if centre is None else sample_grid(centre[0], centre[1], config.zoom, config.grid_size)


def http_config(config: BuildConfig, gate_dir: Path | None = None) -> HttpConfig:
    """How a build's HTTP clients talk: its cache, timeout, retries, cassette, per-host limits; ``gate_dir``
    makes the limits and Retry-After pauses shared by every process using that folder."""
    # a recording must see every request, so it bypasses the cache
    recording = config.cassette is not None and config.cassette_mode == "record"
    return HttpConfig(cache_dir=None if recording else config.cache_dir, offline=config.offline,
                      host_limits=HOST_LIMITS, timeout=config.http_timeout, retries=config.http_retries,
                      backoff=config.http_retry_delay, cassette=config.cassette,
                      cassette_mode=config.cassette_mode, gate_dir=gate_dir)


@dataclass
class Pipeline:
    """The sources and tables one build uses (one per process that builds slots)."""

    imagery: ImageryProvider
    osm: OsmSource
    table: ClassTable  # the output table (classes13 or a mapped one such as classes6)
    rules: ClassTable  # the table whose tag rules are rasterised (the base of a mapped table)


@dataclass(frozen=True)
class BuildContext:
    """What every slot of one build is built with in one process: the settings, the sources and
    tables (:class:`Pipeline`), and the build state the outcomes are recorded into. The three
    travel together from the build (or a worker's start) to each slot."""

    config: BuildConfig
    pipe: Pipeline
    state: BuildState


def open_pipeline(config: BuildConfig, client: HttpClient, env: dict[str, str]) -> Pipeline:
    """Create the imagery provider, OSM source and class tables a config names."""
    table = load_class_table(config.classes)
    rules = table.base or table
    workdir = (config.cache_dir or config.out_dir / ".osmseg-build") / "osm"
    imagery = make_provider(config.imagery, client, env, tile_size=config.tile_size)
    if isinstance(imagery, ZoomRange):  # a provider that knows its zoom range says so before anything is written
        imagery.check_zoom(config.zoom)
    osm = make_osm_source(config.osm, client, workdir, rules)
    # then whether the local sources hold anything over the area at all (a raster, a tile folder,
    # an OSM file of another place): every sample would be rejected, so it is said before the build
    area = sampling_box(config)
    if isinstance(imagery, CoveringImagery) and rejects_no_imagery(config.filters):
        imagery.check_covers(*area, zoom=config.zoom)
    if isinstance(osm, CoveringSource):
        osm.check_covers(*area)
    return Pipeline(imagery=imagery, osm=osm, table=table, rules=rules)


def rejects_no_imagery(filters: FilterConfig) -> bool:
    """Whether ``filters`` reject a sample without any imagery (the default: yes). Builds that keep
    such samples (``--max-missing-imagery 1 --min-contrast 0``: labels alone) need no imagery there.

    >>> rejects_no_imagery(FilterConfig()), rejects_no_imagery(FilterConfig(max_invalid_imagery=1, min_contrast=0))
    (True, False)
    """
    return check_imagery(np.zeros((1, 1, 3), np.uint8), np.zeros((1, 1), bool), 0, filters) is not None


def warn_upsampling(config: BuildConfig, imagery: ImageryProvider) -> None:
    """Warn (call it once per build) when ``--zoom`` asks for sample pixels much finer than a local
    raster's (``resolution_m``): each raster pixel would be stretched over several sample pixels,
    blurred, with no detail gained. The threshold is the one ``osmseg predict`` warns at
    (:data:`~osmseg.grid.RESOLUTION_MISMATCH`); the message names the zoom that matches the raster."""
    if not isinstance(imagery, LocalRaster) or imagery.resolution_m is None:
        return
    source_m = imagery.resolution_m
    sample_m = ground_resolution(config.area.lat, config.zoom)
    factor = resolution_mismatch(source_m, sample_m)
    if factor is None or source_m < sample_m:  # a coarser zoom averages the raster: nothing is invented
        return
    where = imagery.path
    logger.warning("%s has %.3g m pixels, but --zoom %d makes %.3g m sample pixels: the imagery is upsampled "
                   "%.1fx (blurred, no detail gained); --zoom %d matches the raster", where, source_m, config.zoom,
                   sample_m, factor, zoom_for_resolution(config.area.lat, source_m))


def osm_regions(config: BuildConfig, slots: list[int]) -> tuple[LngLatBBox, ...]:
    """The boxes to cut one region file for from a local OSM file before ``slots`` are built: the
    sampling area as one box, or for a country-sized area the boxes of every attempt those
    slots may make (their centres are seeded, so known now): a rejected attempt's next box is
    then cut from the region too, never from the country's file again."""
    area = sampling_box(config)
    if (area.east - area.west) * (area.north - area.south) <= PREPARE_AREA_MAX_DEG2:
        return (area,)
    grids = [g for g in (attempt_grid(config, s, a) for s in slots for a in range(config.max_tries)) if g is not None]
    return tuple(pad_bbox(g.bbox, config.osm_padding_m) for g in grids)


def run_attempt(config: BuildConfig, pipe: Pipeline, slot: int, attempt: int,
                thumbnails: Path | None = None) -> Attempt:
    """Run one attempt; write the sample if it is accepted. Returns the attempt's record.

    OSM comes first: a sample whose mask fails the label checks is rejected before any of
    its 25 tiles is downloaded. With ``thumbnails`` (a folder), an accepted sample also
    leaves there the small pictures the dataset's overview sheet is drawn from.
    """
    centre = attempt_centre(config, slot, attempt)
    if centre is None:
        return Attempt.exhausted()
    lon, lat = centre
    grid = sample_grid(lon, lat, config.zoom, config.grid_size)
    extract = pipe.osm.fetch(pad_bbox(grid.bbox, config.osm_padding_m))
    features = read_features(extract.paths, grid, pipe.rules)
    labels = rasterize(features, grid, pipe.rules)
    if pipe.table is not pipe.rules:
        labels = to_table(labels, pipe.rules, pipe.table)
    rejection = check_labels(labels, config.filters)
    imagery = None
    if rejection is None:
        imagery = pipe.imagery.fetch(grid)
        rejection = check_imagery(imagery.rgb, imagery.valid, imagery.placeholder_tiles, config.filters,
                                  uniform_tiles=imagery.uniform_tiles)
    # OSM objects of a class that could not be drawn at all (their nodes have no location in the
    # data): recorded for rejected attempts too, so an empty mask is never a silent one
    unplaced = features.unplaced or None
    if rejection is not None or imagery is None:
        assert rejection is not None
        # which tiles were of one colour (placeholders a server answered as tiles), for the manifest;
        # no OSM object of any class in the box: when every attempt says so, the source has no data there
        return Attempt.rejected(replace(
            rejection_entry(lon, lat, rejection, attempt=attempt), osm_problems=tuple(features.problems) or None,
            osm_unplaced=unplaced, uniform_tiles=Provenance(imagery.info).uniform_tiles if imagery and imagery.uniform_tiles else None,
            osm_empty=True if not features.features and not features.unplaced else None))
    name = f"{config.prefix}_{slot:05d}"
    written = write_sample(config.out_dir, name, imagery.rgb, labels, pipe.table, grid, config.image_format,
                           valid=imagery.valid)
    if thumbnails is not None:
        # the overview shows the image as a reader decodes it: a JPEG's own pixels, not the ones encoded
        shown = read_rgb(config.out_dir / written.file_in("images")) if config.image_format == "jpg" else imagery.rgb
        write_thumbnails(thumbnails, name, shown, labels)
    entry = sample_entry(name, grid, written, imagery=imagery.info, osm=extract.info, osm_timestamp=extract.timestamp)
    # broken OSM objects that were repaired or skipped, for users checking a mask they doubt
    return Attempt.accepted(replace(entry, osm_problems=tuple(features.problems), osm_unplaced=unplaced))


def run_slot(ctx: BuildContext, slot: int, keep_thumbnails: bool = False) -> SlotOutcome:
    """Try centres for one slot until one is accepted or ``max_tries`` runs out.

    ``keep_thumbnails``: the slot may be among the first the overview sheet shows, so an
    accepted sample leaves its thumbnails in the build state (the sheet is then drawn without
    decoding any image again).
    """
    config, pipe, state = ctx.config, ctx.pipe, ctx.state
    rejections: list[RejectionRecord] = []
    outcome = SlotOutcome(slot, "gave_up")  # unless an attempt is accepted
    thumbnails = state.thumbnails if keep_thumbnails else None
    for attempt in range(config.max_tries):
        record = state.attempt(slot, attempt)
        if record is None:
            try:
                record = run_attempt(config, pipe, slot, attempt, thumbnails)
            except RetriesExhausted as exc:
                # A service kept failing through every retry. That says nothing about this centre,
                # so the slot does not move on to its next centre (the dataset would then depend on
                # the network's luck): the attempt stays unfinished, its reason is recorded, the
                # build goes on with the other slots and the same command later retries it.
                reason = str(exc)
                state.record_failure(slot, attempt, reason)
                return SlotOutcome(slot, "failed", tuple(rejections), attempt=attempt, reason=reason)
            if record.status == "exhausted":  # --no-overlap: no block of the area is left for this attempt
                outcome = SlotOutcome(slot, "gave_up", exhausted=True)
                break
            state.record_attempt(slot, attempt, record)
        if record.sample is not None:
            outcome = SlotOutcome(slot, "accepted", sample=record.sample)
            break
        if record.rejection is not None:
            rejections.append(record.rejection)
    outcome = replace(outcome, rejected=tuple(rejections))
    state.record_slot(outcome)
    return outcome
