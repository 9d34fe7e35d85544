"""The training package's commands: ``osmseg train``, ``osmseg predict`` and ``osmseg eval``.

Registered on the ``osmseg`` group as plugins (entry points ``osmseg.commands`` in
pyproject.toml, as rasterio registers ``rio`` commands), so the core package never imports
this one. Each command builds one typed, frozen request from its options
(:func:`osmseg.cli.requests.make_request`: ``PredictConfig``, :class:`EvalRequest`; train's
``TrainConfig`` through ``make_config``, which layers a ``--config`` file under the options),
calls one library function of :mod:`training` and prints. The library (and so PyTorch) is imported when a command runs,
not when the CLI starts: ``osmseg build`` works without the ``train`` extra.

``train`` runs the same code on a CPU, a GPU, or several under ``torchrun --nproc-per-node N
-m osmseg train ...``; settings come from defaults < ``--config FILE`` (YAML/TOML) < options.
``predict`` segments images of any size (PNG/JPEG/GeoTIFF); ``eval`` writes metrics and
pictures for a checkpoint on labelled images. Imports: osmseg core and training.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from osmseg.cli.common import (
    F,
    output_options,
    report_errors,
    require_torch,
    typed_options,
)
from osmseg.cli.drawers import progress_drawer
from osmseg.cli.options import CLASSES, DEVICE, OUT, SEED, declare, moved
from osmseg.cli.requests import make_request
from osmseg.errors import ConfigError
from osmseg.units import plural, ratio
from training.models.spec import ARCHS
from training.run.recipe import RECIPES

if TYPE_CHECKING:  # the library (and PyTorch) is imported when a command runs
    from osmseg.runtime.progress import Progress
    from training.evaluation.metrics import EvalMetrics


def _default(name: str) -> object:
    """The training setting ``name``'s default, which ``osmseg train --help`` shows (read from
    :class:`training.run.config.TrainConfig`, which imports no torch). Only the options typed on the
    command line override a --config file, so a default here never hides the file's value.

    >>> _default("epochs"), _default("loader_workers")
    (100, 2)
    """
    from training.run.config import FIELDS

    return FIELDS[name].default


def _recipes_default(name: str) -> str:
    """What ``--help`` shows as the default of a recipe setting: each shipped recipe's value.

    >>> _recipes_default("lr")
    "the recipe's (osmseg 0.01, paper 0.1, lite0 0.001)"
    """
    return "the recipe's (" + ", ".join(f"{r.name} {getattr(r, name)}" for r in RECIPES.values()) + ")"


CONFIG = declare("--config", dest="config_file",
                 help="YAML or TOML file of settings, or a shipped one by name (cpu.yaml, gpu.yaml); the options "
                      "below override it, and the defaults shown apply where neither sets a value.")
MODEL = declare("--model", help="airsegnet6 | airsegnet13 | a name of your own (the class table decides the outputs).")
WIDTH = declare("--width", type=float,
                help="Channel multiplier: 1.0 is the paper's SegNet; 0.125 trains on a CPU (unet-lite0: its "
                     "decoder's channels).")
ARCH = declare("--arch", type=click.Choice(list(ARCHS)),
               help="segnet-skip: SegNet whose decoder also adds each encoder stage's features (no extra weights; "
                    "learns fine detail at small widths) | segnet: as published, the dissertation's network | "
                    "unet-lite0: a U-Net decoder on EfficientNet-Lite0, whose ImageNet weights install with osmseg.")
INIT = declare("--init",
               help="First weights: auto (unet-lite0: imagenet; SegNet: random) | random (as the dissertation) | "
                    "imagenet (SegNet: torchvision's VGG16-BN, downloaded; unet-lite0: the installed "
                    "EfficientNet-Lite0 weights) or a vgg16_bn PATH.pth (the encoder, width 1.0) | an osmseg run's "
                    "best.pt/last.pt (fine-tuning at its width: the whole network, or all but the classifier when "
                    "the classes differ).")
EPOCHS = declare("--epochs", type=click.IntRange(min=1),
                 help="Passes over the training data (with random crops, an epoch is --steps-per-epoch batches).")
RECIPE = declare("--recipe", type=click.Choice(["auto", *RECIPES]),
                 help="How the network learns: auto (the --arch's own: osmseg for SegNet, lite0 for unet-lite0) | "
                      "osmseg (AdamW lr 0.01, cosine, 16 random 128x128 crops, no class weights; for small data and "
                      "CPUs) | paper (the dissertation's SegNet recipe: SGD lr 0.1 poly, median-frequency weights, "
                      "fixed 360x480 patches) | lite0 (fine-tuning: AdamW lr 0.001, warm-up, 4 crops of 256). "
                      "docs/training.md compares them.")
BATCH_SIZE = declare("--batch-size", type=click.IntRange(min=1),
                     help="Images a batch: training crops, or windows predicted at once.")
LR = declare("--lr", type=click.FloatRange(min=0, min_open=True),
             help="Peak learning rate (after the warm-up; the schedule decays it).")
CLASS_WEIGHTS = declare("--class-weights", type=click.Choice(["none", "median-frequency", "sqrt-median-frequency"]),
                        help="Loss weight of each class: none, median-frequency (the paper's) or its square root.")
CROP = declare("--crop", type=click.IntRange(min=32), help="Side of the random training crops (recipe osmseg).")
STEPS_PER_EPOCH = declare("--steps-per-epoch", type=click.IntRange(min=1),
                          help="Batches of random crops per epoch (recipe osmseg).")
BALANCED_CROPS = declare("--balanced-crops", type=click.FloatRange(0, 1),
                         help="Share of the random crops centred on a pixel of one class, drawn uniformly from the "
                              "classes the training labels hold: rare classes are seen as often as common ones "
                              "(recipe osmseg).")
ENCODER_LR = declare("--encoder-lr", type=click.FloatRange(0, 10),
                     help="The encoder's learning rate as a multiple of --lr (below 1: pretrained features change "
                          "less).")
FREEZE_BN = declare("--freeze-bn/--train-bn",
                    help="Keep the encoder's BatchNorm statistics as initialised (their scale and shift still "
                         "learn).")
EMA = declare("--ema", type=click.FloatRange(0, 1, max_open=True),
              help="Decay per step of the moving average of the weights that model.pt holds (0: the final weights).")
DICE = declare("--dice", type=click.FloatRange(min=0),
               help="Weight of a soft Dice loss added to the cross-entropy (0: none).")
CROP_SCALE = declare("--crop-scale", type=click.FloatRange(1, 4),
                     help="Zoom random crops out by a factor drawn in [1, CROP_SCALE]: crops of up to --crop x "
                          "CROP_SCALE pixels resized to --crop, so the network also sees coarser ground pixels (1: "
                          "none).")
JITTER = declare("--jitter", type=click.FloatRange(0, 1, max_open=True),
                 help="Colour jitter: brightness, contrast and saturation factors drawn in 1 +- JITTER (0: none).")
KEEP_UNLABELED = declare("--keep-unlabeled/--ignore-unlabeled", dest="keep_unlabeled",
                         help="Train 'unlabeled' as a class instead of ignoring it (labels of one other class only "
                              "always do: it is their background).")
SPLIT_BY = declare("--split-by", type=click.Choice(["groups", "image"]),
                   help="groups: samples that overlap on the ground stay in one split; image: each image alone.")
LOADER_WORKERS = declare("--loader-workers", type=click.IntRange(min=0),
                         help="DataLoader worker processes per training process (0: load in the training process).")
MAX_STEPS_PER_EPOCH = declare("--max-steps-per-epoch", type=click.IntRange(min=0),
                              help="Cap batches per epoch (smoke tests).")
OVERLAP = declare("--overlap", type=click.IntRange(min=0), help="Window overlap in pixels.")
BLOCK_SIZE = declare("--block-size", type=click.IntRange(min=256),
                     help="Large rasters are predicted block by block (same result, bounded memory).")
PAIR = declare("--pair", dest="pairs", nargs=2, multiple=True,
               type=click.Path(exists=True, dir_okay=False, path_type=Path), metavar="IMAGE LABEL",
               help="Evaluate on this image and label file instead of a dataset (repeatable).")
SPLIT = declare("--split", type=click.Choice(["test", "val", "train", "all"]),
                help="For the dataset the model was trained on: which of its recorded splits.")
MAPPING = declare("--mapping", help="Class mapping for foreign labels, e.g. inria-buildings.toml (data_manifests/).")
PANELS = declare("--panels", type=click.IntRange(min=1), help="Samples shown in panels.png.")
MODE = declare("--mode", type=click.Choice(["split-join", "rescale"]),
               help="split-join: windows of the training patch size; rescale: letterbox the whole image into one.")
JOIN = declare("--join", type=click.Choice(["blend", "crop"]),
               help="split-join: blend overlapping windows smoothly, or keep each window's centre (the "
                    "dissertation's).")
TTA = declare("--tta", is_flag=True, help="Average over flips (and 90-degree turns of square inputs).")
RESOLUTION = declare("--resolution", metavar="METRES|model",
                     help="Resample georeferenced inputs, and a dataset's images (placed by its manifest.json), to "
                          "this ground pixel size before predicting ('model': the training data's, from the "
                          "checkpoint); masks and labels stay on the input's grid.")



@click.command("train")
@output_options
@click.argument("dataset", type=click.Path(exists=True, file_okay=False, path_type=Path))
@OUT(required=True, detail=": the run's checkpoints, log.csv, curves.png, splits.json (rerun to resume).")
@CONFIG()
@MODEL(default=_default("model"))
@CLASSES(show_default="the dataset's manifest.json, else the model's",
         detail=" of the labels when the dataset has no manifest.json or classes.toml; with one, the table the "
                "model learns: the dataset's, or one mapping it (classes6.toml on 13 classes).")
@WIDTH(default=_default("width"))
@ARCH(default=_default("arch"))
@INIT(default=_default("init"))
@EPOCHS(default=_default("epochs"))
@RECIPE(default=_default("recipe"))
@BATCH_SIZE(show_default=_recipes_default("batch_size"))
@LR(show_default=_recipes_default("lr"))
@CLASS_WEIGHTS(show_default=_recipes_default("class_weights"))
@CROP(show_default=_recipes_default("crop"))
@STEPS_PER_EPOCH(show_default="cover the training pixels once, >= 50")
@BALANCED_CROPS(show_default=_recipes_default("balanced_crops"))
@ENCODER_LR(show_default=_recipes_default("encoder_lr"))
@FREEZE_BN(default=None, show_default=_recipes_default("freeze_bn"))
@EMA(show_default=_recipes_default("ema"))
@DICE(show_default=_recipes_default("dice"))
@CROP_SCALE(show_default=_recipes_default("crop_scale"))
@JITTER(show_default=_recipes_default("jitter"))
@KEEP_UNLABELED(default=not _default("ignore_unlabeled"))
@SPLIT_BY(default=_default("split_by"))
@SEED(default=_default("seed"), detail=": crops, augmentation, splits, first weights.")
@LOADER_WORKERS(default=_default("loader_workers"))
@DEVICE(default=_default("device"))
@MAX_STEPS_PER_EPOCH(show_default="no cap")
@moved("--workers", "--workers is build's (build processes): osmseg train's DataLoader processes are --loader-workers")
@click.pass_context
@report_errors
def train_command(ctx: click.Context, /, dataset: Path, out_dir: Path, config_file: str | None,
                  keep_unlabeled: bool, **options: object) -> None:
    """Train a SegNet on DATASET (a folder made by `osmseg build`, or images/ + labels/)."""
    require_torch()
    from training.run.config import find_config_file, make_config
    from training.run.train import run

    typed = typed_options(ctx)  # defaults shown in --help must not override the --config file
    overrides = {k: v for k, v in options.items() if k in typed}
    overrides["ignore_unlabeled"] = not keep_unlabeled if "keep_unlabeled" in typed else None
    config = make_config(dataset, out_dir, find_config_file(config_file) if config_file else None, overrides)

    def resuming(done: int, epochs: int) -> None:
        if ctx.obj["verbosity"] >= 0:
            click.echo(f"nothing to do: {out_dir} has trained its {plural(epochs, 'epoch')}" if done >= epochs else
                       f"resuming {out_dir} after epoch {done} of {epochs}", err=True)

    with progress_drawer(ctx.obj.get("progress")) as progress:
        summary = run(config, progress=progress, resuming=resuming)
    if summary.rank != 0:  # under torchrun only rank 0 reports, as only it writes
        return
    if summary.best is not None and ctx.obj["verbosity"] >= 0:
        b, last = summary.best, summary.last
        final = f"final epoch {last.epoch}: val mIoU {ratio(last.val_miou)}; " if last is not None else ""
        click.echo(f"{final}best epoch {b.epoch}: val mIoU {ratio(b.val_miou)} (best.pt)", err=True)
        click.echo(f"use {out_dir / 'model.pt'} (osmseg predict {out_dir} ...): {summary.choice}", err=True)
    click.echo(json.dumps({"model": str(out_dir / "model.pt"), "best": str(out_dir / "best.pt"),
                           "last": str(out_dir / "last.pt"), "log": str(out_dir / "log.csv")}))


def inference_options(func: F) -> F:
    """``--mode``, ``--join``, ``--tta``, ``--resolution`` and ``--device``: how ``predict`` and ``eval``
    run a network over an image, declared once for both (as rasterio's shared option decorators)."""
    options = [
        MODE(default="split-join", show_default=True),
        JOIN(default="blend", show_default=True),
        TTA(),
        RESOLUTION(),
        DEVICE(default="auto", show_default=True),
    ]
    for option in reversed(options):
        func = option(func)
    return func


@click.command("predict")
@output_options
@click.argument("checkpoint", type=click.Path(exists=True, path_type=Path))
@click.argument("inputs", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False, path_type=Path))
@OUT(required=True, detail=" of the masks: NAME.png (class ids) and NAME_color.png for PNG/JPEG inputs; NAME.tif "
                           "and NAME_color.tif (Cloud-Optimized GeoTIFFs, georeferenced) for GeoTIFF inputs, with "
                           "NAME.qml, the QGIS style naming the classes.")
@inference_options
@OVERLAP(show_default="a quarter of the window")
@BLOCK_SIZE(default=2048, show_default=True)
@BATCH_SIZE(default=4, show_default=True)
@click.pass_context
@report_errors
def predict_command(ctx: click.Context, /, **params: Any) -> None:
    """Write a class mask (and a colour mask) for every INPUT image."""
    require_torch()
    from training.inference.predict import PredictConfig, predict_files

    config = make_request(PredictConfig, params)  # its fields are the options'
    with progress_drawer(ctx.obj.get("progress")) as progress:
        masks = predict_files(config, progress)
    for mask in masks:
        click.echo(str(mask))


@click.command("eval")
@output_options
@click.argument("checkpoint", type=click.Path(exists=True, path_type=Path))
@click.argument("dataset", required=False, type=click.Path(exists=True, file_okay=False, path_type=Path))
@PAIR()
@SPLIT(default="test", show_default=True)
@MAPPING()
@inference_options
@OUT(required=True, detail=" of metrics.json, metrics.txt and the pictures.")
@PANELS(default=4, show_default=True)
@click.pass_context
@report_errors
def eval_command(ctx: click.Context, /, **params: Any) -> None:
    """Evaluate CHECKPOINT on DATASET (its test split when it is the training dataset)."""
    request = make_request(EvalRequest, params)
    with progress_drawer(ctx.obj.get("progress")) as progress:
        metrics = request.run(progress)
    if ctx.obj["verbosity"] >= 0:
        from training.evaluation.metrics import format_table

        click.echo(format_table(metrics), err=True)
        pictures = sorted(p.name for p in request.out_dir.glob("*.png"))
        click.echo(f"pictures in {request.out_dir}/: {', '.join(pictures)}", err=True)
    click.echo(str(request.out_dir / "metrics.json"))


@dataclass(frozen=True)
class EvalRequest:
    """What ``osmseg eval`` was asked: a checkpoint (or run folder), the labelled images (a dataset
    or ``--pair``s), how to predict them and where the metrics go. :meth:`run` is the one library call."""

    checkpoint: Path
    dataset: Path | None
    pairs: tuple[tuple[Path, Path], ...]
    split: str
    mapping: str | None
    mode: str
    join: str
    resolution: str | None
    tta: bool
    out_dir: Path
    panels: int
    device: str

    def run(self, progress: Progress | None = None) -> EvalMetrics:
        """Predict the images, write metrics.json, metrics.txt and the pictures into ``out_dir``."""
        if (self.dataset is None) == (not self.pairs):
            raise ConfigError("give a DATASET folder or --pair IMAGE LABEL (one of the two), e.g. "
                              "osmseg eval run/best.pt data/berlin --out eval/")
        require_torch()
        from training.evaluation.evaluate import EvalOptions, run_eval

        opts = EvalOptions(mode=self.mode, join=self.join, tta=self.tta, split=self.split, mapping=self.mapping,
                           panels=self.panels, device=self.device, resolution_m=self.resolution)
        return run_eval(self.checkpoint, self.dataset, self.out_dir, opts, self.pairs, progress)
