"""A finished build's dataset-level files, written from its slot records without holding them all.

When every slot of a build has an outcome, :func:`finalize` writes ``manifest.json``,
``DATASHEET.md``, ``ATTRIBUTION.md``, the STAC catalog, ``overview.png`` and
``class_histogram.png`` (and the zip). A dataset of tens of thousands of samples has a
manifest of tens of megabytes; to keep the builder's memory flat, the samples and rejections
are never all in memory at once: :class:`SlotRecords` reads the slot records of the build
state once, copying the entries into two JSON-lines files of a temporary folder and keeping a
few numbers per sample (where its line is, its bounds, its tile key), and the writers then
iterate :class:`SampleEntries` / :class:`RejectionEntries`, lazy sequences that read each
entry from those files as they go. The manifest is written in pieces
(:func:`osmseg.output.manifest.write_manifest`) with exactly the bytes one ``json.dumps``
(sorted keys, indent 2, UTF-8 unescaped) would give. Imports: osmseg core below it (output,
state, records, sampling).
"""

from __future__ import annotations

import hashlib
import json
import tempfile
from collections import Counter
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import IO, Generic, TypeVar, overload

import numpy as np

from osmseg import __version__
from osmseg.builder.config import BuildConfig
from osmseg.builder.records import SlotOutcome
from osmseg.builder.state import BuildState
from osmseg.classes import ClassTable
from osmseg.errors import DatasetError
from osmseg.output import (
    class_totals,
    make_zip,
    summary_entry,
    write_attribution,
    write_class_histogram,
    write_datasheet,
    write_manifest,
    write_overview,
)
from osmseg.output.manifest import (
    FORMAT_VERSION,
    AreaRecord,
    DatasetManifest,
    DatasetSummary,
    Json,
    JsonObject,
    Provenance,
    RejectionRecord,
    SampleRecord,
    ToolInfo,
    config_entry,
)
from osmseg.output.stac import write_stac
from osmseg.overlap import overlap_groups
from osmseg.runtime.processes import deferred_termination, owner

__all__ = ["ENTRIES_PREFIX", "RejectionEntries", "SampleEntries", "SlotRecords", "finalize"]

#: The temporary folder of a finalize in the build state: ``entries-HOST-PID-RANDOM``.
ENTRIES_PREFIX = "entries-"


class SlotRecords:
    """A finished build's slot records, read once: the samples' and rejections' manifest entries
    copied, one JSON line each, into two files of a temporary folder of the build state (read in
    sequence by the writers, a few times, where a shared file system would pay for every small
    record opened again), plus what the summary needs: each sample's bounds (for overlap groups) and tile key
    (for duplicates), counts. It keeps a few numbers per sample, never the entries. Use it as a
    context manager: the temporary folder goes when it closes."""

    def __init__(self, state: BuildState, slots: int) -> None:
        self.state = state
        # beside the records, named by its owner: the next run sweeps it when a kill left it; made and
        # remembered before a SIGTERM may unwind, and removed when reading the records does not finish
        with deferred_termination():
            self._folder = tempfile.TemporaryDirectory(prefix=f"{ENTRIES_PREFIX}{owner()}-", dir=state.root)
        try:
            self._read(slots)
        except BaseException:
            self._folder.cleanup()
            raise

    def _read(self, slots: int) -> None:
        """Copy the slots' entries into the folder's two files; count what the summary needs."""
        folder = Path(self._folder.name)
        self.files = {"samples": folder / "samples.jsonl", "rejected": folder / "rejected.jsonl"}
        self.offsets: dict[str, list[int]] = {"samples": [], "rejected": []}  # where each entry's line starts
        self.rejected_by_reason: Counter[str] = Counter()
        self.osm_unplaced = 0
        bounds: list[tuple[float, float, float, float]] = []
        tiles: Counter[bytes] = Counter()
        with open(self.files["samples"], "wb") as samples, open(self.files["rejected"], "wb") as rejected:
            for slot in range(slots):
                outcome = self._outcome(slot)
                for r in outcome.rejected:
                    self.rejected_by_reason[r.reason] += 1
                    self.osm_unplaced += r.osm_unplaced or 0
                    self._add(rejected, "rejected", replace(r, slot=slot).to_json())
                if outcome.sample is not None:
                    sample = outcome.sample
                    box = sample.bounds()
                    if box is None:
                        raise DatasetError(f"slot {slot} of {self.state.root.parent} records no bounds_3857: delete "
                                           "its record and run the same build command again")
                    bounds.append(box)
                    tiles[hashlib.blake2b("/".join(t.quadkey for t in sample.tiles).encode(),
                                          digest_size=16).digest()] += 1
                    self.osm_unplaced += sample.osm_unplaced or 0
                    self._add(samples, "samples", sample.to_json())
        self.groups = np.asarray(overlap_groups(bounds), dtype=np.int64)
        sizes = Counter(self.groups.tolist())
        self.duplicate_samples = sum(n - 1 for n in tiles.values())
        self.overlapping_samples = sum(1 for g in self.groups.tolist() if sizes[g] > 1)
        self.overlap_group_count = len(sizes)

    def _outcome(self, slot: int) -> SlotOutcome:
        outcome = self.state.slot(slot)
        if outcome is None:
            raise DatasetError(f"slot {slot} of {self.state.root.parent} has no outcome yet: run the same build "
                               "command again to finish it")
        return outcome

    def _add(self, file: IO[bytes], kind: str, entry: Mapping[str, Json]) -> None:
        self.offsets[kind].append(file.tell())
        file.write(json.dumps(entry, ensure_ascii=False).encode("utf-8") + b"\n")

    def entries(self, kind: str) -> Iterator[JsonObject]:
        """The entries of ``kind`` ("samples" or "rejected"), in slot order, as JSON objects."""
        with open(self.files[kind], "rb") as f:
            for line in f:
                yield json.loads(line)

    def entry(self, kind: str, i: int) -> JsonObject:
        with open(self.files[kind], "rb") as f:
            f.seek(self.offsets[kind][i])
            return dict(json.loads(f.readline()))

    def __enter__(self) -> SlotRecords:
        return self

    def __exit__(self, *exc: object) -> None:
        self._folder.cleanup()


_Record = TypeVar("_Record", SampleRecord, RejectionRecord)


class _Entries(Sequence[_Record], Generic[_Record]):
    """A manifest list (samples or rejections) read from :class:`SlotRecords` as it is iterated,
    a typed record at a time."""

    kind = ""

    def __init__(self, records: SlotRecords) -> None:
        self.records = records

    def __len__(self) -> int:
        return len(self.records.offsets[self.kind])

    def _record(self, entry: JsonObject, i: int) -> _Record:
        raise NotImplementedError

    @overload
    def __getitem__(self, index: int) -> _Record: ...
    @overload
    def __getitem__(self, index: slice) -> list[_Record]: ...
    def __getitem__(self, index: int | slice) -> _Record | list[_Record]:
        if isinstance(index, slice):
            return [self[i] for i in range(len(self))[index]]
        i = range(len(self))[index]
        return self._record(self.records.entry(self.kind, i), i)

    def __iter__(self) -> Iterator[_Record]:
        for i, entry in enumerate(self.records.entries(self.kind)):
            yield self._record(entry, i)


class SampleEntries(_Entries[SampleRecord]):
    """The manifest's ``samples``, each with its ``overlap_group``."""

    kind = "samples"

    def _record(self, entry: JsonObject, i: int) -> SampleRecord:
        where = f"{self.records.state.root} sample {i}"
        return replace(SampleRecord.from_json(entry, where), overlap_group=int(self.records.groups[i]))


class RejectionEntries(_Entries[RejectionRecord]):
    """The manifest's ``rejected``: every rejected attempt, slot by slot, with its slot."""

    kind = "rejected"

    def _record(self, entry: JsonObject, i: int) -> RejectionRecord:
        return RejectionRecord.from_json(entry, f"{self.records.state.root} rejected attempt {i}")


def finalize(
    config: BuildConfig,
    table: ClassTable,
    state: BuildState,
    imagery_info: Mapping[str, Json],
    osm_info: Mapping[str, Json],
    command_line: str,
) -> DatasetSummary:
    """Write manifest, datasheet, attribution, STAC, pictures (and zip) from the finished slots.

    Returns the manifest's ``summary``. Every slot of the build must have its outcome recorded.
    """
    with SlotRecords(state, config.samples) as records:
        return _write_dataset_files(config, table, state, records, imagery_info, osm_info, command_line)


def _write_dataset_files(config: BuildConfig, table: ClassTable, state: BuildState, records: SlotRecords,
                         imagery_info: Mapping[str, Json], osm_info: Mapping[str, Json],
                         command_line: str) -> DatasetSummary:
    samples, rejected = SampleEntries(records), RejectionEntries(records)
    area = config.area
    counts = summary_entry(samples, rejected, requested=config.samples, max_attempts=config.samples * config.max_tries)
    # slots draw independently (that is what makes shards exact), so two may land on one grid, or
    # overlap: groups of overlapping samples are recorded, and training keeps a group in one split
    summary = replace(counts, duplicate_samples=records.duplicate_samples,
                      overlapping_samples=records.overlapping_samples, overlap_groups=records.overlap_group_count,
                      osm_unplaced=records.osm_unplaced)
    manifest = DatasetManifest(
        format_version=FORMAT_VERSION, tool=ToolInfo("osmseg", __version__), command=command_line, seed=config.seed,
        area=AreaRecord(name=area.name, kind=area.kind, lat=area.lat, lon=area.lon, radius_km=area.radius_km,
                        bbox=tuple(area.bbox) if area.bbox else None),
        zoom=config.zoom, grid_size=config.grid_size, image_format=config.image_format,
        config=config_entry(config.identity()), classes=table, filters=config.filters.to_dict(),
        imagery=Provenance(imagery_info), osm=Provenance(osm_info), samples=samples, rejected=rejected,
        summary=summary)
    write_datasheet(config.out_dir, manifest)
    write_attribution(config.out_dir, manifest)
    write_stac(config.out_dir, manifest)
    write_overview(config.out_dir, samples, table, kept=state.thumbnails)
    write_class_histogram(config.out_dir, class_totals(samples), table)
    write_manifest(config.out_dir, manifest)  # last: a manifest says the dataset is complete
    if config.zip:
        out = config.out_dir.resolve()
        make_zip(config.out_dir, out.parent / f"{out.name}.zip")
    return summary
