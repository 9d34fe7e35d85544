"""``osmseg build``: sample centres, fetch imagery and OSM, rasterise, filter, write, on every core.

:func:`build` checks the sources and the output folder, cuts the OSM data every sample needs
from a local file in one pass, then builds the slots that are not finished yet
(:func:`osmseg.builder.slots.run_slot`: one attempt after another until a sample is accepted) in this
process or on worker processes (:mod:`osmseg.builder.workers`), and finally writes the dataset-level
files from the finished slots (:func:`finalize`): ``manifest.json``, ``DATASHEET.md``,
``ATTRIBUTION.md``, the STAC catalog, pictures and, if asked, a zip. See :mod:`osmseg.builder.state` for
why slots make a build resumable, shardable and independent of the number of workers.
"""

from __future__ import annotations

import logging
import os
import re
import shutil
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from osmseg.builder.config import DEFAULT_ZOOM, SAMPLE_TILES, BuildConfig, Shard, sampling_box
from osmseg.builder.finalize import ENTRIES_PREFIX, finalize
from osmseg.builder.records import SlotOutcome
from osmseg.builder.sampling import check_room
from osmseg.builder.slots import (
    BuildContext,
    Pipeline,
    attempt_grid,
    http_config,
    open_pipeline,
    osm_regions,
    warn_upsampling,
)
from osmseg.builder.state import STATE_SUBDIRS, BuildState
from osmseg.builder.workers import FirstSamples, SlotRunner
from osmseg.errors import ConfigError
from osmseg.grid import LngLatBBox, ground_resolution, pad_bbox
from osmseg.imagery.base import ServedVerdicts
from osmseg.net.http import HttpClient
from osmseg.osm.base import RegionSource
from osmseg.output.atomic import sweep_temp_files as sweep_temp
from osmseg.output.manifest import SAMPLE_DIRS
from osmseg.output.stac import ITEMS_DIR, STAC_DIR
from osmseg.output.writer import IMAGE_FORMATS
from osmseg.runtime.folderlock import STATE_DIR
from osmseg.runtime.processes import start_fork_server, sweep_owned
from osmseg.runtime.progress import Progress, report
from osmseg.units import noun, plural

logger = logging.getLogger(__name__)

__all__ = ["DEFAULT_ZOOM", "NO_IMAGERY_REASONS", "SAMPLE_TILES", "BuildConfig", "BuildSummary", "Shard", "build", "check_config", "finalize",
           "sampling_box"]


@dataclass
class BuildSummary:
    """What a build did, for the closing summary."""

    out_dir: Path
    accepted: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
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
    asked: int = 0  # --samples
    osm_empty: int = 0  # rejected attempts whose OSM data held no object of any class
    max_tries: int = 0  # --max-tries
    served_verdicts: bool = False  # the imagery's "no imagery here" comes from a server (asked again by a rerun)
    rechecked: int = 0  # finished slots built again because a server's "no imagery here" had rejected an attempt
    built: int | None = None  # slots this run built (0: a rerun with nothing left to do; None: not counted)
    sharded: bool = False  # this run builds one --shard of the samples

    def lines(self) -> list[str]:
        """The closing summary, a line each; a rerun with every slot already finished says so first.

        >>> BuildSummary(Path("ds"), accepted=1, osm_problems=1, overlapping=2, groups=1, dataset_accepted=1).lines()[0]
        'accepted 1 sample; rejected 0 attempts (none)'
        >>> print("\\n".join(BuildSummary(Path("ds"), accepted=2, built=0, osm_problems=1, finalized=True,
        ...                                dataset_accepted=2).lines()))
        nothing to do: every sample was already built
        accepted 2 samples; rejected 0 attempts (none)
        time 0.0 s
        1 broken OSM object was repaired or skipped (listed per sample in manifest.json as osm_problems; -v prints it)
        """
        reasons = ", ".join(f"{n} {r}" for r, n in sorted(self.rejected.items())) or "none"
        whole = (f"; the dataset holds {self.dataset_accepted}" if self.finalized
                 and self.dataset_accepted != self.accepted else "")
        rejected = sum(self.rejected.values())
        out = [] if self.built != 0 else [f"nothing to do: every sample{' of this shard' if self.sharded else ''} "
                                          "was already built"]
        out += [
            f"accepted {plural(self.accepted, 'sample')}{whole}; rejected {plural(rejected, 'attempt')} ({reasons})",
            f"time {self.seconds:.1f} s",
        ]
        if self.unplaced:
            out.append(f"warning: {plural(self.unplaced, 'OSM object')} that match{'es' if self.unplaced == 1 else ''} "
                       f"a class {'was' if self.unplaced == 1 else 'were'} not drawn: none of "
                       f"{'its' if self.unplaced == 1 else 'their'} nodes has a location in the OSM data (an extract "
                       "without its nodes?); see osm_problems in manifest.json, and check the --osm source")
        if self.osm_problems:
            one = self.osm_problems == 1
            out.append(f"{plural(self.osm_problems, 'broken OSM object')} {'was' if one else 'were'} repaired or skipped "
                       f"(listed per sample in manifest.json as osm_problems; -v prints {'it' if one else 'them'})")
        if self.overlapping:
            repeat = f", {self.duplicates} of them the very tiles of another" if self.duplicates else ""
            out.append(f"{self.overlapping} of {plural(self.dataset_accepted, 'sample')} overlap"
                       f"{'s' if self.overlapping == 1 else ''} another ({plural(self.groups, 'spatial group')}"
                       f"{repeat}): training keeps each group in one split; --no-overlap draws samples that never "
                       "overlap")
        if self.finalized and 0 < self.dataset_accepted < self.asked:
            out.append(self.incomplete())
        else:
            if self.exhausted:
                out.append(f"{plural(self.exhausted, 'slot')} ran out of tile blocks of the area (--no-overlap gives "
                           "every attempt its own): widen the area, or ask for fewer --samples")
            if self.gave_up - self.exhausted > 0:
                out.append(f"{plural(self.gave_up - self.exhausted, 'slot')} hit --max-tries without an accepted sample")
        if self.rechecked:
            out.append(f"{plural(self.rechecked, 'sample')} {'were' if self.rechecked != 1 else 'was'} built again: an "
                       "attempt had been rejected for tiles the server said had no imagery, which every run asks again")
        if self.failed:
            out.append(f"{plural(len(self.failed), 'sample')} could not be fetched (services kept failing through every "
                       "retry); their reasons are in .osmseg-build/failures/")
        pending = self.pending_other_shards - len(self.failed)
        if pending > 0:
            out.append(f"{plural(pending, 'slot')} belong{'s' if pending == 1 else ''} to other shards and "
                       f"{'is' if pending == 1 else 'are'} not built yet")
        return out

    def incomplete(self) -> str:
        """The line of a finished dataset holding fewer samples than asked: how many, why, what to do.

        The build still succeeds (exit 0): the dataset is complete for its options (its manifest
        says ``"complete": false`` and ``"requested"``), and the same command gives the same one again.

        >>> BuildSummary(Path("ds"), gave_up=7, finalized=True, dataset_accepted=1, asked=8, max_tries=10).incomplete()
        'incomplete: the dataset holds 1 of the 8 samples asked for: 7 slots gave up after --max-tries 10 rejected attempts (reasons above and in manifest.json); the same command gives the same dataset again: for more, build into a new --out with a higher --max-tries, looser filters or a larger area'
        """
        missing = self.asked - self.dataset_accepted
        tries = self.gave_up - self.exhausted
        causes = ([f"{plural(tries, 'slot')} gave up after --max-tries {self.max_tries} rejected "
                   f"{noun(self.max_tries, 'attempt')}"] if tries else [])
        if self.exhausted:
            causes.append(f"{plural(self.exhausted, 'slot')} ran out of tile blocks of the area (--no-overlap)")
        why = " and ".join(causes) if causes and self.gave_up == missing else f"{plural(missing, 'slot')} gave up"
        more = "a higher --max-tries, looser filters or a larger area" if tries or not self.exhausted else "a larger area"
        absent = sum(self.rejected[r] for r in NO_IMAGERY_REASONS)
        if tries and absent:
            again = ("if the provider has imagery there, run the same command again later (a server's 'no imagery "
                     "here' is asked again by every run); else " if self.served_verdicts else "")
            return (f"incomplete: the dataset holds {self.dataset_accepted} of the {self.asked} samples asked for: "
                    f"{why}, {absent} of them for tiles of one colour or empty (no imagery); {again}sample where "
                    "--imagery has imagery (--bbox/--lat/--lon), give another --imagery, or allow a few such tiles "
                    "(--max-placeholder-tiles, --max-missing-imagery)")
        return (f"incomplete: the dataset holds {self.dataset_accepted} of the {self.asked} samples asked for: {why} "
                f"(reasons above and in manifest.json); the same command gives the same dataset again: for more, "
                f"build into a new --out with {more}")


def build(
    config: BuildConfig,
    env: dict[str, str] | None = None,
    progress: Progress | None = None,
    command_line: str = "",
) -> BuildSummary:
    """Build (or resume) the dataset described by ``config`` in ``config.out_dir``.

    ``progress`` gets a :class:`~osmseg.runtime.progress.Step` per finished slot of this shard, with
    the accepted, rejected and failed counts so far (the CLI draws its bar with it).
    ``command_line`` is recorded in the manifest; pass it without secrets. ``env`` (default:
    this process's environment) supplies keys; worker processes get it through their pipe.
    """
    env = dict(os.environ if env is None else env)
    start = time.monotonic()
    check_config(config)
    summary = BuildSummary(out_dir=config.out_dir, asked=config.samples, max_tries=config.max_tries)
    if config.worker_count(len(config.my_slots())) > 1:
        start_fork_server()
    with HttpClient(http_config(config)) as client:
        # every source and option is checked before anything is written into the output folder:
        # a command refused here leaves no state that the corrected command would be refused by
        pipe = open_pipeline(config, client, env)
        warn_upsampling(config, pipe.imagery)  # here, not in open_pipeline: workers open theirs too
        config.out_dir.mkdir(parents=True, exist_ok=True)
        state = BuildState(config.out_dir)
        try:
            _build_slots(BuildContext(config, pipe, state), env, progress, command_line, summary)
        finally:
            state.release()
    summary.seconds = time.monotonic() - start
    return summary


def _build_slots(ctx: BuildContext, env: dict[str, str], progress: Progress | None, command_line: str,
                 summary: BuildSummary) -> None:
    """The body of :func:`build` while it holds the output folder: build the unfinished slots of
    this shard, then, when every slot of the build has its outcome, the dataset-level files."""
    config, pipe, state = ctx.config, ctx.pipe, ctx.state
    state.claim(config.identity(), command_line)  # refuses a folder another build holds now
    sweep_work_area(config.out_dir)  # only now: what is left is a killed process's, or a sharer's live files
    mine = config.my_slots()
    first = FirstSamples()
    todo: list[int] = []
    recheck = asks_verdicts_again(config, pipe)
    summary.served_verdicts = recheck or served_verdicts(pipe)
    for slot in mine:  # finished slots are counted, not kept: memory does not grow with the build
        outcome = state.slot(slot)
        verdict = verdict_attempt(outcome) if outcome is not None and recheck else None
        if verdict is not None:  # a server's "no imagery here" rejected an attempt: asked again from there
            state.reopen(slot, verdict, config.max_tries)
            summary.rechecked += 1
            outcome = None
        if outcome is None:
            todo.append(slot)
            continue
        _count(summary, outcome)
        if outcome.status == "accepted":
            first.accepted(slot)
    summary.built, summary.sharded = len(todo), config.shard is not None
    regions = prepare_osm(config, pipe, mine, todo)
    finished = len(mine) - len(todo)
    report(progress, "build", finished, len(mine), "sample")
    with SlotRunner(ctx, env, config.worker_count(len(todo)), regions) as runner:
        for count, outcome in enumerate(runner.run(todo, first), start=finished + 1):
            _count(summary, outcome)
            counts = {"failed": len(summary.failed)} if summary.failed else {}
            report(progress, "build", count, len(mine), "sample", accepted=summary.accepted,
                   rejected=sum(summary.rejected.values()), **counts)
    summary.pending_other_shards = sum(not state.has_slot(s) for s in range(config.samples))
    if summary.pending_other_shards == 0:
        state.check_owner()  # the folder was deleted meanwhile (or taken where there are no locks)
        sweep_work_area(config.out_dir)  # again: a killed build's worker may have outlived the first sweep
        whole = finalize(config, pipe.table, state, pipe.imagery.describe(), pipe.osm.describe(), command_line)
        summary.dataset_accepted = whole.accepted or 0  # every shard's samples, not only ours
        summary.duplicates = whole.duplicate_samples or 0
        summary.overlapping = whole.overlapping_samples or 0
        summary.groups = whole.overlap_groups or 0
        summary.finalized = True


#: Rejection reasons that say the imagery source had nothing (at a sample's place, or a tile of it).
NO_IMAGERY_REASONS = ("missing_imagery", "placeholder_imagery")


def served_verdicts(pipe: Pipeline) -> bool:
    """Whether the build's imagery says "no imagery here" from a server (:class:`ServedVerdicts`)."""
    return isinstance(pipe.imagery, ServedVerdicts) and pipe.imagery.verdicts_served()


def asks_verdicts_again(config: BuildConfig, pipe: Pipeline) -> bool:
    """Whether this run asks a server's "no imagery here" again: online, imagery from a server. Offline
    and under ``--replay`` the answers are the recorded ones, verdicts included."""
    replaying = config.cassette is not None and config.cassette_mode == "replay"
    return not config.offline and not replaying and served_verdicts(pipe)


def verdict_attempt(outcome: SlotOutcome) -> int | None:
    """The first attempt of a finished slot that a missing-imagery verdict rejected, or None."""
    attempts = [r.attempt for r in outcome.rejected if r.reason in NO_IMAGERY_REASONS and r.attempt is not None]
    return min(attempts) if attempts else None


def prepare_osm(config: BuildConfig, pipe: Pipeline, mine: list[int], todo: list[int]) -> tuple[LngLatBBox, ...]:
    """Cut, from a local OSM file, one region file for this process's slots ``mine`` (the sampling
    area, or the first attempts' boxes of a country-sized area: the same region however far the
    build has got, so a resumed or requeued shard finds it), then every first attempt's box of
    the unfinished slots ``todo``, in passes over the file whose number does not grow with the
    samples. Returns the region boxes (worker processes find the region by them). Other
    sources: nothing to do."""
    if not todo or not isinstance(pipe.osm, RegionSource):
        return ()
    regions = osm_regions(config, mine)
    pipe.osm.prepare(list(regions))
    grids = [g for g in (attempt_grid(config, s, 0) for s in todo) if g is not None]
    pipe.osm.cut([pad_bbox(g.bbox, config.osm_padding_m) for g in grids])
    return regions


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


#: The folders of a dataset that only osmseg writes into (beside its sample folders).
OWN_FOLDERS = (STAC_DIR, f"{STAC_DIR}/{ITEMS_DIR}", STATE_DIR, *(f"{STATE_DIR}/{d}" for d in STATE_SUBDIRS))


def sweep_work_area(out_dir: Path) -> None:
    """Remove what killed processes left in the output folder: temporary files (``.NAME.*.tmp``)
    in the folders osmseg writes (its sample folders, the STAC catalog, the build state, and the
    output folder itself, where only names osmseg gave are touched: it may be the user's), and
    the build state's temporary folders (``entries-*`` of an interrupted finalize). Never read,
    only litter; those of live writers, such as a shard started at the same time, stay. Called
    while this build holds the folder, so an ``entries-*`` folder of the older unnamed form
    (osmseg < 0.4) has no live writer either."""
    sweep_temp(out_dir, named_only=True)
    for folder in (*SAMPLE_DIRS, *OWN_FOLDERS):
        if (out_dir / folder).is_dir():
            sweep_temp(out_dir / folder)
    state = out_dir / STATE_DIR
    sweep_owned(state, ENTRIES_PREFIX)
    for old in state.glob(f"{ENTRIES_PREFIX}*"):
        if old.is_dir() and re.fullmatch(rf"{ENTRIES_PREFIX}[A-Za-z0-9_]{{8}}", old.name):
            shutil.rmtree(old, ignore_errors=True)


def _count(summary: BuildSummary, outcome: SlotOutcome) -> None:
    summary.unplaced += outcome.unplaced
    summary.exhausted += outcome.exhausted
    if outcome.status == "failed":
        summary.failed.append((outcome.slot, str(outcome.reason)))
    elif outcome.sample is not None:
        summary.accepted += 1
        summary.osm_problems += len(outcome.sample.osm_problems or ())
    else:
        summary.gave_up += 1
    summary.rejected.update(r.reason for r in outcome.rejected)
    summary.osm_empty += sum(1 for r in outcome.rejected if r.osm_empty)
