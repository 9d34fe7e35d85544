"""Geometry helpers of the OSM reader: Web Mercator projection and polygon clean-up.

Imports: numpy and shapely only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import reduce
from typing import cast

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

EARTH_RADIUS = 6378137.0
MAX_LAT = 85.0511287798


def lonlat_to_mercator(coords: np.ndarray) -> np.ndarray:
    """``(N, 2)`` lon/lat degrees to EPSG:3857 metres (spherical Web Mercator, exact).

    >>> lonlat_to_mercator(np.array([[180.0, 45.0]])).round(1).tolist()
    [[20037508.3, 5621521.5]]
    >>> import mercantile; x, y = mercantile.xy(24.94, 60.17)
    >>> bool(np.allclose(lonlat_to_mercator(np.array([[24.94, 60.17]])), [[x, y]]))
    True
    """
    lon = np.radians(coords[:, 0])
    lat = np.radians(np.clip(coords[:, 1], -MAX_LAT, MAX_LAT))
    return np.column_stack([EARTH_RADIUS * lon, EARTH_RADIUS * np.log(np.tan(math.pi / 4 + lat / 2))])


def to_mercator(geoms: np.ndarray) -> np.ndarray:
    """Shapely geometries in lon/lat degrees to EPSG:3857 metres."""
    return cast("np.ndarray", shapely.transform(geoms, lonlat_to_mercator))


def mercator_scale(lonlat: np.ndarray) -> np.ndarray:
    """Web Mercator metres per ground metre at each lon/lat geometry: ``1/cos(latitude)`` at the
    middle of its own latitude span.

    Taken from the feature itself, never from the sample it is drawn in: a road or crown then has
    the same Web Mercator outline, and so the same pixels, in every sample box that sees it (the
    scale at the sample's centre made two overlapping samples disagree where an edge passed near
    a pixel centre). Over a feature's span the scale varies by ``tan(lat) * dlat`` (5e-4 for a
    2 km way at 60 N: 5 mm on a 10 m road).

    >>> mercator_scale(np.array([shapely.Point(24.9, 60.0), shapely.LineString([(0, -1), (1, 1)])])).round(6).tolist()
    [2.0, 1.0]
    """
    _, south, _, north = shapely.bounds(lonlat).T
    return cast("np.ndarray", 1.0 / np.cos(np.radians(np.clip((south + north) / 2, -MAX_LAT, MAX_LAT))))  # as projected


def polygonal(geom: BaseGeometry) -> BaseGeometry | None:
    """The polygon parts of ``geom`` (make_valid and clipping can leave lines and points)."""
    if geom is None or geom.is_empty:
        return None
    if geom.geom_type in ("Polygon", "MultiPolygon"):
        return geom
    parts = [p for p in shapely.get_parts(geom) if p.geom_type in ("Polygon", "MultiPolygon") and not p.is_empty]
    if not parts:
        return None
    return parts[0] if len(parts) == 1 else shapely.union_all(parts)


def even_odd(lines: Sequence[BaseGeometry]) -> BaseGeometry | None:
    """Polygon from member lines: join them, keep the closed rings, combine even-odd."""
    if not lines:
        return None
    merged = shapely.line_merge(shapely.MultiLineString(lines))
    rings = [p for p in shapely.get_parts(merged) if p.is_closed and len(p.coords) >= 4]
    polys = [shapely.make_valid(shapely.Polygon(r.coords)) for r in rings]
    polys = [p for p in polys if not p.is_empty]
    if not polys:
        return None
    return polygonal(reduce(shapely.symmetric_difference, polys))
