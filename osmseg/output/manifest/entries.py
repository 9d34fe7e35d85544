"""What a build records in the manifest, made from what it did: a sample's entry from its grid
and files, a rejected attempt's, the summary's counts, the command line without its secrets
(:func:`osmseg.redact.command_line`).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import mercantile

from osmseg.grid import SampleGrid
from osmseg.output.manifest.dataset import TOP_LEVEL_SETTINGS, DatasetSummary
from osmseg.output.manifest.samples import Point, Provenance, RejectionRecord, SampleRecord, TileRecord
from osmseg.output.manifest.values import Json, JsonObject
from osmseg.output.writer import WrittenSample
from osmseg.redact import command_line

__all__ = ["REASONS", "Rejection", "class_totals", "command_line", "config_entry", "rejection_entry", "sample_entry",
           "summary_entry", "tile_entry"]

#: Why the builder rejects a sample, in the order its filters check (:mod:`osmseg.builder.filters`):
#: the manifest lists the rejected attempts by these reasons.
REASONS: tuple[str, ...] = ("unlabeled", "single_class", "placeholder_imagery", "missing_imagery", "low_contrast")


@dataclass(frozen=True)
class Rejection:
    """Why a sample was rejected: a machine ``reason`` (one of :data:`REASONS`) and a human ``detail``."""

    reason: str
    detail: str


def tile_entry(tile: mercantile.Tile) -> TileRecord:
    """A tile as the manifest lists it.

    >>> tile_entry(mercantile.Tile(3, 5, 3)).to_json()
    {'z': 3, 'x': 3, 'y': 5, 'quadkey': '213'}
    """
    return TileRecord(z=tile.z, x=tile.x, y=tile.y, quadkey=mercantile.quadkey(tile))


def sample_entry(
    name: str,
    grid: SampleGrid,
    written: WrittenSample,
    *,
    imagery: Mapping[str, Json],
    osm: Mapping[str, Json],
    osm_timestamp: str | None,
) -> SampleRecord:
    """The manifest entry of one accepted sample.

    Args:
        name: sample name (file stem).
        grid: the sample's grid (centre, tiles, bounds).
        written: what :func:`osmseg.output.writer.write_sample` returned.
        imagery: ``Imagery.info`` (provider provenance, no keys).
        osm: ``OsmExtract.info`` (source provenance, no keys).
        osm_timestamp: ``OsmExtract.timestamp`` (ISO 8601) or None when unknown.
    """
    return SampleRecord(
        name=name, center=Point(grid.lon, grid.lat), bbox_wgs84=tuple(grid.bbox), bounds_3857=tuple(grid.xy_bounds),
        zoom=grid.zoom, ground_resolution_m=grid.ground_resolution, tiles=tuple(tile_entry(t) for t in grid.tiles),
        imagery=Provenance(dict(imagery)), osm=Provenance({**osm, "timestamp": osm_timestamp}),
        class_histogram=dict(written.class_histogram), files=dict(written.files))


def rejection_entry(lon: float, lat: float, rejection: Rejection, attempt: int | None = None) -> RejectionRecord:
    """The manifest entry of one rejected attempt: centre, reason, detail (and attempt number).

    >>> rejection_entry(1.5, 2.0, Rejection("unlabeled", "80.0% unlabeled >= 70.0%"), attempt=4).reason
    'unlabeled'
    """
    return RejectionRecord(center=Point(lon, lat), reason=rejection.reason, detail=rejection.detail, attempt=attempt)


def summary_entry(samples: Sequence[SampleRecord], rejected: Iterable[RejectionRecord], *, requested: int,
                  max_attempts: int) -> DatasetSummary:
    """Counts for the manifest's ``summary``: accepted, rejected (total and by reason), attempts
    (the overlap counts are the finaliser's to add).

    >>> unlabeled = RejectionRecord(None, "unlabeled", "-")
    >>> summary_entry([], [unlabeled] * 2, requested=3, max_attempts=10).rejected_by_reason
    {'unlabeled': 2}
    """
    by_reason = Counter(r.reason for r in rejected)
    count = sum(by_reason.values())
    return DatasetSummary(
        requested=requested, accepted=len(samples), rejected=count, attempts=len(samples) + count,
        max_attempts=max_attempts, rejected_by_reason={k: by_reason[k] for k in sorted(by_reason, key=_reason_order)},
        complete=len(samples) >= requested)


def _reason_order(reason: str) -> tuple[int, str]:
    return (REASONS.index(reason) if reason in REASONS else len(REASONS), reason)


def class_totals(samples: Iterable[SampleRecord]) -> dict[str, int]:
    """Pixel count per class name summed over samples."""
    totals: Counter[str] = Counter()
    for s in samples:
        totals.update(s.class_histogram)
    return dict(totals)


def config_entry(identity: Mapping[str, Json]) -> JsonObject:
    """The manifest's ``config``: the build's identity less what the top level already says.

    >>> config_entry({"seed": 1, "zoom": 18, "samples": 4, "imagery": "bing"})
    {'samples': 4, 'imagery': 'bing'}
    """
    return {k: v for k, v in identity.items() if k not in TOP_LEVEL_SETTINGS}
