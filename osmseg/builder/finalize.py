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
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import IO, Any, overload

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
from osmseg.output.manifest import FORMAT, FORMAT_VERSION, Summary, config_entry
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
                    self.rejected_by_reason[str(r["reason"])] += 1
                    self.osm_unplaced += int(r.get("osm_unplaced", 0))
                    self._add(rejected, "rejected", dict(r, slot=slot))
                if outcome.sample is not None:
                    sample = outcome.sample
                    left, bottom, right, top = (float(v) for v in sample["bounds_3857"])
                    bounds.append((left, bottom, right, top))
                    tiles[hashlib.blake2b("/".join(t["quadkey"] for t in sample["tiles"]).encode(),
                                          digest_size=16).digest()] += 1
                    self.osm_unplaced += int(sample.get("osm_unplaced", 0))
                    self._add(samples, "samples", sample)
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

    def _add(self, file: IO[bytes], kind: str, entry: dict[str, Any]) -> None:
        self.offsets[kind].append(file.tell())
        file.write(json.dumps(entry, ensure_ascii=False).encode("utf-8") + b"\n")

    def entries(self, kind: str) -> Iterator[dict[str, Any]]:
        """The entries of ``kind`` ("samples" or "rejected"), in slot order."""
        with open(self.files[kind], "rb") as f:
            for line in f:
                yield json.loads(line)

    def entry(self, kind: str, i: int) -> dict[str, Any]:
        with open(self.files[kind], "rb") as f:
            f.seek(self.offsets[kind][i])
            return dict(json.loads(f.readline()))

    def __enter__(self) -> SlotRecords:
        return self

    def __exit__(self, *exc: object) -> None:
        self._folder.cleanup()


class _Entries(Sequence[dict[str, Any]]):
    """A manifest list (samples or rejections) read from :class:`SlotRecords` as it is iterated."""

    kind = ""

    def __init__(self, records: SlotRecords) -> None:
        self.records = records

    def __len__(self) -> int:
        return len(self.records.offsets[self.kind])

    def _entry(self, i: int) -> dict[str, Any]:
        return self.records.entry(self.kind, i)

    @overload
    def __getitem__(self, index: int) -> dict[str, Any]: ...
    @overload
    def __getitem__(self, index: slice) -> list[dict[str, Any]]: ...
    def __getitem__(self, index: int | slice) -> dict[str, Any] | list[dict[str, Any]]:
        if isinstance(index, slice):
            return [self._entry(i) for i in range(len(self))[index]]
        return self._entry(range(len(self))[index])

    def __iter__(self) -> Iterator[dict[str, Any]]:
        return self.records.entries(self.kind)


class SampleEntries(_Entries):
    """The manifest's ``samples``, each with its ``overlap_group``."""

    kind = "samples"

    def _entry(self, i: int) -> dict[str, Any]:
        return {**self.records.entry(self.kind, i), "overlap_group": int(self.records.groups[i])}

    def __iter__(self) -> Iterator[dict[str, Any]]:
        for sample, group in zip(self.records.entries(self.kind), self.records.groups.tolist()):
            yield {**sample, "overlap_group": group}


class RejectionEntries(_Entries):
    """The manifest's ``rejected``: every rejected attempt, slot by slot, with its slot."""

    kind = "rejected"


def finalize(
    config: BuildConfig,
    table: ClassTable,
    state: BuildState,
    imagery_info: dict[str, Any],
    osm_info: dict[str, Any],
    command_line: str,
) -> Summary:
    """Write manifest, datasheet, attribution, STAC, pictures (and zip) from the finished slots.

    Returns the manifest's ``summary``. Every slot of the build must have its outcome recorded.
    """
    with SlotRecords(state, config.samples) as records:
        return _write_dataset_files(config, table, state, records, imagery_info, osm_info, command_line)


def _write_dataset_files(config: BuildConfig, table: ClassTable, state: BuildState, records: SlotRecords,
                         imagery_info: dict[str, Any], osm_info: dict[str, Any], command_line: str) -> Summary:
    samples, rejected = SampleEntries(records), RejectionEntries(records)
    area = config.area
    counts = summary_entry(samples, rejected, requested=config.samples, max_attempts=config.samples * config.max_tries)
    # slots draw independently (that is what makes shards exact), so two may land on one grid, or
    # overlap: groups of overlapping samples are recorded, and training keeps a group in one split
    summary: Summary = {
        **counts,
        "duplicate_samples": records.duplicate_samples,
        "overlapping_samples": records.overlapping_samples,
        "overlap_groups": records.overlap_group_count,
        "osm_unplaced": records.osm_unplaced,
    }
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
        "summary": summary,
    }
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
