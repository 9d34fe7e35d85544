"""Random crops for training: a new view of the training images at every step.

The ``paper`` recipe cuts each sample into a fixed grid of patches (six 360x480 per 1280x1280
sample), so a run over 2 samples sees the same 12 views, augmented by flips and turns. The
``osmseg`` recipe draws crops anywhere instead (:class:`RandomCrops`), which on small data is
what makes more steps worth taking (``docs/training.md`` has the measurements).

Every draw of item ``index`` in epoch ``epoch`` comes from :func:`training.augment.item_rng`
(``seed``, ``epoch``, ``index``): which image (in proportion to its pixels), which of the
square's symmetries, where the crop lies. So a resumed run, any number of loader workers and
any order of loading give the same crops. Consecutive indices share an image
(:data:`CROPS_PER_IMAGE` crops of each), so a batch decodes a few images, not one per crop:
the loader takes items in order (:func:`crop_sampler`), and the randomness is in the draws.

>>> crop_sampler(10, rank=1, world_size=2)
range(10, 20)
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from osmseg.errors import DatasetError
from training.augment import draw, item_rng, orient
from training.data import PatchDataset, SampleFiles

#: crops drawn from one image before the next is chosen (a batch of 16 decodes 4 images)
CROPS_PER_IMAGE = 4


class RandomCrops(PatchDataset):
    """``length`` random ``crop`` x ``crop`` training pairs of ``files`` (see the module docstring).

    Keyword arguments are :class:`~training.data.PatchDataset`'s (normalisation, augmentation,
    seed, label checks and mapping, decoded-image cache).
    """

    def __init__(self, files: Sequence[SampleFiles], crop: int, length: int, **kwargs: object) -> None:
        super().__init__(files, None, **kwargs)  # type: ignore[arg-type]
        self.crop, self.length = int(crop), int(length)
        small = [self.files[fi].image.name for fi, (_, _, h, w) in self.items if min(h, w) < self.crop]
        if small:
            raise DatasetError(f"{len(small)} training images (e.g. {small[0]}) are smaller than the {self.crop}-px "
                               "random crop; use a smaller --crop")
        pixels = np.array([h * w for _, (_, _, h, w) in self.items], dtype=np.float64)
        self.weights = pixels / pixels.sum()

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, index: int) -> tuple[torch.Tensor, torch.Tensor]:
        if not 0 <= index < self.length:
            raise IndexError(f"crop {index} out of range (0..{self.length - 1})")
        group = np.random.default_rng([self.seed, self.epoch, index // CROPS_PER_IMAGE, 1])  # not an item's stream
        fi = int(group.choice(len(self.files), p=self.weights))
        image, label = self.load(fi)
        rng = item_rng(self.seed, self.epoch, index)
        d = None
        if self.augment is not None:
            d = draw(self.augment, rng, square=image.shape[0] == image.shape[1])
            image, label = orient(image, d), orient(label, d)
        top = int(rng.integers(0, image.shape[0] - self.crop + 1))
        left = int(rng.integers(0, image.shape[1] - self.crop + 1))
        return self.tensors(image, label, (slice(top, top + self.crop), slice(left, left + self.crop)), d)


def crop_sampler(per_process: int, rank: int, world_size: int) -> range:
    """The items process ``rank`` trains on in an epoch: its own contiguous block, in order."""
    del world_size  # each process's block has the same length
    return range(rank * per_process, (rank + 1) * per_process)
