"""The two loops, as in torchvision's segmentation references: one epoch of training, one evaluation.

Both run unchanged on the CPU, one GPU (with AMP and channels_last) or under DDP: the caller
passes the device, whether to use AMP, and a model that may be wrapped in
``DistributedDataParallel``; losses are averaged and confusion matrices summed over processes.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Sized
from dataclasses import dataclass

import torch
from torch import nn

from osmseg.progress import Progress, track

from training.distributed import all_reduce_sum
from training.metrics import ConfusionMatrix


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


def _batches(loader: Iterable, opts: StepOptions, task: str, progress: Progress | None) -> Iterable:
    total = len(loader) if isinstance(loader, Sized) else None
    if opts.max_steps is not None and total is not None:
        total = min(total, opts.max_steps)
    batches = itertools.islice(loader, opts.max_steps) if opts.max_steps is not None else loader
    yield from track(batches, progress, task, total, unit="batch")


def train_one_epoch(
    model: nn.Module,
    criterion: nn.Module,
    optimizer: torch.optim.Optimizer,
    scheduler: torch.optim.lr_scheduler.LRScheduler,
    scaler: torch.amp.GradScaler,
    loader: Iterable,
    opts: StepOptions,
    epoch: int,
    on_step: Callable[[int, float], None] | None = None,
    progress: Progress | None = None,
) -> float:
    """Train for one epoch; returns the mean training loss over all processes.

    The scheduler steps once per batch (poly decay is defined per iteration). ``on_step(step,
    loss)`` after each batch; ``progress`` gets a step per batch (task ``epoch N train``).
    """
    model.train()
    total = torch.zeros(2, dtype=torch.float64, device=opts.device)  # loss sum, batches
    for step, (images, masks) in enumerate(_batches(loader, opts, f"epoch {epoch} train", progress)):
        images, masks = opts.to_device(images, masks)
        with opts.autocast():
            loss = criterion(model(images), masks)
        optimizer.zero_grad(set_to_none=True)
        scaler.scale(loss).backward()
        scaler.step(optimizer)
        scaler.update()
        scheduler.step()
        total += torch.tensor([loss.item(), 1.0], dtype=torch.float64, device=opts.device)
        if on_step is not None:
            on_step(step, loss.item())
    all_reduce_sum(total)
    return float(total[0] / total[1]) if total[1] else float("nan")


@torch.inference_mode()
def evaluate(
    model: nn.Module,
    criterion: nn.Module,
    loader: Iterable,
    opts: StepOptions,
    num_classes: int,
    ignore_index: int | None,
    progress: Progress | None = None,
    task: str = "validate",
) -> tuple[float, ConfusionMatrix]:
    """Mean loss and the confusion matrix over ``loader``, summed over all processes
    (``progress``: a step per batch, as ``task``)."""
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
    return (float(total[0] / total[1]) if total[1] else float("nan")), matrix
