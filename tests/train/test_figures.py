"""Evaluation pictures: valid PNGs whose pixels show what they claim (colours, matrix shape, curves)."""

from __future__ import annotations

import csv
from pathlib import Path

import matplotlib
import numpy as np
import pytest
from matplotlib.figure import Figure
from matplotlib.legend import Legend
from PIL import Image

from osmseg.classes import load_class_table
from osmseg.errors import DatasetError
from osmseg.output.plotting import figure
from training.evaluation.figures import (
    checkpoint_curves,
    checkpoint_curves_png,
    confusion_matrix_png,
    draw_per_class_iou,
    draw_training_curves,
    per_class_iou_png,
    qualitative_panels,
    training_curves_png,
)
from training.evaluation.metrics import metrics_from_matrix

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


def _legends(fig: Figure) -> list[Legend]:
    return [*fig.legends, *(ax.get_legend() for ax in fig.axes if ax.get_legend() is not None)]


def test_the_miou_legend_hides_no_bar_or_value(tmp_path: Path) -> None:
    """The demo's per_class_iou.png: "mIoU 0.763" sat in the lower right of the axes, over the
    value of the last bar (tree, 0.780). The legend is under the axes, clear of every bar and value."""
    names = ["unlabeled", "building", "highway", "water"]
    matrix = [[0, 0, 0, 0], [0, 80, 2, 1], [0, 3, 90, 1], [0, 1, 2, 85]]  # water last, IoU ~0.9
    metrics = metrics_from_matrix(matrix, names, ignore_index=0)
    with figure(6.5, 2.8) as fig:
        ax = draw_per_class_iou(fig, metrics, TABLE)
        fig.canvas.draw()
        values = [t for t in ax.texts if t.get_text().startswith("0.")]
        assert len(values) == 3  # building, highway, water
        legends = _legends(fig)
        assert [[t.get_text() for t in legend.get_texts()] for legend in legends] == [[f"mIoU {metrics['miou']:.3f}"]]
        box = legends[0].get_window_extent()
        assert not box.overlaps(ax.get_window_extent())
        assert not [t.get_text() for t in values if box.overlaps(t.get_window_extent())]
    _pixels(per_class_iou_png(metrics, TABLE, tmp_path / "iou.png"))


def test_training_curves_mark_an_epoch_and_their_legend_hides_no_point() -> None:
    with figure(9.0, 4.5) as fig:
        loss_ax, score_ax = draw_training_curves(fig, HISTORY, title="what the curves are", mark=(2, "best.pt: epoch 2"))
        fig.canvas.draw()
        for ax in (loss_ax, score_ax):
            marks = [line for line in ax.lines if line.get_label() == "best.pt: epoch 2"]
            assert len(marks) == 1 and list(marks[0].get_xdata()) == [2, 2]
        (legend,) = _legends(fig)  # one, for both axes, the mark named once
        assert [t.get_text() for t in legend.get_texts()] == [
            "train loss", "validation loss", "validation mIoU", "validation pixel accuracy", "best.pt: epoch 2"]
        assert not legend.get_window_extent().overlaps(loss_ax.get_window_extent())
        assert not legend.get_window_extent().overlaps(score_ax.get_window_extent())
        assert fig.get_suptitle() == "what the curves are"


def test_eval_curves_of_best_pt_draw_the_whole_run_when_its_log_is_beside_it(tmp_path: Path) -> None:
    """The demo's case: 8 epochs planned and run, best.pt saved at epoch 6 with the history up to
    it, the run's log.csv beside it. eval's curves.png stopped at epoch 6 and said nothing of it."""
    history = [{"epoch": e, "lr": 0.01, "train_loss": 2.0 / e, "val_loss": 2.2 / e, "val_miou": 0.1 * e,
                "val_pixel_accuracy": 0.05 + 0.1 * e, "seconds": 1.0} for e in range(1, 9)]
    run = tmp_path / "run"
    run.mkdir()
    with (run / "log.csv").open("w", newline="") as f:  # as training.run.files writes it
        writer = csv.DictWriter(f, fieldnames=list(history[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(history)
    best = {"epoch": 6, "history": history[:6], "config": {"epochs": 8}}
    rows, title, mark = checkpoint_curves(best, run / "best.pt")
    assert [r["epoch"] for r in rows] == list(range(1, 9))
    assert title == "The whole training run (the log.csv beside best.pt): epochs 1–8 of 8 planned; best.pt is epoch 6"
    assert mark == (6, "best.pt: epoch 6 (evaluated)")
    pixels = _pixels(checkpoint_curves_png(best, run / "best.pt", tmp_path / "curves.png"))
    assert _count(pixels, CURVE_GREEN) > 50

    (run / "log.csv").unlink()  # the checkpoint alone: its own history, said to stop at its epoch
    rows, title, mark = checkpoint_curves(best, run / "best.pt")
    assert [r["epoch"] for r in rows] == list(range(1, 7)) and mark[0] == 6
    assert title == ("Training history stored in best.pt: epochs 1–6 of 8 planned, up to the checkpoint's epoch; "
                     "the run's log.csv, with any later epochs, is not beside it")
