"""Do overlapping samples agree on their shared ground pixels? Counts on the real Helsinki extract.

Run: ``.venv/bin/python benchmarks/overlap_agreement.py [--pairs 40] [--zooms 17 18 19]`` (needs
../shared/data, else prints "skipped"; prints, asserts nothing; about a minute). For each zoom,
``--pairs`` seeded pairs of 5x5-tile sample grids: the first around a random point of the extract, the second around a random tile
up to 3 tiles away (so the two overlap), each with the centre point a build would give it. Both
are drawn the way ``osmseg build`` draws a sample (:func:`osmseg.osm.features.read_features`
then :func:`osmseg.rasterize.rasterize`, classes13) from the same OSM file, and every pixel
the two boxes share is compared.

Pairs are counted apart by whether a box of theirs holds a loose end of the coastline (its
``osm_problems`` say "coastline in the box has loose ends"): the extract
(``helsinki-osm/helsinki.osm.pbf``, 24.935..24.953 E, 60.164..60.179 N) cuts the coast, and
the sea of a box that holds a cut end depends on where the end falls in it (see docs/osm.md),
a property of the data, not of the drawing. Differing pixels are also counted by class pair.
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

import mercantile
import numpy as np

from osmseg.classes import load_class_table
from osmseg.grid import LngLatBBox, SampleGrid, sample_grid
from osmseg.osm.features import FeatureSet, read_features
from osmseg.rasterize import rasterize

PBF = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "helsinki-osm" / "helsinki.osm.pbf"
EXTRACT = LngLatBBox(24.935, 60.164, 24.953, 60.179)


def shared_pixels(a: SampleGrid, b: SampleGrid, la: np.ndarray, lb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two label arrays cut to the pixels both grids cover (same zoom, tile-aligned)."""
    ox = (b.tiles[0].x - a.tiles[0].x) * 256
    oy = (b.tiles[0].y - a.tiles[0].y) * 256
    c0, c1 = max(0, ox), min(a.width, ox + b.width)
    r0, r1 = max(0, oy), min(a.height, oy + b.height)
    if c0 >= c1 or r0 >= r1:
        return np.zeros(0, np.uint8), np.zeros(0, np.uint8)
    return la[r0:r1, c0:c1], lb[r0 - oy:r1 - oy, c0 - ox:c1 - ox]


def loose_coast(features: FeatureSet) -> bool:
    """True if the box holds a loose end of the coastline (its sea is then the data's guess)."""
    return any("coastline in the box has loose ends" in p for p in features.problems)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=40)
    parser.add_argument("--zooms", type=int, nargs="+", default=[17, 18, 19])
    args = parser.parse_args()
    if not PBF.is_file():
        print(f"skipped: {PBF} is absent")
        return
    table = load_class_table("classes13.toml")
    names = {0: "unlabeled", **{c.id: c.name for c in table.classes}}
    for zoom in args.zooms:
        rng = np.random.default_rng([7, zoom])
        totals = {False: [0, 0, 0], True: [0, 0, 0]}  # loose coast: pairs, shared px, differing px
        kinds: dict[bool, Counter[tuple[str, str]]] = {False: Counter(), True: Counter()}
        for _ in range(args.pairs):
            lon, lat = rng.uniform(EXTRACT.west, EXTRACT.east), rng.uniform(EXTRACT.south, EXTRACT.north)
            a = sample_grid(lon, lat, zoom)
            dx, dy = rng.integers(-3, 4, size=2)
            t = a.tiles[len(a.tiles) // 2]
            tile = mercantile.Tile(t.x + int(dx), t.y + int(dy), zoom)
            w, s, e, n = mercantile.bounds(tile)
            b = sample_grid(rng.uniform(w, e), rng.uniform(s, n), zoom)
            fa, fb = read_features([PBF], a, table), read_features([PBF], b, table)
            sa, sb = shared_pixels(a, b, rasterize(fa, a, table), rasterize(fb, b, table))
            differ = sa != sb
            loose = loose_coast(fa) or loose_coast(fb)
            row = totals[loose]
            row[0] += 1
            row[1] += sa.size
            row[2] += int(differ.sum())
            for x, y in zip(sa[differ].tolist(), sb[differ].tolist()):
                first, second = sorted((names[x], names[y]))
                kinds[loose][first, second] += 1
        for loose, (pairs, shared, differ) in totals.items():
            label = "a box with loose coastline ends" if loose else "coastline complete in both boxes"
            by_pair = ", ".join(f"{a}/{b} {n}" for (a, b), n in kinds[loose].most_common())
            print(f"zoom {zoom}, {label}: {pairs} pairs, {shared} shared pixels, {differ} differ"
                  + (f" ({by_pair})" if by_pair else ""))


if __name__ == "__main__":
    main()
