"""Real held-out figures for osmseg's trainer: building IoU on Kampala tiles it never saw, and
on Austin (another continent, another camera), beside a per-pixel baseline.

Why: the demo and the recipe ablation train and test on rendered or tiny data. Here the data
are real (``../shared/data``, made by others): drone tiles of Kampala with OSM building
footprints, and the Inria Austin sample with its own building mask. A network that has learnt
roofs must beat a logistic regression on pixel colours (``pixel_baseline.py``) on both.

What it does:

1. Builds a CamVid-layout dataset from the complete z21 block of Kampala tiles
   (``kampala.py``): the **west 7 columns** are train (three 7x2-tile strips) and validation
   (one strip, drawn with the seed), the **east 5 columns** the test split (two 5x4-tile
   mosaics); a second 4x4-tile block 450 m south-west is a fourth training mosaic. No tile is
   in two splits, and the test area is a separate part of the town.
   GeoTIFFs in EPSG:3857 (~0.0744 m ground pixels); labels are the OSM footprints rasterised
   on each mosaic's transform, transparent drone pixels unlabeled (ignored).
2. Trains each variant through the real command line, ``python -m osmseg train DATASET --out
   RUN --model buildings --width 0.125 --device cpu --seed S --epochs E --steps-per-epoch N``
   (E=20, N=30 by default), then the variant's own ``--train-args`` (default: SegNet with
   skips and its recipe, ``--arch segnet-skip``; the dissertation's recipe and network,
   ``--recipe paper --arch segnet``; and unet-lite0 from its ImageNet weights at width 1.0,
   ``--arch unet-lite0 --init imagenet --width 1.0``). A variant on the paper's fixed 360x480 grid (``--recipe paper``,
   which ignores ``--steps-per-epoch``) gets, unless its arguments say ``--epochs``,
   as many epochs as see the same number of training pixels as E x N steps of the default
   recipe (16 crops of 128x128 a step). Wall time of each training is measured.
3. Scores ``RUN/model.pt`` (the checkpoint the run hands on), ``RUN/last.pt`` and, when it is
   another epoch, ``RUN/best.pt`` (best validation mIoU, on one strip) with ``osmseg predict`` on the Kampala test
   mosaics and on ``inria-austin/image.tif`` with ``--resolution model`` (resampled to the
   training data's 0.0744 m, mask back on Austin's 0.3 m grid), reading the written masks
   with rasterio: building IoU and pixel accuracy (building vs the rest) over labelled
   pixels, counted with numpy.
4. Fits the baseline on a seeded subsample of the Kampala training pixels, balanced and
   unweighted, and scores it the same way: on the test mosaics, and on Austin resampled to
   the Kampala training resolution (so it sees roofs at the size it learnt them), its mask
   brought back to Austin's grid with nearest neighbour.

Run from the project root (needs the ``train`` and ``bench`` extras; a default training takes
2-3 minutes on a quiet 2-core CPU, the ``--width 0.25`` one about twice that, everything with
the predictions about half an hour, three to four times that when another job shares the
CPUs)::

    .venv/bin/python benchmarks/bench_real_heldout.py [--out DIR] [--json results.json]
        [--png results.png] [--train-args "--crop 256 --batch-size 4" ...] [--seeds 0 1 2] [--fit-test]

With ``--seeds S ...`` all of it runs once per seed (validation strip, training, baseline
sample); the table gives mean (min-max) over the seeds. ``--fit-test`` measures a ceiling
instead: the test mosaics are also training data (``kampala.py``), so every method is scored
on ground it learnt from. Prints a markdown table; ``--json``
writes every figure, the settings and the seeds;
``--png`` shows image | labels | network (best.pt, last.pt) of the first variant | balanced
baseline, for Kampala and Austin. Without ``--out`` everything goes into a temporary folder
that is removed at the end. Exits with code 1 and one line when ``../shared/data``
(``--shared-data``) is absent. Figures measured on the shared machine: benchmarks/README.md.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, cast

import numpy as np
import rasterio
from PIL import Image

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path[:0] = [str(ROOT), str(HERE)]

from kampala import BUILDING, UNLABELED, build_kampala  # noqa: E402
from pixel_baseline import Fitted, back_to_grid, building_scores, fit_baseline, resample  # noqa: E402

from osmseg.grid import ground_pixel_size  # noqa: E402
from training.datasets.patches import PATCH_SIZE, dataset_resolution, discover_camvid, patch_boxes  # noqa: E402
from training.run.recipe import recipe_named  # noqa: E402

#: the networks side by side: SegNet with skips and its recipe (random weights), the
#: dissertation's SegNet and recipe, and unet-lite0 from its ImageNet weights (its own recipe)
DEFAULT_VARIANTS = ("--arch segnet-skip", "--recipe paper --arch segnet",
                    "--arch unet-lite0 --init imagenet --width 1.0")
NEEDED = ("kampala-oam/tiles", "kampala-oam/osm-buildings.geojson", "inria-austin/image.tif",
          "inria-austin/buildings.tif")
Pairs = list[tuple[np.ndarray, np.ndarray, np.ndarray]]  # (prediction, truth, valid) per image


def osmseg(args: list[str], log: Path) -> str:
    """Run ``python -m osmseg ARGS`` on this checkout; stdout returned, stderr kept in ``log``."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    with log.open("a", encoding="utf-8") as err:
        err.write(f"$ python -m osmseg {shlex.join(args)}\n")
        err.flush()
        done = subprocess.run([sys.executable, "-m", "osmseg", *args], check=False, stdout=subprocess.PIPE,
                              stderr=err, text=True, env=env, cwd=ROOT)
    if done.returncode != 0:
        tail = log.read_text(encoding="utf-8").splitlines()[-15:]
        sys.exit(f"osmseg {args[0]} failed (exit {done.returncode}); end of {log}:\n" + "\n".join(tail))
    return done.stdout


def read_band(path: Path) -> np.ndarray:
    with rasterio.open(path) as ds:
        return cast("np.ndarray", ds.read(1))


def read_rgb(path: Path) -> np.ndarray:
    with rasterio.open(path) as ds:
        return cast("np.ndarray", ds.read([1, 2, 3]).transpose(1, 2, 0))


def pooled(pairs: Pairs) -> dict[str, Any]:
    """:func:`building_scores` over all pixels of all images at once."""
    return building_scores(*(np.concatenate([p[i].ravel() for p in pairs]) for i in range(3)))


def option(args: list[str], name: str) -> str | None:
    """The value of ``--name V`` or ``--name=V`` in ``args`` (the last one, as click takes it)."""
    found = None
    for i, arg in enumerate(args):
        if arg == name and i + 1 < len(args):
            found = args[i + 1]
        elif arg.startswith(name + "="):
            found = arg.split("=", 1)[1]
    return found


def variant_args(variant: str, a: argparse.Namespace, grid_patches: int, seed: int) -> list[str]:
    """The variant's training options: the bench's budget, then its own (which win)."""
    extra = shlex.split(variant)
    epochs = a.epochs
    if option(extra, "--recipe") == "paper" and option(extra, "--epochs") is None:  # the fixed patch grid
        osm = recipe_named("osmseg")  # an epoch of the grid is every patch once, whatever the batch size
        budget = a.epochs * a.steps_per_epoch * osm.batch_size * osm.crop ** 2
        epochs = max(1, round(budget / (grid_patches * PATCH_SIZE[0] * PATCH_SIZE[1])))
    return ["--model", "buildings", "--width", str(a.width), "--device", "cpu", "--seed", str(seed),
            "--epochs", str(epochs), "--steps-per-epoch", str(a.steps_per_epoch), *extra]


def score_checkpoint(checkpoint: Path, dataset: Path, austin: Path, out: Path, log: Path) -> dict[str, Any]:
    """``osmseg predict`` of the Kampala test mosaics and of Austin (``--resolution model``),
    the written masks read back and scored."""
    tests = sorted((dataset / "test").glob("*.tif"))
    osmseg(["predict", str(checkpoint), *map(str, tests), "--out", str(out / "kampala")], log)
    osmseg(["predict", str(checkpoint), str(austin / "image.tif"), "--resolution", "model",
            "--out", str(out / "austin")], log)
    kampala: Pairs = []
    for t in tests:
        truth = read_band(dataset / "testannot" / t.name)
        kampala.append((read_band(out / "kampala" / t.name) == BUILDING, truth == BUILDING, truth != UNLABELED))
    austin_truth = read_band(austin / "buildings.tif") == 255
    austin_pred = read_band(out / "austin" / "image.tif") == BUILDING
    return {"kampala": pooled(kampala), "austin": pooled([(austin_pred, austin_truth, np.ones_like(austin_truth))]),
            "_masks": {"kampala": kampala[0][0], "austin": austin_pred}}


def train_and_score(variant: str, dataset: Path, run: Path, a: argparse.Namespace, grid_patches: int,
                    austin: Path, seed: int) -> list[dict[str, Any]]:
    """Train one variant with the CLI; score the checkpoint it hands on (model.pt), last.pt and
    best.pt (best validation mIoU; scored only when it is another epoch than the last)."""
    if run.exists():
        sys.exit(f"{run} exists: give a new --out (a rerun would resume that run, not time a new one)")
    log = run.parent / f"{run.name}.log"
    args = variant_args(variant, a, grid_patches, seed)
    began = time.monotonic()
    osmseg(["train", str(dataset), "--out", str(run), *args], log)
    seconds = time.monotonic() - began
    with (run / "log.csv").open(encoding="utf-8") as f:
        history = list(csv.DictReader(f))
    best = max(history, key=lambda r: float(r["val_miou"] or "-inf"))  # the epoch best.pt holds
    common = {"variant": variant or "default", "seed": seed, "train_args": args, "train_seconds": round(seconds, 1),
              "epochs_run": len(history), "val_miou_by_epoch": [float(r["val_miou"] or "nan") for r in history]}
    model = dict(common, checkpoint="model.pt", **score_checkpoint(run / "model.pt", dataset, austin,
                                                                   run / "pred-model", log))
    rows = [model, dict(common, checkpoint="last.pt", **score_checkpoint(run / "last.pt", dataset, austin,
                                                                         run / "pred-last", log))]
    if int(best["epoch"]) != len(history):
        rows.append(dict(common, checkpoint="best.pt", best_epoch=int(best["epoch"]),
                         **score_checkpoint(run / "best.pt", dataset, austin, run / "pred-best", log)))
    else:  # the last epoch's weights of the kind model.pt holds: the same file's content
        rows.append(dict(model, checkpoint="best.pt", best_epoch=int(best["epoch"])))
    return rows


def summary(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Rows of the same variant and checkpoint over seeds: mean, min and max of every figure."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["variant"], r.get("checkpoint", "")), []).append(r)
    out = []
    for (variant, checkpoint), members in groups.items():
        entry: dict[str, Any] = {"variant": variant, "checkpoint": checkpoint, "seeds": [m["seed"] for m in members]}
        for key in ("train_seconds",):
            values = [float(m[key]) for m in members]
            entry[key] = {"mean": float(np.mean(values)), "min": min(values), "max": max(values)}
        for where in ("kampala", "austin"):
            entry[where] = {k: {"mean": float(np.mean([m[where][k] for m in members])),
                                "min": min(m[where][k] for m in members), "max": max(m[where][k] for m in members)}
                            for k in ("building_iou", "pixel_accuracy")}
        out.append(entry)
    return out


def baselines(dataset: Path, austin: Path, a: argparse.Namespace, resolution: float, seed: int) -> list[dict[str, Any]]:
    """Fit the pixel baseline (balanced, unweighted) on Kampala train; score Kampala test and Austin."""
    splits = discover_camvid(dataset)
    labels = [read_band(f.label) for f in splits["train"]]
    images = [read_rgb(f.image) for f in splits["train"]]
    tests = [(read_rgb(f.image), read_band(f.label)) for f in splits["test"]]
    austin_rgb = read_rgb(austin / "image.tif")
    austin_truth = read_band(austin / "buildings.tif") == 255
    with rasterio.open(austin / "image.tif") as ds:
        austin_res = ground_pixel_size(ds.crs, ds.transform, ds.width, ds.height)
    scale = float(austin_res or 0.3) / resolution
    upsampled = resample(austin_rgb, scale)
    out = []
    for balanced in (True, False):
        began = time.monotonic()
        model: Fitted = fit_baseline(images, [lab == BUILDING for lab in labels], [lab != UNLABELED for lab in labels],
                                     a.baseline_samples, seed, balanced)
        seconds = time.monotonic() - began
        kampala = [(model.predict(rgb), lab == BUILDING, lab != UNLABELED) for rgb, lab in tests]
        austin_pred = back_to_grid(model.predict(upsampled), austin_truth.shape)
        out.append({"variant": "baseline " + ("balanced" if balanced else "unweighted"), "seed": seed, "train_seconds":
                    round(seconds, 1), "samples": model.samples, "building_share_of_samples": model.positive_share,
                    "austin_scale": round(scale, 4), "kampala": pooled(kampala),
                    "austin": pooled([(austin_pred, austin_truth, np.ones_like(austin_truth))]),
                    "_masks": {"kampala": kampala[0][0], "austin": austin_pred}})
    return out


def spread(figure: dict[str, float], digits: int = 3) -> str:
    """``mean (min-max)`` of a figure over seeds; the mean alone for one seed."""
    if figure["min"] == figure["max"]:
        return f"{figure['mean']:.{digits}f}"
    return f"{figure['mean']:.{digits}f} ({figure['min']:.{digits}f}-{figure['max']:.{digits}f})"


def table(rows: list[dict[str, Any]]) -> str:
    """Markdown: one line per variant and checkpoint, mean (min-max) over the seeds."""
    lines = ["| method | checkpoint | Kampala building IoU | Austin building IoU | Kampala pixel accuracy | "
             "Austin pixel accuracy | train s |", "|---|---|---|---|---|---|---|"]
    for r in summary(rows):
        lines.append(f"| {r['variant']} | {r['checkpoint'] or '-'} | {spread(r['kampala']['building_iou'])} | "
                     f"{spread(r['austin']['building_iou'])} | {spread(r['kampala']['pixel_accuracy'])} | "
                     f"{spread(r['austin']['pixel_accuracy'])} | {spread(r['train_seconds'], 0)} |")
    return "\n".join(lines)


def picture(path: Path, dataset: Path, austin: Path, networks: list[dict[str, Any]], baseline: dict[str, Any]) -> None:
    """image | labels | network (each checkpoint) | baseline, for the first Kampala test mosaic and Austin."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    first = sorted((dataset / "test").glob("*.tif"))[0]
    lab = read_band(dataset / "testannot" / first.name)
    rows = [("Kampala test", read_rgb(first), lab == BUILDING, lab == UNLABELED, "kampala"),
            ("Austin", read_rgb(austin / "image.tif"), read_band(austin / "buildings.tif") == 255, None, "austin")]
    colours = np.array([[90, 90, 90], [255, 220, 0], [0, 0, 0]], np.uint8)  # background, building, unlabeled
    columns = 3 + len(networks)
    fig, axes = plt.subplots(2, columns, figsize=(4 * columns, 9.4))
    fig.subplots_adjust(left=0.01, right=0.99, top=0.9, bottom=0.07, wspace=0.04, hspace=0.25)
    for row, (title, rgb, truth, void, key) in zip(axes, rows, strict=True):
        panels = [(rgb, f"{title}: image")]
        shown: list[tuple[str, np.ndarray, dict[str, Any] | None]] = [(f"{title}: labels", truth, None)]
        shown += [(f"network {n['variant']}\n{n['checkpoint']}", n["_masks"][key], n) for n in networks]
        shown += [(baseline["variant"], baseline["_masks"][key], baseline)]
        for name, mask, r in shown:
            ids = mask.astype(np.uint8)
            if void is not None:
                ids[void] = 2
            panels.append((colours[ids], f"{name}: IoU {r[key]['building_iou']:.3f}" if r else name))
        for ax, (img, text) in zip(row, panels, strict=True):
            ax.imshow(img, interpolation="nearest")
            ax.set_title(text, fontsize=10)
            ax.axis("off")
    fig.legend(handles=[Patch(color=colours[i] / 255, label=n) for i, n in
                        enumerate(("background", "building", "unlabeled"))], loc="lower center", ncol=3)
    fig.suptitle("Held out: Kampala east columns (never trained on) and Inria Austin (another city, "
                 "resampled to the training resolution)")
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--shared-data", type=Path, default=ROOT.parent / "shared" / "data")
    p.add_argument("--out", type=Path, help="keep the dataset, runs and masks here (default: a temporary folder)")
    p.add_argument("--train-args", action="append", metavar="ARGS",
                   help=f"one training variant's extra options (repeatable; default: {list(DEFAULT_VARIANTS)})")
    p.add_argument("--epochs", type=int, default=20)
    p.add_argument("--steps-per-epoch", type=int, default=30)
    p.add_argument("--width", type=float, default=0.125)
    p.add_argument("--baseline-samples", type=int, default=200_000, help="training pixels the baseline fits on")
    p.add_argument("--seeds", type=int, nargs="+", default=[0],
                   help="one whole run per seed (validation strip, training, baseline subsample); figures are "
                        "reported as mean (min-max) over them")
    p.add_argument("--fit-test", action="store_true",
                   help="a ceiling, not a benchmark: the Kampala test mosaics are also training data, so the "
                        "networks are scored on ground they learnt (the baselines too)")
    p.add_argument("--json", type=Path, help="write every figure, the settings and seeds here")
    p.add_argument("--png", type=Path, help="write the picture here (the first seed's runs)")
    a = p.parse_args()
    missing = [n for n in NEEDED if not (a.shared_data / n).exists()]
    if missing:
        print(f"skipped: {a.shared_data / missing[0]} is absent (real data in ../shared/data)", file=sys.stderr)
        sys.exit(1)
    variants = a.train_args or list(DEFAULT_VARIANTS)
    out = (a.out or Path(tempfile.mkdtemp(prefix="bench-real-heldout-"))).resolve()  # the trainer runs elsewhere
    try:
        rows: list[dict[str, Any]] = []
        datasets = {}
        austin = a.shared_data / "inria-austin"
        for seed in a.seeds:
            dataset = out / f"kampala-z21-seed{seed}"
            built = build_kampala(a.shared_data, dataset, seed, fit_test=a.fit_test)
            datasets[seed] = built
            for m in built["mosaics"]:  # read back from the written files, independently of the builder
                lab = np.asarray(Image.open(dataset / f"{m['split']}annot" / f"{m['name']}.tif"))
                m["building_pixels_read_back"] = int((lab == BUILDING).sum())
                print(f"seed {seed}: {m['split']:5} {m['name']} {m['width']}x{m['height']}: building "
                      f"{m['building_fraction']:.3f} of labelled pixels, unlabeled {m['unlabeled_fraction']:.4f}",
                      file=sys.stderr)
            files = discover_camvid(dataset)
            resolution = dataset_resolution(dataset, files["train"]) or 0.0746
            grid = sum(len(patch_boxes(m["height"], m["width"])) for m in built["mosaics"] if m["split"] == "train")
            (out / "runs").mkdir(exist_ok=True)
            for i, variant in enumerate(variants):
                slug = "-".join(shlex.split(variant)).strip("-").replace("--", "") or "default"
                print(f"seed {seed}: training {variant or 'default'} ...", file=sys.stderr)
                for r in train_and_score(variant, dataset, out / "runs" / f"seed{seed}-{i}-{slug}", a, grid, austin,
                                         seed):
                    rows.append(r)
                    print(f"  trained in {r['train_seconds']:.0f} s; {r['checkpoint']}: Kampala IoU "
                          f"{r['kampala']['building_iou']:.3f}, Austin IoU {r['austin']['building_iou']:.3f}",
                          file=sys.stderr)
            rows += baselines(dataset, austin, a, resolution, seed)
        print(table(rows))
        if a.png:
            first = a.seeds[0]
            picture(a.png, out / f"kampala-z21-seed{first}", austin,
                    [r for r in rows if r["variant"] == rows[0]["variant"] and r["seed"] == first
                     and r["checkpoint"] != "best.pt"],
                    next(r for r in rows if r["variant"] == "baseline balanced" and r["seed"] == first))
        if a.json:
            settings = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(a).items()}
            report = {"settings": dict(settings, train_args=variants),
                      "seeds": {"each": "validation strip, training and baseline subsample of one run",
                                "used": a.seeds},
                      "training_resolution_m": resolution, "datasets": {str(k): v for k, v in datasets.items()},
                      "summary": summary(rows),
                      "results": [{k: v for k, v in r.items() if k != "_masks"} for r in rows]}
            a.json.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    finally:
        if a.out is None:
            shutil.rmtree(out, ignore_errors=True)


if __name__ == "__main__":
    main()
