"""Run a segmentation model on images of any size and CRS (``osmseg predict``).

Two modes:

* ``split-join`` (default): cover the image with overlapping windows of the model's training
  size (360x480), predict each, join.  ``join="blend"`` (default) sums the windows' softmax
  probabilities weighted by a ramp that fades out towards each window edge, so there are no
  seams and every pixel is decided mostly by the window that sees it with most context;
  ``join="crop"`` is the dissertation's: each overlap is split in the middle and each window
  keeps only its central part (cheaper, exact class ids per window, but a seam can show where
  two windows disagree).  Blending averages *probabilities*, not logits: they are bounded, so
  a window that is confidently wrong near its edge (where it lacks context) cannot outvote a
  window that sees the pixel in its centre, whatever the logits' scale.
* ``rescale``: letterbox the whole image into one window (black bars, added before
  normalisation), predict once, crop the bars and scale the class map back with nearest
  neighbour: class ids are never interpolated.  Fast and sees all context, but loses detail.

split-join is the default because it shows the model the ground resolution it was trained
at (the training patches are cut from the samples, never scaled): a 1280x1280 sample
rescaled into 360x480 shrinks 3.6 times, and roads and trees a few pixels wide vanish.

Test-time augmentation (``tta=True``) averages the logits of flipped copies (and, for square
windows, rotated ones) after undoing each transform.  When the checkpoint ignores a class in
training (``spec.ignore_index``, normally 0 = unlabeled) that class is never predicted: its
logit was never trained.

Big rasters are processed in blocks (:meth:`training.tiling.WindowGrid.blocks`): each block
reads its windows plus halo through a rasterio window and writes its part of a tiled
GeoTIFF, so memory is bounded by the block (about ``num_classes * block_size**2 * 4`` bytes
for blending) whatever the raster's size, and the result equals whole-image processing.
``rescale`` reads a raster decimated (GDAL resamples on the fly; memory is one window plus
GDAL's block cache) and writes the upscaled mask block by block.
"""

from __future__ import annotations

import logging
import os
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import rasterio
import torch
from affine import Affine
from PIL import Image
from rasterio.enums import Resampling
from rasterio.errors import NotGeoreferencedWarning, RasterioError
from rasterio.vrt import WarpedVRT
from rasterio.windows import Window

from osmseg.errors import ConfigError, ImageryError
from osmseg.output.atomic import temp_path_for
from osmseg.grid import ground_pixel_size
from osmseg.output.geotiff import cog_file, write_class_metadata
from training.distributed import pick_device
from training.tiling import Box, WindowGrid, blend_weight, letterbox, nearest_index, pixel_blocks

if TYPE_CHECKING:
    from training.checkpoint import ModelSpec

logger = logging.getLogger(__name__)

MODES = ("split-join", "rescale")
JOINS = ("blend", "crop")
#: overlap None = a quarter of each window side (90x120 px for 360x480): a 2048x2048 raster takes
#: 48 windows instead of 30 for a plain tiling, and each kept pixel is at least ~45 px from
#: of the inner window edges (crop), or cross-faded over 90-120 px (blend).
DEFAULT_OVERLAP_FRACTION = 0.25
DEFAULT_BLOCK = 2048  # pixels a side of an output block (blend: ~235 MB of float32 for 14 classes)
PIL_SUFFIXES = (".png", ".jpg", ".jpeg")
Progress = Callable[[int, int], None]  # (windows done, windows planned)


@dataclass(frozen=True)
class InferenceOptions:
    """How to predict; validated on creation (ConfigError with a one-line message)."""

    mode: str = "split-join"
    join: str = "blend"
    overlap: int | tuple[int, int] | None = None
    tta: bool = False
    batch_size: int = 4
    device: str = "cpu"
    block_size: int | None = DEFAULT_BLOCK

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ConfigError(f"mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        if self.join not in JOINS:
            raise ConfigError(f"join must be one of {', '.join(JOINS)}, got {self.join!r}")
        if self.overlap is not None:
            overlaps = (self.overlap,) if isinstance(self.overlap, int) else tuple(self.overlap)
            if len(overlaps) not in (1, 2) or not all(isinstance(o, int) and o >= 0 for o in overlaps):
                raise ConfigError(f"overlap must be pixels >= 0 (one number or rows,cols), got {self.overlap!r}")
        if self.batch_size < 1:
            raise ConfigError(f"batch size must be at least 1, got {self.batch_size}")
        if self.block_size is not None and self.block_size < 1:
            raise ConfigError(f"block size must be at least 1 pixel, got {self.block_size}")


# --------------------------------------------------------------------------- model running

def _device(name: str) -> torch.device:
    """The torch device ``name`` names (``auto``: the GPU when there is one, as in training)."""
    return pick_device(name)


_Op = Callable[[torch.Tensor], torch.Tensor]


def _tta_pairs(square: bool) -> list[tuple[_Op, _Op]]:
    """(transform, inverse) pairs of a group (so TTA output is exactly flip-equivariant).

    Flips for any window; for square windows the whole dihedral group (rotations too).
    """
    pairs: list[tuple[_Op, _Op]] = [
        (lambda t: t, lambda t: t),
        (lambda t: t.flip(-1), lambda t: t.flip(-1)),
        (lambda t: t.flip(-2), lambda t: t.flip(-2)),
        (lambda t: t.flip(-2, -1), lambda t: t.flip(-2, -1)),
    ]
    if square:  # the rest of the dihedral group: rotations by 90/270 and the two transposes
        pairs += [
            (lambda t: t.rot90(1, (-2, -1)), lambda t: t.rot90(-1, (-2, -1))),
            (lambda t: t.rot90(-1, (-2, -1)), lambda t: t.rot90(1, (-2, -1))),
            (lambda t: t.transpose(-2, -1), lambda t: t.transpose(-2, -1)),
            (lambda t: t.transpose(-2, -1).flip(-2, -1), lambda t: t.flip(-2, -1).transpose(-2, -1)),
        ]
    return pairs


def normalise(pixels: np.ndarray, mean: torch.Tensor, std: torch.Tensor) -> torch.Tensor:
    """``(N, h, w, 3)`` uint8 -> ``(N, 3, h, w)`` float32 on ``mean``'s device, as in training.

    RGB scaled to 0..1, minus ``mean``, over ``std`` (both ``(1, 3, 1, 1)``, from the spec). The
    one place inference and :mod:`localization.features` turn pixels into network input.
    """
    x = torch.from_numpy(np.ascontiguousarray(pixels)).to(mean.device).permute(0, 3, 1, 2).float() / 255.0
    return (x - mean) / std


class _Runner:
    """Normalises uint8 windows and runs the model (batching, device, autocast, TTA)."""

    def __init__(self, model: torch.nn.Module, spec: ModelSpec, options: InferenceOptions) -> None:
        if not 1 <= spec.num_classes <= 256:
            raise ConfigError(f"num_classes must be 1..256 for uint8 masks, got {spec.num_classes}")
        self.device = _device(options.device)
        self.model = model.to(self.device).eval()
        self.num_classes = spec.num_classes
        self.mean = torch.tensor(spec.mean, dtype=torch.float32, device=self.device).view(1, 3, 1, 1)
        self.std = torch.tensor(spec.std, dtype=torch.float32, device=self.device).view(1, 3, 1, 1)
        ignore = spec.ignore_index  # never trained, so never predicted (unless it is the only class)
        self.ignore = ignore if ignore is not None and 0 <= ignore < spec.num_classes > 1 else None
        self.tta = options.tta

    def logits(self, pixels: np.ndarray) -> torch.Tensor:
        """``(N, h, w, 3)`` uint8 windows -> ``(N, C, h, w)`` float32 logits on the device."""
        x = normalise(pixels, self.mean, self.std)
        cuda = self.device.type == "cuda"
        if cuda:
            x = x.contiguous(memory_format=torch.channels_last)
        with torch.autocast(self.device.type, enabled=cuda):
            if self.tta:
                pairs = _tta_pairs(square=x.shape[-1] == x.shape[-2])
                out = sum(undo(self.model(do(x)).float()) for do, undo in pairs) / len(pairs)
            else:
                out = self.model(x).float()
        want = (x.shape[0], self.num_classes, *x.shape[-2:])
        if tuple(out.shape) != want:
            raise ConfigError(f"the model returned logits of shape {tuple(out.shape)} for input {tuple(x.shape)}, "
                              f"expected {want}: does the checkpoint's num_classes match the network?")
        if self.ignore is not None:
            out[:, self.ignore] = float("-inf")
        return out


# --------------------------------------------------------------------------- sources and sinks

def _reason(exc: BaseException) -> str:
    """First line of the most specific message in an exception chain (GDAL's is the cause)."""
    while exc.__cause__ is not None and str(exc.__cause__):
        exc = exc.__cause__
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


class _Source(Protocol):
    name: str
    height: int
    width: int

    def read(self, box: Box) -> np.ndarray: ...  # (h, w, 3) uint8 of the box (inside the image)

    def read_resized(self, height: int, width: int) -> np.ndarray: ...  # whole image, resampled


def _rgb(pixels: np.ndarray, name: str) -> np.ndarray:
    """(h, w), (h, w, 1|3|4) uint8 -> (h, w, 3): grey replicated, alpha dropped."""
    if pixels.dtype != np.uint8:
        raise ImageryError(f"{name}: pixels are {pixels.dtype}, the model takes 8-bit RGB; convert it "
                           f"(e.g. gdal_translate -ot Byte -scale)")
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    bands = pixels.shape[2] if pixels.ndim == 3 else -1
    if bands == 1:
        return np.repeat(pixels, 3, axis=2)
    if bands in (3, 4):
        return pixels[:, :, :3]
    raise ImageryError(f"{name}: {bands if bands > 0 else 'unknown'} bands (shape {pixels.shape}); "
                       f"give 1 (grey), 3 (RGB) or 4 (RGBA) bands")


class _ArraySource:
    def __init__(self, pixels: np.ndarray, name: str = "image array") -> None:
        if pixels.ndim not in (2, 3) or pixels.shape[0] < 1 or pixels.shape[1] < 1:
            raise ImageryError(f"{name}: an image must be (height, width[, bands]), got shape {pixels.shape}")
        _rgb(pixels[:1, :1], name)  # check dtype and bands before anything runs
        self.pixels, self.name = pixels, name
        self.height, self.width = int(pixels.shape[0]), int(pixels.shape[1])

    def read(self, box: Box) -> np.ndarray:
        return _rgb(self.pixels[box[0]:box[1], box[2]:box[3]], self.name)

    def read_resized(self, height: int, width: int) -> np.ndarray:
        image = Image.fromarray(np.ascontiguousarray(self.read((0, self.height, 0, self.width))))
        return np.asarray(image.resize((width, height), Image.Resampling.BILINEAR))


class _RasterSource:
    def __init__(self, dataset: Any, name: str) -> None:
        self.dataset, self.name = dataset, name
        self.height, self.width = dataset.height, dataset.width
        if dataset.count not in (1, 3, 4):
            raise ImageryError(f"{name}: {dataset.count} bands; give 1 (grey), 3 (RGB) or 4 (RGBA) bands")
        if dataset.dtypes[0] != "uint8":
            raise ImageryError(f"{name}: pixels are {dataset.dtypes[0]}, the model takes 8-bit RGB; "
                               f"convert it (e.g. gdal_translate -ot Byte -scale)")
        self.indexes = [1, 1, 1] if dataset.count == 1 else [1, 2, 3]

    def _read(self, **kwargs: Any) -> np.ndarray:
        try:
            return self.dataset.read(self.indexes, **kwargs).transpose(1, 2, 0)
        except RasterioError as exc:
            raise ImageryError(f"{self.name}: cannot read pixels ({_reason(exc)}); "
                               f"the file may be truncated or corrupt") from None

    def read(self, box: Box) -> np.ndarray:
        return self._read(window=Window(box[2], box[0], box[3] - box[2], box[1] - box[0]))

    def read_resized(self, height: int, width: int) -> np.ndarray:
        resampling = Resampling.average if height <= self.height else Resampling.bilinear
        return self._read(out_shape=(3, height, width), resampling=resampling)


class _ArraySink:
    def __init__(self, height: int, width: int) -> None:
        self.array = np.zeros((height, width), dtype=np.uint8)

    def write(self, top: int, left: int, classes: np.ndarray) -> None:
        self.array[top:top + classes.shape[0], left:left + classes.shape[1]] = classes


class _RasterSink:
    def __init__(self, dataset: Any) -> None:
        self.dataset = dataset

    def write(self, top: int, left: int, classes: np.ndarray) -> None:
        self.dataset.write(classes, 1, window=Window(left, top, classes.shape[1], classes.shape[0]))


# --------------------------------------------------------------------------- the two modes

def _window_pixels(pixels: np.ndarray, read: Box, window: Box) -> np.ndarray:
    """The window cut from the block's pixels, reflect-padded where it passes the image."""
    part = pixels[window[0] - read[0]:min(window[1], read[1]) - read[0],
                  window[2] - read[2]:min(window[3], read[3]) - read[2]]
    pad = (window[1] - window[0] - part.shape[0], window[3] - window[2] - part.shape[1])
    if pad[0] or pad[1]:
        part = np.pad(part, ((0, pad[0]), (0, pad[1]), (0, 0)), mode="reflect")
    return part


def _argmax_classes(scores: np.ndarray) -> np.ndarray:
    """``scores.argmax(axis=0)`` as uint8, class by class: no copy of the (C, H, W) scores.

    (numpy's argmax over axis 0 first copies the array to make that axis last; torch's is
    several times slower on CPU.)  Ties go to the lower class id, as with argmax.
    """
    best = scores[0].copy()
    classes = np.zeros(best.shape, dtype=np.uint8)
    for c in range(1, scores.shape[0]):
        better = scores[c] > best
        classes[better] = c
        np.maximum(best, scores[c], out=best)
    return classes


def _split_join(runner: _Runner, source: _Source, sink: Any, options: InferenceOptions,
                size: tuple[int, int], progress: Progress | None) -> None:
    overlap = options.overlap
    if overlap is None:
        overlap = (int(size[0] * DEFAULT_OVERLAP_FRACTION), int(size[1] * DEFAULT_OVERLAP_FRACTION))
    grid = WindowGrid.build(source.height, source.width, size, overlap)
    blocks = grid.blocks(options.block_size, options.join)
    planned, done = sum(len(b.windows) for b in blocks), 0
    blend = options.join == "blend"
    weight = torch.from_numpy(blend_weight(size, grid.overlap)).to(runner.device)
    logger.debug("%s: %d windows in %d blocks (%d predictions)", source.name, len(grid), len(blocks), planned)
    for block in blocks:
        top, bottom, left, right = block.box
        pixels = source.read(block.read)
        if blend:
            acc = np.zeros((runner.num_classes, bottom - top, right - left), dtype=np.float32)
        else:
            acc = np.zeros((bottom - top, right - left), dtype=np.uint8)
        for first in range(0, len(block.windows), options.batch_size):
            ids = block.windows[first:first + options.batch_size]
            windows = [grid.window(i) for i in ids]
            logits = runner.logits(np.stack([_window_pixels(pixels, block.read, w) for w in windows]))
            # softmax over channels is 2-3x faster on contiguous NCHW than on channels_last logits
            scores = (torch.softmax(logits.contiguous(), dim=1).mul_(weight) if blend
                      else logits.argmax(dim=1).to(torch.uint8))
            for k, (i, window) in enumerate(zip(ids, windows)):
                region = window if blend else grid.keep(i)
                t0, t1 = max(region[0], top), min(region[1], bottom)
                l0, l1 = max(region[2], left), min(region[3], right)
                if t0 >= t1 or l0 >= l1:
                    continue
                part = scores[k, ..., t0 - window[0]:t1 - window[0], l0 - window[2]:l1 - window[2]].cpu().numpy()
                if blend:  # windows are added in global order, so sums match whole-image ones bit for bit
                    acc[:, t0 - top:t1 - top, l0 - left:l1 - left] += part
                else:
                    acc[t0 - top:t1 - top, l0 - left:l1 - left] = part
            done += len(ids)
            if progress is not None:
                progress(done, planned)
        # dividing by the weight sum would not change the argmax (a positive factor per pixel)
        sink.write(top, left, _argmax_classes(acc) if blend else acc)
        del acc  # free this block's accumulator before the next one is allocated


def _rescale(runner: _Runner, source: _Source, sink: Any, options: InferenceOptions,
             size: tuple[int, int], progress: Progress | None) -> None:
    top, bottom, left, right = letterbox(source.height, source.width, size)
    canvas = np.zeros((size[0], size[1], 3), dtype=np.uint8)  # black bars, before normalisation
    canvas[top:bottom, left:right] = source.read_resized(bottom - top, right - left)
    logits = runner.logits(canvas[None])
    classes = logits[0, :, top:bottom, left:right].argmax(dim=0).to(torch.uint8).cpu().numpy()
    if progress is not None:
        progress(1, 1)
    for r0, r1, c0, c1 in pixel_blocks(source.height, source.width, options.block_size):
        rows = nearest_index(source.height, classes.shape[0], r0, r1)
        cols = nearest_index(source.width, classes.shape[1], c0, c1)
        sink.write(r0, c0, classes[np.ix_(rows, cols)])


@torch.inference_mode()
def _predict(model: torch.nn.Module, spec: ModelSpec, source: _Source, sink: Any,
             options: InferenceOptions, progress: Progress | None) -> None:
    runner = _Runner(model, spec, options)
    size = (int(spec.input_size[0]), int(spec.input_size[1]))
    run = _rescale if options.mode == "rescale" else _split_join
    run(runner, source, sink, options, size, progress)


def predict_array(model: torch.nn.Module, rgb: np.ndarray, spec: ModelSpec, mode: str = "split-join", *,
                  join: str = "blend", overlap: int | tuple[int, int] | None = None, tta: bool = False,
                  batch_size: int = 4, device: str = "cpu", block_size: int | None = DEFAULT_BLOCK,
                  progress: Progress | None = None) -> np.ndarray:
    """Class ids (H, W) uint8 for an (H, W, 3) uint8 RGB image (1 band: grey; 4: alpha dropped).

    The model is moved to ``device`` and put in eval mode.  ``block_size`` bounds the memory of
    the joined scores (None: the whole image in one block; the result is the same).
    """
    options = InferenceOptions(mode, join, overlap, tta, batch_size, device, block_size)
    source = _ArraySource(np.asarray(rgb))
    sink = _ArraySink(source.height, source.width)
    _predict(model, spec, source, sink, options, progress)
    return sink.array


# --------------------------------------------------------------------------- files

@contextmanager
def _atomic(dst: Path) -> Iterator[Path]:
    """A hidden temporary path beside ``dst`` that replaces it (mode 0644) only on success."""
    tmp = temp_path_for(dst)
    try:
        yield tmp
        os.chmod(tmp, 0o644)
        os.replace(tmp, dst)
    finally:
        tmp.unlink(missing_ok=True)


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
def _open_source(src: Path) -> Iterator[tuple[_Source, dict[str, Any]]]:
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
            raise ImageryError(f"{src}: cannot read image ({_reason(exc)}); give a PNG, JPEG or GeoTIFF") from None
        if pixels.dtype == bool:
            pixels = pixels.astype(np.uint8) * 255
        yield _ArraySource(pixels, str(src)), {}
        return
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            dataset = rasterio.open(src)
    except RasterioError as exc:
        raise ImageryError(f"{src}: cannot open raster ({_reason(exc)}); give a PNG, JPEG or GeoTIFF") from None
    with dataset:
        yield _RasterSource(dataset, str(src)), {"crs": dataset.crs, "transform": dataset.transform}


def input_resolution(src: str | Path) -> float | None:
    """Ground metres per pixel of an image file (geodesic, any CRS); None without georeferencing."""
    path = Path(src)
    if path.suffix.lower() in PIL_SUFFIXES:
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as ds:
                return ground_pixel_size(ds.crs, ds.transform, ds.width, ds.height) if ds.crs else None
    except RasterioError:
        return None


def resolution_factor(pixel_m: float | None, target_m: float | None) -> float:
    """How much to enlarge an image with ``pixel_m`` pixels so they become ``target_m`` (1.0: leave it).

    >>> resolution_factor(0.6, 0.3), resolution_factor(None, 0.3), resolution_factor(0.3, 0.31)
    (2.0, 1.0, 1.0)
    """
    if pixel_m is None or target_m is None:
        return 1.0
    factor = pixel_m / target_m
    return 1.0 if abs(factor - 1.0) < 0.05 else factor


def target_resolution(asked: float | str | None, spec: ModelSpec) -> float | None:
    """``--resolution``'s metres: a number, ``"model"`` (the training data's, from the checkpoint) or None."""
    if asked is None or isinstance(asked, (int, float)):
        return None if asked is None else float(asked)
    if str(asked).strip().lower() == "model":
        if spec.resolution_m is None:
            raise ConfigError("--resolution model: this checkpoint does not record the ground resolution of its "
                              "training data; give it in metres, e.g. --resolution 0.3")
        return spec.resolution_m
    try:
        value = float(asked)
    except ValueError:
        raise ConfigError(f"--resolution {asked!r}: give metres per pixel (e.g. 0.3) or 'model'") from None
    if not value > 0:
        raise ConfigError(f"--resolution {asked!r}: must be > 0 metres per pixel")
    return value


def check_resolution(pixel_m: float | None, spec: ModelSpec, name: str, asked: float | None) -> None:
    """Warn when an input's pixels are far (> 1.5x) from the training data's and nothing resamples them."""
    trained = spec.resolution_m
    if asked is not None or pixel_m is None or trained is None:
        return
    if max(pixel_m / trained, trained / pixel_m) > 1.5:
        logger.warning("%s has %.3g m pixels but the model was trained on %.3g m pixels: objects look %.1fx %s "
                       "than it learnt them; pass --resolution model to resample the input first", name, pixel_m,
                       trained, max(pixel_m / trained, trained / pixel_m),
                       "smaller" if pixel_m > trained else "larger")


def predict_file(model: torch.nn.Module, spec: ModelSpec, src: str | Path, dst: str | Path, *,
                 colour_dst: str | Path | None = None, mode: str = "split-join", join: str = "blend",
                 overlap: int | tuple[int, int] | None = None, tta: bool = False, batch_size: int = 4,
                 device: str = "cpu", block_size: int | None = DEFAULT_BLOCK,
                 progress: Progress | None = None, resolution_m: float | None = None) -> Path:
    """Predict ``src`` (PNG/JPEG/GeoTIFF or any GDAL raster) into a class-id mask at ``dst``.

    ``dst`` ending in .png gets an 8-bit greyscale PNG of class ids (the whole mask is held in
    memory); ending in .tif a Cloud-Optimized GeoTIFF with the source's CRS and transform, the
    class colour table and names (:mod:`osmseg.output.geotiff`), predicted block by block.
    ``colour_dst`` (.png, or .tif beside a .tif mask) gets an RGB picture in the class colours.
    ``resolution_m``: a georeferenced input is first resampled (bilinear, on the fly) to pixels of
    that ground size, predicted there, and the classes brought back onto the input's own grid
    (nearest), so the mask always matches the input pixel for pixel. Writes are atomic.
    Returns ``dst``.
    """
    options = InferenceOptions(mode, join, overlap, tta, batch_size, device, block_size)
    src, dst = Path(src), Path(dst)
    out_kind = _kind(dst, "the mask")
    colour = Path(colour_dst) if colour_dst is not None else None
    if colour is not None and _kind(colour, "the colour mask") == "tif" and out_kind != "tif":
        raise ConfigError(f"{colour}: a GeoTIFF colour mask needs a GeoTIFF mask (dst ending in .tif)")
    if src.exists() and any(p is not None and p.resolve() == src.resolve() for p in (dst, colour)):
        raise ConfigError(f"{dst}: the output would overwrite the input image; choose another path")
    lut = spec.palette()
    with _open_source(src) as (source, georef):
        pixel_m = (ground_pixel_size(georef["crs"], georef["transform"], source.width, source.height)
                   if georef.get("crs") else None)
        check_resolution(pixel_m, spec, str(src), resolution_m)
        if resolution_m is not None and pixel_m is None:
            logger.warning("%s is not georeferenced: --resolution cannot apply, predicted at its own pixel size", src)
        factor = resolution_factor(pixel_m, resolution_m)
        logger.info("%s: %dx%d, %s, resampled x%.3g", src, source.width, source.height, options.mode, factor)
        with _resampled(source, georef, factor) as (work, work_georef):
            if out_kind == "png":
                sink = _ArraySink(work.height, work.width)
                _predict(model, spec, work, sink, options, progress)
                classes = sink.array
                if work is not source:
                    classes = np.asarray(Image.fromarray(classes).resize((source.width, source.height),
                                                                          Image.Resampling.NEAREST))
                with _atomic(dst) as tmp:
                    Image.fromarray(classes).save(tmp, format="PNG")
            else:
                profile = {"driver": "GTiff", "height": work.height, "width": work.width, "count": 1,
                           "dtype": "uint8", "compress": "deflate", "tiled": True, "blockxsize": 256,
                           "blockysize": 256, **work_georef}
                with _atomic(dst) as tmp, _staging(tmp) as stage:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore", NotGeoreferencedWarning)
                        with rasterio.open(stage, "w", **profile) as out:
                            _predict(model, spec, work, _RasterSink(out), options, progress)
                            write_class_metadata(out, spec.table)  # the one convention of every osmseg GeoTIFF
                        if work is not source:  # the classes back onto the input's grid, nearest neighbour
                            _regrid(stage, dict(profile, height=source.height, width=source.width, **georef),
                                    spec, block_size)
                        cog_file(stage, tmp, classes=True)
    if colour is not None:
        _write_colour(dst, colour, lut, block_size)
    return dst


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
def _resampled(source: _Source, georef: dict[str, Any], factor: float) -> Iterator[tuple[_Source, dict[str, Any]]]:
    """``source`` seen through a bilinear WarpedVRT enlarged ``factor`` times (itself when 1)."""
    if factor == 1.0 or not isinstance(source, _RasterSource):
        yield source, georef
        return
    width, height = max(1, round(source.width * factor)), max(1, round(source.height * factor))
    transform = georef["transform"] * Affine.scale(source.width / width, source.height / height)
    with WarpedVRT(source.dataset, crs=georef["crs"], transform=transform, width=width, height=height,
                   resampling=Resampling.bilinear) as vrt:
        yield _RasterSource(vrt, source.name), {"crs": georef["crs"], "transform": transform}


def _write_colour(mask: Path, colour: Path, lut: np.ndarray, block_size: int | None) -> None:
    """Colour picture of a written mask: whole for PNG, block by block for GeoTIFF."""
    if _kind(colour, "the colour mask") == "png":
        if mask.suffix.lower() == ".png":
            with Image.open(mask) as image:
                ids = np.asarray(image)
        else:
            with rasterio.open(mask) as ds:
                ids = ds.read(1)
        with _atomic(colour) as tmp:
            Image.fromarray(lut[ids]).save(tmp, format="PNG")
        return
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(mask) as ds, _atomic(colour) as tmp, _staging(tmp) as stage:
            profile = {"driver": "GTiff", "height": ds.height, "width": ds.width, "count": 3, "dtype": "uint8",
                       "crs": ds.crs, "transform": ds.transform, "tiled": True, "blockxsize": 256,
                       "blockysize": 256, "photometric": "RGB"}
            with rasterio.open(stage, "w", **profile) as out:
                for r0, r1, c0, c1 in pixel_blocks(ds.height, ds.width, block_size):
                    window = Window(c0, r0, c1 - c0, r1 - r0)
                    out.write(lut[ds.read(1, window=window)].transpose(2, 0, 1), window=window)
            cog_file(stage, tmp, classes=True)  # class colours: nearest-neighbour overviews
