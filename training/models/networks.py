"""SegNet (Badrinarayanan, Kendall and Cipolla, TPAMI 2017) and the AirSegNet presets.

The encoder is the 13 convolutions of VGG16-BN in five stages (64,64 | 128,128 | 256x3 |
512x3 | 512x3), each a 3x3 convolution + BatchNorm + ReLU, with a 2x2 max pooling after each
stage that also returns where each maximum was.  The decoder mirrors it: each stage unpools
with the indices of its encoder stage (values go back to the positions of the maxima,
zeros elsewhere: SegNet's memory-cheap alternative to U-Net's skip features), then applies
the mirrored convolutions.  As in the authors' Caffe model, the last decoder stage ends in a
3x3 convolution to ``num_classes`` scores with no BatchNorm or ReLU (``conv1_1_D``), whose
softmax is the per-pixel classifier.  At width 1.0 the network has about 29.4 M parameters,
the paper's 29.5 M.

``segnet-skip`` (:data:`~training.models.spec.ARCHS`) is the same network whose decoder also adds, to
each unpooled input, the features the encoder stage had before pooling them (LinkNet's
additive skips, Chaurasia and Culurciello 2017): no weights are added, so checkpoints and
encoder weights load alike, but the decoder no longer has to rebuild every pixel's detail from
the 1/32 bottleneck and the pooling indices, which at small widths it cannot
(``docs/training.md`` measures both).

The encoder's modules are laid out exactly like torchvision's ``vgg16_bn().features``
(``encoder.features.0`` .. ``encoder.features.43``), so ImageNet weights load onto it by
name (:func:`load_encoder_weights`).  ``width`` scales every channel count to
``max(4, round(c * width))``: 1.0 is the paper's network, 0.0625 (first conv 4 channels,
~0.1 M parameters) runs tests and demos on a CPU in moments; the floor of 4 keeps tiny
widths from collapsing to 1-channel layers.

Everything works with ``channels_last`` and CUDA autocast: the unpooled features are put
back into the input's memory format.

>>> net = SegNet(num_classes=7, width=0.0625)
>>> net(torch.zeros(1, 3, 64, 96)).shape
torch.Size([1, 7, 64, 96])
>>> spec = model_spec("airsegnet6", 0.0625)
>>> spec.num_classes, spec.ignore_index, spec.class_names[:3]
(7, 0, ['unlabeled', 'building', 'highway'])
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
from torch import Tensor, nn

from osmseg.classes import ClassTable, load_class_table
from osmseg.errors import ConfigError, DatasetError
from training.models.lite0 import UNetLite0
from training.models.spec import ARCHS, IMAGENET_MEAN, IMAGENET_STD, PRESET_NAMES, ModelSpec

logger = logging.getLogger(__name__)

#: Output channels of VGG16's 13 convolutions, by stage.
VGG16_STAGES: tuple[tuple[int, ...], ...] = ((64, 64), (128, 128), (256, 256, 256), (512, 512, 512), (512, 512, 512))

#: Smallest input side: five 2x2 poolings take 32 pixels down to 1.
MIN_SIZE = 32

#: Model presets: name -> class table in ``data_manifests/`` (outputs = its classes + unlabeled).
PRESETS: dict[str, str] = dict(zip(PRESET_NAMES, ("classes6.toml", "classes13.toml"), strict=True))


def scaled(channels: int, width: float) -> int:
    """Channel count at ``width``: ``max(4, round(channels * width))``.

    >>> scaled(64, 1.0), scaled(64, 0.0625), scaled(512, 0.0625), scaled(64, 0.01)
    (64, 4, 32, 4)
    """
    return max(4, round(channels * width))


def _conv_bn_relu(cin: int, cout: int) -> list[nn.Module]:
    return [nn.Conv2d(cin, cout, kernel_size=3, padding=1), nn.BatchNorm2d(cout), nn.ReLU(inplace=True)]


class SegNetEncoder(nn.Module):
    """VGG16-BN's convolutional part; returns the bottleneck and each stage's pooling indices.

    ``features`` has torchvision's ``vgg16_bn().features`` layout: a stage's (conv, BN, ReLU)
    triples, then its pooling layer (which here also returns indices).
    """

    def __init__(self, width: float = 1.0, in_channels: int = 3) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        cin = in_channels
        for stage in VGG16_STAGES:
            for c in stage:
                layers += _conv_bn_relu(cin, scaled(c, width))
                cin = scaled(c, width)
            layers.append(nn.MaxPool2d(kernel_size=2, stride=2, return_indices=True))
        self.features = nn.Sequential(*layers)
        self.out_channels = cin

    def forward(self, x: Tensor, keep: bool = False) -> tuple[Tensor, list[tuple[Tensor, torch.Size]], list[Tensor]]:
        """``(bottleneck, [(indices, size before pooling) for stages 1..5], features)``: with
        ``keep`` the features each stage pooled (for skips), else no features."""
        pools: list[tuple[Tensor, torch.Size]] = []
        features: list[Tensor] = []
        for layer in self.features:
            if isinstance(layer, nn.MaxPool2d):
                size = x.shape
                if keep:
                    features.append(x)
                x, indices = layer(x)
                pools.append((indices, size))
            else:
                x = layer(x)
        return x, pools, features


class SegNet(nn.Module):
    """SegNet: VGG16-BN encoder (13 conv), pooling indices -> mirrored decoder, 3x3 classifier.

    ``skips``: each decoder stage's unpooled input has the features its encoder stage pooled
    added to it (LinkNet's additive skips; no parameters added, so the weights are SegNet's).
    Without them the decoder sees the encoder only through the bottleneck (1/32 of the input's
    side) and the pooling indices: at small widths fine detail (paths, single trees, the exact
    edge of a roof) is lost there (``docs/training.md`` measures it).

    ``forward`` maps ``(N, in_channels, H, W)`` floats (normalised) to ``(N, num_classes, H, W)``
    logits, for any ``H, W >= 32`` (odd sizes too: unpooling restores each stage's size).
    ``decoder[0]`` pairs with the deepest encoder stage; ``classifier`` is the last layer.
    """

    def __init__(self, num_classes: int, width: float = 1.0, in_channels: int = 3, skips: bool = False) -> None:
        super().__init__()
        self.skips = bool(skips)
        if num_classes < 1 or width <= 0 or in_channels < 1:
            raise ConfigError(f"SegNet needs num_classes >= 1, width > 0 and in_channels >= 1, "
                              f"got {num_classes}, {width}, {in_channels}")
        self.num_classes, self.width, self.in_channels = num_classes, float(width), in_channels
        self.encoder = SegNetEncoder(width, in_channels)
        self.unpool = nn.MaxUnpool2d(kernel_size=2, stride=2)
        stages: list[nn.Module] = []
        for i in reversed(range(len(VGG16_STAGES))):
            chans = [scaled(c, width) for c in VGG16_STAGES[i]]
            # mirrored convs: all keep the stage's width but the last, which narrows to the
            # next (shallower) stage's; the shallowest stage's last conv is the classifier
            outs = chans[:-1] + ([scaled(VGG16_STAGES[i - 1][-1], width)] if i > 0 else [])
            layers: list[nn.Module] = []
            cin = chans[-1]
            for cout in outs:
                layers += _conv_bn_relu(cin, cout)
                cin = cout
            stages.append(nn.Sequential(*layers))
        self.decoder = nn.ModuleList(stages)
        self.classifier = nn.Conv2d(scaled(VGG16_STAGES[0][0], width), num_classes, kernel_size=3, padding=1)
        self._init_weights()

    def _init_weights(self) -> None:
        """As torchvision's VGG: Kaiming-normal convolutions (fan-out), BatchNorm at identity."""
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
                if m.bias is not None:
                    nn.init.zeros_(m.bias)
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)

    def forward(self, x: Tensor) -> Tensor:
        if x.dim() != 4 or x.shape[1] != self.in_channels:
            raise ConfigError(f"SegNet input must be (N, {self.in_channels}, H, W), got {tuple(x.shape)}")
        if min(x.shape[-2:]) < MIN_SIZE:
            raise ConfigError(f"SegNet input must be at least {MIN_SIZE}x{MIN_SIZE} pixels, "
                              f"got {x.shape[-2]}x{x.shape[-1]}; pad or enlarge the image")
        memory_format = (torch.channels_last if x.is_contiguous(memory_format=torch.channels_last)
                         and not x.is_contiguous() else torch.contiguous_format)
        x, pools, features = self.encoder(x, keep=self.skips)
        return self.decode(x, pools, memory_format, features)

    def decode(self, x: Tensor, pools: list[tuple[Tensor, torch.Size]],
               memory_format: torch.memory_format = torch.contiguous_format,
               features: list[Tensor] | None = None) -> Tensor:
        """Decoder: unpool with each encoder stage's indices (deepest first), add that stage's
        ``features`` when given (skips), convolve, classify."""
        skips = list(reversed(features)) if features else [None] * len(pools)
        for stage, (indices, size), skip in zip(self.decoder, reversed(pools), skips, strict=True):
            x = self.unpool(x, indices, output_size=size[-2:]).contiguous(memory_format=memory_format)
            if skip is not None:
                x = x + skip
            x = stage(x)
        return cast("Tensor", self.classifier(x))


#: A network osmseg builds: SegNet (``segnet``, ``segnet-skip``) or :class:`~training.models.lite0.UNetLite0`.
Network = SegNet | UNetLite0


def build_model(spec: ModelSpec) -> Network:
    """A freshly initialised network for ``spec`` (weights come from a checkpoint or training)."""
    if spec.arch not in ARCHS:
        raise ConfigError(f"unknown architecture {spec.arch!r}; use one of {', '.join(ARCHS)}")
    if spec.arch == "unet-lite0":
        return UNetLite0(num_classes=spec.num_classes, width=spec.width)
    return SegNet(num_classes=spec.num_classes, width=spec.width, skips=spec.arch == "segnet-skip")


def model_spec(name: str, width: float = 1.0, ignore_unlabeled: bool = True,
               class_table: ClassTable | Mapping[str, Any] | str | Path | None = None,
               input_size: tuple[int, int] = (360, 480),
               mean: tuple[float, float, float] = IMAGENET_MEAN,
               std: tuple[float, float, float] = IMAGENET_STD,
               resolution_m: float | None = None, arch: str = "segnet") -> ModelSpec:
    """The spec of a SegNet named ``name`` whose outputs are ``class_table``'s ids (0..max id).

    ``class_table`` (a ClassTable, its ``to_dict()``, or a TOML name/path) defaults to the
    preset's (``airsegnet6`` -> ``classes6.toml``, ``airsegnet13`` -> ``classes13.toml``); other
    names need one.  ``ignore_unlabeled`` makes the unlabeled class (0; CamVid's void 11) the loss's
    and metrics' ignore index.
    The default normalisation is ImageNet's mean/std: what an ImageNet-initialised encoder
    expects, and for a randomly initialised one just a harmless centring of the inputs.

    >>> s = model_spec("airsegnet13", 0.25, ignore_unlabeled=False)
    >>> s.num_classes, s.ignore_index, s.input_size
    (14, None, (360, 480))
    """
    if class_table is None:
        if name not in PRESETS:
            raise ConfigError(f"unknown model {name!r}; use one of {sorted(PRESETS)} or give a class table")
        class_table = PRESETS[name]
    if isinstance(class_table, ClassTable):
        table = class_table
    elif isinstance(class_table, Mapping):
        table = ClassTable.from_dict(class_table, f"model {name!r} class table")
    else:
        table = load_class_table(str(class_table))
    return ModelSpec(arch=arch, name=name, num_classes=table.num_classes, width=float(width),
                     class_table=table.to_dict(),
                     ignore_index=table.unlabeled.id if ignore_unlabeled else None, input_size=(int(input_size[0]), int(input_size[1])),
                     mean=tuple(float(v) for v in mean), std=tuple(float(v) for v in std),  # type: ignore[arg-type]
                     resolution_m=None if resolution_m is None else float(resolution_m))


def unlabeled_as_background(spec: ModelSpec, pixels: np.ndarray, where: str = "the labels"
                            ) -> tuple[ModelSpec, str | None]:
    """``spec`` trained as a binary model when its labels hold one class besides the ignored one.

    ``pixels`` are the training labels' pixels per class id (the model's ids). With unlabeled
    ignored and a single other class (building footprints, or ``airsegnet6`` on a build with
    only buildings) there is nothing to tell apart: every scored pixel is that class, the loss
    is minimised by predicting it everywhere and validation, blind to unlabeled, scores that
    1.0. So the unlabeled class becomes the background class: trained, predicted and scored
    (``ignore_index`` None, recorded in the checkpoint, so ``predict`` and ``eval`` do the
    same). Returns the spec to train and, when it changed, the one-line warning to log.
    DatasetError when no pixel is labelled at all.

    >>> spec = model_spec("airsegnet6", 0.0625)
    >>> binary, note = unlabeled_as_background(spec, np.array([90, 10, 0, 0, 0, 0, 0]))
    >>> binary.ignore_index, note.split(":")[0]
    (None, "the labels hold one class besides 'unlabeled'")
    >>> unlabeled_as_background(spec, np.array([90, 10, 5, 0, 0, 0, 0]))[0] is spec
    True
    """
    if spec.ignore_index is None:
        return spec, None
    names = spec.class_names
    ignored = names[spec.ignore_index]
    labelled = [i for i in np.flatnonzero(np.asarray(pixels)) if i != spec.ignore_index]
    if not labelled:
        raise DatasetError(f"{where} hold no pixel of any class but {ignored!r}, which training ignores: nothing to "
                           "learn; check the labels and the class table (--classes)")
    if len(labelled) > 1:
        return spec, None
    only = names[int(labelled[0])]
    return dataclasses.replace(spec, ignore_index=None), (
        f"{where} hold one class besides {ignored!r}: {only!r}. With {ignored!r} ignored there would be nothing to "
        f"tell apart (validation would score any model 1.0), so {ignored!r} is trained, predicted and scored as "
        f"the background of a binary model; pass --keep-unlabeled to choose this yourself (no warning), or label "
        "more classes")


def _vgg_features(state: Mapping[str, Any], source: str) -> dict[str, Tensor]:
    """The ``features`` part of a vgg16_bn state dict (full model or ``.features``), keys ``N.name``."""
    for wrapper in ("state_dict", "model"):  # {"state_dict": ...} as many training scripts save
        if isinstance(state.get(wrapper), Mapping):
            state = state[wrapper]
    out: dict[str, Tensor] = {}
    for key, value in state.items():
        key = key.removeprefix("module.").removeprefix("encoder.").removeprefix("features.")
        if isinstance(value, Tensor) and key.split(".")[0].isdigit():
            out[key] = value
    if not out:
        raise ConfigError(f"{source} holds no vgg16_bn convolution weights (keys like features.0.weight)")
    return out


def read_encoder_weights(source: str | Path) -> dict[str, Tensor]:
    """The VGG16-BN ``features`` weights of ``source``: ``"imagenet"`` (torchvision's
    ``IMAGENET1K_V1``, downloaded into the torch hub cache on first use, so it needs the network
    once) or a local ``.pth`` holding a ``vgg16_bn`` state dict, of the whole model or of
    ``.features``. A ConfigError (one line) for a file that holds no such weights."""
    if str(source) == "imagenet":
        from torchvision.models import VGG16_BN_Weights

        try:
            state = torch.hub.load_state_dict_from_url(VGG16_BN_Weights.IMAGENET1K_V1.url, progress=False,
                                                       check_hash=True)
        except (OSError, RuntimeError):  # URLError is an OSError; bad hashes are RuntimeErrors
            raise ConfigError("ImageNet weights need the network to download them once; "
                              "pass a local .pth of vgg16_bn instead") from None
        return _vgg_features(state, "torchvision ImageNet weights")
    path = Path(source)
    if not path.is_file():
        raise ConfigError(f"encoder weights {path} not found; give a .pth of torchvision vgg16_bn or 'imagenet'")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # torch.load raises many kinds on a file that is not its own
        raise ConfigError(f"{path} is not a readable vgg16_bn state dict (weights saved with "
                          "torch.save(model.state_dict(), path))") from None
    if not isinstance(state, Mapping):
        raise ConfigError(f"{path} holds no state dict (a mapping of tensors), so no vgg16_bn weights")
    return _vgg_features(state, str(path))


def load_encoder_weights(model: SegNet, source: str | Path | Mapping[str, Tensor]) -> None:
    """Initialise ``model``'s encoder from VGG16-BN weights (the decoder stays random).

    ``source``: what :func:`read_encoder_weights` reads, or the weights it read. Needs
    ``width == 1.0`` and 3 input channels, where the shapes are VGG's. Remember ImageNet weights
    expect ImageNet normalisation (the default of :func:`model_spec`).
    """
    if model.width != 1.0 or model.in_channels != 3:
        raise ConfigError(f"VGG16-BN encoder weights need width 1.0 and 3 input channels, got width {model.width} "
                          f"and {model.in_channels}; train from random init (--init random) or use --width 1.0")
    where = "the vgg16_bn weights" if isinstance(source, Mapping) else str(source)
    weights = dict(source) if isinstance(source, Mapping) else read_encoder_weights(source)
    expected = model.encoder.features.state_dict()
    missing = [k for k in expected if k not in weights]
    wrong = [k for k in expected if k in weights and weights[k].shape != expected[k].shape]
    if missing or wrong:
        key = (wrong or missing)[0]
        detail = f"{tuple(weights[key].shape)} instead of {tuple(expected[key].shape)}" if wrong else "missing"
        raise ConfigError(f"{where} does not fit the VGG16-BN encoder: features.{key} {detail}; give vgg16_bn weights")
    model.encoder.features.load_state_dict({k: weights[k] for k in expected})
    logger.info("encoder initialised from %s", where)
