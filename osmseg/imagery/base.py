"""The imagery provider interface: give a sample grid, get back a 1280x1280 RGB image.

Providers (``bing``, ``xyz:TEMPLATE``, ``geotiff:PATH``) differ only in where pixels come
from; every one returns an :class:`Imagery` on exactly the sample's Web Mercator grid
(:class:`osmseg.grid.SampleGrid`), so OSM masks line up with it by construction.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from osmseg.grid import SampleGrid


@dataclass
class Imagery:
    """Pixels of one sample plus what is needed to report where they came from.

    Attributes:
        rgb: ``(H, W, 3)`` uint8 image on the sample grid.
        valid: ``(H, W)`` bool, False where the provider had no imagery (Bing "no tile"
            placeholders, transparent/empty tiles, outside a GeoTIFF's footprint).
        placeholder_tiles: number of tiles without imagery: those the provider marked as "no
            imagery here" and those of one colour.
        uniform_tiles: how many of ``placeholder_tiles`` are tiles of one colour.
        info: JSON-able provenance for the manifest (provider, tile URLs with keys removed,
            capture dates when known). Never holds an API key.
    """

    rgb: np.ndarray
    valid: np.ndarray
    placeholder_tiles: int = 0
    info: dict[str, Any] = field(default_factory=dict)
    uniform_tiles: int = 0


class ImageryProvider(Protocol):
    """What the builder needs from an imagery source."""

    #: short name recorded in the manifest, e.g. "bing", "xyz", "geotiff"
    name: str
    #: attribution line required by the provider's terms
    attribution: str

    def fetch(self, grid: SampleGrid) -> Imagery:
        """Pixels for ``grid``. Raises :class:`osmseg.errors.ImageryError` or ``NetworkError``."""
        ...

    def describe(self) -> dict[str, Any]:
        """JSON-able description (no keys) for the manifest and the datasheet."""
        ...


@runtime_checkable
class ZoomRange(Protocol):
    """An imagery source that knows which zooms it serves (a named tile layer)."""

    def check_zoom(self, zoom: int) -> None:
        """ConfigError when ``zoom`` is outside the source's range, saying which zooms it has."""
        ...


@runtime_checkable
class CoveringImagery(Protocol):
    """An imagery source that can say, before a build writes anything, whether it has pixels over
    the sampling area (a raster or a tile folder of another place)."""

    def check_covers(self, west: float, south: float, east: float, north: float, zoom: int | None = None) -> None:
        """ConfigError when the source has no pixels over the box (lon/lat degrees)."""
        ...


@runtime_checkable
class ServedVerdicts(Protocol):
    """An imagery source whose "no imagery here" comes from a server (a tile server over HTTP): a
    verdict that may have been a passing fault, so a sample rejected for it is built again by a
    later run (:func:`osmseg.net.http.HttpClient.fetch`'s ``absent``). A tile folder or a raster
    file says it for good, and is not one."""

    def verdicts_served(self) -> bool:
        """True when this source's "no imagery here" answers come from a server."""
        ...


@runtime_checkable
class LocalRaster(Protocol):
    """An imagery source read from a raster file of a known ground resolution (a GeoTIFF)."""

    path: Path
    resolution_m: float | None  # metres per pixel on the ground, None when the CRS does not tell
