"""``osmseg train``: the whole training run (torchvision-references style ``main``).

Reads the dataset, splits it by image (``splits.json``), trains with validation every epoch,
and writes into the output folder, from rank 0 only:

* ``model.pt`` after every epoch: the checkpoint to use (``osmseg predict RUN`` takes it),
  the final weights, averaged over the last steps when the recipe keeps a moving average
  (``ema``; :func:`choice_note` says why not the best epoch);
* ``last.pt`` (everything needed to resume exactly) and ``best.pt`` (best validation mIoU of the
  weights ``model.pt`` holds) — all three usable by ``osmseg predict`` / ``osmseg eval``;
* ``log.csv`` (one row per epoch), ``curves.png`` and TensorBoard events when installed.

Rerunning the same command resumes from ``last.pt``: data order and augmentations depend only
on (seed, epoch, index), so a resumed CPU run ends with the same weights as one never stopped.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import signal
import sys
import time
from collections.abc import Callable, Iterable, Mapping
from contextlib import ExitStack
from dataclasses import asdict, dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
from torch import nn
from torch.nn.parallel import DistributedDataParallel
from torch.optim.swa_utils import AveragedModel
from torch.utils.data import DataLoader, DistributedSampler

from osmseg.errors import ConfigError, DatasetError
from osmseg.output.manifest import refuse_busy
from osmseg.runtime.progress import Progress, report
from training.datasets.augment import AugmentConfig
from training.datasets.classes import run_tables
from training.datasets.patches import (
    PatchDataset,
    SampleFiles,
    dataset_fingerprint,
    dataset_resolution,
    discover_dataset,
    files_by_name,
    fitted_patch,
    validate,
    weights_from_histograms,
)
from training.datasets.sampling import RandomCrops, crop_sampler
from training.datasets.splits import (
    choose_splits,
    class_pixels,
    read_splits,
    sample_groups,
    split_warning,
    write_splits,
)
from training.devices import Dist, barrier, cleanup, setup
from training.evaluation.metrics import ConfusionMatrix, Metrics
from training.models.checkpoint import InitWeights, load_checkpoint, read_init, save_checkpoint
from training.models.networks import build_model, model_spec, unlabeled_as_background
from training.models.spec import ModelSpec
from training.run.config import TrainConfig
from training.run.engine import StepOptions, evaluate, train_one_epoch
from training.run.files import RunFiles
from training.run.fitting import SegmentationLoss, make_optimizer, make_scheduler, weight_average
from training.run.recipe import RECIPES, Recipe, steps_per_epoch

logger = logging.getLogger(__name__)

#: What :func:`run` calls when it resumes a run: with its epochs done and the epochs asked.
Resuming = Callable[[int, int], None]
#: Settings that may change between an interrupted run and its resumption.
RESUMABLE_CHANGES = {"loader_workers", "device", "tensorboard", "out_dir", "dataset"}
#: settings added since runs began to record their recipe: what the runs made before them used
SETTINGS_ADDED = {"balanced_crops": 0.0, "arch": "segnet", "encoder_lr": 1.0, "freeze_bn": False, "ema": 0.0,
                  "dice": 0.0, "crop_scale": 1.0, "jitter": 0.1}


@dataclass(frozen=True)
class EpochRow:
    """One epoch of a run: a row of its log.csv (losses None when no batch had a labelled pixel;
    the validation metrics None when the epoch had none)."""

    epoch: int
    lr: float
    train_loss: float | None
    val_loss: float | None
    val_miou: float | None
    val_pixel_accuracy: float | None
    seconds: float

    @classmethod
    def from_row(cls, row: Mapping[str, float | None]) -> EpochRow:
        """The row as the loop and the checkpoints' ``history`` keep it (a dict per epoch)."""
        def number(key: str) -> float | None:
            value = row.get(key)
            return None if value is None else float(value)

        return cls(epoch=int(row["epoch"] or 0), lr=float(row["lr"] or 0.0), train_loss=number("train_loss"),
                   val_loss=number("val_loss"), val_miou=number("val_miou"),
                   val_pixel_accuracy=number("val_pixel_accuracy"), seconds=float(row.get("seconds") or 0.0))


@dataclass(frozen=True)
class TrainResult:
    """What :func:`run` did: the run folder, every epoch's row (a resumed run's earlier ones too),
    the best epoch by validation mIoU, and this process's rank (only rank 0 writes and reports)."""

    out_dir: Path
    history: tuple[EpochRow, ...]
    best: EpochRow | None
    rank: int = 0
    choice: str = ""  # which weights model.pt holds, and why

    @property
    def epochs(self) -> int:
        return len(self.history)

    @property
    def last(self) -> EpochRow | None:
        return self.history[-1] if self.history else None


def rounded(loss: float | None, digits: int = 6) -> float | None:
    """A loss for log.csv and the log: None (an empty cell) when no batch had a labelled pixel."""
    return None if loss is None else round(loss, digits)


def seeded_loader(dataset: PatchDataset, config: TrainConfig, d: Dist, shuffle: bool) -> DataLoader[Any]:
    """A loader whose order depends only on (seed, epoch) and the number of processes.

    Random crops (:class:`~training.datasets.sampling.RandomCrops`) are taken in order, each process
    its own block: the draws are random already, and neighbours share an image. A grid of
    patches is shuffled with a DistributedSampler (which pads the last round with repeated
    items so that every process takes the same number of steps). The validation loader
    (``shuffle=False``) gives each process every ``world_size``-th item and pads nothing, so
    the metrics summed over processes count every pixel exactly once.
    """
    sampler: Any
    if isinstance(dataset, RandomCrops):
        sampler = crop_sampler(len(dataset) // d.world_size, d.rank, d.world_size)
    elif shuffle:
        sampler = DistributedSampler(dataset, num_replicas=d.world_size, rank=d.rank, shuffle=True,
                                     seed=config.seed, drop_last=False)
    else:
        sampler = list(range(d.rank, len(dataset), d.world_size))
    return DataLoader(dataset, batch_size=config.settings.batch_size, sampler=sampler, num_workers=config.loader_workers,
                      pin_memory=d.device.type == "cuda", persistent_workers=config.loader_workers > 0,
                      worker_init_fn=_loader_worker_start if config.loader_workers > 0 else None)


def stop_loader_workers(*loaders: DataLoader[Any]) -> None:
    """End the persistent workers of ``loaders`` now, however training ends.

    torch ends them when the loader's iterator is garbage: at once on a normal end, but when
    training unwinds by an exception its traceback holds the iterator, and a traceback caught in
    a reference cycle holds it until the garbage collector runs, which may be after the exit
    handler that waits for every child process. Workers that ignore SIGTERM (see
    :func:`_loader_worker_start`) would then keep the process from ever exiting.
    """
    for loader in loaders:
        iterator = getattr(loader, "_iterator", None)  # torch keeps a persistent loader's one iterator here
        shutdown = getattr(iterator, "_shutdown_workers", None)
        if callable(shutdown):
            shutdown()


def _loader_worker_start(worker_id: int) -> None:
    """A loader worker leaves stopping to the training process: a SIGTERM sent to the whole process
    group (``timeout``, Slurm, ``kill -- -PGID``) would otherwise kill it mid-batch, and torch
    would then report the dead worker with a traceback while the training process unwinds and
    says it was terminated. The training process stops its workers itself; a worker still ends
    when the training process is gone (torch watches its parent).

    And a training process stopped while it takes a batch's tensors over (their file descriptors
    go through a handshake with a thread of the worker, multiprocessing's resource sharer) drops
    that handshake: the thread reports the dropped connection through ``sys.excepthook`` with a
    traceback under the training process's one line. Here such reports are dropped; any other
    error still reaches the previous hook (a batch's own errors travel to the training process).
    """
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    sys.excepthook = _without_dropped_handovers(sys.excepthook)


def _without_dropped_handovers(previous: Callable[..., Any]) -> Callable[..., Any]:
    """``previous`` (an excepthook) that leaves out a connection the other side dropped."""
    def hook(kind: type[BaseException], value: BaseException, tb: TracebackType | None) -> None:
        if not issubclass(kind, (EOFError, ConnectionError)):
            previous(kind, value, tb)
    return hook


def binary_if_one_class(spec: ModelSpec, pixels: dict[str, np.ndarray], names: Iterable[str], d: Dist,
                        where: str) -> ModelSpec:
    """``spec`` with unlabeled as background when the labels of samples ``names`` hold one class
    besides it (:func:`training.models.networks.unlabeled_as_background`); rank 0 logs the warning."""
    total = np.zeros(spec.num_classes, dtype=np.int64)
    for name in names:
        total += pixels[name]
    spec, note = unlabeled_as_background(spec, total, where)
    if note and d.is_main:
        logger.warning("%s", note)
    return spec


def check_resumable(saved: dict[str, Any], config: TrainConfig) -> None:
    """Refuse to resume a run made with other settings (other than RESUMABLE_CHANGES)."""
    now = config.to_dict()
    then = saved.get("config", {})
    # a setting added after the run began was, for that run, its default; runs from before
    # recipes (osmseg < 0.5) learnt by the paper's
    defaults = {f.name: f.default for f in dataclasses.fields(TrainConfig) if f.default is not dataclasses.MISSING}
    if "recipe" not in then:
        defaults.update(recipe="paper", **RECIPES["paper"].to_dict())
    defaults.update((k, v) for k, v in SETTINGS_ADDED.items() if k not in then)
    changed = sorted(k for k in now if k not in RESUMABLE_CHANGES and then.get(k, defaults.get(k)) != now[k])
    if saved.get("dataset_sha256") != dataset_fingerprint(config.dataset):
        changed.append("the dataset's manifest.json")
    if changed:
        named = [f"--{k} {then.get(k, defaults.get(k))}" for k in ("recipe", "arch") if k in changed]
        hint = f" (it learnt by {' '.join(named)})" if named else ""
        raise ConfigError(f"{config.out_dir} holds a run with other settings ({', '.join(changed)}){hint}; "
                          "use a new --out, or the same settings to resume it")


def prepare_splits(config: TrainConfig, files: list[SampleFiles], d: Dist,
                   pixels: dict[str, np.ndarray] | None = None, spec: ModelSpec | None = None) -> dict[str, list[str]]:
    """The run's image splits: read back on resume, else drawn from the seed and written down.

    With ``pixels`` (per sample, by the classes of ``spec``) the draw whose validation class
    mix is closest to training's is kept, the class shares are recorded in ``splits.json``,
    and a validation that still cannot represent the training classes is reported
    (:func:`training.datasets.splits.choose_splits`)."""
    path = config.out_dir / "splits.json"
    if path.exists():
        return read_splits(path)
    names = sorted(f.name for f in files)
    images = {f.name: f.image for f in files}
    groups = sample_groups(config.dataset, names, images) if config.split_by == "groups" else None
    splits, selection = choose_splits(names, config.seed, config.test_fraction, config.val_fraction, groups=groups,
                                      pixels=pixels if spec is not None else None,
                                      class_names=spec.class_names if spec is not None else (),
                                      ignore_index=spec.ignore_index if spec is not None else None)
    if not splits["train"] or not splits["val"]:
        areas = len(set(groups.values())) if groups else len(names)
        if groups and areas < len(names):
            raise DatasetError(
                f"{config.dataset}: its {len(names)} samples overlap on the ground in {areas} separate "
                f"area{'s' if areas != 1 else ''}, too few "
                "to keep a test and a validation area apart from the training ones; build it again with osmseg build "
                "--no-overlap or a larger area, or train with --split-by image (test images then share pixels with "
                "training ones)")
        raise DatasetError(f"{config.dataset}: {len(names)} images are too few to split into train, val and test; "
                           "build more samples, or lower test_fraction and val_fraction in a --config file")
    if groups is None and d.is_main:
        logger.warning("splitting by image (--split-by image): overlapping samples may share pixels across splits")
    if d.is_main:
        if selection and pixels is not None and spec is not None:
            warning = split_warning(splits, selection, spec.ignore_index, spec.class_names, pixels)
            if warning:
                logger.warning("%s", warning)
        write_splits(path, splits, config.seed, config.split_by, groups, selection)
    return splits


def run(config: TrainConfig, progress: Progress | None = None, resuming: Resuming | None = None) -> TrainResult:
    """Train (or resume) the run ``config`` describes; returns a summary of the best epoch.

    ``progress`` gets steps from rank 0 only: epochs (task ``train``, each with its losses,
    validation mIoU and seconds as values), and each epoch's training and validation batches
    (the CLI draws them as bars on a terminal, and a line per epoch in a log). ``resuming`` is
    called once (rank 0) when the run folder holds a run with the same settings, before it goes
    on: with its epochs done and ``config.epochs`` (equal: nothing is left to train).
    """
    d = setup(config.device)
    try:
        with ExitStack() as teardown:
            return _run(config, d, teardown, progress, resuming)
    finally:
        cleanup()


def datasets(config: TrainConfig, d: Dist, spec: ModelSpec, files: list[SampleFiles], train_files: list[SampleFiles],
             val_files: list[SampleFiles], histograms: np.ndarray, pixels: dict[str, np.ndarray], num_classes: int,
             label_lut: np.ndarray | None) -> tuple[PatchDataset, PatchDataset, np.ndarray]:
    """``(training set, validation set, the training files' pixels per model class)``: random crops or
    patches of ``config.patch_size`` by the recipe, validation in whole patches."""
    patches = functools.partial(PatchDataset, mean=spec.mean, std=spec.std, ignore_index=spec.ignore_index,
                                seed=config.seed, num_classes=num_classes, label_lut=label_lut)
    recipe = config.settings
    index = {f.name: i for i, f in enumerate(files)}
    train_pixels = int(histograms[[index[f.name] for f in train_files]].sum())
    train_class_pixels = np.stack([pixels[f.name] for f in train_files])  # (files, model classes)
    train_set: PatchDataset
    augment = AugmentConfig.overhead(recipe.jitter, recipe.crop_scale) if config.augment else False
    if recipe.sampling == "random":
        per_process = steps_per_epoch(recipe, train_pixels, d.world_size) * recipe.batch_size
        train_set = RandomCrops(train_files, recipe.crop, per_process * d.world_size, mean=spec.mean, std=spec.std,
                                ignore_index=spec.ignore_index, seed=config.seed, augment=augment,
                                num_classes=num_classes, label_lut=label_lut,
                                balance=recipe.balanced_crops, class_pixels=train_class_pixels)
    else:
        train_set = patches(train_files, config.patch_size, augment=augment)
    val_set = patches(val_files, fitted_patch(config.patch_size, val_files), augment=False)  # 256-px tiles too
    if len(train_set) == 0:
        raise DatasetError(f"{config.dataset}: no training patches of {config.patch_size}; are the images smaller?")
    return train_set, val_set, train_class_pixels


def class_weights(recipe: Recipe, train_class_pixels: np.ndarray, spec: ModelSpec) -> torch.Tensor | None:
    """The loss's class weights from the training split's pixels by model id (None: ``class_weights = "none"``)."""
    if recipe.class_weights == "none":
        return None
    weights = weights_from_histograms(train_class_pixels, spec.ignore_index)  # by model id
    if recipe.class_weights == "sqrt-median-frequency":  # the same order, a square root of the spread
        weights = weights.sqrt()
    return weights


def placed_model(spec: ModelSpec, init: InitWeights | None, config: TrainConfig, d: Dist
                 ) -> tuple[nn.Module, nn.Module, StepOptions]:
    """``(model, what trains it, step options)``: the model built, initialised and on its device (channels
    last and AMP on CUDA when asked), wrapped in DistributedDataParallel across processes."""
    model = build_model(spec)
    if init is not None:
        init.apply(model)
    opts = StepOptions(device=d.device, amp=config.amp and d.device.type == "cuda",
                       channels_last=config.channels_last and d.device.type == "cuda",
                       max_steps=config.max_steps_per_epoch)
    model.to(d.device)
    if opts.channels_last:
        model.to(memory_format=torch.channels_last)
    net: nn.Module = model
    if d.distributed:
        net = DistributedDataParallel(model, device_ids=[d.device.index] if d.device.type == "cuda" else None)
    return model, net, opts


def resumed(saved: dict[str, Any] | None, model: nn.Module, optimizer: Any, scheduler: Any, scaler: Any,
            average: AveragedModel | None = None) -> tuple[list[dict[str, Any]], float, int]:
    """``(history, best val mIoU, epochs done)`` of a saved run, its states loaded; nothing done for a new one."""
    if saved is None:
        return [], -math.inf, 0
    model.load_state_dict(saved["model"])
    optimizer.load_state_dict(saved["optimizer"])
    scheduler.load_state_dict(saved["scheduler"])
    scaler.load_state_dict(saved["scaler"])
    if average is not None:
        average.load_state_dict(saved["average"])
    history = list(saved["history"])
    best = max((h["val_miou"] for h in history if h.get("val_miou") is not None), default=-math.inf)
    return history, best, int(saved["epoch"])


def run_record(spec: ModelSpec, config: TrainConfig, splits: dict[str, list[str]], weights: torch.Tensor | None,
               saved: dict[str, Any] | None, init: InitWeights | None) -> dict[str, Any]:
    """What every checkpoint of a run holds besides its states: the model, settings, splits, class
    weights, the dataset's fingerprint and the initial weights' origin (a resumed run's own)."""
    return {
        "spec": asdict(spec), "config": config.to_dict(), "splits": splits,
        "class_weights": None if weights is None else weights.cpu(),
        "dataset_sha256": dataset_fingerprint(config.dataset),
        "init": saved.get("init") if saved is not None else (init.record if init is not None else None),
    }


def validated(model: nn.Module, criterion: nn.Module, val_loader: DataLoader[Any], opts: StepOptions,
              spec: ModelSpec, d: Dist, shown: Progress | None, epoch: int
              ) -> tuple[float | None, ConfusionMatrix]:
    """``(validation loss, confusion matrix)`` after ``epoch`` (from 0), in every process alike."""
    if d.distributed:  # every process validates with rank 0's BN statistics (those saved below)
        for buffer in model.buffers():
            dist.broadcast(buffer, src=0)
    # The plain module, not the DDP wrapper: its first forward after training would sync
    # buffers (a collective), but processes may hold different numbers of val batches.
    return evaluate(model, criterion, val_loader, opts, spec.num_classes, spec.ignore_index,
                    progress=shown, task=f"epoch {epoch + 1} validate")


def save_epoch(files_out: RunFiles, state: dict[str, Any], chosen: dict[str, Any], history: list[dict[str, Any]],
               metrics: Metrics, best: float) -> float:
    """An epoch's files: best.pt when its mIoU beats ``best``, model.pt, log.csv, then last.pt;
    returns the new best. ``state`` is everything a resumption needs; ``chosen`` the weights the
    run hands on (the moving average when the recipe keeps one, else the model's)."""
    handed = {k: v for k, v in state.items() if k not in ("optimizer", "scheduler", "scaler", "average")}
    handed["model"] = chosen
    if metrics["miou"] is not None and metrics["miou"] > best:
        best = metrics["miou"]
        save_checkpoint(files_out.best, handed)
    save_checkpoint(files_out.model, handed)
    files_out.write_log(history)
    # last.pt is the commit point of an epoch, written after the others: a run killed in
    # between redoes the epoch on resume and rewrites them all.
    save_checkpoint(files_out.last, state)
    return best


def training_states(model: nn.Module, optimizer: Any, scheduler: Any, scaler: Any, average: AveragedModel | None
                    ) -> dict[str, Any]:
    """The states a resumption loads (:func:`resumed`): weights, optimiser, schedule, scaler, the average."""
    states = {"model": model.state_dict(), "optimizer": optimizer.state_dict(), "scheduler": scheduler.state_dict(),
              "scaler": scaler.state_dict()}
    if average is not None:
        states["average"] = average.state_dict()
    return states


def choice_note(recipe: Recipe) -> str:
    """Which weights ``model.pt`` holds, and why (recorded in every checkpoint, said by ``osmseg train``)."""
    if recipe.ema:
        return (f"model.pt holds the final weights averaged over the last ~{round(1 / (1 - recipe.ema))} steps "
                f"(ema {recipe.ema:g}): an average smooths the noise of the last steps without asking a small "
                "validation split to choose an epoch")
    return ("model.pt holds the final weights, the learning rate annealed: the epoch a small validation split calls "
            "best (best.pt) is mostly noise, and on held-out imagery a moving average of the weights did no better")


def _run(config: TrainConfig, d: Dist, teardown: ExitStack, progress: Progress | None = None,
         resuming: Resuming | None = None) -> TrainResult:
    torch.manual_seed(config.seed)  # the same initial weights in every process
    refuse_busy(config.dataset)  # a folder a build is writing: its first build has no manifest to say so
    dataset_table, model_table, label_lut = run_tables(config.dataset, config.classes, config.model)
    files, given_splits = discover_dataset(config.dataset)
    spec: ModelSpec = model_spec(config.model, config.width, ignore_unlabeled=config.ignore_unlabeled,
                                 class_table=model_table, input_size=config.patch_size,
                                 resolution_m=dataset_resolution(config.dataset, files), arch=config.arch)
    histograms = validate(files, dataset_table.num_classes)  # raw ids of every label, checked up front
    pixels = class_pixels(histograms, [f.name for f in files], spec.num_classes, label_lut)  # by model id
    spec = binary_if_one_class(spec, pixels, list(pixels), d, "the labels")
    last_path = config.out_dir / "last.pt"
    saved = load_checkpoint(last_path, map_location=d.device) if last_path.exists() else None
    if saved is not None:
        check_resumable(saved, config)  # before anything is written into someone else's run
        if resuming is not None and d.is_main:  # said before the data are loaded, which takes a while
            resuming(int(saved["epoch"]), config.epochs)
    init = read_init(config.init_source, spec) if saved is None else None  # a bad --init: refused before any output
    if d.is_main:  # only now: bad input above leaves no output folder behind
        config.out_dir.mkdir(parents=True, exist_ok=True)
        for litter in config.out_dir.glob(".*.tmp"):  # a checkpoint save cut short by a kill
            litter.unlink(missing_ok=True)
    barrier()
    splits = given_splits or prepare_splits(config, list(files), d, pixels, spec)
    spec = binary_if_one_class(spec, pixels, splits["train"], d, "the training split's labels")
    train_files = files_by_name(files, splits["train"])
    val_files = files_by_name(files, splits["val"])
    recipe = config.settings
    train_set, val_set, train_class_pixels = datasets(config, d, spec, files, train_files, val_files, histograms,
                                                      pixels, dataset_table.num_classes, label_lut)

    weights = class_weights(recipe, train_class_pixels, spec)
    model, net, opts = placed_model(spec, init, config, d)
    shown = progress if d.is_main else None  # one process reports
    criterion = SegmentationLoss(weight=None if weights is None else weights.to(d.device),
                                 ignore_index=-100 if spec.ignore_index is None else spec.ignore_index, dice=recipe.dice)
    optimizer = make_optimizer(model, recipe)
    train_loader = seeded_loader(train_set, config, d, shuffle=True)
    val_loader = seeded_loader(val_set, config, d, shuffle=False)
    teardown.callback(stop_loader_workers, train_loader, val_loader)  # however the run ends: see there
    steps = len(train_loader) if config.max_steps_per_epoch is None else min(len(train_loader), config.max_steps_per_epoch)
    scheduler = make_scheduler(optimizer, recipe, config.epochs * steps)
    scaler = torch.amp.GradScaler(d.device.type, enabled=opts.amp)

    files_out = RunFiles(config.out_dir, d, config.tensorboard)
    average = weight_average(model, recipe.ema)  # what model.pt holds (None: the model's own weights)
    history, best, start = resumed(saved, model, optimizer, scheduler, scaler, average)
    handed = model if average is None else average.module  # validated, and written to best.pt and model.pt
    base_state = run_record(spec, config, splits, weights, saved, init)
    report(shown, "train", start, config.epochs, "epoch")
    for epoch in range(start, config.epochs):
        began = time.monotonic()
        train_set.set_epoch(epoch)
        if isinstance(train_loader.sampler, DistributedSampler):
            train_loader.sampler.set_epoch(epoch)
        lr = optimizer.param_groups[0]["lr"]
        train_loss = train_one_epoch(net, criterion, optimizer, scheduler, scaler, train_loader, opts, epoch + 1,
                                     progress=shown, freeze_bn=recipe.freeze_bn,
                                     after_step=None if average is None else lambda: average.update_parameters(model))
        val_loss, matrix = validated(handed, criterion, val_loader, opts, spec, d, shown, epoch)
        metrics = matrix.compute(spec.class_names)  # by id, never by list position
        row = {"epoch": epoch + 1, "lr": lr, "train_loss": rounded(train_loss), "val_loss": rounded(val_loss),
               "val_miou": metrics["miou"], "val_pixel_accuracy": metrics["pixel_accuracy"],
               "seconds": round(time.monotonic() - began, 2)}
        history.append(row)
        report(shown, "train", epoch + 1, config.epochs, "epoch", {"train loss": row["train_loss"], "val loss":
               row["val_loss"], "val mIoU": row["val_miou"], "epoch seconds": row["seconds"]})
        if d.is_main:
            state = dict(base_state, **training_states(model, optimizer, scheduler, scaler, average), epoch=epoch + 1,
                         history=history, val_metrics=metrics, checkpoint_choice=choice_note(recipe))
            best = save_epoch(files_out, state, handed.state_dict(), history, metrics, best)
            logger.info("epoch %d/%d: train loss %s, val loss %s, val mIoU %s", epoch + 1, config.epochs,
                        rounded(train_loss, 4), rounded(val_loss, 4), metrics["miou"])
        barrier()
    files_out.close()
    rows = tuple(EpochRow.from_row(h) for h in history)
    best_row = max((h for h in rows if h.val_miou is not None), key=lambda h: h.val_miou or 0.0, default=None)
    return TrainResult(out_dir=config.out_dir, history=rows, best=best_row, rank=d.rank, choice=choice_note(recipe))
