"""What a training step does besides the loops: the optimiser and its schedule, the loss, the
encoder's BatchNorm, and the moving average of the weights that ``model.pt`` holds.

Each follows a setting of the run's :class:`~training.run.recipe.Recipe`:

* ``encoder_lr``: the encoder's parameters (``model.encoder``, SegNet's and unet-lite0's alike)
  in a parameter group of their own at ``encoder_lr`` x ``lr``; the schedule scales both groups.
* ``freeze_bn``: the encoder's BatchNorm layers stay in evaluation mode while the network
  trains, so their running statistics stay the pretrained ones (batches of 4 crops of one town
  are a poor estimate of them); their scale and shift still learn.
* ``dice``: a soft Dice loss over the classes, ``dice`` times, beside the cross-entropy: it
  weighs a class by its overlap, not its pixel count, so buildings on a mostly bare crop count.
* ``ema``: :func:`weight_average`, torch's :class:`~torch.optim.swa_utils.AveragedModel` with an
  exponential moving average of parameters and buffers, updated after every optimiser step.
  Why: on the few images users have, the validation split is one or a few strips, and the
  epoch it calls best is noise (issue 19: ``best.pt`` was worse than ``last.pt`` on held-out
  tiles for every variant). An average over the last few hundred steps smooths the noise of the
  last ones without asking validation to choose.

Imports: osmseg core, torch, training.run.recipe.
"""

from __future__ import annotations

import functools

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

from training.run.recipe import Recipe, lr_factor

__all__ = ["SegmentationLoss", "freeze_encoder_bn", "make_optimizer", "make_scheduler", "weight_average"]


def _encoder(model: nn.Module) -> nn.Module | None:
    encoder = getattr(model, "encoder", None)
    return encoder if isinstance(encoder, nn.Module) else None


def parameter_groups(model: nn.Module, recipe: Recipe) -> list[dict[str, object]]:
    """The optimiser's groups: the encoder at ``encoder_lr`` x ``lr``, the rest at ``lr`` (one group
    when the multiple is 1 or the model has no ``encoder``).

    >>> from training.run.recipe import recipe_named
    >>> net = nn.Sequential()
    >>> net.encoder, net.head = nn.Linear(2, 2), nn.Linear(2, 1)
    >>> [(len(g["params"]), g["lr"]) for g in parameter_groups(net, recipe_named("osmseg", encoder_lr=0.1))]
    [(2, 0.001), (2, 0.01)]
    """
    encoder = _encoder(model)
    if encoder is None or recipe.encoder_lr == 1.0:
        return [{"params": list(model.parameters()), "lr": recipe.lr}]
    inside = {id(p) for p in encoder.parameters()}
    return [{"params": list(encoder.parameters()), "lr": recipe.lr * recipe.encoder_lr},
            {"params": [p for p in model.parameters() if id(p) not in inside], "lr": recipe.lr}]


def make_optimizer(model: nn.Module, recipe: Recipe) -> torch.optim.Optimizer:
    """The recipe's optimiser over ``model``'s parameters (:func:`parameter_groups`)."""
    groups = parameter_groups(model, recipe)
    if recipe.optimizer == "adamw":
        return torch.optim.AdamW(groups, lr=recipe.lr, weight_decay=recipe.weight_decay)
    return torch.optim.SGD(groups, lr=recipe.lr, momentum=recipe.momentum, weight_decay=recipe.weight_decay)


def make_scheduler(optimizer: torch.optim.Optimizer, recipe: Recipe,
                   total_steps: int) -> torch.optim.lr_scheduler.LambdaLR:
    """Per-step rate: the recipe's warm-up (a fraction of ``total_steps``), then its schedule."""
    warmup = round(recipe.warmup * total_steps)
    return torch.optim.lr_scheduler.LambdaLR(
        optimizer, functools.partial(lr_factor, total=total_steps, warmup=warmup, schedule=recipe.schedule,
                                     power=recipe.poly_power))


def freeze_encoder_bn(model: nn.Module) -> None:
    """Put the encoder's BatchNorm layers in evaluation mode (call after every ``model.train()``).

    >>> net = nn.Sequential(); net.encoder = nn.BatchNorm2d(3); _ = net.train(); freeze_encoder_bn(net)
    >>> net.encoder.training, net.training
    (False, True)
    """
    encoder = _encoder(model)
    for m in encoder.modules() if encoder is not None else ():
        if isinstance(m, nn.modules.batchnorm._BatchNorm):
            m.eval()


class SegmentationLoss(nn.Module):
    """Cross-entropy (class ``weight``, pixels of ``ignore_index`` left out) plus ``dice`` times a
    soft Dice loss: 1 - the mean over classes of 2|P.T| / (|P| + |T|), from the softmax, over the
    batch's labelled pixels, classes absent from both prediction and truth counting as 1.

    >>> loss = SegmentationLoss(ignore_index=0, dice=1.0)
    >>> logits = torch.tensor([[[[9.0]], [[-9.0]], [[-9.0]]]])  # (1, 3 classes, 1, 1): class 0
    >>> round(float(loss(logits, torch.tensor([[[1]]]))), 1)  # wrong: CE 18 + Dice 0.5 (1 missed, 2 absent)
    18.5
    """

    def __init__(self, weight: Tensor | None = None, ignore_index: int = -100, dice: float = 0.0) -> None:
        super().__init__()
        self.ignore_index, self.dice = ignore_index, dice
        self.cross_entropy = nn.CrossEntropyLoss(weight=weight, ignore_index=ignore_index)

    def forward(self, logits: Tensor, masks: Tensor) -> Tensor:
        loss: Tensor = self.cross_entropy(logits, masks)
        if self.dice == 0:
            return loss
        keep = (masks != self.ignore_index).unsqueeze(1).to(logits.dtype)  # (N, 1, H, W)
        probs = logits.float().softmax(1) * keep
        truth = F.one_hot(masks.clamp(0, logits.shape[1] - 1), logits.shape[1]).permute(0, 3, 1, 2) * keep
        classes = [c for c in range(logits.shape[1]) if c != self.ignore_index]
        inter = (probs * truth).sum((0, 2, 3))[classes]
        total = (probs + truth).sum((0, 2, 3))[classes]
        dice = (2 * inter + 1e-6) / (total + 1e-6)
        total_loss: Tensor = loss + self.dice * (1 - dice.mean())
        return total_loss


def weight_average(model: nn.Module, decay: float) -> AveragedModel | None:
    """An exponential moving average of ``model``'s parameters and buffers (``decay`` per step),
    None when ``decay`` is 0. Call ``update_parameters(model)`` after each optimiser step; its
    ``module`` is a model of the same kind, averaged."""
    if decay == 0:
        return None
    return AveragedModel(model, multi_avg_fn=get_ema_multi_avg_fn(decay), use_buffers=True)  # type: ignore[no-untyped-call]
