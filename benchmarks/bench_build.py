"""Dataset-builder throughput on real data: samples/s on 1 worker and on every core, beside the
per-sample floor of the same work done by bare library calls, measured in the same run.

Run: ``.venv/bin/python benchmarks/bench_build.py [--samples 64] [--long 2000]`` (needs
../shared/data; prints, asserts nothing). Sources are local, as a country-size build's are: the
Helsinki OSM extract (``helsinki-osm/helsinki.osm.pbf``) and a GeoTIFF in EPSG:3067 (the Finnish
grid, so every sample is warped) whose pixels are a real drone photo (``oam-rgb/manila.tif``,
mirrored 2x2 to cover the area at 0.3 m/px; it does not match the Helsinki OSM data, which does
not matter for speed and gives the encoders real photo content). Zoom 18, ``--max-unlabeled
0.95`` so that every attempt is accepted and samples = attempts.

Lines printed (each build is ``osmseg build`` as a user runs it, in a fresh process):

* ``cold``: the first build, which cuts the region and every sample's box from the PBF;
* ``warm, N workers``: the same build into a new folder with the cache warm, for ``--workers
  1`` and for every core, PNG and JPEG photos: wall seconds, samples/s of the whole build and
  "steady" (between the first and the last finished sample: start-up and finalising left
  out, which is what a long build sees), CPU seconds of all the build's processes (workers
  included: this process adopts the fork server's orphans) per sample, peak RSS of the
  largest process;
* ``identical``: the ``--workers 1`` and the all-cores folders hold the same bytes;
* ``floor``: per sample, the bare library calls doing the same work on the same boxes: a
  pyosmium pass over the sample's OSM extract, ``rasterio.features.rasterize`` of its features,
  a windowed read + ``reproject`` of the photo, encoding the photo, the two PNG masks and the
  label COG with the writer's settings, and SHA-256 of the four files; the same with the photo
  warped as osmseg warps it (:mod:`osmseg.imagery.remap`: PROJ on a lattice, OpenCV's bilinear
  ``remap``, four times cheaper than GDAL's warper here); then the build's
  marginal CPU per sample (the 1-worker build's CPU less the least of three 1-sample builds',
  over the samples but one) divided by each; and the photo's encoding with Pillow's PNG level 1
  (the encoder osmseg used before, in the issue's definition of the floor);
* ``read_features``: median over the boxes of :func:`osmseg.osm.features.read_features`
  beside a bare osmium pass over the same box file;
* ``--long N``: one all-cores JPEG build of N samples with the RSS of the builder and of its
  largest worker read from /proc when 100, 500, ... N samples are done.

``--json PATH`` also writes the builds' figures there (what ``docs/figures.py`` quotes).
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import logging
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import osmium
import rasterio
from PIL import Image
from rasterio.enums import Resampling
from rasterio.features import rasterize as bare_rasterize
from rasterio.warp import reproject, transform_bounds
from rasterio.windows import Window, from_bounds

ROOT = Path(__file__).resolve().parents[1]
R = TypeVar("R")
sys.path.insert(0, str(ROOT))

from osmseg.builder.config import BuildConfig, available_cores  # noqa: E402
from osmseg.builder.slots import attempt_grid  # noqa: E402
from osmseg.classes import load_class_table  # noqa: E402
from osmseg.grid import pad_bbox  # noqa: E402
from osmseg.imagery.remap import source_pixels, warp_bilinear  # noqa: E402
from osmseg.osm.features import read_features  # noqa: E402
from osmseg.osm.localfile import LocalFileSource  # noqa: E402
from osmseg.output.geotiff import encode_cog, write_class_metadata  # noqa: E402
from osmseg.output.writer import COMPRESS_LEVEL, PHOTO_COMPRESS_LEVEL, encode_jpeg, encode_png  # noqa: E402
from osmseg.places import Area  # noqa: E402

SHARED = ROOT.parent / "shared" / "data"
HELSINKI = SHARED / "helsinki-osm" / "helsinki.osm.pbf"
PHOTO = SHARED / "oam-rgb" / "manila.tif"
LON, LAT, RADIUS_KM = 24.944, 60.1715, 0.25


def make_imagery(path: Path) -> None:
    """A 4096x4096 RGB GeoTIFF in EPSG:3067 at 0.3 m/px centred on the area: manila.tif mirrored 2x2."""
    with rasterio.open(PHOTO) as src:
        rgb = src.read([1, 2, 3])
    top = np.concatenate([rgb, rgb[:, :, ::-1]], axis=2)
    rgb = np.concatenate([top, top[:, ::-1, :]], axis=1)
    _, height, width = rgb.shape
    from pyproj import Transformer

    x, y = Transformer.from_crs("EPSG:4326", "EPSG:3067", always_xy=True).transform(LON, LAT)
    res = 0.3
    transform = rasterio.transform.from_origin(x - width / 2 * res, y + height / 2 * res, res, res)
    with rasterio.open(path, "w", driver="GTiff", width=width, height=height, count=3, dtype="uint8",
                       crs="EPSG:3067", transform=transform, tiled=True, compress="deflate", photometric="RGB") as dst:
        dst.write(rgb)


@dataclass
class Run:
    wall: float
    cpu: float  # user + sys of every process of the build
    peak_mb: float  # largest resident set of any of its processes
    accepted: int
    steady: float  # samples/s between the first and the last finished sample (start-up and finalising left out)
    first: float  # seconds until the first sample was finished (start-up, cutting OSM data, one sample)
    last: float  # seconds from the last sample finished to the end (manifest, STAC, pictures)


def adopt_orphans() -> None:
    """Make this process the reaper of the build's orphans (Linux): a build's workers are children
    of its fork server, which outlives the build by a moment; reaped here, their CPU time counts."""
    if sys.platform.startswith("linux"):
        import ctypes

        ctypes.CDLL(None).prctl(36, 1, 0, 0, 0)  # PR_SET_CHILD_SUBREAPER


def reap_all(timeout: float = 15.0) -> None:
    """Wait for every remaining child (the fork server and its workers end once the build has)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            time.sleep(0.05)


def build_args(out: Path, cache: Path, tif: Path, samples: int, workers: int, fmt: str) -> list[str]:
    return [sys.executable, "-m", "osmseg", "-q", "build", "--lat", str(LAT), "--lon", str(LON), "--radius-km",
            str(RADIUS_KM), "--samples", str(samples), "--seed", "0", "--zoom", "18", "--imagery", f"geotiff:{tif}",
            "--osm", str(HELSINKI), "--max-unlabeled", "0.95", "--image-format", fmt, "--out", str(out),
            "--cache-dir", str(cache), "--workers", str(workers)]


def run_build(out: Path, cache: Path, tif: Path, samples: int, workers: int, fmt: str,
              watch: tuple[int, ...] = ()) -> tuple[Run, dict[int, tuple[float, float]]]:
    """Run one ``osmseg build`` in a fresh process; with ``watch``, the RSS (MB) of the builder and of
    its largest worker when that many samples are done."""
    shutil.rmtree(out, ignore_errors=True)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    # stderr to a file, not a pipe: the wall time ends when the command does (a shell's prompt
    # returns), not when the fork server, which holds a copy of stderr, has finished exiting too
    with tempfile.TemporaryFile() as err_file:
        proc = subprocess.Popen(build_args(out, cache, tif, samples, workers, fmt), stdout=subprocess.DEVNULL,
                                stderr=err_file)
        seen: dict[int, tuple[float, float]] = {}
        times: dict[int, float] = {}
        stop = threading.Event()
        threading.Thread(target=_watch, args=(proc.pid, out, (1, samples, *watch), seen, times, stop, start),
                         daemon=True).start()
        proc.wait()
        wall = time.perf_counter() - start
        err_file.seek(0)
        err = err_file.read()
    stop.set()
    reap_all()
    if proc.returncode != 0:
        sys.exit(f"build failed ({proc.returncode}): {err.decode()[-2000:]}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    accepted = sum(1 for _ in (out / "labels").glob("*.png"))
    span = times.get(samples, wall) - times.get(1, 0.0)
    steady = (samples - 1) / span if samples > 1 and span > 0 else float("nan")
    return Run(wall, cpu, after.ru_maxrss / 1024, accepted, steady, times.get(1, wall),
               wall - times.get(samples, wall)), seen


def _rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def _descendants(pid: int) -> list[int]:
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                kids = [int(k) for k in (task / "children").read_text().split()]
            except OSError:
                kids = []
            out += kids
            todo += kids
    return out


def _watch(pid: int, out: Path, marks: tuple[int, ...], seen: dict[int, tuple[float, float]],
           times: dict[int, float], stop: threading.Event, start: float) -> None:
    """Note when 1, N, ... samples are done, and the RSS of the builder and its largest worker then."""
    slots = out / ".osmseg-build" / "slots"
    while not stop.is_set() and len(times) < len(set(marks)):
        done = sum(1 for _ in slots.glob("*.json")) if slots.is_dir() else 0
        for mark in marks:
            if mark not in times and done >= mark:
                times[mark] = time.perf_counter() - start
                workers = [_rss_mb(p) for p in _descendants(pid)]
                seen[mark] = (_rss_mb(pid), max(workers, default=0.0))
        time.sleep(0.05)


FLOOR_PARTS = ("osmium pass", "rasterize", "read+warp", "photo", "masks", "label COG", "sha256")


def floor_per_sample(tif: Path, cache: Path, samples: int,
                     fmt: str) -> tuple[dict[str, float], float, float, float, float]:
    """Per sample, the CPU seconds of each bare library call doing the build's work (see the module
    doc), Pillow's PNG level 1 for the photo (the encoder osmseg used before), the same read with
    osmseg's warp (PROJ on a lattice + ``cv2.remap``) in place of ``reproject``, and the median
    read_features / bare-osmium-pass times (s) over the same boxes."""
    table = load_class_table("classes13.toml")
    config = BuildConfig(out_dir=Path("unused"), area=Area("Helsinki", LAT, LON, RADIUS_KM), imagery="", zoom=18,
                         samples=samples, seed=0)
    source = LocalFileSource(HELSINKI, cache / "osm")
    grids = [g for g in (attempt_grid(config, s, 0) for s in range(samples)) if g is not None]
    src = rasterio.open(tif)
    palette = table.palette()
    parts = dict.fromkeys(FLOOR_PARTS, 0.0)
    pillow, remapped, t_read, t_bare = 0.0, 0.0, [], []

    def timed_cpu(part: str, fn: Callable[[], R]) -> R:
        start = time.process_time()
        result = fn()
        parts[part] += time.process_time() - start
        return result

    for grid in grids:
        box = source.fetch(pad_bbox(grid.bbox, config.osm_padding_m)).paths[0]
        features = read_features([box], grid, table)  # not timed: the shapes the bare rasteriser burns
        shapes = [(f.geometry, f.class_id) for f in sorted(features, key=lambda f: f.order)]
        timed_cpu("osmium pass", lambda: sum(1 for _ in osmium.FileProcessor(str(box)).with_locations()))
        labels = timed_cpu("rasterize", lambda: bare_rasterize(shapes, out_shape=(grid.height, grid.width),
                                                               transform=grid.transform, fill=0, dtype="uint8"))

        def read_warp() -> np.ndarray:
            window = from_bounds(*transform_bounds("EPSG:3857", src.crs, *grid.xy_bounds), src.transform)
            window = window.round_offsets().round_lengths().intersection(Window(0, 0, src.width, src.height))
            data = src.read(window=window)
            rgb = np.zeros((3, grid.height, grid.width), np.uint8)
            reproject(data, rgb, src_transform=src.window_transform(window), src_crs=src.crs,
                      dst_transform=grid.transform, dst_crs="EPSG:3857", resampling=Resampling.bilinear)
            return np.ascontiguousarray(rgb.transpose(1, 2, 0))

        photo = timed_cpu("read+warp", read_warp)

        def read_remap() -> np.ndarray:  # the same window, warped as osmseg warps it
            window = from_bounds(*transform_bounds("EPSG:3857", src.crs, *grid.xy_bounds), src.transform)
            window = window.round_offsets().round_lengths().intersection(Window(0, 0, src.width, src.height))
            data = src.read(window=window)
            maps = source_pixels("EPSG:3857", grid.transform, (grid.height, grid.width), src.crs,
                                 src.window_transform(window))
            return warp_bilinear(data, *maps, alpha=False)

        start = time.process_time()
        read_remap()
        remapped += time.process_time() - start
        files = [timed_cpu("photo", lambda: encode_png(photo, PHOTO_COMPRESS_LEVEL) if fmt == "png"
                           else encode_jpeg(photo)),
                 *timed_cpu("masks", lambda: [encode_png(np.take(palette, labels, axis=0), COMPRESS_LEVEL),
                                              encode_png(labels, COMPRESS_LEVEL, runs=True)]),
                 timed_cpu("label COG", lambda: encode_cog(labels, "EPSG:3857", grid.transform, classes=True,
                                                           describe=lambda dst: write_class_metadata(dst, table)))]
        timed_cpu("sha256", lambda: [hashlib.sha256(data).hexdigest() for data in files])
        start = time.process_time()
        Image.fromarray(photo).save(io.BytesIO(), format="PNG", compress_level=1)
        pillow += time.process_time() - start
        t_read.append(_timed(lambda: read_features([box], grid, table)))
        t_bare.append(_timed(lambda: sum(1 for _ in osmium.FileProcessor(str(box)).with_locations())))
    n = len(grids)
    return ({k: v / n for k, v in parts.items()}, pillow / n, remapped / n, statistics.median(t_read),
            statistics.median(t_bare))


def _timed(fn: Callable[[], object], repeat: int = 3) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def tree(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and ".osmseg-build" not in p.parts}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=64, help="samples per timed build [64]")
    parser.add_argument("--long", type=int, default=0, help="also one all-cores JPEG build of this many samples "
                        "with RSS at 100, 500, ... (e.g. 2000)")
    parser.add_argument("--json", type=Path, help="also write the builds' figures to this JSON file")
    args = parser.parse_args()
    logging.disable(logging.WARNING)  # this script's own reads repair the extract's edge objects quietly
    if not (HELSINKI.exists() and PHOTO.exists()):
        sys.exit(f"skipped: {HELSINKI} or {PHOTO} is absent (../shared/data)")
    cores = available_cores()
    n = args.samples
    figures: dict[str, Any] = {"cores": cores, "samples": n, "warm": {}}
    adopt_orphans()
    with tempfile.TemporaryDirectory(prefix="bench-build-") as tmp:
        work = Path(tmp)
        tif = work / "photo-3067.tif"
        make_imagery(tif)
        cache = work / "cache"
        print(f"osmseg build, Helsinki PBF + real photo GeoTIFF (EPSG:3067), zoom 18, {cores} cores, "
              f"{n} samples per build")
        cold, _ = run_build(work / "cold", cache, tif, n, cores, "png")
        print(f"cold      {cores} workers png  {cold.wall:7.2f} s  (cuts the region and all {n} boxes from the PBF)")
        runs: dict[tuple[int, str], Run] = {}
        for fmt in ("png", "jpg"):
            for workers in sorted({1, cores}):
                run, _ = run_build(work / f"w{workers}-{fmt}", cache, tif, n, workers, fmt)
                runs[workers, fmt] = run
                figures["warm"][f"{workers} {fmt}"] = {"rate": run.accepted / run.wall, "steady": run.steady,
                                                       "cpu_per_sample_s": run.cpu / run.accepted,
                                                       "peak_mb": run.peak_mb}
                print(f"warm      {workers} worker{'s' if workers > 1 else ' '} {fmt}  {run.wall:7.2f} s  "
                      f"{run.accepted / run.wall:5.2f} samples/s (steady {run.steady:5.2f})  "
                      f"{run.cpu / run.accepted * 1000:4.0f} ms CPU/sample  peak RSS {run.peak_mb:4.0f} MB")
            if cores > 1:
                one, every = runs[1, fmt], runs[cores, fmt]
                same = tree(work / f"w1-{fmt}") == tree(work / f"w{cores}-{fmt}")
                print(f"scaling   {fmt}: {cores} workers / 1 worker = {one.wall / every.wall:4.2f}x samples/s "
                      f"(steady {every.steady / one.steady:4.2f}x); identical bytes: {'yes' if same else 'NO'}")
        # marginal CPU per sample: builds of n and of 1 sample, so fixed costs (imports, start-up) cancel
        for fmt in ("png", "jpg"):
            # the fixed cost (start-up, finalising): the least CPU of three 1-sample builds
            fixed = min(run_build(work / f"one-{fmt}", cache, tif, 1, 1, fmt)[0].cpu for _ in range(3))
            marginal = (runs[1, fmt].cpu - fixed) / (n - 1)
            parts, pillow, remapped, t_read, t_bare = floor_per_sample(tif, cache, n, fmt)
            floor = sum(parts.values())
            ours = floor - parts["read+warp"] + remapped
            figures.setdefault("floor", {})[fmt] = {"parts_s": parts, "floor_s": floor, "remapped_s": remapped,
                                                    "marginal_s": marginal}
            print(f"floor     {fmt}: bare calls {floor * 1000:4.0f} ms CPU/sample = "
                  + " + ".join(f"{k} {v * 1000:.0f}" for k, v in parts.items()))
            print(f"          with osmseg's warp (PROJ lattice + cv2.remap, {remapped * 1000:.0f} ms) in place of "
                  f"reproject: {ours * 1000:4.0f} ms")
            print(f"          build {marginal * 1000:4.0f} ms marginal CPU/sample (fixed {fixed - marginal:4.2f} s)"
                  f" = {marginal / floor:4.2f}x the floor, {marginal / ours:4.2f}x the floor with osmseg's warp"
                  + (f"; with Pillow's PNG level 1 for the photo ({pillow * 1000:.0f} ms) the floor would be "
                     f"{(floor - parts['photo'] + pillow) * 1000:.0f} ms" if fmt == "png" else ""))
        print(f"read_features {t_read * 1000:6.1f} ms  bare osmium pass {t_bare * 1000:6.1f} ms  "
              f"ratio {t_read / t_bare:4.2f} (median over {n} boxes)")
        if args.long:
            marks = tuple(m for m in (100, 500, 1000, 2000, 5000, 10000, 20000) if m < args.long) + (args.long,)
            run, seen = run_build(work / "long", cache, tif, args.long, cores, "jpg", watch=marks)
            print(f"long      {args.long} samples jpg, {cores} workers: {run.wall:7.1f} s "
                  f"{run.accepted / run.wall:5.2f} samples/s (steady {run.steady:5.2f}; first sample after "
                  f"{run.first:4.1f} s, dataset files in {run.last:4.1f} s), peak RSS {run.peak_mb:5.0f} MB")
            for mark in marks:
                builder, worker = seen.get(mark, (float("nan"), float("nan")))
                print(f"          RSS at {mark:6d} samples: builder {builder:6.0f} MB, largest worker {worker:6.0f} MB")
            figures["long"] = {"samples": args.long, "rate": run.accepted / run.wall, "steady": run.steady,
                               "builder_mb": [seen[m][0] for m in marks if m in seen],
                               "worker_mb": [seen[m][1] for m in marks if m in seen]}
        if args.json:
            args.json.write_text(json.dumps(figures, indent=2, sort_keys=True))


if __name__ == "__main__":
    main()
