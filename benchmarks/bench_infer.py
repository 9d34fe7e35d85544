"""Inference time and memory: split-join (blend, crop) and rescale, beside the bare window forwards.

Run: ``.venv/bin/python benchmarks/bench_infer.py [--full-split-join]`` (prints, asserts
nothing). First each network side by side (SegNet with skips at the CPU width 0.125, SegNet as
published at width 1.0, unet-lite0): a bare forward of the whole 1280x1280 tile and
``osmseg predict``'s default (split-join, blend), in seconds and tiles per second, and the
process's RSS peak. The 1280x1280 image is a sample of the offline ``osmseg demo`` dataset (built in a
temporary folder); the 2048x2048 one is ``../shared/data/oam-rgb/manila.tif`` (that part is
skipped when ``../shared/data`` is absent). Every figure is measured in this run:

* each mode beside the *bare forwards*: the same number of 360x480 forwards of the same
  network on random tensors already in memory, batched the same way (:meth:`WindowGrid.blocks`
  gives the windows and batches split-join runs) and in the memory layout predict hands the
  network (channels_last, from its HWC -> CHW permute), half of them run before the
  predictions and half after. ratio = predict time / bare time: what reading, normalising,
  softmax, blending or cropping, argmax and joining (for files also decoding and encoding)
  cost on top of the network (1.00 = nothing). The same ratio in CPU time is printed too: it
  moves much less than wall time when other processes share the CPUs.
* memory of each call: ``numpy +`` is the tracemalloc peak over what was traced before the
  call (numpy-side allocations: window stacks, the blend accumulator, the mask; torch tensors
  are not traced); ``RSS peak`` is the process's high-water mark during the call (VmHWM, reset
  before it after handing freed heap back to the OS).

1280x1280: :func:`training.inference.windows.predict_array` with the CPU config's width 0.125 in all
modes, and the paper's width 1.0 in rescale mode (one window); its split-join (20 windows,
seconds each on a CPU) only with ``--full-split-join``. 2048x2048: the GeoTIFF path,
:func:`training.inference.predict.predict_file` GeoTIFF -> GeoTIFF mask, whole raster in one block in all
modes, then blend block by block (``--block-size``, default 1280: four blocks): the two blend
runs each in a fresh process, so that their RSS peaks (and rises over the process with the
model loaded) compare without one run's leftovers in the other's. Models have random
weights: time does not depend on them.
"""

from __future__ import annotations

import argparse
import ctypes
import functools
import json
import logging
import os
import subprocess
import sys
import tempfile
import time
import tracemalloc
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np
import rasterio
import torch
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from training.inference.predict import predict_file  # noqa: E402
from training.inference.tiling import WindowGrid  # noqa: E402
from training.inference.windows import DEFAULT_OVERLAP_FRACTION, InferenceOptions, predict_array  # noqa: E402
from training.models.networks import Network, build_model, model_spec  # noqa: E402
from training.models.spec import ModelSpec  # noqa: E402

MANILA = ROOT.parent / "shared" / "data" / "oam-rgb" / "manila.tif"
SIZE = (360, 480)
T = TypeVar("T")
REPEAT_SINGLE = 3  # timings of a single window (rescale): median of this many
MODES = [("split-join", "blend"), ("split-join", "crop"), ("rescale", "blend")]  # rescale ignores join


# ------------------------------------------------------------------------------ memory
def _status_mb(key: str) -> float | None:
    """A line of /proc/self/status in MB (None off Linux)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


def _trim_and_reset_peak() -> None:
    """Give freed heap back to the OS (glibc) and reset the RSS high-water mark (Linux >= 4.0)."""
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):
        pass
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass


@dataclass(frozen=True)
class Result:
    """Wall and CPU seconds, numpy peak rise and RSS peak (and its rise) of one call, in MB."""

    seconds: float
    cpu: float
    numpy_rise: float
    rss_peak: float
    rss_rise: float

    def memory(self, rise: bool = False) -> str:
        extra = f" (+{self.rss_rise:4.0f})" if rise else ""
        return f"numpy +{self.numpy_rise:4.0f} MB, RSS peak {self.rss_peak:5.0f} MB{extra}"


def measure(fn: Callable[[], object]) -> Result:
    """Run ``fn`` once (tracemalloc must be on) and measure it."""
    _trim_and_reset_peak()
    before_rss = _status_mb("VmRSS") or 0.0
    before_traced = tracemalloc.get_traced_memory()[0]
    tracemalloc.reset_peak()
    start, cpu = time.perf_counter(), time.process_time()
    fn()
    seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
    peak = _status_mb("VmHWM") or 0.0
    return Result(seconds, cpu, (tracemalloc.get_traced_memory()[1] - before_traced) / 2**20, peak, peak - before_rss)


# ------------------------------------------------------------------------------- model
def window_batches(height: int, width: int, join: str, batch: int, block_size: int | None) -> list[int]:
    """Batch sizes split-join runs for an image: per block, its windows in batches of ``batch``."""
    overlap = (int(SIZE[0] * DEFAULT_OVERLAP_FRACTION), int(SIZE[1] * DEFAULT_OVERLAP_FRACTION))
    grid = WindowGrid.build(height, width, SIZE, overlap)
    sizes = []
    for block in grid.blocks(block_size, join):
        n = len(block.windows)
        sizes += [min(batch, n - first) for first in range(0, n, batch)]
    return sizes


class Bare:
    """The network alone: forwards of random 360x480 batches already in memory."""

    def __init__(self, model: Network) -> None:
        self.model = model.eval()
        self.inputs: dict[int, torch.Tensor] = {}

    @torch.inference_mode()
    def run(self, sizes: list[int]) -> tuple[float, float]:
        """(wall, CPU) seconds of one forward per batch size in ``sizes`` (each shape warmed up first)."""
        for b in sizes:
            if b not in self.inputs:
                self.inputs[b] = torch.randn(b, 3, *SIZE).contiguous(memory_format=torch.channels_last)
                self.model(self.inputs[b])  # untimed warm-up of this shape
        start, cpu = time.perf_counter(), time.process_time()
        for b in sizes:
            self.model(self.inputs[b])
        return time.perf_counter() - start, time.process_time() - cpu


def line(label: str, windows: int, r: Result, bare: tuple[float, float] | None, rise: bool = False) -> None:
    beside = " " * 53 if bare is None else (f"bare {windows:2d} fwd {bare[0]:6.2f} s   ratio {r.seconds / bare[0]:4.2f} "
                                             f"(CPU time {r.cpu / bare[1]:4.2f})")
    print(f"  {label:<26}{windows:3d} windows {r.seconds:6.2f} s   {beside}   {r.memory(rise)}", flush=True)


def bench(model: Network, height: int, width: int, batch: int, modes: list[tuple[str, str]],
          run: Callable[[str, str], Result], rise: bool = False) -> None:
    """Each (mode, join) measured by ``run`` beside the bare forwards of the same batches.

    Half the bare forwards run before the predictions and half after, so a change in the
    machine's load during the run weighs on both sides alike. A single window (rescale) is
    timed three times on each side and the medians kept: one forward is too short to trust once.
    """
    bare = Bare(model)
    batches = {key: window_batches(height, width, key[1], batch, None) if key[0] == "split-join" else [1]
               for key in modes}
    distinct = {tuple(s) for s in batches.values()}
    before = {k: median([bare.run(list(k[0::2])) for _ in range(REPEAT_SINGLE if len(k) == 1 else 1)])
              for k in distinct}
    results = {key: median([run(*key) for _ in range(REPEAT_SINGLE if len(batches[key]) == 1 else 1)])
               for key in modes}
    after = {k: bare.run(list(k[1::2])) for k in distinct}
    for (mode, join), sizes in batches.items():
        k = tuple(sizes)
        total = (before[k][0] + after[k][0], before[k][1] + after[k][1])
        line(f"{mode} {join}" if mode == "split-join" else mode, sum(sizes), results[(mode, join)], total, rise)


def median(runs: list[T]) -> T:
    """The run with the median wall time (a Result or a (wall, CPU) pair)."""
    return sorted(runs, key=lambda r: r.seconds if isinstance(r, Result) else r[0])[len(runs) // 2]  # type: ignore[index]


def params(model: Network) -> str:
    return f"{sum(p.numel() for p in model.parameters()) / 1e6:.2f} M params"


# ------------------------------------------------------------------------------ GeoTIFF
def tiny_model() -> tuple[Network, ModelSpec]:
    torch.manual_seed(0)
    spec = model_spec("airsegnet13", 0.125)
    return build_model(spec), spec


def geotiff_run(model: Network, spec: ModelSpec, out: Path, mode: str, join: str, batch: int,
                block: int | None) -> Result:
    options = InferenceOptions(mode=mode, join=join, batch_size=batch, block_size=block)
    return measure(lambda: predict_file(model, spec, MANILA, out, options))


def child_main(args: argparse.Namespace) -> None:
    """``--child``: one GeoTIFF prediction in this fresh process; prints its Result as JSON."""
    model, spec = tiny_model()
    predict_array(model, np.zeros((*SIZE, 3), np.uint8), spec)  # first-call costs out of the timing
    Bare(model).run([args.batch_size])  # and the first forward of a full batch (warms that shape)
    tracemalloc.start()
    block = args.block_size if args.block_size > 0 else None
    print(json.dumps(asdict(geotiff_run(model, spec, args.out, args.mode, args.join, args.batch_size, block))))


def in_child(args: argparse.Namespace, out: Path, mode: str, join: str, block: int | None) -> Result:
    """The same measurement in a fresh Python process (RSS not shared with earlier runs)."""
    cmd = [sys.executable, __file__, "--child", "--out", str(out), "--mode", mode, "--join", join,
           "--batch-size", str(args.batch_size), "--block-size", str(block or 0), "--threads", str(args.threads)]
    done = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return Result(**json.loads(done.stdout.strip().splitlines()[-1]))


# ------------------------------------------------------------------------ architectures
#: the networks side by side (issue 32): SegNet as trained on a CPU, as published, and unet-lite0
ARCHITECTURES = (("segnet-skip", 0.125), ("segnet", 1.0), ("unet-lite0", 1.0))


def architectures(rgb: np.ndarray, batch: int) -> None:
    """Each network on the 1280x1280 image: one bare forward of the whole tile (median of 3),
    and ``predict_array`` split-join blend (the default of ``osmseg predict``), as tiles per
    second and seconds per tile, with the RSS peak of the prediction."""
    print(f"{rgb.shape[1]}x{rgb.shape[0]} per network: a bare forward of the whole tile, and predict_array "
          "split-join blend (osmseg predict's default):")
    whole = torch.randn(1, 3, *rgb.shape[:2]).contiguous(memory_format=torch.channels_last)
    for arch, width in ARCHITECTURES:
        torch.manual_seed(0)
        spec = model_spec("airsegnet13", width, arch=arch)
        model = build_model(spec).eval()
        with torch.inference_mode():
            model(whole)  # warm-up
            forwards = []
            for _ in range(REPEAT_SINGLE):
                start = time.perf_counter()
                model(whole)
                forwards.append(time.perf_counter() - start)
        predict_array(model, rgb[:SIZE[0], :SIZE[1]], spec)  # first-call costs out of the timing
        predict = functools.partial(predict_array, model, rgb, spec, "split-join", join="blend", batch_size=batch,
                                    block_size=None)
        r = median([measure(predict) for _ in range(REPEAT_SINGLE)])
        print(f"  {arch:<12} width {width:<5g} ({params(model)}): forward {sorted(forwards)[len(forwards) // 2]:5.2f} s; predict "
              f"{r.seconds:5.2f} s a tile = {1 / r.seconds:5.2f} tiles/s, RSS peak {r.rss_peak:5.0f} MB", flush=True)
        del model


# --------------------------------------------------------------------------------- main
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--image", type=Path, help="a 1280x1280 RGB image (default: a demo sample)")
    parser.add_argument("--batch-size", type=int, default=4)
    parser.add_argument("--block-size", type=int, default=1280, help="block side for the block-wise GeoTIFF run")
    parser.add_argument("--full-split-join", action="store_true", help="also split-join at width 1.0 (slow on a CPU)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--mode", help=argparse.SUPPRESS)
    parser.add_argument("--join", help=argparse.SUPPRESS)
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)  # the demo build's per-feature warnings are not the point here
    torch.set_num_threads(args.threads)
    if args.child:
        child_main(args)
        return
    batch = args.batch_size
    tiny, tiny_spec = tiny_model()
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, {os.cpu_count()} CPUs, load average "
          f"{os.getloadavg()[0]:.1f}; batch {batch}, windows {SIZE[0]}x{SIZE[1]}, overlap "
          f"{DEFAULT_OVERLAP_FRACTION:.0%} of a window side; RSS after imports {_status_mb('VmRSS') or 0:.0f} MB")
    tracemalloc.start()

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        if args.image is None:
            from osmseg.builder.run import build
            from osmseg.demo import demo_config

            build(demo_config(work / "demo"), env=dict(os.environ, BING_MAPS_KEY="demo-key-not-secret"))
            args.image = sorted((work / "demo" / "images").glob("*.png"))[0]
        with Image.open(args.image) as im:
            rgb = np.asarray(im.convert("RGB"))
        height, width = rgb.shape[:2]

        def array(model: Network, spec: ModelSpec) -> Callable[[str, str], Result]:
            return lambda mode, join: measure(lambda: predict_array(model, rgb, spec, mode, join=join,
                                                                    batch_size=batch, block_size=None))

        architectures(rgb, batch)
        predict_array(tiny, rgb[:SIZE[0], :SIZE[1]], tiny_spec)  # first-call costs out of the timings
        print(f"{width}x{height} {args.image.name}, predict_array, width 0.125 ({params(tiny)}):")
        bench(tiny, height, width, batch, MODES, array(tiny, tiny_spec))

        torch.manual_seed(0)
        full_spec = model_spec("airsegnet13", 1.0)
        full = build_model(full_spec)
        print(f"{width}x{height} {args.image.name}, predict_array, width 1.0 ({params(full)}):")
        bench(full, height, width, batch, MODES if args.full_split_join else MODES[2:], array(full, full_spec))
        if not args.full_split_join:
            n = sum(window_batches(height, width, "blend", batch, None))
            print(f"  split-join at width 1.0: skipped ({n} windows, each about a rescale's bare forward on this "
                  "CPU); --full-split-join runs it")
        del full

        if not MANILA.exists():
            print(f"2048x2048 GeoTIFF: skipped, {MANILA} is absent (../shared/data)")
            return
        with rasterio.open(MANILA) as src:
            height, width = src.height, src.width
        out = work / "mask.tif"

        def geotiff(mode: str, join: str) -> Result:  # blend in a fresh process: its RSS is compared below
            if join == "blend" and mode == "split-join":
                return in_child(args, out, mode, join, None)
            return geotiff_run(tiny, tiny_spec, out, mode, join, batch, None)

        print(f"{width}x{height} {MANILA.name} -> GeoTIFF mask, predict_file (JPEG-in-GeoTIFF read, DEFLATE write), "
              f"width 0.125, whole raster in one block (blend: fresh process, RSS rise over it in brackets):")
        bench(tiny, height, width, batch, MODES, geotiff, rise=True)
        windows = sum(window_batches(height, width, "blend", batch, args.block_size))
        line(f"blend, blocks of {args.block_size}", windows, in_child(args, out, "split-join", "blend", args.block_size),
             None, rise=True)


if __name__ == "__main__":
    main()
