"""Sample filter: each heuristic at its threshold, the fixed order of checks, and real imagery."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import shared_path

from osmseg.builder.filters import FilterConfig, check_imagery, check_labels, check_sample, grey_std
from osmseg.errors import ConfigError
from osmseg.output.manifest import REASONS, Rejection

DEFAULT = FilterConfig()


def labels_with(unlabeled: int, classes: tuple[int, ...] = (1, 2), total: int = 100) -> np.ndarray:
    """A 10x10 label image: ``unlabeled`` zeros, the rest split between ``classes``."""
    flat = np.zeros(total, np.uint8)
    rest = np.arange(total - unlabeled)
    flat[unlabeled:] = np.array(classes, np.uint8)[rest % len(classes)]
    return flat.reshape(10, total // 10)


def contrast_image(std: float, shape: tuple[int, int] = (10, 10)) -> np.ndarray:
    """Grey RGB image whose grey-level standard deviation is exactly ``std`` (half at 100-std, half at 100+std)."""
    rgb = np.full((*shape, 3), 100 - std, np.float64)
    rgb[: shape[0] // 2] = 100 + std
    return rgb.astype(np.uint8)


GOOD_RGB = contrast_image(40)
ALL_VALID = np.ones((10, 10), bool)
GOOD_LABELS = labels_with(0)


def test_a_good_sample_is_kept() -> None:
    assert check_sample(GOOD_RGB, ALL_VALID, GOOD_LABELS, 0, DEFAULT) is None


def test_unlabeled_at_threshold_is_rejected_just_below_is_kept() -> None:
    assert check_labels(labels_with(70), DEFAULT) == Rejection("unlabeled", "70.0% unlabeled >= 70.0%")
    assert check_labels(labels_with(69), DEFAULT) is None
    assert check_labels(labels_with(83), DEFAULT).detail == "83.0% unlabeled >= 70.0%"
    # configurable: at 0.9, 83% passes
    assert check_labels(labels_with(83), FilterConfig(max_unlabeled=0.9)) is None


def test_unlabeled_threshold_exact_on_a_full_size_sample() -> None:
    labels = np.ones((1280, 1280), np.uint8)
    labels[:, :1] = 2
    n70 = 1280 * 1280 * 7 // 10  # 1146880, exactly 70 %
    labels.ravel()[1280:1280 + n70] = 0
    assert check_labels(labels, DEFAULT).reason == "unlabeled"
    labels.ravel()[1280] = 1
    assert check_labels(labels, DEFAULT) is None


def test_single_class_is_rejected_two_classes_kept() -> None:
    only_water = np.full((10, 10), 8, np.uint8)
    assert check_labels(only_water, DEFAULT) == Rejection("single_class", "1 labelled class (id 8) < 2")
    # one pixel of a second class is enough at min_classes=2
    only_water[0, 0] = 1
    assert check_labels(only_water, DEFAULT) is None
    assert check_labels(only_water, FilterConfig(min_classes=3)).detail == "2 labelled classes (id 1, 8) < 3"


def test_unlabeled_does_not_count_as_a_class() -> None:
    labels = labels_with(50, classes=(4,))  # 50 % unlabeled + one class
    assert check_labels(labels, DEFAULT).reason == "single_class"
    # even max_unlabeled=1.0 rejects an all-unlabeled sample (>= 100 %), as "unlabeled"
    empty = np.zeros((10, 10), np.uint8)
    assert check_labels(empty, FilterConfig(max_unlabeled=1.0)).reason == "unlabeled"


def test_placeholder_tiles() -> None:
    assert check_imagery(GOOD_RGB, ALL_VALID, 1, DEFAULT) == Rejection(
        "placeholder_imagery", "1 placeholder (no imagery) tile > 0"
    )
    assert check_imagery(GOOD_RGB, ALL_VALID, 0, DEFAULT) is None
    assert check_imagery(GOOD_RGB, ALL_VALID, 1, FilterConfig(max_placeholder_tiles=1)) is None
    assert check_imagery(GOOD_RGB, ALL_VALID, 3, FilterConfig(max_placeholder_tiles=1)).detail.startswith("3 placeholder")


def test_missing_imagery_at_threshold() -> None:
    valid = ALL_VALID.copy()
    valid[0, 0] = False
    assert check_imagery(GOOD_RGB, valid, 0, DEFAULT) == Rejection(
        "missing_imagery", "1.0% of pixels without imagery > 0.0%"
    )
    tolerant = FilterConfig(max_invalid_imagery=0.01)
    assert check_imagery(GOOD_RGB, valid, 0, tolerant) is None  # exactly 1 % allowed
    valid[0, 1] = False
    assert check_imagery(GOOD_RGB, valid, 0, tolerant).reason == "missing_imagery"


def test_low_contrast_at_threshold() -> None:
    assert grey_std(contrast_image(8)) == 8.0
    assert check_imagery(contrast_image(8), ALL_VALID, 0, DEFAULT) is None
    assert check_imagery(contrast_image(7), ALL_VALID, 0, DEFAULT) == Rejection("low_contrast", "grey-level std 7.0 < 8")
    flat = np.full((10, 10, 3), 128, np.uint8)
    assert check_imagery(flat, ALL_VALID, 0, DEFAULT).detail == "grey-level std 0.0 < 8"


def test_contrast_uses_luma_not_a_single_channel() -> None:
    # pure red vs pure blue differ strongly in luma (76 vs 29)
    rgb = np.zeros((10, 10, 3), np.uint8)
    rgb[:5, :, 0] = 255
    rgb[5:, :, 2] = 255
    assert grey_std(rgb) == pytest.approx((0.299 - 0.114) * 255 / 2, abs=1e-5)


def test_contrast_is_measured_on_pixels_with_imagery_only() -> None:
    # a uniform image with a black hole has high overall contrast, but the imagery itself is blank
    rgb = np.full((10, 10, 3), 200, np.uint8)
    rgb[:3] = 0
    valid = ALL_VALID.copy()
    valid[:3] = False
    assert grey_std(rgb) > 8
    assert check_imagery(rgb, valid, 0, FilterConfig(max_invalid_imagery=0.5)).reason == "low_contrast"


def test_order_of_checks_is_fixed() -> None:
    blank = np.zeros((10, 10, 3), np.uint8)
    none_valid = np.zeros((10, 10), bool)
    empty = np.zeros((10, 10), np.uint8)
    # everything wrong: labels are checked first
    assert check_sample(blank, none_valid, empty, 5, DEFAULT).reason == "unlabeled"
    assert check_sample(blank, none_valid, np.full((10, 10), 3, np.uint8), 5, DEFAULT).reason == "single_class"
    # good labels: placeholder, then missing, then contrast
    assert check_sample(blank, none_valid, GOOD_LABELS, 5, DEFAULT).reason == "placeholder_imagery"
    assert check_sample(blank, none_valid, GOOD_LABELS, 0, DEFAULT).reason == "missing_imagery"
    assert check_sample(blank, ALL_VALID, GOOD_LABELS, 0, DEFAULT).reason == "low_contrast"
    assert REASONS == ("unlabeled", "single_class", "placeholder_imagery", "missing_imagery", "low_contrast")


def test_config_is_validated_and_round_trips() -> None:
    assert FilterConfig.from_dict(DEFAULT.to_dict()) == DEFAULT
    assert DEFAULT.to_dict() == {
        "max_unlabeled": 0.7, "min_classes": 2, "max_placeholder_tiles": 0,
        "max_invalid_imagery": 0.0, "min_contrast": 8.0,
    }
    with pytest.raises(ConfigError, match="max_unlabeled"):
        FilterConfig(max_unlabeled=70)
    with pytest.raises(ConfigError, match="min_contrast"):
        FilterConfig(min_contrast=-1)
    with pytest.raises(ConfigError, match="unknown filter settings"):
        FilterConfig.from_dict({"max_unlabelled": 0.5})


def test_mismatched_arrays_are_refused() -> None:
    with pytest.raises(ValueError, match="differ in size"):
        check_sample(GOOD_RGB, ALL_VALID, np.zeros((5, 5), np.uint8), 0, DEFAULT)
    with pytest.raises(ValueError, match="rgb must be"):
        check_imagery(GOOD_RGB[..., 0], ALL_VALID, 0, DEFAULT)


def test_real_uniform_aerial_imagery_passes_the_contrast_threshold() -> None:
    """The most uniform real image in ../shared/data (canopy and savanna) keeps clear of min_contrast."""
    rasterio = pytest.importorskip("rasterio")
    path = shared_path("oam-rgb", "brazil.tif")
    with rasterio.open(path) as src:
        rgb = src.read([1, 2, 3], window=((0, 1280), (0, 1280))).transpose(1, 2, 0)
    assert grey_std(rgb) > 2 * DEFAULT.min_contrast
    assert check_imagery(rgb, np.ones(rgb.shape[:2], bool), 0, DEFAULT) is None
