"""Training throughput of SegNet in images/s (training crops or patches per second), loop vs bare steps.

Run: ``.venv/bin/python benchmarks/bench_train.py [--dataset DIR] [--steps 4] [--full-steps 2]``
(prints, asserts nothing; builds the offline ``osmseg demo`` dataset in a temporary folder
unless ``--dataset`` names one). Every figure is measured in this run, beside a bare baseline:

* loop: :func:`training.run.engine.train_one_epoch` through the trainer's own parts
  (:func:`training.run.train.seeded_loader` over the recipe's augmented training set — random
  crops for the ``osmseg`` recipe, the grid of 360x480 patches for ``paper`` — its loss (class
  weights where the recipe has them), optimiser and schedule, GradScaler), timed over ``steps``
  batches after one warm-up batch (which also pays for starting the loader workers);
* bare: the same network and optimiser, forward + loss + backward + optimiser step on random
  tensors of the same shape already in memory (no data loading, no loss weights, no
  metrics, no scheduler), run right after the loop so it is just as warm;
* ratio = bare images/s / loop images/s: what the data loader and the loop cost on top of
  the network's own arithmetic (1.00 = nothing).

Configurations: the CPU config (width 0.125, default recipe: 16 crops of 128x128 a batch,
``training/configs/cpu.yaml``), the same width by ``--recipe paper`` (4 patches of 360x480),
unet-lite0 by its recipe (4 crops of 256x256, the loop with its moving average of the weights),
and the paper's network (width 1.0, batch 2 and only ``--full-steps`` steps on a CPU); with
CUDA, also width 1.0 at batch 4 with AMP + channels_last (``training/configs/gpu.yaml``).
Peak RSS is the main process's high-water mark during each configuration (reset between
them where Linux allows) and the largest loader worker's.
"""

from __future__ import annotations

import argparse
import gc
import json
import logging
import math
import os
import resource
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from training.datasets.classes import model_classes  # noqa: E402
from training.datasets.patches import PatchDataset, dataset_class_table, discover, validate, weights_from_histograms  # noqa: E402
from training.datasets.sampling import RandomCrops  # noqa: E402
from training.devices import Dist  # noqa: E402
from training.models.networks import build_model, model_spec  # noqa: E402
from training.run.config import TrainConfig  # noqa: E402
from training.run.engine import StepOptions, train_one_epoch  # noqa: E402
from training.run.fitting import SegmentationLoss, make_optimizer, make_scheduler, weight_average  # noqa: E402
from training.run.train import seeded_loader  # noqa: E402


@dataclass(frozen=True)
class Case:
    """One configuration to measure."""

    label: str
    width: float
    batch: int
    steps: int  # timed steps (after one warm-up step)
    device: torch.device
    recipe: str = "osmseg"
    amp: bool = False
    channels_last: bool = False
    arch: str = "segnet-skip"


# ------------------------------------------------------------------------------ memory
def reset_peak_rss() -> bool:
    """Reset this process's RSS high-water mark (Linux >= 4.0); False where that is not possible."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _status_mb(key: str) -> float | None:
    """A memory line of /proc/self/status in MB (None off Linux)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


def peak_rss_mb() -> float:
    """This process's peak RSS: VmHWM (since the last reset) or ru_maxrss (since start)."""
    peak = _status_mb("VmHWM")
    if peak is not None:
        return peak
    scale = 1024 * 1024 if sys.platform == "darwin" else 1024  # bytes on macOS, KiB on Linux
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / scale


def rss_mb() -> float:
    """This process's RSS now (its peak where the current value is not available)."""
    return _status_mb("VmRSS") or peak_rss_mb()


def worker_peak_rss_mb() -> float:
    """Largest peak RSS of any finished child process (the loader workers)."""
    scale = 1024 * 1024 if sys.platform == "darwin" else 1024
    return resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / scale


# ------------------------------------------------------------------------------- data
def demo_dataset(folder: Path) -> Path:
    """The 4-sample 1280x1280 ``osmseg demo`` dataset, built offline from its recorded fixtures."""
    from osmseg.builder.run import build
    from osmseg.demo import demo_config

    out = folder / "dataset"
    build(demo_config(out), env=dict(os.environ, BING_MAPS_KEY="demo-key-not-secret"))
    return out


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


# ------------------------------------------------------------------------------ measure
def measure(case: Case, dataset: Path, workers: int, seed: int = 0) -> dict[str, Any]:
    """Loop and bare throughput of one configuration, printed on two lines (and returned)."""
    reset_peak_rss()
    if case.device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(case.device)
    config = TrainConfig(dataset=dataset, out_dir=dataset, width=case.width,  # out_dir: nothing is written
                         recipe=case.recipe, arch=case.arch, batch_size=case.batch, loader_workers=workers, seed=seed, amp=case.amp,
                         channels_last=case.channels_last, max_steps_per_epoch=case.steps + 1)
    recipe = config.settings
    dataset_table = dataset_class_table(dataset)
    table, lut = model_classes(config.model, dataset_table)
    spec = model_spec(config.model, case.width, class_table=table, input_size=config.patch_size, arch=case.arch)
    files = discover(dataset)
    hist = validate(files, dataset_table.num_classes)
    if lut is not None:  # dataset ids -> model ids before counting, as the trainer does
        hist = np.stack([np.bincount(lut[:len(row)], weights=row, minlength=spec.num_classes) for row in hist])
    weights = weights_from_histograms(hist, spec.ignore_index) if recipe.class_weights != "none" else None
    common: dict[str, Any] = dict(mean=spec.mean, std=spec.std, augment=config.augment, ignore_index=spec.ignore_index,
                                  seed=seed, num_classes=dataset_table.num_classes, label_lut=lut)
    needed = (case.steps + 1) * case.batch
    train_set: PatchDataset
    if recipe.sampling == "random":
        shape = (recipe.crop, recipe.crop)
        train_set = RandomCrops(files, recipe.crop, needed, **common)
    else:
        shape = config.patch_size
        reps = math.ceil(needed / len(PatchDataset(files, config.patch_size, **common)))
        train_set = PatchDataset(files * reps, config.patch_size, **common)  # images repeated if too few batches

    torch.manual_seed(seed)
    model = build_model(spec).to(case.device)
    if case.channels_last:
        model = model.to(memory_format=torch.channels_last)
    params = sum(p.numel() for p in model.parameters())
    criterion = SegmentationLoss(weight=None if weights is None else weights.to(case.device),
                                 ignore_index=-100 if spec.ignore_index is None else spec.ignore_index, dice=recipe.dice)
    average = weight_average(model, recipe.ema)  # the loop pays for the moving average, the bare steps do not
    optimizer = make_optimizer(model, recipe)
    scheduler = make_scheduler(optimizer, recipe, config.epochs * (case.steps + 1))
    scaler = torch.amp.GradScaler(case.device.type, enabled=case.amp)
    opts = StepOptions(device=case.device, amp=case.amp, channels_last=case.channels_last,
                       max_steps=case.steps + 1)
    loader = seeded_loader(train_set, config, Dist(0, 1, 0, case.device), shuffle=True)
    train_set.set_epoch(0)
    if hasattr(loader.sampler, "set_epoch"):
        loader.sampler.set_epoch(0)

    ends: list[float] = []  # wall clock at the end of each step (loss.item() has synchronised)
    train_one_epoch(model, criterion, optimizer, scheduler, scaler, loader, opts, epoch=1,
                    on_step=lambda step, loss: ends.append(time.perf_counter()), freeze_bn=recipe.freeze_bn,
                    after_step=None if average is None else lambda: average.update_parameters(model))
    loop_time = ends[-1] - ends[0]  # steps 1..steps, after the warm-up step 0
    del loader  # shut the (persistent) workers down before the bare steps
    gc.collect()

    # Bare: same model and optimiser (warm from the loop), tensors already on the device.
    memory_format = torch.channels_last if case.channels_last else torch.contiguous_format
    x = torch.randn(case.batch, 3, *shape, device=case.device).contiguous(memory_format=memory_format)
    y = torch.randint(0, spec.num_classes, (case.batch, *shape), device=case.device)
    sync(case.device)
    bare_ends = [time.perf_counter()]
    for _ in range(case.steps):
        with torch.autocast(case.device.type, dtype=torch.float16, enabled=case.amp):
            loss = nn.functional.cross_entropy(model(x), y)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()  # type: ignore[no-untyped-call]
        optimizer.step()
        sync(case.device)
        bare_ends.append(time.perf_counter())
    bare_time = bare_ends[-1] - bare_ends[0]

    images = case.steps * case.batch
    loop_ips, bare_ips = images / loop_time, images / bare_time
    memory = f"peak RSS {peak_rss_mb():6.0f} MB, largest loader worker {worker_peak_rss_mb():5.0f} MB"
    if case.device.type == "cuda":
        memory += f", CUDA max allocated {torch.cuda.max_memory_allocated(case.device) / 2**20:6.0f} MB"
    print(f"{case.label:<34} ({params / 1e6:5.2f} M params) batch {case.batch} of {shape[0]}x{shape[1]}, "
          f"{case.steps} timed steps; {memory}")
    print(f"    loop {loop_ips:7.2f} img/s ({spread(ends)})   bare fwd+bwd+{recipe.optimizer} {bare_ips:7.2f} img/s "
          f"({spread(bare_ends)})   ratio {bare_ips / loop_ips:5.2f}", flush=True)
    return {"loop_images_per_s": loop_ips, "bare_images_per_s": bare_ips, "ratio": bare_ips / loop_ips,
            "batch": case.batch, "shape": list(shape), "peak_rss_mb": peak_rss_mb()}


def spread(ends: list[float]) -> str:
    """Mean seconds per step and the range of single steps, from the steps' end times."""
    steps = [b - a for a, b in zip(ends[:-1], ends[1:])]
    return f"{sum(steps) / len(steps):6.2f} s/step, {min(steps):.2f}..{max(steps):.2f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, help="an osmseg build output (default: build the demo dataset)")
    parser.add_argument("--steps", type=int, default=4, help="timed steps of the CPU config")
    parser.add_argument("--full-steps", type=int, default=2, help="timed steps at width 1.0 on the CPU")
    parser.add_argument("--cuda-steps", type=int, default=20, help="timed steps of the CUDA config")
    parser.add_argument("--loader-workers", type=int, default=2, help="DataLoader workers (cpu.yaml: 2)")
    parser.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    parser.add_argument("--skip-full", action="store_true", help="leave out width 1.0 on the CPU")
    parser.add_argument("--json", type=Path, help="also write every figure to this JSON file")
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)  # the demo build's per-feature warnings are not the point here
    torch.set_num_threads(args.threads)
    cpu = torch.device("cpu")
    cases = [Case("CPU config: width 0.125, CPU", 0.125, 16, args.steps, cpu),
             Case("width 0.125, CPU, --recipe paper", 0.125, 4, args.steps, cpu, recipe="paper"),
             Case("unet-lite0, lite0 recipe, CPU", 1.0, 4, args.steps, cpu, recipe="lite0", arch="unet-lite0")]
    if not args.skip_full:
        cases.append(Case("paper's network: width 1.0, CPU", 1.0, 2, args.full_steps, cpu, recipe="paper"))

    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        dataset = args.dataset or demo_dataset(Path(tmp))
        files = discover(dataset)
        print(f"dataset {dataset if args.dataset else 'osmseg demo'}: {len(files)} images, built/read in "
              f"{time.perf_counter() - start:.1f} s; torch {torch.__version__}, {torch.get_num_threads()} threads, "
              f"{args.loader_workers} loader workers, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}; "
              f"RSS after imports and data {rss_mb():.0f} MB")
        figures = {case.label: measure(case, dataset, args.loader_workers) for case in cases}
        if torch.cuda.is_available():
            gpu = torch.device("cuda")
            cuda = Case(f"width 1.0, {torch.cuda.get_device_name(gpu)}, AMP+channels_last", 1.0, 4,
                        args.cuda_steps, gpu, amp=True, channels_last=True, recipe="paper")
            figures[cuda.label] = measure(cuda, dataset, args.loader_workers)
        else:
            print("CUDA: skipped (no CUDA device here); on a GPU this also measures width 1.0, batch 4, "
                  "AMP + channels_last")
        print(f"load average at the end {os.getloadavg()[0]:.1f} (other processes on these CPUs slow both "
              "columns alike, but add noise to the ratio)")
        if args.json:
            args.json.write_text(json.dumps(figures, indent=1) + "\n")


if __name__ == "__main__":
    main()
