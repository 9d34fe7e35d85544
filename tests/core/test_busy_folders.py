"""A folder a running build owns is refused by every command that reads it or writes into it.

Issue 31, item 4: the README says a command reading a dataset is refused while a build holds it,
but only ``verify`` was (through ``manifest.json``, which a first build writes last): ``train``
read 2 of 6 images and failed naming options it does not have, ``eval``, ``predict``,
``localize`` and ``localize-bench`` read half-written files. Here another process holds the
folder exactly as a running build does (:meth:`osmseg.builder.state.BuildState.claim`, the OS
lock of :mod:`osmseg.runtime.folderlock`), the folder holding what a first build has written so far
(images and labels, no manifest yet), and each command is run as a user runs it.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result
from conftest import REPO_ROOT, TEST_DATA
from PIL import Image

from osmseg.cli.main import cli

torch = pytest.importorskip("torch")

#: holds DATASET as ``osmseg build`` does until its stdin closes
HOLDER = """
import sys
from pathlib import Path
from osmseg.builder.state import BuildState
state = BuildState(Path(sys.argv[1]))
state.claim({"seed": 1}, "osmseg build --seed 1 --out " + sys.argv[1])
print("holding", flush=True)
sys.stdin.read()
"""


@pytest.fixture(scope="module")
def building(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, int]]:
    """``(dataset, pid)``: tinyseg as a first build leaves it midway (images and labels of its first
    samples, no manifest yet), held by process ``pid``. Module-scoped (one holding process, not one
    per command): every test checks that its command left the folder as it found it."""
    data = tmp_path_factory.mktemp("held") / "ds"
    for folder in ("images", "labels"):
        (data / folder).mkdir(parents=True)
        for name in ("tinyseg_000.png", "tinyseg_001.png"):
            shutil.copy(TEST_DATA / "tinyseg" / folder / name, data / folder / name)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO_ROOT), os.environ.get("PYTHONPATH", "")]))
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(data)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "holding"
        yield data, holder.pid
    finally:
        assert holder.stdin is not None
        holder.stdin.close()
        holder.wait(timeout=60)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A tiny checkpoint of tinyseg's classes and a ground panorama mask (classes13, sky 14)."""
    import json

    from training.models.checkpoint import save_checkpoint
    from training.models.networks import build_model, model_spec

    folder = tmp_path_factory.mktemp("inputs")
    torch.manual_seed(0)
    table = json.loads((TEST_DATA / "tinyseg" / "manifest.json").read_text())["classes"]
    spec = model_spec("tiny", 0.0625, class_table=table, input_size=(64, 96))
    save_checkpoint(folder / "model.pt", {"spec": spec, "model": build_model(spec).state_dict()})
    view = np.full((224, 1232), 14, np.uint8)
    view[112:] = 2
    view[60:112, 100:300] = view[60:112, 700:900] = 1
    Image.fromarray(view).save(folder / "query.png")
    return {"model": folder / "model.pt", "query": folder / "query.png"}


def run(*args: object) -> Result:
    return CliRunner().invoke(cli, ["-q", *(str(a) for a in args)])


def commands(data: Path, inputs: dict[str, Path], out: Path) -> dict[str, list[object]]:
    image, label = data / "images" / "tinyseg_000.png", data / "labels" / "tinyseg_000.png"
    model, query = inputs["model"], inputs["query"]
    return {
        "train": ["train", data, "--out", out, "--config", TEST_DATA / "train" / "tiny.yaml", "--epochs", 1],
        "eval": ["eval", model, data, "--out", out, "--device", "cpu"],
        "eval --pair": ["eval", model, "--pair", image, label, "--out", out, "--device", "cpu"],
        "predict": ["predict", model, image, "--out", out, "--device", "cpu"],
        "predict --out": ["predict", model, TEST_DATA / "tinyseg" / "images" / "tinyseg_005.png", "--out",
                          data / "labels", "--device", "cpu"],
        "localize": ["localize", "--aerial", label, "--ground", query, "--ground-landmarks", "aerial13",
                     "--ground-table", "classes13.toml", "--aerial-resolution", 0.5, "--out", out],
        "localize-bench": ["localize-bench", data, "--out", out, "--viewpoints", 2, "--no-plots"],
        "localize-bench MASK": ["localize-bench", label, "--aerial-resolution", 0.5, "--out", out, "--viewpoints", 2,
                                "--no-plots"],
        "verify": ["verify", data],
    }


@pytest.mark.parametrize("command", ["train", "eval", "eval --pair", "predict", "predict --out", "localize",
                                     "localize-bench", "localize-bench MASK", "verify"])
def test_a_command_on_a_folder_a_build_holds_is_refused_at_once(building: tuple[Path, int], inputs: dict[str, Path],
                                                                tmp_path: Path, command: str) -> None:
    data, pid = building
    before = sorted(str(p.relative_to(data)) for p in data.rglob("*") if ".osmseg-build" not in p.parts)
    result = run(*commands(data, inputs, tmp_path / "out")[command])
    assert result.exit_code == 1, result.output
    assert "Traceback" not in result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1, result.output
    assert errors[0].startswith(f"Error: {data} is being built now (pid {pid} on {os.uname().nodename} since "), errors
    assert errors[0].endswith("): use it when the build has ended"), errors
    assert not (tmp_path / "out").exists()
    assert sorted(str(p.relative_to(data)) for p in data.rglob("*") if ".osmseg-build" not in p.parts) == before


def test_the_same_commands_run_once_the_build_has_ended(building: tuple[Path, int], inputs: dict[str, Path],
                                                        tmp_path: Path) -> None:
    """The refusal is the build's lock, not the folder: a folder nobody holds is read."""
    data, _ = building
    shutil.copytree(data, tmp_path / "free", ignore=shutil.ignore_patterns(".osmseg-build"))
    for command in ("eval --pair", "predict", "localize"):
        result = run(*commands(tmp_path / "free", inputs, tmp_path / command.replace(" ", ""))[command])
        assert result.exit_code == 0, (command, result.output)
