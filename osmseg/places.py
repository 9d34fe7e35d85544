"""Where to sample: city presets, a point, or a box, and seeded random centres in them.

>>> find_preset("sao paulo").name
'São Paulo'
>>> find_preset("  BERLIN ").lat
52.52
"""

from __future__ import annotations

import math
import unicodedata
from dataclasses import dataclass

import numpy as np

from osmseg.datafiles import load_toml
from osmseg.errors import ConfigError, UnknownPlaceError
from osmseg.grid import LngLatBBox

EARTH_RADIUS_M = 6371008.8


@dataclass(frozen=True)
class Preset:
    """A named sampling area from ``data_manifests/cities.toml``."""

    name: str
    lat: float
    lon: float
    radius_km: float
    kind: str
    source: str
    note: str = ""


@dataclass(frozen=True)
class Area:
    """Where sample centres are drawn: a disc (centre + radius) or a box."""

    name: str
    lat: float
    lon: float
    radius_km: float | None = None
    bbox: LngLatBBox | None = None
    kind: str = "custom"  # urban | rural for presets

    def random_centres(self, rng: np.random.Generator, n: int) -> list[tuple[float, float]]:
        """``n`` (lon, lat) centres drawn uniformly over the disc (by area) or the box."""
        out: list[tuple[float, float]] = []
        for _ in range(n):
            if self.bbox is not None:
                b = self.bbox
                lon = float(rng.uniform(b.west, b.east))
                # uniform by area on the sphere: uniform in sin(lat)
                s = rng.uniform(math.sin(math.radians(b.south)), math.sin(math.radians(b.north)))
                lat = math.degrees(math.asin(float(s)))
            else:
                assert self.radius_km is not None
                r = self.radius_km * 1000.0 * math.sqrt(float(rng.uniform()))
                theta = float(rng.uniform(0.0, 2 * math.pi))
                lon, lat = destination(self.lon, self.lat, r, theta)
            out.append((lon, lat))
        return out


def normalise_name(name: str) -> str:
    """Case- and accent-insensitive key for a place name.

    >>> normalise_name("  São  Paulo ")
    'sao paulo'
    """
    decomposed = unicodedata.normalize("NFKD", name)
    stripped = "".join(c for c in decomposed if not unicodedata.combining(c))
    return " ".join(stripped.casefold().replace("-", " ").replace("_", " ").split())


def load_presets(manifest: str = "cities.toml") -> dict[str, Preset]:
    """All presets, keyed by their display name."""
    table = load_toml(manifest)
    presets = {}
    for name, entry in table.items():
        try:
            presets[name] = Preset(name=name, **entry)
        except TypeError as exc:
            raise ConfigError(f"{manifest}: preset {name!r} is malformed ({exc})") from None
    return presets


def find_preset(name: str, manifest: str = "cities.toml") -> Preset:
    """The preset whose name matches ``name`` regardless of case, accents and spacing."""
    presets = load_presets(manifest)
    wanted = normalise_name(name)
    for preset in presets.values():
        if normalise_name(preset.name) == wanted:
            return preset
    known = ", ".join(sorted(presets))
    raise UnknownPlaceError(f"unknown city {name!r}; use one of: {known}; or give --lat/--lon or --bbox")


def parse_bbox(text: str) -> LngLatBBox:
    """Parse ``--bbox W,S,E,N`` in degrees (every command's: one parser, one message).

    >>> parse_bbox("13.3,52.4,13.5,52.6")
    LngLatBBox(west=13.3, south=52.4, east=13.5, north=52.6)
    """
    try:
        w, s, e, n = (float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"--bbox {text!r}: expected four numbers W,S,E,N in degrees") from None
    if not _inside(w, s, e, n):
        raise ConfigError(f"--bbox {text!r}: need W<E within ±180 and S<N within ±85.06 (Web Mercator)"
                          f"{_meant(text, w, e)}")
    return LngLatBBox(w, s, e, n)


def _inside(w: float, s: float, e: float, n: float) -> bool:
    return -180 <= w < e <= 180 and -85.06 <= s < n <= 85.06


def _meant(text: str, w: float, e: float) -> str:
    """What a ``--bbox`` given in another order most likely meant, as the user wrote its numbers
    ("" when no reordering is a box; latitude and longitude are taken as swapped only when a
    "latitude" lies beyond ±90°, and a box across the antimeridian is refused, not turned around).

    >>> _meant("13.5,52.4,13.3,52.6", 13.5, 13.3)
    '; did you mean --bbox 13.3,52.4,13.5,52.6 (west first, south second)?'
    >>> _meant("-33.9,151.2,-33.8,151.3", -33.9, -33.8)
    '; did you mean --bbox 151.2,-33.9,151.3,-33.8 (longitude first)?'
    >>> _meant("179.5,-17,-179.5,-16", 179.5, -179.5)
    '; a box cannot cross the antimeridian: search each side of it on its own'
    """
    words = [v.strip() for v in text.split(",")]
    if w > 90 and e < -90:
        return "; a box cannot cross the antimeridian: search each side of it on its own"
    orders = ((0, 1, 2, 3), (2, 1, 0, 3), (0, 3, 2, 1), (2, 3, 0, 1), (1, 0, 3, 2), (3, 0, 1, 2), (1, 2, 3, 0),
              (3, 2, 1, 0))
    lat_out = max(abs(float(words[1])), abs(float(words[3]))) > 90   # latitudes that cannot be: lon, lat given
    for order in orders[1:]:   # the first is what was given
        values = [float(words[i]) for i in order]
        if _inside(*values) and (order[0] in (1, 3)) == lat_out:
            what = "longitude first" if order[0] in (1, 3) else "west first, south second"
            return f"; did you mean --bbox {','.join(words[i] for i in order)} ({what})?"
    return ""


def check_centre(lat: float, lon: float) -> None:
    """ConfigError unless ``--lat``/``--lon`` is a finite point Web Mercator can draw (every
    command's: one check, one message).

    >>> check_centre(60.5, 26.9)
    >>> check_centre(89.0, 0.0)
    Traceback (most recent call last):
    ...
    osmseg.errors.ConfigError: --lat 89.0 --lon 0.0: out of range for Web Mercator (|lat| <= 85.05, |lon| <= 180)
    """
    if not (math.isfinite(lat) and math.isfinite(lon) and -85.05 <= lat <= 85.05 and -180 <= lon <= 180):
        raise ConfigError(f"--lat {lat} --lon {lon}: out of range for Web Mercator (|lat| <= 85.05, |lon| <= 180)")


def destination(lon: float, lat: float, distance_m: float, bearing_rad: float) -> tuple[float, float]:
    """The point ``distance_m`` from (lon, lat) along ``bearing_rad`` on a sphere."""
    phi1, lam1 = math.radians(lat), math.radians(lon)
    d = distance_m / EARTH_RADIUS_M
    phi2 = math.asin(math.sin(phi1) * math.cos(d) + math.cos(phi1) * math.sin(d) * math.cos(bearing_rad))
    lam2 = lam1 + math.atan2(
        math.sin(bearing_rad) * math.sin(d) * math.cos(phi1), math.cos(d) - math.sin(phi1) * math.sin(phi2)
    )
    return (math.degrees(lam2) + 540.0) % 360.0 - 180.0, math.degrees(phi2)


def haversine_m(lon1: float, lat1: float, lon2: np.ndarray | float, lat2: np.ndarray | float) -> np.ndarray:
    """Great-circle distance in metres from (lon1, lat1) to each (lon2, lat2) on the same sphere as
    :func:`destination` (so a point ``destination(..., d, ...)`` is ``d`` away).

    >>> round(float(haversine_m(0.0, 0.0, *destination(0.0, 0.0, 1234.5, 1.0))), 3)
    1234.5
    """
    phi1, phi2 = np.radians(lat1), np.radians(lat2)
    dphi, dlam = phi2 - phi1, np.radians(np.asarray(lon2) - lon1)
    a = np.sin(dphi / 2) ** 2 + np.cos(phi1) * np.cos(phi2) * np.sin(dlam / 2) ** 2
    return np.asarray(2 * EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(a, 0.0, 1.0))))
