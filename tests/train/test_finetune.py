"""Fine-tuning (issue 19, item 6): ``osmseg train ... --init RUN/best.pt`` starts from a previous run.

Through the real command line on tinyseg: a tiny run A, then runs that start from A's
``best.pt`` on A's dataset and on a copy relabelled with another class table. With
``--max-steps-per-epoch 0`` a run takes no training step, so its ``last.pt`` holds exactly the
weights it started from (validation runs in eval mode and changes nothing).
"""

from __future__ import annotations

import hashlib
import json
import shutil
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
TINY = TEST_DATA / "train" / "tiny.yaml"
WIDTH = 0.0625


@pytest.fixture(scope="module", autouse=True)
def one_thread() -> Iterator[None]:
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def osmseg(*args: object) -> Result:
    return CliRunner().invoke(cli, ["-q", *(str(a) for a in args)])


def train(data: Path, out: Path, *extra: object) -> Result:
    return osmseg("train", data, "--out", out, "--config", TINY, "--width", WIDTH, "--epochs", 1, *extra)


@pytest.fixture(scope="module")
def run_a(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Run A: one epoch on tinyseg (5 classes)."""
    run = tmp_path_factory.mktemp("a") / "run"
    result = train(TINYSEG, run)
    assert result.exit_code == 0, result.output
    return run


@pytest.fixture(scope="module")
def three_classes(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Dataset B: tinyseg relabelled with a table of its own (unlabeled, building, ground)."""
    data = Path(shutil.copytree(TINYSEG, tmp_path_factory.mktemp("b") / "data",
                                ignore=shutil.ignore_patterns("data.py")))
    for path in (data / "labels").glob("*.png"):
        label = np.asarray(Image.open(path))
        Image.fromarray(np.select([label == 0, label == 1], [0, 1], 2).astype(np.uint8), mode="L").save(path)
    manifest = json.loads((data / "manifest.json").read_text())
    manifest["classes"] = {"name": "buildings-ground", "classes": [
        {"id": 0, "name": "unlabeled", "color": [0, 0, 0]}, {"id": 1, "name": "building", "color": [255, 0, 0]},
        {"id": 2, "name": "ground", "color": [0, 160, 0]}]}
    (data / "manifest.json").write_text(json.dumps(manifest))
    return data


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_fine_tuning_on_another_class_table_reuses_all_but_the_classifier(run_a: Path, three_classes: Path,
                                                                          tmp_path: Path) -> None:
    run = tmp_path / "run"
    result = train(three_classes, run, "--init", run_a / "best.pt", "--max-steps-per-epoch", 0)
    assert result.exit_code == 0, result.output
    a = load_checkpoint(run_a / "best.pt")["model"]
    b = load_checkpoint(run / "last.pt")
    assert b["spec"]["num_classes"] == 3
    body = [k for k in a if not k.startswith("classifier.")]
    assert any(k.startswith("encoder.") for k in body) and any(k.startswith("decoder.") for k in body)
    assert all(torch.equal(a[k], b["model"][k]) for k in body)  # encoder and decoder, BN statistics too
    assert a["classifier.weight"].shape[0] == 5 and b["model"]["classifier.weight"].shape[0] == 3
    init = b["init"]
    assert init["path"] == str((run_a / "best.pt").resolve()) and init["sha256"] == sha256(run_a / "best.pt")
    assert init["classes"] == "tinyseg" and "classifier starts afresh" in init["reused"]
    assert b["config"]["init"] == str(run_a / "best.pt")


def test_fine_tuning_on_the_same_classes_reuses_the_whole_network(run_a: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    result = train(TINYSEG, run, "--init", run_a / "last.pt", "--max-steps-per-epoch", 0)
    assert result.exit_code == 0, result.output
    a, b = load_checkpoint(run_a / "last.pt")["model"], load_checkpoint(run / "last.pt")
    assert a.keys() == b["model"].keys() and all(torch.equal(a[k], b["model"][k]) for k in a)
    assert b["init"]["reused"].startswith("the whole network")

    # resuming needs only the run: the start is in last.pt, the init file may be gone
    moved = Path(shutil.copytree(run_a, tmp_path / "a-copy"))
    again = train(TINYSEG, tmp_path / "run2", "--init", moved / "last.pt", "--max-steps-per-epoch", 0)
    assert again.exit_code == 0, again.output
    (moved / "last.pt").unlink()
    resumed = train(TINYSEG, tmp_path / "run2", "--init", moved / "last.pt", "--max-steps-per-epoch", 0)
    assert resumed.exit_code == 0, resumed.output
    assert load_checkpoint(tmp_path / "run2" / "last.pt")["init"]["sha256"] == sha256(run_a / "last.pt")


def test_fine_tuning_another_width_is_a_one_line_usage_error(run_a: Path, tmp_path: Path) -> None:
    result = osmseg("train", TINYSEG, "--out", tmp_path / "run", "--config", TINY, "--width", 0.125, "--epochs", 1,
                    "--init", run_a / "best.pt")
    assert result.exit_code == 2 and "Traceback" not in result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error: ")]
    assert len(errors) == 1, result.output
    assert "width-0.0625" in errors[0] and "--width 0.0625" in errors[0]
    assert not (tmp_path / "run").exists()  # refused before anything was written
    missing = osmseg("train", TINYSEG, "--out", tmp_path / "run", "--config", TINY, "--init", tmp_path / "nope.pt")
    assert missing.exit_code == 2 and "nope.pt: no such file" in missing.output
    assert not (tmp_path / "run").exists()
