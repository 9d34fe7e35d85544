"""Where the builder's samples fall: tile blocks for sampling that never overlaps.

Random centres drawn independently (what keeps ``--shard`` exact) can land near each other;
:func:`osmseg.overlap.overlap_groups` finds the samples that overlap.

**Non-overlapping sampling** (``osmseg build --no-overlap``). The area's tile grid is cut into
blocks of ``grid_size x grid_size`` tiles aligned on multiples of ``grid_size``; a block is a
candidate when its centre lies in the area. The candidates are shuffled once by the seed, and
attempt ``a`` of slot ``s`` takes candidate ``a * samples + s``: every attempt of every slot
gets its own block, so no two samples (nor a sample and a rejected draw) ever share a pixel,
and an attempt's block still depends only on (seed, slot, attempt), which keeps shards and
resumed builds exact. Blocks are equally likely (uniform over the Web Mercator plane, which
over a city or a region is uniform over the ground within a fraction of a percent).
"""

from __future__ import annotations

import functools
import math

import mercantile
import numpy as np

from osmseg.errors import ConfigError
from osmseg.grid import LngLatBBox
from osmseg.places import Area, haversine_m

#: Enumerating more candidate blocks than this is refused (an area too large for --no-overlap at
#: this zoom; random sampling rarely overlaps there anyway).
MAX_BLOCKS = 5_000_000


def block_centre(bx: int, by: int, zoom: int, grid_size: int) -> tuple[float, float]:
    """(lon, lat) of the centre of tile block (bx, by): the middle tile's centre.

    >>> [round(v, 6) for v in block_centre(0, 0, 1, 1)]
    [-90.0, 66.51326]
    """
    lon, lat = block_centres(np.array([bx]), np.array([by]), zoom, grid_size)[0]
    return float(lon), float(lat)


def block_centres(bx: np.ndarray, by: np.ndarray, zoom: int, grid_size: int) -> np.ndarray:
    """``(k, 2)`` (lon, lat) centres of many tile blocks at once (as :func:`block_centre`)."""
    n = 2.0**zoom
    half = grid_size // 2
    x = (np.asarray(bx) * grid_size + half + 0.5) / n
    y = (np.asarray(by) * grid_size + half + 0.5) / n
    return np.column_stack([x * 360.0 - 180.0, np.degrees(np.arctan(np.sinh(np.pi * (1.0 - 2.0 * y))))])


def _lon_ranges(west: float, east: float) -> list[tuple[float, float]]:
    """A longitude interval as one or two within [-180, 180] (a disc across the antimeridian)."""
    if east - west >= 360.0:
        return [(-180.0, 180.0)]
    if west < -180.0:
        return [(west + 360.0, 180.0), (-180.0, east)]
    if east > 180.0:
        return [(west, 180.0), (-180.0, east - 360.0)]
    return [(west, east)]


@functools.lru_cache(maxsize=8)
def candidate_blocks(area: Area, zoom: int, grid_size: int, seed: int) -> np.ndarray:
    """The area's candidate blocks ``(k, 2)`` as (bx, by), in the seed's shuffled order."""
    if area.bbox is not None:
        box = area.bbox
    else:
        assert area.radius_km is not None
        dlat = area.radius_km / 111.32
        dlon = area.radius_km / (111.32 * max(math.cos(math.radians(min(abs(area.lat) + dlat, 89.9))), 1e-6))
        box = LngLatBBox(area.lon - dlon, max(area.lat - dlat, -85.05), area.lon + dlon, min(area.lat + dlat, 85.05))
    full = 2**zoom // grid_size  # whole blocks only: a partial block at the world's edge is not a sample
    ranges = []
    for west, east in _lon_ranges(box.west, box.east):
        nw = mercantile.tile(west, box.north, zoom)
        se = mercantile.tile(east, box.south, zoom)
        ranges.append((nw.x // grid_size, min(se.x // grid_size, full - 1),
                       nw.y // grid_size, min(se.y // grid_size, full - 1)))
    count = sum((x1 - x0 + 1) * (y1 - y0 + 1) for x0, x1, y0, y1 in ranges)
    if count > MAX_BLOCKS:
        raise ConfigError(f"--no-overlap: the area holds {count:,} tile blocks at zoom {zoom}, too many to enumerate; "
                          "sample a smaller area, or drop --no-overlap (overlaps are rare in areas this large)")
    parts = []
    for x0, x1, y0, y1 in ranges:
        bx, by = np.meshgrid(np.arange(x0, x1 + 1), np.arange(y0, y1 + 1), indexing="xy")
        parts.append(np.column_stack([bx.ravel(), by.ravel()]))
    blocks = np.unique(np.concatenate(parts), axis=0)  # sorted, and a block counted once
    centres = block_centres(blocks[:, 0], blocks[:, 1], zoom, grid_size)
    if area.bbox is not None:
        b = area.bbox
        inside = ((centres[:, 0] >= b.west) & (centres[:, 0] <= b.east) &
                  (centres[:, 1] >= b.south) & (centres[:, 1] <= b.north))
    else:
        assert area.radius_km is not None
        inside = haversine_m(area.lon, area.lat, centres[:, 0], centres[:, 1]) <= area.radius_km * 1000.0
    kept = blocks[inside]
    order = np.random.default_rng([seed, 0x6E6F6F76]).permutation(len(kept))  # "noov": its own stream
    return kept[order]


def block_attempt_centre(area: Area, zoom: int, grid_size: int, seed: int, samples: int,
                         slot: int, attempt: int) -> tuple[float, float] | None:
    """Centre of the block of attempt ``attempt`` of slot ``slot``; None when the area has no more blocks."""
    blocks = candidate_blocks(area, zoom, grid_size, seed)
    index = attempt * samples + slot
    if index >= len(blocks):
        return None
    bx, by = blocks[index]
    return block_centre(int(bx), int(by), zoom, grid_size)


def check_room(area: Area, zoom: int, grid_size: int, seed: int, samples: int) -> int:
    """The number of non-overlapping blocks in the area; ConfigError when fewer than ``samples``."""
    available = len(candidate_blocks(area, zoom, grid_size, seed))
    if available < samples:
        raise ConfigError(f"--no-overlap: the area holds only {available} non-overlapping samples of {grid_size}x"
                          f"{grid_size} tiles at zoom {zoom}; ask for at most {available} --samples, a larger area, "
                          "or a higher --zoom")
    return available
