"""``bing``: Bing Maps aerial imagery through the Imagery Metadata REST API.

One metadata call per provider (``GET /REST/v1/Imagery/Metadata/{set}``) gives the tile URL
template (``imageUrl``, with ``{subdomain}``, ``{quadkey}`` and sometimes ``{culture}``), the
subdomains, the zoom range, the copyright and the imagery suppliers per area; nothing about
tile URLs is hard-coded.  Tiles are addressed by quadkey.  Where Bing has no imagery it
answers with a placeholder picture and the header ``X-VE-Tile-Info: no-tile`` (a 404 with
that header when the URL asks for ``n=z``); such tiles are counted in
:attr:`Imagery.placeholder_tiles` and their pixels are invalid, so the builder can reject the
sample.

The key is passed in by the caller (from ``BING_MAPS_KEY``); it goes only into the metadata
request's ``key`` parameter, which the HTTP client redacts from logs, messages and its cache.
Microsoft retires Bing Maps for Enterprise (Basic keys 30 June 2025, Enterprise 30 June
2028): see docs/imagery.md for the replacements.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

import mercantile

from osmseg.errors import AuthError, ConfigError, CorruptResponse, HTTPStatusError, ImageryError
from osmseg.grid import SampleGrid
from osmseg.imagery.base import Imagery
from osmseg.imagery.mosaic import (
    NO_IMAGERY,
    TilePixels,
    assemble,
    decode_tile,
    fetch_tiles,
    is_absent,
    tile_lists,
    tile_name,
)
from osmseg.net.http import HttpClient
from osmseg.redact import redact

logger = logging.getLogger(__name__)

METADATA_URL = "https://dev.virtualearth.net/REST/v1/Imagery/Metadata/{imagery_set}"
#: ``authenticationResultCode`` values meaning the key was not accepted
REFUSED_CODES = {"InvalidCredentials", "CredentialsExpired", "NoCredentials", "NotAuthorized"}
AUTH_MESSAGE = "Bing Maps refused the key: check BING_MAPS_KEY"
DEFAULT_ATTRIBUTION = "Imagery © Microsoft Corporation and its suppliers (Bing Maps)"


def subdomain_for(quadkey: str, subdomains: list[str]) -> str:
    """A subdomain chosen from the quadkey, so the same tile always has the same URL.

    (Recorded fixtures and the on-disk cache depend on that.)

    >>> subdomain_for("0231", ["t0", "t1", "t2", "t3"])
    't1'
    >>> subdomain_for("", ["t0", "t1"])
    't0'
    """
    if not subdomains:
        return ""
    return subdomains[int(quadkey or "0", 4) % len(subdomains)]


def is_no_tile(headers: Any) -> bool:
    """True when a Bing tile response says "no imagery here" (``X-VE-Tile-Info: no-tile``).

    >>> is_no_tile({"X-VE-Tile-Info": "no-tile"}), is_no_tile({})
    (True, False)
    """
    return "no-tile" in str(headers.get("X-VE-Tile-Info", "")).lower()


def covering_suppliers(
    resource: dict[str, Any], bbox: tuple[float, float, float, float], zoom: int
) -> list[str]:
    """Attributions of the imagery suppliers whose coverage areas meet ``bbox`` at ``zoom``.

    ``bbox`` is (west, south, east, north); Bing's coverage ``bbox`` is [south, west, north, east].

    >>> res = {"imageryProviders": [
    ...     {"attribution": "© Maxar", "coverageAreas": [{"bbox": [-90, -180, 90, 180], "zoomMin": 1, "zoomMax": 21}]},
    ...     {"attribution": "© Vexcel", "coverageAreas": [{"bbox": [40, -75, 41, -73], "zoomMin": 14, "zoomMax": 21}]}]}
    >>> covering_suppliers(res, (13.3, 52.4, 13.5, 52.6), 18)
    ['© Maxar']
    """
    west, south, east, north = bbox
    names: list[str] = []
    for supplier in resource.get("imageryProviders") or []:
        for area in supplier.get("coverageAreas") or []:
            try:
                s, w, n, e = (float(v) for v in area["bbox"])
                zmin, zmax = int(area.get("zoomMin", 1)), int(area.get("zoomMax", 23))
            except (KeyError, TypeError, ValueError):
                continue
            if zmin <= zoom <= zmax and w <= east and e >= west and s <= north and n >= south:
                if supplier.get("attribution") and supplier["attribution"] not in names:
                    names.append(str(supplier["attribution"]))
                break
    return names


class BingProvider:
    """Bing Maps tiles for a sample grid.

    Args:
        client: the shared HTTP client.
        key: the Bing Maps key (the caller reads it from ``BING_MAPS_KEY``); never shown.
        imagery_set: Bing imagery set, ``Aerial`` by default (the dissertation's imagery).
        culture: language code substituted for ``{culture}`` in the tile URL.
        workers: tiles fetched at once (the client's per-host limit applies too).
        metadata_url: the Imagery Metadata endpoint, ``{imagery_set}`` filled in (change it
            only to go through a proxy or a test server).
    """

    name = "bing"

    def __init__(
        self,
        client: HttpClient,
        key: str,
        imagery_set: str = "Aerial",
        culture: str = "en-US",
        workers: int = 4,
        metadata_url: str = METADATA_URL,
    ) -> None:
        if not key:
            raise ConfigError(
                "Bing Maps needs a key: set BING_MAPS_KEY or use --imagery xyz:... / geotiff:..."
            )
        self._client = client
        self._key = key
        self.imagery_set = imagery_set
        self.culture = culture
        self.workers = workers
        self.metadata_url = metadata_url
        self._lock = threading.Lock()
        self._meta: dict[str, Any] | None = None
        #: Bing's copyright line once the metadata is known, a generic line before
        self.attribution = DEFAULT_ATTRIBUTION

    def __repr__(self) -> str:
        return f"BingProvider(imagery_set={self.imagery_set!r})"

    # -- metadata ---------------------------------------------------------------------------

    def metadata(self) -> dict[str, Any]:
        """The Imagery Metadata response (fetched once, then kept on the instance)."""
        with self._lock:
            if self._meta is None:
                self._meta = self._fetch_metadata()
                self.attribution = str(self._meta["copyright"] or DEFAULT_ATTRIBUTION)
            return self._meta

    def _fetch_metadata(self) -> dict[str, Any]:
        url = self.metadata_url.format(imagery_set=self.imagery_set)
        params = {
            "key": self._key,
            "uriScheme": "https",
            "output": "json",
            "include": "ImageryProviders",
        }
        # Error answers are not declared ok_statuses on purpose: the HTTP cache would keep a
        # 401 and (its key ignoring ``key``) replay it after the user fixed BING_MAPS_KEY.
        try:  # an answer that is not JSON (a proxy's error page) or a throttled, empty one is fetched again
            response, body = self._client.fetch(url, _metadata_answer, params=params)
        except AuthError as exc:
            raise AuthError(AUTH_MESSAGE, exc.status) from None
        except HTTPStatusError as exc:
            if exc.status not in (400, 404):
                raise
            raise ConfigError(
                f"Bing Maps does not know imagery set {self.imagery_set!r} (HTTP {exc.status}):"
                " use --imagery bing or bing:Aerial"
            ) from None
        if not isinstance(body, dict):
            raise ImageryError("Bing Maps metadata is not JSON: try again later")
        resource = body["resourceSets"][0]["resources"][0]
        template = str(resource["imageUrl"])
        if "{quadkey}" not in template:
            raise ImageryError(
                f"Bing Maps imageUrl {redact(template)} has no {{quadkey}}: cannot address tiles"
            )
        logger.debug("Bing %s tiles from %s", self.imagery_set, redact(template))
        return {
            "image_url": template,
            "subdomains": [str(s) for s in resource.get("imageUrlSubdomains") or []],
            "zoom_min": int(resource.get("zoomMin") or 1),
            "zoom_max": int(resource.get("zoomMax") or 21),
            "tile_size": int(resource.get("imageWidth") or 256),  # what Bing says its tiles are
            "vintage_start": resource.get("vintageStart"),
            "vintage_end": resource.get("vintageEnd"),
            "brand_logo_uri": body.get("brandLogoUri"),
            "copyright": body.get("copyright"),
            "resource": resource,
        }

    # -- tiles ------------------------------------------------------------------------------

    def tile_url(self, tile: mercantile.Tile) -> str:
        """The tile's URL from the metadata's ``imageUrl`` template."""
        meta = self.metadata()
        quadkey = str(mercantile.quadkey(tile))
        return (
            str(meta["image_url"])
            .replace("{subdomain}", subdomain_for(quadkey, meta["subdomains"]))
            .replace("{quadkey}", quadkey)
            .replace("{culture}", self.culture)
        )

    def fetch_tile(self, tile: mercantile.Tile) -> TilePixels:
        """Pixels of one tile; :data:`NO_IMAGERY` for Bing's "no imagery" placeholder."""
        url = self.tile_url(tile)
        what = f"Bing tile {tile_name(tile)} ({redact(url)})"

        def parse(response: Any) -> TilePixels:
            if is_no_tile(response.headers) or not response.content:
                return NO_IMAGERY
            return decode_tile(response.content, what, int(self.metadata()["tile_size"]))

        # a 200 whose bytes are not an image is fetched again like a 5xx before it fails the sample
        # and "no imagery here" (the no-tile header, one colour, empty) is asked again before it is believed
        response, pixels = self._client.fetch(url, parse, ok_statuses=(404,), corrupt=(ImageryError,),
                                              absent=is_absent)
        if pixels is None or pixels is NO_IMAGERY:
            logger.debug(
                "Bing has no imagery for tile %s (HTTP %s)", tile_name(tile), response.status_code
            )
            return NO_IMAGERY
        return pixels

    def verdicts_served(self) -> bool:
        """Bing's "no imagery here" (its no-tile header, a tile of one colour) comes from its servers."""
        return True

    def fetch(self, grid: SampleGrid) -> Imagery:
        """The sample's tiles merged into one image on ``grid``."""
        meta = self.metadata()
        if not meta["zoom_min"] <= grid.zoom <= meta["zoom_max"]:
            raise ConfigError(
                f"zoom {grid.zoom} is outside Bing {self.imagery_set}'s range"
                f" {meta['zoom_min']}-{meta['zoom_max']}: change --zoom"
            )
        parts = fetch_tiles(grid.tiles, self.fetch_tile, self.workers)
        rgb, valid, placeholders = assemble(grid, parts)
        lists = tile_lists(grid, parts)
        info: dict[str, Any] = {
            "provider": self.name,
            "imagery_set": self.imagery_set,
            "image_url": redact(meta["image_url"]),
            **lists,
            "suppliers": covering_suppliers(meta["resource"], grid.bbox, grid.zoom),
            "copyright": meta["copyright"],
        }
        if meta["vintage_start"] or meta["vintage_end"]:
            info["vintage"] = [meta["vintage_start"], meta["vintage_end"]]
        return Imagery(rgb=rgb, valid=valid, placeholder_tiles=placeholders, info=info,
                       uniform_tiles=len(lists["uniform_tiles"]))

    def describe(self) -> dict[str, Any]:
        """Imagery set, tile template, logo and copyright for the manifest (needs the metadata)."""
        meta = self.metadata()
        return {
            "provider": self.name,
            "imagery_set": self.imagery_set,
            "culture": self.culture,
            "image_url": redact(meta["image_url"]),
            "subdomains": meta["subdomains"],
            "zoom_range": [meta["zoom_min"], meta["zoom_max"]],
            "brand_logo_uri": meta["brand_logo_uri"],
            "copyright": meta["copyright"],
            "attribution": self.attribution,
        }


def _metadata_answer(response: Any) -> dict[str, Any]:
    """The Imagery Metadata JSON; AuthError for a refused key, CorruptResponse for an unusable answer."""
    try:
        body = response.json()
    except ValueError:
        body = None
    if not isinstance(body, dict):
        raise CorruptResponse("Bing Maps metadata is not a JSON object")
    if str(body.get("authenticationResultCode", "")) in REFUSED_CODES:
        raise AuthError(AUTH_MESSAGE, response.status_code)
    try:
        str(body["resourceSets"][0]["resources"][0]["imageUrl"])
    except (KeyError, IndexError, TypeError):
        # Bing answers a throttled session with empty results (header X-MS-BM-WS-INFO: 1): wait, ask again
        raise CorruptResponse("Bing Maps metadata has no imageUrl (throttled?)") from None
    return body
