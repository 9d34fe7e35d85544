"""Angular profiles: what a camera standing at a point sees around the horizon, class by class.

The ``profile`` method (:mod:`localization.profile.search`) compares what the query shows at every
azimuth with what the aerial image predicts from a candidate position. Both sides become the
same kind of array, a **profile** ``(C, R + 1, A)``:

* ``A`` azimuth bins of ``360 / A`` degrees, bin ``a`` centred on the compass azimuth
  ``a * 360 / A`` (clockwise from north = up in the aerial image);
* ``R`` ground distances ``radii_m`` (metres from the camera) plus one slot ``R`` for "seen
  in this direction at some distance" (a landmark whose distance the query does not tell);
* ``C`` landmark classes (the class dictionary's: building, road, vegetation, footway).

**The vista** (:class:`Vista`): a query mask with a sky adds one more radius, ``vista.distance_m``,
after the others. Where a column's sky comes down to within ``vista.max_deg`` of the horizon,
nothing a few metres tall stands in that direction for a long way: a building or tree 4 m
tall 75 m from a camera 2.5 m up rises 1.1 degrees above the horizon. The claim needs no
height: it says only that *nothing* stands there. Its cell holds the mass ``vista.weight``
(in radii) times the share of the bin's columns that are open, on class ``other``; the aerial
side's vista cell reads ``other`` where no standing pixel lies within the distance (every
ground class merged: the query cannot tell a road 75 m away from grass), else the class that
stands first. A look-alike that fits the near radii but has a building where the view sees
open sky loses that mass; rows of far ground alone weigh too little to say it (each far radius
is one of 16, and its ground class is rarely the same as the map's).

**The query** (:func:`query_from_mask`, :func:`query_from_landmarks`). A ground camera
``h`` metres above flat ground sees the ground at distance ``d`` at the depression angle
``atan(h / d)`` below the horizon, so each panorama row under the horizon is one ground
distance. The pixel there shows the ground's class at ``d`` if nothing stands in between, or
else the *first thing that stands up* (a building, a tree) in that direction. Distances read
this way come from the *bottom* of whatever is seen, never from its top, so they do not
depend on how tall buildings or trees are. A landmark file's point gives its azimuth, and a
distance when its class lies on the ground (road, footway) and its row is below the
horizon; a standing landmark's point (a building's centre) goes to slot ``R``.

**The aerial prediction** (:class:`AerialMaskIndex`, :class:`AerialLandmarkIndex`). From a
mask: one ray per azimuth bin from the position, sampled outward; the class at radius ``r``
is the first standing pixel's class before ``r`` if there is one, else the class at ``r``
(the same first-hit rule, so occlusion is modelled; standing classes are the mask classes
named in ``standing``). Slot ``R`` holds every class seen along the ray. From landmark points:
buildings (:data:`OPAQUE_LANDMARKS`) in slot ``R`` by the same first-hit rule, each point a
façade some metres wide on either side (:func:`first_hits`); every other cell
``P[c, k, a] = max_i g(d_i) K_az(a - θ_i) K_d(d_i, r_k)`` over the landmarks ``i`` of class
``c`` at bearing ``θ_i`` and distance ``d_i`` from the position, with a Gaussian bearing kernel,
a log-normal distance kernel and a distance weight ``g(d) = 1 / (1 + d / d0)``.

Imports: numpy, osmseg core, localization.common (the query's :class:`~localization.common.views.Camera`
and :class:`~localization.common.views.SemanticMap`), localization.profile.horizon (where a view's sky ends).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple, cast

import numpy as np

from localization.common.landmarks import Landmarks
from localization.common.views import OTHER, Camera, SemanticMap
from localization.profile.horizon import horizon_bounds
from osmseg.errors import ConfigError

__all__ = ["MASK_MIN_CONFIDENCE", "Vista", "open_columns", "without_vista", "STANDING_LANDMARKS", "QueryProfile",
           "query_from_mask", "query_poses", "query_from_landmarks", "AerialMaskIndex", "AerialLandmarkIndex", "ray_radii", "OPAQUE_LANDMARKS",
           "HALF_WIDTHS_M", "first_hits", "seen_fraction"]

#: Landmark classes whose points mark something standing (their row says nothing about distance).
STANDING_LANDMARKS = ("building", "vegetation")
#: Landmark classes that hide what lies behind them (trees let the view through between crowns).
OPAQUE_LANDMARKS = ("building",)
#: Half-widths (m) an opaque landmark point may stand for; its predicted profile is the mean over them.
HALF_WIDTHS_M = (4.0, 6.0, 8.0)
#: The "not sure" threshold of an aerial mask: the confidence (localization.profile.search) below which an
#: answer is not given. Chosen on rendered views in Kotka (docs/localization.md): few wrong answers pass it.
MASK_MIN_CONFIDENCE = 0.04


class Vista(NamedTuple):
    """The vista cell of a query mask with a sky (see the module docstring): how far an open horizon
    says nothing stands, how close to the horizon its sky must come down, and its mass in radii."""

    distance_m: float = 75.0
    max_deg: float = 1.0
    weight: float = 4.0


def open_columns(sem: SemanticMap, camera: Camera, max_deg: float) -> np.ndarray:
    """Which columns of a view see sky down to within ``max_deg`` of the (tilted) horizon, and nothing
    standing above that line (sky seen under a tree's crown says nothing): nothing stands there.
    None of them without a sky class.

    >>> cam = Camera(5, 90, row_step_deg=1.0)                # the horizon between rows 44 and 45
    >>> sky = np.zeros((90, 5), bool); sky[:45, 0] = sky[:30, 1] = sky[:44, 2] = sky[:45, 4] = True
    >>> labels, standing = np.where(sky, -1, 0).astype(np.int8), np.zeros_like(sky)
    >>> sky[10:40, 4], standing[10:40, 4] = False, True       # column 4: a crown with sky under it
    >>> open_columns(SemanticMap(labels, standing, ("road", "other"), sky), cam, 1.0).tolist()
    [True, False, True, False, False]
    >>> up = Camera(5, 90, row_step_deg=1.0, hfov_deg=5, pitch_deg=2.0)  # pitched up: the horizon 2 rows lower,
    >>> open_columns(SemanticMap(labels, standing, ("road", "other"), sky), up, 1.0).tolist()  # the sky ends 2° above
    [False, False, False, False, False]
    """
    if sem.sky is None:
        return np.zeros(sem.shape[1], dtype=bool)
    cols = np.arange(sem.shape[1])
    lowest = horizon_bounds(sem)[0]                           # the lowest sky row of each column, -1 none
    horizon = camera.horizon + camera.tilt_rows(cols)
    elevation = (horizon - (lowest + 0.5)) * camera.step      # the lower edge of the lowest sky pixel
    above = np.arange(sem.shape[0])[:, None] + 0.5 < (horizon - max_deg / camera.step)[None, :]
    return cast("np.ndarray", (lowest >= 0) & (elevation <= max_deg + 1e-9) & ~(sem.standing & above).any(axis=0))


def ray_radii(camera: Camera, n: int, min_m: float, max_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``n`` log-spaced ground distances between ``min_m`` and ``max_m`` that fall on distinct rows.

    Returns ``(radii_m, rows)``: each radius is the exact distance of its (integer) row, so the
    query and the aerial prediction look at the same place.

    >>> r, rows = ray_radii(Camera(1232, 224), 6, 3.0, 60.0)   # 3 m is below the bottom row (3.1 m)
    >>> rows.tolist(), [round(float(v), 1) for v in r]
    ([[180, 150, 133, 123, 118]], [5.5, 10.1, 18.2, 34.1, 60.3])
    """
    if not (0 < min_m < max_m):
        raise ConfigError(f"ground distances must satisfy 0 < min < max, got {min_m:g} and {max_m:g}")
    rows = sorted({int(round(camera.row_of(d))) for d in np.geomspace(min_m, max_m, max(1, n))}, reverse=True)
    rows = [r for r in rows if camera.horizon < r < camera.height]
    if not rows:
        raise ConfigError(f"no row of the {camera.width}x{camera.height} query looks at the ground between "
                          f"{min_m:g} and {max_m:g} m: check the horizon row and the camera height")
    rows_a = np.array(rows, dtype=np.int64)
    return camera.distance_m(rows_a), rows_a.reshape(1, -1)


@dataclass(frozen=True, eq=False)
class QueryProfile:
    """A query's profile ``q`` (C, R + 1, A) in its own frame (column azimuths with heading 0 or the given one)."""

    q: np.ndarray
    radii_m: np.ndarray
    classes: tuple[str, ...]
    heading_deg: float | None  # the heading the azimuths were computed with; None: query frame (unknown)
    hfov_deg: float
    pose: tuple[float, float, float] | None = None  # (camera height m, pitch, roll degrees) it was read with
    variants: tuple[QueryProfile, ...] = ()  # the same query read at other camera heights; q is their mean
    vista: bool = False  # the last of radii_m is the vista cell (see the module docstring)

    @property
    def bins(self) -> int:
        return int(self.q.shape[-1])

    @property
    def mass(self) -> float:
        return float(self.q.sum())


def _bins_of(azimuth_deg: np.ndarray, bins: int) -> np.ndarray:
    return np.rint(np.asarray(azimuth_deg) * bins / 360.0).astype(np.int64) % bins


def query_from_mask(sem: SemanticMap, camera: Camera, *, bins: int, radii: tuple[np.ndarray, np.ndarray],
                    heading_deg: float | None = 0.0, vista: Vista | None = None) -> QueryProfile:
    """The profile of a query mask: class fractions of each azimuth bin at each ground row.

    ``heading_deg`` None builds it in the query's own frame, for a heading search. ``vista`` adds
    the vista cell when the view has a sky (see the module docstring).
    """
    if sem.shape != (camera.height, camera.width):
        raise ConfigError(f"query mask is {sem.shape[1]}x{sem.shape[0]} but the camera says "
                          f"{camera.width}x{camera.height}")
    radii_m, rows = radii
    n_c, n_r = len(sem.classes), len(radii_m)
    cols = np.arange(camera.width)
    b = _bins_of(camera.azimuths(cols, heading_deg or 0.0), bins)
    per_bin = np.bincount(b, minlength=bins).astype(np.float64)
    q = np.zeros((n_c, n_r + 1, bins))
    if camera.level and np.array_equal(rows[0], np.rint([camera.row_of(float(d)) for d in radii_m])):
        for k, row in enumerate(rows[0]):
            lab = sem.labels[int(row)].astype(np.int64)
            ok = lab >= 0
            np.add.at(q[:, k, :], (lab[ok], b[ok]), 1.0)
    else:  # a tilted camera, or another camera height than the radii were chosen for: a row per column
        shift = camera.tilt_rows(cols)
        for k, d in enumerate(radii_m):
            row = np.rint(camera.row_of(float(d)) + shift).astype(np.int64)
            inside = (row >= 0) & (row < camera.height)
            lab = np.full(camera.width, -1, dtype=np.int64)
            lab[inside] = sem.labels[row[inside], cols[inside]]
            ok = lab >= 0
            np.add.at(q[:, k, :], (lab[ok], b[ok]), 1.0)

    q[:, :n_r] /= np.maximum(per_bin, 1.0)[None, None, :]
    pose = (camera.camera_height_m, camera.pitch_deg, camera.roll_deg)
    if vista is None or vista.weight <= 0 or sem.sky is None or OTHER not in sem.classes:
        return QueryProfile(q=q, radii_m=radii_m, classes=sem.classes, heading_deg=heading_deg,
                            hfov_deg=camera.hfov_deg, pose=pose)
    if vista.distance_m <= float(radii_m.max()):
        raise ConfigError(f"the vista ({vista.distance_m:g} m) must lie beyond the farthest radius "
                          f"({float(radii_m.max()):g} m)")
    opened = np.bincount(b, weights=open_columns(sem, camera, vista.max_deg).astype(np.float64), minlength=bins)
    far = np.zeros((len(sem.classes), 1, bins))
    far[sem.classes.index(OTHER), 0] = vista.weight * opened / np.maximum(per_bin, 1.0)
    return QueryProfile(q=np.concatenate([q[:, :n_r], far, q[:, n_r:]], axis=1),
                        radii_m=np.append(radii_m, vista.distance_m), classes=sem.classes, heading_deg=heading_deg,
                        hfov_deg=camera.hfov_deg, pose=pose, vista=True)


def without_vista(query: QueryProfile) -> QueryProfile:
    """``query`` without its vista cell (for an aerial side that cannot predict one), each variant alike."""
    if not query.vista:
        return query
    keep = [*range(len(query.radii_m) - 1), len(query.radii_m)]      # every radius but the vista, and slot R
    variants = tuple(without_vista(v) for v in query.variants)
    return dataclasses.replace(query, q=query.q[:, keep], radii_m=query.radii_m[:-1], vista=False, variants=variants)


def query_poses(sem: SemanticMap, camera: Camera, *, bins: int, radii: tuple[np.ndarray, np.ndarray],
                heading_deg: float | None, heights: Sequence[float], vista: Vista | None = None) -> QueryProfile:
    """The query read once per camera height (each of ``heights`` m, the tilt ``camera``'s), for a
    camera whose height is not known: distances read from its rows scale with it.

    The result's ``q`` is the mean of the heights' profiles, whose score at a position is the
    mean of theirs (the score is linear in ``q``). Its ``variants`` are the heights' own
    profiles, of which the search keeps the best at each position
    (:func:`localization.profile.locate.localize_profile`).
    """
    variants = tuple(query_from_mask(sem, dataclasses.replace(camera, camera_height_m=h), bins=bins, radii=radii,
                                     heading_deg=heading_deg, vista=vista) for h in heights)
    first = variants[0]
    return QueryProfile(q=np.mean([v.q for v in variants], axis=0), radii_m=first.radii_m, classes=first.classes,
                        heading_deg=heading_deg, hfov_deg=first.hfov_deg, variants=variants, vista=first.vista)


def query_from_landmarks(lm: Landmarks, camera: Camera, *, bins: int, radii: tuple[np.ndarray, np.ndarray],
                         heading_deg: float | None = 0.0,
                         standing: Sequence[str] = STANDING_LANDMARKS) -> QueryProfile:
    """The profile of a query landmark list: one unit of mass per landmark, at its azimuth bin.

    A landmark of a ground class below the horizon lands in the radius bin nearest (in log
    distance) to the distance its row shows; every other one in slot ``R`` (seen, distance unknown).
    """
    radii_m, _ = radii
    n_r = len(radii_m)
    q = np.zeros((len(lm.classes) + 1, n_r + 1, bins))  # + OTHER, which landmark points never are
    if len(lm):
        b = _bins_of(camera.azimuths(lm.xy[:, 0], heading_deg or 0.0), bins)
        dist = camera.distance_m(lm.xy[:, 1])
        ground = ~np.isin(np.array(lm.classes)[lm.cls], list(standing))
        near = ground & (dist >= radii_m.min() / 1.5) & (dist <= radii_m.max() * 1.5)
        k = np.where(near, np.abs(np.log(np.maximum(dist, 1e-9))[:, None] - np.log(radii_m)[None, :]).argmin(1), n_r)
        np.add.at(q, (lm.cls, k, b), 1.0)
    return QueryProfile(q=q, radii_m=radii_m, classes=(*lm.classes, OTHER), heading_deg=heading_deg,
                        hfov_deg=camera.hfov_deg)


# --------------------------------------------------------------------------- the aerial prediction


#: Class index of a byte of the map (its low 6 bits - 1); -1 for "outside" (128).
_LABEL_OF_BYTE = np.where(np.arange(256) < 128, (np.arange(256) & 63) - 1, -1).astype(np.int8)


def _directions(bins: int) -> tuple[np.ndarray, np.ndarray]:
    az = np.radians(np.arange(bins) * 360.0 / bins)
    return np.sin(az), -np.cos(az)  # image x grows east, y grows south


class AerialMaskIndex:
    """Predicted profiles from an aerial :class:`SemanticMap` at ``resolution_m`` metres per pixel.

    The map is kept as one byte per pixel (class index + 1, plus 64 where it stands) inside a
    border of "outside" bytes (128) as wide as the longest ray, so every ray sample is one
    flat gather with no bounds test.
    """

    def __init__(self, sem: SemanticMap, resolution_m: float, samples: int = 24) -> None:
        if not (resolution_m > 0 and math.isfinite(resolution_m)):
            raise ConfigError(f"the profile method needs the aerial ground resolution in m/px, got {resolution_m}")
        self.sem, self.resolution_m, self.samples = sem, float(resolution_m), samples
        code = sem.labels.astype(np.uint8)  # class index + 1 (none: -1 wraps to 255, then 0), in place: one byte a pixel
        code += 1
        np.add(code, 64, out=code, where=sem.standing)
        self._code = code
        self._padded: tuple[int, np.ndarray] | None = None
        self.classes = sem.classes
        self.grid_m, self.levels, self.weighted = 4.0, 2, True
        self.min_kappa = 0.6         # kappa of rendered views in another scene: docs/localization.md
        self.min_confidence = MASK_MIN_CONFIDENCE

    @property
    def shape(self) -> tuple[int, int]:
        return self.sem.shape

    def _codes(self, pad: int) -> tuple[int, np.ndarray]:
        """``(its pad, the padded byte map)`` at least ``pad`` wide (one tuple: safe to share between threads)."""
        padded = self._padded
        if padded is None or padded[0] < pad:
            padded = self._padded = (pad, np.pad(self._code, pad, constant_values=128))
        return padded

    def labels(self, xy: np.ndarray, radii_m: np.ndarray, bins: int, *,
               vista: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """``(lab, valid)``: the class seen first at each radius and azimuth ``(N, R, A)`` int8 (-1 none), and
        whether the image predicts it (False where the ray left the image before anything stood up).

        ``vista``: the last radius is the vista cell (the module docstring): the class that stands
        first within it, else ``other`` (every ground class merged). Positions are taken at their
        nearest pixel, so every ray is the same flat offsets from it.
        """
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        near = radii_m[:-1] if vista and len(radii_m) > 1 else radii_m
        fine = np.geomspace(0.6, float(near.max()), self.samples)
        if vista:  # on to the vista every 2 m: a wall seen end-on is a few metres wide
            fine = np.concatenate([fine, np.arange(float(near.max()) + 2.0, float(radii_m[-1]), 2.0)])
        s = np.unique(np.concatenate([fine, radii_m]))
        at = np.searchsorted(s, radii_m)                               # radius k is sample at[k]
        dx, dy = _directions(bins)
        steps = s / self.resolution_m
        pad, codes = self._codes(int(math.ceil(steps.max())) + 2)
        pw = codes.shape[1]
        off = (np.rint(dy[:, None] * steps[None, :]).astype(np.int64) * pw
               + np.rint(dx[:, None] * steps[None, :]).astype(np.int64))                     # (A, S)
        base = (np.rint(xy[:, 1]).astype(np.int64) + pad) * pw + np.rint(xy[:, 0]).astype(np.int64) + pad
        code = codes.ravel()[base[:, None, None] + off[None]]                                # (N, A, S)
        stands = (code & 64) > 0
        first = stands.argmax(axis=2)                                                        # (N, A)
        hit = np.take_along_axis(code, first[..., None], axis=2)[..., 0] & 63
        first[~np.take_along_axis(stands, first[..., None], axis=2)[..., 0]] = len(s)      # nothing stands
        # the byte seen at each radius: the first standing thing's before it, else the ground's there
        seen = np.where(first[:, :, None] <= at[None, None, :], hit[:, :, None], code[:, :, at])
        if vista:  # nothing stood up before it: "other", if the ray is still inside the image there
            seen[:, :, -1] = np.where(first <= at[-1], hit,
                                      np.where(code[:, :, at[-1]] < 128, self.classes.index(OTHER) + 1, 128))
        seen = np.ascontiguousarray(np.transpose(seen, (0, 2, 1)))                          # (N, R, A)
        return _LABEL_OF_BYTE[seen], seen < 128

    def profiles(self, xy: np.ndarray, radii_m: np.ndarray, bins: int,
                 need: np.ndarray | None = None, *, vista: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """``(P, V)``: one-hot profiles ``(N, C, R + 1, A)`` float32 and valid cells ``(N, R + 1, A)``.

        ``need`` is accepted for the interface's sake: one-hot profiles cost the same for all cells.
        """
        lab, valid = self.labels(xy, radii_m, bins, vista=vista)
        n, n_r = lab.shape[0], len(radii_m)
        P = np.zeros((n, len(self.classes), n_r + 1, bins), dtype=np.float32)
        for c in range(len(self.classes)):
            P[:, c, :n_r, :] = lab == c
        P[:, :, n_r, :] = P[:, :, :n_r, :].max(axis=2)
        V = np.ones((n, n_r + 1, bins), dtype=np.float32)
        V[:, :n_r, :] = valid
        return P, V


def first_hits(bearing: np.ndarray, dist_m: np.ndarray, cls: np.ndarray, n_classes: int, bins: int,
               half_widths_m: Sequence[float] = HALF_WIDTHS_M,
               depths: list[np.ndarray] | None = None) -> np.ndarray:
    """What a camera sees first in each azimuth bin among opaque landmark points: ``(N, K, A)``.

    Each point ``j`` (bearing ``bearing[n, j]`` radians from position ``n``, ``dist_m[n, j]``
    metres away, class ``cls[j]`` in ``0..K-1``) is an object ``w`` metres wide on either side,
    covering the bins within ``atan(w / d)`` of its bearing (at least its nearest bin). In each
    bin the nearest covering point wins; its class gets ``exp(-delta^2 / 2)`` with ``delta`` the
    bin's offset from the point's bearing in half-widths. The result is the mean over
    ``half_widths_m`` (a point does not say how wide its building is). Work is one entry per
    covered (position, point, bin), so far points cost one or two bins each. ``depths``, when
    given, receives for each half-width the distance of the nearest covering point per bin
    ``(N, A)`` (inf where none): what hides the points behind it (:func:`seen_fraction`).

    >>> v = first_hits(np.array([[0.0, 0.0]]), np.array([[10.0, 20.0]]), np.array([0, 1]), 2, 8, (4.0,))
    >>> v[0, :, 0].round(2).tolist()  # the nearer point hides the farther one in bin 0
    [1.0, 0.0]
    """
    n, m = bearing.shape
    out = np.zeros((n, n_classes, bins), dtype=np.float32)
    if not (n and m):
        if depths is not None:
            depths.extend(np.full((n, bins), np.inf) for _ in half_widths_m)
        return out
    step = 2 * np.pi / bins
    centre = (np.mod(bearing, 2 * np.pi) / step).ravel()
    dist = np.asarray(dist_m, dtype=np.float64).ravel()
    point_cls = np.tile(np.asarray(cls, dtype=np.int64), n)
    for w in half_widths_m:
        half = np.arctan2(w, dist) / step                           # half-width in bins
        near = np.rint(centre)
        lo = np.minimum(np.ceil(centre - half), near).astype(np.int64)
        count = np.minimum(np.maximum(np.floor(centre + half), near).astype(np.int64) - lo + 1, bins)
        pair = np.repeat(np.arange(n * m), count)
        a = lo[pair] + (np.arange(len(pair)) - np.repeat(np.cumsum(count) - count, count))
        delta = (a - centre[pair]) / np.maximum(half[pair], 1e-9)
        row = pair // m
        key = row * bins + np.mod(a, bins)
        depth = np.full(n * bins, np.inf)
        np.minimum.at(depth, key, dist[pair])
        if depths is not None:
            depths.append(depth.reshape(n, bins))
        win = dist[pair] <= depth[key]
        value = np.zeros(n * n_classes * bins, dtype=np.float32)
        np.maximum.at(value, (row[win] * n_classes + point_cls[pair[win]]) * bins + np.mod(a[win], bins),
                      np.exp(-0.5 * delta[win] ** 2).astype(np.float32))
        out += value.reshape(n, n_classes, bins) / np.float32(len(half_widths_m))
    return out


def seen_fraction(bearing: np.ndarray, dist_m: np.ndarray, depths: Sequence[np.ndarray]) -> np.ndarray:
    """For points at ``bearing`` (N, M) and ``dist_m`` from each position, the share of the
    ``depths`` maps (:func:`first_hits`) in which nothing nearer covers their azimuth bin:
    1 in the open, 0 behind a building whatever its width.

    >>> depth = np.full((1, 4), np.inf); depth[0, 0] = 10.0          # a building 10 m to the north
    >>> seen_fraction(np.array([[0.0, 0.0, np.pi]]), np.array([[5.0, 30.0, 30.0]]), [depth]).tolist()
    [[1.0, 0.0, 1.0]]
    """
    if not depths:
        return np.ones(np.shape(bearing))
    bins = depths[0].shape[1]
    b = np.rint(np.mod(bearing, 2 * np.pi) / (2 * np.pi / bins)).astype(np.int64) % bins  # as first_hits rounds
    return cast("np.ndarray", np.mean([dist_m <= np.take_along_axis(d, b, axis=1) for d in depths], axis=0))


class AerialLandmarkIndex:
    """Predicted profiles from aerial landmark points.

    Opaque classes (:data:`OPAQUE_LANDMARKS`, buildings) in slot ``R`` by the first-hit rule of
    :func:`first_hits`, as a mask's rays; every other cell by kernels in bearing and log distance.
    """

    def __init__(self, lm: Landmarks, resolution_m: float, *, sigma_deg: float = 8.0, distance_sd: float = 1.0,
                 d0_m: float = 200.0, opaque: Sequence[str] = OPAQUE_LANDMARKS,
                 half_widths_m: Sequence[float] = HALF_WIDTHS_M) -> None:
        if not (resolution_m > 0 and math.isfinite(resolution_m)):
            raise ConfigError("the profile method needs the aerial ground resolution in m/px (--aerial-resolution); "
                              f"got {resolution_m}")
        self.lm, self.resolution_m = lm, float(resolution_m)
        self.sigma, self.distance_sd, self.d0_m = math.radians(sigma_deg), distance_sd, d0_m
        self.classes = (*lm.classes, OTHER)
        self.opaque = np.array([c in opaque for c in lm.classes], dtype=bool)
        self.half_widths_m = tuple(half_widths_m)
        # point scores are peaked (a kernel a few degrees wide): a fine grid, one refinement
        self.grid_m, self.levels, self.weighted = 1.25, 1, False
        self.min_kappa = 0.3         # a few points give a lower kappa: docs/localization.md
        self.min_confidence = 0.0    # not calibrated for points: no "not sure" gate

    @property
    def shape(self) -> tuple[int, int]:
        return (self.lm.height, self.lm.width)

    def profiles(self, xy: np.ndarray, radii_m: np.ndarray, bins: int,
                 need: np.ndarray | None = None, *, vista: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """``(P, V)`` as :meth:`AerialMaskIndex.profiles`; only the ``need`` (C, R + 1) cells are computed.
        Points cannot say that nothing stands in a direction: a ``vista`` query is refused (the search
        drops its vista cell first, :class:`~localization.profile.locate.Scoring`)."""
        if vista:
            raise ConfigError("aerial landmark points cannot predict a vista cell: build the query without it")
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        n_r, n_c = len(radii_m), len(self.lm.classes)
        P = np.zeros((len(xy), n_c + 1, n_r + 1, bins), dtype=np.float32)
        az = np.radians(np.arange(bins) * 360.0 / bins).astype(np.float32)
        log_r = np.log(radii_m)
        wanted = np.ones((n_c + 1, n_r + 1), dtype=bool) if need is None else np.asarray(need, dtype=bool)
        opaque = np.flatnonzero(self.opaque)
        depths: list[np.ndarray] = []   # per half-width: how far each azimuth bin is open
        if len(opaque):
            on = np.isin(self.lm.cls, opaque)
            d = self.lm.xy[on][None, :, :] - xy[:, None, :]
            hits = first_hits(np.arctan2(d[..., 0], -d[..., 1]), np.hypot(d[..., 0], d[..., 1]) * self.resolution_m,
                              np.searchsorted(opaque, self.lm.cls[on]), len(opaque), bins, self.half_widths_m,
                              depths=depths)
            P[:, opaque, n_r, :] = hits
        for c in range(n_c):
            pts = self.lm.xy[self.lm.cls == c]
            slots = wanted[c].copy()
            slots[n_r] &= not self.opaque[c]
            if not len(pts) or not slots.any():
                continue
            d = pts[None, :, :] - xy[:, None, :]                                   # (N, M, 2)
            bearing = np.arctan2(d[..., 0], -d[..., 1])
            dist_m = np.hypot(d[..., 0], d[..., 1]) * self.resolution_m
            g = seen_fraction(bearing, dist_m, depths) / (1.0 + dist_m / self.d0_m)  # hidden behind buildings: 0
            delta = ((az[None, None, :] - bearing[..., None].astype(np.float32) + np.pi) % (2 * np.pi)
                     - np.pi).astype(np.float32)                                  # (N, M, A), wrapped
            k_az = np.exp(np.float32(-0.5 / self.sigma ** 2) * delta * delta) * g[..., None].astype(np.float32)
            if slots[n_r]:
                P[:, c, n_r, :] = k_az.max(axis=1)
            log_d = np.log(np.maximum(dist_m, 0.5))
            for k in np.flatnonzero(slots[:n_r]):  # (N, M, A) at a time: memory stays that of one radius
                k_d = np.exp(-0.5 * ((log_d - log_r[k]) / self.distance_sd) ** 2).astype(np.float32)
                P[:, c, k, :] = (k_az * k_d[..., None]).max(axis=1)
        return P, np.ones((len(xy), n_r + 1, bins), dtype=np.float32)
