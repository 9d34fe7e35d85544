"""The two loops, as in torchvision's segmentation references: one epoch of training, one evaluation.

Both run unchanged on the CPU, one GPU (with AMP and channels_last) or under DDP: the caller
passes the device, whether to use AMP, and a model that may be wrapped in
``DistributedDataParallel``; losses are averaged and confusion matrices summed over processes.
"""

from __future__ import annotations

import itertools
import logging
import warnings
from collections.abc import Callable, Iterable, Sized
from dataclasses import dataclass
from typing import Any

import torch
from torch import nn

from osmseg.runtime.progress import Progress, track
from osmseg.units import plural
from training.devices import all_reduce_sum, is_distributed
from training.evaluation.metrics import ConfusionMatrix
from training.run.fitting import freeze_encoder_bn

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class StepOptions:
    """How batches are moved and computed on this device."""

    device: torch.device
    amp: bool = False  # autocast to float16 (CUDA only)
    channels_last: bool = False
    max_steps: int | None = None  # stop an epoch early (smoke tests, benchmarks)

    def to_device(self, images: torch.Tensor, masks: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        memory_format = torch.channels_last if self.channels_last else torch.contiguous_format
        images = images.to(self.device, non_blocking=True).contiguous(memory_format=memory_format)
        return images, masks.to(self.device, non_blocking=True)

    def autocast(self) -> torch.autocast:
        return torch.autocast(device_type=self.device.type, dtype=torch.float16, enabled=self.amp)


def _batches(loader: Iterable[Any], opts: StepOptions, task: str, progress: Progress | None) -> Iterable[Any]:
    total = len(loader) if isinstance(loader, Sized) else None
    if opts.max_steps is not None and total is not None:
        total = min(total, opts.max_steps)
    batches = itertools.islice(loader, opts.max_steps) if opts.max_steps is not None else loader
    yield from track(batches, progress, task, total, unit="batch")


def labelled_pixels(masks: torch.Tensor, ignore_index: int | None) -> int:
    """Pixels of ``masks`` the loss counts (all but ``ignore_index``'s).

    >>> labelled_pixels(torch.tensor([[0, 0], [3, 0]]), 0), labelled_pixels(torch.zeros(2, 2), None)
    (1, 4)
    """
    return int(masks.numel() if ignore_index is None else torch.count_nonzero(masks != ignore_index))


def train_one_epoch(
    model: nn.Module,
    criterion: nn.Module,
    optimizer: torch.optim.Optimizer,
    scheduler: torch.optim.lr_scheduler.LRScheduler,
    scaler: torch.amp.GradScaler,
    loader: Iterable[Any],
    opts: StepOptions,
    epoch: int,
    on_step: Callable[[int, float], None] | None = None,
    progress: Progress | None = None,
    freeze_bn: bool = False,
    after_step: Callable[[], None] | None = None,
) -> float | None:
    """Train for one epoch; returns the mean training loss over all processes (None when no
    batch had a labelled pixel).

    The scheduler steps once per batch (poly decay is defined per iteration). ``on_step(step,
    loss)`` after each batch that trained; ``after_step()`` after each optimiser step (the
    weights' moving average); ``progress`` gets a step per batch (task ``epoch N train``).
    ``freeze_bn``: the encoder's BatchNorm layers stay in evaluation mode
    (:func:`training.run.fitting.freeze_encoder_bn`).

    A batch whose pixels are all ``criterion.ignore_index`` (a crop inside an OSM gap) has no
    loss: cross-entropy's mean over zero pixels is 0/0 = NaN. Its gradient is zero, yet an
    optimizer step would still move the weights (SGD's momentum and weight decay, AdamW's
    moment estimates and decoupled decay), and the NaN would make the epoch's mean loss NaN. So
    such a batch contributes nothing: no forward pass (BatchNorm statistics stay too), no
    optimizer step, no loss; only the scheduler steps, because the schedule counts batches (a
    resumed run meets the same batches and skips the same ones). Under DDP a batch is skipped
    when every process's is unlabelled (one summed count, so all take the same steps); a
    process whose own batch is unlabelled while others' are not joins the gradient average with
    a zero loss.
    """
    model.train()
    if freeze_bn:
        freeze_encoder_bn(getattr(model, "module", model))  # the model inside a DDP wrapper
    ignore = getattr(criterion, "ignore_index", None)  # nn.CrossEntropyLoss's; -100 matches no id
    total = torch.zeros(2, dtype=torch.float64, device=opts.device)  # loss sum, batches
    skipped = 0
    for step, (images, masks) in enumerate(_batches(loader, opts, f"epoch {epoch} train", progress)):
        here = labelled_pixels(masks, ignore)  # counted on the loader's (CPU) tensor: no device sync
        everywhere = here
        if is_distributed():  # every process must take (or skip) the same steps
            everywhere = int(all_reduce_sum(torch.tensor([here], dtype=torch.int64, device=opts.device)).item())
        if not everywhere:
            skipped += 1
            with warnings.catch_warnings():  # a skipped first batch is no misuse of the scheduler
                warnings.filterwarnings("ignore", message=r"Detected call of `lr_scheduler\.step\(\)` before")
                scheduler.step()
            continue
        images, masks = opts.to_device(images, masks)
        with opts.autocast():
            logits = model(images)
            loss = criterion(logits, masks) if here else logits.sum() * 0.0
        optimizer.zero_grad(set_to_none=True)
        scaler.scale(loss).backward()
        scaler.step(optimizer)
        scaler.update()
        scheduler.step()
        if after_step is not None:
            after_step()
        if here:
            total += torch.tensor([loss.item(), 1.0], dtype=torch.float64, device=opts.device)
            if on_step is not None:
                on_step(step, loss.item())
    if skipped:
        logger.info("epoch %d: %s had no labelled pixel and %s skipped", epoch, plural(skipped, "batch"),
                    "was" if skipped == 1 else "were")
    all_reduce_sum(total)
    return float(total[0] / total[1]) if total[1] else None


@torch.inference_mode()
def evaluate(
    model: nn.Module,
    criterion: nn.Module,
    loader: Iterable[Any],
    opts: StepOptions,
    num_classes: int,
    ignore_index: int | None,
    progress: Progress | None = None,
    task: str = "validate",
) -> tuple[float | None, ConfusionMatrix]:
    """Mean loss and the confusion matrix over ``loader``, summed over all processes
    (``progress``: a step per batch, as ``task``). The loss is None when no batch had a
    labelled pixel (it is undefined, never NaN)."""
    model.eval()
    matrix = ConfusionMatrix(num_classes, ignore_index=ignore_index)
    total = torch.zeros(2, dtype=torch.float64, device=opts.device)
    for images, masks in _batches(loader, opts, task, progress):
        images, masks = opts.to_device(images, masks)
        with opts.autocast():
            logits = model(images)
            loss = criterion(logits, masks)
        if torch.isfinite(loss):  # a batch of only ignored pixels has no loss
            total += torch.tensor([loss.item(), 1.0], dtype=torch.float64, device=opts.device)
        if ignore_index is not None and num_classes > 1:  # never trained, so never predicted (as in infer)
            logits[:, ignore_index] = float("-inf")
        matrix.update(masks.flatten(), logits.argmax(1).flatten())
    all_reduce_sum(total)
    matrix.reduce_from_all_processes()
    return (float(total[0] / total[1]) if total[1] else None), matrix
