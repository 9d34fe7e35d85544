"""GeoTIFFs as osmseg writes them: Cloud-Optimized, and one convention for class metadata.

**Cloud-Optimized GeoTIFF.** Every GeoTIFF osmseg writes (a dataset's label and image files,
``osmseg predict``'s masks) goes through GDAL's COG driver: 256 x 256 internal tiles, DEFLATE
at a fixed level, overviews down to the tile size, the image data after the header and
overviews in the order COG readers expect. QGIS, GDAL (``/vsicurl/``), torchgeo and STAC
browsers then read any zoom level of a remote file with a few range requests. Overviews of
class ids use nearest neighbour (a class id is never averaged into another class's id);
overviews of photos use averaging. GDAL writes no timestamp, so the bytes depend only on the
pixels and these options.

**Class metadata**, the same in every class-id GeoTIFF (dataset labels and predictions):

* the band's colour table holds each class's colour (QGIS and GDAL show classes in colour);
* band tags ``CLASS_<id> = <name>`` name every class id, unlabeled (0) included, so
  ``gdalinfo`` lists the classes and any reader can map ids to names without osmseg;
* the dataset tag ``CLASS_TABLE = <table name>`` says which table (``osm13``, ``osm6``, ...).

:func:`read_class_table` reads the three back into a :class:`~osmseg.classes.ClassTable`.

**No nodata value.** Class 0 (unlabeled: no OSM feature covers the pixel) is a label a model
can be trained on (``--keep-unlabeled``), not missing data. Declaring it nodata would make
GIS tools draw it transparent (a style choice users can still make) and make mosaicking tools
such as torchgeo's merge let another file's pixels replace it where samples overlap.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
from affine import Affine
from rasterio.io import DatasetReader, DatasetWriter, MemoryFile
from rasterio.shutil import copy as copy_raster

from osmseg.classes import ClassDef, ClassTable
from osmseg.errors import DatasetError

#: Internal tile size of every GeoTIFF osmseg writes (the Web Mercator tile size).
BLOCK = 256
#: zlib level of the DEFLATE compression: fixed, so output bytes never depend on GDAL's default.
DEFLATE_LEVEL = 6
#: Dataset tag with the unlabeled class id, written only when it is not 0 (CamVid's void: 11).
UNLABELED_TAG = "CLASS_UNLABELED"
CLASS_TABLE_TAG = "CLASS_TABLE"
_CLASS_TAG = re.compile(r"^CLASS_(\d{1,3})$")


def cog_options(*, classes: bool) -> dict[str, str]:
    """GDAL COG creation options: class ids (nearest overviews) or photos (averaged, predictor).

    >>> cog_options(classes=True)["OVERVIEW_RESAMPLING"], cog_options(classes=False)["PREDICTOR"]
    ('NEAREST', 'YES')
    """
    return {
        "BLOCKSIZE": str(BLOCK),
        "COMPRESS": "DEFLATE",
        "LEVEL": str(DEFLATE_LEVEL),
        "PREDICTOR": "NO" if classes else "YES",  # horizontal differencing pays off on photos only
        "OVERVIEWS": "AUTO",  # halve until a level fits in one tile
        "OVERVIEW_RESAMPLING": "NEAREST" if classes else "AVERAGE",
        "BIGTIFF": "IF_SAFER",
    }


def class_tags(table: ClassTable) -> tuple[dict[str, str], dict[str, str]]:
    """The dataset tags and band tags naming ``table``'s classes (see the module doc).

    >>> from osmseg.classes import load_class_table
    >>> dataset, band = class_tags(load_class_table("classes6.toml"))
    >>> dataset, band["CLASS_0"], band["CLASS_6"]
    ({'CLASS_TABLE': 'osm6'}, 'unlabeled', 'dirt road')
    """
    band = {f"CLASS_{c.id}": c.name for c in sorted((table.unlabeled, *table.classes), key=lambda c: c.id)}
    dataset = {CLASS_TABLE_TAG: table.name}
    if table.unlabeled.id != 0:  # osmseg's own tables keep the tags they always had
        dataset[UNLABELED_TAG] = str(table.unlabeled.id)
    return dataset, band


def write_class_metadata(dst: DatasetWriter, table: ClassTable, band: int = 1) -> None:
    """Give band ``band`` of an open GeoTIFF the class colour table, names and table name."""
    palette = table.palette()
    dst.write_colormap(band, {i: (int(r), int(g), int(b), 255) for i, (r, g, b) in enumerate(palette)})
    dst.set_band_description(band, f"class id ({table.name}); {table.unlabeled.id} = {table.unlabeled.name}")
    dataset_tags, band_tags = class_tags(table)
    dst.update_tags(band, **band_tags)
    dst.update_tags(**dataset_tags, AREA_OR_POINT="Area")


def read_class_table(src: DatasetReader | str | Path, band: int = 1) -> ClassTable | None:
    """The class table a class-id GeoTIFF carries (names from ``CLASS_<id>``, colours from its
    colour table), or None when it has no ``CLASS_<id>`` tags."""
    if not isinstance(src, DatasetReader):
        with rasterio.open(src) as opened:
            return read_class_table(opened, band)
    names = {int(m.group(1)): name for key, name in src.tags(band).items() if (m := _CLASS_TAG.match(key))}
    if not names:
        return None
    try:
        colours = src.colormap(band)
    except ValueError:  # no colour table
        colours = {}
    defs = [ClassDef(id=i, name=n, color=tuple(int(v) for v in colours.get(i, (0, 0, 0, 255))[:3]))  # type: ignore[arg-type]
            for i, n in sorted(names.items())]
    table_name = src.tags().get(CLASS_TABLE_TAG, "geotiff")
    try:
        void = int(src.tags().get(UNLABELED_TAG, 0))
    except ValueError:
        void = -1  # from_dict says what is wrong
    return ClassTable.from_dict({"name": table_name, "unlabeled": void, "classes": [
        {"id": d.id, "name": d.name, "color": list(d.color)} for d in defs]}, f"{src.name} class tags")


def encode_cog(array: np.ndarray, crs: Any, transform: Affine, *, classes: bool,
               describe: Callable[[DatasetWriter], None] | None = None, mask: np.ndarray | None = None) -> bytes:
    """COG bytes of ``array`` (``(H, W)`` class ids or ``(H, W, 3)`` RGB, uint8) on a grid.

    ``describe(dataset)`` may add metadata (class tags, band descriptions) before the copy
    into the COG layout; tags, colour tables and descriptions are carried over. ``mask``
    (``(H, W)`` bool, False where there is no data) becomes the file's internal mask band (a
    GDAL per-dataset mask, with overviews), which the COG driver writes after each level's
    image data as the COG layout wants.
    """
    data = np.ascontiguousarray(array if array.ndim == 3 else array[:, :, None], dtype=np.uint8)
    height, width, count = data.shape
    profile: dict[str, Any] = {"driver": "GTiff", "width": width, "height": height, "count": count,
                               "dtype": "uint8", "crs": crs, "transform": transform, "interleave": "pixel"}
    if count == 3:
        profile["photometric"] = "RGB"
    with MemoryFile() as staging:
        with staging.open(**profile) as dst:
            dst.write(data.transpose(2, 0, 1))
            if mask is not None:
                dst.write_mask(np.where(mask, 255, 0).astype(np.uint8))
            if describe is not None:
                describe(dst)
        with staging.open() as src:
            return cog_copy(src, classes=classes)


def cog_copy(src: DatasetReader, *, classes: bool) -> bytes:
    """The COG bytes of an open dataset (GDAL's COG driver, :func:`cog_options`)."""
    with MemoryFile() as out:
        copy_raster(src, out.name, driver="COG", **cog_options(classes=classes))
        return bytes(out.read())


def cog_file(src_path: Path, dst_path: Path, *, classes: bool) -> None:
    """Rewrite a GeoTIFF at ``src_path`` as a COG at ``dst_path`` (streamed by GDAL, any size)."""
    with rasterio.open(src_path) as src:
        cog_dataset(src, dst_path, classes=classes)


def cog_dataset(src: Any, dst_path: Path, *, classes: bool) -> None:
    """Write an open dataset (a file, a WarpedVRT) as a COG at ``dst_path``, streamed by GDAL."""
    try:
        copy_raster(src, str(dst_path), driver="COG", **cog_options(classes=classes))
    except rasterio.errors.RasterioError as exc:
        raise DatasetError(f"{dst_path}: could not write the Cloud-Optimized GeoTIFF ({exc}); "
                           "check the free disk space") from None
