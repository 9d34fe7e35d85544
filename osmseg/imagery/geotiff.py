"""``geotiff:PATH``: a local GeoTIFF / COG in any CRS, warped onto the sample's grid.

NAIP, national orthophotos and drone mosaics come in their own projection (UTM, Swiss LV95,
World Mercator, ...).  GDAL's warper (through :class:`rasterio.vrt.WarpedVRT`, bilinear)
resamples exactly the window a sample needs onto its EPSG:3857 grid
(``grid.transform``, ``grid.width`` x ``grid.height``), so a huge COG is never read whole.

Pixels outside the raster's footprint, under its nodata value or its alpha/mask band are
invalid.  Bands: 3+ bands give RGB (by colour interpretation when set, else bands 1-3; a
4th band is used as alpha only when it is marked alpha, so NAIP's near-infrared band is
ignored), 1 band (or grey + alpha) is grey replicated to RGB.  Only 8-bit rasters are
read: for 16-bit or float imagery the right stretch is the user's choice, so the error says
how to convert.
"""

from __future__ import annotations

import logging
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
from rasterio.crs import CRS
from rasterio.enums import ColorInterp, Resampling
from rasterio.errors import NotGeoreferencedWarning, RasterioError
from rasterio.vrt import WarpedVRT
from rasterio.warp import transform_bounds

from osmseg.errors import ConfigError, ImageryError, UnusableImagery
from osmseg.grid import SampleGrid
from osmseg.imagery.base import Imagery
from osmseg.imagery.mosaic import ALPHA_VALID

logger = logging.getLogger(__name__)

WEB_MERCATOR = CRS.from_epsg(3857)


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
        try:
            with warnings.catch_warnings():  # a raster without CRS is refused below, in one line
                warnings.simplefilter("ignore", NotGeoreferencedWarning)
                src = rasterio.open(self.path)
            with src:
                self.crs = src.crs
                self.bounds = tuple(src.bounds)
                self.size = (src.width, src.height)
                self.count = src.count
                dtypes = set(src.dtypes)
                colorinterp = tuple(src.colorinterp)
                palette = ColorInterp.palette in colorinterp
        except RasterioError:
            raise UnusableImagery(
                f"{self.path} is not a raster GDAL can read: give a GeoTIFF/COG"
            ) from None
        if self.crs is None:
            raise UnusableImagery(
                f"{self.path} has no CRS: georeference it first (gdal_edit.py -a_srs EPSG:...)"
            )
        if dtypes != {"uint8"}:
            raise UnusableImagery(
                f"{self.path} is {'/'.join(sorted(dtypes))}, not 8-bit: convert it first"
                " (gdal_translate -ot Byte -scale ...)"
            )
        if palette:
            raise UnusableImagery(
                f"{self.path} is a paletted raster: expand it first (gdal_translate -expand rgb)"
            )
        self.bands = rgb_bands(colorinterp)
        self._has_alpha = ColorInterp.alpha in colorinterp

    def __repr__(self) -> str:
        return f"GeoTiffProvider({str(self.path)!r})"

    def check_covers(self, west: float, south: float, east: float, north: float) -> None:
        """ConfigError when the raster's footprint misses the sampling area (lon/lat degrees) entirely:
        every sample would be rejected as missing imagery, so say it before the build."""
        try:
            left, bottom, right, top = transform_bounds(self.crs, "EPSG:4326", *self.bounds, densify_pts=21)
        except (ValueError, RasterioError):  # a CRS with no lon/lat: nothing to compare
            return
        if right < west or left > east or top < south or bottom > north:
            raise UnusableImagery(
                f"{self.path} covers lon {left:.5f}..{right:.5f}, lat {bottom:.5f}..{top:.5f}, which misses the "
                f"sampling area (lon {west:.5f}..{east:.5f}, lat {south:.5f}..{north:.5f}): sample where the "
                "imagery is (--bbox/--lat/--lon), or give the GeoTIFF of this area")

    def fetch(self, grid: SampleGrid) -> Imagery:
        """The raster warped (bilinear) onto ``grid``; outside its footprint is invalid."""
        try:
            with (
                rasterio.open(self.path) as src,
                WarpedVRT(
                    src,
                    crs=WEB_MERCATOR,
                    transform=grid.transform,
                    width=grid.width,
                    height=grid.height,
                    resampling=Resampling.bilinear,
                    add_alpha=not self._has_alpha,
                ) as vrt,
            ):
                unique = sorted(set(self.bands))
                data = vrt.read(unique)
                # the alpha band the warper filled from the footprint, nodata, alpha or mask
                alpha = vrt.read(vrt.colorinterp.index(ColorInterp.alpha) + 1)
        except RasterioError as exc:
            cause = exc.__cause__ or exc.__context__
            why = str(cause or exc).splitlines()[0] if str(cause or exc) else type(exc).__name__
            raise ImageryError(
                f"cannot read {self.path} while warping it to the sample grid ({why}): "
                "the file looks truncated or corrupt; download or export it again"
            ) from None
        planes = {band: data[i] for i, band in enumerate(unique)}
        rgb = np.stack([planes[b] for b in self.bands], axis=-1).astype(np.uint8)
        valid = alpha >= ALPHA_VALID  # bilinear alpha fades at the footprint edge
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
