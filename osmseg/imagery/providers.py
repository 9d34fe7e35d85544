"""Named imagery providers from the xyzservices catalogue: ``--imagery Esri.WorldImagery``.

`xyzservices <https://xyzservices.readthedocs.io>`_ is the tile-provider catalogue folium,
geopandas and contextily use.  A catalogue entry becomes an :class:`~osmseg.imagery.xyz.XYZProvider`,
so tiles get the same fetching, decoding, caching and key hygiene as ``xyz:`` templates:

* template: ``build_url`` with the entry's variant, format etc.; ``{s}`` = the first
  subdomain (stable URLs for cache and cassettes), ``{r}`` = the entry's default (256 px),
  ``{-y}`` for ``tms`` entries; ArcGIS tile services get ``?blankTile=false`` (missing
  imagery is a 404, not a "Map data not yet available" picture);
* attribution: the entry's plain-text ``attribution`` (manifest.json, ATTRIBUTION.md), with
  the licence note of :data:`AERIAL_PROVIDERS` as ``terms``;
* a ``--zoom`` outside ``min_zoom``-``max_zoom`` is a one-line ConfigError naming the zoom
  to use; tiles wholly outside ``bounds`` are "no imagery" without a request;
* a key (``requires_token()``) comes from ``<FAMILY>_API_KEY`` (:func:`key_env_name`) and
  enters the template as ``{env:NAME}``, so only the request itself ever holds it.

Only aerial imagery makes sense as training images: :func:`aerial_providers` lists the
recommended ones; other names work but warn when they do not look like imagery.

>>> key_env_name("MapTiler.Satellite")
'MAPTILER_API_KEY'
>>> tile_template(find_tile_provider("esri world imagery"), {})
'https://server.arcgisonline.com/ArcGIS/rest/services/World_Imagery/MapServer/tile/{z}/{y}/{x}?blankTile=false'
"""

from __future__ import annotations

import difflib
import logging
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import mercantile
import xyzservices
import xyzservices.providers
from xyzservices import TileProvider

from osmseg.errors import ConfigError
from osmseg.grid import SampleGrid
from osmseg.imagery.base import Imagery
from osmseg.imagery.mosaic import NO_IMAGERY, TilePixels, tile_name
from osmseg.imagery.xyz import XYZProvider
from osmseg.net.http import HttpClient

logger = logging.getLogger(__name__)

#: a provider that needs no key and covers the world (what errors suggest)
KEYLESS_DEFAULT = "Esri.WorldImagery"
#: a provider's key is read from ``<FAMILY>`` + this, e.g. ``MAPTILER_API_KEY``
KEY_ENV_SUFFIX = "_API_KEY"
COMMERCIAL = "check the provider's terms before storing tiles or sharing a dataset"
UNREVIEWED = f"not reviewed by osmseg: {COMMERCIAL}"

_TOKEN_MARK = "<insert your"  # how xyzservices marks a key to fill in (see requires_token)
_ARCGIS_TILE = re.compile(r"/MapServer/tile/\{z\}/\{y\}/\{x\}$")
_LOOKS_AERIAL = re.compile(r"imagery|satellite|ortho|aerial|luchtfoto|swissimage|photo", re.I)
_HAS_LABELS = re.compile(r"hybrid|label|topo", re.I)


@dataclass(frozen=True)
class AerialProvider:
    """A recommended aerial provider: name, coverage, a one-line licence note (not legal
    advice), and whether an open licence allows building and sharing a dataset (with the
    attribution kept, as ATTRIBUTION.md does)."""

    name: str
    coverage: str
    terms: str
    open_licence: bool


#: Recommended aerial providers (checked against xyzservices 2026.9; see docs/imagery.md).
AERIAL_PROVIDERS: tuple[AerialProvider, ...] = (
    AerialProvider("Esri.WorldImagery", "world", f"commercial (Esri and its suppliers): {COMMERCIAL}", False),
    AerialProvider("USGS.USImagery", "USA", "US federal data, public domain (USGS The National Map); credit the USGS", True),
    AerialProvider("GeoportailFrance.orthos", "France", "IGN BD ORTHO, Licence Ouverte / Etalab 2.0 (open, attribution required)", True),
    AerialProvider("nlmaps.luchtfoto", "Netherlands", "PDOK Luchtfoto (Beeldmateriaal Nederland), CC-BY 4.0", True),
    AerialProvider("BasemapAT.orthofoto", "Austria", "basemap.at, CC-BY 4.0 (credit 'Datenquelle: basemap.at')", True),
    AerialProvider("SwissFederalGeoportal.SWISSIMAGE", "Switzerland", "swisstopo open government data: free use, credit '© swisstopo'", True),
    AerialProvider("MapTiler.Satellite", "world", f"commercial, key in MAPTILER_API_KEY: {COMMERCIAL}", False),
)


def _normal(name: str) -> str:
    """A name as xyzservices' ``query_name`` compares it: lower case, letters and digits only."""
    return re.sub(r"[^0-9a-z]", "", name.lower())


def catalogue() -> dict[str, TileProvider]:
    """Every provider of the installed xyzservices by its dotted name."""
    return dict(xyzservices.providers.flatten())


def aerial_providers() -> list[AerialProvider]:
    """The recommended aerial providers that the installed xyzservices knows.

    >>> [p.name for p in aerial_providers()][:2]
    ['Esri.WorldImagery', 'USGS.USImagery']
    >>> [p.name for p in aerial_providers() if p.open_licence][:1]
    ['USGS.USImagery']
    """
    known = catalogue()
    return [p for p in AERIAL_PROVIDERS if p.name in known]


def find_tile_provider(name: str) -> TileProvider | None:
    """The catalogue entry ``name`` means (any case and punctuation), or None."""
    if not _normal(name):
        return None
    try:
        return xyzservices.providers.query_name(name)
    except ValueError:
        return None


def close_names(name: str, count: int = 3) -> list[str]:
    """Web Mercator catalogue names that look like ``name``, for "did you mean" in errors.

    A family name alone (``Esri``) gives that family's recommended, then aerial, entries first.

    >>> close_names("Esri.WorldImagry")[0]
    'Esri.WorldImagery'
    >>> close_names("esri")[:1]
    ['Esri.WorldImagery']
    """
    names = sorted(n for n, p in catalogue().items() if p.get("crs") in (None, "EPSG:3857"))
    wanted = _normal(name)
    family = [n for n in names if _normal(n.split(".")[0]) == wanted]
    if family:
        curated = {p.name for p in AERIAL_PROVIDERS}
        return sorted(family, key=lambda n: (n not in curated, not _LOOKS_AERIAL.search(n), n))[:count]
    leaf = [n for n in names if _normal(n.split(".")[-1]) == wanted]  # "swissimage", "orthofoto"
    by_normal = {_normal(n): n for n in names}
    similar = [by_normal[m] for m in difflib.get_close_matches(wanted, list(by_normal), n=count, cutoff=0.6)]
    return list(dict.fromkeys(leaf + similar))[:count]


def key_env_name(provider_name: str, attribute: str | None = None) -> str:
    """The environment variable a provider's key is read from: ``<FAMILY>_API_KEY``.

    One key per company account, so the family (the part before the dot) names it.  An
    entry needing several keys gets one variable per attribute (``<FAMILY>_<ATTRIBUTE>``).

    >>> key_env_name("HERE.satelliteDay"), key_env_name("MapBox")
    ('HERE_API_KEY', 'MAPBOX_API_KEY')
    >>> key_env_name("Example.layer", "appCode")
    'EXAMPLE_APP_CODE'
    """
    family = re.sub(r"[^0-9A-Za-z]+", "_", provider_name.split(".")[0]).strip("_").upper()
    if attribute is None:
        return family + KEY_ENV_SUFFIX
    return f"{family}_{re.sub(r'(?<=[a-z0-9])(?=[A-Z])|[^0-9A-Za-z]+', '_', attribute).upper()}"


def token_attributes(provider: TileProvider) -> list[str]:
    """The entry's attributes that hold a key to fill in (what ``requires_token()`` checks)."""
    return sorted(
        k for k, v in provider.items()
        if isinstance(v, str) and _TOKEN_MARK in v and f"{{{k}}}" in str(provider.get("url", ""))
    )


def key_envs(provider: TileProvider) -> dict[str, str]:
    """Each key attribute of the entry and the environment variable it is read from.

    >>> key_envs(find_tile_provider("MapTiler.Satellite")), key_envs(find_tile_provider("Esri.WorldImagery"))
    ({'key': 'MAPTILER_API_KEY'}, {})
    """
    attrs = token_attributes(provider)
    return {a: key_env_name(str(provider.name), a if len(attrs) > 1 else None) for a in attrs}


def tile_template(provider: TileProvider, key_envs: Mapping[str, str]) -> str:
    """The entry's URL as an osmseg ``xyz`` template; key attributes become ``{env:NAME}``.

    ``key_envs`` maps each key attribute (:func:`token_attributes`) to its variable name.

    >>> tile_template(find_tile_provider("MapTiler.Satellite"), {"key": "MAPTILER_API_KEY"})
    'https://api.maptiler.com/tiles/satellite-v2/{z}/{x}/{y}.jpg?key={env:MAPTILER_API_KEY}'
    """
    fill = {attr: f"{{env:{env}}}" for attr, env in key_envs.items()}
    try:
        url = str(provider.build_url(**fill))  # {x}{y}{z} kept, first subdomain, default {r}
    except (KeyError, IndexError, ValueError) as exc:
        raise ConfigError(
            f"xyzservices entry {provider.name} has a URL osmseg cannot fill ({type(exc).__name__}: {exc}):"
            " use --imagery xyz:TEMPLATE"
        ) from None
    if provider.get("tms"):
        url = url.replace("{y}", "{-y}")
    if _ARCGIS_TILE.search(url):
        url += "?blankTile=false"  # ArcGIS: 404 for missing tiles instead of a picture of text
    return url


class NamedProvider(XYZProvider):
    """An :class:`XYZProvider` made from an xyzservices entry (see the module docstring).

    Args:
        provider: the catalogue entry (:func:`find_tile_provider`).
        client: the shared HTTP client.
        env: where ``<FAMILY>_API_KEY`` comes from (default: ``os.environ``).
        workers: tiles fetched at once (the client's per-host limit applies too).
        tile_size: the px of the server's tiles, when the entry does not say (its ``tileSize``).
    """

    name = "xyzservices"

    def __init__(
        self,
        provider: TileProvider,
        client: HttpClient | None = None,
        *,
        env: Mapping[str, str] | None = None,
        workers: int = 4,
        tile_size: int | None = None,
    ) -> None:
        env = os.environ if env is None else env
        self.provider_name = str(provider.name)
        label = f"--imagery {self.provider_name}"
        crs = provider.get("crs")
        if crs not in (None, "EPSG:3857"):
            raise ConfigError(f"{label} serves tiles in {crs}, not Web Mercator (EPSG:3857): pick another provider")
        self.key_envs = key_envs(provider)
        for var in self.key_envs.values():
            if not env.get(var):
                raise ConfigError(
                    f"{label} needs an API key: set {var} (export {var}=...)"
                    f" or use a provider without key such as --imagery {KEYLESS_DEFAULT}"
                )
        self.min_zoom = int(provider.get("min_zoom", 0))
        self.max_zoom: int | None = int(provider["max_zoom"]) if "max_zoom" in provider else None
        bounds = provider.get("bounds")  # [[south, west], [north, east]]
        self.bounds: tuple[float, float, float, float] | None = (
            (float(bounds[0][1]), float(bounds[0][0]), float(bounds[1][1]), float(bounds[1][0])) if bounds else None
        )
        self.terms = next((p.terms for p in AERIAL_PROVIDERS if p.name == self.provider_name), UNREVIEWED)
        attribution = str(provider.get("attribution") or "") or None
        if tile_size is None and "tileSize" in provider:
            tile_size = int(provider["tileSize"])
        super().__init__(tile_template(provider, self.key_envs), client, env=env, attribution=attribution,
                         workers=workers, tile_size=tile_size)
        self._warn_if_unsuitable(provider)

    def _warn_if_unsuitable(self, provider: TileProvider) -> None:
        """Log a warning for entries that are broken or are not plain aerial imagery."""
        name, text = self.provider_name, f"{self.provider_name} {provider.get('variant', '')}"
        if provider.get("status") == "broken":
            logger.warning("xyzservices marks %s as broken: its tiles may not load", name)
        if any(p.name == name for p in AERIAL_PROVIDERS):
            pass
        elif not _LOOKS_AERIAL.search(text):
            logger.warning("%s does not look like aerial imagery: a rendered map teaches a model map"
                           " colours, not the ground; see docs/imagery.md for aerial providers", name)
        elif _HAS_LABELS.search(text):
            logger.warning("%s draws map labels or lines over the imagery: they will be in the images", name)

    def __repr__(self) -> str:
        return f"NamedProvider({self.provider_name!r})"

    def check_zoom(self, zoom: int) -> None:
        """Raise a one-line :class:`ConfigError` when ``zoom`` is outside the entry's range."""
        if self.max_zoom is not None and zoom > self.max_zoom:
            raise ConfigError(
                f"--zoom {zoom} is above {self.provider_name}'s highest zoom {self.max_zoom}:"
                f" use --zoom {self.max_zoom} or lower"
            )
        if zoom < self.min_zoom:
            raise ConfigError(
                f"--zoom {zoom} is below {self.provider_name}'s lowest zoom {self.min_zoom}:"
                f" use --zoom {self.min_zoom} or higher"
            )

    def covers(self, tile: mercantile.Tile) -> bool:
        """False when ``tile`` lies wholly outside the entry's ``bounds``."""
        if self.bounds is None:
            return True
        west, south, east, north = self.bounds
        b = mercantile.bounds(tile)
        return bool(b.east > west and b.west < east and b.north > south and b.south < north)

    def fetch_tile(self, tile: mercantile.Tile) -> TilePixels:
        """Pixels of one tile; :data:`NO_IMAGERY` without a request outside the bounds."""
        if not self.covers(tile):
            logger.debug("tile %s is outside %s's bounds", tile_name(tile), self.provider_name)
            return NO_IMAGERY
        return super().fetch_tile(tile)

    def fetch(self, grid: SampleGrid) -> Imagery:
        """The sample's tiles merged into one image on ``grid`` (zoom checked first)."""
        self.check_zoom(grid.zoom)
        imagery = super().fetch(grid)
        imagery.info["name"] = self.provider_name
        return imagery

    def describe(self) -> dict[str, Any]:
        """Provider, entry name, template (keys not expanded), attribution and terms."""
        info = {
            **super().describe(),
            "name": self.provider_name,
            "catalogue": f"xyzservices {xyzservices.__version__}",
            "terms": self.terms,
            "zoom_range": [self.min_zoom, self.max_zoom],
        }
        if self.bounds is not None:
            info["bounds_wgs84"] = list(self.bounds)
        if self.key_envs:
            info["key_env"] = sorted(self.key_envs.values())
        return info
