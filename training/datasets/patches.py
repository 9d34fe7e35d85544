"""Datasets for training: image/label pairs, patches, class weights.

A dataset is a folder of RGB images, single-band label images of class ids with the same
file stems, and a class table saying what the ids mean (``manifest.json``'s ``classes`` as
``osmseg build`` writes it, a ``classes.toml`` beside the images, or ``--classes``). CamVid's
folder layout (``train/`` + ``trainannot/``, ...) loads through the same code
(:func:`discover_dataset`).

Patches
    As in the dissertation, each 1280x1280 sample gives six non-overlapping 360x480 patches
    (3 rows x 2 columns). They cover 1080x960 of the 1280x1280 pixels; the grid is centred,
    so the 200 unused rows and 320 unused columns are split evenly between opposite borders
    (100 px top and bottom, 160 px left and right) rather than all lost on one side.

Splits
    By area, never by patch or image: see :mod:`training.datasets.splits`.

Loading speed
    Decoding a 1280x1280 PNG takes ~50 ms, six times the label's decode and much more than
    cutting a patch. :class:`PatchDataset` keeps the last ``cache_images`` decoded images in
    an LRU cache per process (each DataLoader worker has its own; use
    ``persistent_workers=True`` so caches survive epochs). Under shuffling the hit rate is
    about ``cache_images / number of images``: small datasets (tests, demos, CPU runs) end up
    fully cached, sequential passes (validation) decode each image once instead of six times,
    and a large shuffled run gains little, at a bounded memory cost (~6.5 MB per image).
"""

from __future__ import annotations

import hashlib
import logging
import warnings
from collections import OrderedDict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rasterio
import rasterio.errors
import torch
from torch.utils.data import Dataset
from torchvision.transforms.v2 import functional as F

from osmseg.classes import ClassTable, load_class_table
from osmseg.errors import DatasetError
from osmseg.grid import ground_pixel_size
from osmseg.images import image_size, is_tiff, read_label, read_rgb
from osmseg.output.manifest import manifest_path, read_manifest
from osmseg.units import plural
from training.datasets.augment import OVERHEAD, AugmentConfig, Draw, draw, item_rng, jitter, orient

logger = logging.getLogger(__name__)

PATCH_SIZE = (360, 480)  # (height, width), the dissertation's and SegNet's CamVid input
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")
LABEL_SUFFIXES = (".png", ".tif", ".tiff")
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
SPLIT_NAMES = ("train", "val", "test")


@dataclass(frozen=True)
class SampleFiles:
    """One labelled sample: its name (the shared file stem), image file and label file."""

    name: str
    image: Path
    label: Path


# ---------------------------------------------------------------------------------- reading
# (image files are read by osmseg.images: read_rgb, read_label, image_size)


def check_label(label: np.ndarray, path: Path, num_classes: int) -> None:
    """DatasetError naming ``path`` and the offending values if any id is >= ``num_classes``."""
    if label.size and (int(label.max()) >= num_classes or int(label.min()) < 0):
        bad = [int(v) for v in np.unique(label) if not 0 <= v < num_classes]
        shown = ", ".join(map(str, bad[:8])) + (", ..." if len(bad) > 8 else "")
        raise DatasetError(f"{path}: class ids {shown} are not in the class table (ids 0..{num_classes - 1}); "
                           "fix the labels or give the matching class table (--classes)")


def _check_sizes(f: SampleFiles) -> tuple[int, int]:
    size, label_size = image_size(f.image), image_size(f.label)
    if size != label_size:
        raise DatasetError(f"{f.label}: label is {label_size[1]}x{label_size[0]} but image {f.image.name} is "
                           f"{size[1]}x{size[0]}; labels must be on the image's pixel grid")
    return size


# ---------------------------------------------------------------------------------- patches
def patch_boxes(height: int, width: int, size: tuple[int, int] = PATCH_SIZE) -> list[tuple[int, int]]:
    """(top, left) of the non-overlapping ``size`` patches of a ``height`` x ``width`` image.

    As many whole patches as fit, row-major, on a grid centred in the image (the leftover
    border is split evenly between opposite sides, the extra pixel of an odd leftover going
    to the bottom/right).

    >>> patch_boxes(1280, 1280)
    [(100, 160), (100, 640), (460, 160), (460, 640), (820, 160), (820, 640)]
    >>> patch_boxes(360, 480), patch_boxes(130, 160, (64, 80))
    ([(0, 0)], [(1, 0), (1, 80), (65, 0), (65, 80)])
    """
    ph, pw = size
    if ph < 1 or pw < 1:
        raise DatasetError(f"patch size must be positive, got {ph}x{pw}")
    if height < ph or width < pw:
        raise DatasetError(f"image of {width}x{height} is smaller than the {pw}x{ph} patch; "
                           "use a smaller patch size or larger images")
    rows, cols = height // ph, width // pw
    top0, left0 = (height - rows * ph) // 2, (width - cols * pw) // 2
    return [(top0 + r * ph, left0 + c * pw) for r in range(rows) for c in range(cols)]


def fitted_patch(size: tuple[int, int], files: Sequence[SampleFiles], least: int = 32) -> tuple[int, int]:
    """``size`` shrunk, side by side, to the smallest of ``files`` (so every image has at least
    one patch): validation on 256-px tiles (XYZ, fAIr, SpaceNet chips) runs on 256-px patches
    rather than refusing the 360x480 grid. A side under ``least`` pixels is a DatasetError.

    >>> fitted_patch((360, 480), [])
    (360, 480)
    """
    ph, pw = size
    for f in files:
        height, width = _check_sizes(f)
        if min(height, width) < least:
            raise DatasetError(f"{f.image}: image of {width}x{height} is too small to validate on; "
                               f"every side must be at least {least} pixels")
        ph, pw = min(ph, height), min(pw, width)
    return ph, pw


# -------------------------------------------------------------------------------- discovery
def _files_by_stem(folder: Path, suffixes: tuple[str, ...]) -> dict[str, Path]:
    found: dict[str, Path] = {}
    for path in sorted(folder.iterdir()):
        if path.name.startswith(".") or not path.is_file() or path.suffix.lower() not in suffixes:
            continue  # hidden temp files of an atomic write are never part of a dataset
        if path.stem in found:
            raise DatasetError(f"{folder}: two files for sample {path.stem!r} ({found[path.stem].name}, "
                               f"{path.name}); keep one")
        found[path.stem] = path
    return found


def discover(root: Path, image_dir: str = "images", label_dir: str = "labels") -> list[SampleFiles]:
    """Pair ``root/image_dir`` images with ``root/label_dir`` labels by file stem, sorted by name.

    Reads every image header, so an unreadable image fails here rather than mid-training.
    Labels without an image are skipped with a warning; images without a label are an error.
    """
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f"{root}: no such dataset folder; give the folder `osmseg build --out` wrote")
    folders = (root / image_dir, root / label_dir)
    for folder in folders:
        if not folder.is_dir():
            raise DatasetError(f"{root}: no {folder.name}/ folder; a dataset needs {image_dir}/ (RGB images) "
                               f"and {label_dir}/ (class-id masks with the same file names)")
    images = _files_by_stem(folders[0], IMAGE_SUFFIXES)
    labels = _files_by_stem(folders[1], LABEL_SUFFIXES)
    if not images:
        raise DatasetError(f"{folders[0]}: no images ({', '.join(IMAGE_SUFFIXES)}); is this the right folder?")
    missing = [name for name in images if name not in labels]
    if missing:
        shown = ", ".join(missing[:3]) + (f" and {len(missing) - 3} more" if len(missing) > 3 else "")
        raise DatasetError(f"{folders[1]}: no label for {plural(len(missing), 'image')}: {shown}; add the labels or "
                           "remove the images")
    orphans = sorted(set(labels) - set(images))
    if orphans:
        logger.warning("%s: %s without an image ignored (e.g. %s)", folders[1], plural(len(orphans), "label"),
                       orphans[0])
    files = [SampleFiles(name=name, image=path, label=labels[name]) for name, path in sorted(images.items())]
    for f in files:
        image_size(f.image)
    return files


def discover_camvid(root: Path) -> dict[str, list[SampleFiles]]:
    """The splits of a CamVid-style folder: ``train/`` + ``trainannot/``, ``val/`` + ``valannot/``,
    ``test/`` + ``testannot/`` (those present; ``train`` is required)."""
    root = Path(root)
    splits = {s: discover(root, s, f"{s}annot") for s in SPLIT_NAMES if (root / s).is_dir()}
    if "train" not in splits:
        raise DatasetError(f"{root}: no train/ and trainannot/ folders (CamVid layout)")
    return splits


def discover_dataset(root: Path) -> tuple[list[SampleFiles], dict[str, list[str]] | None]:
    """All samples of a dataset folder in either layout, and the splits it comes with (CamVid),
    or None when the splits are ours to draw (``osmseg build`` output, ``images/`` + ``labels/``)."""
    root = Path(root)
    if (root / "images").is_dir() or not (root / "train").is_dir():
        return discover(root), None
    given = discover_camvid(root)
    files = [f for split in given.values() for f in split]
    names = [f.name for f in files]
    if len(set(names)) != len(names):
        raise DatasetError(f"{root}: a sample name appears in two of {', '.join(given)}; rename it")
    return sorted(files, key=lambda f: f.name), {s: [f.name for f in given.get(s, [])] for s in SPLIT_NAMES}


def files_by_name(files: Sequence[SampleFiles], names: Iterable[str]) -> list[SampleFiles]:
    """The samples called ``names`` (in that order); DatasetError if the dataset lacks one."""
    by_name = {f.name: f for f in files}
    names = list(names)
    missing = [n for n in names if n not in by_name]
    if missing:
        raise DatasetError(f"the dataset has no sample {missing[0]!r} ({len(missing)} missing) named in the "
                           "splits; was the dataset changed? train again with a new --out")
    return [by_name[n] for n in names]


# ------------------------------------------------------------------------------ class table
def dataset_class_table(root: Path, classes: str | None = None) -> ClassTable:
    """What the label ids of dataset ``root`` mean: the TOML table ``classes`` when given, else
    ``root/manifest.json``'s ``classes`` (``osmseg build`` output), else ``root/classes.toml``."""
    if classes is not None:
        return load_class_table(str(classes))
    root = Path(root)
    if manifest_path(root).is_file():
        return read_manifest(root).classes
    if (root / "classes.toml").is_file():
        return load_class_table(str(root / "classes.toml"))
    raise DatasetError(f"{root}: no manifest.json or classes.toml says what the label ids mean; "
                       "give a class table with --classes FILE.toml")


def dataset_resolution(root: Path, files: Sequence[SampleFiles]) -> float | None:
    """The training images' ground pixel size in metres (median), recorded in the checkpoint.

    ``osmseg build`` output says it per sample (manifest.json ``ground_resolution_m``); other
    datasets are measured from their georeferenced images (up to 16 of them); None when the
    images are plain PNG/JPEG, which say nothing about the ground.
    """
    values: list[float] = []
    if manifest_path(Path(root)).is_file():
        try:
            values = [float(v) for v in read_manifest(Path(root)).ground_resolutions()]
        except (DatasetError, ValueError, TypeError):
            values = []  # measured from the images below; training does not need it
    if not values:
        for f in [f for f in files if is_tiff(f.image)][:16]:
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # NotGeoreferencedWarning for plain TIFFs
                    with rasterio.open(f.image) as ds:
                        size = ground_pixel_size(ds.crs, ds.transform, ds.width, ds.height) if ds.crs else None
            except rasterio.errors.RasterioError:
                size = None
            if size is not None:
                values.append(size)
    return round(float(np.median(values)), 4) if values else None


# ------------------------------------------------------------------------- checks, weights
def label_histogram(label: np.ndarray, num_classes: int, path: Path | str = "label") -> np.ndarray:
    """Pixels per class id ``(num_classes,)`` int64; DatasetError for ids outside the table."""
    check_label(label, Path(path), num_classes)
    return np.bincount(label.ravel(), minlength=num_classes).astype(np.int64)


def validate(files: Sequence[SampleFiles], num_classes: int) -> np.ndarray:
    """Check every sample before training (sizes, readable labels, ids < ``num_classes``).

    Returns the per-image class histograms ``(len(files), num_classes)``, from which
    :func:`weights_from_histograms` gives the median-frequency weights without a second pass.
    """
    hist = np.zeros((len(files), num_classes), dtype=np.int64)
    for i, f in enumerate(files):
        size = _check_sizes(f)
        label = read_label(f.label)
        if label.shape != size:
            raise DatasetError(f"{f.label}: decodes to {label.shape} but its header says {size}; re-encode it")
        hist[i] = label_histogram(label, num_classes, f.label)
    return hist


def weights_from_histograms(hist: np.ndarray, ignore_index: int | None) -> torch.Tensor:
    """SegNet's median-frequency class weights from per-image class histograms.

    ``freq(c)`` = pixels of class c / total pixels of the images where c is present;
    ``weight(c) = median(freq) / freq(c)``, the median taken over the classes present.
    Pixels of ``ignore_index`` count nowhere (they are not in the loss, so they are not in
    any total either) and that class gets weight 0; classes that never occur get weight 0
    too (they contribute no loss, and a finite number keeps the checkpoint readable).
    """
    hist = np.array(hist, dtype=np.float64, ndmin=2)
    if ignore_index is not None:
        hist[:, ignore_index] = 0
    totals = hist.sum(axis=1, keepdims=True)
    image_pixels = ((hist > 0) * totals).sum(axis=0)
    present = image_pixels > 0
    if not present.any():
        raise DatasetError("no labelled pixels to compute class weights from; check the labels or the splits")
    freq = np.zeros(hist.shape[1])
    freq[present] = hist.sum(axis=0)[present] / image_pixels[present]
    weights = np.zeros(hist.shape[1])
    weights[present] = np.median(freq[present]) / freq[present]
    return torch.tensor(weights, dtype=torch.float32)


def median_frequency_weights(labels: Iterable[np.ndarray], num_classes: int, ignore_index: int | None) -> torch.Tensor:
    """Median-frequency weights (:func:`weights_from_histograms`) of label images.

    >>> a, b = np.array([[1, 1], [1, 2]]), np.array([[2, 2], [0, 0]])
    >>> median_frequency_weights([a, b], 4, ignore_index=0).tolist()  # freq 3/4, 3/6 -> median 5/8
    [0.0, 0.8333333134651184, 1.25, 0.0]
    """
    hist = [label_histogram(np.asarray(lab), num_classes) for lab in labels]
    return weights_from_histograms(np.stack(hist) if hist else np.zeros((0, num_classes)), ignore_index)


# ----------------------------------------------------------------------------------- dataset
Box = tuple[int, int, int, int]  # top, left, height, width


class PatchDataset(Dataset[tuple[torch.Tensor, torch.Tensor]]):
    """Patches of labelled images: item ``i`` is one (image, patch box) pair.

    Returns ``(image, mask)``: image a float32 tensor ``(3, H, W)`` scaled to 0..1 and then
    normalised with ``mean``/``std``; mask an int64 tensor ``(H, W)`` of class ids.

    ``boxes_or_patch_size``: a patch size ``(H, W)`` (the grid of :func:`patch_boxes` of each
    image), a list of ``(top, left, H, W)`` boxes used in every image, or None for one item
    per whole image. ``augment``: False, True (:data:`~training.datasets.augment.OVERHEAD`) or an
    :class:`~training.datasets.augment.AugmentConfig`; the draws depend only on (``seed``, epoch,
    index), so call :meth:`set_epoch` before each epoch. ``num_classes``: when given, each
    label is checked (ids < num_classes) the first time it is decoded. ``label_lut``: a
    lookup array applied to label ids after that check (e.g. ``classes6.lookup_from_base()``
    to train AirSegNet6 on a 13-class dataset). ``ignore_index`` is the class left out of
    :meth:`class_weights`.
    """

    def __init__(self, files: Sequence[SampleFiles],
                 boxes_or_patch_size: tuple[int, int] | Sequence[Box] | None = PATCH_SIZE,
                 mean: Sequence[float] = IMAGENET_MEAN, std: Sequence[float] = IMAGENET_STD,
                 augment: bool | AugmentConfig = False, ignore_index: int | None = 0, seed: int = 0, *,
                 num_classes: int | None = None, label_lut: np.ndarray | None = None,
                 cache_images: int = 8) -> None:
        if seed < 0:
            raise DatasetError(f"seed must be >= 0, got {seed}")
        self.files = list(files)
        self.mean, self.std = [float(v) for v in mean], [float(v) for v in std]
        self.augment: AugmentConfig | None = OVERHEAD if augment is True else (augment or None)
        self.ignore_index, self.seed = ignore_index, int(seed)
        self.num_classes = num_classes
        self.label_lut = None if label_lut is None else np.asarray(label_lut)
        self.cache_images = cache_images
        self._cache: OrderedDict[int, tuple[np.ndarray, np.ndarray]] = OrderedDict()
        # Shared memory, so that DataLoader workers (persistent ones too) see set_epoch().
        self._epoch = torch.zeros(1, dtype=torch.int64).share_memory_()  # type: ignore[no-untyped-call]
        self.items: list[tuple[int, Box]] = []
        for fi, f in enumerate(self.files):
            height, width = _check_sizes(f)
            for box in self._boxes(boxes_or_patch_size, height, width, f):
                self.items.append((fi, box))

    @staticmethod
    def _boxes(spec: tuple[int, int] | Sequence[Box] | None, height: int, width: int, f: SampleFiles) -> list[Box]:
        if spec is None:
            return [(0, 0, height, width)]
        if len(spec) == 2 and all(isinstance(v, (int, np.integer)) for v in spec):
            ph, pw = int(spec[0]), int(spec[1])  # type: ignore[arg-type]
            try:
                return [(t, left, ph, pw) for t, left in patch_boxes(height, width, (ph, pw))]
            except DatasetError as exc:
                raise DatasetError(f"{f.image}: {exc}") from None
        boxes = [tuple(int(v) for v in b) for b in spec]  # type: ignore[union-attr]
        for t, left, bh, bw in boxes:
            if t < 0 or left < 0 or t + bh > height or left + bw > width:
                raise DatasetError(f"{f.image}: box {(t, left, bh, bw)} lies outside the {width}x{height} image")
        return boxes  # type: ignore[return-value]

    @property
    def epoch(self) -> int:
        return int(self._epoch[0])

    def set_epoch(self, epoch: int) -> None:
        """Use the augmentation draws of ``epoch`` from now on (in all workers)."""
        self._epoch[0] = int(epoch)

    def __len__(self) -> int:
        return len(self.items)

    def load(self, fi: int) -> tuple[np.ndarray, np.ndarray]:
        """Decoded (image, label) of file ``fi``, checked and mapped; cached (LRU, read-only)."""
        if fi in self._cache:
            self._cache.move_to_end(fi)
            return self._cache[fi]
        f = self.files[fi]
        image, label = read_rgb(f.image), read_label(f.label)
        if label.shape != image.shape[:2]:
            raise DatasetError(f"{f.label}: label is {label.shape[1]}x{label.shape[0]} but image {f.image.name} "
                               f"is {image.shape[1]}x{image.shape[0]}; labels must be on the image's pixel grid")
        if self.num_classes is not None:
            check_label(label, f.label, self.num_classes)
        if self.label_lut is not None:
            check_label(label, f.label, len(self.label_lut))
            label = self.label_lut[label]
        image.flags.writeable = False
        label.flags.writeable = False
        if self.cache_images > 0:
            self._cache[fi] = (image, label)
            while len(self._cache) > self.cache_images:
                self._cache.popitem(last=False)
        return image, label

    def __getitem__(self, index: int) -> tuple[torch.Tensor, torch.Tensor]:
        if not 0 <= index < len(self.items):
            raise IndexError(f"patch {index} out of range (0..{len(self.items) - 1})")
        fi, (top, left, height, width) = self.items[index]
        image, label = self.load(fi)
        d = None
        if self.augment is not None:
            d = draw(self.augment, item_rng(self.seed, self.epoch, index), square=image.shape[0] == image.shape[1])
            image, label = orient(image, d), orient(label, d)
        return self.tensors(image, label, (slice(top, top + height), slice(left, left + width)), d)

    def tensors(self, image: np.ndarray, label: np.ndarray, window: tuple[slice, slice],
                d: Draw | None) -> tuple[torch.Tensor, torch.Tensor]:
        """The training pair of ``window`` of an (oriented) image: jittered by ``d``, normalised."""
        x = torch.from_numpy(image[window].copy()).permute(2, 0, 1).to(torch.float32).div_(255.0)
        if d is not None:
            x = jitter(x, d)
        x = F.normalize(x, self.mean, self.std)
        y = torch.from_numpy(label[window].astype(np.int64))
        return x, y

    def class_weights(self, num_classes: int) -> torch.Tensor:
        """Median-frequency weights over the (unaugmented) patches, ``ignore_index`` left out."""
        def masks() -> Iterable[np.ndarray]:
            for fi, (top, left, height, width) in self.items:
                yield self.load(fi)[1][top:top + height, left:left + width]
        return median_frequency_weights(masks(), num_classes, self.ignore_index)


def dataset_fingerprint(root: Path) -> str | None:
    """sha256 of the dataset's manifest.json (recorded in checkpoints), None without one."""
    manifest = root / "manifest.json"
    return hashlib.sha256(manifest.read_bytes()).hexdigest() if manifest.is_file() else None
