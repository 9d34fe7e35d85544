"""``osmseg build``: sample centres, fetch imagery and OSM, rasterise, filter, write.

The pipeline for one attempt (see :func:`run_attempt`):

    centre --grid--> SampleGrid --imagery--> RGB 1280x1280
                             \\--osm-------> OSM file --features--> polygons --rasterize--> labels
    (RGB, labels) --filters--> accepted: images/, segmented/, labels/, geo/   |  rejected: reason

:func:`build` runs the attempts slot by slot (see :mod:`osmseg.state` for why slots make a
build resumable and shardable), then writes the dataset-level files: ``manifest.json``,
``DATASHEET.md``, ``ATTRIBUTION.md``, pictures and, if asked, a zip.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections import Counter
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from osmseg import __version__
from osmseg.classes import ClassTable, load_class_table
from osmseg.errors import ConfigError, RetriesExhausted
from osmseg.rejection import FilterConfig, check_imagery, check_labels
from osmseg.grid import TILE_SIZE, LngLatBBox, SampleGrid, ground_resolution, pad_bbox, sample_grid
from osmseg.imagery import make_provider
from osmseg.imagery.base import ImageryProvider
from osmseg.net.http import DEFAULT_HOST_LIMITS, HttpClient, HttpConfig
from osmseg.redact import redact
from osmseg.osm.base import OsmSource
from osmseg.osm.features import read_features
from osmseg.osm.sources import make_osm_source
from osmseg.output import (
    class_totals,
    make_zip,
    rejection_entry,
    sample_entry,
    summary_entry,
    write_attribution,
    write_class_histogram,
    write_datasheet,
    write_manifest,
    write_overview,
    write_sample,
)
from osmseg.output.manifest import FORMAT, FORMAT_VERSION, SAMPLE_DIRS, config_entry
from osmseg.output.stac import write_stac
from osmseg.output.writer import IMAGE_FORMATS
from osmseg.places import Area, normalise_name
from osmseg.progress import Progress, report
from osmseg.rasterize import rasterize, to_table
from osmseg.sampling import block_attempt_centre, check_room, overlap_groups
from osmseg.records import Attempt, SlotOutcome
from osmseg.state import BuildState

logger = logging.getLogger(__name__)

#: Zoom 18: ~0.6 m/px at the equator, ~0.37 m/px in Berlin; a 5x5 sample spans ~470 m there.
#: Fine enough that footways, single trees and small buildings are several pixels wide, coarse
#: enough that Bing/Esri cover every preset area at this level.
DEFAULT_ZOOM = 18

#: Sampling areas up to this size (square degrees) are cut from a local OSM file as one region.
PREPARE_AREA_MAX_DEG2 = 1.0

#: Per-host request limits: the OSM API and Overpass ask for at most 2 concurrent connections.
HOST_LIMITS = {**DEFAULT_HOST_LIMITS, "dev.virtualearth.net": 2}


@dataclass(frozen=True)
class Shard:
    """``--shard K/N``: this process builds slots ``i`` with ``i % N == K - 1``."""

    index: int  # 1-based K
    count: int  # N

    @classmethod
    def parse(cls, text: str) -> "Shard":
        """Parse ``K/N``.

        >>> Shard.parse("2/8")
        Shard(index=2, count=8)
        """
        try:
            k, n = (int(v) for v in text.split("/"))
        except ValueError:
            raise ConfigError(f"--shard {text!r}: expected K/N, e.g. 1/4") from None
        if not 1 <= k <= n:
            raise ConfigError(f"--shard {text!r}: need 1 <= K <= N")
        return cls(k, n)

    def owns(self, slot: int) -> bool:
        return slot % self.count == self.index - 1


@dataclass(frozen=True)
class BuildConfig:
    """Everything that decides a build. Passed explicitly; no global settings."""

    out_dir: Path
    area: Area
    imagery: str
    osm: str = "api"
    samples: int = 30
    seed: int = 0
    zoom: int = DEFAULT_ZOOM
    grid_size: int = 5
    classes: str = "classes13.toml"
    image_format: str = "png"
    filters: FilterConfig = field(default_factory=FilterConfig)
    max_tries: int = 10
    osm_padding_m: float = 60.0
    cache_dir: Path | None = None
    offline: bool = False
    shard: Shard | None = None
    zip: bool = False
    name_prefix: str | None = None
    http_timeout: float = 30.0  # seconds to connect, and between bytes read
    cassette: Path | None = None  # --record/--replay FILE
    cassette_mode: str = "replay"
    no_overlap: bool = False  # --no-overlap: every attempt gets its own tile block (osmseg.sampling)

    def identity(self) -> dict[str, Any]:
        """What decides the dataset's content; recorded in the state and the manifest.

        Returned in its JSON form (tuples as lists), so the identity a rerun computes equals,
        value for value, the one read back from ``.osmseg-build/config.json``.
        """
        return json.loads(json.dumps(self._identity(), allow_nan=False))

    def _identity(self) -> dict[str, Any]:
        return {
            "area": {k: v for k, v in asdict(self.area).items() if v is not None},
            "imagery": redact(self.imagery),  # a literal key in a template never reaches disk
            "osm": redact(self.osm),
            "samples": self.samples,
            "seed": self.seed,
            "zoom": self.zoom,
            "grid_size": self.grid_size,
            "classes": self.classes,
            "image_format": self.image_format,
            "filters": self.filters.to_dict(),
            "max_tries": self.max_tries,
            "osm_padding_m": self.osm_padding_m,
            # only when asked, so that a folder built before the option existed still resumes
            **({"sampling": "blocks (--no-overlap)"} if self.no_overlap else {}),
        }

    def my_slots(self) -> list[int]:
        """The slots this process builds: all of them, or this shard's share."""
        return [s for s in range(self.samples) if self.shard is None or self.shard.owns(s)]

    @property
    def prefix(self) -> str:
        return self.name_prefix or normalise_name(self.area.name).replace(" ", "-") or "sample"


@dataclass
class BuildSummary:
    """What a build did, for the closing summary."""

    out_dir: Path
    accepted: int = 0
    rejected: Counter = field(default_factory=Counter)
    gave_up: int = 0
    osm_problems: int = 0
    pending_other_shards: int = 0
    seconds: float = 0.0
    finalized: bool = False
    duplicates: int = 0
    failed: list[tuple[int, str]] = field(default_factory=list)  # (slot, reason) of attempts that could not fetch
    unplaced: int = 0  # OSM objects of a class with no located node, over all attempts
    overlapping: int = 0  # samples sharing pixels with another sample
    groups: int = 0  # groups of overlapping samples (a sample alone is a group)
    no_overlap: bool = False
    exhausted: int = 0  # slots that ran out of tile blocks of the area (--no-overlap)
    dataset_accepted: int = 0  # samples in the finished dataset (all shards), once the manifest is written

    def lines(self) -> list[str]:
        reasons = ", ".join(f"{n} {r}" for r, n in sorted(self.rejected.items())) or "none"
        whole = (f"; the dataset holds {self.dataset_accepted}" if self.finalized
                 and self.dataset_accepted != self.accepted else "")
        out = [
            f"accepted {self.accepted} samples{whole}; rejected {sum(self.rejected.values())} attempts ({reasons})",
            f"time {self.seconds:.1f} s",
        ]
        if self.unplaced:
            out.append(f"warning: {self.unplaced} OSM objects that match a class were not drawn: none of their nodes "
                       "has a location in the OSM data (an extract without its nodes?); see osm_problems in "
                       "manifest.json, and check the --osm source")
        if self.osm_problems:
            out.append(f"{self.osm_problems} broken OSM objects were repaired or skipped "
                       "(listed per sample in manifest.json as osm_problems; -v prints them)")
        if self.overlapping:
            repeat = f", {self.duplicates} of them the very tiles of another" if self.duplicates else ""
            groups = f"{self.groups} spatial group{'s' if self.groups != 1 else ''}"
            out.append(f"{self.overlapping} of {self.dataset_accepted} samples overlap another ({groups}{repeat}): training "
                       "keeps each group in one split; --no-overlap draws samples that never overlap")
        if self.exhausted:
            out.append(f"{self.exhausted} slots ran out of tile blocks of the area (--no-overlap gives every attempt "
                       "its own): widen the area, or ask for fewer --samples")
        if self.gave_up - self.exhausted > 0:
            out.append(f"{self.gave_up - self.exhausted} slots hit --max-tries without an accepted sample")
        if self.failed:
            out.append(f"{len(self.failed)} samples could not be fetched (services kept failing through every retry); "
                       "their reasons are in .osmseg-build/failures/")
        pending = self.pending_other_shards - len(self.failed)
        if pending > 0:
            out.append(f"{pending} slots belong to other shards and are not built yet")
        return out


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


@dataclass
class Pipeline:
    """The sources and tables one build uses."""

    imagery: ImageryProvider
    osm: OsmSource
    table: ClassTable  # the output table (classes13 or a mapped one such as classes6)
    rules: ClassTable  # the table whose tag rules are rasterised (the base of a mapped table)


def run_attempt(config: BuildConfig, pipe: Pipeline, slot: int, attempt: int) -> Attempt:
    """Run one attempt; write the sample if it is accepted. Returns the attempt's record.

    OSM comes first: a sample whose mask fails the label checks is rejected before any of
    its 25 tiles is downloaded.
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
        rejection = check_imagery(imagery.rgb, imagery.valid, imagery.placeholder_tiles, config.filters)
    # OSM objects of a class that could not be drawn at all (their nodes have no location in the
    # data): recorded for rejected attempts too, so an empty mask is never a silent one
    unplaced = {"osm_unplaced": features.unplaced} if features.unplaced else {}
    if rejection is not None or imagery is None:
        assert rejection is not None
        problems = {"osm_problems": list(features.problems)} if features.problems else {}
        return Attempt.rejected({**rejection_entry(lon, lat, rejection, attempt=attempt), **problems, **unplaced})
    name = f"{config.prefix}_{slot:05d}"
    written = write_sample(config.out_dir, name, imagery.rgb, labels, pipe.table, grid, config.image_format)
    entry = sample_entry(name, grid, written, imagery=imagery.info, osm=extract.info, osm_timestamp=extract.timestamp)
    # broken OSM objects that were repaired or skipped, for users checking a mask they doubt
    entry["osm_problems"] = list(features.problems)
    entry.update(unplaced)
    return Attempt.accepted(entry)


def run_slot(config: BuildConfig, pipe: Pipeline, state: BuildState, slot: int) -> SlotOutcome:
    """Try centres for one slot until one is accepted or ``max_tries`` runs out."""
    rejections: list[dict[str, Any]] = []
    outcome = SlotOutcome(slot, "gave_up")  # unless an attempt is accepted
    for attempt in range(config.max_tries):
        record = state.attempt(slot, attempt)
        if record is None:
            try:
                record = run_attempt(config, pipe, slot, attempt)
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
        rejections.append(dict(record.rejection or {}))
    outcome = replace(outcome, rejected=tuple(rejections))
    state.record_slot(outcome)
    return outcome


def open_pipeline(config: BuildConfig, client: HttpClient, env: dict[str, str]) -> Pipeline:
    """Create the imagery provider, OSM source and class tables a config names."""
    table = load_class_table(config.classes)
    rules = table.base or table
    workdir = (config.cache_dir or config.out_dir / ".osmseg-build") / "osm"
    imagery = make_provider(config.imagery, client, env)
    check_zoom = getattr(imagery, "check_zoom", None)
    if callable(check_zoom):  # a provider that knows its zoom range says so before anything is written
        check_zoom(config.zoom)
    check_covers = getattr(imagery, "check_covers", None)
    if callable(check_covers):  # a local raster that misses the area: every sample would be rejected
        check_covers(*sampling_box(config))
    osm = make_osm_source(config.osm, client, workdir, rules)
    return Pipeline(imagery=imagery, osm=osm, table=table, rules=rules)


def build(
    config: BuildConfig,
    env: dict[str, str] | None = None,
    progress: Progress | None = None,
    command_line: str = "",
) -> BuildSummary:
    """Build (or resume) the dataset described by ``config`` in ``config.out_dir``.

    ``progress`` gets a :class:`~osmseg.progress.Step` per finished slot of this shard, with
    the accepted, rejected and failed counts so far (the CLI draws its bar with it). ``command_line`` is recorded in the manifest; pass it without secrets.
    """
    env = dict(os.environ if env is None else env)
    start = time.monotonic()
    check_config(config)
    summary = BuildSummary(out_dir=config.out_dir)
    recording = config.cassette is not None and config.cassette_mode == "record"
    http = HttpConfig(
        # a recording must see every request, so it bypasses the cache
        cache_dir=None if recording else config.cache_dir,
        offline=config.offline, host_limits=HOST_LIMITS, timeout=config.http_timeout,
        cassette=config.cassette, cassette_mode=config.cassette_mode,
    )
    with HttpClient(http) as client:
        # every source and option is checked before anything is written into the output folder:
        # a command refused here leaves no state that the corrected command would be refused by
        pipe = open_pipeline(config, client, env)
        config.out_dir.mkdir(parents=True, exist_ok=True)
        sweep_temp_files(config.out_dir)
        state = BuildState(config.out_dir)
        state.check_config(config.identity())
        mine = config.my_slots()
        todo = [s for s in mine if state.slot(s) is None]
        prepare = getattr(pipe.osm, "prepare", None)
        if todo and callable(prepare):
            # one pass over a big local file, cutting a small region every attempt reads
            area = sampling_box(config)
            if (area.east - area.west) * (area.north - area.south) <= PREPARE_AREA_MAX_DEG2:
                prepare([area])
            else:  # a country-sized area: cut just the first-try boxes
                grids = [g for g in (_grid(config, s, 0) for s in todo) if g is not None]
                prepare([pad_bbox(g.bbox, config.osm_padding_m) for g in grids])
        report(progress, "build", 0, len(mine), "sample")
        for done, slot in enumerate(mine, start=1):
            outcome = state.slot(slot) or run_slot(config, pipe, state, slot)
            _count(summary, outcome)
            counts = {"failed": len(summary.failed)} if summary.failed else {}
            report(progress, "build", done, len(mine), "sample", accepted=summary.accepted,
                   rejected=sum(summary.rejected.values()), **counts)
        imagery_info, osm_info = pipe.imagery.describe(), pipe.osm.describe()
    outcomes = [state.slot(s) for s in range(config.samples)]
    summary.pending_other_shards = sum(o is None for o in outcomes)
    if summary.pending_other_shards == 0:
        state.check_owner()  # another command took the folder over meanwhile
        manifest = finalize(config, pipe.table, [o for o in outcomes if o is not None], imagery_info, osm_info, command_line)
        summary.dataset_accepted = manifest["summary"]["accepted"]  # every shard's samples, not only ours
        summary.duplicates = manifest["summary"]["duplicate_samples"]
        summary.overlapping = manifest["summary"]["overlapping_samples"]
        summary.groups = manifest["summary"]["overlap_groups"]
        summary.finalized = True
    summary.seconds = time.monotonic() - start
    return summary


def check_config(config: BuildConfig) -> None:
    """Refuse, with one line each, the settings that no source needs to see to know are wrong."""
    if config.samples < 1:
        raise ConfigError("--samples must be at least 1")
    if config.image_format not in IMAGE_FORMATS:
        raise ConfigError(f"--image-format must be one of {', '.join(IMAGE_FORMATS)}, got {config.image_format!r}")
    ground_resolution(config.area.lat, config.zoom)  # validates lat
    if config.no_overlap:
        check_room(config.area, config.zoom, config.grid_size, config.seed, config.samples)
    if config.out_dir.exists() and not config.out_dir.is_dir():
        raise ConfigError(f"--out {config.out_dir} is a file; give a folder (new, or a build to resume)")


def sweep_temp_files(out_dir: Path) -> None:
    """Remove ``.NAME.*.tmp`` files a killed build left in the sample folders (never read, only litter)."""
    for folder in SAMPLE_DIRS:
        for tmp in (out_dir / folder).glob(".*.tmp"):
            tmp.unlink(missing_ok=True)


def sampling_box(config: BuildConfig) -> LngLatBBox:
    """A box holding every grid (plus OSM padding) that any attempt of the build can draw."""
    a = config.area
    box = a.bbox or pad_bbox(LngLatBBox(a.lon, a.lat, a.lon, a.lat), (a.radius_km or 0.0) * 1000.0)
    tile_m = TILE_SIZE * ground_resolution(a.lat, config.zoom)
    return pad_bbox(box, (config.grid_size / 2 + 1) * tile_m + config.osm_padding_m)


def _grid(config: BuildConfig, slot: int, attempt: int) -> SampleGrid | None:
    centre = attempt_centre(config, slot, attempt)
    return None if centre is None else sample_grid(centre[0], centre[1], config.zoom, config.grid_size)


def _count(summary: BuildSummary, outcome: SlotOutcome) -> None:
    summary.unplaced += outcome.unplaced
    summary.exhausted += outcome.exhausted
    if outcome.status == "failed":
        summary.failed.append((outcome.slot, str(outcome.reason)))
    elif outcome.sample is not None:
        summary.accepted += 1
        summary.osm_problems += len(outcome.sample.get("osm_problems", ()))
    else:
        summary.gave_up += 1
    summary.rejected.update(r["reason"] for r in outcome.rejected)


def finalize(
    config: BuildConfig,
    table: ClassTable,
    outcomes: list[SlotOutcome],
    imagery_info: dict[str, Any],
    osm_info: dict[str, Any],
    command_line: str,
) -> dict[str, Any]:
    """Write manifest, datasheet, attribution, pictures (and zip) from the finished slots."""
    samples = [o.sample for o in outcomes if o.sample is not None]
    rejected = [dict(r, slot=o.slot) for o in outcomes for r in o.rejected]
    area = config.area
    manifest: dict[str, Any] = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "tool": {"name": "osmseg", "version": __version__},
        "command": command_line,
        "seed": config.seed,
        "area": {"name": area.name, "kind": area.kind, "lat": area.lat, "lon": area.lon, "radius_km": area.radius_km,
                 "bbox": list(area.bbox) if area.bbox else None},
        "zoom": config.zoom,
        "grid_size": config.grid_size,
        "image_format": config.image_format,
        "config": config_entry(config.identity()),
        "classes": table.to_dict(),
        "filters": config.filters.to_dict(),
        "imagery": imagery_info,
        "osm": osm_info,
        "samples": samples,
        "rejected": rejected,
        "summary": summary_entry(samples, rejected, requested=config.samples,
                                 max_attempts=config.samples * config.max_tries),
    }
    # slots draw independently (that is what makes shards exact), so two may land on one grid, or
    # overlap: groups of overlapping samples are recorded, and training keeps a group in one split
    grids = Counter(tuple(t["quadkey"] for t in s["tiles"]) for s in samples)
    groups = overlap_groups([s["bounds_3857"] for s in samples])
    sizes = Counter(groups)
    for sample, group in zip(samples, groups):
        sample["overlap_group"] = group
    manifest["summary"].update(
        duplicate_samples=sum(n - 1 for n in grids.values()),
        overlapping_samples=sum(1 for g in groups if sizes[g] > 1),
        overlap_groups=len(sizes),
        osm_unplaced=sum(int(r.get("osm_unplaced", 0)) for r in [*samples, *rejected]),
    )
    write_manifest(config.out_dir, manifest)
    write_datasheet(config.out_dir, manifest)
    write_attribution(config.out_dir, manifest)
    write_stac(config.out_dir, manifest)
    write_overview(config.out_dir, samples, table)
    write_class_histogram(config.out_dir, class_totals(samples), table)
    if config.zip:
        out = config.out_dir.resolve()
        make_zip(config.out_dir, out.parent / f"{out.name}.zip")
    return manifest
