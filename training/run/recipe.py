"""Training recipes: how the network is optimised, as one named, recorded value.

A :class:`Recipe` is everything about *how* a run learns (optimiser, learning rate and its
schedule, class weights, how patches are drawn, batch size); :class:`~training.run.config.TrainConfig`
names one (``--recipe``) and may override any of its settings. Two are shipped:

``osmseg`` (the default)
    AdamW (lr 0.01, weight decay 1e-4), no warm-up (one is available: ``warmup``), a cosine
    decay to zero; no class weights; random 128x128 crops (drawn anywhere in the
    training images, after one of the square's eight symmetries), 16 per batch, at least 50
    steps per epoch. It is built for what most users have: a few hundred samples or fewer,
    often a CPU. Each choice is measured against the alternatives in ``docs/training.md``
    (``benchmarks/bench_recipe.py`` regenerates the tables).

``paper``
    The dissertation's, which is SegNet's (Badrinarayanan et al. 2017): SGD, momentum 0.9,
    weight decay 5e-4, median-frequency class weights, lr 0.1 with a polynomial decay (power
    0.9), the fixed grid of 360x480 patches of each sample, 4 per batch. Runs made before
    osmseg 0.5 used it (they resume with ``--recipe paper``).

Why the default is not the paper's, in short (the figures are in ``docs/training.md``): on
small data the median-frequency weights reach 100-200x for classes that barely occur, so the
gradient is dominated by a handful of pixels; SGD at lr 0.1 without warm-up and only a few
steps per epoch leaves the network a near-constant predictor for most of a short run; and a
grid of 6 fixed patches per sample shows the network the same 6 views of each image, where
random crops show a new one at every step.

>>> r = recipe_named("paper")
>>> r.optimizer, r.lr, r.class_weights, r.sampling
('sgd', 0.1, 'median-frequency', 'grid')
>>> lr_factor(0, total=100, warmup=10, schedule="cosine"), lr_factor(10, total=100, warmup=10, schedule="cosine")
(0.1, 1.0)
>>> round(lr_factor(55, total=100, warmup=10, schedule="cosine"), 3), lr_factor(100, total=100, warmup=10, schedule="cosine")
(0.5, 0.0)
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from osmseg.errors import ConfigError

OPTIMIZERS = ("adamw", "sgd")
SCHEDULES = ("cosine", "poly", "constant")
CLASS_WEIGHTS = ("none", "median-frequency", "sqrt-median-frequency")
SAMPLINGS = ("random", "grid")


@dataclass(frozen=True)
class Recipe:
    """How a run learns. ``warmup``: fraction of all steps with a linear warm-up of the rate.
    ``crop`` and ``steps_per_epoch`` apply to ``sampling="random"`` (``steps_per_epoch`` None:
    enough batches to cover the training pixels once, and at least :data:`MIN_STEPS_PER_EPOCH`);
    ``sampling="grid"`` cuts each image into the run's fixed patches (``--patch-*``).
    ``balanced_crops``: the share of random crops centred on a pixel of one class, the class
    drawn uniformly from those the training labels hold (rare-class sampling), so a class of a
    few thousand pixels is seen as often as the rest without weighting its loss.
    ``encoder_lr``: the encoder's learning rate as a multiple of ``lr`` (below 1 keeps pretrained
    features closer to where they started). ``freeze_bn``: the encoder's BatchNorm layers keep
    their statistics (running mean and variance; their scale and shift still learn), as
    fine-tuning on small batches often does. ``ema``: the decay per step of an exponential
    moving average of the weights (0: none), the weights ``model.pt`` holds. ``dice``: the
    weight of a soft Dice loss added to the cross-entropy (0: cross-entropy alone).
    ``crop_scale``: random crops are zoomed out by a factor uniform in [1, crop_scale] (a crop
    of ``crop * s`` pixels resized to ``crop``; 1: none). ``jitter``: the colour jitter
    (brightness, contrast, saturation factors uniform in [1 - jitter, 1 + jitter])."""

    name: str
    optimizer: str
    lr: float
    weight_decay: float
    momentum: float  # SGD only
    schedule: str
    warmup: float
    poly_power: float
    class_weights: str
    sampling: str
    crop: int
    steps_per_epoch: int | None
    batch_size: int
    balanced_crops: float = 0.0
    encoder_lr: float = 1.0
    freeze_bn: bool = False
    ema: float = 0.0
    dice: float = 0.0
    crop_scale: float = 1.0
    jitter: float = 0.1

    def __post_init__(self) -> None:
        checks = [
            (self.optimizer in OPTIMIZERS, f"optimizer must be one of {', '.join(OPTIMIZERS)}"),
            (self.lr > 0, "lr must be > 0"),
            (self.weight_decay >= 0, "weight_decay must be >= 0"),
            (self.schedule in SCHEDULES, f"schedule must be one of {', '.join(SCHEDULES)}"),
            (0 <= self.warmup < 1, "warmup must be a fraction of the steps in [0, 1)"),
            (self.class_weights in CLASS_WEIGHTS, f"class_weights must be one of {', '.join(CLASS_WEIGHTS)}"),
            (self.sampling in SAMPLINGS, f"sampling must be one of {', '.join(SAMPLINGS)}"),
            (self.crop >= 32, "crop must be at least 32 pixels"),
            (self.steps_per_epoch is None or self.steps_per_epoch >= 1, "steps_per_epoch must be >= 1"),
            (self.batch_size >= 1, "batch_size must be >= 1"),
            (0 <= self.balanced_crops <= 1, "balanced_crops must be a share of the crops in [0, 1]"),
            (self.balanced_crops == 0 or self.sampling == "random", "balanced_crops needs sampling random"),
            (0 <= self.encoder_lr <= 10, "encoder_lr must be a multiple of lr in [0, 10]"),
            (0 <= self.ema < 1, "ema must be a decay per step in [0, 1)"),
            (self.dice >= 0, "dice must be a loss weight >= 0"),
            (1 <= self.crop_scale <= 4, "crop_scale must be a zoom-out factor in [1, 4]"),
            (self.crop_scale == 1 or self.sampling == "random", "crop_scale needs sampling random"),
            (0 <= self.jitter < 1, "jitter must be in [0, 1)"),
        ]
        for ok, message in checks:
            if not ok:
                raise ConfigError(f"training recipe {self.name}: {message}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


#: an epoch of random crops has at least this many steps, so a tiny dataset is not validated
#: (and checkpointed) after every few steps
MIN_STEPS_PER_EPOCH = 50

RECIPES: dict[str, Recipe] = {
    "osmseg": Recipe(name="osmseg", optimizer="adamw", lr=0.01, weight_decay=1e-4, momentum=0.9, schedule="cosine",
                     warmup=0.0, poly_power=0.9, class_weights="none", sampling="random", crop=128,
                     steps_per_epoch=None, batch_size=16),
    "paper": Recipe(name="paper", optimizer="sgd", lr=0.1, weight_decay=5e-4, momentum=0.9, schedule="poly",
                    warmup=0.0, poly_power=0.9, class_weights="median-frequency", sampling="grid", crop=128,
                    steps_per_epoch=None, batch_size=4),
    "lite0": Recipe(name="lite0", optimizer="adamw", lr=1e-3, weight_decay=1e-4, momentum=0.9, schedule="cosine",
                    warmup=0.05, poly_power=0.9, class_weights="none", sampling="random", crop=256,
                    steps_per_epoch=None, batch_size=4),
}

#: the recipe a network learns by when the run names none
ARCH_RECIPES = {"segnet-skip": "osmseg", "segnet": "osmseg", "unet-lite0": "lite0"}

#: the settings a recipe decides (a run's config may override each)
RECIPE_FIELDS = tuple(f.name for f in fields(Recipe) if f.name != "name")


def recipe_named(name: str, **overrides: Any) -> Recipe:
    """The shipped recipe ``name`` with ``overrides`` (None values are left to the recipe)."""
    if name not in RECIPES:
        raise ConfigError(f"--recipe {name}: not a recipe; use {' or '.join(RECIPES)}")
    given = {k: v for k, v in overrides.items() if v is not None}
    unknown = sorted(set(given) - set(RECIPE_FIELDS))
    if unknown:
        raise ConfigError(f"unknown recipe settings {unknown}; known: {', '.join(RECIPE_FIELDS)}")
    return replace(RECIPES[name], **given)


def lr_factor(step: int, total: int, warmup: int, schedule: str, power: float = 0.9) -> float:
    """Learning-rate multiplier at optimiser step ``step`` of ``total``: a linear warm-up over
    the first ``warmup`` steps (from 1/warmup to 1), then ``schedule`` over the rest: cosine
    to 0, poly ``(1 - t) ** power``, or constant."""
    if step < warmup:
        return (step + 1) / warmup
    if schedule == "constant":
        return 1.0
    t = min(1.0, (step - warmup) / max(1, total - warmup))
    if schedule == "cosine":
        return 0.5 * (1.0 + math.cos(math.pi * t))
    return float(max(0.0, 1.0 - t) ** power)


def steps_per_epoch(recipe: Recipe, training_pixels: int, world_size: int = 1) -> int:
    """Batches per process per epoch of random crops: ``recipe.steps_per_epoch``, else enough
    crops to cover ``training_pixels`` once, at least :data:`MIN_STEPS_PER_EPOCH`.

    >>> steps_per_epoch(recipe_named("osmseg"), 2 * 1280 * 1280)
    50
    >>> steps_per_epoch(recipe_named("osmseg"), 400 * 1280 * 1280), steps_per_epoch(recipe_named("osmseg", steps_per_epoch=7), 1)
    (2500, 7)
    """
    if recipe.steps_per_epoch is not None:
        return recipe.steps_per_epoch
    crops = math.ceil(training_pixels / (recipe.crop * recipe.crop))
    return max(MIN_STEPS_PER_EPOCH, math.ceil(crops / (recipe.batch_size * world_size)))
