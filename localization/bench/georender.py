"""A second renderer for the localization benchmarks: ground views ray-cast over 3-D geometry.

Why a second one: :mod:`localization.bench.render` draws a panorama from the aerial label mask with
a one-height-per-class first-hit model, the same model the profile method scores with. A
benchmark drawn only that way measures the method against itself. This renderer shares no
code with it or with the methods (the panorama's pixel convention below is written out
again, and ``tests/localize/test_loc_georender.py`` checks that both renderers agree on a scene where
their models coincide). It works on geometry in metres rather than on a mask, and its scene
is closer to what a camera sees:

Scene (:class:`Scene`)
    **Solids** are prisms standing on flat ground: a footprint polygon (shapely, metres, x
    east, y north), a base and a top height, a class id and an opacity. Buildings are opaque
    prisms from 0 m to their own height; a tree is a crown, a prism from its trunk height to
    its top with opacity below 1 (a ray crossing it is stopped with that probability, drawn
    per pixel and object from the scene's seed: leaves let some of what is behind through);
    a car is a 1.5 m box. **Ground patches** (polygons with a class, later ones drawn over
    earlier ones: roads over grass) colour the ground; elsewhere it is ``ground_class``.

Camera (:class:`Camera`)
    At ``(x, y)``, ``eye_m`` above the ground, looking along ``heading_deg`` (compass,
    clockwise from north), tilted by ``pitch_deg`` (positive: looking up) and ``roll_deg``
    (positive: the right side down), seeing ``hfov_deg`` degrees across ``width`` columns.
    Pixels are square in angle (the convention every method of osmseg assumes): column ``c``
    looks ``hfov * ((c + 0.5) / width - 0.5)`` degrees right of the heading, row ``r`` at
    ``(height / 2 - r - 0.5) * hfov / width`` degrees above the camera's horizon.

Model
    Each pixel's ray leaves the eye in its own direction (tilt included). It hits a solid
    where its height ``eye + d * tan(elevation)`` lies between the solid's base and top at a
    distance ``d`` inside the footprint; the nearest hit that is not seen through wins. So a
    near 3 m wall hides a far 20 m building only below the wall's top, a roof higher than the
    eye is never seen from below, and a row above the horizon shows sky unless something
    rises into it. A ray going down that hits nothing meets the ground at ``eye / tan(-el)``
    and takes the ground's class there; ground beyond ``max_range_m`` is ``far_class``.

>>> from shapely.geometry import box
>>> scene = Scene(solids=(Solid(box(-10, 20, 10, 30), 0.0, 10.0, class_id=1),), ground_class=5)
>>> view = render(scene, Camera(0.0, 0.0, eye_m=2.0, width=360, height=90), sky_class=14, far_class=0)
>>> view[[0, 30, 44, 60], 180].tolist()      # looking north: sky, building, building, ground
[14, 1, 1, 5]
>>> int(view[30, 0])                         # looking south: nothing stands there
14
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import shapely
from shapely.geometry import LineString, Polygon
from shapely.strtree import STRtree

from osmseg.errors import ConfigError

__all__ = ["Solid", "GroundPatch", "Scene", "Camera", "render", "pixel_directions", "tree_crown"]


@dataclass(frozen=True)
class Solid:
    """A prism on the ground: ``polygon`` (metres) from ``base_m`` up to ``top_m``, of class
    ``class_id``; ``opacity`` < 1 lets that share of the rays crossing it through."""

    polygon: Polygon
    base_m: float
    top_m: float
    class_id: int
    opacity: float = 1.0

    def __post_init__(self) -> None:
        if not 0 <= self.base_m < self.top_m:
            raise ConfigError(f"a solid needs 0 <= base < top, got base {self.base_m} m and top {self.top_m} m")
        if not 0 < self.opacity <= 1:
            raise ConfigError(f"opacity must be in (0, 1], got {self.opacity}")


@dataclass(frozen=True)
class GroundPatch:
    """A flat area of the ground of class ``class_id`` (later patches are drawn over earlier)."""

    polygon: Polygon
    class_id: int


@dataclass(frozen=True)
class Scene:
    """Solids and ground patches in metres; ``seed`` draws which rays pass through crowns."""

    solids: tuple[Solid, ...] = ()
    ground: tuple[GroundPatch, ...] = ()
    ground_class: int = 0
    seed: int = 0


@dataclass(frozen=True)
class Camera:
    """Where the camera stands and how it looks (see the module docstring)."""

    x: float
    y: float
    eye_m: float = 1.7
    heading_deg: float = 0.0
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    hfov_deg: float = 360.0
    width: int = 1232
    height: int = 224
    max_range_m: float = 150.0

    def __post_init__(self) -> None:
        if self.eye_m <= 0:
            raise ConfigError(f"the camera must stand above the ground, got eye height {self.eye_m} m")
        if not 0 < self.hfov_deg <= 360:
            raise ConfigError(f"hfov must be in (0, 360] degrees, got {self.hfov_deg}")
        if self.width < 1 or self.height < 1 or self.height * self.hfov_deg / self.width > 180:
            raise ConfigError(f"a {self.width}x{self.height} view of {self.hfov_deg}° would span more than 180° "
                              "from top to bottom; give a wider image")

    @property
    def step_deg(self) -> float:
        return self.hfov_deg / self.width


def tree_crown(x: float, y: float, height_m: float, class_id: int, radius_m: float | None = None,
               trunk_m: float | None = None, opacity: float = 0.7) -> Solid:
    """A tree as a crown: a disc of ``radius_m`` (default a third of the height, at least 1.5 m)
    from ``trunk_m`` (default a third of the height) to ``height_m``.

    >>> t = tree_crown(0, 0, 9.0, class_id=4)
    >>> t.base_m, t.top_m, round(t.polygon.area / math.pi)
    (3.0, 9.0, 9)
    """
    radius = radius_m if radius_m is not None else max(1.5, height_m / 3)
    trunk = trunk_m if trunk_m is not None else height_m / 3
    return Solid(shapely.Point(x, y).buffer(radius, quad_segs=8), trunk, height_m, class_id, opacity)


def pixel_directions(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """World azimuth (degrees, [0, 360)) and elevation (degrees) of every pixel's ray, ``(height, width)``.

    >>> az, el = pixel_directions(Camera(0, 0, width=4, height=2))
    >>> az[0].round(6).tolist(), el[:, 0].round(6).tolist()
    ([225.0, 315.0, 45.0, 135.0], [45.0, -45.0])
    """
    step = math.radians(camera.step_deg)
    across = (np.arange(camera.width) + 0.5 - camera.width / 2) * step       # right of the heading
    up = (camera.height / 2 - np.arange(camera.height) - 0.5) * step          # above the camera's horizon
    a, e = np.meshgrid(across, up)
    # camera frame: x right, y forward, z up
    v = np.stack([np.cos(e) * np.sin(a), np.cos(e) * np.cos(a), np.sin(e)])
    p, r = math.radians(camera.pitch_deg), math.radians(camera.roll_deg)
    # pitch: turn forward towards up about the x axis
    v = np.stack([v[0], v[1] * math.cos(p) - v[2] * math.sin(p), v[1] * math.sin(p) + v[2] * math.cos(p)])
    # roll: turn about the forward axis, the right side going down
    v = np.stack([v[0] * math.cos(r) + v[2] * math.sin(r), v[1], -v[0] * math.sin(r) + v[2] * math.cos(r)])
    azimuth = (np.degrees(np.arctan2(v[0], v[1])) + camera.heading_deg) % 360.0
    elevation = np.degrees(np.arcsin(np.clip(v[2], -1.0, 1.0)))
    return azimuth, elevation


@dataclass
class _Caster:
    """The scene's solids indexed for rays from one camera position."""

    scene: Scene
    camera: Camera
    tree: STRtree = field(init=False)

    def __post_init__(self) -> None:
        self.tree = STRtree([s.polygon for s in self.scene.solids])

    def spans(self, azimuth_deg: float) -> list[tuple[float, float, int]]:
        """(distance in, distance out, solid index) of every footprint the ray along
        ``azimuth_deg`` crosses within range, nearest first (a footprint the camera stands in
        starts at 0)."""
        c, rad = self.camera, math.radians(azimuth_deg)
        dx, dy = math.sin(rad), math.cos(rad)
        ray = LineString([(c.x, c.y), (c.x + dx * c.max_range_m, c.y + dy * c.max_range_m)])
        out: list[tuple[float, float, int]] = []
        for i in self.tree.query(ray, predicate="intersects"):
            crossing = ray.intersection(self.scene.solids[int(i)].polygon)
            for part in getattr(crossing, "geoms", [crossing]):
                coords = np.asarray(part.coords) if not part.is_empty else np.empty((0, 2))
                if len(coords) == 0:
                    continue
                d = (coords[:, 0] - c.x) * dx + (coords[:, 1] - c.y) * dy
                out.append((float(d.min()), float(d.max()), int(i)))
        return sorted(out)


def _hits(span: tuple[float, float, int], solid: Solid, eye: float, slope: np.ndarray) -> np.ndarray:
    """Distance at which rays of the given ``slope`` (tan of elevation) first enter ``solid``
    within ``span``; inf where they pass above or below it."""
    d_in, d_out, _ = span
    with np.errstate(divide="ignore", invalid="ignore"):
        low = (solid.base_m - eye) / slope    # where the ray's height crosses the base ...
        high = (solid.top_m - eye) / slope    # ... and the top
    enter = np.where(slope > 0, low, np.where(slope < 0, high, -np.inf))
    leave = np.where(slope > 0, high, np.where(slope < 0, low, np.inf))
    level = slope == 0  # a level ray is inside the prism's height range or never
    inside_level = (solid.base_m <= eye) & (eye <= solid.top_m)
    start = np.maximum(d_in, enter)
    end = np.minimum(d_out, leave)
    hit = np.where(level, inside_level, start <= end)
    return np.where(hit, np.maximum(start, d_in), np.inf)


def render(scene: Scene, camera: Camera, sky_class: int, far_class: int) -> np.ndarray:
    """The ``(height, width)`` uint8 class view ``camera`` sees of ``scene``."""
    azimuth, elevation = pixel_directions(camera)
    slope = np.tan(np.radians(elevation))
    out = np.full(azimuth.shape, sky_class, np.uint8)
    nearest = np.full(azimuth.shape, np.inf)
    caster = _Caster(scene, camera)
    # rays are cast per azimuth, quantised finely enough that a tilted column's pixels share few
    bins = np.round(azimuth / camera.step_deg * 4).astype(np.int64).ravel()
    order = np.argsort(bins, kind="stable")
    starts = np.flatnonzero(np.diff(bins[order], prepend=-1))
    for group in np.split(order, starts[1:]):
        b = int(bins[group[0]])
        where = np.unravel_index(group, azimuth.shape)
        spans = caster.spans(b * camera.step_deg / 4)
        for span in spans:
            solid = scene.solids[span[2]]
            d = _hits(span, solid, camera.eye_m, slope[where])
            if solid.opacity < 1:
                draws = np.random.default_rng([scene.seed, span[2], b % (1 << 62)]).random(len(d))
                d = np.where(draws < solid.opacity, d, np.inf)
            closer = d < nearest[where]
            rows, cols = where[0][closer], where[1][closer]
            nearest[rows, cols] = d[closer]
            out[rows, cols] = solid.class_id
    # the ground: rays going down that no solid stopped before they reach it
    down = slope < 0
    with np.errstate(divide="ignore"):
        ground_d = np.where(down, camera.eye_m / np.where(down, -slope, 1.0), np.inf)
    to_ground = down & (ground_d < nearest)
    far = to_ground & (ground_d > camera.max_range_m)
    out[far] = far_class
    seen = to_ground & ~far
    rad = np.radians(azimuth[seen])
    xs = camera.x + ground_d[seen] * np.sin(rad)
    ys = camera.y + ground_d[seen] * np.cos(rad)
    out[seen] = ground_classes(scene, xs, ys)
    return out


def ground_classes(scene: Scene, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """The ground's class at points ``(xs, ys)``: the last patch holding each, else ``ground_class``."""
    classes = np.full(len(xs), scene.ground_class, np.uint8)
    if not scene.ground or len(xs) == 0:
        return classes
    order = np.full(len(xs), -1, np.int64)
    points = shapely.points(xs, ys)
    tree = STRtree([g.polygon for g in scene.ground])
    point_i, patch_i = tree.query(points, predicate="intersects")
    np.maximum.at(order, point_i, patch_i)
    has = order >= 0
    classes[has] = np.array([g.class_id for g in scene.ground], np.uint8)[order[has]]
    return classes
