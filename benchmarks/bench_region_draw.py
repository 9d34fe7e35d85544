"""Drawing a region's blocks from OpenStreetMap: each block read from the whole file (as region
search did up to issue 34) against one pass over the file for all blocks (now), side by side.

Run: ``.venv/bin/python benchmarks/bench_region_draw.py [--json PATH]``. Needs ``../shared/data``.

Cases, all real OSM extracts made by others (``../shared/data``):

* **Kotka**: the whole Kotka extract's box (110 blocks of 5x5 z18 tiles), ``kotka.osm.pbf``;
* **Helsinki**: Helsinki centre (the box of the region benches), ``helsinki.osm.pbf``;
* **Kotka, three files**: Kotka's blocks with the Kotka, Helsinki and West Oakland files all given
  as ``--osm`` (a split download, or a bigger file than the region): what every block had to
  read grows with the input, what the one pass reads does not.

Methods, each in its own process (CPU seconds of the process, peak resident set):

* **per block** (the baseline, what ``BlockMasks`` did): ``read_features(osm files, block)`` and
  ``rasterize``, for each block;
* **one pass**: :class:`localization.region.cache.BlockMasks` with ``prepare`` over every block
  (the builder's cutter: the region cut out once, then every block's extract in one write
  pass), then each block read from its extract.

The two are compared pixel by pixel: ``differing`` counts pixels whose class differs, over every
block. No cache folder is used, so each method draws every block; each block's classes are
written to a file as it is drawn (not kept), and every process runs before any comparison (on
Linux a child's peak starts from its parent's at the fork).
"""

from __future__ import annotations

import argparse
import json
import logging
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from localization.region.cache import BlockMasks  # noqa: E402
from localization.region.search import RegionConfig, region_blocks  # noqa: E402
from osmseg.classes import load_class_table  # noqa: E402
from osmseg.osm.features import read_features  # noqa: E402
from osmseg.rasterize import rasterize  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
KOTKA = DATA / "helsinki-osm" / "kotka.osm.pbf"
HELSINKI = DATA / "helsinki-osm" / "helsinki.osm.pbf"
OAKLAND = DATA / "oakland-osm" / "west-oakland.osm"
CASES: dict[str, tuple[tuple[float, float, float, float], tuple[Path, ...]]] = {
    "Kotka": ((26.93, 60.52, 26.97, 60.54), (KOTKA,)),
    "Helsinki": ((24.936, 60.165, 24.952, 60.178), (HELSINKI,)),
    "Kotka, three files": ((26.93, 60.52, 26.97, 60.54), (KOTKA, HELSINKI, OAKLAND)),
}
METHODS = ("per block", "one pass")


def draw(case: str, method: str, out: Path) -> dict[str, Any]:
    """Draw every block of ``case`` by ``method``; the classes go to ``out`` (raw uint8), figures are returned."""
    bbox, osm = CASES[case]
    table = load_class_table("classes13.toml")
    grids = [g for g, _ in region_blocks(RegionConfig(bbox))]
    start = time.process_time()
    with open(out, "wb") as raw:  # each block's classes as drawn, one after the other (not kept in memory)
        if method == "per block":
            for g in grids:
                raw.write(rasterize(read_features(list(osm), g, table), g, table).astype(np.uint8).tobytes())
        else:
            blocks = BlockMasks(list(osm), table, grids)
            blocks.prepare(range(len(grids)))
            for b in range(len(grids)):
                raw.write(blocks.mask(b).tobytes())
        cpu = time.process_time() - start
    return {"case": case, "method": method, "blocks": len(grids), "block_px": grids[0].height * grids[0].width,
            "cpu_s": round(cpu, 2),
            "peak_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, help="also write the rows here")
    ap.add_argument("--one", nargs=3, metavar=("CASE", "METHOD", "FILE"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    logging.disable(logging.WARNING)  # the extracts' cut-off ways are said once per block otherwise
    if args.one:
        print(json.dumps(draw(args.one[0], args.one[1], Path(args.one[2]))))
        return {}
    missing = [p for _, files in CASES.values() for p in files if not p.is_file()]
    if missing:
        sys.exit(f"{missing[0]} is missing: this benchmark needs ../shared/data")
    import tempfile

    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        # every process first, the comparisons after: a child's peak counts its parent's at the fork
        runs: dict[tuple[str, str], dict[str, Any]] = {}
        for case in CASES:
            for method in METHODS:
                raw = Path(tmp) / f"{list(CASES).index(case)}-{METHODS.index(method)}.u8"
                done = subprocess.run([sys.executable, __file__, "--one", case, method, str(raw)], check=True,
                                      capture_output=True, text=True)
                runs[case, method] = {**json.loads(done.stdout.strip().splitlines()[-1]), "file": raw}
        print(f"{'case':20} {'blocks':>6} {'per block CPU s':>16} {'one pass CPU s':>15} {'ratio':>6} "
              f"{'peak MB':>9} {'differing px':>13}")
        for case in CASES:
            got = {m: runs[case, m] for m in METHODS}
            size = got["one pass"]["block_px"]
            differing = 0
            with open(got["per block"].pop("file"), "rb") as fa, open(got["one pass"].pop("file"), "rb") as fb:
                for _ in range(got["one pass"]["blocks"]):
                    differing += int((np.fromfile(fa, np.uint8, size) != np.fromfile(fb, np.uint8, size)).sum())
            row = {"case": case, "blocks": got["one pass"]["blocks"], "per_block": got["per block"],
                   "one_pass": got["one pass"], "ratio": round(got["one pass"]["cpu_s"] / got["per block"]["cpu_s"], 3),
                   "differing_px": differing, "pixels": size * got["one pass"]["blocks"]}
            rows.append(row)
            print(f"{case:20} {row['blocks']:>6} {row['per_block']['cpu_s']:>16.1f} {row['one_pass']['cpu_s']:>15.1f} "
                  f"{row['ratio']:>6.2f} {row['per_block']['peak_mb']:>4}/{row['one_pass']['peak_mb']:<4} "
                  f"{row['differing_px']:>13}")
    doc = {"rows": rows}
    if args.json:
        args.json.write_text(json.dumps(doc, indent=2) + "\n")
    return doc


if __name__ == "__main__":
    main()
