"""Metrics against hand-computed confusion matrices, DDP reduction, and class mappings."""

from __future__ import annotations

import json
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import shared_path

from osmseg.classes import load_class_table
from osmseg.errors import ConfigError, DatasetError
from training.evaluation.metrics import (
    IGNORE,
    ConfusionMatrix,
    format_table,
    load_class_mapping,
)

NAMES = ["unlabeled", "building", "road", "tree", "water"]

# The hand example. Class 0 (unlabeled) is ignore_index; water (4) never occurs in the ground
# truth but is predicted once. (ground truth, prediction, number of pixels):
PAIRS = [
    (1, 1, 8), (1, 2, 1), (1, 4, 1),  # 10 building pixels: 8 right, 1 as road, 1 as water
    (2, 1, 1), (2, 2, 4), (2, 3, 1),  # 6 road pixels: 1 as building, 4 right, 1 as tree
    (3, 0, 1), (3, 3, 3),             # 4 tree pixels: 1 as unlabeled, 3 right
]
IGNORED = [(0, 1, 3), (0, 2, 2)]      # 5 unlabeled ground-truth pixels: never counted
# Confusion matrix by hand (rows ground truth, columns prediction, order of NAMES):
#   unlabeled  0 0 0 0 0
#   building   0 8 1 0 1     support 10
#   road       0 1 4 1 0     support 6
#   tree       1 0 0 3 0     support 4
#   water      0 0 0 0 0     support 0
#   predicted: 1 9 5 4 1     total 20, trace 15
# building: TP 8, FP 1 (a road pixel), FN 2 -> IoU 8/11, precision 8/9, recall 8/10, F1 16/19
# road:     TP 4, FP 1 (a building pixel), FN 2 -> IoU 4/7, precision 4/5, recall 4/6, F1 8/11
# tree:     TP 3, FP 1 (a road pixel), FN 1 -> IoU 3/5, precision 3/4, recall 3/4, F1 6/8
# water:    no ground truth -> IoU, recall, F1 null; precision 0/1 = 0 (one false alarm)
# unlabeled (ignored): no ground truth -> IoU null; precision 0/1 = 0 (a tree pixel)
# pixel accuracy = 15/20; mIoU over the 3 present classes = (8/11 + 4/7 + 3/5) / 3
# mean accuracy = (8/10 + 4/6 + 3/4) / 3; FWIoU = (10 * 8/11 + 6 * 4/7 + 4 * 3/5) / 20
EXPECTED = {
    "building": dict(iou=Fraction(8, 11), precision=Fraction(8, 9), recall=Fraction(8, 10), f1=Fraction(16, 19),
                     support=10, predicted=9),
    "road": dict(iou=Fraction(4, 7), precision=Fraction(4, 5), recall=Fraction(4, 6), f1=Fraction(8, 11),
                 support=6, predicted=5),
    "tree": dict(iou=Fraction(3, 5), precision=Fraction(3, 4), recall=Fraction(3, 4), f1=Fraction(6, 8),
                 support=4, predicted=4),
    "water": dict(iou=None, precision=Fraction(0), recall=None, f1=None, support=0, predicted=1),
    "unlabeled": dict(iou=None, precision=Fraction(0), recall=None, f1=None, support=0, predicted=1),
}


def _pixels(pairs: list[tuple[int, int, int]], seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Flat target/prediction tensors holding each (gt, pred) pair ``count`` times, shuffled."""
    gt = [g for g, _, n in pairs for _ in range(n)]
    pred = [p for _, p, n in pairs for _ in range(n)]
    order = torch.randperm(len(gt), generator=torch.Generator().manual_seed(seed))
    return torch.tensor(gt)[order], torch.tensor(pred)[order]


def _hand_matrix() -> ConfusionMatrix:
    """The hand example fed as two batches of 1 x 5 x 5 id images, as a validation loop would."""
    gt, pred = _pixels(PAIRS + IGNORED)  # 25 pixels
    cm = ConfusionMatrix(5, ignore_index=0, class_names=NAMES)
    images_gt, images_pred = gt.reshape(1, 5, 5), pred.reshape(1, 5, 5)
    cm.update(images_gt[:, :2], images_pred[:, :2])
    cm.update(images_gt[:, 2:], images_pred[:, 2:])
    return cm


def _close(value: float | None, want: Fraction | None) -> bool:
    return value is None if want is None else value == pytest.approx(float(want), abs=1e-12)


def test_hand_computed_matrix_and_per_class_metrics() -> None:
    m = _hand_matrix().compute()
    assert m["confusion_matrix"] == [
        [0, 0, 0, 0, 0],
        [0, 8, 1, 0, 1],
        [0, 1, 4, 1, 0],
        [1, 0, 0, 3, 0],
        [0, 0, 0, 0, 0],
    ]
    assert list(m["per_class"]) == NAMES
    for name, want in EXPECTED.items():
        got = m["per_class"][name]
        assert got["id"] == NAMES.index(name)
        assert got["support"] == want["support"] and got["predicted"] == want["predicted"], name
        for key in ("iou", "precision", "recall", "f1"):
            assert _close(got[key], want[key]), (name, key, got[key])


def test_hand_computed_summaries_exclude_the_absent_class() -> None:
    m = _hand_matrix().compute()
    assert m["pixel_accuracy"] == pytest.approx(15 / 20)
    assert m["num_pixels"] == 20  # the 5 ignored pixels are not counted
    assert m["classes_present"] == 3
    assert m["miou"] == pytest.approx((8 / 11 + 4 / 7 + 3 / 5) / 3)
    # with water counted as IoU 0 the mean would be lower: the absent class is really left out
    assert m["miou"] > (8 / 11 + 4 / 7 + 3 / 5) / 4
    assert m["mean_accuracy"] == pytest.approx((8 / 10 + 4 / 6 + 3 / 4) / 3)
    assert m["fwiou"] == pytest.approx((10 * 8 / 11 + 6 * 4 / 7 + 4 * 3 / 5) / 20)


def test_ignored_pixels_do_not_count_whatever_is_predicted_there() -> None:
    base = _hand_matrix().compute()
    gt, pred = _pixels(PAIRS + IGNORED)
    pred = torch.where(gt == 0, torch.full_like(pred, 4), pred)  # predict water on every ignored pixel
    cm = ConfusionMatrix(5, ignore_index=0, class_names=NAMES)
    cm.update(gt, pred)
    assert cm.compute() == base
    # without ignore_index the unlabeled row is counted: 5 more pixels, unlabeled now present
    cm_all = ConfusionMatrix(5, ignore_index=None, class_names=NAMES)
    cm_all.update(gt, pred)
    m = cm_all.compute()
    assert m["num_pixels"] == 25 and m["per_class"]["unlabeled"]["support"] == 5
    assert m["per_class"]["unlabeled"]["iou"] == 0.0 and m["classes_present"] == 4


def test_logits_are_argmaxed_and_names_can_be_given_to_compute() -> None:
    target = torch.tensor([[[0, 1], [2, 2]]])
    logits = torch.nn.functional.one_hot(torch.tensor([[[0, 1], [1, 2]]]), 3).permute(0, 3, 1, 2).float()
    cm = ConfusionMatrix(3, ignore_index=None)
    cm.update(target, logits)
    m = cm.compute(["a", "b", "c"])
    assert m["confusion_matrix"] == [[1, 0, 0], [0, 1, 0], [0, 1, 1]]
    assert m["per_class"]["c"]["recall"] == 0.5


def test_metrics_are_json_without_nan() -> None:
    empty = ConfusionMatrix(3, ignore_index=0).compute()
    assert empty["pixel_accuracy"] is None and empty["miou"] is None and empty["fwiou"] is None
    for m in (empty, _hand_matrix().compute()):
        text = json.dumps(m, allow_nan=False)
        assert json.loads(text) == m


def test_numpy_inputs_and_reset() -> None:
    cm = ConfusionMatrix(2, ignore_index=None)
    cm.update(np.array([[0, 1]], dtype=np.uint8), np.array([[0, 1]], dtype=np.uint8))
    assert cm.compute()["miou"] == 1.0
    cm.reset()
    assert cm.matrix().sum() == 0


def test_bad_inputs_give_one_line_errors() -> None:
    cm = ConfusionMatrix(3, ignore_index=0)
    with pytest.raises(DatasetError, match=r"class id 7 is outside 0\.\.2") as exc:
        cm.update(torch.tensor([1, 7]), torch.tensor([1, 1]))
    assert "\n" not in str(exc.value)
    with pytest.raises(DatasetError, match="shape"):
        cm.update(torch.zeros(2, 3, dtype=torch.long), torch.zeros(3, 2, dtype=torch.long))
    with pytest.raises(DatasetError, match="predicted class id 5"):
        cm.update(torch.tensor([1, 2]), torch.tensor([1, 5]))
    with pytest.raises(ConfigError, match="class names"):
        ConfusionMatrix(3, class_names=["a", "b"])


def test_format_table_lists_every_class_and_the_summaries() -> None:
    text = format_table(_hand_matrix().compute())
    lines = text.splitlines()
    for name in NAMES[1:]:
        assert any(line.startswith(name) for line in lines)
    # the ignored class has no scores: it is named under the table, not given a row of dashes
    assert not any(line.startswith(NAMES[0]) for line in lines)
    assert any(line.startswith("not scored:") and NAMES[0] in line for line in lines)
    building = next(line for line in lines if line.startswith("building"))
    assert building.split() == ["building", "0.727", "0.889", "0.800", "0.842", "10"]  # ratios: 3 decimals
    water = next(line for line in lines if line.startswith("water"))
    assert water.split()[1] == "-"  # undefined IoU is shown as "-", not 0 or nan
    assert f"{(8 / 11 + 4 / 7 + 3 / 5) / 3:.3f}" in next(line for line in lines if line.startswith("mIoU"))
    assert "nan" not in text.lower()
    assert len({len(line) for line in lines[: len(NAMES) + 2]}) == 1  # fixed width: header, rules and rows align


# ----------------------------------------------------------------------------- DDP on CPU


def _rank_data(rank: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(100 + rank)
    return torch.randint(0, 4, (2, 6, 6), generator=g), torch.randint(0, 4, (2, 6, 6), generator=g)


def _ddp_worker(rank: int, world_size: int, init_file: str, out_dir: str) -> None:
    torch.set_num_threads(1)
    torch.distributed.init_process_group("gloo", init_method=f"file://{init_file}", rank=rank, world_size=world_size)
    try:
        cm = ConfusionMatrix(4, ignore_index=0)
        cm.update(*_rank_data(rank))
        local = cm.matrix()
        cm.reduce_from_all_processes()
        np.save(Path(out_dir) / f"rank{rank}.npy", np.stack([local, cm.matrix()]))
    finally:
        torch.distributed.destroy_process_group()


def test_reduce_sums_the_matrices_of_two_gloo_processes(tmp_path: Path) -> None:
    torch.multiprocessing.spawn(_ddp_worker, args=(2, str(tmp_path / "init"), str(tmp_path)), nprocs=2, join=True)
    results = [np.load(tmp_path / f"rank{r}.npy") for r in range(2)]
    expected = []
    for rank in range(2):
        cm = ConfusionMatrix(4, ignore_index=0)
        cm.update(*_rank_data(rank))
        expected.append(cm.matrix())
        assert np.array_equal(results[rank][0], expected[rank])  # before the reduce: the rank's own counts
    assert not np.array_equal(expected[0], expected[1])
    for rank in range(2):
        assert np.array_equal(results[rank][1], expected[0] + expected[1])


def test_reduce_without_distributed_is_a_no_op() -> None:
    cm = _hand_matrix()
    before = cm.matrix()
    cm.reduce_from_all_processes()
    assert np.array_equal(cm.matrix(), before)


# ----------------------------------------------------------------------------- class mappings

CLASSES13 = [c["name"] for c in load_class_table("classes13.toml").to_dict()["classes"]]
CLASSES6 = [c["name"] for c in load_class_table("classes6.toml").to_dict()["classes"]]


def test_inria_mapping_maps_labels_and_predictions() -> None:
    m = load_class_mapping("inria-buildings")
    assert m.classes == ("background", "building") and m.ignore_index is None
    gt = np.array([[0, 255, 255], [0, 0, 255]], dtype=np.uint8)
    assert m.map_gt(gt).tolist() == [[0, 1, 1], [0, 0, 1]]
    for names in (CLASSES13, CLASSES6):
        pred = np.arange(len(names), dtype=np.uint8)
        mapped = m.map_pred(pred, names)
        assert mapped.dtype == np.uint8
        assert [names[i] for i in np.flatnonzero(mapped == 1)] == ["building"]  # everything else, unlabeled too, is background
    table = m.class_table_dict()
    assert [c["name"] for c in table["classes"]] == ["background", "building"]
    assert table["classes"][1]["color"] == [255, 255, 0]


def test_unmapped_ground_truth_value_is_named() -> None:
    m = load_class_mapping("inria-buildings")
    with pytest.raises(DatasetError, match=r"\[128\].*inria-buildings") as exc:
        m.map_gt(np.array([0, 128, 255], dtype=np.uint8))
    assert "\n" not in str(exc.value)


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "mapping.toml"
    path.write_text(text)
    return path


def test_camvid_style_mapping_with_ignored_void(tmp_path: Path) -> None:
    """Many classes onto fewer, a void value left out of the metrics, no "*" default."""
    path = _write(tmp_path, """
name = "camvid-to-ground"
classes = ["road", "building", "other"]
ignore = [11]
[ground_truth]
0 = "other"      # sky
1 = "building"
3 = "road"
4 = "other"      # pavement
[prediction]
road = "road"
building = "building"
sky = "other"
pavement = "other"
""")
    m = load_class_mapping(path)
    gt = m.map_gt(np.array([3, 1, 11, 0, 4], dtype=np.uint8))
    assert gt.tolist() == [0, 1, IGNORE, 2, 2]
    pred = m.map_pred(np.array([0, 1, 2, 3, 1]), ["sky", "building", "pavement", "road"])
    assert pred.tolist() == [2, 1, 2, 0, 1]
    cm = ConfusionMatrix(m.num_classes, ignore_index=m.ignore_index, class_names=list(m.classes))
    cm.update(gt, pred)
    assert cm.compute()["num_pixels"] == 4  # the void pixel is not counted
    with pytest.raises(ConfigError, match="'unlabeled' is not mapped"):
        m.map_pred(np.array([0]), ["unlabeled", "sky", "building", "pavement", "road"])
    with pytest.raises(ConfigError, match=r"names model classes \['pavement'\]"):
        m.map_pred(np.array([0]), ["sky", "building", "road"])


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('classes = ["a"]\n[ground_truth]\n0 = "b"\n[prediction]\n"*" = "a"\n', "unknown class 'b'"),
        ('classes = ["a"]\n[ground_truth]\nx = "a"\n[prediction]\n"*" = "a"\n', "key 'x' is not an integer"),
        ('classes = ["a"]\n[ground_truth]\n0 = "a"\n[prediction]\nbuilding = "z"\n', "unknown class 'z'"),
        ('classes = ["a"]\n[ground_truth]\n0 = "a"\n', r"needs a \[prediction\] table"),
        ('classes = []\n[ground_truth]\n0 = "a"\n[prediction]\n"*" = "a"\n', "non-empty list"),
        ('classes = ["a"]\nignore = [0]\n[ground_truth]\n0 = "a"\n[prediction]\n"*" = "a"\n', "both mapped and ignored"),
        ('classes = ["a"]\ncolour = 1\n[ground_truth]\n0 = "a"\n[prediction]\n"*" = "a"\n', "unknown keys"),
        ('classes = ["a"\n', "not valid TOML"),
    ],
)
def test_bad_mapping_files_give_one_line_config_errors(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message) as exc:
        load_class_mapping(_write(tmp_path, text))
    assert "\n" not in str(exc.value)


def test_unknown_mapping_name() -> None:
    with pytest.raises(ConfigError, match="not found"):
        load_class_mapping("no-such-mapping")


def test_real_inria_labels_through_the_mapping() -> None:
    """Inria Austin's real 0/255 mask: a prediction equal to it scores 1, a shifted one less."""
    import rasterio

    with rasterio.open(shared_path("inria-austin", "buildings.tif")) as src:
        raw = src.read(1)
    m = load_class_mapping("inria-buildings")
    gt = m.map_gt(raw)
    assert int((gt == 1).sum()) == int((raw == 255).sum()) > 0
    # a classes6 model that finds exactly the buildings and calls the rest highway or unlabeled
    ids = {n: i for i, n in enumerate(CLASSES6)}
    perfect = np.where(raw == 255, ids["building"], np.where(np.arange(raw.shape[1]) % 2, ids["highway"], 0))
    cm = ConfusionMatrix(m.num_classes, ignore_index=m.ignore_index, class_names=list(m.classes))
    cm.update(torch.from_numpy(gt), torch.from_numpy(m.map_pred(perfect.astype(np.uint8), CLASSES6)))
    assert cm.compute()["per_class"]["building"]["iou"] == 1.0
    shifted = np.roll(perfect, 20, axis=1).astype(np.uint8)  # 6 m east
    cm.reset()
    cm.update(gt, m.map_pred(shifted, CLASSES6))
    result = cm.compute()
    assert 0.0 < result["per_class"]["building"]["iou"] < 1.0
    assert result["per_class"]["background"]["support"] == int((raw == 0).sum())
