"""Write one accepted sample: image, colour mask, class-index mask and a georeferenced GeoTIFF.

For a sample called ``NAME`` in dataset folder ``OUT``::

    OUT/images/NAME.png      the aerial image, RGB (NAME.jpg with --image-format jpg, or NAME.tif,
                             a Cloud-Optimized GeoTIFF on the label GeoTIFF's grid, with cog)
    OUT/segmented/NAME.png   the labels in class colours, RGB (the dissertation's layout)
    OUT/labels/NAME.png      the class ids, 8-bit greyscale (0 = unlabeled)
    OUT/geo/NAME.tif         the class ids as a Cloud-Optimized GeoTIFF in EPSG:3857 with a colour
                             table and class names (osmseg.output.geotiff)
    OUT/geo/NAME.qml         its QGIS style: QGIS opens NAME.tif with the classes' colours and names
                             in the legend (osmseg.output.style)

Every file is encoded in memory with fixed options and no timestamps, hashed, and written
atomically, so the same inputs give byte-identical files and the manifest's SHA-256 is the
hash of exactly the bytes on disk.
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass
from pathlib import Path

import imagecodecs
import numpy as np
from PIL import Image

from osmseg.classes import ClassTable
from osmseg.errors import ConfigError, DatasetError
from osmseg.grid import SampleGrid
from osmseg.output.atomic import atomic_write_bytes, sha256_bytes
from osmseg.output.geotiff import encode_cog, write_class_metadata
from osmseg.output.style import qml_style, style_path

IMAGE_FORMATS = ("png", "jpg", "cog")
#: file suffix of the image of each format
IMAGE_SUFFIXES = {"png": "png", "jpg": "jpg", "cog": "tif"}
#: zlib level for PNG and the GeoTIFF's DEFLATE: fixed, so output bytes never depend on defaults.
COMPRESS_LEVEL = 6
#: Aerial photos barely compress (level 6 saves ~14% over level 1 at 5x the time), so the
#: images/ PNGs use the fast level; masks compress well and cheaply at COMPRESS_LEVEL.
PHOTO_COMPRESS_LEVEL = 1
#: libpng's row filter "up" (each row minus the one above), for every PNG osmseg writes. Pillow
#: tries all five filters on every row and keeps the best, which costs more than the deflate
#: itself: on a real 1280 px photo, libpng with "up" at level 1 takes ~56 ms for 2.13 MB where
#: Pillow's level 1 takes ~130 ms for 2.14 MB; a colour mask ~19 ms instead of ~41 ms.
PNG_FILTER_UP = 32
#: zlib's run-length strategy: a class-id mask is long runs of one byte (~3 ms, 3 % smaller
#: than the default strategy at level 6, which takes ~15 ms); colour masks and photos are not.
ZLIB_RLE = 3
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")


@dataclass(frozen=True)
class WrittenSample:
    """What :func:`write_sample` wrote: each file (relative path) with its SHA-256, and the pixels
    per class name of the labels (every class, zeros included)."""

    files: dict[str, str]
    class_histogram: dict[str, int]

    def file_in(self, folder: str) -> str:
        """The file written under ``folder`` (``images``, ``labels``, ...)."""
        return next(rel for rel in self.files if rel.startswith(f"{folder}/"))


def check_name(name: str) -> str:
    """``name`` if it is a safe sample file stem (letters, digits, ``_ . -``; no leading dot).

    >>> check_name("berlin_0007")
    'berlin_0007'
    """
    if not _NAME.fullmatch(name):
        raise ConfigError(f"sample name {name!r} must be letters, digits, '_', '.', '-' and not start with '.'")
    return name


def sample_paths(name: str, image_format: str = "png") -> dict[str, str]:
    """Relative (POSIX) paths of a sample's files, keyed by kind.

    >>> sample_paths("a_1", "jpg")["image"]
    'images/a_1.jpg'
    """
    if image_format not in IMAGE_FORMATS:
        raise ConfigError(f"image format must be one of {', '.join(IMAGE_FORMATS)}, got {image_format!r}")
    check_name(name)
    return {
        "image": f"images/{name}.{IMAGE_SUFFIXES[image_format]}",
        "segmented": f"segmented/{name}.png",
        "labels": f"labels/{name}.png",
        "geo": f"geo/{name}.tif",
        "geo_style": style_path(f"geo/{name}.tif"),
    }


def encode_png(array: np.ndarray, level: int = COMPRESS_LEVEL, *, runs: bool = False) -> bytes:
    """PNG bytes of an ``(H, W)`` (greyscale), ``(H, W, 3)`` (RGB) or ``(H, W, 4)`` (RGBA) uint8 array;
    no metadata chunks.

    Encoded by libpng through imagecodecs with fixed settings (zlib ``level``, the "up" row
    filter, and with ``runs`` zlib's run-length strategy, for class-id masks), so the same
    pixels always give the same bytes. Any PNG reader reads them.

    >>> encode_png(np.zeros((2, 2), np.uint8))[:8] == b"\\x89PNG\\r\\n\\x1a\\n"
    True
    """
    data = np.ascontiguousarray(array, dtype=np.uint8)
    if data.ndim not in (2, 3) or (data.ndim == 3 and data.shape[2] not in (3, 4)):
        raise DatasetError(f"a PNG needs an (H, W), (H, W, 3) or (H, W, 4) array, got shape {data.shape}")
    options: dict[str, int] = {"level": level, "filter": PNG_FILTER_UP}
    if runs:
        options["strategy"] = ZLIB_RLE
    return bytes(imagecodecs.png_encode(data, **options))


def encode_jpeg(rgb: np.ndarray, quality: int = 95) -> bytes:
    """Baseline JPEG bytes, 4:4:4 chroma (keeps thin roads' colour edges), no EXIF/JFIF density."""
    if not 1 <= quality <= 100:
        raise ConfigError(f"JPEG quality must be 1..100, got {quality}")
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb, dtype=np.uint8)).save(
        buf, format="JPEG", quality=quality, subsampling=0, optimize=False, progressive=False
    )
    return buf.getvalue()


def encode_label_geotiff(labels: np.ndarray, table: ClassTable, grid: SampleGrid) -> bytes:
    """Cloud-Optimized GeoTIFF bytes of the class ids on ``grid`` (EPSG:3857).

    256 x 256 tiles, DEFLATE, nearest-neighbour overviews, the class colours as colour table and
    the class names as ``CLASS_<id>`` band tags (:mod:`osmseg.output.geotiff`). No nodata value:
    0 (unlabeled) is a real label. The bytes depend only on the inputs.
    """
    return encode_cog(labels, "EPSG:3857", grid.transform, classes=True,
                      describe=lambda dst: write_class_metadata(dst, table))


def encode_image_cog(rgb: np.ndarray, grid: SampleGrid, valid: np.ndarray | None = None) -> bytes:
    """Cloud-Optimized GeoTIFF bytes of the RGB photo on ``grid``: the label GeoTIFF's very grid.

    Lossless (DEFLATE with horizontal differencing), averaged overviews, photometric RGB. Where
    ``valid`` (``(H, W)`` bool) is False the provider had no imagery: the file then carries an
    internal mask band (0 there, 255 elsewhere; its overviews too), so GIS tools draw those
    pixels transparent, ``rasterio``'s ``dataset_mask()`` and ``read(masked=True)`` mark them,
    and torchgeo's merge takes an overlapping sample's pixels there instead of black ones. A
    photo without missing pixels has no mask.
    """
    mask = None if valid is None or bool(np.all(valid)) else np.asarray(valid, dtype=bool)
    return encode_cog(rgb, "EPSG:3857", grid.transform, classes=False, mask=mask)


def encode_image(rgb: np.ndarray, grid: SampleGrid, image_format: str, jpeg_quality: int = 95,
                 valid: np.ndarray | None = None) -> bytes:
    """The aerial image's bytes in ``image_format`` (png, jpg or cog; ``valid``: see :func:`encode_image_cog`)."""
    if image_format == "png":
        return encode_png(rgb, PHOTO_COMPRESS_LEVEL)
    if image_format == "jpg":
        return encode_jpeg(rgb, jpeg_quality)
    if image_format == "cog":
        return encode_image_cog(rgb, grid, valid)
    raise ConfigError(f"image format must be one of {', '.join(IMAGE_FORMATS)}, got {image_format!r}")


def class_histogram(labels: np.ndarray, table: ClassTable) -> dict[str, int]:
    """Pixel count per class name (every class of ``table``, zeros included).

    >>> from osmseg.classes import load_class_table
    >>> h = class_histogram(np.array([[0, 1], [1, 1]], np.uint8), load_class_table())
    >>> h["unlabeled"], h["building"], h["water"]
    (1, 3, 0)
    """
    counts = np.bincount(labels.ravel(), minlength=256)
    known = table.by_id
    stray = [int(i) for i in np.flatnonzero(counts) if int(i) not in known]
    if stray:
        raise DatasetError(f"labels hold class ids {stray} that class table {table.name!r} does not define")
    return {c.name: int(counts[c.id]) for c in sorted(known.values(), key=lambda c: c.id)}


def write_sample(
    out_dir: Path,
    name: str,
    rgb: np.ndarray,
    labels: np.ndarray,
    table: ClassTable,
    grid: SampleGrid,
    image_format: str = "png",
    jpeg_quality: int = 95,
    valid: np.ndarray | None = None,
) -> WrittenSample:
    """Write the five files of one sample atomically (``valid``: the pixels that have imagery,
    marked in a COG photo's mask; see :func:`encode_image_cog`).

    Returns the files with their SHA-256 and the pixels per class, for the manifest (see
    :func:`osmseg.output.manifest.sample_entry`).
    """
    paths = sample_paths(name, image_format)
    shape = (grid.height, grid.width)
    if rgb.shape != (*shape, 3) or labels.shape != shape:
        raise DatasetError(
            f"sample {name}: image {rgb.shape} and labels {labels.shape} must be {shape + (3,)} and {shape} (the grid)"
        )
    if rgb.dtype != np.uint8 or labels.dtype != np.uint8:
        raise DatasetError(f"sample {name}: image and labels must be uint8, got {rgb.dtype} and {labels.dtype}")
    if valid is not None and valid.shape != shape:
        raise DatasetError(f"sample {name}: the valid-imagery mask is {valid.shape}, not {shape} (the grid)")
    histogram = class_histogram(labels, table)
    encoded = {
        paths["image"]: encode_image(rgb, grid, image_format, jpeg_quality, valid),
        paths["segmented"]: encode_png(table.colorize(labels)),
        paths["labels"]: encode_png(labels, runs=True),
        paths["geo"]: encode_label_geotiff(labels, table, grid),
        paths["geo_style"]: qml_style(table),
    }
    out_dir = Path(out_dir)
    files = {}
    for rel, data in encoded.items():
        atomic_write_bytes(out_dir / rel, data)
        files[rel] = sha256_bytes(data)
    return WrittenSample(files=files, class_histogram=histogram)
