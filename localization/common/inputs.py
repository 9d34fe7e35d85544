"""Inputs of ``osmseg localize``: each side (aerial, ground) read into landmarks plus what to draw.

A side is a label mask (PNG/GeoTIFF of class ids, its table from ``--*-table``, its dataset's
manifest or the dictionary), a landmark file (``x y Class`` lines, CSV, ``.npy``), or an RGB
image segmented with ``--*-checkpoint``. :func:`load_side` tells them apart and returns a
:class:`Side`; errors name the option to change.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from osmseg.classes import ClassTable, load_class_table
from osmseg.errors import ConfigError, DatasetError
from osmseg.images import is_tiff, read_raster, read_rgb
from osmseg.output.manifest import MANIFEST_NAME, SampleRecord, read_manifest

if TYPE_CHECKING:
    from localization.common.landmarks import Landmarks
    from localization.common.views import SemanticMap

logger = logging.getLogger(__name__)

LANDMARK_SUFFIXES = (".txt", ".csv", ".npy", ".lm")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")


@dataclass(frozen=True)
class Side:
    """One image's landmarks, what to draw under them, and its ground resolution if known.

    ``paint`` draws a mask's colour picture when there is no RGB ``background``; it runs only
    when pictures are asked for. ``colours`` gives each landmark class its class-table colour
    (:func:`~localization.common.landmarks.landmark_colours`: the table of the mask, else the
    dictionary's own), for the pictures' dots and legends. ``photo`` is the RGB image
    the landmarks were found in (segmented, or given by --*-image): the one landmark
    features (--feature-threshold) are computed from; None for a mask or landmark file alone.
    """

    landmarks: Landmarks
    background: np.ndarray | None
    resolution: float | None
    paint: Callable[[], np.ndarray] | None = None
    photo: np.ndarray | None = None
    semantic: SemanticMap | None = None  # a mask side's classes (the profile method's input)
    colours: dict[str, tuple[int, int, int]] = field(default_factory=dict)  # landmark class -> RGB

    def picture(self) -> np.ndarray | None:
        """The RGB image to draw under the landmarks, if any."""
        return self.background if self.background is not None or self.paint is None else self.paint()


@dataclass(frozen=True)
class SideOptions:
    """How to read one side (the command's ``--aerial-*`` or ``--ground-*`` options)."""

    name: str  # "aerial" or "ground": for messages
    classes: str
    table: str | None
    size: tuple[int, int] | None
    checkpoint: Path | None
    panorama: bool
    mode: str
    min_size: int
    grid_stride: int
    model: Path | None = None          # a TorchScript/ONNX model to segment the image with (--ground-model)
    model_classes: Path | None = None  # its class mapping TOML (--ground-model-classes)

    @property
    def segments(self) -> str | None:
        """The option that segments an RGB image on this side, if one was given (for messages)."""
        if self.checkpoint is not None:
            return f"--{self.name}-checkpoint"
        return f"--{self.name}-model" if self.model is not None else None


def _dictionary(name: str) -> Any:
    """A landmark class dictionary by name ("aerial13", "landmarks-aerial13", a .toml path)."""
    from localization.common.landmarks import load_landmark_classes

    return load_landmark_classes(name)


# --------------------------------------------------------------------------- reading inputs


def _read_image(path: Path) -> tuple[np.ndarray, float | None]:
    """Pixels ``(H, W)`` or ``(H, W, bands)`` of an image, and its ground resolution (m/px) if georeferenced."""
    raster = read_raster(path)
    if raster.resolution_m is None:  # a photo, not a map: as a person sees it (its EXIF orientation applied)
        from localization.common.photo import upright_pixels

        return upright_pixels(raster.pixels, path), None
    return raster.pixels, raster.resolution_m


def _manifest_for(mask: Path) -> tuple[ClassTable, SampleRecord, Path] | None:
    """The class table and sample entry of ``mask`` in the manifest of the osmseg dataset listing it, and its root.

    Looks at ``DATASET/labels/NAME.png`` -> ``DATASET/manifest.json`` (and a manifest beside the
    mask); a manifest that does not list the mask is not its own and is ignored.
    """
    for root in (mask.parent.parent, mask.parent):
        if not (root / MANIFEST_NAME).is_file():
            continue
        manifest = read_manifest(root)
        rel = mask.resolve().relative_to(root.resolve()).as_posix()
        sample = next((s for s in manifest.samples if rel in s.files), None)
        if sample is not None:
            return manifest.classes, sample, root
    return None


def manifest_bounds_3857(mask: Path) -> tuple[tuple[float, float, float, float], tuple[int, int]] | None:
    """The Web Mercator bounds (left, bottom, right, top) and shape (rows, cols) of a dataset
    mask, from the manifest of the osmseg dataset listing it; None when there is none."""
    found = _manifest_for(mask)
    if found is None:
        return None
    _, sample, _ = found
    bounds = sample.bounds()
    if bounds is None:
        return None
    shape = read_raster(mask).pixels.shape[:2]
    left, bottom, right, top = (float(v) for v in bounds)
    return (left, bottom, right, top), (int(shape[0]), int(shape[1]))


def _mask_side(path: Path, pixels: np.ndarray, resolution: float | None, opts: SideOptions, dictionary: Any,
               rgb: np.ndarray | None, table: ClassTable | None) -> Side:
    """Landmarks of a label mask, with the best background at hand (RGB image, class colours)."""
    from localization.common.landmarks import landmark_colours, landmarks_from_mask, panorama_table
    from localization.common.views import semantic_map

    background = rgb
    if opts.table is not None:
        table = load_class_table(opts.table)
    elif table is None:
        found = _manifest_for(path)
        if found is not None:
            table, sample, root = found
            resolution = resolution or sample.ground_resolution_m
            image = None if (rel := sample.file_in("images")) is None else root / rel
            if background is None and image is not None and image.is_file():
                background = _drawable(_read_image(image)[0])  # the sample's photo, whatever its format
    if table is not None and opts.name == "ground" and max(table.by_id) < 255:
        table = panorama_table(table)  # a view from the ground may show the sky, as the renderers draw it
    ids: Any = {c.id: c.name for c in table.by_id.values()} if table is not None else None
    # the colours of the mask's table, else of the dictionary's own (a mask read with the dictionary's classes)
    shown = table if table is not None else (load_class_table(dictionary.mask_table) if dictionary.mask_table else None)
    colours = {c.id: c.color for c in shown.by_id.values()} if shown is not None else {}
    mask = pixels if np.issubdtype(pixels.dtype, np.integer) else pixels.astype(np.int64)  # not 8 bytes a pixel
    lm = landmarks_from_mask(mask, ids, dictionary, mode=opts.mode, stride=opts.grid_stride,
                             min_size=opts.min_size, panorama=opts.panorama)
    paint: Callable[[], np.ndarray] | None = None
    if background is None and 0 <= int(mask.min()) and int(mask.max()) < 256:
        names = ids if ids is not None else dictionary.mask_ids()

        def paint_mask() -> np.ndarray:
            return _colourise(mask, colours, names, dictionary)
        paint = paint_mask
    return Side(lm, background, resolution, paint, semantic=semantic_map(mask, ids, dictionary),
                colours=landmark_colours(dictionary, shown))


def _colourise(mask: np.ndarray, colours: dict[int, Any], ids: dict[int, str] | None, dictionary: Any) -> np.ndarray:
    """An RGB picture of a class mask: its table's colours, else (a dictionary with no class table)
    pale landmark-class colours (others grey)."""
    lut = np.full((256, 3), 235, dtype=np.uint8)
    if colours:
        for cid, rgb_colour in colours.items():
            if 0 <= cid < 256:
                lut[cid] = rgb_colour
    elif ids:
        from matplotlib.colors import to_rgb

        from localization.common.figures import landmark_palette

        palette = dict(zip(dictionary.names, landmark_palette(dictionary.names)))
        for cid, name in ids.items():
            target = dictionary.mapping.get(name)
            if target is not None and 0 <= cid < 256:  # pale, so the graph drawn over it stands out
                lut[cid] = [round(255 - 0.45 * (255 - 255 * v)) for v in to_rgb(palette[target])]
    return cast("np.ndarray", lut[mask])


def _drawable(pixels: np.ndarray) -> np.ndarray | None:
    """``pixels`` as an RGB picture to draw under landmarks (values clipped), or None if they are no image.

    Not :func:`osmseg.images.as_rgb`, which refuses what a model cannot take: a picture may be drawn
    from a 16-bit photo, and a mask of class ids is not one.
    """
    if pixels.ndim == 3 and pixels.shape[2] >= 3:
        rgb = pixels[:, :, :3]
        return rgb if rgb.dtype == np.uint8 else np.clip(rgb, 0, 255).astype(np.uint8)
    if pixels.ndim == 2 and pixels.dtype == np.uint8:
        return np.repeat(pixels[:, :, None], 3, axis=2)
    return None


def _photo(path: Path, pixels: np.ndarray, resolution: float | None) -> np.ndarray | None:
    """The RGB photo a model sees (to segment it, or for landmark features): a GeoTIFF as every
    osmseg imagery reader takes it (:func:`osmseg.images.read_rgb`: 16-bit values scaled by their
    declared depth, a colour table looked up, as ``osmseg build`` and ``predict`` do), else ``pixels``
    as drawn (None if they are no image). ``resolution``: the image's m/px, None for a photo."""
    if not is_tiff(path):
        return _drawable(pixels)
    rgb = read_rgb(path)
    if rgb is not None and resolution is None:  # a TIFF photo, not a map: upright, as a person sees it
        from localization.common.photo import upright_pixels

        rgb = upright_pixels(rgb, path)
    return rgb


def _segmented_side(path: Path, pixels: np.ndarray, resolution: float | None, opts: SideOptions,
                    dictionary: Any) -> Side:
    """Segment an RGB image with ``opts.checkpoint`` (an osmseg checkpoint, needs PyTorch) or
    ``opts.model`` (TorchScript or ONNX, with its class mapping), then read its mask."""
    rgb = _photo(path, pixels, resolution)
    if rgb is None:
        raise ConfigError(f"{path}: {opts.segments} needs an RGB image, got {pixels.shape}")
    if opts.model is not None:
        from localization.common.landmarks import panorama_table
        from training.inference.foreign import load_foreign_model

        # a ground photo shows the sky: the mapping may name it, as the table's panorama has it
        foreign = load_foreign_model(opts.model, opts.model_classes, panorama_table if opts.name == "ground" else None)
        mask = foreign.segment(rgb)
        return replace(_mask_side(path, mask, resolution, opts, dictionary, rgb, foreign.mapping.table), photo=rgb)
    from osmseg.cli.common import require_torch

    require_torch()
    from training.inference.windows import predict_array
    from training.models.checkpoint import model_from_checkpoint

    model, spec = model_from_checkpoint(opts.checkpoint)  # type: ignore[arg-type]
    mask = predict_array(model, rgb, spec)
    return replace(_mask_side(path, mask, resolution, opts, dictionary, rgb, spec.table), photo=rgb)


def _landmark_file_side(path: Path, opts: SideOptions, dictionary: Any) -> Side:
    """Landmarks of an ``x y Class`` / CSV / .npy file, sized by --*-size, an image beside it, or their extent."""
    from localization.common.landmark_files import read_landmarks

    background, size = None, opts.size
    beside = next((path.with_suffix(s) for s in IMAGE_SUFFIXES if path.with_suffix(s).is_file()), None)
    resolution = None
    if beside is not None:
        pixels, resolution = _read_image(beside)
        background = _drawable(pixels)
        size = size or (pixels.shape[1], pixels.shape[0])
    if size is None:
        probe = read_landmarks(path, dictionary, 1 << 30, 1 << 30)
        if len(probe) == 0:
            size = (1, 1)
        else:
            size = (int(probe.xy[:, 0].max()) + 1, int(probe.xy[:, 1].max()) + 1)
        logger.warning("%s: no image size given (--%s-size) and no image beside it: using %dx%d, the landmarks' "
                       "extent%s", path, opts.name, size[0], size[1],
                       "; a panorama's width must be exact for its wrap-around" if opts.panorama else "")
    elif background is not None and (background.shape[1], background.shape[0]) != size:
        background = None  # an image of another size cannot be drawn under these landmarks
    from localization.common.landmarks import landmark_colours

    return Side(read_landmarks(path, dictionary, size[0], size[1], panorama=opts.panorama), background, resolution,
                colours=landmark_colours(dictionary))


def load_side(path: Path, opts: SideOptions) -> Side:
    """Read one side of the match from whatever ``path`` is (see the module docstring)."""
    dictionary = _dictionary(opts.classes)
    suffix = path.suffix.lower()
    if suffix in LANDMARK_SUFFIXES or suffix not in IMAGE_SUFFIXES:
        if opts.segments is not None:
            raise ConfigError(f"{opts.segments} needs an image to segment, but {path.name} is a landmark file")
        return _landmark_file_side(path, opts, dictionary)
    pixels, resolution = _read_image(path)
    if opts.segments is not None:
        return _segmented_side(path, pixels, resolution, opts, dictionary)
    if pixels.ndim != 2 or not np.issubdtype(pixels.dtype, np.integer):
        kind = f"{pixels.shape[2]}-band" if pixels.ndim == 3 else f"{pixels.dtype}"
        raise DatasetError(f"{path}: a {kind} image is not a label mask of class ids: give the mask, a landmark "
                           f"file, or --{opts.name}-checkpoint to segment it")
    return _mask_side(path, pixels, resolution, opts, dictionary, None, None)


def with_photo(side: Side, path: Path | None, name: str) -> Side:
    """``side`` with the RGB photo of ``--NAME-image`` (for landmark features; drawn under the pictures)."""
    if path is None:
        return side
    rgb, lm = _photo(path, *_read_image(path)), side.landmarks
    if rgb is None or rgb.shape[:2] != (lm.height, lm.width):
        got = "not an RGB image" if rgb is None else f"{rgb.shape[1]}x{rgb.shape[0]}"
        raise ConfigError(f"--{name}-image {path.name} is {got}; the {name} landmarks need the {lm.width}x{lm.height} "
                          f"RGB photo they were found in (or a matching --{name}-size)")
    return replace(side, background=rgb, photo=rgb)
