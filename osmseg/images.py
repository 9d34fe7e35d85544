"""Reading images: the one module every osmseg package reads RGB photos, label masks and rasters with.

* :func:`read_rgb` -- a photo as ``(H, W, 3)`` uint8 RGB (PNG, JPEG or any GDAL raster; grey
  repeated, alpha and extra bands dropped);
* :func:`read_label` -- a label mask as ``(H, W)`` integer class ids (``labels/*.png``,
  ``geo/*.tif``, foreign masks);
* :func:`read_raster` -- the pixels as stored plus the georeferencing (CRS, transform, ground
  metres per pixel) when the file has it: what a caller needs that must tell a mask from a
  photo itself (``osmseg localize``);
* :func:`as_rgb` -- an array's pixels as RGB for a model, with one contract (8-bit, 1/3/4 bands);
* :func:`pixel_rule` -- how a raster's stored values become 8-bit colour (16-bit scaled by its
  declared bit depth, a colour table looked up): the one rule ``osmseg build`` (``geotiff:PATH``),
  ``osmseg predict`` and :func:`read_rgb` read imagery rasters with;
* :func:`image_size` -- ``(height, width)`` from the header, without decoding.

An unreadable or unsuitable file raises :class:`UnreadableImage`, one line naming the file; it
is both a :class:`~osmseg.errors.DatasetError` (a dataset's file) and an
:class:`~osmseg.errors.ImageryError` (an input image), so callers catch what they know.
Imports: osmseg.errors and osmseg.grid only.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import rasterio
from PIL import Image, UnidentifiedImageError
from rasterio.enums import ColorInterp
from rasterio.errors import NotGeoreferencedWarning, RasterioError

from osmseg.errors import DatasetError, ImageryError
from osmseg.grid import ground_pixel_size

#: label PNG modes that hold class ids (palette indices count as ids)
LABEL_MODES = ("L", "P", "1", "I", "I;16")


class UnreadableImage(DatasetError, ImageryError):
    """An image or mask file that cannot be read, or holds the wrong kind of pixels."""


@dataclass(frozen=True)
class Raster:
    """An image's pixels as stored (``(H, W)`` for one band, else ``(H, W, bands)``) and where it lies."""

    pixels: np.ndarray
    crs: Any = None  # rasterio CRS, None for PNG/JPEG or an ungeoreferenced TIFF
    transform: Any = None  # affine.Affine, None when there is no CRS
    resolution_m: float | None = None  # ground metres per pixel (geodesic), None when unknown


@dataclass(frozen=True)
class PixelRule:
    """How one raster's stored values become 8-bit colour: the rule every imagery reader applies.

    * 8-bit values are taken as they are.
    * 16-bit unsigned values are scaled linearly from the raster's declared bit depth
      (``bits``: its ``NBITS``, as 11- or 12-bit satellite imagery declares it, else 16) to
      0..255, ``round(v * 255 / (2**bits - 1))``, clipped: the same for every window of the
      file, so a value never depends on what else a sample or a block holds.
    * A paletted band (``palette``, a colour table) is looked up index by index into RGBA;
      the table's alpha (and the nodata index) mark pixels without imagery. Indices cannot
      be averaged or interpolated: a paletted raster is resampled nearest-neighbour (``nearest``)
      before the lookup.
    """

    bits: int = 8
    palette: np.ndarray | None = None  # (entries, 4) uint8 RGBA by index

    @property
    def nearest(self) -> bool:
        """True when the stored values must be resampled nearest-neighbour (palette indices)."""
        return self.palette is not None

    def colours(self, data: np.ndarray) -> np.ndarray:
        """Stored values ``(bands, h, w)`` as uint8 colour: scaled, or a palette's one band as
        ``(4, h, w)`` RGBA.

        >>> PixelRule(bits=12).colours(np.array([[[0, 2048, 4095, 65535]]], np.uint16)).tolist()
        [[[0, 128, 255, 255]]]
        >>> lut = np.array([[10, 20, 30, 255], [0, 0, 0, 0]], np.uint8)
        >>> PixelRule(palette=lut).colours(np.array([[[0, 1]]], np.uint8))[:, 0].tolist()
        [[10, 0], [20, 0], [30, 0], [255, 0]]
        """
        if self.palette is not None:
            return np.moveaxis(self.palette[np.minimum(data[0], len(self.palette) - 1)], -1, 0)
        if data.dtype == np.uint8:
            return data
        top = 2**self.bits - 1
        wide = np.minimum(data.astype(np.uint32), top)
        return cast("np.ndarray", ((wide * 255 + top // 2) // top).astype(np.uint8))


def pixel_rule(dataset: Any, name: str, error: type[Exception] = ImageryError) -> PixelRule:
    """The :class:`PixelRule` of an open rasterio dataset; ``error`` (one line naming ``name``) for
    pixels no rule reads without a choice only their owner can make (signed, float, 32-bit)."""
    dtypes = set(dataset.dtypes)
    if len(dtypes) != 1 or not dtypes <= {"uint8", "uint16"}:
        raise error(f"{name} is {'/'.join(sorted(dtypes))}: imagery is read as 8- or 16-bit unsigned values; "
                    "convert it first with the stretch it needs (gdal_translate -ot Byte -scale MIN MAX 0 255)")
    dtype = dtypes.pop()
    declared = dataset.tags(1, ns="IMAGE_STRUCTURE").get("NBITS") or dataset.tags(ns="IMAGE_STRUCTURE").get("NBITS")
    bits = 8 if dtype == "uint8" else int(declared) if str(declared).isdigit() and 8 < int(declared) <= 16 else 16
    if ColorInterp.palette not in dataset.colorinterp:
        return PixelRule(bits=bits)
    if dataset.count != 1:
        raise error(f"{name} has a colour table among {dataset.count} bands: expand it first "
                    "(gdal_translate -expand rgba)")
    try:
        table = dataset.colormap(1)
    except ValueError:
        raise error(f"{name} is marked paletted but has no colour table: fix its colour interpretation "
                    "(gdal_edit.py -colorinterp_1 gray)") from None
    lut = np.zeros((256 if dtype == "uint8" else 65536, 4), np.uint8)  # indices beyond the table: no imagery
    for index, rgba in table.items():
        if 0 <= index < len(lut):
            lut[index] = rgba
    if dataset.nodata is not None and 0 <= int(dataset.nodata) < len(lut):
        lut[int(dataset.nodata), 3] = 0
    return PixelRule(bits=bits, palette=lut)


def is_tiff(path: Path) -> bool:
    return Path(path).suffix.lower() in (".tif", ".tiff")


def _unreadable(path: Path, exc: Exception) -> UnreadableImage:
    reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return UnreadableImage(f"{path}: cannot read this image ({reason}); replace or remove it")


def image_size(path: Path) -> tuple[int, int]:
    """``(height, width)`` of an image or label file from its header, without decoding pixels."""
    path = Path(path)
    try:
        if is_tiff(path):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NotGeoreferencedWarning)
                with rasterio.open(path) as src:
                    return src.height, src.width
        with Image.open(path) as im:
            return im.height, im.width
    except (OSError, UnidentifiedImageError, ValueError) as exc:  # RasterioIOError is an OSError
        raise _unreadable(path, exc) from None


def _read_tiff(path: Path, colour: bool = False) -> np.ndarray:
    """A TIFF's pixels ``(H, W, bands)``: as stored, or with ``colour`` as 8-bit colour (:func:`pixel_rule`)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(path) as src:
            data = src.read()
            if colour:
                data = pixel_rule(src, str(path), UnreadableImage).colours(data)
            return np.moveaxis(data, 0, -1)


def read_rgb(path: Path) -> np.ndarray:
    """A photo as ``(H, W, 3)`` uint8 RGB (grey is repeated, alpha and extra bands dropped; a
    GeoTIFF's 16-bit values and colour table as :func:`pixel_rule` says)."""
    path = Path(path)
    try:
        if is_tiff(path):
            array = _read_tiff(path, colour=True)
            if array.shape[2] < 3:
                array = np.repeat(array[:, :, :1], 3, axis=2)
            return np.ascontiguousarray(array[:, :, :3])
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"))
    except (OSError, UnidentifiedImageError, ValueError) as exc:
        if isinstance(exc, UnreadableImage):
            raise
        raise _unreadable(path, exc) from None


def read_label(path: Path) -> np.ndarray:
    """A label mask as ``(H, W)`` class ids (uint8, or a wider integer type if stored so)."""
    path = Path(path)
    try:
        if is_tiff(path):
            array = _read_tiff(path)[:, :, 0]
        else:
            with Image.open(path) as im:
                if im.mode not in LABEL_MODES:
                    raise UnreadableImage(f"{path}: label is a {im.mode} image; labels must be single-band "
                                          "class ids (labels/, not the colour masks in segmented/)")
                array = np.asarray(im)
    except (OSError, UnidentifiedImageError, ValueError) as exc:
        if isinstance(exc, UnreadableImage):
            raise
        raise _unreadable(path, exc) from None
    if array.dtype == bool:
        array = array.astype(np.uint8)
    if not np.issubdtype(array.dtype, np.integer):
        raise UnreadableImage(f"{path}: label values are {array.dtype}; labels must be integer class ids")
    return array


def read_raster(path: Path) -> Raster:
    """The pixels as stored and, for a georeferenced raster, its CRS, transform and ground resolution.

    PNG/JPEG: colour modes become RGB (an alpha channel is dropped), a 1-bit image becomes
    0/255-free ids (``L``), and ``L``/``P``/``I`` modes stay as they are (class ids).
    """
    path = Path(path)
    if is_tiff(path):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NotGeoreferencedWarning)
                with rasterio.open(path) as src:
                    data = src.read()
                    crs = src.crs
                    transform = src.transform if crs is not None else None
                    resolution = ground_pixel_size(crs, src.transform, src.width, src.height) if crs else None
        except (RasterioError, OSError) as exc:
            raise UnreadableImage(f"{path}: cannot read the image ({exc})") from None
        return Raster(data[0] if data.shape[0] == 1 else np.moveaxis(data, 0, -1), crs, transform, resolution)
    try:
        with Image.open(path) as img:
            img.load()
            if img.mode in ("RGBA", "LA", "CMYK", "YCbCr", "HSV", "LAB"):
                img = img.convert("RGB")  # colour: an image to segment or to draw
            elif img.mode == "1":
                img = img.convert("L")
            return Raster(np.asarray(img))  # "L", "P" (palette indices), "I;16", "I": class ids
    except (UnidentifiedImageError, OSError) as exc:
        raise UnreadableImage(f"{path}: cannot read the image ({exc})") from None


def as_rgb(pixels: np.ndarray, name: str = "image") -> np.ndarray:
    """``(h, w)`` or ``(h, w, 1|3|4)`` uint8 pixels as ``(h, w, 3)``: grey repeated, alpha dropped.

    >>> as_rgb(np.zeros((2, 2), np.uint8)).shape
    (2, 2, 3)
    """
    if pixels.dtype != np.uint8:
        raise UnreadableImage(f"{name}: pixels are {pixels.dtype}, the model takes 8-bit RGB; convert it "
                              f"(e.g. gdal_translate -ot Byte -scale)")
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    bands = pixels.shape[2] if pixels.ndim == 3 else -1
    if bands == 1:
        return np.repeat(pixels, 3, axis=2)
    if bands in (3, 4):
        return pixels[:, :, :3]
    raise UnreadableImage(f"{name}: {bands if bands > 0 else 'unknown'} bands (shape {pixels.shape}); "
                          f"give 1 (grey), 3 (RGB) or 4 (RGBA) bands")
