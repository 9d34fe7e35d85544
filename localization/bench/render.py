"""Render the semantic 360° panorama a camera ~2 m above the ground would see, from an aerial mask.

Real ground panoramas paired with aerial images are not available offline, so the localization
benchmark (:mod:`localization.bench.rendered`) renders them. The model is a "voxel space" ray caster,
as in old terrain engines: the aerial label mask is a height field, one height per class.

Camera and panorama
    The camera stands at ``viewpoint`` (aerial pixel coordinates, x = column, y = row, pixel
    centres at integers as landmark centroids are) ``camera_height_m`` above the ground. Column
    ``c`` of a ``width``-column panorama looks along the compass azimuth
    ``heading + 360 * ((c + 0.5) / width - 0.5)`` degrees (clockwise from north = up in the
    mask): the centre column looks along ``heading_deg`` (default 0, north), columns grow
    clockwise (east is right of north), and azimuth 0/360 wraps around the left/right edge.
    Rows are equiangular: row ``r`` looks at elevation ``(height / 2 - r - 0.5) * dθ`` with
    ``dθ = vfov / height``; by default pixels are square in angle (``dθ = 360° / width``; the
    paper's 1232 x 224 panoramas then span ±32.7° around the horizon, which is between rows
    111 and 112).

Scene
    Every class has a height in metres (:data:`DEFAULT_HEIGHTS`: building 10 m, tree 6 m; any
    other class, road, footway, grass, water, unlabeled..., is flat ground, 0 m). One ray per
    column marches outward in steps of ``step_px`` mask pixels up to ``max_range_m``. A sample
    at distance ``d`` of a class of height ``h`` reaches up to elevation
    ``atan2(h - camera_h, d)`` (ground: the depression angle ``-atan(camera_h / d)``). Marching
    front to back, a sample is visible in the rows between the highest elevation drawn so far
    in its column (a z-buffer of one number per column) and its own top: so a building fills
    its rows from its base up to ``atan((h - camera_h) / d)`` and hides everything behind it
    that does not rise above that angle; ground classes are seen from below the camera out to
    the first occluder. Rows that no sample reaches are sky (:data:`SKY_NAME`) above the horizon
    and ``far`` (default the table's unlabeled class 0: ground beyond ``max_range_m`` or off the
    mask, too far to name) below it.

Class table of the panorama
    The aerial table's ids are kept and one class is added: ``sky`` with the next free id
    (``max id + 1``: 14 for classes13.toml, 7 for classes6.toml) and colour :data:`SKY_COLOR`
    (:func:`panorama_table`). So one landmark dictionary serves both images; ``sky`` is never
    a landmark.

Noise (:class:`NoiseConfig`, seeded): a viewpoint offset (the camera stands ``offset_m`` metres
away from the true viewpoint in a random direction; the truth stays put), missed landmarks
(components under ``miss_small_px`` pixels, and any other with probability ``miss_prob``, become
unlabeled) and class confusion (a fraction of the remaining landmark components is relabelled
as another landmark class).

>>> t = load_class_table("classes13.toml")
>>> mask = np.full((201, 201), t.by_name["highway"].id, np.uint8)
>>> mask[40:60, 90:111] = t.by_name["building"].id        # 20 m wide, 41-60 m north at 1 m/px
>>> pano = render_panorama(mask, t, 1.0, (100, 100), RenderConfig(width=360, height=90))
>>> names = pano.table.by_id
>>> [names[int(i)].name for i in pano.labels[[0, 40, 60, 89], 180]]
['sky', 'building', 'highway', 'highway']
>>> names[int(pano.labels[40, 0])].name                     # looking south: no building
'sky'
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from localization.common.landmarks import (
    SKY_COLOR,
    SKY_NAME,
    LandmarkClasses,
    Landmarks,
    landmarks_from_mask,
    panorama_table,
)
from localization.common.views import check_view_shape
from osmseg.classes import ClassTable, load_class_table
from osmseg.errors import ConfigError

__all__ = [
    "DEFAULT_HEIGHTS", "SKY_NAME", "SKY_COLOR", "RenderConfig", "NoiseConfig", "Panorama", "RenderedView",
    "panorama_table", "object_heights", "column_azimuths", "azimuth_to_column", "row_elevations",
    "elevation_to_row", "render_panorama", "offset_viewpoint", "apply_noise", "render_view", "save_panorama_png",
]

#: Heights in metres of the classes that stand up from the ground (by class name); others are 0.
DEFAULT_HEIGHTS: Mapping[str, float] = {"building": 10.0, "tree": 6.0}


@dataclass(frozen=True)
class RenderConfig:
    """Camera, panorama size and scene heights (see the module docstring for the model)."""

    width: int = 1232
    height: int = 224
    camera_height_m: float = 2.0
    max_range_m: float = 100.0
    step_px: float = 1.0
    heights: Mapping[str, float] = field(default_factory=lambda: dict(DEFAULT_HEIGHTS))
    vfov_deg: float | None = None  # None: square pixels in angle, 360 * height / width degrees
    heading_deg: float = 0.0
    far: str = "unlabeled"  # class of unseen ground rows (beyond range/off the mask): a class name or "sky"
    height_spread: float = 0.0  # each building/tree gets its class height times U(1 - s, 1 + s) (seeded per object)
    height_seed: int = 0

    def __post_init__(self) -> None:
        if self.width < 8 or self.height < 2:
            raise ConfigError(f"panorama size must be at least 8 x 2 pixels, got {self.width} x {self.height}")
        if not (self.camera_height_m > 0 and self.max_range_m > 0 and self.step_px > 0):
            raise ConfigError("camera height, max range and step must be positive numbers")
        if self.vfov_deg is not None and not 0 < self.vfov_deg <= 180:
            raise ConfigError(f"vfov_deg must be in (0, 180], got {self.vfov_deg}")
        if self.vfov_deg is None:  # square pixels in angle: a 360° panorama is at least twice as wide as high
            check_view_shape(self.width, self.height, 360.0, "the rendered panorama (--pano-width, --pano-height)",
                             "give a --pano-width at least twice the --pano-height")
        if any(not math.isfinite(h) or h < 0 for h in self.heights.values()):
            raise ConfigError("class heights must be finite and >= 0 metres")
        if not 0 <= self.height_spread < 1:
            raise ConfigError(f"height spread must be in [0, 1) (a fraction of each class height), "
                              f"got {self.height_spread}")

    @property
    def row_step_deg(self) -> float:
        """Degrees of elevation per panorama row."""
        return (self.vfov_deg if self.vfov_deg is not None else 360.0 * self.height / self.width) / self.height


@dataclass(frozen=True)
class NoiseConfig:
    """Seeded perturbations of a rendered view; all off by default."""

    confusion: float = 0.0     # fraction of landmark components relabelled as another landmark class
    miss_small_px: int = 0     # components with fewer pixels are missed (become unlabeled)
    miss_prob: float = 0.0     # every other landmark component is missed with this probability
    offset_m: float = 0.0      # camera displaced this far from the true viewpoint (random direction)
    seed: int = 0

    def __post_init__(self) -> None:
        if not (0 <= self.confusion <= 1 and 0 <= self.miss_prob <= 1):
            raise ConfigError("confusion and miss_prob are fractions in [0, 1]")
        if self.miss_small_px < 0 or self.offset_m < 0:
            raise ConfigError("miss_small_px and offset_m must be >= 0")

    @property
    def active(self) -> bool:
        return bool(self.confusion or self.miss_small_px or self.miss_prob)


@dataclass(frozen=True)
class Panorama:
    """A rendered semantic panorama: class ids in ``table`` (the aerial table plus sky)."""

    labels: np.ndarray               # (height, width) uint8
    table: ClassTable
    camera: tuple[float, float]      # where it was rendered from, aerial pixels (x, y)
    heading_deg: float
    resolution_m: float              # of the aerial mask, m/px
    sources: np.ndarray | None = None  # (height, width) int64: flat aerial index (y * W + x) seen, -1 none

    def rgb(self) -> np.ndarray:
        """``(height, width, 3)`` uint8 picture in the class colours."""
        return self.table.colorize(self.labels)


@dataclass(frozen=True)
class RenderedView:
    """A (possibly noisy) panorama, its landmarks, and the true viewpoint to score against."""

    panorama: Panorama
    landmarks: Landmarks
    truth: tuple[float, float]       # true viewpoint, aerial pixels (x, y)


# --------------------------------------------------------------------------- class tables


def _as_table(table: ClassTable | Mapping[str, Any] | str) -> ClassTable:
    if isinstance(table, ClassTable):
        return table
    if isinstance(table, str):
        return load_class_table(table)
    return ClassTable.from_dict(table)


# --------------------------------------------------------------------------- panorama geometry


def column_azimuths(width: int, heading_deg: float = 0.0) -> np.ndarray:
    """Compass azimuth in degrees [0, 360) of each column's centre.

    >>> column_azimuths(4).tolist()
    [225.0, 315.0, 45.0, 135.0]
    """
    return (heading_deg + 360.0 * ((np.arange(width) + 0.5) / width - 0.5)) % 360.0


def azimuth_to_column(azimuth_deg: float, width: int, heading_deg: float = 0.0) -> float:
    """Column coordinate (pixel centres at integers, in [-0.5, width - 0.5)) looking along ``azimuth_deg``.

    The inverse of :func:`column_azimuths`, in the landmark convention (a centroid's x).

    >>> azimuth_to_column(0.0, 1232), azimuth_to_column(90.0, 1232), azimuth_to_column(180.0, 1232)
    (615.5, 923.5, -0.5)
    """
    return float(((azimuth_deg - heading_deg) / 360.0 + 0.5) * width % width) - 0.5


def row_elevations(config: RenderConfig) -> np.ndarray:
    """Elevation in degrees of each row's centre, top row first (positive: above the horizon).

    >>> row_elevations(RenderConfig(width=360, height=4)).tolist()
    [1.5, 0.5, -0.5, -1.5]
    """
    return (config.height / 2 - np.arange(config.height) - 0.5) * config.row_step_deg


def elevation_to_row(elevation_deg: float, config: RenderConfig) -> float:
    """Row coordinate (centres at integers) looking at ``elevation_deg`` (the horizon: ``height / 2 - 0.5``).

    >>> elevation_to_row(0.0, RenderConfig(width=1232, height=224))
    111.5
    """
    return config.height / 2 - 0.5 - float(elevation_deg) / config.row_step_deg


def _rows_reached(top_deg: np.ndarray, config: RenderConfig) -> np.ndarray:
    """How many rows, counted from the bottom, have their centre at or below ``top_deg``."""
    k = np.floor(top_deg / config.row_step_deg + config.height / 2 + 0.5)
    rows = np.clip(np.nan_to_num(k, neginf=0.0, posinf=config.height), 0, config.height)
    return cast("np.ndarray", rows.astype(np.int64))


def _class_id(table: ClassTable, name: str) -> int:
    try:
        return table.by_name[name].id
    except KeyError:
        raise ConfigError(f"class {name!r} is not in the class table {table.name!r}: "
                          f"use one of {sorted(table.by_name)}") from None


def _height_lut(table: ClassTable, config: RenderConfig) -> np.ndarray:
    lut = np.zeros(256, dtype=np.float64)
    for name, h in config.heights.items():
        if name in table.by_name:  # heights of classes this table lacks are unused: one dict serves all tables
            lut[table.by_name[name].id] = h
    return lut


def object_heights(mask: np.ndarray, table: ClassTable | Mapping[str, Any] | str,
                   config: RenderConfig = RenderConfig()) -> np.ndarray:
    """Per-pixel heights (H, W) in metres: each object's class height times its own random factor.

    An object is an 8-connected component of one class with a height; its factor is drawn
    uniformly from ``[1 - height_spread, 1 + height_spread]`` with ``height_seed`` (in
    component order, so the same mask and seed give the same scene). The localization methods
    never read these heights: the benchmark varies them so that a method tuned to the
    renderer's class heights would fail.

    >>> t = load_class_table("classes13.toml")
    >>> m = np.zeros((5, 9), np.uint8); m[1:3, 1:3] = m[1:3, 5:8] = t.by_name["building"].id
    >>> h = object_heights(m, t, RenderConfig(height_spread=0.5, height_seed=1))
    >>> bool(h[1, 1] != h[1, 5]), bool(5.0 <= h[1, 1] <= 15.0), float(h[0, 0])
    (True, True, 0.0)
    """
    from scipy import ndimage

    mask = np.asarray(mask)
    lut = _height_lut(panorama_table(table), config)
    out = lut[mask].astype(np.float32)
    if config.height_spread <= 0:
        return cast("np.ndarray", out)
    rng = np.random.default_rng([config.height_seed, 7])
    for cid in np.flatnonzero(lut > 0):
        labels, n = ndimage.label(mask == cid, structure=np.ones((3, 3), dtype=bool))
        if n:
            factor = rng.uniform(1 - config.height_spread, 1 + config.height_spread, n + 1).astype(np.float32)
            factor[0] = 1.0
            out = np.where(labels > 0, out * factor[labels], out)
    return cast("np.ndarray", out)


def render_panorama(mask: np.ndarray, table: ClassTable | Mapping[str, Any] | str, resolution_m: float,
                    viewpoint: tuple[float, float], config: RenderConfig = RenderConfig(), *,
                    sources: bool = False, heights: np.ndarray | None = None) -> Panorama:
    """Ray-cast the panorama seen from ``viewpoint`` (aerial pixels x, y) over the label ``mask``.

    One ray per column, all columns and steps at once (numpy, no Python loop over pixels).
    ``sources=True`` also records, per panorama pixel, the aerial pixel it shows
    (:attr:`Panorama.sources`; sky and far ground: -1). ``heights`` (H, W) metres per pixel
    (:func:`object_heights`, computed once per mask) replaces the class heights; without it, a
    ``height_spread`` in ``config`` computes them here.
    """
    mask = np.asarray(mask)
    if mask.ndim != 2 or mask.size == 0 or not np.issubdtype(mask.dtype, np.integer):
        raise ConfigError(f"aerial mask must be a non-empty 2-D array of class ids, got {mask.dtype} {mask.shape}")
    if not (resolution_m > 0 and math.isfinite(resolution_m)):
        raise ConfigError(f"ground resolution must be a positive number of metres per pixel, got {resolution_m}")
    pano_table = panorama_table(table)
    mh, mw = mask.shape
    x0, y0 = float(viewpoint[0]), float(viewpoint[1])
    if not (-0.5 <= x0 < mw - 0.5 and -0.5 <= y0 < mh - 0.5):
        raise ConfigError(f"viewpoint ({x0:g}, {y0:g}) is outside the {mw} x {mh} mask")
    if heights is None and config.height_spread > 0:
        heights = object_heights(mask, pano_table, config)
    if heights is not None and np.shape(heights) != mask.shape:
        raise ConfigError(f"heights must have the mask's shape {mask.shape}, got {np.shape(heights)}")
    height_lut = _height_lut(pano_table, config)
    sky_id, far_id = _class_id(pano_table, SKY_NAME), _class_id(pano_table, config.far)

    w, h = config.width, config.height
    az = np.deg2rad(column_azimuths(w, config.heading_deg))
    steps = max(1, int(config.max_range_m / (config.step_px * resolution_m)))
    dist_px = (np.arange(steps) + 1.0) * config.step_px                      # (S,)
    xs = np.rint(x0 + np.sin(az)[:, None] * dist_px[None, :]).astype(np.int64)  # (W, S)
    ys = np.rint(y0 - np.cos(az)[:, None] * dist_px[None, :]).astype(np.int64)
    inside = (xs >= 0) & (xs < mw) & (ys >= 0) & (ys < mh)
    cls = np.where(inside, mask[np.clip(ys, 0, mh - 1), np.clip(xs, 0, mw - 1)], 0).astype(np.int64)
    stand = (height_lut[cls] if heights is None else
             np.where(inside, np.asarray(heights)[np.clip(ys, 0, mh - 1), np.clip(xs, 0, mw - 1)], 0.0))
    top = np.degrees(np.arctan2(stand - config.camera_height_m, dist_px[None, :] * resolution_m))
    reached = np.where(inside, _rows_reached(top, config), 0)
    reached = np.maximum.accumulate(reached, axis=1)                          # the per-column z-buffer

    # Pixel j rows up from the bottom of column c shows the first sample whose reach exceeds j:
    # offset each column's non-decreasing reach so one flat searchsorted answers every pixel.
    offsets = np.arange(w, dtype=np.int64)[:, None] * (h + 1)
    flat = (reached + offsets).ravel()
    queries = (offsets + np.arange(h, dtype=np.int64)[None, :]).ravel()      # (W*H,) column-major by bottom row
    first = np.searchsorted(flat, queries, side="right")
    seen = first < (np.repeat(np.arange(w), h) + 1) * steps
    sample = np.minimum(first, cls.size - 1)
    ids = np.where(seen, cls.ravel()[sample], -1).reshape(w, h)

    above = (row_elevations(config) > 0)[::-1]                                # per bottom-up row
    ids = np.where(ids >= 0, ids, np.where(above[None, :], sky_id, far_id))
    labels = np.ascontiguousarray(ids[:, ::-1].T).astype(np.uint8)             # rows top-down
    seen_from = None
    if sources:  # which aerial pixel each panorama pixel shows (the visible-landmark oracle needs it)
        flat_xy = np.where(inside, ys * mw + xs, -1).ravel()
        seen_from = np.ascontiguousarray(np.where(seen, flat_xy[sample], -1).reshape(w, h)[:, ::-1].T)
    return Panorama(labels=labels, table=pano_table, camera=(x0, y0), heading_deg=config.heading_deg,
                    resolution_m=float(resolution_m), sources=seen_from)


# --------------------------------------------------------------------------- noise and views


def offset_viewpoint(viewpoint: tuple[float, float], offset_m: float, resolution_m: float,
                     rng: np.random.Generator, shape: tuple[int, int] | None = None) -> tuple[float, float]:
    """``viewpoint`` moved ``offset_m`` metres in a random direction (clamped into a mask of ``shape``).

    >>> x, y = offset_viewpoint((50.0, 50.0), 10.0, 0.5, np.random.default_rng(0))
    >>> round(math.hypot(x - 50, y - 50), 6)
    20.0
    """
    angle = rng.uniform(0.0, 2.0 * math.pi)
    x = viewpoint[0] + math.cos(angle) * offset_m / resolution_m
    y = viewpoint[1] + math.sin(angle) * offset_m / resolution_m
    if shape is not None:
        x, y = min(max(x, 0.0), shape[1] - 1.0), min(max(y, 0.0), shape[0] - 1.0)
    return (x, y)


def _representatives(table: ClassTable, classes: LandmarkClasses) -> dict[int, int]:
    """Landmark class index -> a mask class id that maps to it (the lowest id), for relabelling."""
    reps: dict[int, int] = {}
    for c in sorted((table.unlabeled, *table.classes), key=lambda c: c.id):
        target = classes.mapping.get(c.name)
        if target in classes.names:
            reps.setdefault(classes.names.index(target), c.id)
    return reps


def apply_noise(labels: np.ndarray, table: ClassTable, classes: LandmarkClasses, noise: NoiseConfig) -> np.ndarray:
    """Missed landmarks and class confusion on a panorama's landmark components (a new array).

    Components are connected regions of one landmark class, wrapping around azimuth 0/360.
    Missed ones become unlabeled (0). Then ``round(confusion * K)`` of the K remaining are
    chosen and repainted with a mask class of another landmark class (uniformly among those the
    table can paint). Each kind of noise has its own random stream, derived from ``seed``.
    """
    out = np.array(labels, dtype=np.uint8, copy=True)
    if not noise.active:
        return out
    comps = landmarks_from_mask(out, table, classes, mode="component", min_size=1, panorama=True)
    pixels = comps.pixels or ()
    sizes = np.array([len(p) for p in pixels], dtype=np.int64)
    miss_rng = np.random.default_rng([noise.seed, 1])
    missed = (sizes < noise.miss_small_px) | (miss_rng.random(len(sizes)) < noise.miss_prob)
    for k in np.flatnonzero(missed):
        out[pixels[k][:, 1], pixels[k][:, 0]] = table.unlabeled.id
    kept = np.flatnonzero(~missed)
    reps = _representatives(table, classes)
    conf_rng = np.random.default_rng([noise.seed, 2])
    n_flip = int(round(noise.confusion * len(kept)))
    for k in conf_rng.permutation(kept)[:n_flip] if n_flip else ():
        others = [i for i in sorted(reps) if i != int(comps.cls[k])]
        if others:
            target = others[int(conf_rng.integers(len(others)))]
            out[pixels[k][:, 1], pixels[k][:, 0]] = reps[target]
    return out


def render_view(mask: np.ndarray, table: ClassTable | Mapping[str, Any] | str, resolution_m: float,
                viewpoint: tuple[float, float], classes: LandmarkClasses, *,
                config: RenderConfig = RenderConfig(), noise: NoiseConfig = NoiseConfig(),
                mode: str = "centroid", min_size: int = 50, stride: int = 50, sources: bool = False,
                heights: np.ndarray | None = None) -> RenderedView:
    """Render the panorama at ``viewpoint`` (with ``noise``) and extract its landmarks.

    The landmarks are those of the (noisy) panorama, as cylinders (``panorama=True``), with the
    same ``mode``/``min_size``/``stride`` as :func:`localization.common.landmarks.landmarks_from_mask`.
    ``truth`` is always the given ``viewpoint``, even when the camera was offset. ``sources``:
    keep which aerial pixel each panorama pixel shows (:func:`render_panorama`).
    """
    camera = (float(viewpoint[0]), float(viewpoint[1]))
    if noise.offset_m > 0:
        mask_shape = np.asarray(mask).shape
        camera = offset_viewpoint(camera, noise.offset_m, resolution_m, np.random.default_rng([noise.seed, 0]),
                                  (int(mask_shape[0]), int(mask_shape[1])))
    pano = render_panorama(mask, table, resolution_m, camera, config, sources=sources, heights=heights)
    if noise.active:
        pano = dataclasses.replace(pano, labels=apply_noise(pano.labels, pano.table, classes, noise))
    marks = landmarks_from_mask(pano.labels, pano.table, classes, mode=mode, min_size=min_size, stride=stride,
                                panorama=True)
    return RenderedView(panorama=pano, landmarks=marks, truth=(float(viewpoint[0]), float(viewpoint[1])))


def save_panorama_png(path: Path | str, panorama: Panorama) -> Path:
    """Write the panorama as a paletted PNG (atomic, no timestamp): its pixels are the class ids, its
    palette the class colours, so a viewer shows the colours and ``osmseg localize --ground`` takes
    the file as a query mask, as GDAL and PIL read it as one band of ids."""
    import io

    from PIL import Image

    from osmseg.output.atomic import atomic_write_bytes

    labels = np.ascontiguousarray(panorama.labels, dtype=np.uint8)  # class ids are 0-255 (ClassTable)
    image = Image.frombytes("P", (labels.shape[1], labels.shape[0]), labels.tobytes())
    image.putpalette(panorama.table.palette().tobytes())
    buf = io.BytesIO()
    image.save(buf, format="PNG")
    return atomic_write_bytes(Path(path), buf.getvalue())
