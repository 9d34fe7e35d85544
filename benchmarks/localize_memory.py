"""Memory of one ``osmseg localize`` command against the size of the aerial mask, as a user runs it.

Run: ``.venv/bin/python benchmarks/localize_memory.py [--sizes 5,25] [--work DIR] [--json PATH]``. Needs the
Kotka extract of ``../shared/data/helsinki-osm`` (skips with a message without it). For each size
(in 256 px tiles: 5 is the demo's 1280 px, 25 is 6400 px, about 1.9 km at 0.29 m/px):

1. the builder's label mask of Kotka at that size (benchmarks/osm_mask.py, a GeoTIFF);
2. one panorama rendered there by ``osmseg localize-bench --save-panoramas 1``, as saved;
3. ``osmseg localize`` of that panorama in that mask, the profile and the paper method, each in
   its own process: its maximum resident set (``os.wait4``, the kernel's figure for that
   process alone), its wall time, and the bytes per mask pixel above ``osmseg --version``
   (the interpreter and its imports), printed side by side; then the bytes each further mask
   pixel costs (the slope between the smallest and the largest size) beside the mask's one.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OSM = ROOT.parent / "shared" / "data" / "helsinki-osm" / "kotka.osm.pbf"
OSMSEG = [sys.executable, "-m", "osmseg"]
TABLES = ["--aerial-landmarks", "aerial13", "--aerial-table", "classes13.toml",
          "--ground-landmarks", "aerial13", "--ground-table", "classes13.toml"]


def measured(cmd: list[str]) -> tuple[float, float]:
    """``(max RSS in MB, seconds)`` of ``cmd`` run to its end; raises if it fails."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=ROOT)
    _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    stderr = proc.stderr.read().decode() if proc.stderr else ""
    if proc.returncode:
        raise SystemExit(f"{' '.join(cmd[2:])} failed ({proc.returncode}): {stderr.strip()[-400:]}")
    return usage.ru_maxrss / 1024, seconds


def query_of(mask: Path, resolution: str, work: Path) -> Path:
    """A rendered panorama of ``mask``'s first seeded viewpoint (class ids of the aerial table plus sky)."""
    bench = work / f"bench-{mask.stem}"
    subprocess.run([*OSMSEG, "-q", "localize-bench", str(mask), "--out", str(bench), "--aerial-resolution", resolution,
                    "--viewpoints", "1", "--methods", "profile", "--no-negatives", "--no-plots",
                    "--save-panoramas", "1"], check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
    return next((bench / "panoramas").glob("0000_*.png"))  # class ids, sky included: a query mask as saved


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", default="5,25", help="mask sizes in 256 px tiles, odd, comma separated")
    parser.add_argument("--work", type=Path, default=None, help="folder for the masks (default: a temporary one)")
    parser.add_argument("--json", type=Path, default=None, help="also write every figure there")
    args = parser.parse_args()
    if not OSM.is_file():
        print(f"skipped: {OSM} is not here (see ../shared/data/README)")
        return
    work = args.work or Path(tempfile.mkdtemp(prefix="localize-memory-"))
    work.mkdir(parents=True, exist_ok=True)
    base_mb, _ = measured([*OSMSEG, "--version"])
    print(f"osmseg --version: {base_mb:.0f} MB (the interpreter and its imports)")
    print(f"{'mask':>12} {'method':>8} {'max RSS':>9} {'above base':>11} {'bytes/px':>9} {'time':>7}")
    seen: dict[str, list[tuple[int, float]]] = {}
    rows: list[dict[str, object]] = []
    slopes: dict[str, float] = {}
    for tiles in (int(t) for t in args.sizes.split(",")):
        mask = work / f"kotka-{tiles}.tif"
        resolution = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "osm_mask.py"), str(OSM), str(mask),
                                     "--lon", "26.9475", "--lat", "60.5337", "--size", str(tiles)],
                                    check=True, capture_output=True, text=True, cwd=ROOT).stdout.split()[-1]
        query = query_of(mask, resolution, work)
        pixels = (256 * tiles) ** 2
        for method in ("profile", "paper"):
            mb, seconds = measured([*OSMSEG, "-q", "localize", "--ground", str(query), "--aerial", str(mask),
                                    "--aerial-resolution", resolution, "--method", method, *TABLES,
                                    "--out", str(work / f"loc-{tiles}-{method}")])
            print(f"{256 * tiles:>7} px² {method:>8} {mb:>6.0f} MB {mb - base_mb:>8.0f} MB "
                  f"{(mb - base_mb) * 2**20 / pixels:>9.1f} {seconds:>6.1f}s", flush=True)
            seen.setdefault(method, []).append((pixels, mb))
            rows.append({"size_px": 256 * tiles, "method": method, "max_rss_mb": mb, "above_base_mb": mb - base_mb,
                         "bytes_per_px": (mb - base_mb) * 2**20 / pixels, "seconds": seconds})
    for method, runs in seen.items():  # what each further pixel costs: the slope between the two extreme sizes
        (p0, m0), (p1, m1) = min(runs), max(runs)
        if p1 > p0:
            slopes[method] = (m1 - m0) * 2**20 / (p1 - p0)
            print(f"{method}: {(m1 - m0) * 2**20 / (p1 - p0):.1f} bytes per further mask pixel "
                  f"(the mask itself: 1 byte)")
    if args.json:
        args.json.write_text(json.dumps({"base_mb": base_mb, "runs": rows, "bytes_per_further_px": slopes}, indent=1),
                             encoding="utf-8")


if __name__ == "__main__":
    main()
