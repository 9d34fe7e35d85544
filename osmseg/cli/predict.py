"""``osmseg predict``: segment images of any size (PNG/JPEG/GeoTIFF) with a checkpoint."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import click

from osmseg.cli.common import report_errors, require_torch
from osmseg.errors import ConfigError


@click.command("predict")
@click.argument("checkpoint", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.argument("inputs", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Folder for the masks: NAME.png (class ids) and NAME_color.png for PNG/JPEG inputs; "
                   "NAME.tif and NAME_color.tif (Cloud-Optimized GeoTIFFs, georeferenced) for GeoTIFF inputs.")
@click.option("--mode", type=click.Choice(["split-join", "rescale"]), default="split-join", show_default=True,
              help="split-join: windows of the training patch size; rescale: letterbox the whole image into one.")
@click.option("--join", type=click.Choice(["blend", "crop"]), default="blend", show_default=True,
              help="blend overlapping windows smoothly, or keep each window's centre (the dissertation's).")
@click.option("--overlap", type=click.IntRange(min=0), help="Window overlap in pixels [a quarter of the window].")
@click.option("--block-size", type=click.IntRange(min=256), default=2048, show_default=True,
              help="Large rasters are predicted block by block (same result, bounded memory).")
@click.option("--tta", is_flag=True, help="Average over flips (and 90-degree turns of square inputs).")
@click.option("--resolution", "resolution", metavar="METRES|model",
              help="Resample georeferenced inputs to this ground pixel size before predicting ('model': the "
                   "training data's, from the checkpoint); the masks stay on the input's grid.")
@click.option("--batch-size", type=int, default=4, show_default=True)
@click.option("--device", default="auto", show_default=True, help="auto (a GPU when there is one) | cpu | cuda | cuda:N")
@click.pass_context
@report_errors
def predict_command(ctx: click.Context, checkpoint: Path, inputs: tuple[Path, ...], out_dir: Path, mode: str,
                    join: str, overlap: int | None, block_size: int, tta: bool, resolution: str | None,
                    batch_size: int, device: str) -> None:
    """Write a class mask (and a colour mask) for every INPUT image."""
    stems = Counter(src.stem for src in inputs)
    if clash := sorted(stem for stem, n in stems.items() if n > 1):
        raise ConfigError(f"{stems[clash[0]]} inputs are named {clash[0]}.*: their masks would overwrite each other "
                          f"in {out_dir}; predict them into separate --out folders")
    require_torch()
    from training.checkpoint import model_from_checkpoint
    from training.predict import predict_file, target_resolution

    model, spec = model_from_checkpoint(checkpoint, device=device)
    resolution_m = target_resolution(resolution, spec)
    out_dir.mkdir(parents=True, exist_ok=True)
    for src in inputs:
        geo = src.suffix.lower() in (".tif", ".tiff")
        suffix = ".tif" if geo else ".png"  # a GeoTIFF's colour mask stays georeferenced and block-written
        dst = out_dir / f"{src.stem}{suffix}"
        predict_file(model, spec, src, dst, colour_dst=out_dir / f"{src.stem}_color{suffix}", mode=mode, join=join,
                     overlap=overlap, block_size=block_size, tta=tta, batch_size=batch_size, device=device,
                     resolution_m=resolution_m)
        click.echo(str(dst))
