"""Evaluation pictures: valid PNGs whose pixels show what they claim (colours, matrix shape, curves)."""

from __future__ import annotations

import csv
from pathlib import Path

import matplotlib
import numpy as np
import pytest
from PIL import Image

from osmseg.classes import load_class_table
from osmseg.errors import DatasetError
from training.figures import (
    confusion_matrix_png,
    per_class_iou_png,
    qualitative_panels,
    training_curves_png,
)
from training.metrics import metrics_from_matrix

TABLE = {
    "name": "tiny",
    "classes": [
        {"id": 0, "name": "unlabeled", "color": [0, 0, 0]},
        {"id": 1, "name": "building", "color": [255, 255, 0]},
        {"id": 2, "name": "highway", "color": [50, 50, 255]},
        {"id": 3, "name": "water", "color": [119, 242, 242]},  # in no mask: only the legend shows it
    ],
}
GREY = (128, 128, 128)
BLUES_MAX = (8, 48, 107)  # matplotlib's "Blues" at 1.0: a cell whose whole row is on it


def _pixels(path: Path) -> np.ndarray:
    """The PNG's pixels as (H, W, 3) uint8, after checking it is a whole, valid PNG."""
    with Image.open(path) as im:
        assert im.format == "PNG"
        im.verify()
    with Image.open(path) as im:
        assert 200 <= im.width <= 3000 and 150 <= im.height <= 3000, im.size
        return np.asarray(im.convert("RGB"))


def _count(pixels: np.ndarray, rgb: tuple[int, int, int], tol: int = 0) -> int:
    return int((np.abs(pixels.astype(int) - np.array(rgb)).max(axis=2) <= tol).sum())


def _panel_rows() -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]:
    image = np.full((48, 64, 3), GREY, dtype=np.uint8)
    gt = np.zeros((48, 64), dtype=np.uint8)
    gt[:, 16:32] = 1
    gt[24:, 32:] = 2
    return [("tile 1", image, gt, np.roll(gt, 6, axis=1)), ("tile 2", image, gt, gt)]


def test_qualitative_panels_show_every_class_colour_in_masks_and_legend(tmp_path: Path) -> None:
    path = qualitative_panels(_panel_rows(), TABLE, tmp_path / "panels.png")
    pixels = _pixels(path)
    for entry in TABLE["classes"]:
        assert _count(pixels, tuple(entry["color"])) > 20, entry["name"]
    assert _count(pixels, GREY) > 1000  # the images themselves
    # water is in no mask: its exact colour comes from the legend swatch alone, a small patch
    assert _count(pixels, (119, 242, 242)) < 2000
    assert _count(pixels, (12, 34, 56)) == 0  # a colour that nothing draws is absent
    assert not list(tmp_path.glob(".*"))  # written atomically: no temporary file left


def test_qualitative_panels_with_a_real_class_table(tmp_path: Path) -> None:
    table = load_class_table("classes13.toml").to_dict()
    path = qualitative_panels(_panel_rows()[:1], table, tmp_path / "p13.png")
    pixels = _pixels(path)
    for entry in table["classes"]:  # 14 legend swatches
        assert _count(pixels, tuple(entry["color"])) > 20, entry["name"]


def test_qualitative_panels_reject_mismatched_masks(tmp_path: Path) -> None:
    title, image, gt, pred = _panel_rows()[0]
    with pytest.raises(DatasetError, match="prediction shape") as exc:
        qualitative_panels([(title, image, gt, pred[:, :10])], TABLE, tmp_path / "bad.png")
    assert "\n" not in str(exc.value)
    with pytest.raises(DatasetError, match="at least one"):
        qualitative_panels([], TABLE, tmp_path / "bad.png")
    assert not (tmp_path / "bad.png").exists()


def test_confusion_matrix_picture_of_identity_and_uniform_differ(tmp_path: Path) -> None:
    names = ["building", "highway", "water"]
    identity = metrics_from_matrix(np.eye(3, dtype=int) * 100, names)
    uniform = metrics_from_matrix(np.full((3, 3), 100), names)
    a = _pixels(confusion_matrix_png(identity, tmp_path / "identity.png"))
    b = _pixels(confusion_matrix_png(uniform, tmp_path / "uniform.png"))
    assert a.shape == b.shape and not np.array_equal(a, b)
    # identity: three cells at the top of the colour scale (recall 1); uniform: none, every cell is 1/3
    assert _count(a, BLUES_MAX) > 3 * 500
    assert _count(b, BLUES_MAX) < _count(a, BLUES_MAX) / 10  # at most a sliver of the colour bar


def test_confusion_matrix_picture_is_deterministic_and_leaves_rcparams_alone(tmp_path: Path) -> None:
    before = dict(matplotlib.rcParams)
    metrics = metrics_from_matrix([[5, 1, 0], [2, 7, 1], [0, 0, 0]], ["a", "b", "c"])
    first = confusion_matrix_png(metrics, tmp_path / "one.png").read_bytes()
    second = confusion_matrix_png(metrics, tmp_path / "two.png").read_bytes()
    assert first == second
    assert dict(matplotlib.rcParams) == before
    counts = _pixels(confusion_matrix_png(metrics, tmp_path / "counts.png", normalise=None))
    assert counts.shape[2] == 3


CURVE_BLUE, CURVE_ORANGE, CURVE_GREEN = (31, 119, 180), (255, 127, 14), (44, 160, 44)  # tab: colours

HISTORY = [
    {"epoch": 1, "lr": 0.01, "train_loss": 2.0, "val_loss": 2.2, "val_miou": 0.10, "val_pixel_accuracy": 0.3},
    {"epoch": 2, "lr": 0.01, "train_loss": 1.4, "val_loss": 1.8, "val_miou": 0.25, "val_pixel_accuracy": 0.5},
    {"epoch": 3, "lr": 0.01, "train_loss": 1.1, "val_loss": 1.6, "val_miou": 0.31, "val_pixel_accuracy": 0.6},
]


def test_training_curves_from_a_three_epoch_history(tmp_path: Path) -> None:
    pixels = _pixels(training_curves_png(HISTORY, tmp_path / "curves.png"))
    for colour in (CURVE_BLUE, CURVE_ORANGE, CURVE_GREEN):  # train loss, val loss, val mIoU
        assert _count(pixels, colour) > 50, colour


def test_training_curves_from_the_csv_log_with_gaps(tmp_path: Path) -> None:
    log = tmp_path / "log.csv"
    with log.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(HISTORY[0]))
        writer.writeheader()
        for row in HISTORY:
            writer.writerow(row)
    from_csv = _pixels(training_curves_png(log, tmp_path / "csv.png"))
    from_list = _pixels(training_curves_png(HISTORY, tmp_path / "list.png"))
    assert np.array_equal(from_csv, from_list)
    # a run whose validation mIoU is undefined (nan / empty) still draws its losses
    gaps = [dict(row, val_miou=None, val_loss=float("nan")) for row in HISTORY]
    pixels = _pixels(training_curves_png(gaps, tmp_path / "gaps.png"))
    assert _count(pixels, CURVE_BLUE) > 50
    assert _count(pixels, CURVE_GREEN) == 0 and _count(pixels, CURVE_ORANGE) == 0


def test_training_curves_bad_input(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="cannot read training log"):
        training_curves_png(tmp_path / "missing.csv", tmp_path / "c.png")
    with pytest.raises(DatasetError, match="no epochs"):
        training_curves_png([], tmp_path / "c.png")


def test_per_class_iou_bars_in_class_colours(tmp_path: Path) -> None:
    metrics = metrics_from_matrix([[0, 0, 0, 0], [0, 8, 2, 0], [0, 1, 9, 0], [0, 0, 0, 0]],
                                  [c["name"] for c in TABLE["classes"]], ignore_index=0)  # unlabeled: not scored
    pixels = _pixels(per_class_iou_png(metrics, TABLE, tmp_path / "iou.png"))
    assert _count(pixels, (255, 255, 0)) > 500 and _count(pixels, (50, 50, 255)) > 500
    assert _count(pixels, (119, 242, 242)) == 0  # water is absent from the ground truth: no bar
