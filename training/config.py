"""Training configuration: one dataclass, read from YAML/TOML, overridden from the command line.

Defaults follow the SegNet recipe (Badrinarayanan et al. 2017): SGD with momentum 0.9,
weight decay 5e-4 and median-frequency class weights. Learning rate and schedule are ours:

* ``lr = 0.1`` — SegNet's own rate — with a polynomial ("poly", power 0.9) decay to zero over
  the run, as torchvision's segmentation references use. Measured on the real Kampala dataset
  (16 samples, width 0.125, CPU, ``--keep-unlabeled``): at 0.01 the loss sat at ln 2 (a constant
  predictor) for 19 epochs and at 0.05 for the first epochs, while 0.1 started learning by epoch
  7 (val mIoU 0.27 -> 0.52 by epoch 9); on tests/data/tinyseg 0.01 leaves the loss at ~1.5 after
  6 epochs. From random initialisation (the dissertation trains "a completely new network") the
  large early steps are what get the network out of the constant solution; the poly tail then
  gives the small steps that sharpen boundaries.
* ``batch_size = 4`` patches of 360x480 (SegNet trained CamVid at batch 12 on a 12 GB GPU; 4
  fits a common 8 GB card at width 1.0 with AMP).

>>> c = TrainConfig(dataset=Path("d"), out_dir=Path("o"))
>>> c.lr, c.momentum, c.weight_decay, c.schedule
(0.1, 0.9, 0.0005, 'poly')
>>> merged = with_overrides(c, {"epochs": 3, "width": None})
>>> merged.epochs, merged.width
(3, 1.0)
"""

from __future__ import annotations

import json
import logging
import tomllib
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

from osmseg.errors import ConfigError

logger = logging.getLogger(__name__)

#: the AirSegNet presets (training.model.PRESETS gives their class tables)
PRESET_NAMES = ("airsegnet6", "airsegnet13")


@dataclass(frozen=True)
class TrainConfig:
    """Everything that decides a training run (recorded in every checkpoint)."""

    dataset: Path
    out_dir: Path
    model: str = "airsegnet13"  # airsegnet6 | airsegnet13 | any name with --classes
    classes: str | None = None  # class table TOML; default: the dataset's manifest, else the model's
    width: float = 1.0  # channel multiplier; 1.0 is the paper's network
    init: str = "random"  # random | imagenet | PATH to a vgg16_bn .pth | an osmseg checkpoint (fine-tuning)
    ignore_unlabeled: bool = True  # unlabeled (0) ignored in loss and metrics
    patch_height: int = 360
    patch_width: int = 480
    epochs: int = 100
    batch_size: int = 4
    lr: float = 0.1
    momentum: float = 0.9
    weight_decay: float = 5e-4
    schedule: str = "poly"  # poly | constant
    poly_power: float = 0.9
    class_weights: str = "median-frequency"  # median-frequency | none
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
        checks = [
            (self.epochs >= 1, "epochs must be >= 1"),
            (self.batch_size >= 1, "batch_size must be >= 1"),
            (self.lr > 0, "lr must be > 0"),
            (0 < self.width <= 4, "width must be in (0, 4]"),
            (self.schedule in ("poly", "constant"), "schedule must be poly or constant"),
            (self.class_weights in ("median-frequency", "none"), "class_weights must be median-frequency or none"),
            (0 < self.test_fraction < 1 and 0 <= self.val_fraction < 1, "test/val fractions must be in (0, 1)"),
            (self.patch_height >= 32 and self.patch_width >= 32, "patches must be at least 32x32"),
            (self.split_by in ("groups", "image"), "split_by must be groups or image"),
        ]
        for ok, message in checks:
            if not ok:
                raise ConfigError(f"training config: {message}")

    @property
    def patch_size(self) -> tuple[int, int]:
        return (self.patch_height, self.patch_width)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (paths as strings) for checkpoints and logs."""
        return {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(self).items()}


FIELDS = {f.name: f for f in fields(TrainConfig)}

#: settings renamed since 0.3.0 (old name -> new): still read from config files, with a warning
RENAMED = {"workers": "loader_workers"}


#: the settings files shipped with osmseg (``--config cpu.yaml`` finds them from any folder)
CONFIGS_DIR = Path(__file__).resolve().parent / "configs"


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
