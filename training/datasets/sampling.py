"""Random crops for training: a new view of the training images at every step.

The ``paper`` recipe cuts each sample into a fixed grid of patches (six 360x480 per 1280x1280
sample), so a run over 2 samples sees the same 12 views, augmented by flips and turns. The
``osmseg`` recipe draws crops anywhere instead (:class:`RandomCrops`), which on small data is
what makes more steps worth taking (``docs/training.md`` has the measurements).

Every draw of item ``index`` in epoch ``epoch`` comes from :func:`training.datasets.augment.item_rng`
(``seed``, ``epoch``, ``index``): which image (in proportion to its pixels), which of the
square's symmetries, where the crop lies. So a resumed run, any number of loader workers and
any order of loading give the same crops. Consecutive indices share an image
(:data:`CROPS_PER_IMAGE` crops of each), so a batch decodes a few images, not one per crop:
the loader takes items in order (:func:`crop_sampler`), and the randomness is in the draws.

With ``balance`` > 0 that share of the groups of crops is *class-balanced* (rare-class
sampling, as nnU-Net oversamples foreground and DAFormer rare classes): a class is drawn
uniformly from those the training labels hold, an image in proportion to its pixels of that
class, and each crop of the group is centred on one of them (the window kept inside the
image), then turned and mirrored. On the demo data construction is 0.15 % of the training
pixels: without it a crop holds some about once in 40 steps, and the network never learns it;
class weights would instead multiply its loss 20x (``docs/training.md`` compares both).

>>> crop_sampler(10, rank=1, world_size=2)
range(10, 20)
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from osmseg.errors import DatasetError
from training.datasets.augment import draw, item_rng, orient, zoom_out
from training.datasets.patches import PatchDataset, SampleFiles

#: crops drawn from one image before the next is chosen (a batch of 16 decodes 4 images)
CROPS_PER_IMAGE = 4


class RandomCrops(PatchDataset):
    """``length`` random ``crop`` x ``crop`` training pairs of ``files`` (see the module docstring).

    Keyword arguments are :class:`~training.datasets.patches.PatchDataset`'s (normalisation, augmentation,
    seed, label checks and mapping, decoded-image cache).
    """

    def __init__(self, files: Sequence[SampleFiles], crop: int, length: int, balance: float = 0.0,
                 class_pixels: np.ndarray | None = None, **kwargs: object) -> None:
        super().__init__(files, None, **kwargs)  # type: ignore[arg-type]
        self.crop, self.length = int(crop), int(length)
        small = [self.files[fi].image.name for fi, (_, _, h, w) in self.items if min(h, w) < self.crop]
        if small:
            raise DatasetError(f"{len(small)} training images (e.g. {small[0]}) are smaller than the {self.crop}-px "
                               "random crop; use a smaller --crop")
        pixels = np.array([h * w for _, (_, _, h, w) in self.items], dtype=np.float64)
        self.weights = pixels / pixels.sum()
        self.balance = float(balance)
        self.class_weights_by_file: dict[int, np.ndarray] = {}  # class id -> P(file | class)
        if self.balance > 0:
            if class_pixels is None or len(class_pixels) != len(self.files):
                raise ValueError("balanced crops need the training labels' pixels per class, one row per file")
            counts = np.asarray(class_pixels, dtype=np.float64).copy()
            if self.ignore_index is not None and self.ignore_index < counts.shape[1]:
                counts[:, self.ignore_index] = 0
            for c in np.flatnonzero(counts.sum(axis=0) > 0):
                self.class_weights_by_file[int(c)] = counts[:, c] / counts[:, c].sum()
        self.classes = sorted(self.class_weights_by_file)
        self._where: dict[tuple[int, int], np.ndarray] = {}  # (file, class) -> flat indices of a sample of its pixels

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, index: int) -> tuple[torch.Tensor, torch.Tensor]:
        if not 0 <= index < self.length:
            raise IndexError(f"crop {index} out of range (0..{self.length - 1})")
        if self.balance > 0 and self.classes:
            balanced = np.random.default_rng([self.seed, self.epoch, index // CROPS_PER_IMAGE, 2])
            if balanced.random() < self.balance:
                c = self.classes[int(balanced.integers(len(self.classes)))]
                return self.centred_on(int(balanced.choice(len(self.files), p=self.class_weights_by_file[c])), c, index)
        group = np.random.default_rng([self.seed, self.epoch, index // CROPS_PER_IMAGE, 1])  # not an item's stream
        fi = int(group.choice(len(self.files), p=self.weights))
        image, label = self.load(fi)
        rng = item_rng(self.seed, self.epoch, index)
        d = None
        if self.augment is not None:
            d = draw(self.augment, rng, square=image.shape[0] == image.shape[1])
            image, label = orient(image, d), orient(label, d)
        side = self.side(index, image.shape)
        top = int(rng.integers(0, image.shape[0] - side + 1))
        left = int(rng.integers(0, image.shape[1] - side + 1))
        return self.zoomed(*self.tensors(image, label, (slice(top, top + side), slice(left, left + side)), d))

    def side(self, index: int, shape: tuple[int, ...]) -> int:
        """Side in image pixels of crop ``index``: ``crop``, or zoomed out by the augmentation's
        ``scale`` (at most the image's shorter side)."""
        if self.augment is None or self.augment.scale == 1.0:
            return self.crop
        return min(round(self.crop * zoom_out(self.augment, self.seed, self.epoch, index)), shape[0], shape[1])

    def zoomed(self, x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A zoomed-out crop brought to ``crop`` pixels: the image by area-weighted bilinear
        resampling (antialiased, as coarser imagery looks), the labels by nearest neighbour."""
        side = x.shape[-1]
        if side == self.crop:
            return x, y
        x = torch.nn.functional.interpolate(x[None], size=(self.crop, self.crop), mode="bilinear",
                                            align_corners=False, antialias=True)[0]
        at = torch.from_numpy(((np.arange(self.crop) + 0.5) * side / self.crop).astype(np.int64))  # pixel centres
        return x, y[at][:, at]


    #: pixels of a class remembered per image to centre crops on (a seeded sample of them)
    WHERE_SAMPLE = 4096

    def where(self, fi: int, c: int) -> np.ndarray:
        """Flat indices of (a seeded sample of) the pixels of class ``c`` in image ``fi``."""
        key = (fi, c)
        if key not in self._where:
            found = np.flatnonzero(self.load(fi)[1] == c)
            if len(found) > self.WHERE_SAMPLE:
                found = np.sort(np.random.default_rng([self.seed, fi, c, 3]).choice(found, self.WHERE_SAMPLE,
                                                                                    replace=False))
            self._where[key] = found
        return self._where[key]

    def centred_on(self, fi: int, c: int, index: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Crop ``index``, centred on a pixel of class ``c`` of image ``fi`` (kept inside the
        image), then turned and mirrored by the item's draw."""
        image, label = self.load(fi)
        rng = item_rng(self.seed, self.epoch, index)
        d = draw(self.augment, rng, square=True) if self.augment is not None else None
        pixels = self.where(fi, c)
        if len(pixels) == 0:  # the histogram promised this class: labels changed under the run
            raise DatasetError(f"{self.files[fi].label}: holds no pixel of class {c} any more; was it rewritten?")
        y, x = divmod(int(pixels[int(rng.integers(len(pixels)))]), label.shape[1])
        side = self.side(index, label.shape)
        top = min(max(0, y - side // 2), label.shape[0] - side)
        left = min(max(0, x - side // 2), label.shape[1] - side)
        window = (slice(top, top + side), slice(left, left + side))
        image, label = image[window], label[window]
        if d is not None:
            image, label = orient(image, d), orient(label, d)
        return self.zoomed(*self.tensors(image, label, (slice(None), slice(None)), d))


def crop_sampler(per_process: int, rank: int, world_size: int) -> range:
    """The items process ``rank`` trains on in an epoch: its own contiguous block, in order."""
    del world_size  # each process's block has the same length
    return range(rank * per_process, (rank + 1) * per_process)
