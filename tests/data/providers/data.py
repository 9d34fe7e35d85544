#!/usr/bin/env python3
"""Write the named-provider test fixtures in this folder (run it again to regenerate them).

Synthetic and deterministic (fixed seed, no network).  Tile pixels encode where they belong,
as in ``tests/data/imagery/data.py`` (whose helpers this script reuses):

* red   = 32 + 64 * (x % 3)  -- the tile's column
* green = 32 + 64 * (y % 3)  -- the tile's row
* blue  = (col + row) // 2   -- a diagonal ramp inside the tile (catches flips/transposes)

Outputs (vcrpy cassettes, the format ``osmseg build --record`` writes and ``--replay`` reads):

``esri.yaml``      Esri World Imagery (``--imagery Esri.WorldImagery``): the 25 JPEG tiles of
                   the 5 x 5 grid at z18 around (LON, LAT) in tinycity (Helsinki), at the
                   real server's URLs ``https://server.arcgisonline.com/ArcGIS/rest/services/
                   World_Imagery/MapServer/tile/{z}/{y}/{x}?blankTile=false`` (row before
                   column) with ArcGIS-style response headers; plus one tile west of the grid
                   answered 404 with an ArcGIS JSON error, as the server does for a missing
                   tile when asked ``blankTile=false``.
``maptiler.yaml``  MapTiler Satellite (needs ``MAPTILER_API_KEY``): one JPEG tile at
                   ``https://api.maptiler.com/tiles/satellite-v2/18/X/Y.jpg``, recorded the
                   way osmseg's recorder stores it, i.e. without the ``key`` parameter.
"""

from __future__ import annotations

import importlib.util
import random
from pathlib import Path

import mercantile

HERE = Path(__file__).resolve().parent
_spec = importlib.util.spec_from_file_location("imagery_data", HERE.parent / "imagery" / "data.py")
assert _spec is not None and _spec.loader is not None
imagery_data = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(imagery_data)
encode, interaction, tile_pixels, write_cassette = (
    imagery_data.encode, imagery_data.interaction, imagery_data.tile_pixels, imagery_data.write_cassette
)

ZOOM, SIZE, SEED = 18, 5, 2026
# the centre of the z18 tile holding (24.94, 60.17), inside tests/data/tinycity/tinycity.osm
CENTRE = mercantile.tile(24.94, 60.17, ZOOM)
_b = mercantile.bounds(CENTRE)
LON, LAT = (_b.west + _b.east) / 2, (_b.south + _b.north) / 2
ESRI = "https://server.arcgisonline.com/ArcGIS/rest/services/World_Imagery/MapServer/tile"
MAPTILER = "https://api.maptiler.com/tiles/satellite-v2"
DATE = "Mon, 14 Sep 2026 09:12:03 GMT"


def grid_tiles() -> list[mercantile.Tile]:
    """The 5 x 5 tiles around CENTRE, row-major from the north-west (as osmseg.grid does)."""
    half = SIZE // 2
    return [
        mercantile.Tile(CENTRE.x + dx, CENTRE.y + dy, ZOOM)
        for dy in range(-half, half + 1)
        for dx in range(-half, half + 1)
    ]


def missing_tile() -> mercantile.Tile:
    """A tile west of the grid that the server has no imagery for."""
    return mercantile.Tile(CENTRE.x - 10, CENTRE.y, ZOOM)


def esri_uri(tile: mercantile.Tile) -> str:
    return f"{ESRI}/{tile.z}/{tile.y}/{tile.x}?blankTile=false"


def etag(rng: random.Random) -> str:
    """An ETag in the base-36 style ArcGIS Online uses (e.g. ``"10i954m13i2"``)."""
    digits = "0123456789abcdefghijklmnopqrstuvwxyz"
    return '"' + "".join(rng.choice(digits) for _ in range(11)) + '"'


def write_esri(rng: random.Random) -> None:
    items = []
    for tile in grid_tiles():
        headers = {
            "Content-Type": "image/jpeg",
            "Cache-Control": "public, max-age=86400",
            "ETag": etag(rng),
            "Access-Control-Allow-Origin": "*",
            "X-Content-Type-Options": "nosniff",
            "Date": DATE,
        }
        items.append(interaction(esri_uri(tile), 200, "OK", headers, encode(tile_pixels(tile), "JPEG")))
    body = b'{"error":{"code":404,"message":"Not Found","details":[]}}'
    headers = {"Content-Type": "application/json;charset=utf-8", "Cache-Control": "no-cache", "Date": DATE}
    items.append(interaction(esri_uri(missing_tile()), 404, "Not Found", headers, body))
    write_cassette(HERE / "esri.yaml", items)


def write_maptiler(rng: random.Random) -> None:
    headers = {
        "Content-Type": "image/jpeg",
        "Cache-Control": "public, max-age=43200",
        "ETag": etag(rng),
        "Access-Control-Allow-Origin": "*",
        "Date": DATE,
    }
    uri = f"{MAPTILER}/{CENTRE.z}/{CENTRE.x}/{CENTRE.y}.jpg"
    write_cassette(HERE / "maptiler.yaml", [interaction(uri, 200, "OK", headers, encode(tile_pixels(CENTRE), "JPEG"))])


def main() -> None:
    rng = random.Random(SEED)
    write_esri(rng)
    write_maptiler(rng)
    total = sum(p.stat().st_size for p in HERE.glob("*.yaml"))
    print(f"wrote provider fixtures to {HERE} ({total / 1024:.0f} kB)")


if __name__ == "__main__":
    main()
