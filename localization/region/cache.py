"""The region's blocks as drawn from OpenStreetMap, kept deflated in memory and (optionally) on disk.

Drawing a block (reading its OSM features, rasterising them) is most of a region search's
first pass, and it depends only on the OSM files, the class table, the zoom and the block, not
on the query. So every drawn block is kept deflated (a few kB: memory stays small whatever the
region's size), and with a cache folder written there too, under a key of everything it
depends on: the OSM files (resolved path, size, modification time: a new extract is a new
key), the class table's classes and rules, and the block's tiles. A second query of the same
region reads the blocks instead of drawing them again, and answers the same.

Cache files are written to a temporary name and renamed, so a search killed mid-write leaves
no half file, and two searches drawing the same block write the same bytes.

Imports: numpy, osmseg core.
"""

from __future__ import annotations

import hashlib
import json
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from osmseg.classes import ClassTable
from osmseg.grid import SampleGrid
from osmseg.osm.features import read_features
from osmseg.output.atomic import atomic_write_bytes
from osmseg.rasterize import rasterize

__all__ = ["BlockMasks", "osm_key"]

#: bumped when the drawing of a block changes, so old cache entries are not read
CACHE_VERSION = 1


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

    ``cache_dir``: a folder for drawn blocks shared between runs (None: memory only). ``drawn``
    and ``read`` count the blocks drawn from OSM and read from the cache.
    """

    def __init__(self, osm: Sequence[Path | str], table: ClassTable, grids: Sequence[SampleGrid],
                 cache_dir: Path | None = None) -> None:
        self.osm, self.table, self.grids = [Path(p) for p in osm], table, list(grids)
        self.folder = None
        if cache_dir is not None:
            self.folder = Path(cache_dir) / "region-blocks" / osm_key(self.osm, table, self.grids[0].size)
        self._packed: dict[int, bytes] = {}
        self.drawn = self.read = 0

    def _file(self, b: int) -> Path | None:
        if self.folder is None:
            return None
        first = self.grids[b].tiles[0]
        return self.folder / f"{first.z}-{first.x}-{first.y}.bin"

    def mask(self, b: int) -> np.ndarray:
        """Block ``b``'s mask (class ids, uint8)."""
        grid = self.grids[b]
        packed = self._packed.get(b)
        if packed is None:
            path = self._file(b)
            if path is not None and path.is_file():
                packed = path.read_bytes()
                if len(zlib.decompress(packed)) != grid.height * grid.width:  # not ours: draw it again
                    packed = None
                else:
                    self.read += 1
            if packed is None:
                mask = rasterize(read_features(list(self.osm), grid, self.table), grid, self.table)
                packed = zlib.compress(np.ascontiguousarray(mask, np.uint8).tobytes(), 1)
                self.drawn += 1
                if path is not None:
                    atomic_write_bytes(path, packed, durable=False)
            self._packed[b] = packed
        return np.frombuffer(zlib.decompress(packed), np.uint8).reshape(grid.height, grid.width)
