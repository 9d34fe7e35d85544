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

Big rasters are processed in blocks (:meth:`training.inference.tiling.WindowGrid.blocks`): each block
reads its windows plus halo through a rasterio window and writes its part of a tiled
GeoTIFF, so memory is bounded by the block (about ``num_classes * block_size**2 * 4`` bytes
for blending) whatever the raster's size, and the result equals whole-image processing.
``rescale`` reads a raster decimated (GDAL resamples on the fly; memory is one window plus
GDAL's block cache) and writes the upscaled mask block by block.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, cast

import numpy as np
import torch
from PIL import Image
from rasterio.enums import MaskFlags, Resampling
from rasterio.errors import RasterioError
from rasterio.windows import Window

from osmseg.errors import ConfigError, ImageryError
from osmseg.images import PixelRule, as_rgb, pixel_rule
from osmseg.runtime.progress import Progress, report
from training.devices import pick_device
from training.inference.tiling import Box, WindowGrid, blend_weight, letterbox, nearest_index, pixel_blocks

if TYPE_CHECKING:
    from training.models.spec import ModelSpec

logger = logging.getLogger(__name__)

MODES = ("split-join", "rescale")
JOINS = ("blend", "crop")
#: overlap None = a quarter of each window side (90x120 px for 360x480): a 2048x2048 raster takes
#: 48 windows instead of 30 for a plain tiling, and each kept pixel is at least ~45 px from
#: of the inner window edges (crop), or cross-faded over 90-120 px (blend).
DEFAULT_OVERLAP_FRACTION = 0.25
DEFAULT_BLOCK = 2048  # pixels a side of an output block (blend: ~235 MB of float32 for 14 classes)
PIL_SUFFIXES = (".png", ".jpg", ".jpeg")
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
    one place inference and :mod:`localization.paper.features` turn pixels into network input.
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
                out = torch.zeros(())
                for do, undo in pairs:  # one view at a time: peak memory of two logit maps
                    out = out + undo(self.model(do(x)).float())
                out = out / len(pairs)
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

def error_reason(exc: BaseException) -> str:
    """First line of the most specific message in an exception chain (GDAL's is the cause)."""
    while exc.__cause__ is not None and str(exc.__cause__):
        exc = exc.__cause__
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


class Source(Protocol):
    name: str
    height: int
    width: int

    def read(self, box: Box) -> np.ndarray: ...  # (h, w, 3) uint8 of the box (inside the image)

    def read_resized(self, height: int, width: int) -> np.ndarray: ...  # whole image, resampled

    @property
    def has_mask(self) -> bool: ...  # whether some pixels may be marked empty

    def valid(self, box: Box) -> np.ndarray: ...  # (h, w) bool: True where the box has image data


class ArraySource:
    def __init__(self, pixels: np.ndarray, name: str = "image array") -> None:
        if pixels.ndim not in (2, 3) or pixels.shape[0] < 1 or pixels.shape[1] < 1:
            raise ImageryError(f"{name}: an image must be (height, width[, bands]), got shape {pixels.shape}")
        as_rgb(pixels[:1, :1], name)  # check dtype and bands before anything runs
        self.pixels, self.name = pixels, name
        self.height, self.width = int(pixels.shape[0]), int(pixels.shape[1])

    def read(self, box: Box) -> np.ndarray:
        return as_rgb(self.pixels[box[0]:box[1], box[2]:box[3]], self.name)

    def read_resized(self, height: int, width: int) -> np.ndarray:
        image = Image.fromarray(np.ascontiguousarray(self.read((0, self.height, 0, self.width))))
        return np.asarray(image.resize((width, height), Image.Resampling.BILINEAR))

    @property
    def has_mask(self) -> bool:
        return self.pixels.ndim == 3 and self.pixels.shape[2] == 4

    def valid(self, box: Box) -> np.ndarray:
        """Opaque pixels (alpha >= 128) of an RGBA image; everything otherwise."""
        part = self.pixels[box[0]:box[1], box[2]:box[3]]
        return part[:, :, 3] >= 128 if self.has_mask else np.ones(part.shape[:2], dtype=bool)


class RasterSource:
    """A raster read block by block as 8-bit RGB by :func:`osmseg.images.pixel_rule`: 16-bit values
    scaled by their declared bit depth, a colour table looked up (its alpha marks empty pixels),
    as ``osmseg build`` reads the same file. ``rule``: that of the file a WarpedVRT ``dataset`` shows
    (a VRT does not carry the file's declared bit depth)."""

    def __init__(self, dataset: Any, name: str, rule: PixelRule | None = None) -> None:
        self.dataset, self.name = dataset, name
        self.height, self.width = dataset.height, dataset.width
        if dataset.count not in (1, 3, 4):
            raise ImageryError(f"{name}: {dataset.count} bands; give 1 (grey), 3 (RGB) or 4 (RGBA) bands")
        self.rule = rule if rule is not None else pixel_rule(dataset, name)
        self.palette = self.rule.palette is not None
        self.indexes = [1] if self.palette else [1, 1, 1] if dataset.count == 1 else [1, 2, 3]

    def _read(self, **kwargs: Any) -> np.ndarray:
        """RGB ``(h, w, 3)``, or a palette's RGBA ``(h, w, 4)``."""
        try:
            return cast("np.ndarray", self.rule.colours(self.dataset.read(self.indexes, **kwargs)).transpose(1, 2, 0))
        except RasterioError as exc:
            raise ImageryError(f"{self.name}: cannot read pixels ({error_reason(exc)}); "
                               f"the file may be truncated or corrupt") from None

    def read(self, box: Box) -> np.ndarray:
        return self._read(window=Window(box[2], box[0], box[3] - box[2], box[1] - box[0]))[:, :, :3]

    def read_resized(self, height: int, width: int) -> np.ndarray:
        resampling = (Resampling.nearest if self.rule.nearest else
                      Resampling.average if height <= self.height else Resampling.bilinear)
        return self._read(out_shape=(len(self.indexes), height, width), resampling=resampling)[:, :, :3]

    @property
    def has_mask(self) -> bool:
        """True when GDAL knows empty pixels (nodata, alpha band, internal or side-car mask), or a
        colour table has transparent entries."""
        lut = self.rule.palette
        if lut is not None:
            return bool((lut[:, 3] < 255).any())
        return MaskFlags.all_valid not in self.dataset.mask_flag_enums[0]

    def valid(self, box: Box) -> np.ndarray:
        window = Window(box[2], box[0], box[3] - box[2], box[1] - box[0])
        if self.palette:
            return self._read(window=window)[:, :, 3] >= 128  # the table's alpha, as the builder reads it
        try:
            opaque = self.dataset.read_masks(1, window=window) >= 128  # an alpha band: as the builder, half opaque
            return cast("np.ndarray", opaque)
        except RasterioError as exc:
            raise ImageryError(f"{self.name}: cannot read its mask ({error_reason(exc)})") from None


class ArraySink:
    def __init__(self, height: int, width: int) -> None:
        self.array = np.zeros((height, width), dtype=np.uint8)

    def write(self, top: int, left: int, classes: np.ndarray) -> None:
        self.array[top:top + classes.shape[0], left:left + classes.shape[1]] = classes


class RasterSink:
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


def _split_join(runner: _Runner, source: Source, sink: Any, options: InferenceOptions,
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
    task = f"predict {Path(source.name).name}"
    report(progress, task, 0, planned, "window")
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
            report(progress, task, done, planned, "window")
        # dividing by the weight sum would not change the argmax (a positive factor per pixel)
        sink.write(top, left, _argmax_classes(acc) if blend else acc)
        del acc  # free this block's accumulator before the next one is allocated


def _rescale(runner: _Runner, source: Source, sink: Any, options: InferenceOptions,
             size: tuple[int, int], progress: Progress | None) -> None:
    top, bottom, left, right = letterbox(source.height, source.width, size)
    canvas = np.zeros((size[0], size[1], 3), dtype=np.uint8)  # black bars, before normalisation
    canvas[top:bottom, left:right] = source.read_resized(bottom - top, right - left)
    logits = runner.logits(canvas[None])
    classes = logits[0, :, top:bottom, left:right].argmax(dim=0).to(torch.uint8).cpu().numpy()
    report(progress, f"predict {Path(source.name).name}", 1, 1, "window")
    for r0, r1, c0, c1 in pixel_blocks(source.height, source.width, options.block_size):
        rows = nearest_index(source.height, classes.shape[0], r0, r1)
        cols = nearest_index(source.width, classes.shape[1], c0, c1)
        sink.write(r0, c0, classes[np.ix_(rows, cols)])


@torch.inference_mode()
def run_model(model: torch.nn.Module, spec: ModelSpec, source: Source, sink: Any,
             options: InferenceOptions, progress: Progress | None) -> None:
    """Predict ``source`` into ``sink``. Pixels the source marks as empty (nodata, an alpha band, a
    GDAL mask, transparent PNG pixels) get the unlabeled class: the model saw no image there."""
    runner = _Runner(model, spec, options)
    size = (int(spec.input_size[0]), int(spec.input_size[1]))
    run = _rescale if options.mode == "rescale" else _split_join
    void = spec.table.unlabeled.id
    run(runner, source, _MaskedSink(sink, source, void) if source.has_mask else sink, options, size, progress)


class _MaskedSink:
    """Writes the unlabeled class where the source has no valid pixel."""

    def __init__(self, sink: Any, source: Source, void: int = 0) -> None:
        self.sink, self.source, self.void = sink, source, void

    def write(self, top: int, left: int, classes: np.ndarray) -> None:
        valid = self.source.valid((top, top + classes.shape[0], left, left + classes.shape[1]))
        self.sink.write(top, left, np.where(valid, classes, self.void).astype(classes.dtype))


def predict_array(model: torch.nn.Module, rgb: np.ndarray, spec: ModelSpec, mode: str = "split-join", *,
                  join: str = "blend", overlap: int | tuple[int, int] | None = None, tta: bool = False,
                  batch_size: int = 4, device: str = "cpu", block_size: int | None = DEFAULT_BLOCK,
                  progress: Progress | None = None) -> np.ndarray:
    """Class ids (H, W) uint8 for an (H, W, 3) uint8 RGB image (1 band: grey; 4: alpha dropped).

    The model is moved to ``device`` and put in eval mode.  ``block_size`` bounds the memory of
    the joined scores (None: the whole image in one block; the result is the same).
    """
    options = InferenceOptions(mode, join, overlap, tta, batch_size, device, block_size)
    source = ArraySource(np.asarray(rgb))
    sink = ArraySink(source.height, source.width)
    run_model(model, spec, source, sink, options, progress)
    return sink.array
