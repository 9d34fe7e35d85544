"""Checkpoints: one file that holds everything needed to rebuild and use a trained model.

A checkpoint is a ``torch.save`` zip of plain data only (dicts, lists, tuples, strings,
numbers, tensors), so that :func:`load_checkpoint` can read it with
``torch.load(weights_only=True)``: opening a checkpoint never runs code from the file.
Beside the weights (``"model"``) it holds the :class:`ModelSpec` (architecture, width, class
table with colours, input size, normalisation) as a plain dict under ``"spec"``, so
``osmseg predict``/``osmseg eval`` need only the checkpoint, plus whatever the trainer adds
(optimizer, scheduler, scaler, epoch, RNG states as tensors, config, dataset hash, class
weights, history).  Writes are atomic: a temporary file in the same folder, then
``os.replace``, so an interrupted save never leaves a half-written checkpoint behind.

A checkpoint also starts a new run (``osmseg train --init best.pt``, :func:`read_init`): the
way a user adapts a model to their area, with their own class table if they like.
"""

from __future__ import annotations

import hashlib
import logging
import os
import pickle
import uuid
import zipfile
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path, PurePath
from typing import Any

import numpy as np
import torch
from torch import Tensor

from osmseg.errors import ConfigError
from osmseg.runtime.processes import interrupts_deferred
from training.devices import pick_device
from training.errors import CheckpointError
from training.models.lite0 import UNetLite0, lite0_weights, load_imagenet_encoder
from training.models.networks import Network, build_model, load_encoder_weights, read_encoder_weights
from training.models.spec import ModelSpec

logger = logging.getLogger(__name__)

FORMAT = "osmseg-checkpoint"
VERSION = 1

_SCALARS = (str, int, float, bool, type(None))  # exact types: weights_only refuses subclasses
_OBJECTS = (Tensor, torch.Size, torch.dtype)


def storable(obj: Any, where: str = "state") -> Any:
    """``obj`` with numpy scalars made Python numbers, paths (and str subclasses) made strings.

    Raises CheckpointError naming the first value ``torch.load(weights_only=True)`` would
    refuse (numpy arrays, dataclasses, arbitrary objects).

    >>> storable({"lr": np.float64(0.5), "out": Path("runs/a"), "steps": [1, (2, 3)]})
    {'lr': 0.5, 'out': 'runs/a', 'steps': [1, (2, 3)]}
    >>> storable({"rng": np.zeros(3)})
    Traceback (most recent call last):
    training.errors.CheckpointError: state['rng'] is a numpy.ndarray, which checkpoints cannot hold; store a tensor or a list
    """
    if type(obj) in _SCALARS or isinstance(obj, _OBJECTS):
        return obj
    if isinstance(obj, np.generic):  # np.float64 is a float subclass
        return obj.item()
    if isinstance(obj, (PurePath, str)):  # str subclasses too, e.g. torch.__version__
        return str(obj)
    if isinstance(obj, Mapping):
        out = {storable(k, f"{where} key"): storable(v, f"{where}[{k!r}]") for k, v in obj.items()}
        if isinstance(obj, OrderedDict):  # a state_dict: keep its type and version metadata
            out = OrderedDict(out)
            if hasattr(obj, "_metadata"):
                out._metadata = obj._metadata  # type: ignore[attr-defined]
        return out
    if isinstance(obj, (list, tuple)) and not hasattr(obj, "_fields"):
        items = [storable(v, f"{where}[{i}]") for i, v in enumerate(obj)]
        return items if isinstance(obj, list) else tuple(items)
    kind = f"{type(obj).__module__}.{type(obj).__qualname__}".removeprefix("builtins.")
    raise CheckpointError(f"{where} is a {kind}, which checkpoints cannot hold; store a tensor or a list")


def save_checkpoint(path: Path, state: Mapping[str, Any]) -> None:
    """Write ``state`` (must hold ``"spec"`` and ``"model"``) to ``path`` atomically.

    ``"spec"`` may be a :class:`ModelSpec` or its dict; it is stored as a plain dict.  The
    format marker, version and torch version are added.  Parent folders are created.
    """
    path = Path(path)
    missing = [k for k in ("spec", "model") if k not in state]
    if missing:
        raise CheckpointError(f"checkpoint state lacks {missing}; pass the model spec and model.state_dict()")
    spec = state["spec"]
    spec = ModelSpec.from_dict(asdict(spec) if isinstance(spec, ModelSpec) else spec)
    payload = storable({**state, "spec": asdict(spec), "format": FORMAT, "version": VERSION,
                        "torch_version": str(torch.__version__)})
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")  # open() honours the umask
    try:
        with interrupts_deferred():  # a Ctrl-C or SIGTERM inside torch.save's zip writer surfaces as its error
            with tmp.open("xb") as f:
                torch.save(payload, f)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


#: the checkpoint a run hands on, which a run folder stands for
MODEL_FILE = "model.pt"


def run_checkpoint(path: Path) -> Path:
    """``path``, or for a training run's folder the checkpoint it hands on (``model.pt``).

    CheckpointError when a folder holds none (runs of osmseg before 0.6 wrote only
    ``best.pt`` and ``last.pt``: they are named then)."""
    if not path.is_dir():
        return path
    if (path / MODEL_FILE).is_file():
        return path / MODEL_FILE
    others = sorted(p.name for p in path.glob("*.pt"))
    raise CheckpointError(f"{path} is a folder without {MODEL_FILE}" + (
        f"; give one of its checkpoints: {', '.join(str(path / n) for n in others)}" if others else
        "; give a checkpoint file, or the folder of an osmseg train run"))


def load_checkpoint(path: Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Read and check a checkpoint written by :func:`save_checkpoint` (``"spec"`` stays a dict).

    Raises CheckpointError (one line) if the file is missing, corrupt or truncated, holds
    anything but plain data, or is not an osmseg checkpoint of a version this code reads.
    """
    path = run_checkpoint(Path(path))
    if not path.exists():
        raise CheckpointError(f"checkpoint {path} not found")
    corrupt = f"{path} is not a checkpoint (corrupt or truncated); train again or restore it"
    try:
        with path.open("rb") as f:  # torch.save always writes a zip; a cut one lacks its directory
            is_zip = zipfile.is_zipfile(f)
        if not is_zip:
            raise CheckpointError(corrupt)
        state = torch.load(path, map_location=map_location, weights_only=True)
    except PermissionError as exc:
        raise CheckpointError(f"cannot read checkpoint {path} ({exc.strerror}); check its permissions") from None
    except pickle.UnpicklingError as exc:
        if "weights only" in str(exc).lower():
            raise CheckpointError(f"{path} holds Python objects, not plain data: not an osmseg checkpoint") from None
        raise CheckpointError(corrupt) from None
    except (RuntimeError, EOFError, ValueError, OSError, zipfile.BadZipFile, AttributeError, IndexError, KeyError):
        raise CheckpointError(corrupt) from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not an osmseg checkpoint (no format={FORMAT!r} entry); "
                              "give a file written by osmseg train")
    version = state.get("version")
    if not isinstance(version, int) or version > VERSION:
        raise CheckpointError(f"{path} is checkpoint version {version!r}, this osmseg reads up to {VERSION}; upgrade osmseg")
    model = state.get("model")
    if not isinstance(model, Mapping) or not all(isinstance(v, Tensor) for v in model.values()):
        raise CheckpointError(f"{path}: 'model' is not a state dict of tensors; the checkpoint is damaged")
    try:
        ModelSpec.from_dict(state.get("spec"))  # type: ignore[arg-type]
    except ConfigError as exc:
        raise CheckpointError(f"{path}: bad {exc}") from None
    return state


def _strip_wrappers(weights: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """Remove the key prefixes DistributedDataParallel and torch.compile add."""
    out = dict(weights)
    for prefix in ("module.", "_orig_mod."):
        if out and all(k.startswith(prefix) for k in out):
            out = {k[len(prefix):]: v for k, v in out.items()}
    return out


def model_from_checkpoint(path: Path, device: str | torch.device = "cpu") -> tuple[Network, ModelSpec]:
    """The checkpoint's model, with its weights, on ``device`` in eval mode, and its spec.

    CheckpointError (one line) if the stored weights do not fit the stored spec.
    """

    path = run_checkpoint(Path(path))
    state = load_checkpoint(path, map_location="cpu")
    spec = ModelSpec.from_dict(state["spec"])
    model = build_model(spec)
    weights = _strip_wrappers(state["model"])
    expected = model.state_dict()
    missing = [k for k in expected if k not in weights]
    extra = [k for k in weights if k not in expected]
    wrong = [k for k in expected if k in weights and weights[k].shape != expected[k].shape]
    if missing or extra or wrong:
        first = (f"{wrong[0]} is {tuple(weights[wrong[0]].shape)}, expected {tuple(expected[wrong[0]].shape)}" if wrong
                 else f"{len(missing)} missing, {len(extra)} unexpected, e.g. {(missing or extra)[0]}")
        raise CheckpointError(f"{path}: weights do not fit its spec ({spec.arch}, {spec.num_classes} classes, "
                              f"width {spec.width}): {first}; the checkpoint is inconsistent")
    model.load_state_dict(weights)
    return model.to(pick_device(device) if isinstance(device, str) else device).eval(), spec


# ------------------------------------------------------------------------------ --init
def looks_like_checkpoint(path: Path) -> bool:
    """Whether ``path`` is a ``torch.save`` zip whose pickle carries osmseg's format marker.

    Cheap (it reads the small pickle, never the tensors), so ``--init FILE`` tells a previous
    run's ``best.pt`` from a ``vgg16_bn`` ``.pth`` without loading either twice. A damaged
    checkpoint is then reported by :func:`load_checkpoint`.
    """
    try:
        with zipfile.ZipFile(path) as archive:
            return any(FORMAT.encode() in archive.read(name) for name in archive.namelist()
                       if name.endswith("/data.pkl"))
    except (OSError, zipfile.BadZipFile, RuntimeError, ValueError):
        return False


def file_sha256(path: Path) -> str:
    """The sha256 of ``path``'s bytes (hex)."""
    digest = hashlib.sha256()
    with Path(path).open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


@dataclass(frozen=True)
class InitWeights:
    """A run's first weights (``--init``), read and checked before the run writes anything.

    ``weights`` (an osmseg checkpoint's, by parameter name) are copied onto the new network by
    :meth:`apply`, all of them or all but the classifier's (``keep_classifier`` False); without
    them ``source`` is ``imagenet`` or a vgg16_bn file (its weights, read, in ``encoder``) for
    :func:`training.models.networks.load_encoder_weights`. ``record`` is what the run's checkpoints store
    under ``"init"``.
    """

    source: str
    record: dict[str, Any]
    weights: Mapping[str, Tensor] | None = None
    keep_classifier: bool = True
    encoder: Mapping[str, Tensor] | None = None  # a vgg16_bn file's weights, or unet-lite0's, read by read_init

    def apply(self, model: Network) -> None:
        """Initialise ``model`` (freshly built from the run's spec) from these weights."""
        if self.weights is None:
            if isinstance(model, UNetLite0):
                load_imagenet_encoder(model, self.encoder)
            else:
                load_encoder_weights(model, self.encoder if self.encoder is not None else self.source)
            return
        expected = model.state_dict()
        wanted = {k: v for k, v in self.weights.items() if self.keep_classifier or not k.startswith("classifier.")}
        missing = [k for k in expected if k not in wanted and (self.keep_classifier or not k.startswith("classifier."))]
        wrong = [k for k, v in wanted.items() if k not in expected or v.shape != expected[k].shape]
        if missing or wrong:
            key = (wrong or missing)[0]
            raise CheckpointError(f"--init {self.source}: its weights do not fit this run's network ({key} "
                                  f"{'missing' if not wrong else 'differs'}); the checkpoint is inconsistent")
        model.load_state_dict(wanted, strict=self.keep_classifier)
        logger.info("initialised from %s: %s", self.source, self.record["reused"])


def read_init(source: str, spec: ModelSpec) -> InitWeights | None:
    """What ``--init`` names, checked against the run's ``spec``: None for ``random``.

    ``imagenet`` or a ``vgg16_bn`` file initialise the encoder (width 1.0 only). A checkpoint of
    a previous osmseg run (``best.pt``/``last.pt``) fine-tunes it: with the same class table,
    the whole network is reused; with another one, the encoder and decoder are, and the
    classifier (one output per class) starts afresh. Its width must be the run's (else a
    one-line ConfigError saying which to use). The record holds the checkpoint's path, sha256,
    class table, width and what was reused.
    """
    if source == "random":
        return None
    if spec.arch == "unet-lite0" and source == "imagenet":  # the weights installed with osmseg: no download
        weights, packaged = lite0_weights()
        return InitWeights(source, {**packaged, "reused": "the encoder (EfficientNet-Lite0, ImageNet)"}, encoder=weights)
    path = Path(source).expanduser()
    if source != "imagenet" and not path.is_file():
        raise ConfigError(f"--init {source}: no such file; give random, imagenet, a checkpoint of an osmseg run "
                          "(best.pt, last.pt) or a vgg16_bn .pth")
    if spec.arch == "unet-lite0" and not looks_like_checkpoint(path):
        raise ConfigError(f"--init {source}: unet-lite0 starts from imagenet (its EfficientNet-Lite0 weights, installed "
                          "with osmseg), random, or a checkpoint of an osmseg unet-lite0 run (best.pt, last.pt)")
    if source == "imagenet" or not looks_like_checkpoint(path):
        encoder = None
        if source != "imagenet":  # read now: a file that is neither is refused before the run begins
            try:
                encoder = read_encoder_weights(path)
            except ConfigError:
                raise ConfigError(f"--init {source} is neither a checkpoint of an osmseg run (best.pt, last.pt) nor "
                                  "vgg16_bn weights (a .pth state dict), or it is damaged: give one of those, "
                                  "imagenet or random") from None
        if spec.width != 1.0:
            raise ConfigError(f"--init {source}: VGG16-BN encoder weights need width 1.0, got width {spec.width:g}; "
                              "train from random init (--init random), use --width 1.0, or give a checkpoint of an "
                              "osmseg run of this width")
        record: dict[str, Any] = {"source": source, "reused": "the encoder (vgg16_bn)"}
        if source != "imagenet":
            record.update(path=str(path.resolve()), sha256=file_sha256(path))
        return InitWeights(source, record, encoder=encoder)
    state = load_checkpoint(path)
    then = ModelSpec.from_dict(state["spec"])
    if (then.arch, float(then.width)) != (spec.arch, float(spec.width)):
        raise ConfigError(f"--init {source} is a width-{then.width:g} {then.arch}, this run's is width "
                          f"{spec.width:g}; train with --width {then.width:g} to fine-tune it")
    same = then.class_names == spec.class_names
    reused = ("the whole network (same classes)" if same else
              f"the encoder and decoder; the classifier starts afresh ({then.num_classes} classes of "
              f"{then.table.name!r} before, {spec.num_classes} of {spec.table.name!r} now)")
    record = {"source": source, "path": str(path.resolve()), "sha256": file_sha256(path),
              "classes": then.table.name, "width": float(then.width), "reused": reused}
    return InitWeights(source, record, weights=_strip_wrappers(state["model"]), keep_classifier=same)
