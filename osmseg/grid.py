"""The pixel grid of one sample: a square block of Web Mercator tiles.

A sample is ``size x size`` tiles (5 x 5 in the dissertation) of 256 px around the
tile that holds its centre point, merged into one ``1280 x 1280`` image.  Everything
downstream (imagery, OSM rasterisation, GeoTIFF output) shares this grid, so masks
and images line up by construction.

Pure functions over :mod:`mercantile`, returning small immutable values.

>>> g = sample_grid(13.4050, 52.5200, zoom=18)
>>> g.width, g.height, len(g.tiles)
(1280, 1280, 25)
>>> g.tiles[12] == mercantile.tile(13.4050, 52.5200, 18)
True
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import mercantile
from affine import Affine
from pyproj import CRS, Geod, Transformer
from pyproj.exceptions import CRSError, ProjError

TILE_SIZE = 256
EARTH_CIRCUMFERENCE = 2 * math.pi * 6378137.0
#: Pixels more than this many times larger or smaller than the ones wanted are worth a warning:
#: ``osmseg predict`` when an input's are that far from the training data's, ``osmseg build``
#: when ``--zoom`` asks for pixels that much finer than a local raster's (upsampled, no detail).
RESOLUTION_MISMATCH = 1.5


class LngLatBBox(NamedTuple):
    """A WGS84 bounding box: west, south, east, north in degrees."""

    west: float
    south: float
    east: float
    north: float


class XYBounds(NamedTuple):
    """A Web Mercator (EPSG:3857) box in metres: left, bottom, right, top."""

    left: float
    bottom: float
    right: float
    top: float


@dataclass(frozen=True)
class SampleGrid:
    """The tiles and pixel grid of one sample.

    Attributes:
        lon, lat: the sampled centre point (degrees).
        zoom: the tile zoom level.
        tiles: ``size * size`` tiles in row-major order (north-west first).
        size: tiles per side.
    """

    lon: float
    lat: float
    zoom: int
    tiles: tuple[mercantile.Tile, ...]
    size: int = 5

    @property
    def width(self) -> int:
        """Image width in pixels."""
        return self.size * TILE_SIZE

    @property
    def height(self) -> int:
        """Image height in pixels."""
        return self.size * TILE_SIZE

    @property
    def xy_bounds(self) -> XYBounds:
        """Outer bounds of the tile block in EPSG:3857 metres."""
        nw = mercantile.xy_bounds(self.tiles[0])
        se = mercantile.xy_bounds(self.tiles[-1])
        return XYBounds(nw.left, se.bottom, se.right, nw.top)

    @property
    def bbox(self) -> LngLatBBox:
        """Outer bounds of the tile block in WGS84 degrees."""
        nw = mercantile.bounds(self.tiles[0])
        se = mercantile.bounds(self.tiles[-1])
        return LngLatBBox(nw.west, se.south, se.east, nw.north)

    @property
    def transform(self) -> Affine:
        """Affine transform from (col, row) pixel to EPSG:3857 (x, y)."""
        b = self.xy_bounds
        res = (b.right - b.left) / self.width
        return Affine(res, 0.0, b.left, 0.0, -res, b.top)

    @property
    def pixel_size(self) -> float:
        """Pixel side in Web Mercator metres (not ground metres; see ground_resolution)."""
        return float(EARTH_CIRCUMFERENCE / (TILE_SIZE * 2**self.zoom))

    @property
    def ground_resolution(self) -> float:
        """Pixel side on the ground in metres at the centre latitude."""
        return ground_resolution(self.lat, self.zoom)

    def tile_offset(self, index: int) -> tuple[int, int]:
        """Pixel (col, row) of the top-left corner of ``tiles[index]`` in the merged image."""
        row, col = divmod(index, self.size)
        return col * TILE_SIZE, row * TILE_SIZE


def sample_grid(lon: float, lat: float, zoom: int, size: int = 5) -> SampleGrid:
    """The ``size x size`` tile block centred on the tile holding (lon, lat).

    ``size`` must be odd so that the centre tile is in the middle. At the edges of the Web
    Mercator world (the antimeridian, +-85.05 degrees) the block is shifted inward so it
    never wraps; the centre tile is then off-middle but still inside the block.

    >>> g = sample_grid(0.0, 0.0, zoom=1, size=1)
    >>> g.tiles
    (Tile(x=1, y=1, z=1),)
    >>> sample_grid(179.9999, 0.0, zoom=3, size=3).tiles[0]
    Tile(x=5, y=3, z=3)
    """
    if size < 1 or size % 2 == 0:
        raise ValueError(f"grid size must be a positive odd number, got {size}")
    n = 2**zoom
    if size > n:
        raise ValueError(f"a {size}x{size} grid does not fit in the world at zoom {zoom}")
    centre = mercantile.tile(lon, lat, zoom)
    half = size // 2
    x0 = min(max(centre.x - half, 0), n - size)
    y0 = min(max(centre.y - half, 0), n - size)
    tiles = tuple(mercantile.Tile(x0 + dx, y0 + dy, zoom) for dy in range(size) for dx in range(size))
    return SampleGrid(lon=lon, lat=lat, zoom=zoom, tiles=tiles, size=size)


def ground_resolution(lat: float, zoom: int) -> float:
    """Metres on the ground per pixel of a 256 px tile at ``zoom`` and latitude ``lat``.

    >>> round(ground_resolution(0.0, 18), 3)
    0.597
    >>> round(ground_resolution(52.52, 18), 3)
    0.363
    """
    return float(math.cos(math.radians(lat)) * EARTH_CIRCUMFERENCE / (TILE_SIZE * 2**zoom))


def resolution_mismatch(pixel_m: float, wanted_m: float) -> float | None:
    """How many times (> 1) ``pixel_m`` pixels are larger or smaller than ``wanted_m`` ones, when
    that is more than :data:`RESOLUTION_MISMATCH`; None when they are close enough to say nothing.

    >>> resolution_mismatch(0.51, 0.3), resolution_mismatch(0.3, 0.6), resolution_mismatch(0.4, 0.3)
    (1.7, 2.0, None)
    """
    factor = max(pixel_m / wanted_m, wanted_m / pixel_m)
    return round(factor, 6) if factor > RESOLUTION_MISMATCH else None


def zoom_for_resolution(lat: float, metres: float) -> int:
    """The tile zoom (0..23) whose pixels at ``lat`` are nearest ``metres`` (in ratio): the ``--zoom``
    that matches a raster of that resolution.

    >>> zoom_for_resolution(60.17, 0.3), zoom_for_resolution(0.0, 0.6), zoom_for_resolution(0.0, 0.45)
    (18, 18, 18)
    """
    exact = math.log2(math.cos(math.radians(lat)) * EARTH_CIRCUMFERENCE / (TILE_SIZE * metres))
    return min(23, max(0, round(exact)))


def pad_bbox(bbox: LngLatBBox, metres: float) -> LngLatBBox:
    """``bbox`` grown by about ``metres`` on every side (for fetching OSM data that crosses the edge).

    >>> b = pad_bbox(LngLatBBox(0.0, 0.0, 0.001, 0.001), 111.32)
    >>> round(b.west, 4), round(b.north, 4)
    (-0.001, 0.002)
    """
    dlat = metres / 111_320.0
    mid = math.radians((bbox.south + bbox.north) / 2)
    dlon = metres / (111_320.0 * max(math.cos(mid), 1e-6))
    return LngLatBBox(bbox.west - dlon, max(bbox.south - dlat, -85.0511), bbox.east + dlon, min(bbox.north + dlat, 85.0511))


def ground_pixel_size(crs: Any, transform: Affine, width: int, height: int) -> float | None:
    """Metres on the ground between neighbouring pixel centres at a raster's centre, any CRS.

    The geodesic (WGS84) distances to the next pixel right and down, averaged: for a projected
    CRS with true metres (UTM, national grids) that is the pixel size; for Web Mercator it is the
    pixel size times cos(latitude), not the CRS's own "metres"; for lon/lat degrees it converts.
    None when ``crs`` is None or not tied to the Earth (a local engineering CRS).

    >>> g = sample_grid(13.4050, 52.5200, zoom=18)
    >>> round(ground_pixel_size("EPSG:3857", g.transform, g.width, g.height), 3)  # spherical 0.363
    0.364
    >>> ground_pixel_size("EPSG:32633", Affine(0.3, 0, 390000, 0, -0.3, 5820000), 1000, 1000)  # UTM scale
    0.3001
    """
    if crs is None:
        return None
    col, row = width / 2, height / 2
    xs, ys = zip(transform * (col, row), transform * (col + 1, row), transform * (col, row + 1))
    try:
        to_lonlat = Transformer.from_crs(CRS.from_user_input(crs), "EPSG:4326", always_xy=True)
        lon, lat = to_lonlat.transform(xs, ys, errcheck=True)
    except (ProjError, CRSError):  # a local/engineering CRS (drone software writes these): not on the Earth
        return None
    geod = Geod(ellps="WGS84")
    right = geod.inv(lon[0], lat[0], lon[1], lat[1])[2]
    down = geod.inv(lon[0], lat[0], lon[2], lat[2])[2]
    size = (right + down) / 2
    return round(size, 4) if math.isfinite(size) and size > 0 else None


def pixel_lonlat(bounds: tuple[float, float, float, float], shape: tuple[int, int],
                 xy: tuple[float, float]) -> tuple[float, float]:
    """Longitude and latitude of pixel ``(x, y)`` (centres at integers) of a ``shape`` mask whose
    Web Mercator ``bounds`` are (left, bottom, right, top).

    >>> b = (*mercantile.xy(0.0, -0.001), *mercantile.xy(0.002, 0.001))
    >>> [round(v, 6) for v in pixel_lonlat(b, (200, 200), (99.5, 99.5))]
    [0.001, 0.0]
    """
    left, bottom, right, top = bounds
    height, width = shape
    x = left + (xy[0] + 0.5) * (right - left) / width
    y = top - (xy[1] + 0.5) * (top - bottom) / height
    lon, lat = mercantile.lnglat(x, y)
    return lon, lat
