"""``osmseg train``: train AirSegNet6/13 (SegNet) on a dataset folder.

Runs the same code on a CPU, a GPU, or several under ``torchrun --nproc-per-node N -m osmseg
train ...``. Settings come from defaults < ``--config FILE`` (YAML/TOML) < options.
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from osmseg.cli.common import report_errors, require_torch


@click.command("train")
@click.argument("dataset", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Run folder: checkpoints, log.csv, curves.png, splits.json (rerun to resume).")
@click.option("--config", "config_file",
              help="YAML or TOML file of settings, or a shipped one by name (cpu.yaml, gpu.yaml); options override it.")
@click.option("--model", help="airsegnet6 | airsegnet13 (default airsegnet13; the class table decides the outputs).")
@click.option("--classes", help="Class table TOML when the dataset has no manifest.json (e.g. classes6.toml).")
@click.option("--width", type=float, help="Channel multiplier: 1.0 is the paper's SegNet; 0.125 trains on a CPU.")
@click.option("--init", help="Encoder start: random (default, as the dissertation) | imagenet (downloads) | PATH.pth")
@click.option("--epochs", type=int)
@click.option("--batch-size", type=int)
@click.option("--lr", type=float, help="Initial learning rate (default 0.1, poly decay).")
@click.option("--keep-unlabeled/--ignore-unlabeled", "keep_unlabeled", default=None,
              help="Train 'unlabeled' as a class instead of ignoring it (default: ignored).")
@click.option("--split-by", type=click.Choice(["groups", "image"]),
              help="groups (default): samples that overlap on the ground stay in one split; image: each image alone.")
@click.option("--seed", type=int)
@click.option("--workers", type=int, help="DataLoader worker processes.")
@click.option("--device", help="auto | cpu | cuda | cuda:N")
@click.option("--max-steps-per-epoch", type=int, help="Cap batches per epoch (smoke tests).")
@click.pass_context
@report_errors
def train_command(ctx: click.Context, dataset: Path, out_dir: Path, config_file: str | None,
                  keep_unlabeled: bool | None, **options: object) -> None:
    """Train a SegNet on DATASET (a folder made by `osmseg build`, or images/ + labels/)."""
    require_torch()
    from training.config import find_config_file, make_config
    from training.train import run

    overrides = dict(options)
    overrides["ignore_unlabeled"] = None if keep_unlabeled is None else not keep_unlabeled
    config = make_config(dataset, out_dir, find_config_file(config_file) if config_file else None, overrides)
    summary = run(config, progress=ctx.obj.get("progress", False))
    if summary.get("rank", 0) != 0:  # under torchrun only rank 0 reports, as only it writes
        return
    if summary.get("best") is not None and ctx.obj["verbosity"] >= 0:
        b = summary["best"]
        click.echo(f"best epoch {b['epoch']}: val mIoU {b['val_miou']:.4f}, val pixel accuracy "
                   f"{b['val_pixel_accuracy']:.4f}; checkpoints in {out_dir}/ (best.pt, last.pt)", err=True)
    click.echo(json.dumps({"best": str(out_dir / "best.pt"), "last": str(out_dir / "last.pt"),
                           "log": str(out_dir / "log.csv")}))
