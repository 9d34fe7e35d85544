"""Many per-box extracts of one OSM file in one read, the same as cutting each box on its own.

:func:`osmseg.osm.localfile.write_extract` streams its input five times per call, so cutting
N sample boxes one by one out of a prepared region reads the region 5N times.
:func:`write_extracts` gives every box exactly the file ``write_extract(src, [box], out)``
would write (same objects, same order, same header: byte-identical) with two reads of
``src`` per batch of boxes:

1. one streaming pass collects compact numpy arrays: node ids and fixed-point locations,
   way ids with their node refs, and the ``type=multipolygon`` relations with their member
   ways and nodes.  Ids only serve to turn refs into positions in the file; what stays is
   about 30 bytes per node and per way node ref of ``src`` (locations, grids, tables), and
   a write pass adds 4 bytes per object plus 8 per 64 boxes of its batch;
2. per box, numpy on those arrays computes the id sets of ``write_extract``'s rules for a
   single box: nodes in the box; ways with a node in it, or with a segment crossing it
   (Liang-Barsky, :func:`segments_hit_box`, the vector form of
   :func:`~osmseg.osm.localfile.segment_hits_box`) whose two ends lie in the box grown by
   ``reach``; the multipolygons with one of those ways as member, their member ways and
   member nodes; the nodes of all ways kept.  Grid indexes over nodes and segments make this
   cost per box what the box holds, not what the file holds. With ``enclosing=True`` the
   ways whose bounding box meets the box, the multipolygons whose bounding box holds it and
   the coastline near it join them (:mod:`osmseg.osm.enclosing`: bounding boxes from one ``reduceat`` per file);
3. one streaming write pass per batch hands each object to the writer of every box of the
   batch that keeps it.  All writers of a batch are open at once (each an open file and an
   osmium writer thread), so boxes go in batches of ``batch`` (256; fewer when the process
   may open fewer files): the write pass runs once per batch.

Equivalences that make step 2 exact rather than close: a node counts as in the box when it
lies in the box *and* in the grown box (``_nodes_near`` drops nodes outside the grown box
first, which matters only where ``pad_bbox`` clamps at +-85.05 degrees); a way whose segment
has both ends in the grown box and meets the box is kept whether or not an end lies in the
box itself (an end in the box keeps the way anyway); locations are compared as the same
doubles osmium gives (fixed-point / 1e7).  Files whose node, way or relation ids repeat
(history files) are refused with :class:`NotCuttable` before anything is written: the
caller cuts those box by box.

Every file is written to a temporary name and moved over its real name only when its batch
succeeded (:func:`osmseg.output.atomic.atomic_path`); an exception leaves the batch's
temporary files removed and its real names untouched.
"""

from __future__ import annotations

import errno
import logging
import shutil
from array import array
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import osmium

from osmseg.errors import OSMDataError, first_line
from osmseg.grid import LngLatBBox, pad_bbox
from osmseg.osm.enclosing import Enclosing, enclosing_index, enclosing_keep
from osmseg.output.atomic import atomic_path

logger = logging.getLogger(__name__)

Ints = npt.NDArray[np.integer[Any]]  # ids and offsets: int64; positions: int32 (int64 past 2**31 objects)
Floats = npt.NDArray[np.float64]
Bools = npt.NDArray[np.bool_]

#: Boxes written per write pass (all their files are open at once).
DEFAULT_BATCH = 256
#: Bytes each writer gathers before handing them to osmium's encoder (its default is 4 MB,
#: times a few hundred writers); PBF blocks do not depend on it, so the files stay the same.
_BUFFER = 1 << 16
#: Degrees by which the segment grid's query reaches past a box: more than any rounding error
#: that could let Liang-Barsky find a segment meeting a box its bounding box does not touch.
_SLACK = 1e-9
#: Smallest grid cell in degrees (keeps cell keys inside int64 for tiny boxes).
_MIN_CELL = 1e-5
_KINDS = {"n": 0, "w": 1, "r": 2}


class NotCuttable(ValueError):
    """The file cannot be cut in one pass (its ids repeat); cut it box by box instead."""


def segments_hit_box(x0: Floats, y0: Floats, x1: Floats, y1: Floats, box: LngLatBBox) -> Bools:
    """For each segment (x0, y0)-(x1, y1), whether it meets ``box``: exactly
    :func:`osmseg.osm.localfile.segment_hits_box` (same float operations, same order).

    >>> b = LngLatBBox(0, 0, 1, 1)
    >>> segments_hit_box(np.array([-1., -1, -1, -1]), np.array([.5, 1.9, .5, -1]),
    ...                  np.array([2., 1.9, .5, -.5]), np.array([.5, -1, 2, 3]), b).tolist()
    [True, True, False, False]
    """
    dx, dy = x1 - x0, y1 - y0
    t0, t1 = np.zeros(len(x0)), np.ones(len(x0))
    hit = np.ones(len(x0), dtype=bool)
    for step, gap in ((-dx, x0 - box.west), (dx, box.east - x0), (-dy, y0 - box.south), (dy, box.north - y0)):
        flat = step == 0
        hit &= ~(flat & (gap < 0))
        t = gap / np.where(flat, 1.0, step)
        t0 = np.where(step < 0, np.maximum(t0, t), t0)
        t1 = np.where(step > 0, np.minimum(t1, t), t1)
    return hit & (t0 <= t1)


def _gather(offsets: Ints, values: Ints, rows: Ints) -> Ints:
    """``values[offsets[r]:offsets[r + 1]]`` for every r of ``rows``, concatenated."""
    return _ranges(values, offsets[rows], offsets[rows + 1])


def _ranges(values: Ints, starts: Ints, ends: Ints) -> Ints:
    """``values[s:e]`` for every (s, e) of ``starts``, ``ends``, concatenated."""
    lengths = ends - starts
    total = int(lengths.sum())
    if total == 0:
        return values[:0]
    shift = np.repeat(starts - (np.cumsum(lengths) - lengths), lengths)
    return values[shift + np.arange(total)]


def _csr(keys: Ints, values: Ints, n: int) -> tuple[Ints, Ints]:
    """Offsets and values grouping ``values`` by ``keys`` (0 <= key < n), in input order per key."""
    order = np.argsort(keys, kind="stable")
    offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(keys, minlength=n), out=offsets[1:])
    return offsets, values[order]


def _lookup(sorted_ids: Ints, order: Ints, wanted: Ints) -> Ints:
    """Position in the file of each id of ``wanted`` (``order``'s dtype), -1 for ids it does not hold."""
    if len(sorted_ids) == 0:
        return np.full(len(wanted), -1, dtype=order.dtype)
    at = np.minimum(np.searchsorted(sorted_ids, wanted), len(sorted_ids) - 1)
    return np.where(sorted_ids[at] == wanted, order[at], -1).astype(order.dtype)


def _sorted_unique(ids: Ints, what: str, pos: Any) -> tuple[Ints, Ints]:
    """``ids`` sorted and the positions in ``ids`` (dtype ``pos``) of each; NotCuttable if an id repeats."""
    order = np.argsort(ids, kind="stable")
    ordered = ids[order]
    if len(ordered) > 1 and bool((ordered[1:] == ordered[:-1]).any()):
        raise NotCuttable(f"{what} ids repeat in the file")
    return ordered, order.astype(pos)


@dataclass
class _Grid:
    """Points bucketed by cell of a regular lon/lat grid, for box queries."""

    width: float
    height: float
    columns: int
    rows: int
    keys: Ints  # sorted cell keys (row * columns + column)
    items: Ints  # item of each key

    @classmethod
    def build(cls, lon: Floats, lat: Floats, items: Ints, width: float, height: float) -> _Grid:
        width, height = max(width, _MIN_CELL), max(height, _MIN_CELL)
        grid = cls(width, height, int(360.0 / width) + 3, int(180.0 / height) + 3, items[:0], items[:0])
        keys = grid._row(lat) * grid.columns + grid._column(lon)
        order = np.argsort(keys, kind="stable")
        grid.keys, grid.items = keys[order], items[order]
        return grid

    # cells are non-decreasing in the coordinate: a point >= a bound lies in a cell >= the bound's
    def _column(self, lon: Any) -> Ints:
        return np.clip(np.floor((np.asarray(lon, dtype=np.float64) + 180.0) / self.width).astype(np.int64),
                       0, self.columns - 1)

    def _row(self, lat: Any) -> Ints:
        return np.clip(np.floor((np.asarray(lat, dtype=np.float64) + 90.0) / self.height).astype(np.int64),
                       0, self.rows - 1)

    def query(self, west: float, south: float, east: float, north: float) -> Ints:
        """Items in the cells covering the box (a superset of those inside it)."""
        rows = np.arange(int(self._row(south)), int(self._row(north)) + 1, dtype=np.int64) * self.columns
        lo = np.searchsorted(self.keys, rows + self._column(west), side="left")
        hi = np.searchsorted(self.keys, rows + self._column(east), side="right")
        return _ranges(self.items, lo, hi)


@dataclass
class _Index:
    """What one pass over the file leaves: positions in file order (the i-th node, way,
    multipolygon) stand for objects; grids and CSR tables answer the per-box rules."""

    counts: tuple[int, int, int]  # nodes, ways, relations in the file
    x: Ints  # node locations in osmium's fixed point (int32, 1e-7 degrees)
    y: Ints
    located: Bools
    node_grid: _Grid
    way_offsets: Ints  # way -> its node positions (-1: not in the file)
    way_nodes: Ints
    node_way_offsets: Ints  # node -> ways referring to it
    node_ways: Ints
    seg_a: Ints  # segments between two located nodes, by node position
    seg_b: Ints
    seg_way: Ints
    seg_grid: _Grid  # short segments by the cell of their bounding box's south-west corner
    long_segments: Ints  # the others: checked against every box
    cell: tuple[float, float]
    way_rel_offsets: Ints  # way -> multipolygons with it as member
    way_rels: Ints
    rel_way_offsets: Ints  # multipolygon -> member way positions
    rel_ways: Ints
    rel_node_offsets: Ints  # multipolygon -> member node positions
    rel_nodes: Ints
    rel_position: Ints  # multipolygon -> its position among the file's relations
    enclosing: Enclosing | None = None  # areas holding a box and coastline near it (enclosing=True)


def _collect(src: str) -> tuple[array[int], ...]:
    """The one collecting pass over ``src``, into compact arrays: node ids and fixed-point x, y; way
    ids, their sizes and node refs; relation ids; and of the multipolygons, their position among
    the relations, member ways and their counts, member nodes and their counts."""
    node_ids, xs, ys = array("q"), array("i"), array("i")
    way_ids, way_sizes, refs, coast = array("q"), array("q"), array("q"), array("q")
    rel_ids, mp_position = array("q"), array("q")
    mp_ways, mp_way_sizes, mp_nodes, mp_node_sizes = array("q"), array("q"), array("q"), array("q")
    for obj in osmium.FileProcessor(src, osmium.osm.NODE | osmium.osm.WAY | osmium.osm.RELATION):
        if isinstance(obj, osmium.osm.Node):
            node_ids.append(obj.id)
            loc = obj.location
            xs.append(loc.x)
            ys.append(loc.y)
        elif isinstance(obj, osmium.osm.Way):
            way_ids.append(obj.id)
            before = len(refs)
            refs.extend([nd.ref for nd in obj.nodes])
            way_sizes.append(len(refs) - before)
            if obj.tags.get("natural") == "coastline":
                coast.append(len(way_ids) - 1)
        elif isinstance(obj, osmium.osm.Relation):
            if obj.tags.get("type") == "multipolygon":
                mp_position.append(len(rel_ids))
                members = [(m.type, m.ref) for m in obj.members]
                ways = [ref for t, ref in members if t == "w"]
                nodes = [ref for t, ref in members if t == "n"]
                mp_ways.extend(ways)
                mp_way_sizes.append(len(ways))
                mp_nodes.extend(nodes)
                mp_node_sizes.append(len(nodes))
            rel_ids.append(obj.id)
    return (node_ids, xs, ys, way_ids, way_sizes, refs, rel_ids, mp_position, mp_ways, mp_way_sizes, mp_nodes,
            mp_node_sizes, coast)


def _read(src: str, boxes: Sequence[LngLatBBox], reach: float, enclosing: bool = False) -> _Index:
    """The one collecting pass over ``src`` and the indexes for ``boxes`` (``enclosing``: and for
    the areas holding a box and the coast near it, :mod:`osmseg.osm.enclosing`)."""
    (node_ids, xs, ys, way_ids, way_sizes, refs, rel_ids, mp_position, mp_ways, mp_way_sizes, mp_nodes,
     mp_node_sizes, coast) = _collect(src)
    ids = np.frombuffer(node_ids, dtype=np.int64) if node_ids else np.zeros(0, np.int64)
    x = np.frombuffer(xs, dtype=np.int32) if xs else np.zeros(0, np.int32)
    y = np.frombuffer(ys, dtype=np.int32) if ys else np.zeros(0, np.int32)
    n_nodes, n_ways, n_mps = len(ids), len(way_ids), len(mp_position)
    pos = np.int32 if max(n_nodes, n_ways, len(rel_ids), len(refs)) < 2**31 - 1 else np.int64
    node_sorted, node_order = _sorted_unique(ids, "node", pos)
    way_sorted, way_order = _sorted_unique(_ints(way_ids), "way", pos)
    _sorted_unique(_ints(rel_ids), "relation", pos)
    del ids

    # osmium's Location.valid() and Location.lon/lat (fixed point / 1e7, in double)
    located = (x >= -1_800_000_000) & (x <= 1_800_000_000) & (y >= -900_000_000) & (y <= 900_000_000)
    cell_w = max(b.east - b.west for b in boxes)
    cell_h = max(b.north - b.south for b in boxes)
    where = np.flatnonzero(located).astype(pos)
    node_grid = _Grid.build(_lon(x, where), _lon(y, where), where, cell_w, cell_h)

    sizes = _ints(way_sizes)
    way_offsets = np.zeros(n_ways + 1, dtype=np.int64)
    np.cumsum(sizes, out=way_offsets[1:])
    way_nodes = _lookup(node_sorted, node_order, _ints(refs))
    del refs
    way_of_ref = np.repeat(np.arange(n_ways, dtype=pos), sizes)
    known = way_nodes >= 0
    node_way_offsets, node_ways = _csr(way_nodes[known], way_of_ref[known], n_nodes)

    # segments: consecutive refs of one way, both ends located, short enough for some grown box
    a, b, seg_way = way_nodes[:-1], way_nodes[1:], way_of_ref[:-1]
    keep = (way_of_ref[1:] == seg_way) & (a >= 0) & (b >= 0)
    keep[keep] = located[a[keep]] & located[b[keep]]
    a, b, seg_way = a[keep], b[keep], seg_way[keep]
    west, east = np.minimum(_lon(x, a), _lon(x, b)), np.maximum(_lon(x, a), _lon(x, b))
    south, north = np.minimum(_lon(y, a), _lon(y, b)), np.maximum(_lon(y, a), _lon(y, b))
    grown = [pad_bbox(box, reach) for box in boxes]
    # both ends in a grown box g => (east - west) <= (g.east - g.west) in floats too
    fits = ((east - west <= max(g.east - g.west for g in grown))
            & (north - south <= max(g.north - g.south for g in grown)))
    short = fits & (east - west <= cell_w) & (north - south <= cell_h)
    a, b, seg_way, is_short = a[fits], b[fits], seg_way[fits], short[fits]
    west, south = west[fits], south[fits]
    shorts = np.flatnonzero(is_short).astype(pos)
    seg_grid = _Grid.build(west[shorts], south[shorts], shorts, cell_w, cell_h)

    mp_way_pos = _lookup(way_sorted, way_order, _ints(mp_ways))
    mp_node_pos = _lookup(node_sorted, node_order, _ints(mp_nodes))
    rel_way_offsets = np.zeros(n_mps + 1, dtype=np.int64)
    np.cumsum(_ints(mp_way_sizes), out=rel_way_offsets[1:])
    rel_node_offsets = np.zeros(n_mps + 1, dtype=np.int64)
    np.cumsum(_ints(mp_node_sizes), out=rel_node_offsets[1:])
    rel_of_member = np.repeat(np.arange(n_mps, dtype=pos), _ints(mp_way_sizes))
    member = mp_way_pos >= 0
    way_rel_offsets, way_rels = _csr(mp_way_pos[member], rel_of_member[member], n_ways)
    areas = None if not enclosing else enclosing_index(x, y, located, way_offsets, way_nodes, _ints(coast),
                                                        rel_way_offsets, mp_way_pos, boxes)
    return _Index(
        counts=(n_nodes, n_ways, len(rel_ids)), x=x, y=y, located=located, node_grid=node_grid,
        way_offsets=way_offsets, way_nodes=way_nodes, node_way_offsets=node_way_offsets, node_ways=node_ways,
        seg_a=a, seg_b=b, seg_way=seg_way, seg_grid=seg_grid, long_segments=np.flatnonzero(~is_short).astype(pos),
        cell=(max(cell_w, _MIN_CELL), max(cell_h, _MIN_CELL)), way_rel_offsets=way_rel_offsets, way_rels=way_rels,
        rel_way_offsets=rel_way_offsets, rel_ways=mp_way_pos,
        rel_node_offsets=rel_node_offsets, rel_nodes=mp_node_pos, rel_position=_ints(mp_position), enclosing=areas)



def _ints(values: array[int]) -> Ints:
    return np.frombuffer(values, dtype=np.int64) if values else np.zeros(0, np.int64)


def _lon(fixed: Ints, points: Ints) -> Floats:
    """Degrees of the fixed-point coordinates at ``points``: the doubles osmium's Location.lon/lat give."""
    return fixed[points] / 10_000_000


def _inside(index: _Index, points: Ints, box: LngLatBBox) -> Bools:
    """Which of the located node ``points`` lie in ``box`` (edges included)."""
    lon, lat = _lon(index.x, points), _lon(index.y, points)
    return (box.west <= lon) & (lon <= box.east) & (box.south <= lat) & (lat <= box.north)


def keep_sets(index: _Index, box: LngLatBBox, reach: float) -> tuple[Ints, Ints, Ints]:
    """Positions (file order) of the nodes, ways and relations ``write_extract`` keeps for ``box``."""
    grown = pad_bbox(box, reach)
    near = index.node_grid.query(*box)
    inside = np.unique(near[_inside(index, near, box) & _inside(index, near, grown)])
    ways = _gather(index.node_way_offsets, index.node_ways, inside)

    width, height = index.cell
    seg = np.concatenate([index.seg_grid.query(box.west - width - _SLACK, box.south - height - _SLACK,
                                               box.east + _SLACK, box.north + _SLACK), index.long_segments])
    ends_a, ends_b = index.seg_a[seg], index.seg_b[seg]
    seg = seg[_inside(index, ends_a, grown) & _inside(index, ends_b, grown)]
    ends_a, ends_b = index.seg_a[seg], index.seg_b[seg]
    hits = segments_hit_box(_lon(index.x, ends_a), _lon(index.y, ends_a), _lon(index.x, ends_b), _lon(index.y, ends_b),
                            box)
    found = [ways, index.seg_way[seg[hits]]]
    held: Ints = np.zeros(0, np.int64)
    if index.enclosing is not None:
        around, held = enclosing_keep(index.enclosing, box)
        found.append(around)
    kept = np.unique(np.concatenate(found))

    rels = np.union1d(_gather(index.way_rel_offsets, index.way_rels, kept), held)
    members = _gather(index.rel_way_offsets, index.rel_ways, rels)
    ways = np.union1d(kept, members[members >= 0])
    nodes = np.concatenate([inside, _gather(index.rel_node_offsets, index.rel_nodes, rels),
                            _gather(index.way_offsets, index.way_nodes, ways)])
    nodes = np.unique(nodes[nodes >= 0])
    return nodes, ways, index.rel_position[rels]


def batch_size(wanted: int = DEFAULT_BATCH) -> int:
    """``wanted``, or fewer when the process may not open two files per box of a batch."""
    try:
        import resource  # POSIX only
    except ImportError:
        return wanted
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY:
        return wanted
    return max(1, min(wanted, (soft - 64) // 2))


def write_extracts(src: Path, jobs: Sequence[tuple[LngLatBBox, Path]], reach: float,
                   header: Callable[[LngLatBBox], osmium.io.Header], done: Callable[[int, dict[str, int]], object],
                   one_by_one: Callable[[LngLatBBox, Path], dict[str, int]], batch: int = DEFAULT_BATCH,
                   enclosing: bool = False) -> None:
    """Write for every (box, out) of ``jobs`` the file ``write_extract(src, [box], out, reach, enclosing)`` writes.

    ``header(box)`` gives each file's header; ``done(i, counts)`` is called for job ``i`` (with
    its numbers of nodes, ways, relations written) once its file is in place, batch by batch,
    so an interruption keeps the batches finished before it.  Reads ``src`` once, then once per
    batch of ``batch`` boxes.  A file whose ids repeat (:class:`NotCuttable`, found before
    anything is written) is cut box by box with ``one_by_one(box, out)`` instead.
    """
    if not jobs:
        return
    src_name = str(src)
    try:
        try:
            index = _read(src_name, [box for box, _ in jobs], reach, enclosing)
        except NotCuttable as exc:
            logger.info("%s: %s; cutting %d boxes one by one", src, exc, len(jobs))
            for i, (box, out) in enumerate(jobs):
                done(i, one_by_one(box, out))
            return
        size = batch_size(batch)
        for start in range(0, len(jobs), size):
            part = jobs[start:start + size]
            counts = _write_batch(src_name, index, part, reach, header)
            for i, c in enumerate(counts):
                done(start + i, c)
    except RuntimeError as exc:
        raise OSMDataError(f"--osm {src}: cannot read it as OSM data ({first_line(exc)}); "
                           "give a valid .osm/.osm.pbf/.osm.bz2 file") from None


#: Bytes per OSM object that the free-space check before writing extracts counts on: a city
#: extract takes ~16 bytes per object as PBF, so this is four times what a write can need.
BYTES_PER_OBJECT = 64


def ensure_room(folder: Path, objects: int) -> None:
    """Raise ``OSError(ENOSPC)`` unless ``folder``'s disk has room for PBF files of ``objects``
    objects (:data:`BYTES_PER_OBJECT` each, plus a megabyte).

    Checked before osmium writes: pyosmium cannot recover from a write that fails for lack of
    space (the process aborts when the writer is closed or collected), so a full disk must be
    found first, and then it is the one-line "disk is full" error every other write gives.
    """
    folder.mkdir(parents=True, exist_ok=True)
    need = objects * BYTES_PER_OBJECT + (1 << 20)
    free = shutil.disk_usage(folder).free
    if free < need:
        raise OSError(errno.ENOSPC, f"No space left on device: OSM extracts need about {need // (1 << 20) + 1} MB, "
                      f"{free // (1 << 20)} MB are free", str(folder))


def _write_batch(src: str, index: _Index, jobs: Sequence[tuple[LngLatBBox, Path]], reach: float,
                 header: Callable[[LngLatBBox], osmium.io.Header]) -> list[dict[str, int]]:
    """One write pass: the files of up to a few hundred boxes (all open at once)."""
    words = (len(jobs) + 63) // 64
    masks = [np.zeros((n, words), dtype=np.uint64) for n in index.counts]
    counts = []
    for k, (box, _) in enumerate(jobs):
        kept = keep_sets(index, box, reach)
        for mask, positions in zip(masks, kept):
            mask[positions, k // 64] |= np.uint64(1 << (k % 64))
        counts.append({"n": len(kept[0]), "w": len(kept[1]), "r": len(kept[2])})
    ensure_room(jobs[0][1].parent, sum(sum(c.values()) for c in counts))
    with ExitStack() as stack:
        writers = []
        for box, out in jobs:
            tmp = stack.enter_context(atomic_path(out))
            writers.append(stack.enter_context(osmium.SimpleWriter(osmium.io.File(str(tmp), "pbf"), bufsz=_BUFFER,
                                                                   header=header(box), overwrite=True)))
        adders: tuple[list[Callable[[Any], None]], ...] = (
            [w.add_node for w in writers], [w.add_way for w in writers], [w.add_relation for w in writers])
        plans, groups = zip(*(_plan(mask, add) for mask, add in zip(masks, adders)))
        seen = [0, 0, 0]
        for obj in osmium.FileProcessor(src, osmium.osm.NODE | osmium.osm.WAY | osmium.osm.RELATION):
            kind = _KINDS[obj.type_str()]
            i = seen[kind]
            seen[kind] = i + 1
            if i >= index.counts[kind]:
                raise OSMDataError(f"--osm {src}: the file changed while it was cut; run the same command again")
            for add in groups[kind][plans[kind][i]]:
                add(obj)
        if tuple(seen) != index.counts:
            raise OSMDataError(f"--osm {src}: the file changed while it was cut; run the same command again")
    return counts


def _plan(mask: npt.NDArray[np.uint64], adders: list[Callable[[Any], None]]
          ) -> tuple[memoryview, list[tuple[Any, ...]]]:
    """For each object (row of ``mask``: one bit per box), the index of its tuple of ``adders``."""
    rows = np.flatnonzero(mask.any(axis=1))
    plan = np.zeros(len(mask), dtype=np.int32)
    groups: list[tuple[Any, ...]] = [()]
    if len(rows):
        sets, inverse = np.unique(mask[rows], axis=0, return_inverse=True)
        plan[rows] = inverse.reshape(-1) + 1
        bits = np.unpackbits(sets.astype("<u8").view(np.uint8), axis=1, bitorder="little")[:, :len(adders)]
        groups += [tuple(adders[k] for k in np.flatnonzero(row)) for row in bits]
    return plan.data, groups
