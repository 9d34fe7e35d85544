"""Training configuration: one dataclass, read from YAML/TOML, overridden from the command line.

*How* the network learns is a named :class:`~training.run.recipe.Recipe` (``recipe``: by default
the network's own, ``osmseg`` for SegNet and ``lite0`` for unet-lite0, or ``paper``, the
dissertation's SegNet recipe); every setting of it (``lr``,
``batch_size``, ``class_weights`` ...) may be overridden one by one, and a setting left at None
is the recipe's. The rest (data, model, width, epochs, device) is the run's own.
:attr:`TrainConfig.settings` is the resolved recipe, which the trainer uses and every
checkpoint records.

The ``paper`` recipe's learning rate, measured before osmseg 0.5 (real Kampala dataset, 16
samples, width 0.125, CPU, ``--keep-unlabeled``): at 0.01 SGD sat at ln 2 (a constant
predictor) for 19 epochs, at 0.1 it started learning by epoch 7; the ``osmseg`` recipe's
choices are measured in ``docs/training.md``.

>>> c = TrainConfig(dataset=Path("d"), out_dir=Path("o"))
>>> c.recipe_name, c.settings.optimizer, c.settings.lr, c.settings.schedule
('osmseg', 'adamw', 0.01, 'cosine')
>>> TrainConfig(dataset=Path("d"), out_dir=Path("o"), arch="unet-lite0").to_dict()["recipe"]
'lite0'
>>> p = TrainConfig(dataset=Path("d"), out_dir=Path("o"), recipe="paper", lr=0.05)
>>> p.settings.optimizer, p.settings.lr, p.settings.batch_size, p.to_dict()["lr"]
('sgd', 0.05, 4, 0.05)
>>> merged = with_overrides(c, {"epochs": 3, "width": None})
>>> merged.epochs, merged.width
(3, 1.0)
"""

from __future__ import annotations

import json
import logging
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import tomllib

from osmseg.errors import ConfigError
from training.models.spec import ARCHS, PRESET_NAMES
from training.run.recipe import ARCH_RECIPES, RECIPE_FIELDS, RECIPES, Recipe, recipe_named

logger = logging.getLogger(__name__)

#: where a network's first weights come from when the run names none: SegNet from random weights, as the
#: dissertation trained it (torchvision's ImageNet VGG16-BN is a download); unet-lite0 from the ImageNet
#: weights installed with osmseg
ARCH_INITS = {"segnet-skip": "random", "segnet": "random", "unet-lite0": "imagenet"}

#: the AirSegNet presets (training.models.networks.PRESETS gives their class tables)


@dataclass(frozen=True)
class TrainConfig:
    """Everything that decides a training run (recorded in every checkpoint)."""

    dataset: Path
    out_dir: Path
    model: str = "airsegnet13"  # airsegnet6 | airsegnet13 | any name with --classes
    classes: str | None = None  # class table TOML; default: the dataset's manifest, else the model's
    width: float = 1.0  # channel multiplier; 1.0 is the paper's network
    arch: str = "segnet-skip"  # segnet-skip | segnet (the paper's: no skips); training.models.spec.ARCHS
    init: str = "auto"  # auto (the arch's: ARCH_INITS) | random | imagenet | PATH to a vgg16_bn .pth | an osmseg checkpoint
    ignore_unlabeled: bool = True  # unlabeled (0) ignored in loss and metrics
    patch_height: int = 360  # the grid patches of sampling "grid", and the window predict and eval use
    patch_width: int = 480
    epochs: int = 100
    recipe: str = "auto"  # auto (the arch's) | osmseg | paper | lite0: training/run/recipe.py; the settings below override it
    optimizer: str | None = None  # adamw | sgd
    batch_size: int | None = None
    lr: float | None = None
    momentum: float | None = None  # SGD only
    weight_decay: float | None = None
    schedule: str | None = None  # cosine | poly | constant
    warmup: float | None = None  # fraction of the steps with a linear warm-up
    poly_power: float | None = None
    class_weights: str | None = None  # none | median-frequency | sqrt-median-frequency
    sampling: str | None = None  # random (crops anywhere) | grid (the fixed patches)
    crop: int | None = None  # side of a random crop
    steps_per_epoch: int | None = None  # random sampling: batches per epoch (None: cover the pixels once, >= 50)
    balanced_crops: float | None = None  # random sampling: share of crops centred on a uniformly drawn class
    encoder_lr: float | None = None  # the encoder's learning rate as a multiple of lr
    freeze_bn: bool | None = None  # the encoder's BatchNorm statistics stay as initialised
    ema: float | None = None  # decay per step of the weights' moving average (0: none)
    dice: float | None = None  # weight of a soft Dice loss beside the cross-entropy
    crop_scale: float | None = None  # random crops zoomed out by up to this factor (1: none)
    jitter: float | None = None  # colour jitter: brightness/contrast/saturation factors in 1 +- jitter
    augment: bool = True
    test_fraction: float = 1 / 3
    val_fraction: float = 0.15
    split_by: str = "groups"  # groups: overlapping samples share a split | image: each image alone
    seed: int = 0
    loader_workers: int = 2  # DataLoader worker processes (``osmseg build --workers`` counts build processes)
    device: str = "auto"  # auto | cpu | cuda | cuda:N
    amp: bool = True  # mixed precision; used only on CUDA
    channels_last: bool = True  # memory format; used only on CUDA
    max_steps_per_epoch: int | None = None  # cap for smoke tests and benchmarks
    tensorboard: bool = True  # write TensorBoard events when the package is installed

    def __post_init__(self) -> None:
        preset = self.model.strip().lower().replace("-", "").replace("_", "")
        if preset in PRESET_NAMES:
            object.__setattr__(self, "model", preset)  # AirSegNet6, airsegnet-6: the preset
        elif preset.startswith("airsegnet"):
            raise ConfigError(f"--model {self.model}: not a preset; use {' or '.join(PRESET_NAMES)} (or a name of "
                              "your own, not starting with airsegnet, to train on the dataset's class table)")
        object.__setattr__(self, "recipe", self.recipe.strip().lower())
        self.settings  # noqa: B018 - the recipe and its overrides are checked here, not at the first step
        checks = [
            (self.epochs >= 1, "epochs must be >= 1"),
            (0 < self.width <= 4, "width must be in (0, 4]"),
            (0 < self.test_fraction < 1 and 0 <= self.val_fraction < 1, "test/val fractions must be in (0, 1)"),
            (self.patch_height >= 32 and self.patch_width >= 32, "patches must be at least 32x32"),
            (self.split_by in ("groups", "image"), "split_by must be groups or image"),
            (self.arch in ARCHS, f"arch must be one of {', '.join(ARCHS)}"),
            (self.recipe == "auto" or self.recipe in RECIPES, f"recipe must be auto or one of {', '.join(RECIPES)}"),
        ]
        for ok, message in checks:
            if not ok:
                raise ConfigError(f"training config: {message}")

    @property
    def patch_size(self) -> tuple[int, int]:
        return (self.patch_height, self.patch_width)

    @property
    def init_source(self) -> str:
        """Where the first weights come from: ``init``, or for ``auto`` the network's own (:data:`ARCH_INITS`)."""
        return ARCH_INITS[self.arch] if self.init == "auto" else self.init

    @property
    def recipe_name(self) -> str:
        """The recipe's name: ``recipe``, or for ``auto`` the network's own (``training.run.recipe.ARCH_RECIPES``)."""
        return ARCH_RECIPES[self.arch] if self.recipe == "auto" else self.recipe

    @property
    def settings(self) -> Recipe:
        """The recipe this run learns by: ``recipe`` with the settings given here."""
        return recipe_named(self.recipe_name, **{k: getattr(self, k) for k in RECIPE_FIELDS})

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (paths as strings) for checkpoints and logs; the recipe's settings resolved."""
        resolved = dict(self.settings.to_dict(), recipe=self.recipe_name, init=self.init_source)
        return {k: (str(v) if isinstance(v, Path) else resolved[k] if k in (*RECIPE_FIELDS, "recipe", "init") else v)
                for k, v in asdict(self).items()}


FIELDS = {f.name: f for f in fields(TrainConfig)}

#: settings renamed since 0.3.0 (old name -> new): still read from config files, with a warning
RENAMED = {"workers": "loader_workers"}


#: the settings files shipped with osmseg (``--config cpu.yaml`` finds them from any folder)
CONFIGS_DIR = Path(__file__).resolve().parent.parent / "configs"


def find_config_file(value: str | Path) -> Path:
    """``--config``'s file: a path, or the name of a shipped one (``cpu``, ``cpu.yaml``, ``gpu.yaml``).

    >>> find_config_file("cpu").name
    'cpu.yaml'
    """
    path = Path(value).expanduser()
    if path.is_file():
        return path
    for candidate in (CONFIGS_DIR / path.name, CONFIGS_DIR / f"{path.name}.yaml"):
        if not path.parent.parts and candidate.is_file():
            return candidate
    shipped = ", ".join(sorted(p.name for p in CONFIGS_DIR.glob("*.yaml")))
    raise ConfigError(f"--config {value}: no such file; give a .yaml/.toml path, or one of osmseg's: {shipped}")


def read_config_file(path: Path) -> dict[str, Any]:
    """Settings from a YAML (``.yaml``/``.yml``) or TOML (``.toml``) file; unknown keys are errors."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"--config {path}: cannot read it ({exc.strerror}); give an existing .yaml or .toml") from None
    try:
        if path.suffix in (".yaml", ".yml"):
            import yaml

            data = yaml.safe_load(text) or {}
        elif path.suffix == ".toml":
            data = tomllib.loads(text)
        elif path.suffix == ".json":
            data = json.loads(text)
        else:
            raise ConfigError(f"--config {path}: use a .yaml, .toml or .json file")
    except (ValueError, ImportError) as exc:  # yaml.YAMLError and TOMLDecodeError are ValueErrors
        raise ConfigError(f"--config {path}: not valid ({type(exc).__name__}: {str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"--config {path}: expected a mapping of settings")
    for old, new in RENAMED.items():
        if old in data:
            if new in data:
                raise ConfigError(f"--config {path}: {old} is the old name of {new}: keep {new} only")
            logger.warning("--config %s: '%s' is now '%s' (DataLoader processes); rename it, the old name will "
                           "stop working in a later version", path, old, new)
            data[new] = data.pop(old)
    unknown = sorted(set(data) - set(FIELDS))
    if unknown:
        raise ConfigError(f"--config {path}: unknown settings {unknown}; known: {', '.join(sorted(FIELDS))}")
    return data


def with_overrides(config: TrainConfig, overrides: dict[str, Any]) -> TrainConfig:
    """``config`` with every override that is not None applied (CLI options win over the file)."""
    given = {k: v for k, v in overrides.items() if v is not None}
    unknown = sorted(set(given) - set(FIELDS))
    if unknown:
        raise ConfigError(f"unknown training settings {unknown}")
    for key in ("dataset", "out_dir"):
        if key in given:
            given[key] = Path(given[key])
    try:
        return replace(config, **given)
    except TypeError as exc:
        raise ConfigError(f"training config: {exc}") from None


def make_config(dataset: Path, out_dir: Path, file: Path | None, overrides: dict[str, Any]) -> TrainConfig:
    """Defaults < config file < command-line options."""
    settings: dict[str, Any] = {}
    if file is not None:
        settings.update(read_config_file(file))
    settings.update({k: v for k, v in overrides.items() if v is not None})
    settings.update(dataset=Path(dataset), out_dir=Path(out_dir))
    base = TrainConfig(dataset=Path(dataset), out_dir=Path(out_dir))
    return with_overrides(base, settings)
