"""OSM files to class-labelled polygons in one sample's Web Mercator box.

:func:`read_features` streams OSM XML or PBF with pyosmium (node locations cached, multipolygon
relations assembled by osmium's area handler: courtyards and lake islands become holes) and
never builds an in-memory OSM model.  Each object gets the first class of the table whose rule
matches its tags and geometry kind; ``natural=coastline`` ways become sea (see
:mod:`osmseg.osm.coastline`).  Geometries are projected to EPSG:3857; lines are buffered to
their ground width and tree nodes to crowns (metres on the ground are ``1/cos(lat)`` Web
Mercator metres); everything is clipped to the sample box plus a small margin.

Broken data is repaired or skipped with a ``logger.warning`` that names the OSM object, never a
crash: an area way that is not closed is closed; where nodes are missing from the file (an
extract's edge) a line is split and an area is drawn through the nodes that remain; invalid
polygons (self-intersections) go through ``shapely.make_valid``; a multipolygon osmium cannot
assemble (missing or unclosed members) is rebuilt from its closed rings (even-odd) or
skipped.  Warnings are only given for objects that reach the sample box, and are also kept in
:attr:`FeatureSet.problems`; they are logged once reading is done.  Classified objects that
cannot be placed at all, anywhere (no node of theirs has a location in the file: an extract
without its nodes) are summed up in one more warning and counted in
:attr:`FeatureSet.unplaced`, so that an empty result is never silent.  An unreadable file
(truncated, HTML instead of XML, not OSM) raises :class:`~osmseg.errors.OSMDataError`.
Several files (a split download) are merged with osmium first, keeping one copy (the newest
version) of each object.

Negative ids (what JOSM writes for objects not yet uploaded, e.g. labels a user drew): osmium's
node location cache ignores them.  A file is read as usual and only when that pass meets a
negative node ref it cannot locate, or a multipolygon with a negative id or member ref, it is
read again from a renumbered temporary copy (:mod:`osmseg.osm.renumber`); files without
negative ids cost nothing extra.  Problems and :attr:`Feature.osm_id` name objects by their
original ids ("way -201", "w-201"), as JOSM shows them.

Geometry decisions (also documented in ``data_manifests/classes13.toml``): a closed way that
matches a "line" rule is a line unless tagged ``area=yes``; ``area=no`` forces a line; the
table's ``hidden`` rules (tunnels, underground) drop a feature; bridges are drawn.
"""

from __future__ import annotations

import contextlib
import logging
import math
import tempfile
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import osmium
import osmium.filter
import shapely
from shapely.geometry.base import BaseGeometry

from osmseg.classes import ClassDef, ClassTable
from osmseg.errors import OSMDataError
from osmseg.grid import SampleGrid, XYBounds
from osmseg.osm.coastline import sea_polygon
from osmseg.osm.geometry import even_odd, polygonal, to_mercator
from osmseg.osm.renumber import original_id, write_renumbered

logger = logging.getLogger(__name__)


#: Features are clipped to the sample box grown by this many pixels (no edge effects).
CLIP_MARGIN_PX = 2


@dataclass(frozen=True)
class Feature:
    """One drawable OSM feature.

    Attributes:
        class_id: id in the class table it was read with.
        order: draw order of its class (higher is drawn on top).
        geometry: Polygon or MultiPolygon in EPSG:3857, clipped to the sample box (+ margin).
        osm_id: "n<id>", "w<id>" or "r<id>" with the id in the file (negative for objects JOSM
            has not uploaded); "coastline" for sea built from coastline ways.
        kind: how it was drawn: "area", "line" (buffered way), "point" (buffered node), "sea".
    """

    class_id: int
    order: int
    geometry: BaseGeometry
    osm_id: str
    kind: str


@dataclass(frozen=True)
class FeatureSet:
    """The features of one sample box, plus what was repaired or skipped on the way.

    Attributes:
        features: in file order (the rasteriser sorts by draw order).
        bounds: the EPSG:3857 box the features were clipped to (sample box + margin).
        problems: the warnings logged for broken OSM objects in or near the box, and one
            summing up the unplaced objects if there are any.
        unplaced: how many classified objects (anywhere in the file) were not drawn because
            no node of theirs has a location in the file.
    """

    features: tuple[Feature, ...]
    bounds: XYBounds
    problems: tuple[str, ...] = ()
    unplaced: int = 0

    def __iter__(self) -> Iterator[Feature]:
        return iter(self.features)

    def __len__(self) -> int:
        return len(self.features)


def read_features(paths: Sequence[Path | str], grid: SampleGrid, table: ClassTable) -> FeatureSet:
    """Read OSM file(s) and return the classified, projected, clipped features of ``grid``.

    Several files (a split download) are merged first, keeping one copy of each object.
    Raises ``OSMDataError`` for a missing or unreadable file.
    """
    files = [Path(p) for p in paths]
    if not files:
        raise OSMDataError("no OSM file given to read; fetch OSM data for the sample first")
    for f in files:
        if not f.is_file():
            raise OSMDataError(f"OSM file {f} does not exist or is not a file; fetch it again or check the --osm path")
    collector = _Collector(table, grid)
    with _one_file(files) as (source, name):
        collector.stream(source, name)
        if not collector.negative:
            collector.repair_relations(source, name)
        if collector.negative:  # JOSM's negative ids: read everything again, renumbered
            with _renumbered(source, name) as copy:
                collector = _Collector(table, grid, renumbered=True)
                collector.stream(copy, name)
                collector.repair_relations(copy, name)
    return collector.finish()


#: File name endings osmium recognises; any other file is sniffed (XML starts with "<").
_KNOWN_SUFFIXES = {".osm", ".pbf", ".xml", ".o5m", ".opl", ".gz", ".bz2"}


def _format(path: Path) -> str:
    """osmium format name for ``path``: "" (from its name) or, for names like "map", sniffed."""
    if path.suffix.lower() in _KNOWN_SUFFIXES:
        return ""
    with path.open("rb") as f:
        head = f.read(64).lstrip(b"\xef\xbb\xbf \t\r\n")
    return "osm" if head.startswith(b"<") else "pbf"


@contextlib.contextmanager
def _one_file(files: list[Path]) -> Iterator[tuple[osmium.io.File, str]]:
    """The single file to stream and its name for messages: the file, or a merged copy."""
    if len(files) == 1:
        yield osmium.io.File(str(files[0]), _format(files[0])), str(files[0])
        return
    reader = osmium.MergeInputReader()
    for f in files:
        try:
            reader.add_buffer(f.read_bytes(), _format(f) or _suffix_format(f))
        except RuntimeError as exc:
            raise OSMDataError(_read_error(f, exc)) from None
    with tempfile.TemporaryDirectory(prefix="osmseg-merge-") as tmp:
        merged = Path(tmp) / "merged.osm.pbf"
        writer = osmium.SimpleWriter(str(merged))
        try:
            reader.apply(writer, simplify=True)  # sorted, newest version of each object only
        finally:
            writer.close()
        yield osmium.io.File(str(merged)), " + ".join(str(f) for f in files)


@contextlib.contextmanager
def _renumbered(source: osmium.io.File, name: str) -> Iterator[osmium.io.File]:
    """A temporary copy of ``source`` with its negative ids made positive (streamed)."""
    with tempfile.TemporaryDirectory(prefix="osmseg-renumber-") as tmp:
        copy = Path(tmp) / "renumbered.osm.pbf"
        try:
            changed = write_renumbered(source, copy, name)
        except RuntimeError as exc:
            raise OSMDataError(_read_error(name, exc)) from None
        logger.info("%s has negative ids (objects not uploaded from JOSM): read it renumbered (%d objects)",
                    name, changed)
        yield osmium.io.File(str(copy))


def _suffix_format(path: Path) -> str:
    """osmium format string from a file name ("osm", "pbf", "osm.gz", ...)."""
    suffixes = [s.lstrip(".").lower() for s in path.suffixes[-2:]]
    if suffixes and suffixes[-1] in ("gz", "bz2"):
        return ".".join(suffixes) if len(suffixes) == 2 else "osm." + suffixes[-1]
    return {"xml": "osm"}.get(suffixes[-1], suffixes[-1]) if suffixes else "osm"


def _read_error(path: Path | str, exc: Exception) -> str:
    reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return f"cannot read OSM file {path} ({reason}); it is truncated or not OSM XML/PBF: download it again"


def _tags(obj: Any) -> dict[str, str]:
    return {t.k: t.v for t in obj.tags}


def _runs(nodes: Any) -> tuple[list[list[tuple[float, float]]], int]:
    """(lon, lat) of located nodes, in runs split where a node has no location; missing count."""
    runs: list[list[tuple[float, float]]] = []
    run: list[tuple[float, float]] = []
    missing = 0
    for n in nodes:
        loc = n.location
        if loc.valid():
            c = (loc.lon, loc.lat)
            if not run or run[-1] != c:
                run.append(c)
        else:
            missing += 1
            if run:
                runs.append(run)
                run = []
    if run:
        runs.append(run)
    return runs, missing


class _Collector:
    """Gathers classified geometries (lon/lat) while streaming, then projects and clips them."""

    def __init__(self, table: ClassTable, grid: SampleGrid, renumbered: bool = False) -> None:
        self.table = table
        self.grid = grid
        self.renumbered = renumbered  # reading a renumbered copy: name objects by original_id()
        self.negative = False  # met a negative id osmium cannot locate or assemble: read renumbered
        self.unplaced: Counter[tuple[str, str]] = Counter()  # (class name, "way"/"relation")
        self.sea_class = table.coastline_class
        self.wkb = osmium.geom.WKBFactory()
        # (kind, class, osm id, lon/lat geometry, width in ground metres or nan, note or None)
        self.items: list[tuple[str, ClassDef, str, BaseGeometry, float, str | None]] = []
        self.coast: list[BaseGeometry] = []
        self.relations: dict[int, tuple[ClassDef, tuple[int, ...]]] = {}  # multipolygon candidates
        self.assembled: set[int] = set()
        self.problems: list[str] = []
        self.near = tuple(grid.bbox)  # where a skipped broken object is worth a warning
        rules = [r for c in table.classes for r in c.rules] + list(table.hidden)
        self.relevant = frozenset(k.lstrip("!") for r in rules for k in r.tags) | {"area", "natural"}
        self.decisions: dict[tuple[str, tuple[tuple[str, str], ...]], ClassDef | None] = {}

    def classify(self, tags: dict[str, str], geometry: str) -> ClassDef | None:
        """The table's class for ``tags`` as ``geometry``; None if none or hidden (memoised)."""
        key = (geometry, tuple(sorted((k, v) for k, v in tags.items() if k in self.relevant)))
        if key not in self.decisions:
            hidden = self.table.is_hidden(tags)
            self.decisions[key] = None if hidden else self.table.classify(tags, geometry)
        return self.decisions[key]

    # -- streaming -------------------------------------------------------------------------
    def stream(self, source: osmium.io.File, name: str) -> None:
        t = self.table
        node_keys = t.rule_keys("point")
        other_keys = t.rule_keys("area", "line") | ({"natural"} if self.sea_class else set())
        area_keys = t.rule_keys("area")
        fp = osmium.FileProcessor(source).with_locations()
        if area_keys:  # assemble multipolygon relations that may match an area rule
            fp.with_areas(osmium.filter.KeyFilter(*area_keys))
        nodes = osmium.filter.KeyFilter(*node_keys) if node_keys else osmium.filter.EntityFilter(osmium.osm.NOTHING)
        nodes.enable_for(osmium.osm.NODE)
        fp.with_filter(nodes)
        tagged = osmium.filter.KeyFilter(*other_keys)
        tagged.enable_for(osmium.osm.WAY | osmium.osm.RELATION | osmium.osm.AREA)
        fp.with_filter(tagged)  # untagged objects never reach Python
        iterator = iter(fp)
        while True:
            try:
                obj = next(iterator)
            except StopIteration:
                break
            except RuntimeError as exc:  # osmium's parse errors (XML, PBF) arrive as RuntimeError
                raise OSMDataError(_read_error(name, exc)) from None
            if isinstance(obj, osmium.osm.Node):
                self.node(obj)
            elif isinstance(obj, osmium.osm.Way):
                self.way(obj)
            elif isinstance(obj, osmium.osm.Area):
                if not obj.from_way():  # closed ways are handled (and repaired) in way()
                    self.area(obj)
            elif isinstance(obj, osmium.osm.Relation):
                self.relation(obj)

    def node(self, n: osmium.osm.Node) -> None:
        tags = _tags(n)
        cls = self.classify(tags, "point")
        if cls is None or not n.location.valid():
            return
        point = shapely.Point(n.location.lon, n.location.lat)
        self.add("point", cls, f"n{self.oid(n.id)}", point, cls.width_for(tags, "point"))

    def way(self, w: osmium.osm.Way) -> None:
        tags = _tags(w)
        if self.sea_class is not None and tags.get("natural") == "coastline":
            runs, _ = self.runs_of(w)
            if not runs:
                self.unplaced["coastline", "way"] += 1
            self.coast.extend(shapely.LineString(r) for r in runs if len(r) >= 2)
            return
        line_cls = self.classify(tags, "line")
        area_cls = self.classify(tags, "area")
        as_area = area_cls is not None and (tags.get("area") == "yes" or line_cls is None) and tags.get("area") != "no"
        cls = area_cls if as_area else line_cls
        if cls is None:
            return
        runs, missing = self.runs_of(w)
        if not runs:
            self.unplaced[cls.name, "way"] += 1
        located = np.concatenate(runs) if runs else np.empty((0, 2))
        wid = self.oid(w.id)
        name = f"way {wid} ({cls.name})"
        notes = [f"{missing} of its {len(w.nodes)} nodes are missing from the file: drew it without them"] if missing else []
        if not as_area:
            lines = [r for r in runs if len(r) >= 2]
            if not lines:
                self.warn_near(f"{name}: fewer than 2 of its nodes have a location in the file: skipped", located)
                return
            geom = shapely.LineString(lines[0]) if len(lines) == 1 else shapely.MultiLineString(lines)
            self.add("line", cls, f"w{wid}", geom, cls.width_for(tags, "line"), name, notes)
            return
        ring = [tuple(c) for c in located]
        if ring and ring[0] != ring[-1]:
            if not w.is_closed():
                notes.append("is tagged as an area but not closed: closed it")
            ring.append(ring[0])
        if len(set(ring)) < 3:
            self.warn_near(f"{name}: fewer than 3 of its nodes have a location in the file: skipped", located)
            return
        self.add("area", cls, f"w{wid}", shapely.Polygon(ring), None, name, notes)

    def add(self, kind: str, cls: ClassDef, osm_id: str, geom: BaseGeometry, width: float | None,
            name: str = "", notes: Sequence[str] = ()) -> None:
        """Keep a feature (lon/lat); ``notes`` on its repairs are logged if it reaches the box."""
        note = f"{name}: {'; '.join(notes)}" if notes else None
        self.items.append((kind, cls, osm_id, geom, math.nan if width is None else width, note))

    def runs_of(self, w: osmium.osm.Way) -> tuple[list[Any], int]:
        """The way's located coordinates in runs split where nodes are missing, and how many are."""
        try:
            return [shapely.get_coordinates(shapely.from_wkb(self.wkb.create_linestring(w)))], 0
        except (osmium.InvalidLocationError, RuntimeError):
            runs, missing = _runs(w.nodes)
            self.note_negative(w, missing)
            return runs, missing

    def note_negative(self, w: osmium.osm.Way, missing: int) -> None:
        """Remember a way with a node missing because its id is negative (osmium never locates those)."""
        if missing and not self.negative:
            self.negative = any(n.ref < 0 for n in w.nodes)

    def oid(self, osm_id: int) -> int:
        """The id the user's file gives the object (differs when reading a renumbered copy)."""
        return original_id(osm_id) if self.renumbered else osm_id

    def relation(self, r: osmium.osm.Relation) -> None:
        tags = _tags(r)
        if tags.get("type") != "multipolygon":
            return
        cls = self.classify(tags, "area")
        if cls is not None:
            refs = tuple(m.ref for m in r.members if m.type == "w")
            self.relations[r.id] = (cls, refs)
            if r.id < 0 or any(ref < 0 for ref in refs):
                self.negative = True

    def area(self, a: osmium.osm.Area) -> None:
        cls = self.classify(_tags(a), "area")
        if cls is None:
            return
        try:
            geom = shapely.from_wkb(self.wkb.create_multipolygon(a))
        except (osmium.InvalidLocationError, RuntimeError):
            return  # osmium could not assemble it (an empty area): repaired in repair_relations
        self.assembled.add(a.orig_id())
        self.add("area", cls, f"r{self.oid(a.orig_id())}", geom, None)

    # -- repair ----------------------------------------------------------------------------
    def repair_relations(self, source: osmium.io.File, name: str) -> None:
        """Rebuild multipolygons osmium could not assemble from their closed rings (even-odd)."""
        broken = {rid: v for rid, v in self.relations.items() if rid not in self.assembled}
        if not broken:
            return
        wanted = {ref for _, refs in broken.values() for ref in refs}
        lines: dict[int, BaseGeometry] = {}
        located: set[int] = set()  # member ways with a node that has a location
        member_filter = osmium.filter.IdFilter(wanted)
        member_filter.enable_for(osmium.osm.WAY)
        fp = (osmium.FileProcessor(source, osmium.osm.NODE | osmium.osm.WAY).with_locations()
              .with_filter(osmium.filter.EntityFilter(osmium.osm.WAY))
              .with_filter(member_filter))
        try:
            for w in fp:
                if not isinstance(w, osmium.osm.Way):  # never: the filters pass ways only
                    continue
                runs, missing = _runs(w.nodes)
                self.note_negative(w, missing)
                if runs:
                    located.add(w.id)
                coords = [c for run in runs for c in run]
                if len(coords) >= 2:
                    lines[w.id] = shapely.LineString(coords)
        except RuntimeError as exc:
            raise OSMDataError(_read_error(name, exc)) from None
        for rid, (cls, refs) in sorted(broken.items()):
            present = [lines[ref] for ref in refs if ref in lines]
            missing = len(refs) - len(present)
            name = f"relation {self.oid(rid)} ({cls.name})"
            why = f"{missing} of its {len(refs)} member ways are missing from the file" if missing else "its rings do not close"
            geom = even_odd(present)
            if located.isdisjoint(refs):
                self.unplaced[cls.name, "relation"] += 1
            if geom is None:
                self.warn_near(f"{name}: osmium could not assemble it ({why}) and no member ring closes: skipped",
                               [c for line in present for c in line.coords])
            else:
                self.add("area", cls, f"r{self.oid(rid)}", geom, None, name,
                         [f"osmium could not assemble it ({why}): drew its closed rings"])

    def warn_near(self, message: str, coords: Any) -> None:
        """Warn about a skipped object if one of its known (lon, lat) points is in the box (else debug)."""
        w, s, e, n = self.near
        xy = np.asarray(coords, dtype=float).reshape(-1, 2)
        if bool(((xy[:, 0] >= w) & (xy[:, 0] <= e) & (xy[:, 1] >= s) & (xy[:, 1] <= n)).any()):
            self.warn(message)
        else:
            logger.debug(message)

    def warn(self, message: str) -> None:
        """Keep a problem; :meth:`finish` logs them (a pass that is read again logs nothing)."""
        self.problems.append(message)

    # -- projection, buffering, clipping -----------------------------------------------------
    def finish(self) -> FeatureSet:
        g = self.grid
        res = g.pixel_size
        b = g.xy_bounds
        m = CLIP_MARGIN_PX * res
        clip = XYBounds(b.left - m, b.bottom - m, b.right + m, b.top + m)
        features: list[Feature] = []
        if self.items:
            features.extend(self._project(clip))
        if self.coast and self.sea_class is not None:
            sea = sea_polygon(list(to_mercator(np.array(self.coast, dtype=object))), clip, warn=self.warn)
            if sea is not None:
                features.append(Feature(self.sea_class.id, self.sea_class.order, sea, "coastline", "sea"))
        if self.unplaced:
            self.warn(_unplaced_message(self.unplaced))
        for message in self.problems:
            logger.warning(message)
        return FeatureSet(features=tuple(features), bounds=clip, problems=tuple(self.problems),
                          unplaced=sum(self.unplaced.values()))

    def _project(self, clip: XYBounds) -> list[Feature]:
        kinds, classes, ids, geoms, widths, notes = zip(*self.items)
        geom = to_mercator(np.array(geoms, dtype=object))
        # ground metres -> Web Mercator metres: divide by cos(lat), the grid's pixel-size ratio
        half = np.array(widths, dtype=float) / 2 * (self.grid.pixel_size / self.grid.ground_resolution)
        pad = np.nan_to_num(half, nan=0.0)
        x0, y0, x1, y1 = shapely.bounds(geom).T
        near = (x1 >= clip.left - pad) & (x0 <= clip.right + pad) & (y1 >= clip.bottom - pad) & (y0 <= clip.top + pad)
        idx = np.flatnonzero(near & ((np.array(kinds) == "area") | ~np.isnan(half)))
        kind = np.array(kinds, dtype=object)[idx]
        shape = geom[idx]
        note: list[str | None] = [notes[i] for i in idx]
        areas = kind == "area"
        for j in np.flatnonzero(areas & ~shapely.is_valid(shape)):
            i = idx[j]
            reason = shapely.is_valid_reason(shape[j])
            shape[j] = shapely.make_valid(shape[j])
            extra = f"is an invalid polygon ({reason}): repaired"
            note[j] = f"{note[j]}; {extra}" if note[j] else f"{_describe(ids[i])} ({classes[i].name}): {extra}"
        shape[~areas] = shapely.buffer(shape[~areas], half[idx][~areas])
        shape = shapely.intersection(shape, shapely.box(*clip))
        out: list[Feature] = []
        for k, i in enumerate(idx):
            polygon = polygonal(shape[k])
            message = note[k]
            if message:
                (self.warn if polygon is not None else logger.debug)(message)
            if polygon is not None:
                out.append(Feature(classes[i].id, classes[i].order, polygon, ids[i], kinds[i]))
        return out


_KINDS = {"n": "node", "w": "way", "r": "relation"}


def _unplaced_message(counts: Counter[tuple[str, str]]) -> str:
    """One line on the objects no node of which has a location, most numerous first.

    >>> _unplaced_message(Counter({("highway", "way"): 3, ("building", "way"): 12, ("water", "relation"): 1}))[:75]
    '12 building ways, 3 highway ways and 1 water relation have no node with a l'
    >>> _unplaced_message(Counter({("building", "way"): 1}))[:50]
    '1 building way has no node with a location in the '
    """
    parts = [f"{n} {label} {kind}{'' if n == 1 else 's'}"
             for (label, kind), n in sorted(counts.items(), key=lambda item: (-item[1], item[0]))]
    text = parts[0] if len(parts) == 1 else f"{', '.join(parts[:-1])} and {parts[-1]}"
    verb = "has" if sum(counts.values()) == 1 else "have"
    return (f"{text} {verb} no node with a location in the file "
            "(an extract without its nodes, e.g. an Overpass answer without '>;'?): not drawn")


def _describe(osm_id: str) -> str:
    """How warnings name an OSM object: "w12" -> "way 12"."""
    return f"{_KINDS.get(osm_id[:1], 'object')} {osm_id[1:]}"
