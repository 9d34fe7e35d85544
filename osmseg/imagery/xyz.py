"""``xyz:TEMPLATE``: imagery from any slippy-map tile server or a local tile folder.

A template is a URL with placeholders, filled in per tile:

``{z}`` ``{x}`` ``{y}``  the tile's zoom, column and row (XYZ / Google / OSM scheme)
``{-y}``                 the row counted from the south (TMS scheme): ``2**z - 1 - y``
``{q}``                  the tile's Bing-style quadkey
``{env:NAME}``           the value of environment variable ``NAME`` (for API keys)

Templates start with ``https://``, ``http://`` or ``file://`` (a local folder, read straight
from disk; ``file://`` followed by an absolute or relative path).  Keys come only through
``{env:NAME}``: the expanded value lives in memory, while messages, logs and the manifest
show the template with ``{env:NAME}`` left in.  ``{env:NAME}`` is accepted only as the
value of a query parameter the HTTP client redacts and keeps out of its cache
(:data:`osmseg.redact.SECRET_PARAMS`: ``key``, ``access_token``, ``subscription-key``,
``api_key``, ``apikey``, ``token``, ``apiKey``, ...), which is where Mapbox, Azure Maps,
Esri, MapTiler and HERE take keys.

Transparent tile pixels and tiles the server does not have (HTTP 404/204, empty body, a
missing file) are invalid areas, not errors; bytes that are not an image are an
:class:`~osmseg.errors.ImageryError` naming the tile.

>>> p = XYZProvider("file:///tmp/{z}/{x}/{-y}.png")
>>> p.tile_location(mercantile.Tile(x=5, y=2, z=3))
'file:///tmp/3/5/5.png'
>>> fill_template("https://t.example/{q}.jpeg", mercantile.Tile(x=5, y=2, z=3))
'https://t.example/121.jpeg'
"""

from __future__ import annotations

import glob
import logging
import os
import re
import urllib.parse
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import mercantile

from osmseg.errors import ConfigError, HTTPStatusError, ImageryError, NetworkError
from osmseg.grid import TILE_SIZE, SampleGrid
from osmseg.imagery.base import Imagery
from osmseg.imagery.mosaic import (
    NO_IMAGERY,
    TILE_SIZES,
    TilePixels,
    assemble,
    decode_tile,
    fetch_tiles,
    is_absent,
    tile_lists,
    tile_name,
)
from osmseg.net.http import HttpClient
from osmseg.redact import SECRET_PARAMS

logger = logging.getLogger(__name__)

_PLACEHOLDER = re.compile(r"\{([^{}]*)\}")
# a key written literally into a template (not as {env:NAME}), and user:password@ in a URL
_LITERAL_SECRET = re.compile(
    r"([?&;](?:" + "|".join(re.escape(p) for p in SECRET_PARAMS) + r")=)"
    r"(?!\{env:[A-Za-z_][A-Za-z0-9_]*\}(?:[&#]|$))[^&#\s]*",
    re.IGNORECASE,
)
_USERINFO = re.compile(r"(://[^/@\s:]+):[^/@\s]+@")
_TILE_KEYS = {"z", "x", "y", "-y", "q"}
#: A local tile folder is checked for a tile over the sampling area file by file up to this many
#: tiles (centre first: the first found ends it), and by listing its files at the zoom beyond.
MAX_TILE_PROBES = 100_000
_SCHEMES = ("https://", "http://", "file://")

#: attribution lines for well-known imagery hosts (the provider's terms require them)
KNOWN_ATTRIBUTIONS: dict[str, str] = {
    "arcgisonline.com": "Source: Esri, Maxar, Earthstar Geographics, and the GIS User Community",
    "arcgis.com": "Source: Esri, Maxar, Earthstar Geographics, and the GIS User Community",
    "atlas.microsoft.com": "Imagery © Microsoft (Azure Maps) and its suppliers",
    "mapbox.com": "© Mapbox © Maxar",
    "openaerialmap.org": "Imagery: OpenAerialMap contributors (CC-BY 4.0)",
}


def default_attribution(template: str) -> str:
    """The attribution line for a template's host, or a reminder to find it.

    >>> default_attribution("https://api.mapbox.com/v4/mapbox.satellite/{z}/{x}/{y}.jpg")
    '© Mapbox © Maxar'
    >>> default_attribution("file:///data/tiles/{z}/{x}/{y}.png")
    'Imagery from local tiles (file:///data/tiles/{z}/{x}/{y}.png): credit the imagery owner as their terms require'
    """
    if template.startswith("file://"):
        return f"Imagery from local tiles ({template}): credit the imagery owner as their terms require"
    host = urllib.parse.urlsplit(template).hostname or ""
    for suffix, line in KNOWN_ATTRIBUTIONS.items():
        if host == suffix or host.endswith("." + suffix):
            return line
    return f"Imagery from {host}: see the provider's terms for the required attribution"


def safe_text(template: str) -> str:
    """A template or URL fit to show: literal keys redacted, ``{env:NAME}`` kept as a hint.

    >>> safe_text("https://h/{z}/{x}/{y}.jpg?access_token={env:MAPBOX_TOKEN}&style=a")
    'https://h/{z}/{x}/{y}.jpg?access_token={env:MAPBOX_TOKEN}&style=a'
    >>> safe_text("https://h/{z}/{x}/{y}.jpg?access_token=pk.literal&style=a")
    'https://h/{z}/{x}/{y}.jpg?access_token=REDACTED&style=a'
    """
    return _USERINFO.sub(r"\1:REDACTED@", _LITERAL_SECRET.sub(r"\1REDACTED", template))


def parse_template(template: str, env: Mapping[str, str]) -> dict[str, str]:
    """Check a template and return the values of its ``{env:NAME}`` placeholders.

    Raises :class:`ConfigError` for an unknown scheme or placeholder, a template that
    cannot address a tile, or an unset environment variable.

    >>> parse_template("https://a.example/{z}/{x}/{y}.png?access_token={env:TOKEN}", {"TOKEN": "s3cret"})
    {'TOKEN': 's3cret'}
    >>> parse_template("https://a.example/{z}/{x}.png", {})
    Traceback (most recent call last):
    osmseg.errors.ConfigError: xyz template https://a.example/{z}/{x}.png needs {z}, {x} and {y} (or {-y}), or {q}
    """
    if not template.startswith(_SCHEMES):
        raise ConfigError(f"xyz template {template} must start with https://, http:// or file://")
    shell = re.search(r"\$\{([A-Za-z_][A-Za-z0-9_]*)\}", template)
    if shell:  # a shell variable: expanded by the shell it would put the key into argv (ps, history)
        raise ConfigError(f"xyz template: write ${{{shell.group(1)}}} as {{env:{shell.group(1)}}} (in single quotes): "
                          "osmseg reads the key from the environment itself and keeps it out of logs")
    keys = _PLACEHOLDER.findall(template)
    secrets: dict[str, str] = {}
    for key in keys:
        if key.startswith("env:"):
            name = key[4:]
            if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
                raise ConfigError(
                    f"xyz template placeholder {{{key}}} is not a valid environment variable name"
                )
            if not env.get(name):
                raise ConfigError(
                    f"xyz template needs environment variable {name}: set it (export {name}=...)"
                )
            secrets[name] = env[name]
        elif key not in _TILE_KEYS:
            raise ConfigError(
                f"unknown placeholder {{{key}}} in xyz template;"
                " use {z} {x} {y} {-y} {q} {env:NAME}"
            )
    if secrets and not template.startswith("file://"):
        in_params = {
            match
            for name, value in urllib.parse.parse_qsl(urllib.parse.urlsplit(template).query)
            if name in SECRET_PARAMS
            for match in re.findall(r"\{env:([^{}]*)\}", value)
        }
        for name in secrets.keys() - in_params:
            raise ConfigError(
                f"put {{env:{name}}} only in a key query parameter ({', '.join(SECRET_PARAMS)})"
                " of the xyz template, so the key never reaches logs or the cache"
            )
    found = set(keys)
    if not ({"z", "x"} <= found and found & {"y", "-y"}) and "q" not in found:
        raise ConfigError(
            f"xyz template {template} needs {{z}}, {{x}} and {{y}} (or {{-y}}), or {{q}}"
        )
    return secrets


def fill_template(
    template: str, tile: mercantile.Tile, env: Mapping[str, str] | None = None
) -> str:
    """The template with ``tile``'s numbers filled in; ``{env:NAME}`` only when ``env`` is given.

    >>> fill_template("https://h/{z}/{x}/{-y}?k={env:K}", mercantile.Tile(1, 0, 1))
    'https://h/1/1/1?k={env:K}'
    >>> fill_template("https://h/{z}/{x}/{y}?k={env:K}", mercantile.Tile(1, 0, 1), {"K": "v"})
    'https://h/1/1/0?k=v'
    """
    values = {
        "z": str(tile.z),
        "x": str(tile.x),
        "y": str(tile.y),
        "-y": str(2**tile.z - 1 - tile.y),
        "q": str(mercantile.quadkey(tile)),
    }

    def replace(match: re.Match[str]) -> str:
        key = match.group(1)
        if key.startswith("env:"):
            return env[key[4:]] if env is not None else match.group(0)
        return values[key]

    return _PLACEHOLDER.sub(replace, template)


def declared_tile_size(template: str, asked: int | None = None) -> int:
    """The tile size in px a template's server answers with: ``asked`` (``--tile-size``), else 512
    for an ``@2x`` (retina) template, else 256. Tiles of 512 px cover the extent of a 256-px tile
    of the same ``z/x/y`` with twice the pixels; osmseg resamples them to its 256-px grid.

    >>> declared_tile_size("https://h/{z}/{x}/{y}@2x.png"), declared_tile_size("https://h/{z}/{x}/{y}.png", 512)
    (512, 512)
    >>> declared_tile_size("https://h/{z}/{x}/{y}.png", 300)
    Traceback (most recent call last):
    osmseg.errors.ConfigError: --tile-size 300: give one of 256, 512, 1024 (the px of the server's tiles)
    """
    if asked is None:
        return 2 * TILE_SIZE if "@2x" in template else TILE_SIZE
    if asked not in TILE_SIZES:
        raise ConfigError(f"--tile-size {asked}: give one of {', '.join(map(str, TILE_SIZES))} (the px of the "
                          "server's tiles)")
    return asked


class XYZProvider:
    """Tiles from a ``{z}/{x}/{y}`` or ``{q}`` URL template, or a ``file://`` tile folder.

    Args:
        template: the URL template (see the module docstring).
        client: the shared HTTP client; may be None only for ``file://`` templates.
        env: where ``{env:NAME}`` values come from (default: ``os.environ``).
        attribution: the provider's required attribution (default: from the host).
        workers: tiles fetched at once (the client's per-host limit applies too).
        tile_size: the size in px of the server's tiles (:func:`declared_tile_size`: 512 for an
            ``@2x`` template, else 256, unless given): every tile is checked against it.
    """

    name = "xyz"

    def __init__(
        self,
        template: str,
        client: HttpClient | None = None,
        *,
        env: Mapping[str, str] | None = None,
        attribution: str | None = None,
        workers: int = 4,
        tile_size: int | None = None,
    ) -> None:
        self._secrets = parse_template(template, os.environ if env is None else env)
        self.tile_size = declared_tile_size(template, tile_size)
        self.template = template
        self.is_local = template.startswith("file://")
        if self.is_local:
            # a typo in the folder would otherwise look like "no imagery anywhere"
            fixed = Path(urllib.parse.unquote(template[len("file://"):].split("{", 1)[0]))
            folder = fixed if template[len("file://"):].split("{", 1)[0].endswith("/") else fixed.parent
            if not folder.is_dir():
                raise ConfigError(f"--imagery {template}: folder {folder} does not exist; check the file:// template")
        if not self.is_local and safe_text(template) != template:
            logger.warning(
                "the xyz template has a key written out: use {env:NAME} to keep it out of shell history"
            )
        if not self.is_local and client is None:
            raise ConfigError(f"xyz template {self.display_template} needs an HTTP client")
        self._client = client
        self.attribution = attribution or default_attribution(self.display_template)
        self.workers = workers

    @property
    def display_template(self) -> str:
        """The template as shown to people: ``{env:NAME}`` kept, literal keys hidden."""
        return self.template if self.is_local else safe_text(self.template)

    def __repr__(self) -> str:
        return f"XYZProvider({self.display_template!r})"

    def tile_location(self, tile: mercantile.Tile) -> str:
        """Where ``tile`` is, as shown to people (``{env:NAME}`` not expanded)."""
        url = fill_template(self.template, tile)
        return url if self.is_local else safe_text(url)

    def _local_path(self, tile: mercantile.Tile) -> Path:
        """The file of ``tile`` in a ``file://`` template's folder."""
        return Path(urllib.parse.unquote(fill_template(self.template, tile)[len("file://"):]))

    def check_covers(self, west: float, south: float, east: float, north: float, zoom: int | None = None) -> None:
        """ConfigError when a ``file://`` tile folder has no tile at ``zoom`` over the sampling area
        (lon/lat degrees): every sample would be rejected for missing imagery, so say it before
        the build, with the zooms the folder has. Remote templates: nothing to check here."""
        if not self.is_local or zoom is None:
            return
        nw, se = mercantile.tile(west, north, zoom), mercantile.tile(east, south, zoom)
        xs, ys = range(nw.x, se.x + 1), range(nw.y, se.y + 1)
        if len(xs) * len(ys) <= MAX_TILE_PROBES:
            cx, cy = (nw.x + se.x) / 2, (nw.y + se.y) / 2
            tiles = sorted(((x, y) for x in xs for y in ys), key=lambda t: (t[0] - cx) ** 2 + (t[1] - cy) ** 2)
            if any(self._local_path(mercantile.Tile(x, y, zoom)).is_file() for x, y in tiles):
                return
        elif self._listed_tile_in(xs, ys, zoom) is not False:
            return
        zooms = self._local_zooms()
        has = (f"the folder has tiles at zoom {', '.join(map(str, zooms))}: give one of them as --zoom, or sample "
               "where the tiles are (--bbox/--lat/--lon)" if zooms and zoom not in zooms else
               "sample where the tiles are (--bbox/--lat/--lon), or check the template")
        raise ConfigError(f"--imagery {self.template} has no tile at zoom {zoom} over the sampling area (lon "
                          f"{west:.5f}..{east:.5f}, lat {south:.5f}..{north:.5f}; tiles x {xs.start}..{xs.stop - 1}, "
                          f"y {ys.start}..{ys.stop - 1}): {has}")

    def _listed_tile_in(self, xs: range, ys: range, zoom: int) -> bool | None:
        """Whether a file the template names at ``zoom`` lies in columns ``xs`` and rows ``ys``, by
        listing the folder (None when the template cannot be listed)."""
        listed = self._listed(zoom)
        return None if listed is None else any(x in xs and y in ys for _, x, y in listed)

    def _local_zooms(self) -> list[int]:
        """The zooms of the tiles in a ``file://`` folder (none known when it cannot be listed)."""
        return sorted({z for z, _, _ in self._listed(None) or ()})

    def _listed(self, zoom: int | None) -> Iterator[tuple[int, int, int]] | None:
        """``(z, x, y)`` of the files in a ``file://`` template's folder, at ``zoom`` or every zoom (None
        when a placeholder repeats or is an ``{env:NAME}``: then the names cannot be read back)."""
        parts = re.split(r"(\{[^{}]*\})", urllib.parse.unquote(self.template[len("file://"):]))
        keys = [p[1:-1] for p in parts[1::2]]
        if len(set(keys)) != len(keys) or any(k.startswith("env:") for k in keys):
            return None
        digits = "+" if zoom is None else f"{{{zoom}}}"
        groups = {"z": r"(?P<z>\d+)" if zoom is None else str(zoom), "x": r"(?P<x>\d+)", "y": r"(?P<y>\d+)",
                  "-y": r"(?P<ny>\d+)", "q": f"(?P<q>[0-3]{digits})"}
        pattern = "".join(glob.escape(p) if i % 2 == 0 else (str(zoom) if p == "{z}" and zoom is not None else "*")
                          for i, p in enumerate(parts))
        regex = re.compile("".join(re.escape(p) if i % 2 == 0 else groups[p[1:-1]] for i, p in enumerate(parts)))

        def tiles() -> Iterator[tuple[int, int, int]]:
            for name in glob.iglob(pattern):
                m = regex.fullmatch(name)
                if m is None:
                    continue
                found = m.groupdict()
                if found.get("q"):
                    t = mercantile.quadkey_to_tile(found["q"])
                    yield t.z, t.x, t.y
                    continue
                z = int(found["z"]) if found.get("z") else int(zoom or 0)
                y = int(found["y"]) if found.get("y") else 2**z - 1 - int(found["ny"])
                yield z, int(found["x"]), y
        return tiles()

    def _scrub(self, text: str) -> str:
        """``text`` with every expanded secret replaced by its ``{env:NAME}`` placeholder."""
        for name, value in self._secrets.items():
            text = text.replace(value, f"{{env:{name}}}")
        return text

    def fetch_tile(self, tile: mercantile.Tile) -> TilePixels:
        """Pixels of one tile (:data:`NO_IMAGERY` when the server or folder has none)."""
        what = f"tile {tile_name(tile)} ({self.tile_location(tile)})"
        if self.is_local:
            path = self._local_path(tile)
            try:
                data = path.read_bytes()
            except FileNotFoundError:
                logger.debug("no local tile %s", path)
                return NO_IMAGERY
            except OSError as exc:
                raise ImageryError(f"cannot read {what}: {exc.strerror or exc}") from None
        else:
            assert self._client is not None
            url = fill_template(self.template, tile, self._secrets)
            try:
                # a 200 whose bytes are not an image (an HTML error page, a PNG cut short by a
                # proxy) is fetched again like a 5xx before it fails the sample
                # and an answer of "no imagery here" is asked again before it is believed (is_absent)
                response, pixels = self._client.fetch(
                    url, lambda r: decode_tile(r.content, what, self.tile_size) if r.content else NO_IMAGERY,
                    ok_statuses=(204, 404), corrupt=(ImageryError,), absent=is_absent)
            except HTTPStatusError as exc:
                raise type(exc)(self._scrub(str(exc)), exc.status) from None
            except NetworkError as exc:
                raise type(exc)(self._scrub(str(exc))) from None
            if pixels is None or not response.content:
                logger.debug("server has no %s (HTTP %s)", what, response.status_code)
                return NO_IMAGERY
            return pixels
        return decode_tile(data, what, self.tile_size)

    def verdicts_served(self) -> bool:
        """A tile server's "no imagery here" may be a passing fault; a tile folder's missing file is not."""
        return not self.is_local

    def fetch(self, grid: SampleGrid) -> Imagery:
        """The sample's tiles merged into one image on ``grid``."""
        parts = fetch_tiles(grid.tiles, self.fetch_tile, self.workers)
        rgb, valid, placeholders = assemble(grid, parts)
        lists = tile_lists(grid, parts)
        info: dict[str, Any] = {
            "provider": self.name,
            "template": self.display_template,
            **lists,
            "attribution": self.attribution,
        }
        return Imagery(rgb=rgb, valid=valid, placeholder_tiles=placeholders, info=info,
                       uniform_tiles=len(lists["uniform_tiles"]))

    def describe(self) -> dict[str, Any]:
        """Provider, template (keys not expanded) and attribution, for the manifest."""
        return {
            "provider": self.name,
            "template": self.display_template,
            "attribution": self.attribution,
            **({"tile_size": self.tile_size} if self.tile_size != TILE_SIZE else {}),
        }
