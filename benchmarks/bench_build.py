"""Dataset-builder speed on real OSM data: parse, rasterise, and whole-build throughput.

Run: ``.venv/bin/python benchmarks/bench_build.py [--samples 12]`` (needs ../shared/data;
prints, asserts nothing). Every figure is measured in this run, beside a bare baseline:

* parse: :func:`read_features` for one 1280x1280 z18 sample of the Helsinki extract, beside a
  bare osmium pass over the same extract with node locations (the floor for any osmium
  reader);
* rasterise: :func:`rasterize` beside one bare ``rasterio.features.rasterize`` call on the
  same geometries;
* build: ``osmseg build`` from local sources (the Helsinki PBF + a GeoTIFF in EPSG:3067
  rendered from it) with a warm cache, in samples/s, beside the sum of its stages.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import osmium
import rasterio
from rasterio.features import rasterize as bare_rasterize
from rasterio.warp import calculate_default_transform, reproject

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from osmseg.build import BuildConfig, build  # noqa: E402
from osmseg.classes import load_class_table  # noqa: E402
from osmseg.demo.render import render_aerial  # noqa: E402
from osmseg.rejection import FilterConfig  # noqa: E402
from osmseg.grid import sample_grid  # noqa: E402
from osmseg.osm.features import read_features  # noqa: E402
from osmseg.places import Area  # noqa: E402
from osmseg.rasterize import rasterize  # noqa: E402

HELSINKI = ROOT.parent / "shared" / "data" / "helsinki-osm" / "helsinki.osm.pbf"
CENTRE = (24.944, 60.1715)


def timed(fn, repeat: int = 3) -> tuple[float, object]:
    """Median wall time of ``repeat`` calls, and the last result."""
    times, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), result


def bare_osmium_pass(path: Path) -> int:
    """Read every object with node locations: what any osmium-based reader must at least do."""
    count = 0
    for _ in osmium.FileProcessor(str(path)).with_locations():
        count += 1
    return count


def render_geotiff(path: Path, table) -> None:
    """An EPSG:3067 GeoTIFF painted from the extract's labels over a 9x9-tile z18 block."""
    grid = sample_grid(*CENTRE, 18, size=9)
    labels = rasterize(read_features([HELSINKI], grid, table), grid, table)
    rgb = render_aerial(labels, seed=0).transpose(2, 0, 1)
    crs = "EPSG:3067"
    transform, width, height = calculate_default_transform("EPSG:3857", crs, grid.width, grid.height, *grid.xy_bounds)
    with rasterio.open(path, "w", driver="GTiff", width=width, height=height, count=3, dtype="uint8",
                       crs=crs, transform=transform, tiled=True, compress="deflate") as dst:
        for band in range(3):
            reproject(rgb[band], rasterio.band(dst, band + 1), src_transform=grid.transform, src_crs="EPSG:3857",
                      dst_transform=transform, dst_crs=crs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=12)
    args = parser.parse_args()
    if not HELSINKI.exists():
        sys.exit(f"skipped: {HELSINKI} is absent (../shared/data)")
    table = load_class_table("classes13.toml")
    grid = sample_grid(*CENTRE, 18)

    t_bare, n_objects = timed(lambda: bare_osmium_pass(HELSINKI))
    t_parse, features = timed(lambda: read_features([HELSINKI], grid, table))
    t_raster, labels = timed(lambda: rasterize(features, grid, table))
    shapes = [(f.geometry, f.class_id) for f in sorted(features, key=lambda f: f.order)]
    t_bare_raster, _ = timed(lambda: bare_rasterize(shapes, out_shape=(grid.height, grid.width),
                                                     transform=grid.transform, fill=0, dtype="uint8"))
    print(f"Helsinki extract: {HELSINKI.stat().st_size / 1e6:.2f} MB, {n_objects} objects; one sample "
          f"{grid.width}x{grid.height} px at z18 ({grid.ground_resolution:.2f} m/px), {len(shapes)} features")
    print(f"parse     read_features    {t_parse * 1000:8.1f} ms   bare osmium pass {t_bare * 1000:8.1f} ms   "
          f"ratio {t_parse / t_bare:5.2f}")
    print(f"rasterise rasterize        {t_raster * 1000:8.1f} ms   bare rasterio    {t_bare_raster * 1000:8.1f} ms   "
          f"ratio {t_raster / t_bare_raster:5.2f}")
    print(f"          classes present: {sorted(table.by_id[int(c)].name for c in np.unique(labels))}")

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        tif = work / "helsinki-3067.tif"
        render_geotiff(tif, table)

        def run(out: str) -> float:
            config = BuildConfig(
                out_dir=work / out, area=Area(name="Helsinki", lat=CENTRE[1], lon=CENTRE[0], radius_km=0.25),
                imagery=f"geotiff:{tif}", osm=str(HELSINKI), samples=args.samples, seed=0, zoom=18,
                filters=FilterConfig(max_unlabeled=0.95), cache_dir=work / "cache",
            )
            start = time.perf_counter()
            summary = build(config)
            elapsed = time.perf_counter() - start
            assert summary.accepted == args.samples, summary.lines()
            return elapsed

        cold = run("cold")
        warm = run("warm")  # same cache: OSM extracts already cut
        per_sample = warm / args.samples
        stages = t_parse + t_raster
        print(f"build     {args.samples} samples: cold {cold:6.2f} s, warm cache {warm:6.2f} s = "
              f"{args.samples / warm:5.2f} samples/s ({per_sample * 1000:.0f} ms/sample)")
        print(f"          parse+rasterise of a sample {stages * 1000:.0f} ms = {stages / per_sample:5.1%} of a warm "
              "sample; the rest is warping the GeoTIFF, encoding PNG/GeoTIFF files and hashing")


if __name__ == "__main__":
    main()
