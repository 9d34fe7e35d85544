"""What a ground view is: its camera (:class:`Camera`) and its pixels in landmark classes (:class:`SemanticMap`).

Both methods' queries, both renderers and the benchmarks describe a view this way, so it lives
in the shared wing: a cylinder of ``hfov_deg`` around the horizon whose pixels are square in
angle (:func:`check_view_shape` refuses an image that cannot be one), and a mask turned into
the dictionary's landmark classes with the pixels that stand up from the ground and the sky.

Imports: numpy, osmseg core, localization.common.landmarks.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from localization.common.landmarks import SKY_NAME, LandmarkClasses, _landmark_lut, _mask_names
from osmseg.classes import ClassTable
from osmseg.errors import ConfigError

__all__ = ["OTHER", "STANDING_MASK_CLASSES", "VERTICAL_SPAN_TOLERANCE", "Camera", "SemanticMap", "check_view_shape",
           "semantic_map"]
#: Mask classes that stand up from the ground and hide what lies behind them (case-insensitive).
STANDING_MASK_CLASSES = ("building", "tree")
#: The profile class of known flat ground of no landmark class (a dictionary's ``other_ground``).
OTHER = "other"
#: room for a panorama padded by a few rows (an equirectangular 2:1 image spans exactly 180).
VERTICAL_SPAN_TOLERANCE = 0.05


def check_view_shape(width: int, height: int, hfov_deg: float, what: str, fix: str) -> None:
    """ConfigError when a ``width`` x ``height`` image cannot show ``hfov_deg`` degrees around the horizon.

    Every method takes a ground view's pixels as square in angle (:class:`Camera`, the renderer,
    CVUSA's 1232x224 panoramas), so the image spans ``height * hfov / width`` degrees from top to
    bottom, and no camera sees more than the 180 from nadir to zenith: a 360-degree panorama is
    at least twice as wide as high. ``what`` names the image, ``fix`` says what to give instead.

    >>> check_view_shape(1232, 224, 360, "pano.png", "give a panorama")
    >>> check_view_shape(224, 1232, 360, "--ground portrait.png", "give a panorama")
    Traceback (most recent call last):
    osmseg.errors.ConfigError: --ground portrait.png is 224x1232 pixels, which cannot be a 360° panorama: its square pixels would span 1980° from top to bottom, more than the 180° from nadir to zenith (a panorama is at least twice as wide as high, e.g. 1232x224); give a panorama
    """
    span = height * hfov_deg / width
    if span <= 180.0 * (1 + VERTICAL_SPAN_TOLERANCE):
        return
    view = "a 360° panorama" if hfov_deg >= 360 else f"a photo {hfov_deg:g}° wide"
    shape = " (a panorama is at least twice as wide as high, e.g. 1232x224)" if hfov_deg >= 360 else ""
    raise ConfigError(f"{what} is {width}x{height} pixels, which cannot be {view}: its square pixels would span "
                      f"{span:.0f}° from top to bottom, more than the 180° from nadir to zenith{shape}; {fix}")


@dataclass(frozen=True, eq=False)
class SemanticMap:
    """A mask in profile classes: ``labels`` (H, W) int8 index into ``classes`` or -1, ``standing`` (H, W) bool.

    ``classes`` are the dictionary's landmark classes and, last, :data:`OTHER` (its
    ``other_ground`` classes: known flat ground of no landmark class). ``sky`` (H, W) bool marks
    the pixels of a class named ``sky`` (a ground view's), None when the mask's table has none:
    where the sky ends tells a tilted camera's horizon (:mod:`localization.profile.horizon`).
    """

    labels: np.ndarray
    standing: np.ndarray
    classes: tuple[str, ...]
    sky: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.labels.shape[0]), int(self.labels.shape[1]))


def semantic_map(mask: np.ndarray, table: ClassTable | Mapping[int, str] | None, classes: LandmarkClasses,
                 standing: Sequence[str] = STANDING_MASK_CLASSES) -> SemanticMap:
    """``mask`` (class ids of ``table``) in ``classes``' landmark classes, with its standing pixels.

    >>> m = np.array([[1, 2], [0, 1]])
    >>> sm = semantic_map(m, {0: "grass", 1: "building", 2: "highway"},
    ...                   LandmarkClasses(("building", "road"), {"building": "building", "highway": "road"}))
    >>> sm.labels.tolist(), sm.standing.tolist(), sm.classes
    ([[0, 1], [-1, 0]], [[True, False], [False, True]], ('building', 'road', 'other'))
    """
    mask = np.asarray(mask)
    lut = _landmark_lut(mask, table, classes)
    names, _ = _mask_names(table, classes)
    up = {s.lower() for s in standing}
    stand_lut = np.zeros(len(lut), dtype=bool)
    for value, name in names.items():
        if value < len(lut) and name.lower() in up:
            stand_lut[value] = True
    other = {s.lower() for s in classes.other_ground}
    for value, name in names.items():
        if value < len(lut) and name.lower() in other:
            lut[value] = len(classes.names)
    if not np.issubdtype(mask.dtype, np.integer):
        mask = mask.astype(np.int64)
    sky_ids = [value for value, name in names.items() if value < len(lut) and name.lower() == SKY_NAME]
    sky = None
    if sky_ids:  # a ground view's table (an aerial one has no sky: no array for its many pixels)
        sky_lut = np.zeros(len(lut), dtype=bool)
        sky_lut[sky_ids] = True
        sky = sky_lut[mask]
    # the lookups at one byte a pixel: a 6400 px mask through int64 took a third of a GB more
    return SemanticMap(labels=lut.astype(np.int8)[mask], standing=stand_lut[mask], classes=(*classes.names, OTHER),
                       sky=sky)


@dataclass(frozen=True)
class Camera:
    """How a query image's pixels look out: a cylinder of ``hfov_deg`` around the horizon.

    Column ``c`` looks along ``heading + hfov * ((c + 0.5) / width - 0.5)`` degrees (the
    renderer's convention, :mod:`localization.bench.render`); row ``r`` at the elevation
    ``(horizon_row - r) * row_step_deg``. Defaults: square pixels in angle and the horizon
    between the two middle rows, as CVUSA panoramas and :func:`~localization.bench.render.render_panorama`.
    """

    width: int
    height: int
    hfov_deg: float = 360.0
    row_step_deg: float | None = None   # None: hfov / width
    horizon_row: float | None = None    # None: height / 2 - 0.5
    camera_height_m: float = 2.0
    pitch_deg: float = 0.0              # tilt: the horizon lies pitch degrees lower at the centre column...
    roll_deg: float = 0.0               # ...and roll degrees higher a quarter turn to its right (see tilt_rows)

    def __post_init__(self) -> None:
        if self.width < 2 or self.height < 2:
            raise ConfigError(f"query image must be at least 2 x 2 pixels, got {self.width} x {self.height}")
        if not 0 < self.hfov_deg <= 360:
            raise ConfigError(f"horizontal field of view must be in (0, 360] degrees, got {self.hfov_deg:g}")
        if not self.camera_height_m > 0:
            raise ConfigError(f"camera height must be a positive number of metres, got {self.camera_height_m:g}")
        span = self.step * self.height
        if span > 180.0 * (1 + VERTICAL_SPAN_TOLERANCE):
            raise ConfigError(f"a {self.width}x{self.height} query of {self.step:.3g}° rows spans {span:.0f}° from "
                              "top to bottom, more than the 180° from nadir to zenith: give a wider image or a "
                              "narrower field of view")

    @property
    def step(self) -> float:
        return self.row_step_deg if self.row_step_deg is not None else self.hfov_deg / self.width

    @property
    def horizon(self) -> float:
        return self.horizon_row if self.horizon_row is not None else self.height / 2 - 0.5

    @property
    def level(self) -> bool:
        return self.pitch_deg == 0 and self.roll_deg == 0

    def tilt_rows(self, x: np.ndarray) -> np.ndarray:
        """How many rows below :attr:`horizon` the horizon lies at columns ``x``: a tilted camera
        sees it as a sinusoid, ``(pitch cos t - roll sin t) / step`` at the column's azimuth ``t``
        from the centre column (pitched up, the horizon is lower ahead; rolled right side down,
        it is higher on the right).

        >>> Camera(360, 90, pitch_deg=2.0).tilt_rows(np.array([179.5, 359.5])).round(3).tolist()
        [2.0, -2.0]
        """
        t = np.radians(self.hfov_deg * ((np.asarray(x, dtype=np.float64) + 0.5) / self.width - 0.5))
        return (self.pitch_deg * np.cos(t) - self.roll_deg * np.sin(t)) / self.step

    def azimuths(self, x: np.ndarray, heading_deg: float) -> np.ndarray:
        """Compass azimuth (degrees, [0, 360)) of column coordinates ``x`` (centres at integers)."""
        return (heading_deg + self.hfov_deg * ((np.asarray(x, dtype=np.float64) + 0.5) / self.width - 0.5)) % 360.0

    def distance_m(self, row: np.ndarray) -> np.ndarray:
        """Ground distance seen at row coordinates ``row`` (inf at or above the horizon)."""
        dep = np.radians((np.asarray(row, dtype=np.float64) - self.horizon) * self.step)
        with np.errstate(divide="ignore"):
            return np.where(dep > 0, self.camera_height_m / np.tan(np.maximum(dep, 1e-12)), np.inf)

    def row_of(self, distance_m: float) -> float:
        """Row coordinate where the ground ``distance_m`` away is seen."""
        return self.horizon + math.degrees(math.atan(self.camera_height_m / distance_m)) / self.step
