"""A finished build's dataset-level files, written from its slot records without holding them all.

When every slot of a build has an outcome, :func:`finalize` writes ``manifest.json``,
``DATASHEET.md``, ``ATTRIBUTION.md``, the STAC catalog, ``overview.png`` and
``class_histogram.png`` (and the zip). A dataset of tens of thousands of samples has a
manifest of tens of megabytes; to keep the builder's memory flat, the samples and rejections
are never all in memory at once: :class:`SlotRecords` reads the slot records of the build
state once to index them (a few numbers per sample: where its entry is, its bounds, its tile
key), and the writers then iterate :class:`SampleEntries` / :class:`RejectionEntries`, lazy
sequences that read each entry from its record as they go. The manifest is written in pieces
(:func:`osmseg.output.manifest.write_manifest`) with exactly the bytes one ``json.dumps``
would give. Imports: osmseg core below it (output, state, records, sampling).
"""

from __future__ import annotations

import hashlib
from collections import Counter
from collections.abc import Iterator, Sequence
from typing import Any, overload

import numpy as np

from osmseg import __version__
from osmseg.buildconfig import BuildConfig
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
from osmseg.output.manifest import FORMAT, FORMAT_VERSION, config_entry
from osmseg.output.stac import write_stac
from osmseg.records import SlotOutcome
from osmseg.sampling import overlap_groups
from osmseg.state import BuildState

__all__ = ["RejectionEntries", "SampleEntries", "SlotRecords", "finalize"]


class SlotRecords:
    """An index of a finished build's slot records: which slots hold a sample, how many rejections
    each has, each sample's bounds and tile key, and the counts the summary needs. Reading it is
    one pass over the records; it keeps a few numbers per slot, not the entries."""

    def __init__(self, state: BuildState, slots: int) -> None:
        self.state = state
        self.sample_slots: list[int] = []
        self.rejection_slots: list[tuple[int, int]] = []  # (slot, rejections of that slot)
        self.rejected_by_reason: Counter[str] = Counter()
        self.osm_unplaced = 0
        bounds: list[tuple[float, float, float, float]] = []
        tiles: Counter[bytes] = Counter()
        for slot in range(slots):
            outcome = self.outcome(slot)
            if outcome.rejected:
                self.rejection_slots.append((slot, len(outcome.rejected)))
            for r in outcome.rejected:
                self.rejected_by_reason[str(r["reason"])] += 1
                self.osm_unplaced += int(r.get("osm_unplaced", 0))
            if outcome.sample is not None:
                sample = outcome.sample
                self.sample_slots.append(slot)
                left, bottom, right, top = (float(v) for v in sample["bounds_3857"])
                bounds.append((left, bottom, right, top))
                tiles[hashlib.blake2b("/".join(t["quadkey"] for t in sample["tiles"]).encode(),
                                      digest_size=16).digest()] += 1
                self.osm_unplaced += int(sample.get("osm_unplaced", 0))
        self.groups = np.asarray(overlap_groups(bounds), dtype=np.int64)
        sizes = Counter(self.groups.tolist())
        self.duplicate_samples = sum(n - 1 for n in tiles.values())
        self.overlapping_samples = sum(1 for g in self.groups.tolist() if sizes[g] > 1)
        self.overlap_group_count = len(sizes)
        self.rejected_count = sum(n for _, n in self.rejection_slots)

    def outcome(self, slot: int) -> SlotOutcome:
        outcome = self.state.slot(slot)
        if outcome is None:
            raise DatasetError(f"slot {slot} of {self.state.root.parent} has no outcome yet: run the same build "
                               "command again to finish it")
        return outcome


class SampleEntries(Sequence[dict[str, Any]]):
    """The manifest's ``samples``, read from the slot records as they are iterated (with each
    sample's ``overlap_group``)."""

    def __init__(self, records: SlotRecords) -> None:
        self.records = records

    def __len__(self) -> int:
        return len(self.records.sample_slots)

    def _entry(self, i: int) -> dict[str, Any]:
        sample = self.records.outcome(self.records.sample_slots[i]).sample
        assert sample is not None
        return {**sample, "overlap_group": int(self.records.groups[i])}

    @overload
    def __getitem__(self, index: int) -> dict[str, Any]: ...
    @overload
    def __getitem__(self, index: slice) -> list[dict[str, Any]]: ...
    def __getitem__(self, index: int | slice) -> dict[str, Any] | list[dict[str, Any]]:
        if isinstance(index, slice):
            return [self._entry(i) for i in range(len(self))[index]]
        return self._entry(range(len(self))[index])

    def __iter__(self) -> Iterator[dict[str, Any]]:
        for i in range(len(self)):
            yield self._entry(i)


class RejectionEntries(Sequence[dict[str, Any]]):
    """The manifest's ``rejected``: every rejected attempt, slot by slot, read as iterated."""

    def __init__(self, records: SlotRecords) -> None:
        self.records = records

    def __len__(self) -> int:
        return self.records.rejected_count

    @overload
    def __getitem__(self, index: int) -> dict[str, Any]: ...
    @overload
    def __getitem__(self, index: slice) -> list[dict[str, Any]]: ...
    def __getitem__(self, index: int | slice) -> dict[str, Any] | list[dict[str, Any]]:
        if isinstance(index, slice):
            wanted = set(range(len(self))[index])
            return [r for i, r in enumerate(self) if i in wanted]
        i = range(len(self))[index]
        for slot, n in self.records.rejection_slots:
            if i < n:
                return dict(self.records.outcome(slot).rejected[i], slot=slot)
            i -= n
        raise IndexError(index)

    def __iter__(self) -> Iterator[dict[str, Any]]:
        for slot, _ in self.records.rejection_slots:
            for r in self.records.outcome(slot).rejected:
                yield dict(r, slot=slot)


def finalize(
    config: BuildConfig,
    table: ClassTable,
    state: BuildState,
    imagery_info: dict[str, Any],
    osm_info: dict[str, Any],
    command_line: str,
) -> dict[str, Any]:
    """Write manifest, datasheet, attribution, STAC, pictures (and zip) from the finished slots.

    Returns the manifest's ``summary``. Every slot of the build must have its outcome recorded.
    """
    records = SlotRecords(state, config.samples)
    samples, rejected = SampleEntries(records), RejectionEntries(records)
    area = config.area
    summary = summary_entry(samples, rejected, requested=config.samples, max_attempts=config.samples * config.max_tries)
    # slots draw independently (that is what makes shards exact), so two may land on one grid, or
    # overlap: groups of overlapping samples are recorded, and training keeps a group in one split
    summary.update(
        duplicate_samples=records.duplicate_samples,
        overlapping_samples=records.overlapping_samples,
        overlap_groups=records.overlap_group_count,
        osm_unplaced=records.osm_unplaced,
    )
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
