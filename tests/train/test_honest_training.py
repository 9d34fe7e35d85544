"""Honest validation (issue 19, item 5), through the real trainer on constructed datasets.

* A batch whose pixels are all unlabeled (ignored) contributes nothing: no NaN in log.csv, no
  optimizer step, the schedule still counts it.
* Labels that hold one class besides unlabeled train a binary model (unlabeled as background,
  scored), never a one-class model that validation scores 1.0 by masking everything else.
* The split keeps, of a few seeded draws, the one whose validation class mix is closest to
  training's, records the class shares in splits.json, and warns when validation still cannot
  represent the training classes.

Datasets are copies of ``tests/data/tinyseg`` (12 images of 128x160) with rewritten labels;
every check reads the label PNGs again with PIL/numpy, independently of the trainer.
"""

from __future__ import annotations

import copy
import csv
import json
import logging
import math
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result
from PIL import Image

torch = pytest.importorskip("torch")

from conftest import TEST_DATA, shared_path  # noqa: E402

from osmseg.cli.main import cli  # noqa: E402
from training.datasets.splits import make_splits  # noqa: E402
from training.models.checkpoint import load_checkpoint  # noqa: E402
from training.models.networks import SegNet  # noqa: E402
from training.run.engine import StepOptions, train_one_epoch  # noqa: E402

TINYSEG = TEST_DATA / "tinyseg"
TINY = TEST_DATA / "train" / "tiny.yaml"
NAMES = sorted(p.stem for p in (TINYSEG / "images").glob("*.png"))
CLASS_NAMES = ["unlabeled", "building", "highway", "grass", "water"]


@pytest.fixture(scope="module", autouse=True)
def one_thread() -> Iterator[None]:
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def osmseg(*args: object) -> Result:
    return CliRunner().invoke(cli, ["-q", *(str(a) for a in args)])


def relabelled(tmp_path: Path, relabel: Callable[[str, np.ndarray], np.ndarray]) -> Path:
    """A copy of tinyseg whose label of each sample NAME is ``relabel(NAME, label)``."""
    data = Path(shutil.copytree(TINYSEG, tmp_path / "data", ignore=shutil.ignore_patterns("data.py")))
    for name in NAMES:
        path = data / "labels" / f"{name}.png"
        Image.fromarray(relabel(name, np.asarray(Image.open(path))).astype(np.uint8), mode="L").save(path)
    return data


def labels(data: Path, names: list[str]) -> np.ndarray:
    return np.concatenate([np.asarray(Image.open(data / "labels" / f"{n}.png")).ravel() for n in names])


def log_rows(run: Path) -> list[dict[str, str]]:
    with (run / "log.csv").open(newline="") as f:
        return list(csv.DictReader(f))


# ------------------------------------------------------------------------ all-ignored batches
def test_a_batch_of_only_unlabeled_pixels_leaves_no_nan_in_the_log_or_the_weights(tmp_path: Path) -> None:
    """Half the images are unlabeled throughout; at batch size 1 each of their patches is a batch
    with nothing to learn (cross-entropy's mean over zero pixels is NaN)."""
    data = relabelled(tmp_path, lambda name, lab: np.zeros_like(lab) if NAMES.index(name) % 2 else lab)
    run = tmp_path / "run"
    result = osmseg("train", data, "--out", run, "--config", TINY, "--epochs", 2, "--batch-size", 1)
    assert result.exit_code == 0, result.output
    train = load_checkpoint(run / "last.pt")["splits"]["train"]
    assert any(NAMES.index(n) % 2 for n in train)  # unlabeled patches were trained on
    rows = log_rows(run)
    assert len(rows) == 2
    for row in rows:  # an epoch whose every batch was unlabeled has no loss: an empty cell, never NaN
        for key in ("train_loss", "val_loss"):
            assert row[key] == "" or math.isfinite(float(row[key])), row
    assert any(row["train_loss"] for row in rows) and all(row["val_loss"] for row in rows), rows
    weights = load_checkpoint(run / "last.pt")["model"]
    assert all(torch.isfinite(w).all() for w in weights.values() if w.is_floating_point())


def test_an_unlabeled_batch_changes_nothing_but_the_schedule() -> None:
    """One epoch of [labelled batch] and one of [labelled batch, unlabeled batch], from the same
    start with SGD + momentum + weight decay: the same weights, BatchNorm statistics and loss
    (a step with a zero gradient would still have moved them), and the schedule counted both."""
    torch.manual_seed(0)
    images = torch.randn(2, 3, 64, 80)
    labelled = torch.randint(0, 5, (2, 64, 80))
    unlabeled = torch.zeros(2, 64, 80, dtype=torch.int64)
    start = SegNet(num_classes=5, width=0.0625)
    runs = []
    for loader in ([(images, labelled)], [(images, labelled), (images.flip(-1), unlabeled)]):
        model = copy.deepcopy(start)
        optimizer = torch.optim.SGD(model.parameters(), lr=0.1, momentum=0.9, weight_decay=5e-4)
        scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda step: 1.0 / (1 + step))
        scaler = torch.amp.GradScaler("cpu", enabled=False)
        loss = train_one_epoch(model, torch.nn.CrossEntropyLoss(ignore_index=0), optimizer, scheduler, scaler,
                               loader, StepOptions(device=torch.device("cpu")), epoch=1)
        runs.append((loss, model.state_dict(), scheduler.last_epoch))
    (loss_a, state_a, steps_a), (loss_b, state_b, steps_b) = runs
    assert loss_a is not None and math.isfinite(loss_a) and loss_b == loss_a
    assert all(torch.equal(state_a[k], state_b[k]) for k in state_a)
    assert (steps_a, steps_b) == (1, 2)


def test_an_unlabeled_first_batch_raises_no_scheduler_warning() -> None:
    """The schedule counts a skipped batch; PyTorch's "lr_scheduler.step() before optimizer.step()"
    warning (a misuse it guesses at) would only alarm a user whose first crop fell in an OSM gap."""
    import warnings

    torch.manual_seed(0)
    model = SegNet(num_classes=5, width=0.0625)
    optimizer = torch.optim.SGD(model.parameters(), lr=0.1)
    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda step: 1.0 / (1 + step))
    loader = [(torch.randn(2, 3, 64, 80), torch.zeros(2, 64, 80, dtype=torch.int64)),
              (torch.randn(2, 3, 64, 80), torch.randint(1, 5, (2, 64, 80)))]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        loss = train_one_epoch(model, torch.nn.CrossEntropyLoss(ignore_index=0), optimizer, scheduler,
                               torch.amp.GradScaler("cpu", enabled=False), loader,
                               StepOptions(device=torch.device("cpu")), epoch=1)
    assert loss is not None and math.isfinite(loss) and scheduler.last_epoch == 2


# ---------------------------------------------------------------------------- one class only
def test_labels_of_one_class_train_a_binary_model_whose_background_is_scored(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Building footprints only (all else unlabeled): the run trains building against unlabeled as
    background, says so once, records it (spec.ignore_index None) and scores both classes;
    before, validation saw building pixels only and reported mIoU 1.0."""
    data = relabelled(tmp_path, lambda name, lab: np.where(lab == 1, 1, 0))
    run = tmp_path / "run"
    with caplog.at_level(logging.WARNING):
        result = osmseg("train", data, "--out", run, "--config", TINY, "--epochs", 2)
    assert result.exit_code == 0, result.output
    warned = [r.getMessage() for r in caplog.records if "one class besides" in r.getMessage()]
    assert len(warned) == 1, warned
    assert "'building'" in warned[0] and "background" in warned[0] and "--keep-unlabeled" in warned[0]

    last = load_checkpoint(run / "last.pt")
    assert last["spec"]["ignore_index"] is None
    val = last["splits"]["val"]
    truth = labels(data, val)
    metrics = last["val_metrics"]
    assert metrics["num_pixels"] == truth.size  # every validation pixel scored, unlabeled ones too
    background = metrics["per_class"]["unlabeled"]
    assert "ignored" not in background and background["iou"] is not None
    assert background["support"] == int(np.count_nonzero(truth == 0)) > 0
    assert metrics["per_class"]["building"]["support"] == int(np.count_nonzero(truth == 1)) > 0
    assert metrics["classes_present"] == 2
    for row in log_rows(run):
        assert float(row["val_miou"]) < 1 and float(row["val_pixel_accuracy"]) < 1, row

    # eval reads the same from the checkpoint: the test images' every pixel, both classes
    out = tmp_path / "eval"
    assert osmseg("eval", run / "best.pt", data, "--out", out).exit_code == 0
    evaluated = json.loads((out / "metrics.json").read_text())
    test = labels(data, last["splits"]["test"])
    assert evaluated["num_pixels"] == test.size
    assert evaluated["per_class"]["unlabeled"]["support"] == int(np.count_nonzero(test == 0))
    assert evaluated["miou"] < 1


def test_keep_unlabeled_on_one_class_is_the_same_model_without_the_warning(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    data = relabelled(tmp_path, lambda name, lab: np.where(lab == 1, 1, 0))
    with caplog.at_level(logging.WARNING):
        result = osmseg("train", data, "--out", tmp_path / "run", "--config", TINY, "--epochs", 1,
                        "--max-steps-per-epoch", 1, "--keep-unlabeled")
    assert result.exit_code == 0, result.output
    assert not [r for r in caplog.records if "one class besides" in r.getMessage()]
    assert load_checkpoint(tmp_path / "run" / "last.pt")["spec"]["ignore_index"] is None


def test_labels_without_any_class_are_refused_before_anything_is_written(tmp_path: Path) -> None:
    data = relabelled(tmp_path, lambda name, lab: np.zeros_like(lab))
    result = osmseg("train", data, "--out", tmp_path / "run", "--config", TINY, "--epochs", 1)
    assert result.exit_code == 1 and "Traceback" not in result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error: ")]
    assert len(errors) == 1 and "no pixel of any class but 'unlabeled'" in errors[0]
    assert not (tmp_path / "run").exists()


@pytest.mark.shared_data
def test_airsegnet6_on_a_kampala_build_of_buildings_only_is_binary(tmp_path: Path) -> None:
    """The issue's case: AirSegNet6 on real drone imagery with OSM building footprints only."""
    from test_real_build import centre_bbox

    root = shared_path("kampala-oam")
    data = tmp_path / "kampala"
    built = osmseg("build", "--bbox", centre_bbox(), "--zoom", "21", "--samples", "4", "--seed", "5",
                   "--imagery", f"xyz:file://{root}/tiles/OAM-{{x}}-{{y}}-{{z}}.png",
                   "--osm", f"geojson:{root}/osm-buildings.geojson:building=yes", "--min-classes", "1",
                   "--max-unlabeled", "0.99", "--max-missing-imagery", "0.01", "--cache-dir", tmp_path / "cache",
                   "--out", data)
    assert built.exit_code == 0, built.output
    run = tmp_path / "run"
    result = osmseg("train", data, "--out", run, "--model", "airsegnet6", "--width", 0.0625, "--epochs", 1,
                    "--split-by", "image", "--max-steps-per-epoch", 2, "--loader-workers", 0, "--device", "cpu")
    assert result.exit_code == 0, result.output
    last = load_checkpoint(run / "last.pt")
    assert last["spec"]["ignore_index"] is None
    metrics = last["val_metrics"]
    # validation sees each 1280x1280 sample's six 360x480 patches: its centred 1080x960 part
    truth = np.concatenate([np.asarray(Image.open(data / "labels" / f"{n}.png"))[100:1180, 160:1120].ravel()
                            for n in last["splits"]["val"]])
    assert metrics["num_pixels"] == truth.size  # every pixel scored, none masked
    assert metrics["per_class"]["unlabeled"]["support"] == int(np.count_nonzero(truth == 0)) > 0
    assert metrics["per_class"]["building"]["support"] == int(np.count_nonzero(truth == 1)) > 0
    assert metrics["miou"] < 1


# -------------------------------------------------------------------------------------- splits
def shares(data: Path, names: list[str]) -> np.ndarray:
    """Class shares of the labelled pixels of ``names``, counted from the PNGs."""
    counts = np.bincount(labels(data, names), minlength=5)[1:].astype(float)
    return counts / counts.sum()


def test_the_split_keeps_the_draw_whose_validation_looks_like_training(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Two images are all water; the seed's own draw validates on one of them (100 % water against
    training's few %). The run keeps another of 16 seeded draws, closer to training's class mix,
    records which and the class shares, and the recorded draw seed reproduces it."""
    watery = NAMES[3], NAMES[8]
    data = relabelled(tmp_path, lambda name, lab: np.full_like(lab, 4) if name in watery else lab)
    seed = next(s for s in range(100) if make_splits(NAMES, s)["val"][0] in watery)
    naive = make_splits(NAMES, seed)
    naive_distance = np.abs(shares(data, naive["val"]) - shares(data, naive["train"])).sum() / 2
    assert naive_distance > 0.5  # the seed's own draw is unrepresentative

    run = tmp_path / "run"
    with caplog.at_level(logging.WARNING):
        result = osmseg("train", data, "--out", run, "--config", TINY, "--epochs", 1, "--max-steps-per-epoch", 1,
                        "--seed", seed)
    assert result.exit_code == 0, result.output
    doc = json.loads((run / "splits.json").read_text())
    splits, selection = doc["splits"], doc["selection"]
    assert splits["val"][0] not in watery and splits != naive
    assert selection["candidates"] == 16 and selection["draw"] > 0
    assert make_splits(NAMES, selection["draw_seed"]) == splits
    distance = np.abs(shares(data, splits["val"]) - shares(data, splits["train"])).sum() / 2
    assert selection["val_train_distance"] == pytest.approx(distance, abs=1e-6)
    assert selection["first_draw_distance"] == pytest.approx(naive_distance, abs=1e-6)
    assert distance < 0.25 < naive_distance
    for split in ("train", "val", "test"):
        recorded = doc["class_shares"][split]
        assert set(recorded) == set(CLASS_NAMES[1:])  # unlabeled is ignored: no share
        assert [recorded[c] for c in CLASS_NAMES[1:]] == pytest.approx(shares(data, splits[split]), abs=1e-5)
    assert not [r for r in caplog.records if "does not represent" in r.getMessage()]
    assert load_checkpoint(run / "last.pt")["splits"] == splits


def test_a_validation_that_cannot_represent_training_is_reported(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Every image is all building or all water, and validation is one image: whichever it is,
    it lacks the other class. The run warns once, naming it."""
    data = relabelled(tmp_path, lambda name, lab: np.full_like(lab, 1 if NAMES.index(name) % 2 else 4))
    run = tmp_path / "run"
    with caplog.at_level(logging.WARNING):
        result = osmseg("train", data, "--out", run, "--config", TINY, "--epochs", 1, "--max-steps-per-epoch", 1)
    assert result.exit_code == 0, result.output
    warned = [r.getMessage() for r in caplog.records if "does not represent" in r.getMessage()]
    assert len(warned) == 1, warned
    doc = json.loads((run / "splits.json").read_text())
    val_class = "building" if doc["class_shares"]["val"]["building"] else "water"
    other = "water" if val_class == "building" else "building"
    assert f"it lacks '{other}'" in warned[0] and "validation (1 image)" in warned[0]
    assert doc["selection"]["missing_in_val"] == [other]
