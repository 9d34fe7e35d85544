"""A segmentation model osmseg did not train: TorchScript or ONNX, read through a class mapping.

A user's ground photos are often segmented by a model trained elsewhere (Cityscapes, ADE20K,
Mapillary Vistas...). Such a model comes as a TorchScript file (``torch.jit.save``: ``.pt``,
``.ts``, ``.torchscript``) or an ONNX file (``.onnx``, run with onnxruntime on the CPU), and its
output channels are its own classes. A mapping TOML says how to read it::

    table = "classes13.toml"               # the osmseg class table the mask is written in
    size = [512, 1024]                     # optional: rows, columns the model takes (else the photo's)
    mean = [0.485, 0.456, 0.406]           # optional: per-channel normalisation of RGB / 255
    std = [0.229, 0.224, 0.225]            #   (defaults: ImageNet's)

    [classes]                              # output channel = class name of the table
    0 = "highway"                          # Cityscapes road
    1 = "highway"                          # sidewalk
    2 = "building"
    10 = "sky"

Channels the mapping does not name become the table's unlabeled class. The model takes one
``(1, 3, H, W)`` float32 image and gives ``(1, C, H, W)`` scores (any ``H, W``: resized back to the
photo's by nearest neighbour); the class of a pixel is its best channel's.

Imports: numpy, PIL, the osmseg core; torch (TorchScript) or onnxruntime (ONNX) when a model of
that kind is loaded.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tomllib
from PIL import Image

from osmseg.classes import ClassTable, load_class_table
from osmseg.errors import ConfigError

__all__ = ["ClassMapping", "ForeignModel", "TORCHSCRIPT_SUFFIXES", "load_foreign_model", "read_class_mapping"]

TORCHSCRIPT_SUFFIXES = (".pt", ".ts", ".torchscript", ".pth")
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


@dataclass(frozen=True)
class ClassMapping:
    """How to read a foreign model's output: its channels' osmseg classes (``lut``: channel -> class
    id, the unlabeled id where unnamed), the table, the input size and normalisation."""

    path: Path
    table: ClassTable
    lut: np.ndarray
    size: tuple[int, int] | None = None
    mean: tuple[float, float, float] = IMAGENET_MEAN
    std: tuple[float, float, float] = IMAGENET_STD


def _triple(doc: dict[str, Any], key: str, default: tuple[float, float, float], where: str) -> tuple[float, float, float]:
    value = doc.get(key, default)
    if not (isinstance(value, list | tuple) and len(value) == 3 and all(isinstance(v, int | float) for v in value)):
        raise ConfigError(f"{where}: {key} must be three numbers (red, green, blue), got {value!r}")
    return float(value[0]), float(value[1]), float(value[2])


def read_class_mapping(path: Path | str, extend: Callable[[ClassTable], ClassTable] | None = None) -> ClassMapping:
    """Read a mapping TOML (see the module doc); ConfigError naming the file and what to fix.
    ``extend``: what the caller's views add to the named table (a ground view's sky), before the
    channels' class names are looked up in it."""
    where = f"--ground-model-classes {path}"
    try:
        doc = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{where}: cannot read it as TOML ({exc})") from None
    table = load_class_table(str(doc.get("table", "classes13.toml")))
    if extend is not None:
        table = extend(table)
    classes = doc.get("classes")
    if not isinstance(classes, dict) or not classes:
        raise ConfigError(f"{where}: give a [classes] table of output channel = class name, e.g. 2 = \"building\"")
    pairs = []
    for key, name in classes.items():
        if not str(key).isdigit():
            raise ConfigError(f"{where}: [classes] keys are output channels (0, 1, ...), got {key!r}")
        if name not in table.by_name:
            raise ConfigError(f"{where}: {name!r} (channel {key}) is no class of {table.name}; its classes: "
                              f"{', '.join(c.name for c in table.classes)}")
        pairs.append((int(key), table.by_name[name].id))
    lut = np.full(max(k for k, _ in pairs) + 1, table.unlabeled.id, np.uint8)
    for k, cid in pairs:
        lut[k] = cid
    size = doc.get("size")
    if size is not None and not (isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) and v > 0
                                                                                for v in size)):
        raise ConfigError(f"{where}: size must be [rows, columns] the model takes, got {size!r}")
    return ClassMapping(Path(path), table, lut, None if size is None else (size[0], size[1]),
                        _triple(doc, "mean", IMAGENET_MEAN, where), _triple(doc, "std", IMAGENET_STD, where))


def _need(package: str) -> Any:
    """Import ``package`` (the runtime of a model kind), or say in one line how to install it."""
    import importlib

    try:
        return importlib.import_module(package)
    except ImportError:
        raise ConfigError(f"--ground-model needs {package}: pip install 'osmseg[train]'") from None


class ForeignModel:
    """A TorchScript or ONNX segmentation model with its :class:`ClassMapping`: :meth:`segment` an RGB photo."""

    def __init__(self, path: Path, mapping: ClassMapping) -> None:
        self.path, self.mapping = Path(path), mapping
        suffix = self.path.suffix.lower()
        if suffix == ".onnx":
            onnxruntime = _need("onnxruntime")

            try:
                self._session = onnxruntime.InferenceSession(str(self.path), providers=["CPUExecutionProvider"])
            except Exception as exc:  # onnxruntime raises its own exception types
                raise ConfigError(f"--ground-model {self.path}: not an ONNX model onnxruntime can run ({exc})") from None
            self._input = self._session.get_inputs()[0].name
            self._run = self._onnx
        elif suffix in TORCHSCRIPT_SUFFIXES:
            torch = _need("torch")

            try:
                with warnings.catch_warnings():  # torch 2.14 calls TorchScript deprecated; the user's model is one
                    warnings.simplefilter("ignore", FutureWarning)
                    self._module = torch.jit.load(str(self.path), map_location="cpu").eval()
            except (RuntimeError, ValueError) as exc:
                raise ConfigError(f"--ground-model {self.path}: not a TorchScript model ({str(exc).splitlines()[0]}); "
                                  "an osmseg checkpoint goes to --ground-checkpoint") from None
            self._run = self._torchscript
        else:
            raise ConfigError(f"--ground-model {self.path}: give a TorchScript (.pt, .ts) or ONNX (.onnx) model")

    def _onnx(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(self._session.run(None, {self._input: x})[0])

    def _torchscript(self, x: np.ndarray) -> np.ndarray:
        import torch

        with torch.inference_mode():
            out = self._module(torch.from_numpy(x))
        if isinstance(out, dict):  # torchvision's segmentation models answer {"out": scores, ...}
            out = out["out"]
        return out.numpy()  # type: ignore[no-any-return]

    def segment(self, rgb: np.ndarray) -> np.ndarray:
        """Class ids (H, W) uint8 of ``mapping.table`` for an (H, W, 3) uint8 photo."""
        h, w = rgb.shape[:2]
        m = self.mapping
        image = Image.fromarray(np.ascontiguousarray(rgb[..., :3], np.uint8))
        if m.size is not None:
            image = image.resize((m.size[1], m.size[0]), Image.Resampling.BILINEAR)
        x = (np.asarray(image, np.float32) / 255.0 - np.array(m.mean, np.float32)) / np.array(m.std, np.float32)
        batch = np.ascontiguousarray(x.transpose(2, 0, 1)[None], np.float32)
        try:
            scores = self._run(batch)
        except Exception as exc:  # the model's own error (onnxruntime's and torch's types differ)
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]
            raise ConfigError(f"--ground-model {self.path.name} failed on a {'x'.join(map(str, batch.shape))} image "
                              f"({first}); if it takes one input size, give it as size = [rows, columns] in "
                              f"{m.path.name}") from None
        if scores.ndim != 4 or scores.shape[0] != 1:
            raise ConfigError(f"--ground-model {self.path.name}: gave scores of shape {scores.shape}, not (1, classes, "
                              "rows, columns)")
        channels = scores.shape[1]
        if channels < len(m.lut):
            raise ConfigError(f"--ground-model-classes {m.path.name} names channel {len(m.lut) - 1}, but "
                              f"{self.path.name} gives {channels} channels")
        lut = np.concatenate([m.lut, np.full(channels - len(m.lut), m.table.unlabeled.id, np.uint8)])
        labels: np.ndarray = lut[scores[0].argmax(axis=0)]
        if labels.shape != (h, w):
            labels = np.asarray(Image.fromarray(labels).resize((w, h), Image.Resampling.NEAREST))
        return np.asarray(labels, np.uint8)


def load_foreign_model(path: Path | str, mapping: Path | str | None,
                       extend: Callable[[ClassTable], ClassTable] | None = None) -> ForeignModel:
    """A :class:`ForeignModel` (``extend``: see :func:`read_class_mapping`); ConfigError when the mapping is missing."""
    if mapping is None:
        raise ConfigError(f"--ground-model {Path(path).name} needs --ground-model-classes FILE.toml: which osmseg class "
                          "each of its output channels is")
    return ForeignModel(Path(path), read_class_mapping(mapping, extend))
