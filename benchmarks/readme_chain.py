"""The README's real-data chain with three training seeds, beside the per-pixel baseline.

The README's Kampala example and its training block (``osmseg build ... --out data/kampala``,
``osmseg train data/kampala --out runs/kampala --config cpu.yaml --epochs 8``, ``osmseg eval`` on
its test split and on Inria's Austin tile with ``--resolution model``), run as written but for
``--seed S`` of the training (0, 1, 2), in a temporary folder. Beside them, the per-pixel baseline
of ``pixel_baseline.py`` (a balanced logistic regression on each pixel's colour and 7x7
neighbourhood) fitted on the same training split (``splits.json`` of the seed-0 run) and scored
on the same test images and on Austin brought to the model's resolution. Prints building IoU
and pixel accuracy per seed, their mean and spread (min-max), and the baseline's. Needs
``../shared/data`` and the ``bench`` extra (scikit-learn). About 10 minutes on 2 cores::

    .venv/bin/python benchmarks/readme_chain.py
"""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
from PIL import Image

from osmseg.output.manifest import read_manifest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
sys.path.insert(0, str(ROOT / "tests"))  # conftest
sys.path.insert(0, str(ROOT / "tests" / "project"))  # test_readme_chain
sys.path.insert(0, str(ROOT / "benchmarks"))

from pixel_baseline import back_to_grid, building_scores, fit_baseline, resample  # noqa: E402
from test_readme_chain import chain  # noqa: E402

SEEDS = (0, 1, 2)
BUILDING = 1  # classes13's building: the Kampala dataset's one class besides unlabeled


def run(args: list[str], cwd: Path) -> None:
    """``osmseg ARGS`` in ``cwd`` (the README's /data/ paths made the shared data's); its stderr on failure."""
    args = [a.replace("/data/", f"{SHARED}/") for a in args]
    done = subprocess.run([sys.executable, "-m", "osmseg", "-q", *args], cwd=cwd, capture_output=True, text=True,
                          env={**os.environ, "OSMSEG_CACHE_DIR": str(cwd / "cache")})
    if done.returncode:
        raise SystemExit(f"osmseg {shlex.join(args)} failed:\n{done.stderr[-2000:]}")


def with_seed(command: str, seed: int, run_dir: str) -> list[str]:
    """A README command (after ``osmseg``) for the run of ``seed``: its own run folder, eval folders inside it."""
    args = shlex.split(command)[1:]
    args = [a.replace("runs/kampala", run_dir) for a in args]
    if args[0] == "train":
        args += ["--seed", str(seed)]
    if args[0] == "eval" and "--pair" in args:
        args[args.index("--out") + 1] = f"{run_dir}/eval-austin"
    return args


def building_iou(metrics: Path) -> dict[str, float]:
    m = json.loads(metrics.read_text())
    return {"building_iou": float(m["per_class"]["building"]["iou"]), "pixel_accuracy": float(m["pixel_accuracy"])}


def baseline(work: Path, seed: int) -> dict[str, dict[str, float]]:
    """The balanced per-pixel baseline on the training split of the run of ``seed`` (the seed draws the
    split too), scored as the network was: on its test split, and on Austin at the model's resolution."""
    data = work / "data" / "kampala"
    splits = json.loads((work / "runs" / f"seed{seed}" / "splits.json").read_text())["splits"]
    def sample(name: str) -> tuple[np.ndarray, np.ndarray]:
        rgb = np.asarray(Image.open(data / "images" / f"{name}.png").convert("RGB"))
        return rgb, np.asarray(Image.open(data / "labels" / f"{name}.png")) == BUILDING
    train = [sample(n) for n in splits["train"]]
    model = fit_baseline([r for r, _ in train], [b for _, b in train], [np.ones(b.shape, bool) for _, b in train],
                         200_000, seed, balanced=True)
    tests = [sample(n) for n in splits["test"]]
    pred = np.concatenate([model.predict(r).ravel() for r, _ in tests])
    truth = np.concatenate([b.ravel() for _, b in tests])
    kampala = building_scores(pred, truth, np.ones_like(truth))
    with rasterio.open(SHARED / "inria-austin" / "image.tif") as src:
        rgb = np.moveaxis(src.read([1, 2, 3]), 0, -1)
        austin_m = abs(src.transform.a)
    with rasterio.open(SHARED / "inria-austin" / "buildings.tif") as src:
        austin_truth = src.read(1) == 255
    model_m = read_manifest(data).ground_resolutions()[0]
    austin_pred = back_to_grid(model.predict(resample(rgb, austin_m / model_m)), austin_truth.shape)
    austin = building_scores(austin_pred, austin_truth, np.ones_like(austin_truth))
    return {"kampala": {k: float(v) for k, v in kampala.items()}, "austin": {k: float(v) for k, v in austin.items()}}


def spread(values: list[float]) -> str:
    return f"{np.mean(values):.3f} ({min(values):.3f}-{max(values):.3f})"


def main() -> None:
    if not SHARED.exists():
        print(f"skipped: {SHARED} is absent")
        return
    commands = chain()
    work = Path(tempfile.mkdtemp(prefix="readme-chain-"))
    run(shlex.split(commands[0])[1:], work)  # the build, as written
    rows: list[dict[str, Any]] = []
    for seed in SEEDS:
        run_dir = f"runs/seed{seed}"
        began = time.monotonic()
        run(with_seed(commands[1], seed, run_dir), work)
        seconds = time.monotonic() - began
        for command in commands[2:]:
            if shlex.split(command)[1] != "predict":
                run(with_seed(command, seed, run_dir), work)
        rows.append({"seed": seed, "train_s": seconds,
                     "kampala": building_iou(work / run_dir / "eval" / "metrics.json"),
                     "austin": building_iou(work / run_dir / "eval-austin" / "metrics.json"),
                     "baseline": baseline(work, seed)})
    print("README chain (Kampala test split; Inria Austin with --resolution model): building IoU, pixel accuracy")
    for r in rows:
        b = r["baseline"]
        print(f"  seed {r['seed']}: Kampala {r['kampala']['building_iou']:.3f}, {r['kampala']['pixel_accuracy']:.3f} "
              f"(baseline {b['kampala']['building_iou']:.3f}, {b['kampala']['pixel_accuracy']:.3f}); "
              f"Austin {r['austin']['building_iou']:.3f}, {r['austin']['pixel_accuracy']:.3f} "
              f"(baseline {b['austin']['building_iou']:.3f}, {b['austin']['pixel_accuracy']:.3f}); "
              f"training {r['train_s']:.0f} s")
    for place in ("kampala", "austin"):
        print(f"  {place}: network mean (min-max) IoU {spread([r[place]['building_iou'] for r in rows])}, "
              f"pixel accuracy {spread([r[place]['pixel_accuracy'] for r in rows])}; per-pixel baseline IoU "
              f"{spread([r['baseline'][place]['building_iou'] for r in rows])}, pixel accuracy "
              f"{spread([r['baseline'][place]['pixel_accuracy'] for r in rows])}")


if __name__ == "__main__":
    main()
