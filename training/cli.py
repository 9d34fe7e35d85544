"""The training package's commands: ``osmseg train``, ``osmseg predict`` and ``osmseg eval``.

Registered on the ``osmseg`` group as plugins (entry points ``osmseg.commands`` in
pyproject.toml, as rasterio registers ``rio`` commands), so the core package never imports
this one. Each command parses options, builds a config, calls one library function of
:mod:`training` and prints. The library (and so PyTorch) is imported when a command runs,
not when the CLI starts: ``osmseg build`` works without the ``train`` extra.

``train`` runs the same code on a CPU, a GPU, or several under ``torchrun --nproc-per-node N
-m osmseg train ...``; settings come from defaults < ``--config FILE`` (YAML/TOML) < options.
``predict`` segments images of any size (PNG/JPEG/GeoTIFF); ``eval`` writes metrics and
pictures for a checkpoint on labelled images. Imports: osmseg core and training.
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from osmseg.cli.common import (
    F,
    output_options,
    renamed_option,
    report_errors,
    require_torch,
    typed_options,
)
from osmseg.cli.drawers import progress_drawer
from osmseg.errors import ConfigError
from osmseg.units import plural, ratio
from training.recipe import RECIPES
from training.spec import ARCHS


def _default(name: str) -> object:
    """The training setting ``name``'s default, which ``osmseg train --help`` shows (read from
    :class:`training.config.TrainConfig`, which imports no torch). Only the options typed on the
    command line override a --config file, so a default here never hides the file's value.

    >>> _default("epochs"), _default("loader_workers")
    (100, 2)
    """
    from training.config import FIELDS

    return FIELDS[name].default


def _recipes_default(name: str) -> str:
    """What ``--help`` shows as the default of a recipe setting: each shipped recipe's value.

    >>> _recipes_default("lr")
    "the recipe's (osmseg 0.01, paper 0.1, lite0 0.001)"
    """
    return "the recipe's (" + ", ".join(f"{r.name} {getattr(r, name)}" for r in RECIPES.values()) + ")"


@click.command("train")
@output_options
@click.argument("dataset", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Run folder: checkpoints, log.csv, curves.png, splits.json (rerun to resume).")
@click.option("--config", "config_file",
              help="YAML or TOML file of settings, or a shipped one by name (cpu.yaml, gpu.yaml); the options "
                   "below override it, and the defaults shown apply where neither sets a value.")
@click.option("--model", default=_default("model"),
              help="airsegnet6 | airsegnet13 | a name of your own (the class table decides the outputs).")
@click.option("--classes", show_default="the dataset's manifest.json, else the model's",
              help="Class table TOML of the labels when the dataset has no manifest.json or classes.toml; with one, "
                   "the table the model learns: the dataset's, or one mapping it (classes6.toml on 13 classes).")
@click.option("--width", type=float, default=_default("width"),
              help="Channel multiplier: 1.0 is the paper's SegNet; 0.125 trains on a CPU (unet-lite0: its "
                   "decoder's channels).")
@click.option("--arch", type=click.Choice(list(ARCHS)), default=_default("arch"),
              help="segnet-skip: SegNet whose decoder also adds each encoder stage's features (no extra weights; "
                   "learns fine detail at small widths) | segnet: as published, the dissertation's network | "
                   "unet-lite0: a U-Net decoder on EfficientNet-Lite0, whose ImageNet weights install with osmseg.")
@click.option("--init", default=_default("init"),
              help="First weights: auto (unet-lite0: imagenet; SegNet: random) | random (as the dissertation) | imagenet (SegNet: torchvision's VGG16-BN, "
                   "downloaded; unet-lite0: the installed EfficientNet-Lite0 weights) or a vgg16_bn PATH.pth "
                   "(the encoder, width 1.0) | an osmseg run's best.pt/last.pt (fine-tuning at its width: the whole "
                   "network, or all but the classifier when the classes differ).")
@click.option("--epochs", type=click.IntRange(min=1), default=_default("epochs"))
@click.option("--recipe", type=click.Choice(["auto", *RECIPES]), default=_default("recipe"),
              help="How the network learns: auto (the --arch's own: osmseg for SegNet, lite0 for unet-lite0) | osmseg "
                   "(AdamW lr 0.01, cosine, 16 random 128x128 crops, no class weights; for small data and CPUs) | paper "
                   "(the dissertation's SegNet recipe: SGD lr 0.1 poly, median-frequency weights, fixed 360x480 "
                   "patches) | lite0 (fine-tuning: AdamW lr 0.001, warm-up, 4 crops of 256). "
                   "docs/training.md compares them.")
@click.option("--batch-size", type=click.IntRange(min=1), show_default=_recipes_default("batch_size"))
@click.option("--lr", type=click.FloatRange(min=0, min_open=True), show_default=_recipes_default("lr"),
              help="Peak learning rate (after the warm-up; the schedule decays it).")
@click.option("--class-weights", type=click.Choice(["none", "median-frequency", "sqrt-median-frequency"]),
              show_default=_recipes_default("class_weights"))
@click.option("--crop", type=click.IntRange(min=32), show_default=_recipes_default("crop"),
              help="Side of the random training crops (recipe osmseg).")
@click.option("--steps-per-epoch", type=click.IntRange(min=1), show_default="cover the training pixels once, >= 50",
              help="Batches of random crops per epoch (recipe osmseg).")
@click.option("--balanced-crops", type=click.FloatRange(0, 1), show_default=_recipes_default("balanced_crops"),
              help="Share of the random crops centred on a pixel of one class, drawn uniformly from the classes the "
                   "training labels hold: rare classes are seen as often as common ones (recipe osmseg).")
@click.option("--encoder-lr", type=click.FloatRange(0, 10), show_default=_recipes_default("encoder_lr"),
              help="The encoder's learning rate as a multiple of --lr (below 1: pretrained features change less).")
@click.option("--freeze-bn/--train-bn", "freeze_bn", default=None, show_default=_recipes_default("freeze_bn"),
              help="Keep the encoder's BatchNorm statistics as initialised (their scale and shift still learn).")
@click.option("--ema", type=click.FloatRange(0, 1, max_open=True), show_default=_recipes_default("ema"),
              help="Decay per step of the moving average of the weights that model.pt holds (0: the final weights).")
@click.option("--dice", type=click.FloatRange(min=0), show_default=_recipes_default("dice"),
              help="Weight of a soft Dice loss added to the cross-entropy (0: none).")
@click.option("--crop-scale", type=click.FloatRange(1, 4), show_default=_recipes_default("crop_scale"),
              help="Zoom random crops out by a factor drawn in [1, CROP_SCALE]: crops of up to --crop x CROP_SCALE "
                   "pixels resized to --crop, so the network also sees coarser ground pixels (1: none).")
@click.option("--jitter", type=click.FloatRange(0, 1, max_open=True), show_default=_recipes_default("jitter"),
              help="Colour jitter: brightness, contrast and saturation factors drawn in 1 +- JITTER (0: none).")
@click.option("--keep-unlabeled/--ignore-unlabeled", "keep_unlabeled", default=not _default("ignore_unlabeled"),
              help="Train 'unlabeled' as a class instead of ignoring it (labels of one other class only always "
                   "do: it is their background).")
@click.option("--split-by", type=click.Choice(["groups", "image"]), default=_default("split_by"),
              help="groups: samples that overlap on the ground stay in one split; image: each image alone.")
@click.option("--seed", type=click.IntRange(min=0), default=_default("seed"))
@click.option("--loader-workers", type=click.IntRange(min=0), default=_default("loader_workers"),
              help="DataLoader worker processes per training process (0: load in the training process).")
@click.option("--device", default=_default("device"), help="auto | cpu | cuda | cuda:N")
@click.option("--max-steps-per-epoch", type=click.IntRange(min=0), show_default="no cap", help="Cap batches per epoch (smoke tests).")
@renamed_option("--workers", "loader_workers", type=click.IntRange(min=0),
                note=" (DataLoader processes; build's --workers counts build processes)")
@click.pass_context
@report_errors
def train_command(ctx: click.Context, /, dataset: Path, out_dir: Path, config_file: str | None,
                  keep_unlabeled: bool, **options: object) -> None:
    """Train a SegNet on DATASET (a folder made by `osmseg build`, or images/ + labels/)."""
    require_torch()
    from training.config import find_config_file, make_config
    from training.train import run

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
        final = f"final epoch {last['epoch']}: val mIoU {ratio(last['val_miou'])}; " if last is not None else ""
        click.echo(f"{final}best epoch {b['epoch']}: val mIoU {ratio(b['val_miou'])} (best.pt)", err=True)
        click.echo(f"use {out_dir / 'model.pt'} (osmseg predict {out_dir} ...): {summary.choice}", err=True)
    click.echo(json.dumps({"model": str(out_dir / "model.pt"), "best": str(out_dir / "best.pt"),
                           "last": str(out_dir / "last.pt"), "log": str(out_dir / "log.csv")}))


def inference_options(func: F) -> F:
    """``--mode``, ``--join``, ``--tta``, ``--resolution`` and ``--device``: how ``predict`` and ``eval``
    run a network over an image, declared once for both (as rasterio's shared option decorators)."""
    options = [
        click.option("--mode", type=click.Choice(["split-join", "rescale"]), default="split-join", show_default=True,
                     help="split-join: windows of the training patch size; rescale: letterbox the whole image into "
                          "one."),
        click.option("--join", type=click.Choice(["blend", "crop"]), default="blend", show_default=True,
                     help="split-join: blend overlapping windows smoothly, or keep each window's centre (the "
                          "dissertation's)."),
        click.option("--tta", is_flag=True, help="Average over flips (and 90-degree turns of square inputs)."),
        click.option("--resolution", metavar="METRES|model",
                     help="Resample georeferenced inputs, and a dataset's images (placed by its manifest.json), to "
                          "this ground pixel size before predicting ('model': the training data's, from the "
                          "checkpoint); masks and labels stay on the input's grid."),
        click.option("--device", default="auto", show_default=True,
                     help="auto (a GPU when there is one) | cpu | cuda | cuda:N"),
    ]
    for option in reversed(options):
        func = option(func)
    return func


@click.command("predict")
@output_options
@click.argument("checkpoint", type=click.Path(exists=True, path_type=Path))
@click.argument("inputs", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Folder for the masks: NAME.png (class ids) and NAME_color.png for PNG/JPEG inputs; "
                   "NAME.tif and NAME_color.tif (Cloud-Optimized GeoTIFFs, georeferenced) for GeoTIFF inputs, with "
                   "NAME.qml, the QGIS style naming the classes.")
@inference_options
@click.option("--overlap", type=click.IntRange(min=0), show_default="a quarter of the window",
              help="Window overlap in pixels.")
@click.option("--block-size", type=click.IntRange(min=256), default=2048, show_default=True,
              help="Large rasters are predicted block by block (same result, bounded memory).")
@click.option("--batch-size", type=click.IntRange(min=1), default=4, show_default=True)
@click.pass_context
@report_errors
def predict_command(ctx: click.Context, checkpoint: Path, inputs: tuple[Path, ...], out_dir: Path, mode: str,
                    join: str, overlap: int | None, block_size: int, tta: bool, resolution: str | None,
                    batch_size: int, device: str) -> None:
    """Write a class mask (and a colour mask) for every INPUT image."""
    require_torch()
    from training.predict import PredictConfig, predict_files

    config = PredictConfig(checkpoint, inputs, out_dir, mode=mode, join=join, overlap=overlap, block_size=block_size,
                           tta=tta, resolution=resolution, batch_size=batch_size, device=device)
    with progress_drawer(ctx.obj.get("progress")) as progress:
        masks = predict_files(config, progress)
    for mask in masks:
        click.echo(str(mask))


@click.command("eval")
@output_options
@click.argument("checkpoint", type=click.Path(exists=True, path_type=Path))
@click.argument("dataset", required=False, type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--pair", "pairs", nargs=2, multiple=True, type=click.Path(exists=True, dir_okay=False, path_type=Path),
              metavar="IMAGE LABEL", help="Evaluate on this image and label file instead of a dataset (repeatable).")
@click.option("--split", type=click.Choice(["test", "val", "train", "all"]), default="test", show_default=True,
              help="For the dataset the model was trained on: which of its recorded splits.")
@click.option("--mapping", help="Class mapping for foreign labels, e.g. inria-buildings.toml (data_manifests/).")
@inference_options
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Folder for metrics.json, metrics.txt and the pictures.")
@click.option("--panels", type=click.IntRange(min=1), default=4, show_default=True, help="Samples shown in panels.png.")
@click.pass_context
@report_errors
def eval_command(ctx: click.Context, checkpoint: Path, dataset: Path | None, pairs: tuple[tuple[Path, Path], ...],
                 split: str, mapping: str | None, mode: str, join: str, resolution: str | None, tta: bool,
                 out_dir: Path, panels: int, device: str) -> None:
    """Evaluate CHECKPOINT on DATASET (its test split when it is the training dataset)."""
    if (dataset is None) == (not pairs):
        raise ConfigError("give a DATASET folder or --pair IMAGE LABEL (one of the two), e.g. "
                          "osmseg eval run/best.pt data/berlin --out eval/")
    require_torch()
    from training.evaluate import EvalOptions, run_eval
    from training.metrics import format_table

    opts = EvalOptions(mode=mode, join=join, tta=tta, split=split, mapping=mapping, panels=panels, device=device,
                       resolution_m=resolution)
    with progress_drawer(ctx.obj.get("progress")) as progress:
        metrics = run_eval(checkpoint, dataset, out_dir, opts, pairs, progress)
    if ctx.obj["verbosity"] >= 0:
        click.echo(format_table(metrics), err=True)
        pictures = sorted(p.name for p in out_dir.glob("*.png"))
        click.echo(f"pictures in {out_dir}/: {', '.join(pictures)}", err=True)
    click.echo(str(out_dir / "metrics.json"))
