"""Write the builder's label mask of an OSM file around a point as a GeoTIFF in EPSG:3857.

Run: ``.venv/bin/python benchmarks/osm_mask.py kotka.osm.pbf kotka.tif --lon 26.9475 --lat
60.5337 [--zoom 18] [--size 5]``: the ``size`` x ``size`` tiles at ``zoom`` around the point,
drawn by :func:`osmseg.osm.features.read_features` and :func:`osmseg.rasterize.rasterize` in
classes13, georeferenced so that ``osmseg localize-bench --renderer geometry --osm`` can place
its views on the ground. Prints the mask's ground resolution (m/px) for ``--resolution``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import rasterio  # noqa: E402
from rasterio.transform import from_bounds  # noqa: E402

from osmseg.classes import load_class_table  # noqa: E402
from osmseg.grid import sample_grid  # noqa: E402
from osmseg.osm.features import read_features  # noqa: E402
from osmseg.rasterize import rasterize  # noqa: E402


def main(argv: list[str] | None = None) -> float:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("osm", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--lon", type=float, required=True)
    ap.add_argument("--lat", type=float, required=True)
    ap.add_argument("--zoom", type=int, default=18)
    ap.add_argument("--size", type=int, default=5)
    args = ap.parse_args(argv)
    table = load_class_table("classes13.toml")
    grid = sample_grid(args.lon, args.lat, args.zoom, args.size)
    mask = rasterize(read_features([args.osm], grid, table), grid, table)
    b = grid.xy_bounds
    with rasterio.open(args.out, "w", driver="GTiff", width=mask.shape[1], height=mask.shape[0], count=1,
                       dtype="uint8", crs="EPSG:3857",
                       transform=from_bounds(b.left, b.bottom, b.right, b.top, mask.shape[1], mask.shape[0])) as d:
        d.write(mask, 1)
    print(f"{grid.ground_resolution:.4f}")
    return float(grid.ground_resolution)


if __name__ == "__main__":
    main()
