"""The OSM source interface: give a box, get back an OSM file covering it.

Every source (OSM API, Overpass, a local .osm/.osm.pbf, GeoJSON) ends in the same place: an
OSM file on disk that :mod:`osmseg.osm.features` parses with osmium. One parser for all
sources is what makes "the same OSM content reached three ways gives identical masks" true.

Contract for ``fetch(bbox)``: the returned file contains every way with at least one node in
``bbox`` together with all of that way's nodes, every node in ``bbox``, and every multipolygon
relation with a member way in that set together with all of its member ways and their nodes.
Callers pass a box padded beyond the sample (``osmseg.grid.pad_bbox``) so features that merely
cross the sample edge are complete too.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from osmseg.grid import LngLatBBox


@dataclass(frozen=True)
class OsmExtract:
    """OSM data for one box.

    Attributes:
        paths: OSM files (XML ``.osm`` or ``.osm.pbf``) that together cover the box; several
            when a service needed the box split. The parser merges them and drops duplicates.
        timestamp: the data's replication timestamp (ISO 8601) when the source reports one.
        info: JSON-able provenance for the manifest (source, URL without keys, box, parts).
    """

    paths: tuple[Path, ...]
    timestamp: str | None = None
    info: dict[str, Any] = field(default_factory=dict)


class OsmSource(Protocol):
    """What the builder needs from an OSM source."""

    name: str
    attribution: str

    def fetch(self, bbox: LngLatBBox) -> OsmExtract:
        """OSM data covering ``bbox``. Raises ``OSMDataError`` or ``NetworkError``."""
        ...

    def describe(self) -> dict[str, Any]:
        """JSON-able description for the manifest."""
        ...


@runtime_checkable
class CoveringSource(Protocol):
    """An OSM source that can say, before a build writes anything, whether it holds any data over
    the sampling area (a local file of another place would give every sample an empty mask)."""

    def check_covers(self, west: float, south: float, east: float, north: float) -> None:
        """ConfigError when the source holds nothing over the box (lon/lat degrees)."""
        ...


@runtime_checkable
class RegionSource(Protocol):
    """An OSM source read from one large local file: it cuts a region file for a build's area once,
    then the extracts of many sample boxes in a few passes (:mod:`osmseg.osm.cut`)."""

    def prepare(self, bboxes: Sequence[LngLatBBox]) -> Path:
        """Cut (or find, when cut already) the region file that holds everything ``bboxes`` need."""
        ...

    def cut(self, bboxes: Iterable[LngLatBBox], batch: int = ...) -> list[OsmExtract]:
        """The extracts of many boxes at once: for each box, what ``fetch`` would write."""
        ...
