"""Where a source keeps the OSM data of a box on disk: names, validated downloads, done-markers.

Every OSM source (:mod:`.api`, :mod:`.overpass`, :mod:`.localfile`, :mod:`.geojson`) writes the
files of a box into its work folder under a deterministic name (:func:`cache_name`), validates
downloaded XML with osmium before keeping it (:func:`store_osm_xml`), and writes a JSON
"done" marker after the files (atomically, last: :func:`write_done`), which is what makes a
rerun reuse them (:func:`read_done`). Also the data's timestamp and extent of a local file
(:func:`osm_file_timestamp`, :func:`osm_file_extent`). Imports: osmseg core below it (errors, grid, osm.base, output.atomic).
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import osmium

from osmseg.errors import ConfigError, OSMDataError, first_line
from osmseg.grid import LngLatBBox
from osmseg.osm.base import OsmExtract
from osmseg.output.atomic import atomic_path, atomic_write_text

#: Attribution required by the ODbL for any OSM-derived data.
OSM_ATTRIBUTION = "© OpenStreetMap contributors, ODbL 1.0 (https://www.openstreetmap.org/copyright)"


def bbox_label(bbox: LngLatBBox) -> str:
    """Deterministic, file-name-safe text for a box (7 decimals, OSM's coordinate precision).

    >>> bbox_label(LngLatBBox(13.4, 52.5, 13.41, -0.5))
    '13.4000000_52.5000000_13.4100000_-0.5000000'
    """
    return "_".join(f"{v:.7f}" for v in bbox)


def cache_name(kind: str, bbox: LngLatBBox, *identity: str) -> str:
    """File stem for ``kind``'s data for ``bbox`` from a source identified by ``identity``.

    The digest keeps two sources (another URL, another query, another input file) that share
    a work folder apart; the readable box keeps the folder browsable.

    >>> cache_name("api", LngLatBBox(0, 0, 1, 1), "https://api.openstreetmap.org/api/0.6")[:42]
    'api_0.0000000_0.0000000_1.0000000_1.000000'
    """
    digest = hashlib.sha256("\n".join((kind, bbox_label(bbox), *identity)).encode()).hexdigest()[:10]
    return f"{kind}_{bbox_label(bbox)}_{digest}"


def bbox_contains(outer: LngLatBBox, inner: LngLatBBox) -> bool:
    """True if ``inner`` lies within ``outer`` (edges included).

    >>> bbox_contains(LngLatBBox(0, 0, 2, 2), LngLatBBox(0, 0.5, 1, 2)), bbox_contains(LngLatBBox(0, 0, 1, 1), LngLatBBox(0, 0, 2, 1))
    (True, False)
    """
    return outer.west <= inner.west and outer.south <= inner.south and inner.east <= outer.east and inner.north <= outer.north


def check_bbox(bbox: LngLatBBox) -> LngLatBBox:
    """``bbox`` as a LngLatBBox of floats, or ConfigError if it is empty or off the globe."""
    try:
        box = LngLatBBox(*(float(v) for v in bbox))
    except (TypeError, ValueError):
        raise ConfigError(f"bounding box must be four numbers west,south,east,north, got {bbox!r}") from None
    if not (-180 <= box.west < box.east <= 180 and -90 <= box.south < box.north <= 90):
        raise ConfigError(f"bounding box {tuple(box)} must have -180 <= west < east <= 180 and -90 <= south < north <= 90")
    return box


def iso_utc(moment: datetime) -> str:
    """ISO 8601 UTC with a ``Z`` and whole seconds, as OSM writes timestamps.

    >>> iso_utc(datetime(2024, 5, 1, 12, 0, 30, 999, tzinfo=timezone.utc))
    '2024-05-01T12:00:30Z'
    """
    return moment.astimezone(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


@dataclass
class OsmScan:
    """What one pass over an OSM file found (used to validate downloads and find relations).

    Attributes:
        counts: number of nodes, ways, relations.
        way_ids: ids of the ways in the file.
        multipolygons: for each ``type=multipolygon`` relation, the ids of its member ways.
        newest: the newest element timestamp (ISO 8601), None when the file has none.
    """

    counts: dict[str, int] = field(default_factory=lambda: {"n": 0, "w": 0, "r": 0})
    way_ids: set[int] = field(default_factory=set)
    multipolygons: dict[int, tuple[int, ...]] = field(default_factory=dict)
    newest: str | None = None


def scan_osm(path: Path, origin: str, advice: str, fmt: str = "") -> OsmScan:
    """Read ``path`` with osmium once, or raise a one-line OSMDataError if it is not OSM data.

    The message reads "``origin`` is not valid OSM data (osmium's reason); ``advice``", e.g.
    origin "the OSM API answer to map?bbox=..." and advice "run the same command again".
    ``fmt`` is osmium's format name ("osm", "pbf") when the file name does not say it.
    """
    scan = OsmScan()
    newest = None
    try:
        # nodes, ways and relations only: a <changeset> in an XML file is not map data
        for obj in osmium.FileProcessor(osmium.io.File(str(path), fmt), osmium.osm.NODE | osmium.osm.WAY
                                        | osmium.osm.RELATION):
            if isinstance(obj, osmium.osm.Changeset):  # never, given the entities asked for
                continue
            scan.counts[obj.type_str()] += 1
            ts = obj.timestamp
            if ts.year > 1970 and (newest is None or ts > newest):
                newest = ts
            if isinstance(obj, osmium.osm.Way):
                scan.way_ids.add(obj.id)
            elif isinstance(obj, osmium.osm.Relation) and obj.tags.get("type") == "multipolygon":
                scan.multipolygons[obj.id] = tuple(m.ref for m in obj.members if m.type == "w")
    except RuntimeError as exc:
        raise OSMDataError(f"{origin} is not valid OSM data ({first_line(exc)}); {advice}") from None
    scan.newest = iso_utc(newest) if newest is not None else None
    return scan


def store_osm_xml(data: bytes, path: Path, origin: str, advice: str) -> OsmScan:
    """Write downloaded OSM XML to ``path`` only if osmium reads it (temp file, then os.replace).

    Raises the one-line OSMDataError of :func:`scan_osm` (and writes nothing) otherwise.
    """
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
        scan = scan_osm(tmp, origin, advice, fmt="osm")
    return scan




def read_done(marker: Path) -> OsmExtract | None:
    """The extract recorded by a done-marker JSON, if it and all its files exist."""
    try:
        raw = json.loads(marker.read_text(encoding="utf-8"))
        paths = tuple(marker.parent / p for p in raw["paths"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not all(p.exists() for p in paths):
        return None
    return OsmExtract(paths=paths, timestamp=raw.get("timestamp"), info=raw.get("info", {}))


def write_done(marker: Path, extract: OsmExtract) -> OsmExtract:
    """Record ``extract`` in ``marker`` (atomically, after its files): a rerun reuses it."""
    record = {
        "paths": [str(p.relative_to(marker.parent)) for p in extract.paths],
        "timestamp": extract.timestamp,
        "info": extract.info,
    }
    atomic_write_text(marker, json.dumps(record, indent=1, sort_keys=True) + "\n")
    return extract


#: Where :func:`osm_file_extent` found a file's box when its header has none.
NODE_EXTENT = "the extent of its nodes"


def osm_file_extent(path: Path) -> tuple[LngLatBBox | None, str]:
    """The lon/lat box an OSM file covers and where that came from: the bounding box in its header
    (``<bounds>``, a PBF header's box: extract tools write one), else the extent of its located
    nodes (:data:`NODE_EXTENT`, one pass over the file). None for a file without a located node."""
    try:
        with osmium.io.Reader(str(path), osmium.osm.NOTHING) as reader:
            box = reader.header().box()
        if box.valid():
            return LngLatBBox(box.bottom_left.lon, box.bottom_left.lat, box.top_right.lon,
                              box.top_right.lat), "its header's bounds"
        west = south = math.inf
        east = north = -math.inf
        for node in osmium.FileProcessor(str(path), osmium.osm.NODE):
            if not isinstance(node, osmium.osm.Node):  # never: the processor reads nodes only
                continue
            loc = node.location
            if loc.valid():
                west, east = min(west, loc.lon), max(east, loc.lon)
                south, north = min(south, loc.lat), max(north, loc.lat)
    except RuntimeError as exc:
        raise OSMDataError(f"--osm {path}: cannot read it as OSM data ({first_line(exc)}); "
                           "give a valid .osm/.osm.pbf/.osm.bz2 file") from None
    return (LngLatBBox(west, south, east, north) if west <= east else None), NODE_EXTENT


def osm_file_timestamp(path: Path) -> tuple[str | None, str]:
    """The data timestamp of an OSM file and where it came from.

    The replication timestamp in the file header (``osmosis_replication_timestamp``, set by
    Geofabrik, planet and osmium extracts) is the state of OSM the file reflects. Files
    without one (JOSM saves, hand-made or old extracts) get the time of their newest edited
    element ("newest element"): the data is at least that new, and a copy's modification time
    would say nothing about the data. Only a file whose elements carry no timestamps at all
    gets its modification time, marked as such.
    """
    try:
        with osmium.io.Reader(str(path), osmium.osm.NOTHING) as reader:
            header = reader.header()
            stamp = header.get("osmosis_replication_timestamp", "") or header.get("timestamp", "")
    except RuntimeError as exc:
        raise OSMDataError(f"--osm {path}: cannot read the file header ({first_line(exc)}); is it an OSM file?") from None
    if stamp:
        return stamp, "file header"
    newest = scan_osm(path, f"--osm {path}", "give a valid .osm/.osm.pbf file").newest
    if newest is not None:
        return newest, "newest element"
    return iso_utc(datetime.fromtimestamp(path.stat().st_mtime, tz=timezone.utc)), "file modification time"
