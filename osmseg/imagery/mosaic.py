"""Shared tile handling for the tile providers (Bing, XYZ): decode, fetch in parallel, merge.

A tile provider only has to say how to get the bytes of one tile; this module turns the
bytes into pixels (:func:`decode_tile`), fetches the ``size x size`` tiles of a sample
concurrently (:func:`fetch_tiles`) and pastes them into one image on the sample grid
(:func:`assemble`).  A tile with no imagery (a provider placeholder, HTTP 404, a missing
file) becomes an invalid area instead of an error; bytes that are not an image raise
:class:`~osmseg.errors.ImageryError` naming the tile, because they mean something upstream
is wrong (an error page served as a tile, a damaged file) and silently blanking them would
hide it.

Every tile is checked before it is used (and, over HTTP, before it is cached):

* **its size**: a tile that is not the provider's declared tile size (256 px, or 512 for
  "@2x"/512-px providers, which are resampled to the 256-px grid) is an
  :class:`~osmseg.errors.ImageryError` (fetched again): a 128-px thumbnail or a tile of another
  pyramid answered in its place would otherwise be stretched into a sample that looks fine. A
  512-px tile where 256 were declared is a :class:`~osmseg.errors.ConfigError` at once (the
  declaration is wrong: ``--tile-size``), and an empty answer of any size (a 1x1 transparent or
  8x8 white "no tile" image) is what it says, as at the declared size;
* **whether it holds imagery at all**: a tile of one colour (:func:`is_uniform`: the "no
  imagery here" fill of most servers, a blank white or black tile) is a placeholder, counted
  per sample (``uniform_tiles`` in the manifest) and rejected as ``placeholder_imagery`` as
  the provider's own "no tile" answers are. Real imagery never has every pixel of a 256-px
  tile within :data:`UNIFORM_SPREAD` grey levels of each other (sensor and JPEG noise alone
  exceed it).
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

from osmseg.errors import ConfigError, ImageryError
from osmseg.grid import TILE_SIZE, SampleGrid
from osmseg.net.failures import stop_requests

logger = logging.getLogger(__name__)

#: alpha at or above this counts as imagery; below it (transparent tile parts) is invalid
ALPHA_VALID = 128
#: a tile whose pixels (with imagery) all lie within this many levels of each other, in each
#: band, is one colour: a placeholder (JPEG of a flat fill varies by 1-2 levels)
UNIFORM_SPREAD = 3
#: tile sizes a provider may declare (256-px tiles; 512 and 1024 for "@2x"/"@4x" and 512-px servers)
TILE_SIZES = (256, 512, 1024)


@dataclass(frozen=True)
class TilePixels:
    """Pixels of one tile, or none when the provider has no imagery there.

    Attributes:
        rgb: ``(256, 256, 3)`` uint8, or None for "no imagery".
        valid: ``(256, 256)`` bool (False where the tile is transparent), or None.
        placeholder: True when the provider has no imagery for this tile: it said so
            (Bing's ``X-VE-Tile-Info: no-tile``, HTTP 404/204, a missing file), or the tile is
            of one colour (``uniform``).
        uniform: True when the tile was answered but is of one colour (:func:`is_uniform`).
    """

    rgb: np.ndarray | None
    valid: np.ndarray | None
    placeholder: bool = False
    uniform: bool = False


#: the result for a tile the provider has no imagery for
NO_IMAGERY = TilePixels(rgb=None, valid=None, placeholder=True)
#: the result for a tile of one colour: a placeholder that was answered as a tile
UNIFORM_TILE = TilePixels(rgb=None, valid=None, placeholder=True, uniform=True)


def is_absent(pixels: TilePixels | None) -> bool:
    """Whether a tile server's answer says "no imagery here": none at all (a 404, an empty body), a
    placeholder or a tile of one colour, or a tile with no pixel of imagery (wholly transparent).
    Over HTTP such an answer is a verdict, asked again before it is believed
    (:meth:`osmseg.net.http.HttpClient.fetch`'s ``absent``).

    >>> is_absent(None), is_absent(NO_IMAGERY), is_absent(UNIFORM_TILE)
    (True, True, True)
    >>> is_absent(TilePixels(np.zeros((2, 2, 3), np.uint8), np.zeros((2, 2), bool)))
    True
    >>> is_absent(TilePixels(np.zeros((2, 2, 3), np.uint8), np.eye(2, dtype=bool)))
    False
    """
    return pixels is None or pixels.placeholder or pixels.valid is None or not pixels.valid.any()


def tile_name(tile: mercantile.Tile) -> str:
    """``z/x/y`` of a tile, the way messages and manifests name it.

    >>> tile_name(mercantile.Tile(x=3, y=5, z=4))
    '4/3/5'
    """
    return f"{tile.z}/{tile.x}/{tile.y}"


def decode_tile(data: bytes, what: str, tile_size: int = TILE_SIZE) -> TilePixels:
    """Decode PNG/JPEG/WebP tile bytes into RGB pixels and a validity mask, after checking them.

    Transparent pixels (alpha below :data:`ALPHA_VALID`, or a palette's transparent index)
    are invalid.  The tile must be ``tile_size`` px square, the provider's declared size
    (512-px tiles are then resampled to the 256-px grid), unless it is empty (wholly transparent,
    or of one colour); a tile of one colour is :data:`UNIFORM_TILE`.  ``what`` names the tile in
    error messages (``"tile 18/1/2 from ..."``).

    >>> buf = io.BytesIO(); Image.new("RGBA", (256, 256), (10, 20, 30, 0)).save(buf, "PNG")
    >>> px = decode_tile(buf.getvalue(), "tile 1/0/0")
    >>> px.rgb.shape, bool(px.valid.any())
    ((256, 256, 3), False)
    >>> buf = io.BytesIO(); Image.new("RGB", (256, 256), (255, 255, 255)).save(buf, "PNG")
    >>> decode_tile(buf.getvalue(), "tile 1/0/0").uniform
    True
    >>> noise = lambda n: Image.frombytes("RGB", (n, n), bytes(i * 7 % 256 for i in range(3 * n * n)))
    >>> buf = io.BytesIO(); noise(128).save(buf, "PNG")
    >>> decode_tile(buf.getvalue(), "tile 1/0/0")
    Traceback (most recent call last):
    osmseg.errors.ImageryError: tile 1/0/0 is 128x128 px where this provider's tiles are 256x256 px: a broken or substituted tile
    >>> buf = io.BytesIO(); noise(512).save(buf, "PNG")
    >>> decode_tile(buf.getvalue(), "tile 1/0/0")
    Traceback (most recent call last):
    osmseg.errors.ConfigError: tile 1/0/0 is 512x512 px where this provider's tiles are 256x256 px: if the provider's tiles are 512 px, declare it with --tile-size 512
    >>> buf = io.BytesIO(); Image.new("RGBA", (1, 1)).save(buf, "PNG")  # an empty answer of another size
    >>> bool(decode_tile(buf.getvalue(), "tile 1/0/0").valid.any())
    False
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
    if rgba.size != (tile_size, tile_size):
        return _other_size(rgba, what, tile_size)
    if rgba.size != (TILE_SIZE, TILE_SIZE):
        rgba = rgba.resize((TILE_SIZE, TILE_SIZE), Image.Resampling.LANCZOS)
    rgb, valid = _split(np.asarray(rgba, dtype=np.uint8))
    if is_uniform(rgb, valid):
        logger.debug("%s is of one colour: a placeholder, not imagery", what)
        return UNIFORM_TILE
    return TilePixels(rgb=rgb, valid=valid)


def _split(pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """RGB pixels (black where invalid) and the validity mask of decoded RGB or RGBA pixels."""
    if pixels.shape[2] == 4:
        valid = pixels[:, :, 3] >= ALPHA_VALID
        return np.where(valid[:, :, None], pixels[:, :, :3], 0).astype(np.uint8), valid
    return pixels, np.ones(pixels.shape[:2], dtype=bool)


def _other_size(rgba: Image.Image, what: str, tile_size: int) -> TilePixels:
    """A tile that is not the declared size: an empty answer (wholly transparent, or of one colour:
    the 1x1 or 8x8 "no tile" images some servers send) is what it says; a tile of another size
    osmseg knows (512 px where 256 were declared) means the declaration is wrong, which no retry
    mends (:class:`ConfigError`); any other size is a broken or substituted tile, fetched again."""
    rgb, valid = _split(np.asarray(rgba, dtype=np.uint8))
    if not valid.any():
        return TilePixels(rgb=np.zeros((TILE_SIZE, TILE_SIZE, 3), np.uint8), valid=np.zeros((TILE_SIZE, TILE_SIZE), bool))
    if is_uniform(rgb, valid):
        return UNIFORM_TILE
    width, height = rgba.size
    if width == height and width in TILE_SIZES:
        raise ConfigError(f"{what} is {width}x{height} px where this provider's tiles are {tile_size}x{tile_size} px: "
                          f"if the provider's tiles are {width} px, declare it with --tile-size {width}")
    raise ImageryError(f"{what} is {width}x{height} px where this provider's tiles are {tile_size}x{tile_size} px: "
                       "a broken or substituted tile")


def is_uniform(rgb: np.ndarray, valid: np.ndarray) -> bool:
    """Whether a tile is of one colour: at least half of it has imagery, and every pixel of that
    lies within :data:`UNIFORM_SPREAD` levels of the others in each band.

    >>> rgb = np.full((4, 4, 3), 200, np.uint8); every = np.ones((4, 4), bool)
    >>> is_uniform(rgb, every)
    True
    >>> rgb[0, 0] = 180; is_uniform(rgb, every)
    False
    >>> corner = np.zeros((4, 4), bool); corner[1:, 1:] = True; is_uniform(rgb, corner)
    True
    """
    count = int(np.count_nonzero(valid))
    if count * 2 < valid.size:
        return False
    pixels = rgb.reshape(-1, 3) if count == valid.size else rgb[valid]
    return bool((pixels.max(axis=0).astype(np.int16) - pixels.min(axis=0) <= UNIFORM_SPREAD).all())


def fetch_tiles(
    tiles: Sequence[mercantile.Tile],
    fetch_one: Callable[[mercantile.Tile], TilePixels],
    workers: int = 4,
) -> list[TilePixels]:
    """``fetch_one`` applied to every tile, ``workers`` at a time, results in tile order.

    On the first error (or Ctrl-C) the tiles not yet started are cancelled and the error is
    re-raised once the running ones have finished, so no thread keeps working behind the
    caller's back. When the process is stopping (Ctrl-C, SIGTERM), the running ones stop
    waiting between retries too (:func:`osmseg.net.failures.stop_requests`): a ``Retry-After``
    of minutes does not hold the command up.  The HTTP client's per-host limits still apply on top of ``workers``.
    """
    if workers <= 1 or len(tiles) <= 1:
        return [fetch_one(tile) for tile in tiles]
    with ThreadPoolExecutor(
        max_workers=min(workers, len(tiles)), thread_name_prefix="osmseg-tile"
    ) as pool:
        futures = [pool.submit(fetch_one, tile) for tile in tiles]
        try:
            return [future.result() for future in futures]
        except BaseException as exc:
            if not isinstance(exc, Exception):  # Ctrl-C, SIGTERM: the process is stopping, so are its
                stop_requests()                # requests' waits (the pool waits for its threads)
            for future in futures:
                future.cancel()
            raise


def assemble(grid: SampleGrid, parts: Sequence[TilePixels]) -> tuple[np.ndarray, np.ndarray, int]:
    """Paste per-tile pixels into the sample image: ``(rgb, valid, placeholder_count)``.

    ``parts[i]`` belongs to ``grid.tiles[i]`` and lands at ``grid.tile_offset(i)``.
    Tiles without imagery (placeholders, uniform tiles included) stay black and invalid.
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


def tile_lists(grid: SampleGrid, parts: Sequence[TilePixels]) -> dict[str, list[str]]:
    """The manifest's lists of a sample's tiles without imagery: those the provider said it has
    no imagery for (``no_imagery_tiles``) and those of one colour (``uniform_tiles``)."""
    pairs = list(zip(grid.tiles, parts, strict=True))
    return {"no_imagery_tiles": [tile_name(t) for t, p in pairs if p.placeholder and not p.uniform],
            "uniform_tiles": [tile_name(t) for t, p in pairs if p.uniform]}
