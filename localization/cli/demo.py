"""``osmseg demo``: the whole pipeline offline on the embedded recorded fixtures.

Build (4 Helsinki samples replayed from a cassette), localization (panoramas rendered from the
masks, localized by landmark-graph matching), then training and evaluation of a tiny model.
It lives here, in the top layer, because it runs all three packages; the build it replays is
:func:`osmseg.demo.demo_config` in the core. Registered as a plugin (entry point
``osmseg.commands``). Imports: osmseg core, training and localization.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import click

from osmseg.cli.build import run_build
from osmseg.cli.common import output_options, report_errors
from osmseg.cli.drawers import progress_drawer
from osmseg.cli.options import OUT, declare
from osmseg.demo import DEMO_CASSETTE, demo_config
from osmseg.runtime.progress import Progress
from osmseg.units import plural, ratio
from training.cli import EPOCHS

#: The demo's training run: the default network (SegNet with skips) at 1/8 of its width, by the
#: default recipe (epochs of 50 steps of 16 random crops), long enough to learn the rendered
#: imagery (docs/training.md: ``demo`` figures).
DEMO_TRAINING = {"model": "airsegnet13", "width": 0.125, "epochs": 8, "loader_workers": 0, "seed": 0}


def demo_training(dataset: Path, out_dir: Path, epochs: int, verbosity: int, progress: Progress | None) -> None:
    """Train the demo model briefly on the demo dataset, then evaluate it on its test split."""
    from training.evaluation.evaluate import EvalOptions, run_eval
    from training.run.config import make_config
    from training.run.train import run

    run_dir, eval_dir = out_dir / "run", out_dir / "eval"
    settings = dict(DEMO_TRAINING, epochs=epochs, device="cpu")
    if verbosity >= 0:
        click.echo(f"training {settings['model']} (width {settings['width']}, {epochs} epochs, CPU) "
                   f"into {run_dir}/", err=True)
    summary = run(make_config(dataset, run_dir, None, settings), progress=progress)
    seconds = sum(h.seconds for h in summary.history)
    if verbosity >= 0:
        click.echo(f"evaluating {run_dir / 'model.pt'} on the test split into {eval_dir}/", err=True)
    opts = EvalOptions(split="test", device="cpu")
    metrics = run_eval(run_dir / "model.pt", dataset, eval_dir, opts, progress=progress)
    if verbosity >= 0:
        click.echo(f"test mIoU {ratio(metrics['miou'])}, pixel accuracy {ratio(metrics['pixel_accuracy'])} on the "
                   f"held-out image ({epochs} epochs, {seconds:.0f} s of training on the CPU)", err=True)
        click.echo(f"pictures: {eval_dir}/panels.png (image | labels | predictions), confusion_matrix.png, "
                   f"per_class_iou.png, curves.png; dataset overview: {dataset}/overview.png", err=True)


#: The demo's localization run: rendered panoramas at seeded viewpoints of the demo masks.
DEMO_VIEWPOINTS = 12


def demo_localization(dataset: Path, out_dir: Path, verbosity: int, progress: Progress | None) -> None:
    """Render panoramas in the demo masks and localize them with both methods (localize-bench, a few viewpoints)."""
    from localization.bench.rendered import BenchConfig, load_dataset_scenes, run_bench
    from localization.cli.summary import format_summary

    loc_dir = out_dir / "localize"
    drawing = importlib.util.find_spec("matplotlib") is not None
    if verbosity >= 0:
        click.echo(f"localizing {DEMO_VIEWPOINTS} rendered panoramas in the dataset's masks into {loc_dir}/", err=True)
    config = BenchConfig(viewpoints=DEMO_VIEWPOINTS, seed=0, subsets=True, pictures=2 if drawing else 0,
                         methods=("paper", "profile"))
    results = run_bench(load_dataset_scenes(dataset), config, loc_dir, progress=progress, plots=drawing,
                        source=str(dataset))
    if verbosity >= 0:
        click.echo(format_summary(results), err=True)
        click.echo(f"pictures: {loc_dir}/errors.png, confidence.png, classes.png, views/ (candidates, top-5 "
                   "and truth on the mask; the panorama's landmark graph)" if drawing else
                   "localization pictures skipped: matplotlib is not installed (pip install 'osmseg[train]')",
                   err=True)


TRAIN = declare("--train/--no-train",
                help="After the build, train a tiny AirSegNet13 on the CPU and evaluate it (needs osmseg[train]).")
LOCALIZE = declare("--localize/--no-localize",
                   help="After the build, localize rendered panoramas in the dataset's masks (localize-bench).")


@click.command("demo")
@output_options
@OUT(default=Path("demo-out"), show_default=True, detail=": dataset/, localize/, run/ (training) and eval/ (metrics, "
                                                         "pictures).")
@TRAIN(default=True, show_default=True)
@EPOCHS(default=DEMO_TRAINING["epochs"], show_default=True)
@LOCALIZE(default=True, show_default=True)
@click.pass_context
@report_errors
def demo_command(ctx: click.Context, out_dir: Path, train: bool, epochs: int, localize: bool) -> None:
    """Build a small dataset offline from embedded recorded fixtures, localize panoramas rendered
    from its masks, then train and evaluate a tiny model on it."""
    verbosity, drawn = ctx.obj["verbosity"], ctx.obj.get("progress")
    if verbosity >= 0:
        click.echo(f"osmseg demo: replaying {DEMO_CASSETTE.name} (Helsinki, OSM API + Bing wire formats; "
                   "OSM © OpenStreetMap contributors, ODbL; imagery rendered from OSM by osmseg)", err=True)
    dataset = out_dir / "dataset"
    env = dict(os.environ, BING_MAPS_KEY="demo-key-not-secret")
    summary = run_build(demo_config(dataset), verbosity, drawn, env=env)
    if verbosity >= 0:
        click.echo(f"dataset in {dataset}/: images/, segmented/, labels/, geo/, manifest.json, DATASHEET.md, "
                   f"overview.png ({plural(summary.accepted, 'sample')})", err=True)
    with progress_drawer(drawn) as progress:
        if localize:
            demo_localization(dataset, out_dir, verbosity, progress)
        if not train:
            return
        if importlib.util.find_spec("torch") is None:
            click.echo("training skipped: PyTorch is not installed (pip install 'osmseg[train]')", err=True)
            return
        demo_training(dataset, out_dir, epochs, verbosity, progress)
