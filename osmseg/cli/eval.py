"""``osmseg eval``: metrics and pictures for a checkpoint on labelled images."""

from __future__ import annotations

from pathlib import Path

import click

from osmseg.cli.common import report_errors, require_torch
from osmseg.errors import ConfigError


@click.command("eval")
@click.argument("checkpoint", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.argument("dataset", required=False, type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--pair", "pairs", nargs=2, multiple=True, type=click.Path(exists=True, dir_okay=False, path_type=Path),
              metavar="IMAGE LABEL", help="Evaluate on this image and label file instead of a dataset (repeatable).")
@click.option("--split", type=click.Choice(["test", "val", "train", "all"]), default="test", show_default=True,
              help="For the dataset the model was trained on: which of its recorded splits.")
@click.option("--mapping", help="Class mapping for foreign labels, e.g. inria-buildings.toml (data_manifests/).")
@click.option("--mode", type=click.Choice(["split-join", "rescale"]), default="split-join", show_default=True)
@click.option("--join", type=click.Choice(["blend", "crop"]), default="blend", show_default=True,
              help="split-join: blend overlapping windows, or keep each window's centre (the dissertation's).")
@click.option("--resolution", "resolution_m", metavar="METRES|model",
              help="Resample georeferenced inputs to this ground pixel size before predicting ('model': the "
                   "training data's, from the checkpoint); labels stay on their grid.")
@click.option("--tta", is_flag=True, help="Average predictions over flips (and 90-degree turns of square inputs).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Folder for metrics.json, metrics.txt and the pictures.")
@click.option("--panels", type=int, default=4, show_default=True, help="Samples shown in panels.png.")
@click.option("--device", default="auto", show_default=True, help="auto (a GPU when there is one) | cpu | cuda | cuda:N")
@click.pass_context
@report_errors
def eval_command(ctx: click.Context, checkpoint: Path, dataset: Path | None, pairs: tuple[tuple[Path, Path], ...],
                 split: str, mapping: str | None, mode: str, join: str, resolution_m: str | None, tta: bool,
                 out_dir: Path, panels: int, device: str) -> None:
    """Evaluate CHECKPOINT on DATASET (its test split when it is the training dataset)."""
    if (dataset is None) == (not pairs):
        raise ConfigError("give a DATASET folder or --pair IMAGE LABEL (one of the two), e.g. "
                          "osmseg eval run/best.pt data/berlin --out eval/")
    require_torch()
    from training.evaluate import EvalOptions, run_eval
    from training.metrics import format_table

    opts = EvalOptions(mode=mode, join=join, tta=tta, split=split, mapping=mapping, panels=panels, device=device,
                       progress=ctx.obj.get("progress", False), resolution_m=resolution_m)
    metrics = run_eval(checkpoint, dataset, out_dir, opts, pairs)
    if ctx.obj["verbosity"] >= 0:
        click.echo(format_table(metrics), err=True)
        pictures = sorted(p.name for p in out_dir.glob("*.png"))
        click.echo(f"pictures in {out_dir}/: {', '.join(pictures)}", err=True)
    click.echo(str(out_dir / "metrics.json"))
