"""What shapes a box's drawing without a node near it: areas around the box, long segments, the coast.

A cut (:func:`osmseg.osm.localfile.write_extract`, :mod:`osmseg.osm.cut`) keeps the nodes in a
box and the ways that have one there or cross it between two nodes within its reach (1 km).
Some OSM data changes what is drawn over a box while none of its nodes comes that near:

1. **an area the box lies in**: a forest, a lake, an industrial estate larger than the box,
   whose outline is elsewhere; or an area or line crossing the box along a segment whose ends
   are farther than the reach (a 12 km straight forest edge, an 8 km straight road), or
   through a node the file lacks (an area cut at the extract's edge, which osmium draws
   through the nodes it has). With ``enclosing=True`` a cut also keeps every way whose
   bounding box (of its located nodes) meets the box, and every ``type=multipolygon``
   relation whose bounding box (of its member ways') holds it;
2. **the nearest coastline**: a box no coastline crosses is wholly land or wholly sea, and the
   side of the nearest coastline decides (:mod:`osmseg.osm.coastline`). With
   ``enclosing=True`` a cut also keeps the ``natural=coastline`` ways whose bounding box comes
   within :data:`COAST_REACH_M` of the box, so a box at sea within that distance of a coast
   draws sea, as it does from the whole file (farther out at sea it draws land).

The bounding-box tests are necessary, not sufficient: an L-shaped forest whose box meets the
cut's box may not reach it and then draws nothing there. So an extract holds more than the box
needs, never less, and draws what the whole file draws over the box, but for what a per-box
cut cannot see: ``type=boundary`` relations (osmium assembles them as areas too; only
multipolygons are cut), a way whose nodes are in another ``--osm`` file than the way, and
nodes with negative ids (JOSM's new objects, which osmium's location index does not hold).
The same rule has two forms that give the same ids: :class:`EnclosingRule` for the streaming
cut (any number of boxes, their union) and :func:`enclosing_index` / :func:`enclosing_keep` for
the numpy cut of one box at a time.

The dataset builder does not use it (its extracts stay those the API and Overpass give); a
region search does (``localization.region.cache``).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from osmseg.grid import LngLatBBox, pad_bbox

__all__ = ["COAST_REACH_M", "Enclosing", "EnclosingRule", "enclosing_index", "enclosing_keep"]

#: Metres around a box within which coastline ways are kept (their side decides a box at sea).
COAST_REACH_M = 5000.0

Ints = npt.NDArray[np.integer[Any]]
Floats = npt.NDArray[np.float64]
Bools = npt.NDArray[np.bool_]
Box = tuple[float, float, float, float]

#: Fixed-point sentinel beyond any location (osmium's fixed point: 1e-7 degrees).
_FAR = np.int64(1) << 40


def _holds(outer: Box, box: LngLatBBox) -> bool:
    return outer[0] <= box.west and outer[1] <= box.south and outer[2] >= box.east and outer[3] >= box.north


def _meets(a: Box, box: LngLatBBox) -> bool:
    return a[0] <= box.east and a[2] >= box.west and a[1] <= box.north and a[3] >= box.south


def _envelope(boxes: Sequence[LngLatBBox]) -> LngLatBBox:
    return LngLatBBox(min(b.west for b in boxes), min(b.south for b in boxes), max(b.east for b in boxes),
                      max(b.north for b in boxes))


class EnclosingRule:
    """The rule for the union of ``boxes`` (a streaming cut): which ways and relations it keeps.

    ``region``: the file is a region that smaller boxes inside ``boxes`` will be cut from, so
    keep the multipolygons whose bounding box *meets* a box (each might hold one of those
    smaller boxes): the region then holds everything the rule keeps for any box inside it.
    """

    def __init__(self, boxes: Sequence[LngLatBBox], region: bool = False) -> None:
        self.boxes = list(boxes)
        self.coast = [pad_bbox(b, COAST_REACH_M) for b in self.boxes]
        self.region = region
        # everything kept meets these envelopes: one test turns away the ways of a country file far off
        self._envelope = _envelope(self.boxes)
        self._coast_envelope = _envelope(self.coast)

    @staticmethod
    def bounds(points: Iterable[tuple[float, float]]) -> Box | None:
        """The bounding box of (lon, lat) ``points``, None for none."""
        lons, lats = [], []
        for lon, lat in points:
            lons.append(lon)
            lats.append(lat)
        return (min(lons), min(lats), max(lons), max(lats)) if lons else None

    def meets(self, bounds: Box | None) -> bool:
        """Whether a way of these bounds meets one of the boxes."""
        return bounds is not None and _meets(bounds, self._envelope) and any(_meets(bounds, b) for b in self.boxes)

    def encloses(self, outer: Box | None) -> bool:
        """Whether ``outer`` (a multipolygon's bounding box) holds one of the boxes (meets one, for a region)."""
        if outer is None or not _meets(outer, self._envelope):
            return False
        test = _meets if self.region else _holds
        return any(test(outer, b) for b in self.boxes)

    def near_coast(self, bounds: Box | None) -> bool:
        """Whether a coastline way of these bounds comes within :data:`COAST_REACH_M` of a box."""
        return (bounds is not None and _meets(bounds, self._coast_envelope)
                and any(_meets(bounds, b) for b in self.coast))

    @staticmethod
    def union(parts: Iterable[Box | None]) -> Box | None:
        """The bounding box of several (a multipolygon's member ways'), None for none."""
        known = [p for p in parts if p is not None]
        if not known:
            return None
        return (min(p[0] for p in known), min(p[1] for p in known), max(p[2] for p in known),
                max(p[3] for p in known))


@dataclass(frozen=True)
class Enclosing:
    """The numpy form: candidate ways and multipolygons with their bounding boxes in degrees."""

    ways: Ints  # positions of the ways with a located node
    way_box: tuple[Floats, Floats, Floats, Floats]
    coast: Ints  # positions of coastline ways
    coast_box: tuple[Floats, Floats, Floats, Floats]
    rels: Ints  # multipolygon indexes big enough to hold a box
    rel_box: tuple[Floats, Floats, Floats, Floats]


def _reduce(offsets: Ints, values: Ints, fill: np.int64, op: Any) -> Ints:
    """``op.reduceat`` over each [offsets[i], offsets[i+1]) run of ``values``; ``fill`` for empty runs."""
    out = np.full(len(offsets) - 1, fill, dtype=np.int64)
    starts, sizes = offsets[:-1], np.diff(offsets)
    full = sizes > 0
    if full.any():
        out[full] = op.reduceat(values, starts[full])
    return out


def _bounds(offsets: Ints, lo_x: Ints, lo_y: Ints, hi_x: Ints, hi_y: Ints) -> tuple[Ints, Ints, Ints, Ints]:
    """Fixed-point (west, south, east, north) of each [offsets[i], offsets[i+1]) run; ``_FAR`` and
    ``-_FAR`` (no known point) for runs without one."""
    return (_reduce(offsets, lo_x, _FAR, np.minimum), _reduce(offsets, lo_y, _FAR, np.minimum),
            _reduce(offsets, hi_x, -_FAR, np.maximum), _reduce(offsets, hi_y, -_FAR, np.maximum))


def _meeting(bounds: tuple[Floats, Floats, Floats, Floats], box: LngLatBBox) -> Bools:
    """Which of the ``bounds`` (degrees) meet ``box``."""
    west, south, east, north = bounds
    return (west <= box.east) & (east >= box.west) & (south <= box.north) & (north >= box.south)


def _degrees(fixed: tuple[Ints, Ints, Ints, Ints], rows: Ints) -> tuple[Floats, Floats, Floats, Floats]:
    west, south, east, north = (f[rows] / 10_000_000 for f in fixed)
    return west, south, east, north


def enclosing_index(x: Ints, y: Ints, located: Bools, way_offsets: Ints, way_nodes: Ints,
                    coast: Ints, rel_way_offsets: Ints, rel_ways: Ints, boxes: Sequence[LngLatBBox]) -> Enclosing:
    """Bounding boxes of the ways, coastline ways and multipolygons of a file, for :func:`enclosing_keep`.

    ``way_nodes``: node positions of each way's refs (-1: not in the file); ``coast``: coastline
    way positions; ``rel_ways``: member way positions of each multipolygon. Multipolygons too
    small to hold the smallest of ``boxes`` are left out.
    """
    known = way_nodes >= 0
    known[known] = located[way_nodes[known]]
    at = np.where(known, way_nodes, 0)
    xs = np.where(known, x[at].astype(np.int64), _FAR)  # unknown points: _FAR for the minima, -_FAR for the maxima
    ys = np.where(known, y[at].astype(np.int64), _FAR)
    fixed = _bounds(way_offsets, xs, ys, np.where(known, xs, -_FAR), np.where(known, ys, -_FAR))
    # smallest box in fixed point, halved: a margin for rounding, only a speed-up
    min_w = min(b.east - b.west for b in boxes) * 5_000_000
    min_h = min(b.north - b.south for b in boxes) * 5_000_000
    ways = np.flatnonzero(fixed[0] != _FAR)
    member = rel_ways >= 0
    at = np.where(member, rel_ways, 0)
    rel_fixed = _bounds(rel_way_offsets, *(np.where(member, f[at], fill)
                                           for f, fill in zip(fixed, (_FAR, _FAR, -_FAR, -_FAR))))
    rels = np.flatnonzero((rel_fixed[2] - rel_fixed[0] >= min_w) & (rel_fixed[3] - rel_fixed[1] >= min_h))
    return Enclosing(ways=ways, way_box=_degrees(fixed, ways), coast=coast, coast_box=_degrees(fixed, coast),
                     rels=rels, rel_box=_degrees(rel_fixed, rels))


def enclosing_keep(index: Enclosing, box: LngLatBBox) -> tuple[Ints, Ints]:
    """Positions of the ways (meeting ``box``, coastline near it) and indexes of the multipolygons
    (holding it) that :class:`EnclosingRule` keeps for the one box ``box``."""
    near = _meeting(index.coast_box, pad_bbox(box, COAST_REACH_M))
    r_west, r_south, r_east, r_north = index.rel_box
    holds = (r_west <= box.west) & (r_south <= box.south) & (r_east >= box.east) & (r_north >= box.north)
    return np.concatenate([index.ways[_meeting(index.way_box, box)], index.coast[near]]), index.rels[holds]
