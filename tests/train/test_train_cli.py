"""``osmseg train``, ``eval`` and ``predict`` through the real command line on the CPU.

The trainer is tested the way a user runs it (torchgeo style): a YAML config checked in beside
the tests (``tests/data/train/*.yaml``) plus command-line overrides, on the tiny learnable
dataset ``tests/data/tinyseg`` (12 images of 128x160, 5 classes). In-process runs go through
click's CliRunner with one torch thread; the runs that must be separate processes (a run
killed with SIGKILL and resumed, two processes under torchrun) use ``python -m osmseg`` with
``OMP_NUM_THREADS=1``, so that in-process and subprocess runs compute in the same order.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result
from PIL import Image

torch = pytest.importorskip("torch")

from conftest import TEST_DATA  # noqa: E402

from osmseg.cli.main import cli  # noqa: E402
from training.models.checkpoint import load_checkpoint  # noqa: E402

TINYSEG = TEST_DATA / "tinyseg"
CONFIGS = TEST_DATA / "train"
NAMES = sorted(p.stem for p in (TINYSEG / "images").glob("*.png"))
EPOCHS = 3  # tiny.yaml says 5: every run here overrides it with --epochs
RUN_FILES = {"model.pt", "best.pt", "last.pt", "log.csv", "curves.png", "splits.json"}


@pytest.fixture(scope="module", autouse=True)
def one_thread() -> Iterator[None]:
    """One torch thread in this process, as OMP_NUM_THREADS=1 gives the subprocesses."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def osmseg(*args: object) -> Result:
    """Run ``osmseg ARGS`` in this process."""
    return CliRunner().invoke(cli, ["-q", *(str(a) for a in args)])


def train_args(out: Path, *extra: object) -> list[object]:
    return ["train", TINYSEG, "--out", out, "--config", CONFIGS / "tiny.yaml", "--epochs", EPOCHS, *extra]


def subprocess_env() -> dict[str, str]:
    return dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")


def error_line(result: Result) -> str:
    """The one ``Error: ...`` line a failed command printed (and no traceback)."""
    assert isinstance(result.exception, SystemExit), result.exception
    assert "Traceback" not in result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error: ")]
    assert len(errors) == 1, result.output
    return errors[0]


def label(name: str, root: Path = TINYSEG) -> np.ndarray:
    return np.asarray(Image.open(root / "labels" / f"{name}.png"))


def labelled_pixels(names: list[str]) -> int:
    """Pixels of these tinyseg images that are not unlabeled (0, ignored in the metrics)."""
    return sum(int(np.count_nonzero(label(n))) for n in names)


def log_rows(run: Path) -> list[dict[str, str]]:
    with (run / "log.csv").open(newline="") as f:
        return list(csv.DictReader(f))


def tree_bytes(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def copy_tinyseg(tmp_path: Path) -> Path:
    return Path(shutil.copytree(TINYSEG, tmp_path / "tinyseg", ignore=shutil.ignore_patterns("data.py")))


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Result]:
    """One uninterrupted 3-epoch run (the reference of the resume test too)."""
    run = tmp_path_factory.mktemp("train") / "run"
    result = osmseg(*train_args(run))
    assert result.exit_code == 0, result.output
    return run, result


# ------------------------------------------------------------------------------ end to end
def test_train_writes_a_complete_run_and_the_command_line_wins_over_the_file(trained: tuple[Path, Result]) -> None:
    run, result = trained
    assert {p.name for p in run.iterdir()} == RUN_FILES  # and no temp files left behind
    assert json.loads(result.stdout.strip().splitlines()[-1]) == {
        "model": str(run / "model.pt"), "best": str(run / "best.pt"), "last": str(run / "last.pt"),
        "log": str(run / "log.csv")}

    rows = log_rows(run)
    assert [int(r["epoch"]) for r in rows] == list(range(1, EPOCHS + 1))  # --epochs 3 beat the file's 5
    last = load_checkpoint(run / "last.pt")
    assert last["epoch"] == EPOCHS and len(last["history"]) == EPOCHS
    assert last["config"]["epochs"] == EPOCHS and last["config"]["width"] == 0.125  # the rest from the file
    assert last["spec"]["num_classes"] == 5 and last["spec"]["input_size"] == (64, 80)
    assert [float(r["train_loss"]) for r in rows] == [h["train_loss"] for h in last["history"]]

    handed = load_checkpoint(run / "model.pt")  # the default recipe keeps no average: the final weights
    assert handed["epoch"] == EPOCHS and "optimizer" not in handed and "final weights" in handed["checkpoint_choice"]
    assert all(torch.equal(handed["model"][k], last["model"][k]) for k in last["model"])

    best = load_checkpoint(run / "best.pt")
    best_miou = max(float(r["val_miou"]) for r in rows)
    assert best["history"][-1]["val_miou"] == best_miou == best["val_metrics"]["miou"]

    splits = json.loads((run / "splits.json").read_text())["splits"]
    assert splits == last["splits"]
    groups = [set(splits[k]) for k in ("train", "val", "test")]
    assert all(groups) and sum(map(len, groups)) == len(set().union(*groups))  # disjoint by image
    assert set().union(*groups) == set(NAMES)  # and cover the dataset
    with Image.open(run / "curves.png") as im:
        assert im.format == "PNG" and im.width > 100


def test_eval_reports_on_the_test_split_it_was_trained_with(trained: tuple[Path, Result], tmp_path: Path) -> None:
    run, _ = trained
    out = tmp_path / "eval"
    result = osmseg("eval", run / "best.pt", TINYSEG, "--out", out)
    assert result.exit_code == 0, result.output
    assert result.stdout.strip() == str(out / "metrics.json")
    assert {"metrics.json", "metrics.txt", "confusion_matrix.png", "panels.png"} <= {p.name for p in out.iterdir()}

    metrics = json.loads((out / "metrics.json").read_text())
    test_names = load_checkpoint(run / "best.pt")["splits"]["test"]
    which = metrics["evaluated"]["images"]
    assert "'test' split" in which and f"({len(test_names)} images)" in which
    matrix = np.array(metrics["confusion_matrix"])
    assert matrix.shape == (5, 5)
    assert matrix.sum() == metrics["num_pixels"] == labelled_pixels(test_names)  # whole test images, 0 ignored
    assert set(metrics["per_class"]) == {"unlabeled", "building", "highway", "grass", "water"}
    grass = metrics["per_class"]["grass"]
    assert grass["support"] == matrix[3].sum() and grass["iou"] == pytest.approx(
        matrix[3, 3] / (matrix[3].sum() + matrix[:, 3].sum() - matrix[3, 3]))
    assert 0 <= metrics["miou"] <= 1
    assert "mIoU" in (out / "metrics.txt").read_text()
    for picture in ("confusion_matrix.png", "panels.png", "per_class_iou.png", "curves.png"):
        with Image.open(out / picture) as im:
            assert im.format == "PNG" and min(im.size) > 100

    # eval's matrix is the one the masks `osmseg predict` writes give, image by image
    images = [TINYSEG / "images" / f"{n}.png" for n in test_names]
    assert osmseg("predict", run / "best.pt", *images, "--out", tmp_path / "pred").exit_code == 0
    recount = np.zeros((5, 5), dtype=np.int64)
    for n in test_names:
        truth, pred = label(n).ravel(), np.asarray(Image.open(tmp_path / "pred" / f"{n}.png")).ravel()
        keep = truth != 0
        np.add.at(recount, (truth[keep], pred[keep]), 1)
    assert recount.tolist() == metrics["confusion_matrix"]


def test_eval_curves_show_the_whole_run_or_say_where_they_stop(trained: tuple[Path, Result], tmp_path: Path) -> None:
    """The demo's eval/curves.png stopped at epoch 6 of 8 and said nothing of it: it was drawn from
    the history best.pt holds, while the run's own curves.png showed all 8 epochs. With the run's
    log.csv beside the checkpoint it draws the whole run; without it, it says it stops at the
    checkpoint's epoch; either way the checkpoint's epoch is marked."""
    from training.evaluation.figures import checkpoint_curves

    run, _ = trained
    best = load_checkpoint(run / "best.pt")
    epoch = best["epoch"]
    assert 1 <= epoch <= EPOCHS and len(best["history"]) == epoch
    rows, title, mark = checkpoint_curves(best, run / "best.pt")
    assert [r["epoch"] for r in rows] == list(range(1, EPOCHS + 1))  # the whole run, from its log.csv
    assert f"log.csv beside best.pt): epochs 1–{EPOCHS} of {EPOCHS} planned; best.pt is epoch {epoch}" in title
    assert mark == (epoch, f"best.pt: epoch {epoch} (evaluated)")

    alone = tmp_path / "alone"  # best.pt copied away from its run
    alone.mkdir()
    shutil.copy(run / "best.pt", alone / "best.pt")
    rows, title, mark = checkpoint_curves(best, alone / "best.pt")
    assert [r["epoch"] for r in rows] == list(range(1, epoch + 1))
    assert title.startswith(f"Training history stored in best.pt: epochs 1–{epoch} of {EPOCHS} planned, up to the "
                            "checkpoint's epoch")
    assert mark[0] == epoch

    other = log_rows(run)  # beside it, the log of another run (other losses): not taken for its own
    other[0]["train_loss"] = str(float(other[0]["train_loss"]) + 0.5)
    with (alone / "log.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(other[0]))
        writer.writeheader()
        writer.writerows(other)
    rows, title, _ = checkpoint_curves(best, alone / "best.pt")
    assert len(rows) == epoch and title.startswith("Training history stored in best.pt")


def test_eval_names_every_number_by_class_id_not_by_list_position(tmp_path: Path) -> None:
    """A class table listed out of id order (as classes13.toml lists dirt road, id 12, second):
    each class's support in metrics.json/metrics.txt is its own pixel count in the labels."""
    data = copy_tinyseg(tmp_path)
    manifest = json.loads((data / "manifest.json").read_text())
    listed = manifest["classes"]["classes"]
    manifest["classes"]["classes"] = [listed[i] for i in (3, 0, 4, 2, 1)]  # grass, unlabeled, water, ...
    (data / "manifest.json").write_text(json.dumps(manifest))
    run = tmp_path / "run"
    assert osmseg("train", data, "--out", run, "--config", CONFIGS / "tiny.yaml", "--epochs", 1).exit_code == 0
    result = osmseg("eval", run / "best.pt", data, "--split", "all", "--out", tmp_path / "eval")
    assert result.exit_code == 0, result.output

    metrics = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    pixels = np.bincount(np.concatenate([label(n, data).ravel() for n in NAMES]), minlength=5)
    table = metrics
    for entry in listed:  # looked up by id and name, independently of any list order
        reported = table["per_class"][entry["name"]]
        assert reported["id"] == entry["id"]
        expected = 0 if entry["id"] == 0 else int(pixels[entry["id"]])  # unlabeled is ignored
        assert reported["support"] == expected, entry["name"]
        assert np.array(table["confusion_matrix"])[entry["id"]].sum() == expected
    assert table["class_names"] == ["unlabeled", "building", "highway", "grass", "water"]
    text = (tmp_path / "eval" / "metrics.txt").read_text().splitlines()
    water = next(line for line in text if line.startswith("water "))
    assert water.split()[-1].replace(",", "") == str(pixels[4])
    # validation during training names its numbers by id too
    history = load_checkpoint(run / "best.pt")["val_metrics"]
    assert history["class_names"] == table["class_names"]


def test_predict_writes_a_mask_of_the_input_size_in_the_model_classes(trained: tuple[Path, Result],
                                                                     tmp_path: Path) -> None:
    run, _ = trained
    src = TINYSEG / "images" / "tinyseg_000.png"
    result = osmseg("predict", run / "best.pt", src, "--out", tmp_path)
    assert result.exit_code == 0, result.output
    assert result.stdout.strip() == str(tmp_path / "tinyseg_000.png")
    with Image.open(tmp_path / "tinyseg_000.png") as im:
        assert im.size == (160, 128) and im.mode in ("L", "P")
        mask = np.asarray(im)
    assert set(np.unique(mask)) <= {1, 2, 3, 4}  # the model's classes; 0 (ignored in training) never
    with Image.open(tmp_path / "tinyseg_000_color.png") as im:
        assert im.size == (160, 128)
        colour = np.asarray(im.convert("RGB"))
    table = json.loads((TINYSEG / "manifest.json").read_text())["classes"]["classes"]
    palette = np.zeros((256, 3), dtype=np.uint8)
    for c in table:
        palette[c["id"]] = c["color"]
    assert np.array_equal(colour, palette[mask])


def test_predict_compares_the_input_resolution_with_the_training_data_and_resamples_on_request(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """A checkpoint records its training resolution (0.3 m here); a 0.9 m GeoTIFF gets a warning
    without --resolution, and --resolution model predicts at 0.3 m and writes the mask on the
    input's own grid. GeoTIFF inputs give NAME.tif and NAME_color.tif, as --help says."""
    import rasterio
    from rasterio.transform import from_origin

    data = copy_tinyseg(tmp_path)
    manifest = json.loads((data / "manifest.json").read_text())
    for sample in manifest["samples"]:
        sample["ground_resolution_m"] = 0.3
    (data / "manifest.json").write_text(json.dumps(manifest))
    run = tmp_path / "run"
    assert osmseg("train", data, "--out", run, "--config", CONFIGS / "tiny.yaml", "--epochs", 1).exit_code == 0
    assert load_checkpoint(run / "best.pt")["spec"]["resolution_m"] == 0.3

    rgb = np.asarray(Image.open(TINYSEG / "images" / "tinyseg_000.png").convert("RGB"))
    src = tmp_path / "coarse.tif"
    with rasterio.open(src, "w", driver="GTiff", width=160, height=128, count=3, dtype="uint8",
                       crs="EPSG:32633", transform=from_origin(400000, 5800000, 0.9, 0.9)) as dst:
        dst.write(rgb.transpose(2, 0, 1))
    with caplog.at_level("WARNING"):
        plain = osmseg("predict", run / "best.pt", src, "--out", tmp_path / "plain")
    assert plain.exit_code == 0, plain.output
    warned = [r.getMessage() for r in caplog.records if "trained on" in r.getMessage()]
    assert len(warned) == 1 and "0.9 m pixels" in warned[0] and "--resolution model" in warned[0]
    assert sorted(p.name for p in (tmp_path / "plain").iterdir()) == ["coarse.qml", "coarse.tif", "coarse_color.tif"]

    caplog.clear()
    with caplog.at_level("WARNING"):
        resampled = osmseg("predict", run / "best.pt", src, "--resolution", "model", "--out", tmp_path / "fine")
    assert resampled.exit_code == 0, resampled.output
    assert not [r for r in caplog.records if "trained on" in r.getMessage()]
    with rasterio.open(tmp_path / "fine" / "coarse.tif") as mask, rasterio.open(src) as image:
        assert (mask.width, mask.height) == (160, 128) and mask.transform == image.transform
    bad = osmseg("predict", run / "best.pt", src, "--resolution", "fine", "--out", tmp_path / "bad")
    assert bad.exit_code == 2 and "'model'" in bad.output


@pytest.mark.slow  # make test-slow: 25 s of training; test_training_learns_tinyseg learns in make test
# ---------------------------------------------------------------------------- learnability
def test_the_default_recipe_learns_tinyseg_well_above_the_majority_class(tmp_path: Path) -> None:
    """The default recipe (random crops, AdamW, cosine decay) from random weights, 200 steps
    of 16 crops: the test images' pixel accuracy well above always answering their commonest
    class, and no loss that is not a number."""
    result = osmseg("train", TINYSEG, "--out", tmp_path / "run", "--config", CONFIGS / "tiny.yaml",
                    "--epochs", 10, "--steps-per-epoch", 20, "--batch-size", 16)
    assert result.exit_code == 0, result.output
    rows = log_rows(tmp_path / "run")
    assert all(np.isfinite(float(r[k])) for r in rows for k in ("train_loss", "val_loss")), rows
    assert float(rows[-1]["train_loss"]) < 0.5 * float(rows[0]["train_loss"]), rows
    result = osmseg("eval", tmp_path / "run" / "best.pt", TINYSEG, "--out", tmp_path / "eval")
    assert result.exit_code == 0, result.output
    test = json.loads((tmp_path / "run" / "splits.json").read_text())["splits"]["test"]
    labels = np.concatenate([label(n).ravel() for n in test])
    labels = labels[labels != 0]  # unlabeled is ignored in the metrics
    majority = np.bincount(labels).max() / labels.size
    accuracy = json.loads((tmp_path / "eval" / "metrics.json").read_text())["pixel_accuracy"]
    assert accuracy > majority + 0.25 * (1 - majority), (accuracy, majority)  # measured: 0.93 vs majority 0.82


def test_training_learns_tinyseg(tmp_path: Path) -> None:
    """SegNet from random weights learns tinyseg's colour-coded classes in 12 short epochs by
    the dissertation's recipe (``recipe: paper`` in learn.yaml).

    (With learn.yaml and one thread: train loss 1.76 -> 0.45, val mIoU 0.03 -> 0.54.)
    """
    result = osmseg("train", TINYSEG, "--out", tmp_path / "run", "--config", CONFIGS / "learn.yaml")
    assert result.exit_code == 0, result.output
    rows = log_rows(tmp_path / "run")
    loss = [float(r["train_loss"]) for r in rows]
    miou = [float(r["val_miou"]) for r in rows]
    assert len(rows) == 12
    assert loss[-1] < 0.5 * loss[0], loss
    assert max(miou) > miou[0] + 0.25 and max(miou) > 0.4, miou


# ---------------------------------------------------------------------------------- resume
def test_a_killed_run_resumes_to_the_same_weights(trained: tuple[Path, Result], tmp_path: Path) -> None:
    """SIGKILL after epoch 1, rerun the same command: the same weights as the uninterrupted run."""
    reference, _ = trained
    run = tmp_path / "run"
    command = [sys.executable, "-m", "osmseg", "-q", *(str(a) for a in train_args(run))]
    log = tmp_path / "stderr.txt"
    with log.open("wb") as stderr:  # a file, not a pipe: progress bars cannot fill it and block the run
        proc = subprocess.Popen(command, env=subprocess_env(), stdout=subprocess.DEVNULL, stderr=stderr, cwd=tmp_path)
    killed_after = None
    deadline = time.monotonic() + 120
    try:
        while proc.poll() is None and time.monotonic() < deadline:
            if (run / "last.pt").exists() and (epoch := load_checkpoint(run / "last.pt")["epoch"]) >= 1:
                proc.send_signal(signal.SIGKILL)
                killed_after = epoch
                break
            time.sleep(0.02)
    finally:
        proc.kill()
        proc.wait()
    assert killed_after is not None, f"the run ended before epoch 1 was saved: {log.read_text()[-500:]}"
    assert proc.returncode == -signal.SIGKILL
    assert load_checkpoint(run / "last.pt")["epoch"] == killed_after < EPOCHS  # it really was interrupted

    loud = [c for c in command if c != "-q"] + ["--no-progress"]  # the rerun says it resumes (not with -q)
    finish = subprocess.run(loud, env=subprocess_env(), capture_output=True, cwd=tmp_path, timeout=300)
    assert finish.returncode == 0, finish.stderr.decode()[-2000:]
    said = [line for line in finish.stderr.decode().splitlines() if not line.startswith("WARNING")]
    assert said[0] == f"resuming {run} after epoch {killed_after} of {EPOCHS}", said  # once, before anything else
    assert sum("resuming" in line for line in said) == 1 and said[1].startswith("final epoch "), said

    a, b = load_checkpoint(reference / "last.pt"), load_checkpoint(run / "last.pt")
    assert b["epoch"] == EPOCHS
    assert a["model"].keys() == b["model"].keys()
    different = [k for k in a["model"] if not torch.equal(a["model"][k], b["model"][k])]
    assert not different, f"{len(different)} tensors differ, e.g. {different[:3]}"
    assert a["scheduler"] == b["scheduler"]
    state_a = [(k, v) for s in a["optimizer"]["state"].values() for k, v in sorted(s.items())]  # AdamW's moments
    state_b = [(k, v) for s in b["optimizer"]["state"].values() for k, v in sorted(s.items())]
    assert [k for k, _ in state_a] == [k for k, _ in state_b] and any(k == "exp_avg" for k, _ in state_a)
    assert all(torch.equal(x, y) for (_, x), (_, y) in zip(state_a, state_b, strict=True))

    def scores(history: list[dict]) -> list[tuple]:
        return [(h["epoch"], h["lr"], h["train_loss"], h["val_loss"], h["val_miou"]) for h in history]

    assert scores(b["history"]) == scores(a["history"])
    assert [(r["epoch"], r["train_loss"], r["val_miou"]) for r in log_rows(run)] == \
        [(r["epoch"], r["train_loss"], r["val_miou"]) for r in log_rows(reference)]
    assert (run / "splits.json").read_bytes() == (reference / "splits.json").read_bytes()
    best_a, best_b = load_checkpoint(reference / "best.pt"), load_checkpoint(run / "best.pt")
    assert best_a["epoch"] == best_b["epoch"]
    assert all(torch.equal(best_a["model"][k], best_b["model"][k]) for k in best_a["model"])


# --------------------------------------------------------------------------------- torchrun
def test_torchrun_two_cpu_processes_write_once_and_reduce_metrics(tmp_path: Path) -> None:
    """DDP on the CPU (gloo): one set of files, validation metrics summed over both processes.

    ddp.yaml uses whole images as patches, so the validation set is one patch: process 0
    validates it and process 1 nothing. A padding sampler would count it twice.
    """
    run = tmp_path / "run"
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2",
               "-m", "osmseg", "-q", "train", str(TINYSEG), "--out", str(run), "--config", str(CONFIGS / "ddp.yaml"),
               "--max-steps-per-epoch", "2"]
    done = subprocess.run(command, env=subprocess_env(), capture_output=True, cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stderr.decode()[-3000:]
    assert done.stdout.decode().count('"last"') == 1  # only rank 0 reports

    assert {p.name for p in run.iterdir()} == RUN_FILES  # no duplicate or temp files
    rows = log_rows(run)
    assert [int(r["epoch"]) for r in rows] == [1, 2]
    last = load_checkpoint(run / "last.pt")
    assert last["epoch"] == 2 and last["config"]["max_steps_per_epoch"] == 2
    assert not any(k.startswith("module.") for k in last["model"])  # the plain model, not the DDP wrapper
    val = last["splits"]["val"]
    assert len(val) % 2 == 1  # an odd number of validation patches (one per image)
    matrix = np.array(last["val_metrics"]["confusion_matrix"])
    assert matrix.sum() == labelled_pixels(val)  # each validation pixel counted once, over both ranks
    assert [round(h["val_miou"], 12) for h in last["history"]] == [round(float(r["val_miou"]), 12) for r in rows]

    # A whole image is one window, so `osmseg eval` in one process sees what validation saw.
    result = osmseg("eval", run / "best.pt", TINYSEG, "--split", "val", "--out", tmp_path / "eval")
    assert result.exit_code == 0, result.output
    metrics = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    best = load_checkpoint(run / "best.pt")
    assert metrics["confusion_matrix"] == best["val_metrics"]["confusion_matrix"]
    assert metrics["miou"] == pytest.approx(best["val_metrics"]["miou"])


# -------------------------------------------------------------------------------- bad input
def test_missing_dataset_is_a_usage_error(tmp_path: Path) -> None:
    result = osmseg("train", tmp_path / "nowhere", "--out", tmp_path / "run", "--config", CONFIGS / "tiny.yaml")
    assert result.exit_code == 2
    assert "nowhere" in result.output and "does not exist" in result.output
    assert not (tmp_path / "run").exists()


def test_label_of_another_size_names_the_file(tmp_path: Path) -> None:
    data = copy_tinyseg(tmp_path)
    Image.fromarray(label("tinyseg_003")[:100]).save(data / "labels" / "tinyseg_003.png")
    result = osmseg("train", data, "--out", tmp_path / "run", "--config", CONFIGS / "tiny.yaml")
    assert result.exit_code == 1
    line = error_line(result)
    assert "labels/tinyseg_003.png" in line and "160x100" in line and "160x128" in line
    assert not (tmp_path / "run").exists()  # nothing written


def test_label_with_unknown_class_ids_names_the_file_and_ids(tmp_path: Path) -> None:
    data = copy_tinyseg(tmp_path)
    broken = label("tinyseg_007").copy()
    broken[10:20, 10:20] = 9
    broken[40, 40] = 200
    Image.fromarray(broken).save(data / "labels" / "tinyseg_007.png")
    result = osmseg("train", data, "--out", tmp_path / "run", "--config", CONFIGS / "tiny.yaml")
    assert result.exit_code == 1
    line = error_line(result)
    assert "labels/tinyseg_007.png" in line and "9, 200" in line and "0..4" in line
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("damage", ["garbage", "truncated"])
def test_corrupt_checkpoint_is_refused_by_eval_and_predict(trained: tuple[Path, Result], tmp_path: Path,
                                                           damage: str) -> None:
    good = (trained[0] / "best.pt").read_bytes()
    bad = tmp_path / "model.pt"
    bad.write_bytes(b"not a checkpoint at all\n" * 10 if damage == "garbage" else good[: len(good) // 2])
    for args in (["eval", bad, TINYSEG, "--out", tmp_path / "eval"],
                 ["predict", bad, TINYSEG / "images" / "tinyseg_000.png", "--out", tmp_path / "pred"]):
        result = osmseg(*args)
        assert result.exit_code == 1, result.output
        assert "model.pt is not a checkpoint" in error_line(result)
    assert not (tmp_path / "eval").exists() and not (tmp_path / "pred").exists()


def test_model_without_a_class_table_is_a_usage_error(tmp_path: Path) -> None:
    data = copy_tinyseg(tmp_path)
    (data / "manifest.json").unlink()  # images/ and labels/ only: nothing says what the ids mean
    result = osmseg("train", data, "--out", tmp_path / "run", "--config", CONFIGS / "tiny.yaml", "--model", "mine")
    assert result.exit_code == 2
    assert "--model mine" in result.output and "--classes" in result.output and "Traceback" not in result.output
    # a preset's classes that are not the dataset's are refused too, before anything is written
    result = osmseg(*train_args(tmp_path / "run", "--model", "airsegnet13"))
    assert result.exit_code == 2
    assert "--model airsegnet13 predicts the classes of" in result.output and "'tinyseg'" in result.output
    assert not (tmp_path / "run").exists()


def test_config_file_with_an_unknown_setting_is_a_usage_error(tmp_path: Path) -> None:
    config = tmp_path / "typo.yaml"
    config.write_text((CONFIGS / "tiny.yaml").read_text() + "epochz: 3\n")
    result = osmseg("train", TINYSEG, "--out", tmp_path / "run", "--config", config)
    assert result.exit_code == 2
    assert "unknown settings ['epochz']" in result.output
    assert not (tmp_path / "run").exists()


def test_a_finished_run_run_again_says_it_has_nothing_to_do(trained: tuple[Path, Result], tmp_path: Path) -> None:
    run = Path(shutil.copytree(trained[0], tmp_path / "run"))
    result = CliRunner().invoke(cli, ["--no-progress", *(str(a) for a in train_args(run))])
    assert result.exit_code == 0, result.output
    said = [line for line in result.stderr.splitlines() if not line.startswith("WARNING")]
    assert said[0] == f"nothing to do: {run} has trained its {EPOCHS} epochs" and said[1].startswith("final epoch "), said
    assert osmseg(*train_args(run)).stderr == ""  # -q: nothing


def test_resuming_a_run_with_other_settings_is_refused_and_keeps_it(trained: tuple[Path, Result],
                                                                   tmp_path: Path) -> None:
    run = Path(shutil.copytree(trained[0], tmp_path / "run"))
    before = tree_bytes(run)
    result = osmseg(*train_args(run, "--lr", "0.05", "--seed", "3"))
    assert result.exit_code == 2
    assert "other settings (lr, seed)" in result.output and "use a new --out" in result.output
    assert tree_bytes(run) == before  # nothing lost, nothing added


def test_sigterm_to_the_process_group_ends_training_with_one_line(tmp_path: Path) -> None:
    """What ``timeout``, Slurm and ``kill -- -PGID`` do: the loader workers get the SIGTERM too, and
    must not die under the training process with torch's traceback about them."""
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "osmseg", "train", TINYSEG, "--out", out, "--config",
                             CONFIGS / "tiny.yaml", "--epochs", "200", "--loader-workers", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=subprocess_env(), start_new_session=True)
    deadline = time.monotonic() + 300
    while proc.poll() is None and time.monotonic() < deadline and not (out / "log.csv").exists():
        time.sleep(0.05)
    time.sleep(0.5)
    assert proc.poll() is None, proc.communicate()[1].decode()[-800:]
    os.killpg(proc.pid, signal.SIGTERM)
    _, stderr = proc.communicate(timeout=120)
    *progress, last = stderr.decode().splitlines()  # a log (stderr a pipe) has a line per finished epoch
    assert (proc.returncode, last) == (143, "terminated (SIGTERM): rerun the same command to resume; finished work is kept")
    assert all(line.startswith(("train: ", "epoch ")) for line in progress), progress


#: A loader worker whose tensors' hand-over (multiprocessing's resource sharer, which passes their file
#: descriptors) the training process drops mid-handshake, as it does when a SIGTERM to the process
#: group stops it there; then another error of a background thread.
DROPPED_HANDOVER = """
import os, socket, sys, threading
from multiprocessing import resource_sharer
from training.run.train import _loader_worker_start
_loader_worker_start(0)
df = resource_sharer.DupFd(os.pipe()[0])     # what pickling a batch's tensor does in a worker
address, _ = df._id
peer = socket.socket(socket.AF_UNIX)
peer.connect(address)
peer.close()                                 # the training process stopped mid-handshake
resource_sharer._resource_sharer._thread.join(timeout=1)  # the thread reports, and serves on
sys.excepthook(ValueError, ValueError("a real error"), None)
print("went on", flush=True)
"""


def test_a_handover_the_training_process_drops_as_it_stops_is_no_traceback_in_a_worker() -> None:
    """What failed once in a parallel suite's SIGTERM test: a traceback of the worker's resource-sharer
    thread under the one line (reproduced here without a race)."""
    done = subprocess.run([sys.executable, "-c", DROPPED_HANDOVER], capture_output=True, text=True,
                          env=subprocess_env(), timeout=120)
    assert done.returncode == 0 and done.stdout == "went on\n", done.stderr
    assert "resource_sharer" not in done.stderr and "Pipe" not in done.stderr, done.stderr
    assert "ValueError: a real error" in done.stderr  # other errors are still reported


#: Training whose progress callback stops it with an exception held in a reference cycle (its own
#: traceback passes through the frame that holds it), with the garbage collector off.
CYCLIC_STOP = """
import gc, sys
from pathlib import Path
from training.run.config import make_config
from training.run.train import run
gc.disable()
config = make_config(Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]), {"loader_workers": 2, "epochs": 3})

def progress(step):
    if step.task.endswith("validate"):
        stop = RuntimeError("stopped")  # a local that its traceback's frame holds: a cycle
        raise stop

try:
    run(config, progress)
except RuntimeError:
    print("stopped", flush=True)
"""


def test_training_stopped_by_an_exception_in_a_reference_cycle_still_exits(tmp_path: Path) -> None:
    """The loader workers ignore SIGTERM, so the exit handler that waits for child processes
    waits forever unless training ends them itself; a traceback caught in a cycle keeps the
    loader's iterator (whose end would end them) alive past that handler."""
    proc = subprocess.run([sys.executable, "-c", CYCLIC_STOP, TINYSEG, tmp_path / "run", CONFIGS / "tiny.yaml"],
                          capture_output=True, env=subprocess_env(), timeout=120)
    assert (proc.returncode, proc.stdout.decode()) == (0, "stopped\n"), proc.stderr.decode()[-800:]
