"""Recipe ablation: the default (``osmseg``) recipe against the paper's, and each of its choices
against the alternative, every run trained for real by osmseg's trainer.

Run: ``.venv/bin/python benchmarks/bench_recipe.py [--dataset DIR] [--steps 400] [--out DIR]
[--only NAME ...]`` (prints a table, asserts nothing). Without ``--dataset`` it builds the
offline ``osmseg demo`` dataset (4 rendered 1280x1280 samples of central Helsinki: 2 train,
1 validation, 1 test) into a temporary folder. Rerun with the same ``--out`` after a stop: the
variants that finished are read back, the one cut short resumes where its trainer stopped.

For each variant: :func:`training.run.train.run` with the ``osmseg`` recipe changed in one setting
(or the ``paper`` recipe), width 0.125 on the CPU, for the same number of training pixels:
``--steps`` of the default recipe (16 crops of 128x128 a step), as many steps of a variant as
see the same pixels (4 patches of 360x480 are 2.6 times as many a step: 2.6 times fewer
steps), so that every run does about the same arithmetic; the grid sampling has its own
batches per epoch, so its epochs are chosen to give that many steps. Then :func:`training.evaluation.evaluate.run_eval` of the *last*
checkpoint (not ``best.pt``: a choice among epochs on one validation image would add noise) on
the test split. Columns:

* ``test acc`` / ``test mIoU`` — pixel accuracy and mean IoU over the test image's classes;
* ``train acc`` — pixel accuracy of the same model on its own training images (unaugmented,
  whole): far below 1 on these rendered images, the recipe underfits;
* ``acc, BN batch`` — the same last model scored with BatchNorm in training mode (each test
  window normalised by its own statistics instead of the running ones): when it is far above
  ``test acc`` the running statistics are what fails, not the weights;
* ``train s`` — the training run's epochs, as its ``log.csv`` times them (validation every epoch
  included);
* ``px/step`` — training pixels per optimiser step.

Also prints the median-frequency class weights of the training split (the paper's weights),
and writes ``OUT/ablation.json`` and ``OUT/ablation_curves.png`` (training loss and validation
pixel accuracy against training pixels, one line per variant).
"""

from __future__ import annotations

import argparse
import csv
import json
import logging
import os
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from training.datasets.patches import (  # noqa: E402
    dataset_class_table,
    discover_dataset,
    files_by_name,
    validate,
    weights_from_histograms,
)
from training.evaluation.evaluate import EvalOptions, run_eval  # noqa: E402
from training.run.config import make_config  # noqa: E402
from training.run.train import run  # noqa: E402


@dataclass(frozen=True)
class Variant:
    """One training run of the ablation: the osmseg recipe with ``settings`` changed."""

    name: str
    what: str
    settings: dict[str, Any] = field(default_factory=dict)


VARIANTS = (
    Variant("osmseg", "the default recipe and network"),
    Variant("paper", "the dissertation's recipe and network", {"recipe": "paper", "arch": "segnet"}),
    Variant("segnet", "the published SegNet (no skips) for segnet-skip", {"arch": "segnet"}),
    Variant("balanced", "+ half the crops centred on a uniformly drawn class", {"balanced_crops": 0.5}),
    Variant("weights-mf", "+ median-frequency class weights", {"class_weights": "median-frequency"}),
    Variant("weights-sqrt", "+ square root of them", {"class_weights": "sqrt-median-frequency"}),
    Variant("sgd", "SGD lr 0.1 (momentum 0.9) for AdamW", {"optimizer": "sgd", "lr": 0.1, "weight_decay": 5e-4}),
    Variant("lr-0.003", "AdamW lr 0.003 (not 0.01)", {"lr": 0.003}),
    Variant("lr-0.001", "AdamW lr 0.001 (not 0.01)", {"lr": 0.001}),
    Variant("warmup", "+ a linear warm-up over the first 5 % of the steps", {"warmup": 0.05}),
    Variant("grid", "the fixed 360x480 grid for random crops, 4 a batch", {"sampling": "grid", "batch_size": 4}),
    Variant("crop256", "256-px crops, 4 a batch (same pixels a step)", {"crop": 256, "batch_size": 4}),
    Variant("no-augment", "no flips, turns or colour jitter", {"augment": False}),
)


def demo_dataset(folder: Path) -> Path:
    """The ``osmseg demo`` dataset, built offline from its recorded fixtures."""
    from osmseg.builder.run import build
    from osmseg.demo import demo_config

    out = folder / "dataset"
    build(demo_config(out), env=dict(os.environ, BING_MAPS_KEY="demo-key-not-secret"))
    return out


def steps_per_epoch_of(run_dir: Path) -> int:
    """Optimiser steps per epoch of a finished run, from its checkpoint's scheduler."""
    from training.models.checkpoint import load_checkpoint

    last = load_checkpoint(run_dir / "last.pt")
    return int(last["scheduler"]["last_epoch"]) // int(last["epoch"])


def batch_stat_accuracy(checkpoint: Path, dataset: Path) -> float:
    """Test pixel accuracy of ``checkpoint`` with BatchNorm normalising each whole test image by
    its own statistics (training mode, no gradient)."""
    from torchvision.transforms.v2 import functional as F

    from osmseg.images import read_label, read_rgb
    from training.models.checkpoint import load_checkpoint, model_from_checkpoint

    model, spec = model_from_checkpoint(checkpoint, device="cpu")
    model.train()
    test = load_checkpoint(checkpoint)["splits"]["test"]
    files, _ = discover_dataset(dataset)
    right = total = 0
    with torch.no_grad():
        for f in files_by_name(files, test):
            image, label = read_rgb(f.image), read_label(f.label)
            x = F.normalize(torch.from_numpy(image.copy()).permute(2, 0, 1).float().div(255), spec.mean, spec.std)
            logits = model(x[None])[0]
            if spec.ignore_index is not None:
                logits[spec.ignore_index] = -torch.inf
            pred = logits.argmax(0).numpy()
            keep = label != spec.ignore_index if spec.ignore_index is not None else np.ones(label.shape, bool)
            right += int((pred[keep] == label[keep]).sum())
            total += int(keep.sum())
    return right / max(1, total)


def pixels_per_step(config: Any) -> int:
    recipe = config.settings
    crop = (recipe.crop, recipe.crop) if recipe.sampling == "random" else config.patch_size
    return int(recipe.batch_size * crop[0] * crop[1])


def train_variant(variant: Variant, dataset: Path, out: Path, default_steps: int, seed: int) -> dict[str, Any]:
    """Train one variant on as many pixels as ``default_steps`` of the default recipe see;
    evaluate its last checkpoint on the test split."""
    run_dir = out / variant.name
    base = {"model": "ablation", "width": 0.125, "device": "cpu", "loader_workers": 0, "seed": seed,
            "tensorboard": False}
    settings = dict(base, **variant.settings)
    probe = make_config(dataset, run_dir, None, dict(settings, epochs=1))
    default = make_config(dataset, run_dir, None, dict(base, epochs=1))
    steps = max(1, round(default_steps * pixels_per_step(default) / pixels_per_step(probe)))
    per_epoch = 50 if steps >= 100 else max(1, steps // 4)
    if probe.settings.sampling == "grid":  # the grid's batches per epoch
        from training.datasets.patches import PatchDataset

        files, _ = discover_dataset(dataset)
        split = json.loads((out / "splits.json").read_text())["splits"]["train"]
        patches = len(PatchDataset(files_by_name(files, split), probe.patch_size))
        per_epoch = -(-patches // probe.settings.batch_size)
    else:
        settings["steps_per_epoch"] = per_epoch
    settings["epochs"] = max(1, round(steps / per_epoch))
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "splits.json").write_bytes((out / "splits.json").read_bytes())  # every variant: the same split
    config = make_config(dataset, run_dir, None, settings)
    trained_before = (run_dir / "last.pt").stat().st_mtime_ns if (run_dir / "last.pt").exists() else None
    run(config)  # a run already finished in --out is only reopened (the trainer resumes)
    evals = {"test": run_dir / "eval", "train": run_dir / "eval-train"}
    for split, folder in evals.items():
        stale = trained_before != (run_dir / "last.pt").stat().st_mtime_ns
        if stale or not (folder / "metrics.json").exists():
            run_eval(run_dir / "last.pt", dataset, folder, EvalOptions(split=split, device="cpu"))
    metrics, fitted = (json.loads((evals[s] / "metrics.json").read_text()) for s in ("test", "train"))
    with (run_dir / "log.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    seconds = sum(float(r["seconds"]) for r in rows)  # the epochs' own times: a resumed run's add up too
    per_epoch = steps_per_epoch_of(run_dir)
    recipe = config.settings
    return {"name": variant.name, "what": variant.what, "steps": per_epoch * config.epochs, "train_s": round(seconds, 1),
            "test_pixel_accuracy": metrics["pixel_accuracy"], "test_miou": metrics["miou"],
            "train_pixel_accuracy": fitted["pixel_accuracy"],
            "test_pixel_accuracy_bn_batch": batch_stat_accuracy(run_dir / "last.pt", dataset),
            "pixels_per_step": pixels_per_step(config),
            "curve": [(int(r["epoch"]) * per_epoch * pixels_per_step(config) / 1e6, float(r["val_pixel_accuracy"] or "nan"),
                       float(r["train_loss"] or "nan")) for r in rows],
            "recipe": recipe.to_dict()}


def shared_split(dataset: Path, out: Path, seed: int) -> None:
    """Draw the run's split once (the trainer's own draw, from a 1-step run) for every variant."""
    probe = out / "split-probe"
    run(make_config(dataset, probe, None, {"model": "ablation", "width": 0.0625, "device": "cpu", "epochs": 1,
                                           "loader_workers": 0, "seed": seed, "max_steps_per_epoch": 1,
                                           "tensorboard": False}))
    (out / "splits.json").write_bytes((probe / "splits.json").read_bytes())


def class_weight_spread(dataset: Path, out: Path) -> dict[str, Any]:
    """The paper's median-frequency weights of the training split, smallest and largest."""
    table = dataset_class_table(dataset)
    files, _ = discover_dataset(dataset)
    train = files_by_name(files, json.loads((out / "splits.json").read_text())["splits"]["train"])
    weights = weights_from_histograms(validate(train, table.num_classes), 0).numpy()
    names = {c.id: c.name for c in (*table.classes, table.unlabeled)}
    present = [(float(w), names[i]) for i, w in enumerate(weights) if w > 0]
    (lo, lo_name), (hi, hi_name) = min(present), max(present)
    return {"smallest": lo, "smallest_class": lo_name, "largest": hi, "largest_class": hi_name}


def curves_png(results: list[dict[str, Any]], path: Path) -> None:
    """Training loss and validation pixel accuracy against training pixels, one line per variant."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (loss_ax, acc_ax) = plt.subplots(1, 2, figsize=(11, 6), dpi=100)
    colours = [plt.get_cmap("tab20")(i) for i in range(20)]  # a colour each for up to 20 variants
    for i, r in enumerate(results):
        pixels, acc, loss = zip(*r["curve"], strict=True)
        style = {"label": f"{r['name']}: {r['what']}", "linewidth": 2.2 if r["name"] in ("osmseg", "paper") else 1,
                 "color": colours[(2 * i) % 20 + (2 * i) // 20 % 2]}
        loss_ax.plot(pixels, loss, **style)
        acc_ax.plot(pixels, acc, **style)
    loss_ax.set_yscale("log")
    loss_ax.set_ylabel("training loss (weighted where the variant weights classes)")
    acc_ax.set_ylabel("validation pixel accuracy")
    acc_ax.set_ylim(0, 1)
    for ax in (loss_ax, acc_ax):
        ax.set_xlabel("training pixels (millions)")
        ax.grid(alpha=0.3)
    fig.suptitle("Recipe ablation (width 0.125, CPU, demo dataset)")
    fig.tight_layout(rect=(0, 0.17, 1, 1))
    fig.legend(*loss_ax.get_legend_handles_labels(), loc="lower center", ncol=3, fontsize=7, frameon=False)
    fig.savefig(path)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, help="a dataset folder (default: build the demo's)")
    parser.add_argument("--steps", type=int, default=400,
                        help="optimiser steps of the default recipe (the others: as many pixels)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, help="keep the runs here (default: a temporary folder)")
    parser.add_argument("--json", type=Path, help="also write every figure to this JSON file")
    parser.add_argument("--png", type=Path, help="also draw the curves into this PNG")
    parser.add_argument("--only", nargs="*", help="variants to run (default: all)", choices=[v.name for v in VARIANTS])
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    torch.set_num_threads(min(2, os.cpu_count() or 1))
    with tempfile.TemporaryDirectory(prefix="bench-recipe-") as tmp:
        out = args.out or Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        dataset = args.dataset or demo_dataset(Path(tmp))
        shared_split(dataset, out, args.seed)
        spread = class_weight_spread(dataset, out)
        print(f"median-frequency weights of the training split: {spread['smallest']:.2f} ({spread['smallest_class']}) "
              f".. {spread['largest']:.2f} ({spread['largest_class']}), a spread of "
              f"{spread['largest'] / spread['smallest']:.0f}x")
        results = []
        for variant in VARIANTS:
            if args.only and variant.name not in args.only:
                continue
            r = train_variant(variant, dataset, out, args.steps, args.seed)
            results.append(r)
            print(f"{r['name']:<13} steps {r['steps']:>5}  train {r['train_s']:>6.1f} s  test acc {r['test_pixel_accuracy']:.3f}"
                  f"  mIoU {r['test_miou']:.3f}  train acc {r['train_pixel_accuracy']:.3f}  acc, BN batch {r['test_pixel_accuracy_bn_batch']:.3f}"
                  f"  px/step {r['pixels_per_step']:>7}  {r['what']}", flush=True)
        report = {"steps": args.steps, "weights": spread, "variants": results}
        (out / "ablation.json").write_text(json.dumps(report, indent=1) + "\n")
        if args.json:
            args.json.write_text(json.dumps(report, indent=1) + "\n")
        curves_png(results, out / "ablation_curves.png")
        if args.png:
            curves_png(results, args.png)
        print(f"written: {out / 'ablation.json'}, {out / 'ablation_curves.png'}")


if __name__ == "__main__":
    main()
