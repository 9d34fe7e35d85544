"""Shared tile handling for the tile providers (Bing, XYZ): decode, fetch in parallel, merge.

A tile provider only has to say how to get the bytes of one tile; this module turns the
bytes into pixels (:func:`decode_tile`), fetches the ``size x size`` tiles of a sample
concurrently (:func:`fetch_tiles`) and pastes them into one image on the sample grid
(:func:`assemble`).  A tile with no imagery (a provider placeholder, HTTP 404, a missing
file) becomes an invalid area instead of an error; bytes that are not an image raise
:class:`~osmseg.errors.ImageryError` naming the tile, because they mean something upstream
is wrong (an error page served as a tile, a damaged file) and silently blanking them would
hide it.
"""

from __future__ import annotations

import io
import logging
import warnings
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import mercantile
import numpy as np
from PIL import Image

from osmseg.errors import ImageryError
from osmseg.grid import TILE_SIZE, SampleGrid

logger = logging.getLogger(__name__)

#: alpha at or above this counts as imagery; below it (transparent tile parts) is invalid
ALPHA_VALID = 128


@dataclass(frozen=True)
class TilePixels:
    """Pixels of one tile, or none when the provider has no imagery there.

    Attributes:
        rgb: ``(256, 256, 3)`` uint8, or None for "no imagery".
        valid: ``(256, 256)`` bool (False where the tile is transparent), or None.
        placeholder: True when the provider said it has no imagery for this tile
            (Bing's ``X-VE-Tile-Info: no-tile``, HTTP 404/204, a missing file).
    """

    rgb: np.ndarray | None
    valid: np.ndarray | None
    placeholder: bool = False


#: the result for a tile the provider has no imagery for
NO_IMAGERY = TilePixels(rgb=None, valid=None, placeholder=True)


def tile_name(tile: mercantile.Tile) -> str:
    """``z/x/y`` of a tile, the way messages and manifests name it.

    >>> tile_name(mercantile.Tile(x=3, y=5, z=4))
    '4/3/5'
    """
    return f"{tile.z}/{tile.x}/{tile.y}"


def decode_tile(data: bytes, what: str) -> TilePixels:
    """Decode PNG/JPEG/WebP tile bytes into RGB pixels and a validity mask.

    Transparent pixels (alpha below :data:`ALPHA_VALID`, or a palette's transparent index)
    are invalid.  Tiles of another size (512 px "retina" tiles) are resampled to 256 px so
    they fit the grid.  ``what`` names the tile in error messages (``"tile 18/1/2 from ..."``).

    >>> buf = io.BytesIO(); Image.new("RGBA", (256, 256), (10, 20, 30, 0)).save(buf, "PNG")
    >>> px = decode_tile(buf.getvalue(), "tile 1/0/0")
    >>> px.rgb.shape, bool(px.valid.any())
    ((256, 256, 3), False)
    >>> decode_tile(b"<html>Service unavailable</html>", "tile 1/0/0")
    Traceback (most recent call last):
    osmseg.errors.ImageryError: tile 1/0/0 is not a readable image (32 bytes starting b'<html>Serv'): check the URL template / tile file
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            image = Image.open(io.BytesIO(data))
            image.load()
    except (
        OSError,
        SyntaxError,
        ValueError,
        Image.DecompressionBombWarning,
        Image.DecompressionBombError,
    ) as exc:
        logger.debug("cannot decode %s: %s", what, exc)
        raise ImageryError(
            f"{what} is not a readable image ({len(data)} bytes starting {data[:10]!r}): "
            "check the URL template / tile file"
        ) from None
    if image.mode in ("RGBA", "LA", "PA", "La", "RGBa") or "transparency" in image.info:
        rgba = image.convert("RGBA")
    else:
        rgba = image.convert("RGB")
    if rgba.size != (TILE_SIZE, TILE_SIZE):
        rgba = rgba.resize((TILE_SIZE, TILE_SIZE), Image.Resampling.LANCZOS)
    pixels = np.asarray(rgba, dtype=np.uint8)
    if pixels.shape[2] == 4:
        valid = pixels[:, :, 3] >= ALPHA_VALID
        rgb = np.where(valid[:, :, None], pixels[:, :, :3], 0).astype(np.uint8)
    else:
        valid = np.ones((TILE_SIZE, TILE_SIZE), dtype=bool)
        rgb = pixels
    return TilePixels(rgb=rgb, valid=valid)


def fetch_tiles(
    tiles: Sequence[mercantile.Tile],
    fetch_one: Callable[[mercantile.Tile], TilePixels],
    workers: int = 4,
) -> list[TilePixels]:
    """``fetch_one`` applied to every tile, ``workers`` at a time, results in tile order.

    On the first error (or Ctrl-C) the tiles not yet started are cancelled and the error is
    re-raised once the running ones have finished, so no thread keeps working behind the
    caller's back.  The HTTP client's per-host limits still apply on top of ``workers``.
    """
    if workers <= 1 or len(tiles) <= 1:
        return [fetch_one(tile) for tile in tiles]
    with ThreadPoolExecutor(
        max_workers=min(workers, len(tiles)), thread_name_prefix="osmseg-tile"
    ) as pool:
        futures = [pool.submit(fetch_one, tile) for tile in tiles]
        try:
            return [future.result() for future in futures]
        except BaseException:
            for future in futures:
                future.cancel()
            raise


def assemble(grid: SampleGrid, parts: Sequence[TilePixels]) -> tuple[np.ndarray, np.ndarray, int]:
    """Paste per-tile pixels into the sample image: ``(rgb, valid, placeholder_count)``.

    ``parts[i]`` belongs to ``grid.tiles[i]`` and lands at ``grid.tile_offset(i)``.
    Tiles without imagery stay black and invalid.
    """
    if len(parts) != len(grid.tiles):
        raise ValueError(f"expected {len(grid.tiles)} tiles, got {len(parts)}")
    rgb = np.zeros((grid.height, grid.width, 3), dtype=np.uint8)
    valid = np.zeros((grid.height, grid.width), dtype=bool)
    placeholders = 0
    for index, part in enumerate(parts):
        placeholders += part.placeholder
        if part.rgb is None or part.valid is None:
            continue
        col, row = grid.tile_offset(index)
        rgb[row : row + TILE_SIZE, col : col + TILE_SIZE] = part.rgb
        valid[row : row + TILE_SIZE, col : col + TILE_SIZE] = part.valid
    return rgb, valid, placeholders
