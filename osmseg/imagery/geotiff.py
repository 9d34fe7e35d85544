"""``geotiff:PATH``: a local GeoTIFF / COG in any CRS, warped onto the sample's grid.

NAIP, national orthophotos and drone mosaics come in their own projection (UTM, Swiss LV95,
World Mercator, ...).  The source window under the grid (plus a margin for the resampling
kernel) is read once, with the raster's validity (its alpha band, or its nodata / internal
mask as an alpha band), and interpolated bilinearly onto the sample's EPSG:3857 grid
(:mod:`osmseg.imagery.remap`: PROJ's exact coordinates on a refined lattice, OpenCV's
``remap``, colour premultiplied by validity), so invalid source pixels do not bleed into valid
ones and a huge COG is never read whole. The pixels are GDAL's warper's (bilinear) up to
rounding, at a quarter of its cost (the tests compare the two).

**Finer imagery is averaged first.** Where a sample pixel spans more than 1/0.95 source
pixels (measured once per sample along its centre lines, rotation included; GDAL's warper
widens its kernel below the same scale), the window is read averaged to the sample's
resolution (``Resampling.average``, from overviews where the raster has them) and then
interpolated: detail finer than the sample is averaged rather than aliased, every pixel of a
sample is resampled alike, and a sample costs one read and one interpolation whatever the zoom.

The file is opened once per process and kept open; a worker process (forked or spawned) opens
its own, a provider pickles without its handle, and a file replaced on disk is opened again.

Pixels outside the raster's footprint, under its nodata value or its alpha/mask band are
invalid.  Bands: 3+ bands give RGB (by colour interpretation when set, else bands 1-3; a
4th band is used as alpha only when it is marked alpha, so NAIP's near-infrared band is
ignored), 1 band (or grey + alpha) is grey replicated to RGB, a paletted band is looked up in
its colour table (read nearest-neighbour: indices cannot be averaged). 16-bit values are
scaled by their declared bit depth: :func:`osmseg.images.pixel_rule`, the rule ``osmseg
predict`` reads the same file with. Signed, float or 32-bit imagery needs a stretch that is
the user's choice, so the error says how to convert.
"""

from __future__ import annotations

import logging
import math
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
import rasterio.warp
from affine import Affine
from rasterio.crs import CRS
from rasterio.enums import ColorInterp, MaskFlags, Resampling
from rasterio.errors import NotGeoreferencedWarning, RasterioError
from rasterio.io import DatasetReader
from rasterio.warp import transform_bounds
from rasterio.windows import Window

from osmseg.errors import ConfigError, ImageryError, UnusableImagery
from osmseg.grid import SampleGrid, ground_pixel_size
from osmseg.imagery.base import Imagery
from osmseg.imagery.mosaic import ALPHA_VALID
from osmseg.imagery.remap import source_pixels, warp_bilinear
from osmseg.images import pixel_rule

logger = logging.getLogger(__name__)

WEB_MERCATOR = CRS.from_epsg(3857)
# bilinear interpolation alone down to this many grid pixels per source pixel (GDAL's warper
# widens its bilinear kernel below the same 0.95); finer imagery is averaged first
MIN_SCALE = 0.95


def rgb_bands(colorinterp: tuple[ColorInterp, ...]) -> tuple[int, int, int]:
    """1-based band indexes to read as red, green, blue.

    >>> rgb_bands((ColorInterp.gray,))
    (1, 1, 1)
    >>> rgb_bands((ColorInterp.blue, ColorInterp.green, ColorInterp.red))
    (3, 2, 1)
    >>> rgb_bands((ColorInterp.red, ColorInterp.green, ColorInterp.blue, ColorInterp.undefined))
    (1, 2, 3)
    """
    colour = [i for i, c in enumerate(colorinterp, 1) if c != ColorInterp.alpha]
    if not colour:
        raise ImageryError("the raster has only an alpha band: no colour to read")
    by_interp = {c: i for i, c in enumerate(colorinterp, 1)}
    if all(c in by_interp for c in (ColorInterp.red, ColorInterp.green, ColorInterp.blue)):
        return by_interp[ColorInterp.red], by_interp[ColorInterp.green], by_interp[ColorInterp.blue]
    if len(colour) < 3:
        return colour[0], colour[0], colour[0]
    return colour[0], colour[1], colour[2]


def file_stamp(path: Path) -> tuple[int, ...] | None:
    """What changes when a file is replaced or rewritten (device, inode, size, mtime); None if absent."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns


def mercator_footprint(src: DatasetReader) -> tuple[float, float, float, float] | None:
    """EPSG:3857 bounds of the raster's pixels, or None when they cannot be told (no such
    transform, a raster across the antimeridian or over a pole): then every grid is warped."""
    corners = [src.transform * (col, row) for col in (0, src.width) for row in (0, src.height)]
    xs, ys = zip(*corners, strict=True)
    try:
        bounds = transform_bounds(src.crs, WEB_MERCATOR, min(xs), min(ys), max(xs), max(ys), densify_pts=21)
    except (ValueError, RasterioError):
        return None
    left, bottom, right, top = bounds
    if not all(math.isfinite(v) for v in bounds) or left >= right or bottom >= top:
        return None
    return left, bottom, right, top


class GeoTiffProvider:
    """Imagery from one local raster (GeoTIFF, COG, or anything GDAL opens with a CRS).

    The file is checked when the provider is made, so a bad path fails before a build starts.
    """

    name = "geotiff"

    def __init__(self, path: str | Path, attribution: str | None = None) -> None:
        self.path = Path(path).expanduser()
        self.attribution = (
            attribution
            or f"Imagery from {self.path.name}: credit the imagery owner as their terms require"
        )
        if not self.path.exists():
            raise ConfigError(f"GeoTIFF {self.path} does not exist: check the geotiff:PATH")
        self._src: DatasetReader | None = None
        self._pid = 0
        self._stamp: tuple[int, ...] | None = None
        try:
            self._open()
        except RasterioError:
            raise UnusableImagery(
                f"{self.path} is not a raster GDAL can read: give a GeoTIFF/COG"
            ) from None

    def __repr__(self) -> str:
        return f"GeoTiffProvider({str(self.path)!r})"

    def __getstate__(self) -> dict[str, Any]:
        """Pickled without the open dataset: the process that unpickles opens its own."""
        return {**self.__dict__, "_src": None}

    def _open(self) -> DatasetReader:
        """Open the raster, check it is usable, and keep it open for this process.

        Raises RasterioError when GDAL cannot read it (the caller says what that means there) and
        UnusableImagery when it is not imagery this provider reads."""
        stamp = file_stamp(self.path)
        with warnings.catch_warnings():  # a raster without CRS is refused below, in one line
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            src = rasterio.open(self.path)
        try:
            crs = src.crs
            colorinterp = tuple(src.colorinterp)
            if crs is None:
                raise UnusableImagery(
                    f"{self.path} has no CRS: georeference it first (gdal_edit.py -a_srs EPSG:...)"
                )
            # 16-bit values and colour tables become 8-bit colour as osmseg predict reads them
            self._rule = pixel_rule(src, str(self.path), UnusableImagery)
            self.bands = rgb_bands(colorinterp)
            self.crs = crs
            self.bounds = tuple(src.bounds)
            self.size = (src.width, src.height)
            self.count = src.count
            # ground metres per pixel (None for a CRS not tied to the Earth): warns of upsampling zooms
            self.resolution_m = ground_pixel_size(crs, src.transform, src.width, src.height)
            self._has_alpha = ColorInterp.alpha in colorinterp
            self._footprint = mercator_footprint(src)
        except BaseException:
            src.close()
            raise
        self._src, self._pid, self._stamp = src, os.getpid(), stamp
        return src

    def _dataset(self) -> DatasetReader:
        """The raster, open in this process: opened again in a new process (a worker must not
        share its parent's file handle) and when the file on disk was replaced or rewritten."""
        if self._src is None or self._pid != os.getpid() or file_stamp(self.path) != self._stamp:
            self._src = None  # a handle inherited from the parent is dropped, never used
            return self._open()
        return self._src

    def check_covers(self, west: float, south: float, east: float, north: float, zoom: int | None = None) -> None:
        """ConfigError when the raster's footprint misses the sampling area (lon/lat degrees) entirely:
        every sample would be rejected as missing imagery, so say it before the build. (``zoom``:
        any, a raster is resampled to it.)"""
        try:
            left, bottom, right, top = transform_bounds(self.crs, "EPSG:4326", *self.bounds, densify_pts=21)
        except (ValueError, RasterioError):  # a CRS with no lon/lat: nothing to compare
            return
        if right < west or left > east or top < south or bottom > north:
            raise UnusableImagery(
                f"{self.path} covers lon {left:.5f}..{right:.5f}, lat {bottom:.5f}..{top:.5f}, which misses the "
                f"sampling area (lon {west:.5f}..{east:.5f}, lat {south:.5f}..{north:.5f}): sample where the "
                "imagery is (--bbox/--lat/--lon), or give the GeoTIFF of this area")

    @staticmethod
    def _source_window(src: DatasetReader, grid: SampleGrid) -> tuple[Window | None, bool, float]:
        """The source pixels under ``grid`` plus a margin for the resampling kernel (wider when
        downsampling), clipped to the raster (None when the grid misses it); whether nothing was
        clipped (then every grid pixel's resampling kernel lies on the raster); and about how many
        source pixels a grid pixel spans."""
        try:
            left, bottom, right, top = transform_bounds(WEB_MERCATOR, src.crs, *grid.xy_bounds, densify_pts=21)
        except (ValueError, RasterioError):
            return Window(0, 0, src.width, src.height), False, 1.0
        corners = [~src.transform * (x, y) for x in (left, right) for y in (bottom, top)]
        cols, rows = zip(*corners, strict=True)
        if not all(math.isfinite(v) for v in cols + rows):
            return Window(0, 0, src.width, src.height), False, 1.0
        ratio = max((max(cols) - min(cols)) / grid.width, (max(rows) - min(rows)) / grid.height)
        margin = max(2, math.ceil(ratio) + 1)
        col0, row0 = math.floor(min(cols)) - margin, math.floor(min(rows)) - margin
        col1, row1 = math.ceil(max(cols)) + margin, math.ceil(max(rows)) + margin
        inside = col0 >= 0 and row0 >= 0 and col1 <= src.width and row1 <= src.height
        col0, row0, col1, row1 = max(0, col0), max(0, row0), min(src.width, col1), min(src.height, row1)
        if col1 <= col0 or row1 <= row0:
            return None, False, ratio
        return Window(col0, row0, col1 - col0, row1 - row0), inside, ratio

    @staticmethod
    def _decimation(crs: CRS, transform: Affine, grid: SampleGrid, ratio: float) -> float:
        """How many source pixels (of a raster with ``transform`` in ``crs``) to average into one
        before interpolating: 1 unless a grid pixel spans more than ``1 / MIN_SCALE`` source pixels
        along the grid's horizontal or vertical centre line (rotation included), else that span.
        ``ratio`` (the window's extent over the grid's) stands in when the CRS cannot place them."""
        left, bottom, right, top = grid.xy_bounds
        cx, cy = (left + right) / 2, (bottom + top) / 2
        try:
            xs, ys = rasterio.warp.transform(WEB_MERCATOR, crs, [left, right, cx, cx], [cy, cy, bottom, top])
            pixels = [~transform * (x, y) for x, y in zip(xs, ys, strict=True)]
            span = max(math.dist(pixels[0], pixels[1]) / grid.width, math.dist(pixels[2], pixels[3]) / grid.height)
        except (ValueError, RasterioError):
            span = ratio
        if not math.isfinite(span):
            span = ratio
        return span if span * MIN_SCALE > 1.0 else 1.0

    def fetch(self, grid: SampleGrid) -> Imagery:
        """The raster warped (bilinear) onto ``grid``; outside its footprint is invalid."""
        rgb = np.zeros((grid.height, grid.width, 3), dtype=np.uint8)
        valid = np.zeros((grid.height, grid.width), dtype=bool)
        try:
            src = self._dataset()
            window, inside, ratio = self._source_window(src, grid)
            if window is not None:
                colorinterp = src.colorinterp
                palette = self._rule.palette is not None
                unique = [1, 2, 3] if palette else sorted(set(self.bands))  # a palette: the planes of its RGBA
                indexes = [1] if palette else list(unique)
                if self._has_alpha:
                    indexes.append(colorinterp.index(ColorInterp.alpha) + 1)
                # imagery finer than the sample is read averaged to about the sample's resolution
                # (from the raster's overviews where it has them), as bilinear interpolation alone
                # would alias it: memory and time then stay those of a sample whatever the zoom
                # (palette indices cannot be averaged: they are read nearest-neighbour)
                step = self._decimation(src.crs, src.window_transform(window), grid, ratio)
                shape = (max(1, math.ceil(window.height / step)), max(1, math.ceil(window.width / step)))
                resampling = Resampling.nearest if self._rule.nearest else Resampling.average

                def sized(*count: int) -> dict[str, Any]:  # how to read ``count`` bands (none: a 2-D mask)
                    return {} if step == 1.0 else {"out_shape": (*count, *shape), "resampling": resampling}

                # a palette's RGBA: its table's alpha (and nodata index) say which pixels have imagery
                data = self._rule.colours(src.read(indexes, window=window, **sized(len(indexes))))
                if palette and int(data[3].min()) == 255:
                    data = data[:3]  # opaque all over: warped as an RGB raster's bands are
                masked = not palette and not self._has_alpha
                if masked and src.nodata is not None:
                    # as GDAL's warper (UNIFIED_SRC_NODATA): invalid only where every band is nodata
                    masks = src.read_masks(window=window, **sized(src.count))
                    data = np.concatenate([data, (masks.max(axis=0))[np.newaxis]])
                elif masked and any(MaskFlags.all_valid not in f for f in src.mask_flag_enums):
                    data = np.concatenate([data, src.dataset_mask(window=window, **sized())[np.newaxis]])
                has_alpha = len(data) > len(unique)
                # a grid whose every kernel lies on the raster, which marks no pixel invalid, is valid
                # all over: the colour bands alone are warped; elsewhere the raster's footprint ends
                # within the window, and outside it is alpha 0
                whole = inside and not has_alpha
                if not whole and not has_alpha:
                    data = np.concatenate([data, np.full((1, *data.shape[1:]), 255, np.uint8)])
                transform = src.window_transform(window) * Affine.scale(window.width / data.shape[2],
                                                                         window.height / data.shape[1])
                mapx, mapy = source_pixels(WEB_MERCATOR, grid.transform, (grid.height, grid.width), src.crs,
                                           transform)
                out = warp_bilinear(data, mapx, mapy, alpha=not whole)
        except RasterioError as exc:
            cause = exc.__cause__ or exc.__context__
            why = str(cause or exc).splitlines()[0] if str(cause or exc) else type(exc).__name__
            raise ImageryError(
                f"cannot read {self.path} while warping it to the sample grid ({why}): "
                "the file looks truncated or corrupt; download or export it again"
            ) from None
        if window is not None:
            planes = {band: out[..., i] for i, band in enumerate(unique)}
            # bilinear alpha fades at the footprint edge
            valid = np.ones(out.shape[:2], dtype=bool) if whole else out[..., -1] >= ALPHA_VALID
            rgb = np.stack([planes[b] for b in ((1, 2, 3) if palette else self.bands)], axis=-1)
            rgb[~valid] = 0
        info: dict[str, Any] = {
            "provider": self.name,
            "path": str(self.path),
            "crs": self.crs.to_string(),
            "valid_fraction": round(float(valid.mean()), 4),
        }
        return Imagery(rgb=rgb, valid=valid, placeholder_tiles=0, info=info)

    def describe(self) -> dict[str, Any]:
        """Path, CRS, bounds and size of the raster for the manifest."""
        return {
            "provider": self.name,
            "path": str(self.path),
            "crs": self.crs.to_string(),
            "bounds": [float(v) for v in self.bounds],
            "size": list(self.size),
            "bands": list(self.bands),
            "attribution": self.attribution,
        }
