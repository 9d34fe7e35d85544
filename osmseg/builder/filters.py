"""Which samples to keep: the dissertation's rejection heuristics, with recorded thresholds.

Resek (2022) drops a candidate sample when its labels or its imagery would teach a network
nothing useful. A sample is rejected when

1. ``unlabeled``: at least ``max_unlabeled`` (70 %) of its pixels are unlabeled (class 0);
2. ``single_class``: fewer than ``min_classes`` (2) distinct OSM classes appear in it
   (unlabeled does not count: it is the absence of a label, not a class);
3. ``placeholder_imagery``: some tile has no imagery: the provider said so (Bing's "no
   imagery" placeholder, marked in a response header; a 404), or the tile is of one colour
   (the "no imagery here" fill of most tile servers; :func:`osmseg.imagery.mosaic.is_uniform`);
4. ``missing_imagery``: more than ``max_invalid_imagery`` of its pixels have no imagery
   (outside a GeoTIFF's footprint, transparent or missing tiles);
5. ``low_contrast``: the standard deviation of its grey levels (over pixels that have
   imagery) is below ``min_contrast``: blank, single-colour, clouded or washed-out images.

The checks always run in this order and the first failing one is the reason recorded. Label
checks come first because labels come from OSM, before any imagery is downloaded: the
builder can call :func:`check_labels` early and skip 25 tile requests for a sample that
would be rejected anyway; :func:`check_sample` uses the same order, so the recorded reason
does not depend on whether the builder checked early.

Why ``min_contrast = 8``: single-colour placeholders and nodata fills measure 0, and the real
aerial images in ``../shared/data``, the most uniform one (tree canopy and savanna) included,
measure well above 8: docs/dataset-format.md gives the figures (measured by docs/figures.py).

>>> labels = np.zeros((10, 10), np.uint8); labels[:, :4] = 1; labels[:, 4:] = 2
>>> rgb = np.zeros((10, 10, 3), np.uint8); rgb[::2] = 200
>>> check_sample(rgb, np.ones((10, 10), bool), labels, 0, FilterConfig()) is None
True
>>> check_labels(np.zeros((10, 10), np.uint8), FilterConfig())
Rejection(reason='unlabeled', detail='100.0% unlabeled >= 70.0%')
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from osmseg.errors import ConfigError
from osmseg.output.manifest import Rejection


@dataclass(frozen=True)
class FilterConfig:
    """Thresholds of the sample filter (recorded in the manifest and the datasheet).

    Attributes:
        max_unlabeled: reject when the unlabeled fraction is at least this (0..1).
        min_classes: reject when fewer distinct labelled classes than this appear.
        max_placeholder_tiles: reject when the provider marked more tiles than this as
            "no imagery" placeholders.
        max_invalid_imagery: reject when the fraction of pixels without imagery is above
            this (0..1). 0 keeps only fully covered samples: a black hole in the image
            under real labels would teach the network wrong things.
        min_contrast: reject when the grey-level standard deviation (0..255 scale, ITU-R
            601 luma, pixels with imagery only) is below this.
    """

    max_unlabeled: float = 0.70
    min_classes: int = 2
    max_placeholder_tiles: int = 0
    max_invalid_imagery: float = 0.0
    min_contrast: float = 8.0

    def __post_init__(self) -> None:
        for name in ("max_unlabeled", "max_invalid_imagery"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ConfigError(f"filter {name} must be a fraction between 0 and 1, got {value}")
        if self.min_classes < 0:
            raise ConfigError(f"filter min_classes must be 0 or more, got {self.min_classes}")
        if self.max_placeholder_tiles < 0:
            raise ConfigError(f"filter max_placeholder_tiles must be 0 or more, got {self.max_placeholder_tiles}")
        if not 0.0 <= self.min_contrast <= 255.0:
            raise ConfigError(f"filter min_contrast must be between 0 and 255, got {self.min_contrast}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-able thresholds for the manifest.

        >>> FilterConfig().to_dict()["max_unlabeled"]
        0.7
        """
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> FilterConfig:
        """The config recorded by :meth:`to_dict` (e.g. read back from a manifest).

        >>> FilterConfig.from_dict({"min_classes": 3}).min_classes
        3
        """
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"unknown filter settings {unknown}; known: {sorted(known)}")
        return cls(**data)


def _pct(fraction: float) -> str:
    """A fraction as a percentage with one decimal.

    >>> _pct(0.8349)
    '83.5%'
    """
    return f"{100.0 * fraction:.1f}%"


def grey_std(rgb: np.ndarray, valid: np.ndarray | None = None) -> float:
    """Standard deviation of the ITU-R 601 luma (as Pillow's ``convert("L")``) over ``valid`` pixels.

    Returns 0.0 when no pixel is valid. Computed exactly: the luma times 1000 is an integer
    (``299 R + 587 G + 114 B``), so its sums are exact in 64 bits and the result does not
    depend on a summation order (an image of std exactly 8 passes ``min_contrast=8``); rounded
    to 1e-6. Integer arithmetic over the whole image also spares the copy of the valid pixels
    that a masked float computation makes (a 1280 px sample: ~9 ms instead of ~50 ms).

    >>> grey_std(np.full((4, 4, 3), 90, np.uint8))
    0.0
    >>> rgb = np.zeros((2, 2, 3), np.uint8); rgb[0] = 100
    >>> grey_std(rgb)
    50.0
    >>> grey_std(rgb, np.array([[True, False], [True, False]]))
    50.0
    >>> grey_std(np.array([[[255, 255, 255], [0, 0, 0]]], np.uint8))  # no 8- or 16-bit overflow
    127.5
    """
    flat = np.ascontiguousarray(rgb, dtype=np.uint8).reshape(-1, 3)
    luma = np.multiply(flat[:, 0], 299, dtype=np.int32)  # int32 whatever numpy's promotion rules
    luma += np.multiply(flat[:, 1], 587, dtype=np.int32)
    luma += np.multiply(flat[:, 2], 114, dtype=np.int32)
    count = luma.size
    if valid is not None and not valid.all():
        luma *= np.asarray(valid, dtype=bool).reshape(-1)  # invalid pixels add nothing to the sums
        count = int(np.count_nonzero(valid))
    if count == 0:
        return 0.0
    wide = luma.astype(np.int64)
    total, squares = int(wide.sum()), int(np.dot(wide, wide))
    return round(math.sqrt((count * squares - total * total) / (count * count)) / 1000.0, 6)


def check_labels(labels: np.ndarray, config: FilterConfig) -> Rejection | None:
    """The label checks (``unlabeled``, then ``single_class``); None when the labels pass.

    >>> labels = np.zeros((10, 10), np.uint8); labels[:4] = 5
    >>> check_labels(labels, FilterConfig())
    Rejection(reason='single_class', detail='1 labelled class (id 5) < 2')
    """
    total = labels.size
    if total == 0:
        raise ValueError("labels are empty")
    counts = np.bincount(labels.ravel(), minlength=1)
    unlabeled = int(counts[0]) / total
    if unlabeled >= config.max_unlabeled:
        return Rejection("unlabeled", f"{_pct(unlabeled)} unlabeled >= {_pct(config.max_unlabeled)}")
    present = [int(i) for i in np.flatnonzero(counts) if i != 0]
    if len(present) < config.min_classes:
        ids = f" (id {', '.join(map(str, present))})" if present else ""
        noun = "class" if len(present) == 1 else "classes"
        return Rejection("single_class", f"{len(present)} labelled {noun}{ids} < {config.min_classes}")
    return None


def check_imagery(rgb: np.ndarray, valid: np.ndarray, placeholder_tiles: int, config: FilterConfig,
                  uniform_tiles: int = 0) -> Rejection | None:
    """The imagery checks (``placeholder_imagery``, ``missing_imagery``, ``low_contrast``); None when it passes.

    ``placeholder_tiles`` counts the tiles without imagery, ``uniform_tiles`` of them of one colour.

    >>> rgb = np.zeros((4, 4, 3), np.uint8); valid = np.ones((4, 4), bool); valid[0, 0] = False
    >>> check_imagery(rgb, valid, 0, FilterConfig())
    Rejection(reason='missing_imagery', detail='6.2% of pixels without imagery > 0.0%')
    >>> check_imagery(rgb, valid, 2, FilterConfig(), uniform_tiles=1).detail
    '2 placeholder (no imagery) tiles (1 of one colour) > 0'
    """
    if rgb.ndim != 3 or rgb.shape[2] != 3 or valid.shape != rgb.shape[:2]:
        raise ValueError(f"rgb must be (H, W, 3) and valid (H, W); got {rgb.shape} and {valid.shape}")
    if placeholder_tiles > config.max_placeholder_tiles:
        uniform = f" ({uniform_tiles} of one colour)" if uniform_tiles else ""
        return Rejection(
            "placeholder_imagery",
            f"{placeholder_tiles} placeholder (no imagery) tile{'s' if placeholder_tiles != 1 else ''}{uniform}"
            f" > {config.max_placeholder_tiles}",
        )
    invalid = (valid.size - int(np.count_nonzero(valid))) / valid.size  # not 1 - valid/size: 1 - 0.99 > 0.01
    if invalid > config.max_invalid_imagery:
        return Rejection("missing_imagery", f"{_pct(invalid)} of pixels without imagery > {_pct(config.max_invalid_imagery)}")
    contrast = grey_std(rgb, valid.astype(bool))
    if contrast < config.min_contrast:
        return Rejection("low_contrast", f"grey-level std {contrast:.1f} < {config.min_contrast:g}")
    return None


def check_sample(
    rgb: np.ndarray,
    valid: np.ndarray,
    labels: np.ndarray,
    placeholder_tiles: int,
    config: FilterConfig,
) -> Rejection | None:
    """All checks in the documented order (labels, then imagery); None when the sample is kept.

    Args:
        rgb: ``(H, W, 3)`` uint8 image of the sample.
        valid: ``(H, W)`` bool, False where the provider had no imagery.
        labels: ``(H, W)`` uint8 class ids (0 = unlabeled).
        placeholder_tiles: tiles the provider marked as "no imagery here".
        config: the thresholds.
    """
    if labels.shape != rgb.shape[:2]:
        raise ValueError(f"labels {labels.shape} and image {rgb.shape} differ in size")
    return check_labels(labels, config) or check_imagery(rgb, valid, placeholder_tiles, config)
