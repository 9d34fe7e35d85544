"""Sea polygons from OSM coastline ways, inside one box.

OSM maps the sea only by its edge: ``natural=coastline`` ways, drawn with the land on the
left and the water on the right of the way direction.  There is no sea polygon to draw, so
we make one for the box we need:

1. cut the coastline at the box and node it with the box outline;
2. polygonize: the box falls apart into faces, each wholly land or wholly sea;
3. every coastline segment votes, weighted by its length: the face just to its right is sea,
   the face just to its left is land.

This handles a coast crossing the box in any direction, several coast pieces, islands lying
entirely inside the box (their ring votes "sea" for the face around them) and straits and
bays.  A box that no coastline crosses is wholly land or wholly sea: the side of the nearest
coastline decides (the straight path to the nearest coast point crosses no coast).  With no
coastline at all in the data there is no sea.  Coordinates are projected (x east, y north),
e.g. EPSG:3857 metres.  Only coastline crossing or nearest to the box is used, so coastline
cut off elsewhere (an extract's edge) does not matter.

>>> from shapely import LineString
>>> coast = LineString([(0, 5), (10, 5)])  # heading east: water on the right, i.e. south
>>> sea_polygon([coast], (0, 0, 10, 10)).bounds
(0.0, 0.0, 10.0, 5.0)
>>> sea_polygon([coast.reverse()], (0, 0, 10, 10)).bounds
(0.0, 5.0, 10.0, 10.0)
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import cast

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

logger = logging.getLogger(__name__)

#: How far (projected units, metres) beside a segment the side test looks. Far below a pixel.
SIDE_OFFSET = 0.01

#: A face is sea (land) when the coastline with it on the right (left) is this many times longer
#: than the other way round. Clean data gives one side only; loose ends (a coastline that stops
#: inside the box) put both sides in one face, which is then left undecided.
CLEAR_MAJORITY = 3.0


def sea_polygon(coastlines: Sequence[BaseGeometry], bounds: tuple[float, float, float, float],
                warn: Callable[[str], None] = logger.warning) -> BaseGeometry | None:
    """The sea inside ``bounds`` (left, bottom, right, top), or None if there is none.

    ``coastlines`` are LineStrings in OSM direction (land left, water right).  The result is
    a Polygon or MultiPolygon clipped to the box.  ``warn`` receives the one-line message when
    loose coastline ends leave part of the box undecided.

    >>> from shapely import LineString
    >>> far_coast = LineString([(-50, 20), (50, 20)])  # north of the box, sea to its south
    >>> sea_polygon([far_coast], (0, 0, 10, 10)).area, sea_polygon([far_coast.reverse()], (0, 0, 10, 10))
    (100.0, None)
    """
    lines = [g for g in coastlines if g is not None and not g.is_empty and g.geom_type == "LineString"]
    if not lines:
        return None
    box = shapely.box(*bounds)
    crossing = [g for g in lines if g.intersects(box)]
    if not crossing:
        centre = ((bounds[0] + bounds[2]) / 2, (bounds[1] + bounds[3]) / 2)
        return box if _right_of_nearest(lines, centre) else None
    faces = _faces(shapely.MultiLineString(crossing), box)
    if not faces.size:
        return None
    right, left = _side_votes(crossing, box, faces)
    sea = faces[right > CLEAR_MAJORITY * left]
    unsure = ~(right > CLEAR_MAJORITY * left) & ~(left > CLEAR_MAJORITY * right)
    if unsure.any():
        share = 100 * shapely.area(faces[unsure]).sum() / box.area
        warn(f"coastline in the box has loose ends (incomplete data?): {share:.0f}% of the box is neither "
             "clearly sea nor land and is not drawn as sea; give complete coastline ways")
    if not sea.size:
        return None
    return _polygonal(shapely.intersection(shapely.union_all(sea), box))


def _polygonal(geom: BaseGeometry) -> BaseGeometry | None:
    parts = [p for p in shapely.get_parts(geom) if p.geom_type == "Polygon" and p.area > 0]
    if not parts:
        return None
    return parts[0] if len(parts) == 1 else shapely.MultiPolygon(parts)


def _faces(coast: BaseGeometry, box: BaseGeometry) -> np.ndarray:
    """The faces that the coastline cuts ``box`` into."""
    inside = shapely.intersection(coast, box)
    noded = shapely.union_all([inside, box.exterior])
    return cast("np.ndarray", shapely.get_parts(shapely.polygonize(shapely.get_parts(noded))))


def _segments(lines: Sequence[BaseGeometry]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start points, end points and line index of every segment of ``lines``."""
    starts, ends, which = [], [], []
    for i, line in enumerate(lines):
        xy = shapely.get_coordinates(line)
        starts.append(xy[:-1])
        ends.append(xy[1:])
        which.append(np.full(len(xy) - 1, i))
    return np.concatenate(starts), np.concatenate(ends), np.concatenate(which)


def _side_votes(lines: Sequence[BaseGeometry], box: BaseGeometry, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per face: length of coastline with the face on its right (sea side), and on its left."""
    a, b, _ = _segments(lines)
    pieces = shapely.intersection(shapely.linestrings(np.stack([a, b], axis=1)), box)  # box is convex
    keep = (shapely.get_type_id(pieces) == 1) & (shapely.length(pieces) > 4 * SIDE_OFFSET)
    votes = (np.zeros(len(faces)), np.zeros(len(faces)))
    if not keep.any():
        return votes
    mid = shapely.get_coordinates(pieces[keep]).reshape(-1, 2, 2).mean(axis=1)
    direction = b[keep] - a[keep]  # the OSM direction (intersection may reverse a piece)
    length = shapely.length(pieces[keep])
    unit = direction / np.linalg.norm(direction, axis=1)[:, None]
    right = np.column_stack([unit[:, 1], -unit[:, 0]])  # x east, y north: right of (dx, dy) is (dy, -dx)
    tree = shapely.STRtree(faces)
    for side, pts in zip(votes, (mid + SIDE_OFFSET * right, mid - SIDE_OFFSET * right)):
        hit_point, hit_face = tree.query(shapely.points(pts), predicate="within")
        np.add.at(side, hit_face, length[hit_point])
    return votes


def _right_of_nearest(lines: Sequence[BaseGeometry], point: tuple[float, float]) -> bool:
    """True if ``point`` lies on the right (water) side of the coastline nearest to it.

    When the nearest coast point is a vertex, the corner decides: at a left turn the water side
    is the union of both segments' right half-planes, at a right turn their intersection.

    >>> from shapely import LineString
    >>> island = LineString([(0, 0), (10, 0), (10, 10), (0, 10), (0, 0)])  # anticlockwise
    >>> _right_of_nearest([island], (-3, -4)), _right_of_nearest([island], (1, 2))
    (True, False)
    """
    a, b, which = _segments(lines)
    p = np.asarray(point, dtype=float)
    d = b - a
    length2 = np.maximum((d * d).sum(axis=1), 1e-300)
    t = np.clip(((p - a) * d).sum(axis=1) / length2, 0.0, 1.0)
    k = int(np.argmin(((a + t[:, None] * d - p) ** 2).sum(axis=1)))
    same = np.flatnonzero(which == which[k])  # segments of the nearest line, in order
    closed = bool(lines[int(which[k])].is_closed)

    def right_of(i: int) -> bool:
        return _cross(d[i], p - a[i]) < 0

    if t[k] >= 1.0 and (k != same[-1] or closed):
        first, second = k, (k + 1 if k != same[-1] else int(same[0]))
    elif t[k] <= 0.0 and (k != same[0] or closed):
        first, second = (k - 1 if k != same[0] else int(same[-1])), k
    else:
        return right_of(k)
    if _cross(d[first], d[second]) > 0:  # left turn
        return right_of(first) or right_of(second)
    return right_of(first) and right_of(second)


def _cross(u: np.ndarray, v: np.ndarray) -> float:
    return float(u[0] * v[1] - u[1] * v[0])
