"""Augmentation for overhead imagery, applied to an image and its mask together.

An aerial photo has no "up": a roof seen upside down or mirrored is still a roof. So the
geometric part draws one of the eight symmetries of the square (flips and quarter turns),
applied to the image *and* the mask; the photometric part (mild brightness, contrast and
saturation jitter, ~10 %) touches the image only. Random crops may also be *zoomed out*
(``scale``): a crop of ``crop * s`` pixels, ``s`` uniform in [1, scale], resized to ``crop``, so
the network sees the ground at up to ``scale`` times coarser pixels than the data's, as imagery
of another source often is (:func:`zoom_out`). Street-level data (CamVid) has an up and a
sky: use :data:`STREET` (horizontal flips and colour jitter only).

Quarter turns and non-square images
    The geometric transform is applied to the whole decoded image *before* the patch is cut
    (:func:`orient` returns a numpy view, so nothing is copied until the patch is). A square
    image (a 1280x1280 sample) keeps its shape under a quarter turn, so the fixed patch grid
    still fits, and all eight symmetries are used. A non-square image would change shape,
    so it only gets half and no quarter turns (odd draws become even: 0 or 180 degrees), which
    with the flips still gives four of the eight symmetries. Patches are never rotated on
    their own: a 360x480 patch turned by 90 degrees would be 480x360.

Reproducibility
    Every random choice for dataset item ``index`` in epoch ``epoch`` comes from
    :func:`item_rng` (``seed``, ``epoch``, ``index``): not from a global or per-worker
    generator. So the augmentations do not depend on the number of DataLoader workers, on
    which worker loads an item, or on whether training was interrupted and resumed.

>>> d = draw(OVERHEAD, item_rng(0, 0, 0), square=True)
>>> d == draw(OVERHEAD, item_rng(0, 0, 0), square=True), 0 <= d.k < 4
(True, True)
>>> a = np.arange(6).reshape(2, 3)
>>> orient(a, Draw(k=0, hflip=True, vflip=False)).tolist()
[[2, 1, 0], [5, 4, 3]]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torchvision.transforms.v2 import functional as F

from osmseg.errors import ConfigError


@dataclass(frozen=True)
class AugmentConfig:
    """Which augmentations to draw. Jitter amounts are the half-width of a factor range
    around 1 (``0.1``: factors uniform in [0.9, 1.1]); 0 turns that jitter off. ``scale``: the
    largest zoom-out of a random crop (1: none; only :class:`~training.datasets.sampling.RandomCrops`
    zooms, a fixed patch grid cannot)."""

    hflip: bool = True
    vflip: bool = True
    rot90: bool = True
    brightness: float = 0.1
    contrast: float = 0.1
    saturation: float = 0.1
    scale: float = 1.0

    def __post_init__(self) -> None:
        for name in ("brightness", "contrast", "saturation"):
            value = getattr(self, name)
            if not 0 <= value < 1:
                raise ConfigError(f"augmentation {name} must be in [0, 1), got {value}")
        if not 1 <= self.scale <= 4:
            raise ConfigError(f"augmentation scale must be in [1, 4], got {self.scale}")

    @classmethod
    def overhead(cls, jitter: float = 0.1, scale: float = 1.0) -> AugmentConfig:
        """Overhead imagery's augmentation with colour jitter ``jitter`` (brightness, contrast
        and saturation alike) and zoom-out up to ``scale``.

        >>> AugmentConfig.overhead() == OVERHEAD
        True
        """
        return cls(brightness=jitter, contrast=jitter, saturation=jitter, scale=scale)


#: Overhead imagery (the default): all eight square symmetries and mild colour jitter.
OVERHEAD = AugmentConfig()
#: Street-level imagery: left-right flips and colour jitter only (the sky stays up).
STREET = AugmentConfig(vflip=False, rot90=False)
#: Photometric-free: flips and quarter turns only (what the alignment tests use).
GEOMETRIC = AugmentConfig(brightness=0.0, contrast=0.0, saturation=0.0)


@dataclass(frozen=True)
class Draw:
    """The random choices for one item: geometry (image and mask) and colour (image only)."""

    k: int = 0  # quarter turns counter-clockwise (np.rot90), applied first
    hflip: bool = False  # then mirror left-right
    vflip: bool = False  # then mirror top-bottom
    brightness: float = 1.0
    contrast: float = 1.0
    saturation: float = 1.0


def item_rng(seed: int, epoch: int, index: int) -> np.random.Generator:
    """The generator for one item of one epoch: a pure function of (seed, epoch, index).

    >>> int(item_rng(1, 2, 3).integers(1 << 30)) == int(item_rng(1, 2, 3).integers(1 << 30))
    True
    """
    if seed < 0 or epoch < 0 or index < 0:
        raise ConfigError(f"seed, epoch and index must be >= 0, got {seed}, {epoch}, {index}")
    return np.random.default_rng([seed, epoch, index])


def draw(config: AugmentConfig, rng: np.random.Generator, square: bool) -> Draw:
    """Draw one item's augmentation. Always consumes the same numbers from ``rng`` whatever
    ``config`` says, so switching one augmentation off does not reshuffle the others."""
    k, h, v = int(rng.integers(4)), bool(rng.integers(2)), bool(rng.integers(2))
    b, c, s = rng.uniform(-1.0, 1.0, size=3)
    if not square:
        k &= 2  # 90 -> 0, 270 -> 180: a non-square image must keep its shape
    return Draw(
        k=k if config.rot90 else 0,
        hflip=h and config.hflip,
        vflip=v and config.vflip,
        brightness=1.0 + float(b) * config.brightness,
        contrast=1.0 + float(c) * config.contrast,
        saturation=1.0 + float(s) * config.saturation,
    )


def zoom_out(config: AugmentConfig, seed: int, epoch: int, index: int) -> float:
    """The zoom-out factor of crop ``index`` in ``epoch``: uniform in [1, ``config.scale``].
    Drawn from a stream of its own, so a run without zoom draws everything else as before.

    >>> zoom_out(OVERHEAD, 0, 0, 0)
    1.0
    >>> 1.0 <= zoom_out(AugmentConfig(scale=1.5), 0, 0, 0) <= 1.5
    True
    """
    if config.scale == 1.0:
        return 1.0
    return 1.0 + float(np.random.default_rng([seed, epoch, index, 4]).random()) * (config.scale - 1.0)


def orient(array: np.ndarray, d: Draw) -> np.ndarray:
    """``array`` (H, W) or (H, W, C) turned and mirrored as ``d`` says: a view, no copy."""
    if d.k:
        array = np.rot90(array, d.k, axes=(0, 1))
    if d.hflip:
        array = array[:, ::-1]
    if d.vflip:
        array = array[::-1]
    return array


def jitter(image: torch.Tensor, d: Draw) -> torch.Tensor:
    """Colour jitter of a float image (3, H, W) on the 0..1 scale, in a fixed order
    (brightness, contrast, saturation); results stay within 0..1."""
    if d.brightness != 1.0:
        image = F.adjust_brightness(image, d.brightness)
    if d.contrast != 1.0:
        image = F.adjust_contrast(image, d.contrast)
    if d.saturation != 1.0:
        image = F.adjust_saturation(image, d.saturation)
    return image
