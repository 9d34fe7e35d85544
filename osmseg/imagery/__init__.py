"""Imagery providers behind one interface, chosen by an ``--imagery`` spec.

========================  ==============================================================
``bing`` / ``bing:SET``   Bing Maps (key from ``BING_MAPS_KEY``), imagery set ``Aerial``
``xyz:TEMPLATE``          any ``{z}/{x}/{y}`` / ``{q}`` tile URL, or a ``file://`` folder
``geotiff:PATH``          a local GeoTIFF/COG in any CRS (a bare ``*.tif`` path works too)
``NAME``                  a provider of the xyzservices catalogue, e.g. ``Esri.WorldImagery``
                          (key, if any, from ``<FAMILY>_API_KEY``; see :mod:`.providers`)
========================  ==============================================================

Every provider returns an :class:`~osmseg.imagery.base.Imagery` for a sample grid: its pixels,
the tiles' provenance and which pixels are missing or placeholders. Imports: osmseg core below
it (grid, errors, net, redact); never OSM, the builder, training or localization.

>>> make_provider("geotiff:/no/such/file.tif", None)
Traceback (most recent call last):
osmseg.errors.ConfigError: GeoTIFF /no/such/file.tif does not exist: check the geotiff:PATH
>>> make_provider("bing", None, env={})
Traceback (most recent call last):
osmseg.errors.ConfigError: --imagery bing needs BING_MAPS_KEY (Bing Maps Basic keys no longer exist): use --imagery Esri.WorldImagery, which needs no key, another provider name, xyz:TEMPLATE or geotiff:PATH
>>> make_provider("Esri.WorldImagry", None)  # doctest: +ELLIPSIS
Traceback (most recent call last):
osmseg.errors.ConfigError: unknown imagery 'Esri.WorldImagry': use bing (with BING_MAPS_KEY), a provider name such as Esri.WorldImagery, xyz:TEMPLATE or geotiff:PATH; close names: Esri.WorldImagery, ...
"""

from __future__ import annotations

import os
from collections.abc import Mapping

from osmseg.errors import ConfigError
from osmseg.imagery.base import Imagery, ImageryProvider
from osmseg.imagery.bing import BingProvider
from osmseg.imagery.geotiff import GeoTiffProvider
from osmseg.imagery.providers import (
    KEYLESS_DEFAULT,
    AerialProvider,
    NamedProvider,
    aerial_providers,
    close_names,
    find_tile_provider,
)
from osmseg.imagery.xyz import XYZProvider
from osmseg.net.http import HttpClient

__all__ = [
    "KEYLESS_DEFAULT",
    "AerialProvider",
    "BingProvider",
    "GeoTiffProvider",
    "Imagery",
    "ImageryProvider",
    "NamedProvider",
    "XYZProvider",
    "aerial_providers",
    "missing_bing_key",
    "make_provider",
]

BING_KEY_ENV = "BING_MAPS_KEY"
RASTER_SUFFIXES = (".tif", ".tiff", ".vrt")
CHOICES = (
    f"bing (with BING_MAPS_KEY), a provider name such as {KEYLESS_DEFAULT}, xyz:TEMPLATE or geotiff:PATH"
)


def missing_bing_key(asked: bool) -> str:
    """The one phrase for Bing without ``BING_MAPS_KEY`` (``asked``: ``--imagery bing`` was given).

    >>> missing_bing_key(False)
    'no --imagery given, and the default, Bing Maps, needs BING_MAPS_KEY (Bing Maps Basic keys no longer exist)'
    """
    who = "--imagery bing needs" if asked else "no --imagery given, and the default, Bing Maps, needs"
    return f"{who} {BING_KEY_ENV} (Bing Maps Basic keys no longer exist)"


def make_provider(
    spec: str, client: HttpClient | None, env: Mapping[str, str] = os.environ, tile_size: int | None = None
) -> ImageryProvider:
    """The provider an ``--imagery`` spec names.

    ``client`` is the build's shared HTTP client (None is enough for ``geotiff:`` and
    ``xyz:file://``).  ``env`` supplies ``BING_MAPS_KEY``, ``{env:NAME}`` template keys and
    the ``<FAMILY>_API_KEY`` of named providers.  Any other spec is looked up as an
    xyzservices name (:mod:`osmseg.imagery.providers`). ``tile_size`` (``--tile-size``) declares
    the px of a tile server's tiles where the provider does not say (every tile is checked
    against it); Bing's metadata says it, a GeoTIFF has no tiles.
    """
    spec = spec.strip()
    kind, _, arg = spec.partition(":")
    kind = kind.lower()
    if tile_size is not None and (kind in ("bing", "geotiff") or spec.lower().endswith(RASTER_SUFFIXES)):
        raise ConfigError(f"--tile-size is for tile servers (xyz:TEMPLATE, a provider name); --imagery {kind} says "
                          "its own: leave --tile-size out")
    if kind == "bing":
        key = env.get(BING_KEY_ENV, "")
        if not key:
            raise ConfigError(f"{missing_bing_key(True)}: use --imagery {KEYLESS_DEFAULT}, which needs no key, "
                              "another provider name, xyz:TEMPLATE or geotiff:PATH")
        if client is None:
            raise ConfigError("--imagery bing needs an HTTP client")
        return BingProvider(client, key, imagery_set=arg or "Aerial")
    if kind == "xyz":
        if not arg:
            raise ConfigError(
                "--imagery xyz: needs a template, e.g. xyz:https://host/{z}/{x}/{y}.png"
            )
        return XYZProvider(arg, client, env=env, tile_size=tile_size)
    if kind == "geotiff":
        if not arg:
            raise ConfigError("--imagery geotiff: needs a path, e.g. geotiff:ortho.tif")
        return GeoTiffProvider(arg)
    if spec.lower().endswith(RASTER_SUFFIXES):
        return GeoTiffProvider(spec)
    entry = find_tile_provider(spec)
    if entry is not None:
        return NamedProvider(entry, client, env=env, tile_size=tile_size)
    close = close_names(spec)
    hint = f"; close names: {', '.join(close)}" if close else ""
    raise ConfigError(f"unknown imagery {spec!r}: use {CHOICES}{hint}")
