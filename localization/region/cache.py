"""The region's blocks as drawn from OpenStreetMap, kept deflated in memory and (optionally) on disk.

Drawing a block (reading its OSM features, rasterising them) depends only on the OSM files,
the class table, the zoom and the block, not on the query. So every drawn block is kept
deflated (a few kB: memory stays small whatever the region's size), and with a cache folder
written there too, under a key of everything it depends on: the OSM files (resolved path,
size, modification time: a new extract is a new key), the class table's classes and rules,
and the block's tiles. A second query of the same region reads the blocks instead of drawing
them again, and answers the same.

**One pass over each OSM file per region, not one per block.** Reading a block's features
from the whole ``--osm`` file costs what the file holds, so a region of a few hundred blocks
in a city or country extract read that file a few hundred times. :meth:`BlockMasks.prepare`
instead hands the blocks a search will draw to the dataset builder's cutter
(:meth:`osmseg.osm.localfile.LocalFileSource.prepare` and ``.cut``: one set of passes over the
input for the region, one collecting pass and one write pass per 256 blocks over the small
region file), and each block is then read from its own small extract, padded as a build pads
a sample's (:data:`OSM_PADDING_M`). Unlike a build's, these extracts also hold every way whose
bounding box meets the block, the multipolygons around it and the coastline near it
(``enclosing=True``, :mod:`osmseg.osm.enclosing`): a block in the middle of a forest larger than
it is forest, a road of one long straight segment crosses it, as they are drawn from the whole
file. What a per-box cut still cannot see is listed there (a block at sea more than 5 km from
any coast, ``type=boundary`` areas, a way whose nodes are in another ``--osm`` file, negative
ids).
The region's cut of each input (the one pass over a city or country file) is kept in
``CACHE/osm`` with the input's extent and timestamp, so a rerun (a search killed while drawing,
another query of the region) does not read the big file again: it is named by every block the
search asked for, which a rerun asks for again. Each block's own extract is cut from it into a
folder of this search's own (``CACHE/osm/blocks-*``) and deleted once the block is drawn: the
drawing is what is kept, and a region of a thousand blocks no longer leaves a thousand extracts
in the cache. A folder a killed search left is removed by a later one after a day untouched.

Cache files are written to a temporary name and renamed, so a search killed mid-write leaves
no half file, and two searches drawing the same block write the same bytes.

Imports: numpy, osmseg core.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import tempfile
import time
import weakref
import zlib
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from osmseg.classes import ClassTable
from osmseg.grid import LngLatBBox, SampleGrid, pad_bbox
from osmseg.osm.features import read_features
from osmseg.osm.localfile import LocalFileSource
from osmseg.output.atomic import atomic_write_bytes
from osmseg.rasterize import rasterize
from osmseg.runtime.progress import Progress, track

__all__ = ["BlockMasks", "OSM_PADDING_M", "osm_key"]

#: bumped when the drawing of a block changes, so old cache entries are not read
#: (3: each block drawn from its own padded extract with the areas holding it; 2 lost those)
CACHE_VERSION = 3
#: metres of OSM read around each block, as ``osmseg build`` reads around a sample (its ``osm_padding_m``)
OSM_PADDING_M = 60.0
#: the name of a search's folder of block extracts in ``CACHE/osm``, and how long one must lie
#: untouched before another search removes it as left by a killed one
PASSING = "blocks-"
STALE_PASSING_S = 86400.0


def osm_key(osm: Sequence[Path | str], table: ClassTable, size: int) -> str:
    """A key of everything a drawn block depends on besides its tiles (16 hex digits)."""
    files = []
    for path in osm:
        p = Path(path).resolve()
        st = p.stat()
        files.append([str(p), st.st_size, st.st_mtime_ns])
    doc = {"version": CACHE_VERSION, "osm": files, "table": repr(table), "size": size}  # classes and their rules
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]


class BlockMasks:
    """Each block's class mask, drawn once: ``mask(b)`` for block ``b`` of ``grids``.

    ``cache_dir``: a folder for drawn blocks and the region's cut of each OSM file, shared between
    runs (None: memory and a temporary folder only). Call :meth:`prepare` with the blocks a search
    will draw before drawing them, so the OSM files are read once for all of them. ``drawn``
    and ``read`` count the blocks drawn from OSM and read from the cache; ``cuts`` the calls
    that cut blocks out of the OSM files.
    """

    def __init__(self, osm: Sequence[Path | str], table: ClassTable, grids: Sequence[SampleGrid],
                 cache_dir: Path | None = None) -> None:
        self.osm, self.table, self.grids = [Path(p) for p in osm], table, list(grids)
        self.folder = self.workdir = None
        if cache_dir is not None:
            self.folder = Path(cache_dir) / "region-blocks" / osm_key(self.osm, table, self.grids[0].size)
            self.workdir = Path(cache_dir) / "osm"
        self._packed: dict[int, bytes] = {}
        self._extracts: dict[int, list[Path]] = {}
        self._passing: Path | None = None
        self.drawn = self.read = self.cuts = 0

    def _file(self, b: int) -> Path | None:
        if self.folder is None:
            return None
        first = self.grids[b].tiles[0]
        return self.folder / f"{first.z}-{first.x}-{first.y}.bin"

    def _blocks_dir(self) -> Path:
        """Where the blocks' own extracts go: a folder removed with this object, in ``CACHE/osm``
        (the disk the cache was given, not a small or in-memory ``/tmp``) or the temporary folder."""
        if self._passing is None:
            where = None
            if self.workdir is not None:
                self.workdir.mkdir(parents=True, exist_ok=True)
                _sweep(self.workdir)
                where = str(self.workdir)
            self._passing = Path(tempfile.mkdtemp(prefix=PASSING, dir=where))
            weakref.finalize(self, shutil.rmtree, str(self._passing), True)
        return self._passing

    def _work(self) -> Path:
        """Where the region's cut of each OSM file goes: ``CACHE/osm``, else the temporary folder."""
        return self.workdir if self.workdir is not None else self._blocks_dir()

    def _cached(self, b: int) -> bytes | None:
        """Block ``b`` as deflated in memory or in the cache folder (None: not drawn yet)."""
        packed = self._packed.get(b)
        path = self._file(b)
        if packed is None and path is not None and path.is_file():
            grid = self.grids[b]
            packed = path.read_bytes()
            if len(zlib.decompress(packed)) != grid.height * grid.width:  # not ours: draw it again
                return None
            self._packed[b] = packed
            self.read += 1
        return packed

    def prepare(self, blocks: Iterable[int], progress: Progress | None = None) -> None:
        """Cut the OSM of those ``blocks`` not drawn yet out of each OSM file, in one pass over it
        (a country file takes minutes: ``progress`` hears of each file)."""
        wanted = list(dict.fromkeys(blocks))
        todo = [b for b in wanted if b not in self._extracts and self._cached(b) is None]
        if not todo:
            return
        boxes = [_within_the_world(pad_bbox(self.grids[b].bbox, OSM_PADDING_M)) for b in todo]
        for b in todo:
            self._extracts[b] = []
        for path in track(self.osm, progress, f"cutting {len(todo)} blocks out of the OSM", unit="file"):
            source = LocalFileSource(path, self._work(), enclosing=True, extracts=self._blocks_dir())
            if len(wanted) > 1:  # the region out of a big file: one set of passes over it, named by every
                # block asked for (not only those left to draw), so a rerun after a kill finds it again
                source.prepare([_within_the_world(pad_bbox(self.grids[b].bbox, OSM_PADDING_M)) for b in wanted])
            for b, extract in zip(todo, source.cut(boxes)):
                self._extracts[b] += extract.paths
        self.cuts += 1

    def mask(self, b: int) -> np.ndarray:
        """Block ``b``'s mask (class ids, uint8)."""
        grid = self.grids[b]
        packed = self._cached(b)
        if packed is None:
            self.prepare([b])  # a block nobody prepared: cut on its own
            extracts = self._extracts.pop(b)
            mask = rasterize(read_features(extracts, grid, self.table), grid, self.table)
            for cut in extracts:  # drawn: its drawing is kept, not its extract
                cut.unlink(missing_ok=True)
            packed = zlib.compress(np.ascontiguousarray(mask, np.uint8).tobytes(), 1)
            self.drawn += 1
            path = self._file(b)
            if path is not None:
                atomic_write_bytes(path, packed, durable=False)
            self._packed[b] = packed
        return np.frombuffer(zlib.decompress(packed), np.uint8).reshape(grid.height, grid.width)


def _sweep(folder: Path, age_s: float = STALE_PASSING_S) -> None:
    """Remove the blocks' folders that searches killed outright (``kill -9``, a power cut) left in
    ``folder``: those untouched for ``age_s`` (a search drawing its blocks touches its folder with
    every block)."""
    now = time.time()
    for old in folder.glob(f"{PASSING}*"):
        try:
            if old.is_dir() and now - old.stat().st_mtime > age_s:
                shutil.rmtree(old, ignore_errors=True)
        except OSError:  # another search removed it first
            continue


def _within_the_world(box: LngLatBBox) -> LngLatBBox:
    """``box`` with its longitudes kept within ±180° (a block padded past the antimeridian).

    >>> _within_the_world(LngLatBBox(179.9, -16.8, 180.001, -16.7))
    LngLatBBox(west=179.9, south=-16.8, east=180.0, north=-16.7)
    """
    return box._replace(west=max(box.west, -180.0), east=min(box.east, 180.0))
