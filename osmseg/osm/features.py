"""OSM files to class-labelled polygons in one sample's Web Mercator box.

:func:`read_features` streams OSM XML or PBF with pyosmium (node locations cached, multipolygon
relations assembled by osmium's area handler: courtyards and lake islands become holes) and
never builds an in-memory OSM model.  Each object gets the first class of the table whose rule
matches its tags and geometry kind; ``natural=coastline`` ways become sea (see
:mod:`osmseg.osm.coastline`).  Geometries are projected to EPSG:3857; lines are buffered to
their ground width and tree nodes to crowns (metres on the ground are ``1/cos(lat)`` Web
Mercator metres at the feature's own latitude, so that its pixels do not depend on the sample
box: :func:`~osmseg.osm.geometry.mercator_scale`); everything is clipped to the sample box plus
a small margin.

Python does little per object: osmium's filters keep away the objects no rule can match; a
class decision looks up only the tags it depends on, memoised across objects and reads
(:mod:`osmseg.osm.objects`); geometries are kept as osmium's WKB or coordinates, then built,
projected, buffered and clipped in vectorised calls.  The file is read once: osmium's area
handler reads the relations first, which tells the reader the member ways a broken multipolygon
may need (kept as they stream by); plain XML without a relation osmium makes an area of skips
that first pass.

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
from osmseg.osm.geometry import even_odd, mercator_scale, polygonal, to_mercator
from osmseg.osm.objects import (
    Member,
    SecondPass,
    Shapes,
    WayRule,
    as_linestring_wkb,
    clip_to,
    few_points,
    key_filter,
    located_runs,
    member_lines,
    rules_of,
    spells_no_area_relation,
)
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
    # osmium's area handler reads a file twice: not needed for XML that cannot have multipolygons
    areas = len(files) > 1 or not spells_no_area_relation(files[0])
    with _one_file(files) as (source, name):
        collector.stream(source, name, areas)
        if not collector.negative:
            collector.repair_relations()
        if collector.negative:  # JOSM's negative ids: read everything again, renumbered
            with _renumbered(source, name) as copy:
                collector = _Collector(table, grid, renumbered=True)
                collector.stream(copy, name, areas)
                collector.repair_relations()
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


class _Collector:
    """Gathers classified lon/lat geometries while streaming, then projects and clips them."""

    def __init__(self, table: ClassTable, grid: SampleGrid, renumbered: bool = False) -> None:
        self.table = table
        self.grid = grid
        self.renumbered = renumbered  # reading a renumbered copy: name objects by original_id()
        self.negative = False  # met a negative id osmium cannot locate or assemble: read renumbered
        self.unplaced: Counter[tuple[str, str]] = Counter()  # (class name, "way"/"relation")
        self.sea_class = table.coastline_class
        rules = rules_of(table)
        self.node_rule, self.way_rule = rules.node, rules.way
        self.relation_rule, self.area_rule = rules.relation, rules.area
        self.wkb = osmium.geom.WKBFactory()
        # per feature: kind, class, osm id, width in ground metres (or nan), note or None; and
        # its lon/lat geometry in self.shapes
        self.items: list[tuple[str, ClassDef, str, float, str | None]] = []
        self.shapes = Shapes()
        self.coast: list[BaseGeometry] = []
        self.relations: dict[int, tuple[ClassDef, tuple[int, ...]]] = {}  # multipolygon candidates
        self.assembled: set[int] = set()
        self.wanted: set[int] = set()  # their member ways ...
        self.members: dict[int, Member] = {}  # ... as the file has them
        self.problems: list[str] = []
        self.near = tuple(grid.bbox)  # where a skipped broken object is worth a warning
        self.node_keys = table.rule_keys("point")
        self.other_keys = table.rule_keys("area", "line") | ({"natural"} if self.sea_class else set())

    # -- streaming -------------------------------------------------------------------------
    def stream(self, source: osmium.io.File, name: str, areas: bool = True) -> None:
        """Read the file: osmium's area handler first reads its relations, then everything.

        The first pass shows the relations to relation(), so that the second keeps the member
        ways repair_relations() may need (whatever their tags) and the relations themselves
        do not reach Python again.  Without ``areas`` (the file has no relation osmium makes
        an area of) there is one pass, and no area handler.
        """
        fp = osmium.FileProcessor(source).with_locations()
        tagged = osmium.filter.KeyFilter(*self.other_keys)  # untagged objects never reach Python
        if areas and any(r.geometry == "area" for c in self.table.classes for r in c.rules):
            area_keys = self.table.rule_keys("area")  # osmium assembles the relations with these
            # the collector itself is a handler of the first pass: relation() sees the relations
            fp.with_areas(osmium.filter.KeyFilter(*self.other_keys), self, key_filter(area_keys, osmium.osm.RELATION))
            fp.with_filter(SecondPass(self.wanted, self.wkb, self.members))
            fp.with_filter(osmium.filter.EntityFilter(osmium.osm.NODE | osmium.osm.WAY | osmium.osm.AREA))
            tagged.enable_for(osmium.osm.WAY | osmium.osm.AREA)
        else:
            tagged.enable_for(osmium.osm.WAY | osmium.osm.RELATION)
        fp.with_filter(key_filter(self.node_keys, osmium.osm.NODE)).with_filter(tagged)
        node_type, way_type, area_type = osmium.osm.Node, osmium.osm.Way, osmium.osm.Area
        iterator = iter(fp)
        while True:
            try:
                obj: Any = next(iterator)
            except StopIteration:
                break
            except RuntimeError as exc:  # osmium's parse errors (XML, PBF) arrive as RuntimeError
                raise OSMDataError(_read_error(name, exc)) from None
            kind = type(obj)
            if kind is way_type:
                self.way(obj)
            elif kind is node_type:
                self.node(obj)
            elif kind is area_type:  # of a relation (SecondPass drops those of closed ways: see way())
                self.area(obj)
            elif isinstance(obj, osmium.osm.Relation):
                self.relation(obj)

    def node(self, n: osmium.osm.Node) -> None:
        decision = self.node_rule(n.tags)
        if decision is None:
            return
        loc = n.location
        if loc.valid():
            self.shapes.add_point(loc.lon, loc.lat)
            self.items.append(("point", decision[0], f"n{self.oid(n.id)}", decision[1], None))

    def way(self, w: osmium.osm.Way) -> None:
        rule = self.way_rule(w.tags)
        if rule is None:
            return
        if isinstance(rule, str):  # COAST, the only other decision
            self.coastline(w)
            return
        try:
            wkb = self.wkb.create_linestring(w)  # all nodes located, 2 places at least
        except (osmium.InvalidLocationError, RuntimeError):
            self.broken_way(w, rule)
            return
        as_area, cls, width = rule
        wid = original_id(w.id) if self.renumbered else w.id
        wkb = as_linestring_wkb(wkb)
        if not as_area:
            self.shapes.add_line(wkb)
            self.items.append(("line", cls, f"w{wid}", width, None))
            return
        if few_points(wkb):
            self.warn_near(f"way {wid} ({cls.name}): fewer than 3 of its nodes have a location in the file: skipped",
                           shapely.get_coordinates(shapely.from_wkb(wkb)))
        elif self.shapes.add_ring(wkb) and not w.is_closed():
            self.add("area", cls, f"w{wid}", math.nan, f"way {wid} ({cls.name})",
                     ["is tagged as an area but not closed: closed it"])
        else:
            self.items.append(("area", cls, f"w{wid}", math.nan, None))

    def broken_way(self, w: osmium.osm.Way, rule: WayRule) -> None:
        """A way osmium makes no line of: nodes missing from the file, or fewer than 2 places."""
        cls = rule.cls
        runs, missing, negative = located_runs(w.nodes)
        self.negative = self.negative or bool(missing and negative)
        if not runs:
            self.unplaced[cls.name, "way"] += 1
        located = [c for run in runs for c in run]
        wid = self.oid(w.id)
        name = f"way {wid} ({cls.name})"
        notes = [f"{missing} of its {len(w.nodes)} nodes are missing from the file: drew it without them"] if missing else []
        if not rule.as_area:
            lines = [r for r in runs if len(r) >= 2]
            if not lines:
                self.warn_near(f"{name}: fewer than 2 of its nodes have a location in the file: skipped", located)
                return
            self.shapes.add(shapely.LineString(lines[0]) if len(lines) == 1 else shapely.MultiLineString(lines))
            self.add("line", cls, f"w{wid}", rule.width, name, notes)
            return
        ring = located  # an area through the nodes that remain
        if ring and ring[0] != ring[-1]:
            if not w.is_closed():
                notes.append("is tagged as an area but not closed: closed it")
            ring.append(ring[0])
        if len(set(ring)) < 3:
            self.warn_near(f"{name}: fewer than 3 of its nodes have a location in the file: skipped", ring)
            return
        self.shapes.add(shapely.polygons(np.array(ring)))
        self.add("area", cls, f"w{wid}", math.nan, name, notes)

    def coastline(self, w: osmium.osm.Way) -> None:
        try:
            runs: Any = [shapely.get_coordinates(shapely.from_wkb(self.wkb.create_linestring(w)))]
        except (osmium.InvalidLocationError, RuntimeError):
            runs, missing, negative = located_runs(w.nodes)
            self.negative = self.negative or bool(missing and negative)
        if not runs:
            self.unplaced["coastline", "way"] += 1
        self.coast.extend(shapely.LineString(r) for r in runs if len(r) >= 2)

    def add(self, kind: str, cls: ClassDef, osm_id: str, width: float, name: str = "",
            notes: Sequence[str] = ()) -> None:
        """Keep a feature whose geometry was just added to :attr:`shapes`; ``notes`` on its
        repairs are logged if it reaches the box."""
        self.items.append((kind, cls, osm_id, width, f"{name}: {'; '.join(notes)}" if notes else None))

    def oid(self, osm_id: int) -> int:
        """The id the user's file gives the object (differs when reading a renumbered copy)."""
        return original_id(osm_id) if self.renumbered else osm_id

    def relation(self, r: osmium.osm.Relation) -> None:
        cls = self.relation_rule(r.tags)
        if cls is not None:
            refs = tuple(m.ref for m in r.members if m.type == "w")
            self.relations[r.id] = (cls, refs)
            self.wanted.update(refs)
            if r.id < 0 or any(ref < 0 for ref in refs):
                self.negative = True

    def area(self, a: osmium.osm.Area) -> None:
        cls = self.area_rule(a.tags)
        if cls is None:
            return
        try:
            wkb = self.wkb.create_multipolygon(a)
        except (osmium.InvalidLocationError, RuntimeError):
            return  # osmium could not assemble it (an empty area): repaired in repair_relations
        self.assembled.add(a.orig_id())
        self.shapes.add_wkb(wkb)
        self.add("area", cls, f"r{self.oid(a.orig_id())}", math.nan)

    # -- repair ----------------------------------------------------------------------------
    def repair_relations(self) -> None:
        """Rebuild multipolygons osmium could not assemble from their closed rings (even-odd)."""
        broken = {rid: v for rid, v in self.relations.items() if rid not in self.assembled}
        lines, located, negative = member_lines({ref for _, refs in broken.values() for ref in refs}, self.members)
        self.negative = self.negative or negative
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
                self.shapes.add(geom)
                self.add("area", cls, f"r{self.oid(rid)}", math.nan, name,
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
        kinds, classes, ids, widths, notes = zip(*self.items)
        lonlat = self.shapes.build()
        geom = to_mercator(lonlat)
        half = np.array(widths, dtype=float) / 2 * mercator_scale(lonlat)
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
        shape = clip_to(shape, clip, valid=areas)  # (areas are valid now)
        plain = np.isin(shapely.get_type_id(shape), (3, 6)) & ~shapely.is_empty(shape)  # polygonal() as is
        out: list[Feature] = []
        for k, i in enumerate(idx):
            polygon = shape[k] if plain[k] else polygonal(shape[k])
            message = note[k]
            if message:
                (self.warn if polygon is not None else logger.debug)(message)
            if polygon is not None:
                cls = classes[i]
                out.append(Feature(cls.id, cls.order, polygon, ids[i], kinds[i]))
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
