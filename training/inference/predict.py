"""Predict image files of any size and CRS into class masks (``osmseg predict``, ``osmseg eval``).

:func:`predict_file` reads a PNG/JPEG or any GDAL raster and writes the class ids as an 8-bit
PNG or as a Cloud-Optimized GeoTIFF with the source's CRS and transform and the class metadata
every osmseg GeoTIFF carries (:mod:`osmseg.output.geotiff`), block by block for big rasters
(:mod:`training.inference.windows` runs the model). With a target ground resolution the input is seen
through a bilinear WarpedVRT at that pixel size and the classes are brought back onto the
input's own grid with nearest neighbour, so a 0.1 m drone mosaic reaches a model trained on
0.3 m pixels at the size it learnt objects. An image that does not say where it lies (a dataset's
PNG or JPEG) is resampled the same way when its :class:`~training.inference.resolution.GroundPlace` is
known (a dataset's manifest records each sample's); :mod:`training.inference.resolution` also says once,
for all the inputs, which are far from the training data's resolution with nothing resampling
them, or cannot be resampled. Imports: osmseg core, :mod:`training.inference.windows` and
:mod:`training.inference.resolution`.
"""

from __future__ import annotations

import logging
import os
import warnings
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import rasterio
import torch
from affine import Affine
from PIL import Image
from rasterio.enums import ColorInterp, Resampling
from rasterio.errors import NotGeoreferencedWarning, RasterioError
from rasterio.io import MemoryFile
from rasterio.vrt import WarpedVRT
from rasterio.warp import reproject
from rasterio.windows import Window

from osmseg.errors import ConfigError, ImageryError
from osmseg.grid import ground_pixel_size
from osmseg.output.atomic import atomic_path
from osmseg.output.geotiff import cog_file, write_class_metadata
from osmseg.output.manifest import refuse_busy
from osmseg.output.style import qml_style, style_path
from osmseg.runtime.progress import Progress, track
from training.datasets.classes import check_mask_folder
from training.inference.resolution import (
    GroundPlace,
    input_places,
    known_resolution,
    resolution_factor,
    target_resolution,
    warn_resolutions,
)
from training.inference.tiling import pixel_blocks
from training.inference.windows import (
    DEFAULT_BLOCK,
    PIL_SUFFIXES,
    ArraySink,
    ArraySource,
    InferenceOptions,
    RasterSink,
    RasterSource,
    Source,
    error_reason,
    run_model,
)
from training.models.checkpoint import model_from_checkpoint

if TYPE_CHECKING:
    from training.models.spec import ModelSpec

logger = logging.getLogger(__name__)



@contextmanager
def _staging(tmp: Path) -> Iterator[Path]:
    """A hidden file beside ``tmp`` to write a tiled GeoTIFF into block by block before its COG copy."""
    stage = tmp.with_name(tmp.name + ".stage.tif")
    try:
        yield stage
    finally:
        stage.unlink(missing_ok=True)


def _kind(path: Path, what: str) -> str:
    suffix = path.suffix.lower()
    if suffix == ".png":
        return "png"
    if suffix in (".tif", ".tiff"):
        return "tif"
    raise ConfigError(f"{path}: {what} must end in .png or .tif, got {suffix or 'no suffix'!r}")


@contextmanager
def _open_source(src: Path) -> Iterator[tuple[Source, dict[str, Any]]]:
    """The image as a source plus its georeferencing (``crs``, ``transform``; empty for PNG/JPEG)."""
    if not src.is_file():
        raise ImageryError(f"{src}: no such file; check the path")
    if src.suffix.lower() in PIL_SUFFIXES:
        try:
            with Image.open(src) as image:
                image.load()
                if image.mode == "CMYK":
                    image = image.convert("RGB")
                elif image.mode in ("P", "PA"):
                    image = image.convert("RGBA" if "transparency" in image.info or image.mode == "PA" else "RGB")
                pixels = np.asarray(image)
        except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
            raise ImageryError(f"{src}: cannot read image ({error_reason(exc)}); give a PNG, JPEG or GeoTIFF") from None
        if pixels.dtype == bool:
            pixels = pixels.astype(np.uint8) * 255
        yield ArraySource(pixels, str(src)), {}
        return
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            dataset = rasterio.open(src)
    except RasterioError as exc:
        raise ImageryError(f"{src}: cannot open raster ({error_reason(exc)}); give a PNG, JPEG or GeoTIFF") from None
    with dataset:
        yield RasterSource(dataset, str(src)), {"crs": dataset.crs, "transform": dataset.transform}


@dataclass(frozen=True)
class PredictConfig:
    """What ``osmseg predict`` does: a checkpoint's model over ``inputs``, masks into ``out_dir``."""

    checkpoint: Path
    inputs: tuple[Path, ...]
    out_dir: Path
    mode: str = "split-join"  # split-join | rescale
    join: str = "blend"  # blend | crop
    overlap: int | None = None  # window overlap in pixels (None: a quarter of the window)
    block_size: int | None = DEFAULT_BLOCK
    tta: bool = False
    resolution: float | str | None = None  # metres, "model" (the training data's), or None: as they are
    batch_size: int = 4
    device: str = "auto"

    def outputs(self, src: Path) -> tuple[Path, Path]:
        """Where the class mask and the colour mask of input ``src`` go: NAME.png and
        NAME_color.png, or NAME.tif and NAME_color.tif for a GeoTIFF (georeferenced, block-written;
        NAME.qml, the mask's QGIS style, beside them)."""
        suffix = ".tif" if src.suffix.lower() in (".tif", ".tiff") else ".png"
        return self.out_dir / f"{src.stem}{suffix}", self.out_dir / f"{src.stem}_color{suffix}"


def predict_files(config: PredictConfig, progress: Progress | None = None) -> list[Path]:
    """Predict every input of ``config``; returns the class masks written, in input order.

    Inputs whose masks would land on one path (``a.png`` and ``a.jpg``) are refused before the
    model is loaded. ``progress``: the inputs (task ``predict``), and the windows of each (task
    ``predict NAME``).
    """
    stems = Counter(src.stem for src in config.inputs)
    if clash := sorted(stem for stem, n in stems.items() if n > 1):
        raise ConfigError(f"{stems[clash[0]]} inputs are named {clash[0]}.*: their masks would overwrite each other "
                          f"in {config.out_dir}; predict them into separate --out folders")
    refuse_busy(*config.inputs, config.out_dir)  # inputs or masks in a folder a build is writing
    model, spec = model_from_checkpoint(config.checkpoint, device=config.device)
    check_mask_folder(config.out_dir, spec.table, config.checkpoint)  # never masks of one table among another's
    resolution_m = target_resolution(config.resolution, spec)
    places = input_places(config.inputs)  # a dataset's images: placed by its manifest
    warn_resolutions([(str(src), known_resolution(src, places.get(src))) for src in config.inputs], spec, resolution_m)
    config.out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    options = InferenceOptions(config.mode, config.join, config.overlap, config.tta, config.batch_size, config.device,
                               config.block_size)
    for src in track(config.inputs, progress, "predict", unit="image"):  # each image's windows: its own task
        dst, colour = config.outputs(src)
        written.append(predict_file(model, spec, src, dst, options, colour_dst=colour, progress=progress,
                                    resolution_m=resolution_m, place=places.get(src), warn=False))
    return written


def predict_file(model: torch.nn.Module, spec: ModelSpec, src: str | Path, dst: str | Path,
                 options: InferenceOptions | None = None, *, colour_dst: str | Path | None = None,
                 progress: Progress | None = None, resolution_m: float | None = None,
                 place: GroundPlace | None = None, warn: bool = True) -> Path:
    """Predict ``src`` (PNG/JPEG/GeoTIFF or any GDAL raster) into a class-id mask at ``dst``, as
    ``options`` say (split-join or rescale, the join, overlap, TTA, batch, device, block size;
    :class:`~training.inference.windows.InferenceOptions`' defaults when None).

    ``dst`` ending in .png gets an 8-bit greyscale PNG of class ids (the whole mask is held in
    memory); ending in .tif a Cloud-Optimized GeoTIFF with the source's CRS and transform, the
    class colour table and names (:mod:`osmseg.output.geotiff`), predicted block by block, and
    beside it ``NAME.qml``, its QGIS style (:mod:`osmseg.output.style`).
    ``colour_dst`` (.png, or .tif beside a .tif mask) gets an RGB picture in the class colours.
    ``resolution_m``: a georeferenced input is first resampled (bilinear, on the fly) to pixels of
    that ground size, predicted there, and the classes brought back onto the input's own grid
    (nearest), so the mask always matches the input pixel for pixel; ``place``: where an input lies
    whose file does not say (:func:`predict_image`). ``warn``: say when the input
    is far from the training data's resolution with nothing resampling it, or ``resolution_m``
    cannot apply (False: the caller said it, once for all inputs: :func:`warn_resolutions`).
    Writes are atomic. Returns ``dst``.
    """
    options = options if options is not None else InferenceOptions()
    block_size = options.block_size
    src, dst = Path(src), Path(dst)
    out_kind = _kind(dst, "the mask")
    colour = Path(colour_dst) if colour_dst is not None else None
    if colour is not None and _kind(colour, "the colour mask") == "tif" and out_kind != "tif":
        raise ConfigError(f"{colour}: a GeoTIFF colour mask needs a GeoTIFF mask (dst ending in .tif)")
    if src.exists() and any(p is not None and p.resolve() == src.resolve() for p in (dst, colour)):
        raise ConfigError(f"{dst}: the output would overwrite the input image; choose another path")
    lut = spec.palette()
    if out_kind == "png":
        classes = predict_image(model, spec, src, options, resolution_m, progress, place=place, warn=warn)
        with atomic_path(dst) as tmp:
            Image.fromarray(classes).save(tmp, format="PNG")
    else:
        with _open_source(src) as (source, georef):
            factor, georef = _factor(source, georef, spec, src, resolution_m, options, place, warn)
            with _resampled(source, georef, factor) as (work, work_georef):
                profile = {"driver": "GTiff", "height": work.height, "width": work.width, "count": 1,
                           "dtype": "uint8", "compress": "deflate", "tiled": True, "blockxsize": 256,
                           "blockysize": 256, **work_georef}
                with atomic_path(dst) as tmp, _staging(tmp) as stage:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore", NotGeoreferencedWarning)
                        with rasterio.open(stage, "w", **profile) as out:
                            run_model(model, spec, work, RasterSink(out), options, progress)
                            write_class_metadata(out, spec.table)  # the one convention of every osmseg GeoTIFF
                        if work is not source:  # the classes back onto the input's grid, nearest neighbour
                            _regrid(stage, dict(profile, height=source.height, width=source.width, **georef),
                                    spec, block_size)
                        cog_file(stage, tmp, classes=True)
        with atomic_path(Path(style_path(str(dst)))) as tmp:  # QGIS's legend then names the classes
            tmp.write_bytes(qml_style(spec.table))
    if colour is not None:
        _write_colour(dst, colour, lut, block_size)
    return dst


def predict_image(model: torch.nn.Module, spec: ModelSpec, src: str | Path, options: InferenceOptions,
                  resolution_m: float | None = None, progress: Progress | None = None, *,
                  place: GroundPlace | None = None, warn: bool = True) -> np.ndarray:
    """Class ids ``(H, W)`` uint8 of an image file, on the file's own grid, held in memory.

    What :func:`predict_file` writes as a PNG mask and what ``osmseg eval`` scores: the same
    resampling (a bilinear WarpedVRT to ``resolution_m``, GDAL's nearest neighbour back), so
    ``predict`` and ``eval`` of one image with one ``--resolution`` give the same classes.
    ``place``: where the image lies when the file does not say (a dataset sample's PNG): it is
    resampled as a GeoTIFF of that place would be. ``warn``: as :func:`predict_file`'s.
    """
    with _open_source(Path(src)) as (source, georef):
        factor, georef = _factor(source, georef, spec, Path(src), resolution_m, options, place, warn)
        with _resampled(source, georef, factor) as (work, work_georef):
            sink = ArraySink(work.height, work.width)
            run_model(model, spec, work, sink, options, progress)
            if work is source:
                return sink.array
            back = np.zeros((source.height, source.width), dtype=np.uint8)
            reproject(sink.array, back, src_transform=work_georef["transform"], src_crs=work_georef["crs"],
                      dst_transform=georef["transform"], dst_crs=georef["crs"], resampling=Resampling.nearest)
            return back


def _factor(source: Source, georef: dict[str, Any], spec: ModelSpec, src: Path, resolution_m: float | None,
            options: InferenceOptions, place: GroundPlace | None = None, warn: bool = True,
            ) -> tuple[float, dict[str, Any]]:
    """How much to enlarge ``source`` for ``resolution_m``, and the georeferencing it is resampled
    with: the file's own, else ``place``'s (``warn``: when the input is far from the training's
    resolution, or cannot be resampled)."""
    pixel_m = (ground_pixel_size(georef["crs"], georef["transform"], source.width, source.height)
               if georef.get("crs") else None)
    if pixel_m is None and place is not None:  # measured on its place's grid as a GeoTIFF of that place would be
        georef = place.georef(source.width, source.height)
        pixel_m = ground_pixel_size(georef["crs"], georef["transform"], source.width, source.height) or place.pixel_m
    if warn:
        warn_resolutions([(str(src), pixel_m)], spec, resolution_m)
    factor = resolution_factor(pixel_m, resolution_m)
    logger.info("%s: %dx%d, %s, resampled x%.3g", src, source.width, source.height, options.mode, factor)
    return factor, georef


def _regrid(stage: Path, profile: dict[str, Any], spec: ModelSpec, block_size: int | None) -> None:
    """Replace the class mask at ``stage`` by its nearest-neighbour copy on ``profile``'s grid, block by block."""
    regridded = stage.with_name(stage.name + ".grid.tif")
    try:
        with rasterio.open(stage) as staged, WarpedVRT(staged, crs=profile["crs"], transform=profile["transform"],
                                                       width=profile["width"], height=profile["height"],
                                                       resampling=Resampling.nearest) as back, \
                rasterio.open(regridded, "w", **profile) as out:
            for r0, r1, c0, c1 in pixel_blocks(out.height, out.width, block_size):
                window = Window(c0, r0, c1 - c0, r1 - r0)
                out.write(back.read(1, window=window), 1, window=window)
            write_class_metadata(out, spec.table)
        os.replace(regridded, stage)
    finally:
        regridded.unlink(missing_ok=True)


@contextmanager
def _resampled(source: Source, georef: dict[str, Any], factor: float) -> Iterator[tuple[Source, dict[str, Any]]]:
    """``source`` seen through a bilinear WarpedVRT enlarged ``factor`` times (itself when 1). A
    PNG or JPEG placed by a :class:`GroundPlace` is first an in-memory GeoTIFF of its pixels."""
    if factor == 1.0 or not georef.get("crs"):
        yield source, georef
        return
    if isinstance(source, ArraySource):
        with _raster_of(source, georef) as raster, _resampled(raster, georef, factor) as resampled:
            yield resampled
        return
    if not isinstance(source, RasterSource):
        yield source, georef
        return
    width, height = max(1, round(source.width * factor)), max(1, round(source.height * factor))
    transform = georef["transform"] * Affine.scale(source.width / width, source.height / height)
    resampling = Resampling.nearest if source.rule.nearest else Resampling.bilinear  # palette indices: nearest
    with WarpedVRT(source.dataset, crs=georef["crs"], transform=transform, width=width, height=height,
                   resampling=resampling) as vrt:
        yield RasterSource(vrt, source.name, source.rule), {"crs": georef["crs"], "transform": transform}


@contextmanager
def _raster_of(source: ArraySource, georef: dict[str, Any]) -> Iterator[RasterSource]:
    """An image held in memory as an in-memory GeoTIFF at ``georef``: RGB, and its alpha as an alpha
    band (the pixels it marks empty stay empty through the resampling)."""
    whole = (0, source.height, 0, source.width)
    bands = [*source.read(whole).transpose(2, 0, 1)]
    if source.has_mask:
        bands.append(np.where(source.valid(whole), 255, 0).astype(np.uint8))
    with MemoryFile() as memory:
        with memory.open(driver="GTiff", width=source.width, height=source.height, count=len(bands), dtype="uint8",
                         photometric="RGB", **georef) as raster:
            raster.write(np.stack(bands))
            if len(bands) == 4:
                raster.colorinterp = [ColorInterp.red, ColorInterp.green, ColorInterp.blue, ColorInterp.alpha]
        with memory.open() as raster:
            yield RasterSource(raster, source.name)


def _write_colour(mask: Path, colour: Path, lut: np.ndarray, block_size: int | None) -> None:
    """Colour picture of a written mask: whole for PNG, block by block for GeoTIFF."""
    if _kind(colour, "the colour mask") == "png":
        if mask.suffix.lower() == ".png":
            with Image.open(mask) as image:
                ids = np.asarray(image)
        else:
            with rasterio.open(mask) as ds:
                ids = ds.read(1)
        with atomic_path(colour) as tmp:
            Image.fromarray(lut[ids]).save(tmp, format="PNG")
        return
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(mask) as ds, atomic_path(colour) as tmp, _staging(tmp) as stage:
            profile = {"driver": "GTiff", "height": ds.height, "width": ds.width, "count": 3, "dtype": "uint8",
                       "crs": ds.crs, "transform": ds.transform, "tiled": True, "blockxsize": 256,
                       "blockysize": 256, "photometric": "RGB", "compress": "deflate"}
            with rasterio.open(stage, "w", **profile) as out:
                for r0, r1, c0, c1 in pixel_blocks(ds.height, ds.width, block_size):
                    window = Window(c0, r0, c1 - c0, r1 - r0)
                    out.write(lut[ds.read(1, window=window)].transpose(2, 0, 1), window=window)
            cog_file(stage, tmp, classes=True)  # class colours: nearest-neighbour overviews
