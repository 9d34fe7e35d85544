"""What a model is (:class:`ModelSpec`): enough to rebuild it and to feed it and read its output.

Its own module so that :mod:`training.models.networks` (which builds a network from a spec) and
:mod:`training.models.checkpoint` (which stores the spec beside the weights and rebuilds the model)
depend on it, and not on each other. Imports: osmseg core only.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from osmseg.classes import ClassTable
from osmseg.errors import ConfigError

#: the dissertation's networks by name: 6 and 13 classes (``--model``)
PRESET_NAMES = ("airsegnet6", "airsegnet13")

#: ImageNet statistics (0..1 scale), the default input normalisation.
IMAGENET_MEAN: tuple[float, float, float] = (0.485, 0.456, 0.406)
IMAGENET_STD: tuple[float, float, float] = (0.229, 0.224, 0.225)


#: the networks osmseg builds: SegNet as published (``segnet``: the decoder gets the encoder's
#: pooling indices only), SegNet with additive skips (``segnet-skip``: each unpooled decoder
#: input plus the encoder features of that stage, as LinkNet adds them; the same weights), and a
#: U-Net decoder on EfficientNet-Lite0 (``unet-lite0``: ImageNet-pretrained weights that install
#: with osmseg; :mod:`training.models.lite0`)
ARCHS = ("segnet-skip", "segnet", "unet-lite0")


@dataclass(frozen=True)
class ModelSpec:
    """What a model is: enough to rebuild it and to feed it and read its output.

    ``class_table`` is :meth:`osmseg.classes.ClassTable.to_dict` (``{"name", "classes":
    [{"id", "name", "color"}]}``); output channel ``i`` is the class with id ``i``.
    ``ignore_index`` is 0 when unlabeled pixels are ignored in loss and metrics, None when
    unlabeled is a class of its own.  ``mean``/``std`` normalise RGB scaled to 0..1.
    ``resolution_m`` is the ground pixel size of the training images (metres, the median over
    the dataset; None when the training data did not say): ``predict``/``eval`` compare inputs
    with it, and ``--resolution model`` resamples inputs to it.

    >>> spec = ModelSpec("segnet", "demo", 3, 0.0625,
    ...                  {"name": "t", "classes": [{"id": 0, "name": "unlabeled", "color": [0, 0, 0]},
    ...                                            {"id": 2, "name": "water", "color": [0, 0, 255]}]}, 0)
    >>> ModelSpec.from_dict(dataclasses.asdict(spec)) == spec, spec.class_names
    (True, ['unlabeled', 'class1', 'water'])
    """

    arch: str
    name: str
    num_classes: int
    width: float
    class_table: dict[str, Any]
    ignore_index: int | None
    input_size: tuple[int, int] = (360, 480)
    mean: tuple[float, float, float] = IMAGENET_MEAN
    std: tuple[float, float, float] = IMAGENET_STD
    resolution_m: float | None = None

    def __post_init__(self) -> None:
        ids = [c.get("id") for c in self.class_table.get("classes", ())] if isinstance(self.class_table, Mapping) else None
        checks = [
            (self.arch in ARCHS, f"arch must be one of {', '.join(ARCHS)}, got {self.arch!r}"),
            (isinstance(self.num_classes, int) and self.num_classes >= 1, f"num_classes must be >= 1, got {self.num_classes!r}"),
            (isinstance(self.width, (int, float)) and self.width > 0, f"width must be > 0, got {self.width!r}"),
            (ids is not None and all(isinstance(i, int) and 0 <= i < self.num_classes for i in ids),
             f"class_table ids must be integers in 0..{self.num_classes - 1}"),
            (self.ignore_index is None or 0 <= self.ignore_index < self.num_classes,
             f"ignore_index must be None or a class id, got {self.ignore_index!r}"),
            (len(self.input_size) == 2 and all(int(s) >= 32 for s in self.input_size),
             f"input_size must be (height, width) >= 32, got {self.input_size!r}"),
            (len(self.mean) == 3 and len(self.std) == 3 and all(s > 0 for s in self.std),
             "mean and std must be three numbers each (std > 0)"),
            (self.resolution_m is None or (isinstance(self.resolution_m, (int, float)) and self.resolution_m > 0),
             f"resolution_m must be None or > 0 metres, got {self.resolution_m!r}"),
        ]
        for ok, message in checks:
            if not ok:
                raise ConfigError(f"model spec: {message}")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ModelSpec:
        """Inverse of ``dataclasses.asdict``; ConfigError if a field is missing or unknown."""
        names = {f.name for f in dataclasses.fields(cls)}
        required = {f.name for f in dataclasses.fields(cls) if f.default is dataclasses.MISSING}
        if not isinstance(data, Mapping) or not required <= set(data) or not set(data) <= names:
            keys = sorted(data) if isinstance(data, Mapping) else type(data).__name__
            raise ConfigError(f"model spec must have the keys {sorted(names)}, got {keys}")
        values = dict(data)
        for key in ("input_size", "mean", "std"):
            if key in values:
                values[key] = tuple(values[key])
        return cls(**values)

    @property
    def table(self) -> ClassTable:
        """The class table the outputs are ids of (``class_table`` read by ``ClassTable.from_dict``)."""
        return ClassTable.from_dict(self.class_table, f"model spec {self.name!r}")

    @property
    def class_names(self) -> list[str]:
        """Class name per output channel, indexed by class id (``"classN"`` for ids the table does not name)."""
        return self.table.names_by_id(self.num_classes)

    def palette(self) -> np.ndarray:
        """``(256, 3)`` uint8 colour lookup table indexed by class id (unnamed ids black)."""
        return self.table.palette()
