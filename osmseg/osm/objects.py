"""OSM objects as the feature reader meets them: which reach Python, their class, their geometry.

:mod:`osmseg.osm.features` asks, for every node, way, relation and area osmium streams, which
class (if any) its tags give.  Building a dict of all its tags costs more than the rest of the
object's handling (pyosmium hands tags over one at a time), and the answer depends on a few
keys only.  :class:`TagDecisions` memoises a decision function as a tree of tag look-ups: each
node of the tree names the next key to look up, each branch is one value of that key (``None``:
absent), each leaf is a decision.  The tree is learnt from the decision function itself, which
reads tags through a recording mapping: it reads its keys in an order that depends only on the
values it has read before, so every object that gives the same values to those keys gets the
same decision, whatever its other tags.  An object that leaves the tree (values not seen
before) runs the decision function once and adds its path.  An object that repeats a key (not
valid OSM) is read with the key's first value.

The decisions (:func:`rules_of`) are the reader's geometry rules in terms of
:meth:`~osmseg.classes.ClassTable.classify`, :meth:`~osmseg.classes.ClassTable.is_hidden` and
:meth:`~osmseg.classes.ClassDef.width_for`: a way matching a "line" rule is a line unless tagged
``area=yes``; ``area=no`` forces a line; hidden features (tunnels...) are not drawn.

Geometry: osmium's WKB of a way whose nodes all have a location, the runs of located nodes of
one that misses some (:func:`located_runs`), all turned into shapely geometries at once by
:class:`Shapes`.  The member ways of multipolygons, which a repair of one osmium cannot assemble
needs whatever their tags, are kept by :class:`SecondPass` as the file streams by.  Clipping to
the sample box (:func:`clip_to`) skips GEOS's overlay for the polygons inside the box.

What reaches Python: objects with a key some rule needs (:func:`key_filter`); osmium's area
handler (two passes over the file) only where a relation may become an area
(:func:`spells_no_area_relation`).

>>> from osmseg.classes import load_class_table
>>> way = rules_of(load_class_table()).way
>>> way({"highway": "residential", "name": "Mannerheimintie"})
WayRule(as_area=False, cls='highway', width=6.0)
>>> way({"highway": "residential", "tunnel": "yes"}) is None, way({"natural": "coastline"})
(True, 'coastline')
"""

from __future__ import annotations

import dataclasses
import math
import mmap
import weakref
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, Generic, NamedTuple, TypeVar, cast

import numpy as np
import osmium
import osmium.filter
import shapely
from shapely.geometry.base import BaseGeometry

from osmseg.classes import ClassDef, ClassTable

T = TypeVar("T")

#: The decision for a ``natural=coastline`` way when the table draws sea.
COAST = "coastline"

Runs = list[list[tuple[float, float]]]


class _Recorder:
    """The tags of one object as a read-only mapping that remembers what was looked up, in order."""

    def __init__(self, tags: Any) -> None:
        self.tags = tags
        self.seen: dict[str, str | None] = {}

    def get(self, key: str, default: Any = None) -> Any:
        if key not in self.seen:
            self.seen[key] = self.tags.get(key)
        value = self.seen[key]
        return default if value is None else value

    def __contains__(self, key: object) -> bool:
        return isinstance(key, str) and self.get(key) is not None

    def __getitem__(self, key: str) -> str:
        value = self.get(key)
        if value is None:
            raise KeyError(key)
        return str(value)


class TagDecisions(Generic[T]):
    """``decide(tags)`` memoised as a tree of tag look-ups (see the module doc).

    ``decide`` must read tags only through ``get``, ``in`` and ``[]`` of the mapping it is
    given and depend on nothing else.  Calls take any mapping with ``get``: an osmium TagList
    or a dict.
    """

    def __init__(self, decide: Callable[[Any], T]) -> None:
        self.decide = decide
        self.root: Any = None  # a branch is [key, {value: subtree}], a leaf is (decision,)

    def __call__(self, tags: Any) -> T:
        node = self.root
        get = tags.get
        while type(node) is list:
            node = node[1].get(get(node[0]))
        if node is None:
            return self.learn(tags)
        return cast(T, node[0])

    def learn(self, tags: Any) -> T:
        """Run ``decide`` on ``tags`` and add the path of its look-ups to the tree."""
        recorder = _Recorder(tags)
        decision = self.decide(recorder)
        node: Any = (decision,)
        path = list(recorder.seen.items())
        for key, value in reversed(path):
            node = [key, {value: node}]
        if self.root is None:
            self.root = node
            return decision
        at = self.root
        for key, value in path:  # down the tree to where the new path leaves it
            if type(at) is not list or at[0] != key:  # never: decide reads in a fixed order
                break
            if value not in at[1]:
                at[1][value] = node[1][value]
                break
            at, node = at[1][value], node[1][value]
        return decision


class WayRule(NamedTuple):
    """How a way is drawn: as an area or a line of ``cls``, lines ``width`` ground metres wide."""

    as_area: bool
    cls: ClassDef
    width: float  # nan for areas and lines of a class without width

    def __repr__(self) -> str:
        return f"WayRule(as_area={self.as_area}, cls={self.cls.name!r}, width={self.width})"


@dataclasses.dataclass(frozen=True)
class TableRules:
    """The memoised decisions of one class table: for nodes (class and crown diameter), ways
    (:class:`WayRule` or :data:`COAST`), relations (class of a multipolygon) and areas (class)."""

    node: TagDecisions[tuple[ClassDef, float] | None]
    way: TagDecisions[WayRule | str | None]
    relation: TagDecisions[ClassDef | None]
    area: TagDecisions[ClassDef | None]


def _decisions(table: ClassTable) -> TableRules:
    sea = table.coastline_class is not None

    def width(cls: ClassDef, tags: Any, geometry: str) -> float:
        metres = cls.width_for(tags, geometry)
        return math.nan if metres is None else metres

    def area(tags: Any) -> ClassDef | None:
        cls = table.classify(tags, "area")
        return None if cls is None or table.is_hidden(tags) else cls

    def node(tags: Any) -> tuple[ClassDef, float] | None:
        cls = table.classify(tags, "point")
        return None if cls is None or table.is_hidden(tags) else (cls, width(cls, tags, "point"))

    def way(tags: Any) -> WayRule | str | None:
        if sea and tags.get("natural") == "coastline":
            return COAST
        line_cls = table.classify(tags, "line")
        flag = tags.get("area")
        # an area if an area rule matches, unless area=no, or a line rule matches and not area=yes
        area_cls = area(tags) if flag != "no" and (flag == "yes" or line_cls is None) else None
        if area_cls is not None:
            return WayRule(True, area_cls, math.nan)
        if line_cls is None or table.is_hidden(tags):
            return None
        return WayRule(False, line_cls, width(line_cls, tags, "line"))

    def relation(tags: Any) -> ClassDef | None:
        return area(tags) if tags.get("type") == "multipolygon" else None

    return TableRules(TagDecisions(node), TagDecisions(way), TagDecisions(relation), TagDecisions(area))


#: Decision trees by table, kept while the table lives: what one sample's file taught them
#: serves the next (a build reads many).  Keyed by id(): tables are not hashable.
_RULES: dict[int, tuple[weakref.ref[ClassTable], TableRules]] = {}


def rules_of(table: ClassTable) -> TableRules:
    """The memoised decisions of ``table``, shared by every read with the same table object.

    Tables are immutable, so what a tree learnt stays true; a tree grows only by the
    combinations of rule tag values met in the data, which are few.
    """
    key = id(table)
    known = _RULES.get(key)
    if known is not None and known[0]() is table:
        return known[1]
    rules = _decisions(dataclasses.replace(table))  # an equal copy: the cache must not keep table alive
    _RULES[key] = (weakref.ref(table, lambda _: _RULES.pop(key, None)), rules)
    return rules


def located_runs(nodes: Any) -> tuple[Runs, int, bool]:
    """(lon, lat) of located nodes in runs split where a node has no location (repeated places
    dropped); how many nodes have none; whether a node has a negative id (osmium never locates those)."""
    runs: Runs = []
    run: list[tuple[float, float]] = []
    missing = 0
    negative = False
    for n in nodes:
        if n.ref < 0:
            negative = True
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
    return runs, missing, negative


def few_points(wkb: str) -> bool:
    """True if osmium's hex WKB linestring has fewer than 3 distinct points.

    Points are compared by their 32 hex digits (osmium's coordinates are never -0.0 or NaN).

    >>> line = shapely.to_wkb(shapely.LineString([(0, 0), (1, 0), (0, 0), (1, 0)]), hex=True)
    >>> few_points(line), few_points(line + shapely.to_wkb(shapely.Point(0, 1), hex=True)[-32:])
    (True, False)
    """
    first, second, third = wkb[18:50], wkb[50:82], wkb[82:114]
    if third and first != second and third != first and third != second:  # the usual case, quickly
        return False
    seen = set()
    for i in range(18, len(wkb), 32):
        seen.add(wkb[i:i + 32])
        if len(seen) == 3:
            return False
    return True


#: How osmium's hex WKB of a linestring starts on little-endian machines: byte order 1, type 2.
LINESTRING_WKB = "0102000000"


def as_linestring_wkb(wkb: str) -> str:
    """osmium's hex WKB of a line, as little-endian 2D WKB (what it is on every usual machine)."""
    if wkb.startswith(LINESTRING_WKB):
        return wkb
    return str(shapely.to_wkb(shapely.from_wkb(wkb), hex=True, byte_order=1, output_dimension=2))


class Shapes:
    """Lon/lat geometries added one at a time as osmium gives them, built all at once by :meth:`build`.

    Lines and rings are osmium's hex WKB of a line, little-endian 2D (:func:`as_linestring_wkb`).

    >>> s = Shapes()
    >>> s.add_ring(shapely.to_wkb(shapely.LineString([(0, 0), (1, 0), (1, 1)]), hex=True, byte_order=1))
    True
    >>> s.add_point(2, 3); s.build().tolist()
    [<POLYGON ((0 0, 1 0, 1 1, 0 0))>, <POINT (2 3)>]
    """

    def __init__(self) -> None:
        self.shapes: list[BaseGeometry | None] = []  # None: built by build()
        self.line_at: list[int] = []
        self.lines: list[str] = []
        self.ring_at: list[int] = []
        self.rings: list[str] = []  # the shells of polygons
        self.ring_open: list[bool] = []  # the line does not end where it starts: close it
        self.wkb_at: list[int] = []
        self.wkb: list[str] = []  # osmium's hex WKB of multipolygons
        self.point_at: list[int] = []
        self.points: list[tuple[float, float]] = []

    def add(self, geometry: BaseGeometry) -> None:
        self.shapes.append(geometry)

    def add_line(self, wkb: str) -> None:
        self.line_at.append(len(self.shapes))
        self.lines.append(wkb)
        self.shapes.append(None)

    def add_ring(self, wkb: str) -> bool:
        """A polygon with the line as shell, closed if it is not; True if it is not."""
        is_open = wkb[18:50] != wkb[-32:]
        self.ring_at.append(len(self.shapes))
        self.rings.append(wkb)
        self.ring_open.append(is_open)
        self.shapes.append(None)
        return is_open

    def add_wkb(self, wkb: str) -> None:
        """Any geometry as osmium's hex WKB (a multipolygon)."""
        self.wkb_at.append(len(self.shapes))
        self.wkb.append(wkb)
        self.shapes.append(None)

    def add_point(self, lon: float, lat: float) -> None:
        self.point_at.append(len(self.shapes))
        self.points.append((lon, lat))
        self.shapes.append(None)

    def build(self) -> np.ndarray:
        """The geometries, in the order they were added."""
        geom = np.empty(len(self.shapes), dtype=object)
        geom[:] = self.shapes
        if self.line_at:
            coords, counts = _coordinates(self.lines)
            geom[self.line_at] = shapely.linestrings(coords, indices=np.repeat(np.arange(len(counts)), counts))
        if self.ring_at:
            coords, counts = _coordinates(self.rings)
            ends = np.cumsum(counts)
            at = np.flatnonzero(self.ring_open)
            coords = np.insert(coords, ends[at], coords[ends[at] - counts[at]], axis=0)  # repeat the first point
            index = np.insert(np.repeat(np.arange(len(counts)), counts), ends[at], at)
            geom[self.ring_at] = shapely.polygons(shapely.linearrings(coords, indices=index))
        if self.wkb_at:  # (GEOS reads WKB bytes several times faster than hex)
            geom[self.wkb_at] = shapely.from_wkb(np.array([bytes.fromhex(h) for h in self.wkb], dtype=object))
        if self.point_at:
            geom[self.point_at] = shapely.points(np.array(self.points, dtype=float))
        return geom


def _coordinates(lines: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """The (lon, lat) of little-endian hex WKB lines, all in one array, and how many each line has."""
    counts = np.array([(len(h) - 18) >> 5 for h in lines])
    coords = np.frombuffer(bytes.fromhex("".join([h[18:] for h in lines])), dtype="<f8").reshape(-1, 2)
    return coords, counts


#: A way as :class:`SecondPass` found it: osmium's hex WKB (all its nodes have a location), or
#: what :func:`located_runs` says of its nodes.
Member = str | tuple[Runs, int, bool]


class SecondPass:
    """First filter of the main pass when osmium assembles areas: keeps the geometry of the
    ``wanted`` ways (whatever their tags) in ``found``; drops the areas osmium makes of closed
    ways (the reader draws those ways itself)."""

    def __init__(self, wanted: set[int], wkb: osmium.geom.WKBFactory, found: dict[int, Member]) -> None:
        self.wanted = wanted
        self.wkb = wkb
        self.found = found

    def way(self, w: osmium.osm.Way) -> bool:
        if w.id in self.wanted:
            try:
                self.found[w.id] = self.wkb.create_linestring(w)
            except (osmium.InvalidLocationError, RuntimeError):
                self.found[w.id] = located_runs(w.nodes)
        return False

    def area(self, a: osmium.osm.Area) -> bool:
        return a.from_way()


def member_lines(refs: Iterable[int], found: dict[int, Member]) -> tuple[dict[int, BaseGeometry], set[int], bool]:
    """The lines of the ways ``refs`` that :class:`SecondPass` found (of 2 places at least); the
    ways with a located node; whether one misses a node that has a negative id."""
    lines: dict[int, BaseGeometry] = {}
    located: set[int] = set()
    negative = False
    for ref in set(refs) & found.keys():
        member = found[ref]
        if isinstance(member, str):  # all its nodes have a location
            lines[ref] = shapely.from_wkb(member)
            located.add(ref)
            continue
        runs, missing, negative_ref = member
        negative = negative or bool(missing and negative_ref)
        if runs:
            located.add(ref)
        coords = [c for run in runs for c in run]
        if len(coords) >= 2:
            lines[ref] = shapely.LineString(coords)
    return lines, located, negative


def key_filter(keys: frozenset[str], entities: osmium.osm.osm_entity_bits) -> Any:
    """osmium's filter letting through the ``entities`` that have one of ``keys`` (none if no keys)."""
    keyed = osmium.filter.KeyFilter(*keys) if keys else osmium.filter.EntityFilter(osmium.osm.NOTHING)
    keyed.enable_for(entities)
    return keyed


def spells_no_area_relation(path: Path) -> bool:
    """True if ``path`` is OSM XML (not compressed) without a relation osmium makes an area of.

    Osmium assembles relations tagged ``type=multipolygon`` or ``type=boundary``: a file that
    never spells either word (nor uses a character reference, ``&#...;``, that could) has none.
    False for PBF and compressed files (not text), XML in UTF-16 and the like, an empty file.
    """
    try:
        with path.open("rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as text:
            return (text[:64].lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"<")
                    and all(text.find(word) < 0 for word in (b"multipolygon", b"boundary", b"&#")))
    except (OSError, ValueError):  # empty (osmium says what is wrong with it)
        return False


def clip_to(shapes: np.ndarray, box: tuple[float, float, float, float], valid: np.ndarray) -> np.ndarray:
    """``shapes`` clipped to ``box``: GEOS's intersection, except that a valid polygon without
    holes lying inside the box (not touching it) is its own clip and skips the overlay (two
    thirds of the clipping time on a city box). It is the same area, burnt to the same pixels;
    only its vertex order may differ from what GEOS would return. ``valid`` marks the
    geometries known to be valid (the others are checked).
    """
    left, bottom, right, top = box
    x0, y0, x1, y1 = shapely.bounds(shapes).T
    inside = ((x0 > left) & (y0 > bottom) & (x1 < right) & (y1 < top)
              & (shapely.get_type_id(shapes) == 3) & (shapely.get_num_interior_rings(shapes) == 0))
    inside[inside & ~valid] = shapely.is_valid(shapes[inside & ~valid])
    out = shapes.copy()
    out[~inside] = shapely.intersection(shapes[~inside], shapely.box(left, bottom, right, top))
    return cast("np.ndarray", out)
