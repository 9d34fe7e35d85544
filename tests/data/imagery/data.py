#!/usr/bin/env python3
"""Write the imagery test fixtures in this folder (run it again to regenerate them).

Everything is synthetic and deterministic (fixed seed, no network).  Tile pixels encode
where they belong so tests can check positions:

* red   = 32 + 64 * (x % 3)  -- the tile's column (distinct for 3 neighbouring tiles)
* green = 32 + 64 * (y % 3)  -- the tile's row
* blue  = (col + row) // 2   -- a diagonal ramp inside the tile (catches flips/transposes)

Outputs (about 200 kB in all):

``bing.yaml``          vcrpy cassette: Bing Imagery Metadata (Aerial) JSON with the real
                       field names, then the 9 JPEG tiles of a 3x3 grid at z18 in Berlin
                       (URLs from the metadata's imageUrl template and subdomains, subdomain
                       = subdomains[int(quadkey, 4) % 4]); the south-east tile is Bing's
                       "no imagery" placeholder (``X-VE-Tile-Info: no-tile``).  The request
                       URIs carry no ``key``: tests replay with ``filter_query_parameters``.
``bing-refused.yaml``  the metadata call refused: HTTP 401 with Bing's JSON error body.
``xyz.yaml``           PNG tiles of the same grid from a Mapbox-style template
                       (``access_token`` filtered out): north-west tile half transparent,
                       south-west tile 404; plus a tile answered with an HTML page (corrupt)
                       and a tile refused with 401.
``tiles/18/X/Y.png``   the same grid as a local tile folder (for ``file://``): north-west
                       tile half transparent, north-east tile RGB without alpha, centre tile
                       a 512 px "retina" tile, south-west tile missing, plus one truncated
                       (corrupt) PNG outside the grid.
``*.tif``              small GeoTIFFs: ``utm-rgb.tif`` (EPSG:32633, red/green encode the
                       source column/row), ``wgs84-grey-nodata.tif`` (EPSG:4326, 1 band,
                       nodata 0 on its west third), ``rgba.tif`` (EPSG:3857, alpha 0 on its
                       north half), ``rgbn.tif`` (4 bands R,G,B,NIR without alpha),
                       ``no-crs.tif``, ``uint16.tif``, ``not-a-raster.tif`` (text).
"""

from __future__ import annotations

import io
import json
import random
import shutil
from pathlib import Path

import mercantile
import numpy as np
import rasterio
from PIL import Image
from rasterio.enums import ColorInterp
from rasterio.transform import from_origin
from vcr.request import Request
from vcr.serialize import serialize
from vcr.serializers import yamlserializer

HERE = Path(__file__).resolve().parent
LON, LAT, ZOOM = 13.4050, 52.5200, 18  # Berlin, Alexanderplatz area
SIZE = 3
USER_AGENT = "osmseg/0.1.0 (+https://github.com/osmseg/osmseg)"
BING_TEMPLATE = "https://ecn.{subdomain}.tiles.virtualearth.net/tiles/a{quadkey}.jpeg?g=14560"
BING_SUBDOMAINS = ["t0", "t1", "t2", "t3"]
XYZ_BASE = "https://api.mapbox.com/v4/mapbox.satellite"
XYZ_OTHER = "https://tiles.example.org"
SEED = 2022


def grid_tiles() -> list[mercantile.Tile]:
    """The 3x3 tiles around (LON, LAT), row-major from the north-west (as osmseg.grid does)."""
    centre = mercantile.tile(LON, LAT, ZOOM)
    half = SIZE // 2
    return [
        mercantile.Tile(centre.x + dx, centre.y + dy, ZOOM)
        for dy in range(-half, half + 1)
        for dx in range(-half, half + 1)
    ]


def tile_pixels(tile: mercantile.Tile, size: int = 256) -> np.ndarray:
    """The synthetic RGB content of ``tile`` (see the module docstring)."""
    row, col = np.mgrid[0:size, 0:size] * (256 / size)
    rgb = np.empty((size, size, 3), dtype=np.uint8)
    rgb[:, :, 0] = 32 + 64 * (tile.x % 3)
    rgb[:, :, 1] = 32 + 64 * (tile.y % 3)
    rgb[:, :, 2] = ((col + row) // 2).astype(np.uint8)
    return rgb


def encode(array: np.ndarray, fmt: str) -> bytes:
    buf = io.BytesIO()
    if fmt == "JPEG":
        Image.fromarray(array).save(buf, "JPEG", quality=92)
    else:
        Image.fromarray(array).save(buf, "PNG", optimize=True)
    return buf.getvalue()


def half_transparent(rgb: np.ndarray) -> np.ndarray:
    """RGBA with the left half fully transparent."""
    alpha = np.full(rgb.shape[:2], 255, dtype=np.uint8)
    alpha[:, : rgb.shape[1] // 2] = 0
    return np.dstack([rgb, alpha])


def interaction(uri: str, status: int, reason: str, headers: dict[str, str], body: bytes):
    request = Request("GET", uri, None, {"User-Agent": USER_AGENT})
    response = {
        "status": {"code": status, "message": reason},
        "headers": {
            name: [value] for name, value in {**headers, "Content-Length": str(len(body))}.items()
        },
        "body": {"string": body},
    }
    return request, response


def write_cassette(path: Path, interactions: list) -> None:
    requests, responses = zip(*interactions, strict=True)
    path.write_text(
        serialize({"requests": list(requests), "responses": list(responses)}, yamlserializer)
    )


def bing_metadata_body(trace: str) -> dict:
    return {
        "authenticationResultCode": "ValidCredentials",
        "brandLogoUri": "https://dev.virtualearth.net/Branding/logo_powered_by.png",
        "copyright": (
            "Copyright © 2025 Microsoft and its suppliers. All rights reserved. This API cannot be accessed"
            " and the content and any results may not be used, reproduced or transmitted in any manner without"
            " express written permission from Microsoft Corporation."
        ),
        "resourceSets": [
            {
                "estimatedTotal": 1,
                "resources": [
                    {
                        "__type": "ImageryMetadata:http://schemas.microsoft.com/search/local/ws/rest/v1",
                        "imageHeight": 256,
                        "imageUrl": BING_TEMPLATE,
                        "imageUrlSubdomains": BING_SUBDOMAINS,
                        "imageWidth": 256,
                        "imageryProviders": [
                            {
                                "attribution": "© 2025 Microsoft Corporation",
                                "coverageAreas": [
                                    {"bbox": [-90, -180, 90, 180], "zoomMax": 21, "zoomMin": 1}
                                ],
                            },
                            {
                                "attribution": "© 2025 Maxar",
                                "coverageAreas": [
                                    {"bbox": [-67, -179.99, 27, 0], "zoomMax": 21, "zoomMin": 14},
                                    {"bbox": [27, -32, 87, 180], "zoomMax": 21, "zoomMin": 14},
                                ],
                            },
                            {
                                "attribution": "Earthstar Geographics SIO",
                                "coverageAreas": [
                                    {"bbox": [-90, -180, 90, 180], "zoomMax": 8, "zoomMin": 1}
                                ],
                            },
                            {
                                "attribution": "© 2025 Vexcel Imaging",
                                "coverageAreas": [
                                    {
                                        "bbox": [40.4, -74.3, 41.0, -73.6],
                                        "zoomMax": 21,
                                        "zoomMin": 15,
                                    }
                                ],
                            },
                        ],
                        "vintageEnd": None,
                        "vintageStart": None,
                        "zoomMax": 21,
                        "zoomMin": 1,
                    }
                ],
            }
        ],
        "statusCode": 200,
        "statusDescription": "OK",
        "traceId": trace,
    }


def bing_refused_body(trace: str) -> dict:
    return {
        "authenticationResultCode": "InvalidCredentials",
        "brandLogoUri": "https://dev.virtualearth.net/Branding/logo_powered_by.png",
        "copyright": "Copyright © 2025 Microsoft and its suppliers. All rights reserved.",
        "errorDetails": [
            "Access was denied. You may have entered your credentials incorrectly, or you might not have"
            " access to the requested resource or operation."
        ],
        "resourceSets": [],
        "statusCode": 401,
        "statusDescription": "Unauthorized",
        "traceId": trace,
    }


def json_headers(rng: random.Random) -> dict[str, str]:
    return {
        "Cache-Control": "no-cache",
        "Content-Type": "application/json; charset=utf-8",
        "X-BM-TraceID": f"{rng.getrandbits(128):032x}",
        "X-MS-BM-WS-INFO": "0",
        "X-Content-Type-Options": "nosniff",
    }


def metadata_uri() -> str:
    query = "uriScheme=https&output=json&include=ImageryProviders"
    return f"https://dev.virtualearth.net/REST/v1/Imagery/Metadata/Aerial?{query}"


def write_bing(rng: random.Random) -> None:
    trace = f"{rng.getrandbits(128):032x}|DU00000D7D|0.0.0.0"
    meta = json.dumps(bing_metadata_body(trace), ensure_ascii=False).encode()
    items = [interaction(metadata_uri(), 200, "OK", json_headers(rng), meta)]
    tiles = grid_tiles()
    placeholder = np.full((256, 256, 3), 245, dtype=np.uint8)
    placeholder[96:160, 80:176] = 180  # Bing's grey "no imagery" picture, roughly
    for index, tile in enumerate(tiles):
        quadkey = mercantile.quadkey(tile)
        sub = BING_SUBDOMAINS[int(quadkey, 4) % len(BING_SUBDOMAINS)]
        uri = BING_TEMPLATE.replace("{subdomain}", sub).replace("{quadkey}", quadkey)
        headers = {
            "Cache-Control": "public, max-age=86400",
            "Content-Type": "image/jpeg",
            "ETag": '"14560"',
        }
        if index == len(tiles) - 1:
            body = encode(placeholder, "JPEG")
            headers["X-VE-Tile-Info"] = "no-tile"
        else:
            body = encode(tile_pixels(tile), "JPEG")
            headers["X-VE-TILEMETA-CaptureDatesRange"] = "6/1/2021-8/31/2021"
            headers["X-VE-TILEMETA-Product-IDs"] = "209"
        items.append(interaction(uri, 200, "OK", headers, body))
    write_cassette(HERE / "bing.yaml", items)

    refused = json.dumps(bing_refused_body(trace), ensure_ascii=False).encode()
    write_cassette(
        HERE / "bing-refused.yaml",
        [interaction(metadata_uri(), 401, "Unauthorized", json_headers(rng), refused)],
    )


def xyz_png(index: int, tile: mercantile.Tile) -> bytes:
    rgb = tile_pixels(tile)
    return encode(half_transparent(rgb) if index == 0 else rgb, "PNG")


def write_xyz() -> None:
    tiles = grid_tiles()
    items = []
    for index, tile in enumerate(tiles):
        uri = f"{XYZ_BASE}/{tile.z}/{tile.x}/{tile.y}.png"
        if index == 6:
            body = b'{"message":"Tile does not exist"}'
            items.append(
                interaction(uri, 404, "Not Found", {"Content-Type": "application/json"}, body)
            )
        else:
            items.append(
                interaction(uri, 200, "OK", {"Content-Type": "image/png"}, xyz_png(index, tile))
            )
    corrupt = mercantile.Tile(tiles[0].x - 5, tiles[0].y, ZOOM)
    html = b"<!DOCTYPE html><html><body><h1>Service temporarily unavailable</h1></body></html>"
    items.append(
        interaction(
            f"{XYZ_BASE}/{corrupt.z}/{corrupt.x}/{corrupt.y}.png",
            200,
            "OK",
            {"Content-Type": "text/html"},
            html,
        )
    )
    refused = mercantile.Tile(tiles[0].x - 10, tiles[0].y, ZOOM)
    body = b'{"message":"Not Authorized - Invalid Token"}'
    uri = f"{XYZ_OTHER}/{refused.z}/{refused.x}/{refused.y}.png"
    items.append(interaction(uri, 401, "Unauthorized", {"Content-Type": "application/json"}, body))
    write_cassette(HERE / "xyz.yaml", items)


def write_tile_folder() -> None:
    root = HERE / "tiles"
    shutil.rmtree(root, ignore_errors=True)
    tiles = grid_tiles()
    for index, tile in enumerate(tiles):
        path = root / str(tile.z) / str(tile.x) / f"{tile.y}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        if index == 6:
            continue  # missing tile
        if index == 4:
            path.write_bytes(encode(tile_pixels(tile, size=512), "PNG"))  # retina tile
        elif index == 2:
            path.write_bytes(encode(tile_pixels(tile), "PNG"))  # RGB, no alpha
        else:
            path.write_bytes(
                encode(
                    half_transparent(tile_pixels(tile))
                    if index == 0
                    else np.dstack([tile_pixels(tile), np.full((256, 256), 255, np.uint8)]),
                    "PNG",
                )
            )
    corrupt = mercantile.Tile(tiles[0].x - 5, tiles[0].y, ZOOM)
    path = root / str(corrupt.z) / str(corrupt.x) / f"{corrupt.y}.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(encode(tile_pixels(corrupt), "PNG")[:300])  # truncated


def write_tif(name: str, data: np.ndarray, crs: str | None, transform, **extra) -> None:
    profile = {
        "driver": "GTiff",
        "width": data.shape[2],
        "height": data.shape[1],
        "count": data.shape[0],
        "dtype": data.dtype.name,
        "crs": crs,
        "transform": transform,
        "compress": "deflate",
        **extra,
    }
    with rasterio.open(HERE / name, "w", **profile) as dst:
        dst.write(data)


def write_geotiffs() -> None:
    # UTM 33N raster centred near (LON, LAT): 100 x 100 px of 2 m; red/green = 2 * column/row
    from pyproj import Transformer

    east, north = Transformer.from_crs("EPSG:4326", "EPSG:32633", always_xy=True).transform(
        LON, LAT
    )
    left, top = round(east) - 100, round(north) + 100
    row, col = np.mgrid[0:100, 0:100]
    utm = np.stack([2 * col, 2 * row, np.full_like(col, 200)]).astype(np.uint8)
    write_tif("utm-rgb.tif", utm, "EPSG:32633", from_origin(left, top, 2.0, 2.0), photometric="RGB")

    # WGS84 grey raster, 1 band, nodata 0 on the west third
    grey = np.full((1, 60, 60), 150, dtype=np.uint8)
    grey[0, :, :20] = 0
    write_tif(
        "wgs84-grey-nodata.tif",
        grey,
        "EPSG:4326",
        from_origin(LON - 0.0015, LAT + 0.001, 0.00005, 0.00003),
        nodata=0,
    )

    # Web Mercator RGBA, alpha 0 on the north half
    x, y = mercantile.xy(LON, LAT)
    rgba = np.zeros((4, 80, 80), dtype=np.uint8)
    rgba[0], rgba[1], rgba[2], rgba[3] = 10, 120, 230, 255
    rgba[3, :40] = 0
    write_tif(
        "rgba.tif", rgba, "EPSG:3857", from_origin(x - 80, y + 80, 2.0, 2.0), photometric="RGB"
    )
    with rasterio.open(HERE / "rgba.tif", "r+") as dst:
        dst.colorinterp = [ColorInterp.red, ColorInterp.green, ColorInterp.blue, ColorInterp.alpha]

    # NAIP-like 4 bands R, G, B, NIR (no alpha): NIR must not be taken for alpha
    rgbn = np.stack([np.full((40, 40), v, np.uint8) for v in (90, 140, 60, 0)])
    write_tif("rgbn.tif", rgbn, "EPSG:3857", from_origin(x - 40, y + 40, 2.0, 2.0))
    with rasterio.open(HERE / "rgbn.tif", "r+") as dst:
        dst.colorinterp = [
            ColorInterp.red,
            ColorInterp.green,
            ColorInterp.blue,
            ColorInterp.undefined,
        ]

    write_tif("no-crs.tif", np.zeros((3, 8, 8), np.uint8), None, from_origin(0, 8, 1, 1))
    write_tif("uint16.tif", np.zeros((3, 8, 8), np.uint16), "EPSG:3857", from_origin(x, y, 1, 1))
    (HERE / "not-a-raster.tif").write_text("this is not a GeoTIFF\n")


def main() -> None:
    rng = random.Random(SEED)
    write_bing(rng)
    write_xyz()
    write_tile_folder()
    write_geotiffs()
    total = sum(p.stat().st_size for p in HERE.rglob("*") if p.is_file() and p.name != "data.py")
    print(f"wrote imagery fixtures to {HERE} ({total / 1024:.0f} kB)")


if __name__ == "__main__":
    main()
