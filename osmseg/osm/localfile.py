"""Local OSM files (``.osm``, ``.osm.pbf``, ``.osm.bz2``) cut into small per-box extracts.

A local file is the way that scales to whole countries: no rate limits, no network, and a
Geofabrik country ``.osm.pbf`` carries its replication timestamp.  The file is read with
osmium in streaming passes (memory holds id sets, never the data), and for each box an
extract with the content :mod:`osmseg.osm.base` promises is written into the work folder as
``.osm.pbf``:

1. nodes in the box, and the locations of nodes within ``reach`` (1 km) around it;
2. ways with a node in the box, or with a segment crossing the box between two nodes
   within reach (a long straight road or coastline segment can cross a sample without a
   node in it: Overpass finds such ways, the API's map call does not);
3. ``type=multipolygon`` relations with one of those ways as member, with all their member
   ways and nodes;
4. all nodes of the ways kept;
5. everything kept, copied in file order.

The id sets are Python sets, sized by the extract.  ``osmium.IdTracker`` (and ``IdFilter``)
would run passes 2, 4 and 5 in C++, but their dense id sets allocate 512 KB per 4 million
ids of range: real node ids span ten billion, so even a city extract costs ~0.7 GB of RAM
and a second of page zeroing (measured on the Helsinki extract).  The node pass is Python
either way and dominates (~4 µs per node): a country file takes minutes, once, with
:meth:`LocalFileSource.prepare`.

Passes over the input are the same whatever the number of boxes: :meth:`LocalFileSource.prepare`
runs them once for all boxes of a build (or the sampling area as one box) and writes a
*region* file (small); every later :meth:`~LocalFileSource.fetch` of a box inside a prepared
box cuts from that region file instead of the country file.  The region is closed under
these rules (a box inside it gets the same extract from the region as from the country),
so preparing changes speed, never output.

A fetch still reads its region five times for its one box.  :meth:`LocalFileSource.cut`
makes the extracts and done-markers of many boxes at once, byte for byte what ``fetch``
makes for each (so later fetches only read the markers): one pass over the region collects
compact numpy arrays of its nodes, ways and multipolygons, numpy applies the rules above to
each box, and one write pass per batch of boxes (256, all their files open) hands every
object to the files of the boxes that keep it (:mod:`osmseg.osm.cut`).

Timestamp: the replication timestamp of the file header (``osmosis_replication_timestamp``:
Geofabrik, planet and ``osmium extract`` files have it); failing that the file's
modification time, recorded as such in ``info["timestamp_from"]``.

What no box-based source can see (API, Overpass or this): an area whose outline lies
entirely outside the padded box while the box lies inside it (a sample in the middle of a
huge forest or lake).  The builder pads boxes (``osmseg.grid.pad_bbox``) to make that rare;
``enclosing=True`` keeps those areas and the coastline near the box too
(:mod:`osmseg.osm.enclosing`), for a region search whose blocks must draw what the whole
file draws.

File names, done-markers and the input's timestamp come from :mod:`osmseg.osm.store`, which
every source shares.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import osmium

from osmseg.errors import ConfigError, OSMDataError, first_line
from osmseg.grid import LngLatBBox, pad_bbox
from osmseg.osm.base import OsmExtract
from osmseg.osm.cut import DEFAULT_BATCH, ensure_room, write_extracts
from osmseg.osm.enclosing import EnclosingRule
from osmseg.osm.josm import count_deleted, has_deletions, without_deleted
from osmseg.osm.store import (
    NODE_EXTENT,
    OSM_ATTRIBUTION,
    bbox_contains,
    bbox_label,
    cache_name,
    check_bbox,
    osm_file_extent,
    osm_file_timestamp,
    read_done,
    write_done,
)
from osmseg.output.atomic import atomic_path, atomic_write_text

logger = logging.getLogger(__name__)

#: Endings of the OSM files osmium reads (and that ``--osm PATH`` accepts).
OSM_SUFFIXES: tuple[str, ...] = (".osm.pbf", ".pbf", ".osm", ".osm.bz2", ".osm.gz", ".xml", ".osm.xml")
#: Metres around a box within which both ends of a way's segment must lie for the segment to
#: be found crossing the box without a node in it (longer segments are missed, as by the API).
DEFAULT_REACH = 1000.0


# -- extracting ------------------------------------------------------------------------------------


class BoxGrid:
    """Boxes bucketed in a grid of cells about one box in size, to find the boxes a point or a
    segment may touch without trying each: cutting a region for the first attempts of thousands
    of samples asks this of every node of a country's file.

    >>> grid = BoxGrid([LngLatBBox(0, 0, 1, 1), LngLatBBox(5, 5, 6, 6)])
    >>> grid.contains(0.5, 0.5), grid.contains(3, 3), grid.contains(6, 6)
    (True, False, True)
    """

    def __init__(self, boxes: Sequence[LngLatBBox]) -> None:
        self.boxes = list(boxes)
        self.width = max((b.east - b.west for b in self.boxes), default=1.0) or 1.0
        self.height = max((b.north - b.south for b in self.boxes), default=1.0) or 1.0
        self.cells: dict[tuple[int, int], list[LngLatBBox]] = {}
        for b in self.boxes:
            for cell in self._cells(b.west, b.south, b.east, b.north):
                self.cells.setdefault(cell, []).append(b)

    def _cells(self, west: float, south: float, east: float, north: float) -> Iterator[tuple[int, int]]:
        x0, x1 = math.floor(west / self.width), math.floor(east / self.width)
        y0, y1 = math.floor(south / self.height), math.floor(north / self.height)
        return ((x, y) for x in range(x0, x1 + 1) for y in range(y0, y1 + 1))

    def near(self, west: float, south: float, east: float, north: float) -> list[LngLatBBox]:
        """The boxes of the cells that the box west..east, south..north touches (a superset of those it meets)."""
        if len(self.cells) <= 8:  # a few boxes: all of them
            return self.boxes
        found: dict[int, LngLatBBox] = {}
        for cell in self._cells(west, south, east, north):
            for b in self.cells.get(cell, ()):
                found[id(b)] = b
        return list(found.values())

    def contains(self, lon: float, lat: float) -> bool:
        """True if a box holds the point (edges included)."""
        cell = (math.floor(lon / self.width), math.floor(lat / self.height))
        for b in self.cells.get(cell, ()) if len(self.boxes) > 8 else self.boxes:
            if b.west <= lon <= b.east and b.south <= lat <= b.north:
                return True
        return False


def write_extract(src: Path, boxes: Sequence[LngLatBBox], out: Path, reach: float = DEFAULT_REACH,
                  enclosing: bool = False, region: bool = False) -> dict[str, int]:
    """Write to ``out`` (``.osm.pbf``, atomically) the contract's content for the union of ``boxes``.

    Besides ways with a node in a box, ways with a *segment* crossing a box keep too when
    both ends of the segment lie within ``reach`` metres of it (see the module doc).
    ``enclosing``: also the areas holding a box and the coastline near one
    (:mod:`osmseg.osm.enclosing`; one more pass, over the relations, and node locations held
    by osmium's location index during the way pass); ``region``: ``out`` is a region later cut
    into boxes inside ``boxes`` (:class:`~osmseg.osm.enclosing.EnclosingRule`).
    Streams ``src`` five times whatever the number of boxes; memory holds ids, and the
    locations of the nodes within ``reach`` around the boxes.  The output keeps ``src``'s
    replication timestamp and object order.  Returns the numbers of nodes, ways and
    relations written.
    """
    if not boxes:
        raise ValueError("write_extract needs at least one box")
    src_name = str(src)
    envelope = union_boxes(boxes)
    grid = BoxGrid(boxes)
    try:
        keep_nodes, around = _nodes_near(src_name, boxes, reach)
        rule = EnclosingRule(boxes, region) if enclosing else None
        keep_ways, member_bounds = _ways_kept(src_name, keep_nodes, around, grid, rule)
        keep_relations: set[int] = set()
        member_ways: set[int] = set()
        for rel in osmium.FileProcessor(src_name, osmium.osm.RELATION):
            if not isinstance(rel, osmium.osm.Relation) or rel.tags.get("type") != "multipolygon":
                continue
            members = [(m.type, m.ref) for m in rel.members]
            if any(t == "w" and ref in keep_ways for t, ref in members) or (
                    rule is not None
                    and rule.encloses(rule.union(member_bounds.get(ref) for t, ref in members if t == "w"))):
                keep_relations.add(rel.id)
                member_ways.update(ref for t, ref in members if t == "w")
                keep_nodes.update(ref for t, ref in members if t == "n")
        keep_ways |= member_ways
        for way in osmium.FileProcessor(src_name, osmium.osm.WAY):
            if isinstance(way, osmium.osm.Way) and way.id in keep_ways:
                keep_nodes.update(nd.ref for nd in way.nodes)
        keep = {"n": keep_nodes, "w": keep_ways, "r": keep_relations}
        ensure_room(out.parent, sum(len(ids) for ids in keep.values()))
        header = _extract_header(src_name, envelope)
        with atomic_path(out) as tmp:
            counts = {"n": 0, "w": 0, "r": 0}
            with osmium.SimpleWriter(osmium.io.File(str(tmp), "pbf"), header=header, overwrite=True) as writer:
                for obj in osmium.FileProcessor(src_name, osmium.osm.NODE | osmium.osm.WAY | osmium.osm.RELATION):
                    kind = obj.type_str()
                    if obj.id in keep[kind]:
                        writer.add(obj)
                        counts[kind] += 1
    except RuntimeError as exc:
        raise OSMDataError(f"--osm {src}: cannot read it as OSM data ({first_line(exc)}); "
                           "give a valid .osm/.osm.pbf/.osm.bz2 file") from None
    return counts


def _ways_kept(src: str, keep_nodes: set[int], around: dict[int, tuple[float, float]], grid: BoxGrid,
               rule: EnclosingRule | None) -> tuple[set[int], dict[int, tuple[float, float, float, float] | None]]:
    """Ids of the ways with a node in a box or a segment crossing one, and with a ``rule``: of the
    ways meeting a box and the coastline near one, and the bounds of multipolygon members."""
    kept: set[int] = set()
    members: set[int] = set()
    ways = osmium.FileProcessor(src, osmium.osm.WAY)
    if rule is not None:
        for rel in osmium.FileProcessor(src, osmium.osm.RELATION):
            if isinstance(rel, osmium.osm.Relation) and rel.tags.get("type") == "multipolygon":
                members.update(m.ref for m in rel.members if m.type == "w")
        ways = (osmium.FileProcessor(src, osmium.osm.NODE | osmium.osm.WAY).with_locations()
                .with_filter(osmium.filter.EntityFilter(osmium.osm.WAY)))
    bounds: dict[int, tuple[float, float, float, float] | None] = {}
    for way in ways:
        if not isinstance(way, osmium.osm.Way):  # never: the processor hands ways only
            continue
        refs = [nd.ref for nd in way.nodes]
        if not keep_nodes.isdisjoint(refs) or (not around.keys().isdisjoint(refs) and _crosses(refs, around, grid)):
            kept.add(way.id)
        if rule is None:
            continue
        box = rule.bounds((nd.lon, nd.lat) for nd in way.nodes if nd.location.valid())
        if rule.meets(box) or (way.tags.get("natural") == "coastline" and rule.near_coast(box)):
            kept.add(way.id)
        if way.id in members:
            bounds[way.id] = box
    return kept, bounds


def _nodes_near(src: str, boxes: Sequence[LngLatBBox], reach: float) -> tuple[set[int], dict[int, tuple[float, float]]]:
    """Ids of the nodes inside one of ``boxes``, and locations of those outside but within ``reach`` m."""
    grown = [pad_bbox(b, reach) for b in boxes]
    in_boxes, in_grown = BoxGrid(boxes), BoxGrid(grown)
    w, s, e, n = union_boxes(grown)
    single = len(boxes) == 1
    inside: set[int] = set()
    around: dict[int, tuple[float, float]] = {}
    for node in osmium.FileProcessor(src, osmium.osm.NODE):
        if not isinstance(node, osmium.osm.Node):  # never: the processor reads nodes only
            continue
        loc = node.location
        if not loc.valid():
            continue
        lon, lat = loc.lon, loc.lat
        if not (w <= lon <= e and s <= lat <= n):
            continue
        if in_boxes.contains(lon, lat):
            inside.add(node.id)
        elif single or in_grown.contains(lon, lat):
            around[node.id] = (lon, lat)
    return inside, around


def _crosses(refs: list[int], around: dict[int, tuple[float, float]], boxes: BoxGrid) -> bool:
    """True if a segment between two consecutive located nodes of a way crosses one of ``boxes``."""
    for a, b in zip(refs, refs[1:]):
        p, q = around.get(a), around.get(b)
        if p is None or q is None:
            continue
        near = boxes.near(min(p[0], q[0]), min(p[1], q[1]), max(p[0], q[0]), max(p[1], q[1]))
        if any(segment_hits_box(p, q, box) for box in near):
            return True
    return False


def segment_hits_box(p: tuple[float, float], q: tuple[float, float], box: LngLatBBox) -> bool:
    """True if the straight segment p-q (lon, lat) meets ``box`` (Liang-Barsky clipping).

    >>> b = LngLatBBox(0, 0, 1, 1)
    >>> segment_hits_box((-1, 0.5), (2, 0.5), b), segment_hits_box((-1, 1.9), (1.9, -1), b)
    (True, True)
    >>> segment_hits_box((-1, 0.5), (0.5, 2), b), segment_hits_box((-1, -1), (-0.5, 3), b)
    (False, False)
    """
    (x0, y0), (x1, y1) = p, q
    dx, dy = x1 - x0, y1 - y0
    t0, t1 = 0.0, 1.0
    for step, gap in ((-dx, x0 - box.west), (dx, box.east - x0), (-dy, y0 - box.south), (dy, box.north - y0)):
        if step == 0:
            if gap < 0:
                return False
            continue
        t = gap / step
        if step < 0:
            t0 = max(t0, t)
        else:
            t1 = min(t1, t)
        if t0 > t1:
            return False
    return True


def _extract_header(src: str, envelope: LngLatBBox) -> osmium.io.Header:
    """A header for an extract of ``src``: its replication fields, the extract's box."""
    return _box_header(_header_fields(src), envelope)


def _header_fields(src: str) -> list[tuple[str, str]]:
    """The replication fields of ``src``'s header that extracts keep."""
    with osmium.io.Reader(src, osmium.osm.NOTHING) as reader:
        old = reader.header()
    return [(key, old.get(key, "")) for key in ("osmosis_replication_timestamp", "osmosis_replication_sequence_number",
                                                 "osmosis_replication_base_url", "timestamp") if old.get(key, "")]


def _box_header(fields: Sequence[tuple[str, str]], envelope: LngLatBBox) -> osmium.io.Header:
    """An extract header: generator, ``fields`` (see :func:`_header_fields`), the box."""
    header = osmium.io.Header()
    header.set("generator", "osmseg")
    for key, value in fields:
        header.set(key, value)
    header.add_box(osmium.osm.Box(osmium.osm.Location(envelope.west, envelope.south),
                                  osmium.osm.Location(envelope.east, envelope.north)))
    return header


class LocalFileSource:
    """OSM data cut from a local ``.osm`` / ``.osm.pbf`` / ``.osm.bz2`` file.

    Args:
        path: the OSM file (a city, a region, a whole country).
        workdir: folder for the extracts (created); files are named by box and by the input
            file's path, size and modification time, so a rerun reuses them and a changed
            input file is cut again.
        reach: metres around a box within which a way segment crossing it is found.
        enclosing: also keep the areas a box lies inside and the coastline near it
            (:mod:`osmseg.osm.enclosing`); its extracts get names of their own.
        extracts: folder for each box's own extract and its done-marker [``workdir``]: a caller
            that keeps what it makes of them elsewhere (a region search its drawn blocks) cuts
            them into a passing folder; the prepared region files, the input's extent and
            timestamp stay in ``workdir``, where a rerun finds them.
    """

    name = "file"
    attribution = OSM_ATTRIBUTION

    def __init__(self, path: Path, workdir: Path, reach: float = DEFAULT_REACH, enclosing: bool = False,
                 extracts: Path | None = None) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise ConfigError(f"--osm {self.path}: file not found; give an .osm/.osm.pbf path, 'api' or 'overpass'")
        self.workdir = Path(workdir)
        self.extracts = Path(extracts) if extracts is not None else self.workdir
        stat = self.path.stat()
        self.reach = float(reach)
        self.enclosing = enclosing
        self._identity = (str(self.path.resolve()), str(stat.st_size), str(stat.st_mtime_ns), f"reach={self.reach:g}",
                          *(("enclosing",) if enclosing else ()))
        self._timestamp: tuple[str | None, str] | None = None
        self._regions: list[tuple[tuple[LngLatBBox, ...], Path]] = []
        self._readable: Path | None = None
        self._extent: tuple[LngLatBBox | None, str] | None = None

    def readable(self) -> Path:
        """The file to cut from: the input, or (an XML file saved by JOSM with objects marked
        ``action="delete"``) a copy without them in the work folder (:mod:`osmseg.osm.josm`)."""
        if self._readable is None:
            self._readable = self.path
            if self.path.suffix.lower() in (".osm", ".xml") and has_deletions(self.path):
                digest = hashlib.sha256("\n".join(self._identity).encode()).hexdigest()[:16]
                kept = self.workdir / f"josm-live_{digest}.osm"
                if not kept.exists():
                    without_deleted(self.path, kept)
                logger.warning("--osm %s: %d objects are marked deleted (action=delete, a JOSM edit not uploaded): "
                               "left out, as in JOSM", self.path, count_deleted(self.path))
                self._readable = kept
        return self._readable

    def extent(self) -> tuple[LngLatBBox | None, str]:
        """The lon/lat box the file covers and where that came from (:func:`osm_file_extent`); a node
        extent that had to be read is kept in the work folder under the file's identity."""
        if self._extent is None:
            try:
                kept = json.loads(self._extent_file().read_text(encoding="utf-8"))
                self._extent = (LngLatBBox(*(float(v) for v in kept)), NODE_EXTENT)
            except (OSError, ValueError, TypeError):
                self._extent = osm_file_extent(self.path)
        return self._extent

    def _extent_file(self) -> Path:
        """Where the node extent of this input file (its path, size and time) is kept."""
        return self.workdir / f"extent_{hashlib.sha256(chr(10).join(self._identity).encode()).hexdigest()[:16]}.json"

    def _keep_extent(self) -> None:
        """Keep a node extent that had to be read (see :meth:`extent`) for the next process and run."""
        extent, origin = self.extent()
        kept = self._extent_file()
        if extent is not None and origin == NODE_EXTENT and not kept.exists():
            self.workdir.mkdir(parents=True, exist_ok=True)
            atomic_write_text(kept, json.dumps(list(extent)) + "\n")

    def check_covers(self, west: float, south: float, east: float, north: float, area: str = "the sampling area",
                     fix: str = "sample where the data is (--bbox/--lat/--lon)") -> None:
        """ConfigError when the file's extent (:meth:`extent`) misses the sampling area (lon/lat
        degrees) entirely: every sample would have an empty mask, so say it before the build.
        ``area`` names the box and ``fix`` says what to change in another command's words (a
        region search's: ``osmseg localize --osm FILE --bbox``)."""
        extent, origin = self.extent()
        if extent is None:
            raise ConfigError(f"--osm {self.path} holds no node with a location: give an OSM file with data "
                              f"of {area}")
        if extent.east < west or extent.west > east or extent.north < south or extent.south > north:
            raise ConfigError(
                f"--osm {self.path} covers lon {extent.west:.5f}..{extent.east:.5f}, lat {extent.south:.5f}.."
                f"{extent.north:.5f} ({origin}), which misses {area} (lon {west:.5f}..{east:.5f}, "
                f"lat {south:.5f}..{north:.5f}): {fix}, or give the OSM file of this area")
        self._keep_extent()  # only once it served: a refused command writes nothing

    def timestamp(self) -> tuple[str | None, str]:
        """The input file's data timestamp and its origin (see :func:`osm_file_timestamp`).

        Kept in the work folder under the file's identity: a file without a header timestamp is
        read whole to find its newest element, which every worker process and every rerun would
        otherwise do again.
        """
        if self._timestamp is None:
            digest = hashlib.sha256("\n".join(self._identity).encode()).hexdigest()[:16]
            kept = self.workdir / f"timestamp_{digest}.json"
            try:
                stamp, origin = json.loads(kept.read_text(encoding="utf-8"))
                self._timestamp = (None if stamp is None else str(stamp), str(origin))
            except (OSError, ValueError, TypeError):
                self._timestamp = osm_file_timestamp(self.path)
                self.workdir.mkdir(parents=True, exist_ok=True)
                atomic_write_text(kept, json.dumps(list(self._timestamp)) + "\n")
        return self._timestamp

    def prepare(self, bboxes: Sequence[LngLatBBox]) -> Path:
        """Cut one region file holding everything the ``bboxes`` need, in one set of passes.

        Call it with all boxes a build may fetch (or the sampling area as one box) before
        fetching: later fetches of a box inside any of them read the small region file, not
        the big input. Returns the region file (reused when it already exists).
        """
        boxes = tuple(sorted(check_bbox(b) for b in bboxes))
        if not boxes:
            raise ValueError("prepare needs at least one box")
        self.timestamp()  # read the input's header now: fetches then need only the region
        digest = hashlib.sha256("\n".join((*self._identity, *map(bbox_label, boxes))).encode()).hexdigest()[:16]
        region = self.workdir / f"region_{len(boxes)}boxes_{digest}.osm.pbf"
        if not region.exists():
            self.workdir.mkdir(parents=True, exist_ok=True)
            counts = write_extract(self.readable(), boxes, region, self.reach, self.enclosing, region=True)
            logger.info("cut %s from %s for %d boxes: %s", region.name, self.path, len(boxes), counts)
        if all(r != region for _, r in self._regions):
            self._regions.append((boxes, region))
        return region

    def fetch(self, bbox: LngLatBBox) -> OsmExtract:
        """An ``.osm.pbf`` extract for ``bbox`` (see the module doc); reused when already cut."""
        bbox = check_bbox(bbox)
        marker, out = self._names(bbox)
        done = read_done(marker)
        if done is not None:
            return done
        self.extracts.mkdir(parents=True, exist_ok=True)
        counts = write_extract(self._source_for(bbox), [bbox], out, self.reach, self.enclosing)
        return self._record(bbox, marker, out, counts)

    def cut(self, bboxes: Iterable[LngLatBBox], batch: int = DEFAULT_BATCH) -> list[OsmExtract]:
        """Cut the extracts of many boxes at once: for each box, what :meth:`fetch` would write.

        Each box is cut from the file :meth:`fetch` would use (a prepared region holding it,
        else the input), and gets the same ``.osm.pbf`` (byte for byte) and the same done-marker,
        so a later ``fetch`` of it only reads the marker.  Per source file, one collecting pass
        and one write pass per ``batch`` boxes replace :func:`write_extract`'s five passes per
        box (:mod:`osmseg.osm.cut`).  Boxes already cut (marker present) are skipped; boxes
        may overlap and repeat.  Memory holds compact arrays of the source file (prepare
        first for a country file).  Returns the extracts in the order of ``bboxes``.
        """
        boxes = [check_bbox(b) for b in bboxes]
        todo: dict[Path, dict[Path, tuple[LngLatBBox, Path]]] = {}
        for bbox in boxes:
            marker, out = self._names(bbox)
            if read_done(marker) is None:
                todo.setdefault(self._source_for(bbox), {})[marker] = (bbox, out)
        if todo:
            self.extracts.mkdir(parents=True, exist_ok=True)
            self.timestamp()
        for source, wanted in todo.items():
            self._cut_from(source, list(wanted), list(wanted.values()), batch)
        return [self.fetch(bbox) for bbox in boxes]

    def _cut_from(self, source: Path, markers: list[Path], jobs: list[tuple[LngLatBBox, Path]], batch: int) -> None:
        """:meth:`cut` for the boxes whose extracts come from one ``source`` file."""
        fields = _header_fields(str(source))
        write_extracts(source, jobs, self.reach, lambda box: _box_header(fields, box),
                       lambda i, counts: self._record(jobs[i][0], markers[i], jobs[i][1], counts),
                       lambda box, out: write_extract(source, [box], out, self.reach, self.enclosing), batch,
                       self.enclosing)
        logger.info("cut %d boxes from %s", len(jobs), source)

    def _names(self, bbox: LngLatBBox) -> tuple[Path, Path]:
        """The done-marker and the extract file of ``bbox`` in the extracts' folder."""
        stem = cache_name("file", bbox, *self._identity)
        return self.extracts / f"{stem}.json", self.extracts / f"{stem}.osm.pbf"

    def _source_for(self, bbox: LngLatBBox) -> Path:
        """The file to cut ``bbox`` from: the first prepared region holding it, else the input."""
        return next((region for boxes, region in self._regions
                     if any(bbox_contains(b, bbox) for b in boxes)), self.readable())

    def _record(self, bbox: LngLatBBox, marker: Path, out: Path, counts: dict[str, int]) -> OsmExtract:
        """Write ``bbox``'s done-marker for its extract ``out`` (after the file)."""
        stamp, origin = self.timestamp()
        info = {"source": "file", "path": str(self.path), "bbox": list(bbox), "timestamp_from": origin,
                "counts": counts}
        return write_done(marker, OsmExtract(paths=(out,), timestamp=stamp, info=info))

    def describe(self) -> dict[str, Any]:
        """JSON-able description for the manifest."""
        stamp, origin = self.timestamp()
        return {"source": "file", "path": str(self.path), "timestamp": stamp, "timestamp_from": origin,
                "attribution": self.attribution}


def is_osm_path(text: str) -> bool:
    """True if ``text`` ends like an OSM file osmium reads.

    >>> is_osm_path("de.osm.pbf"), is_osm_path("map.OSM"), is_osm_path("x.geojson")
    (True, True, False)
    """
    return text.lower().endswith(OSM_SUFFIXES)


def union_boxes(boxes: Iterable[LngLatBBox]) -> LngLatBBox:
    """The smallest box holding all ``boxes``.

    >>> union_boxes([LngLatBBox(0, 0, 1, 1), LngLatBBox(2, -1, 3, 0)])
    LngLatBBox(west=0, south=-1, east=3, north=1)
    """
    boxes = list(boxes)
    return LngLatBBox(min(b.west for b in boxes), min(b.south for b in boxes),
                      max(b.east for b in boxes), max(b.north for b in boxes))
