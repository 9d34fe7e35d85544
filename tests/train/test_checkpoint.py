"""Checkpoints: exact round trips, atomic writes, and one-line errors for files that are not ours."""

from __future__ import annotations

import os
import random
from collections.abc import Iterator
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from osmseg.errors import ConfigError
from training.errors import CheckpointError
from training.models.checkpoint import load_checkpoint, model_from_checkpoint, save_checkpoint
from training.models.networks import SegNet, build_model, model_spec
from training.models.spec import ModelSpec


@pytest.fixture(autouse=True)
def _threads() -> Iterator[None]:
    before = torch.get_num_threads()
    torch.set_num_threads(min(2, before))
    torch.manual_seed(0)
    yield
    torch.set_num_threads(before)


@pytest.fixture
def spec() -> ModelSpec:
    return model_spec("airsegnet6", 0.0625, input_size=(64, 96))


@pytest.fixture
def trained(spec: ModelSpec) -> tuple[SegNet, torch.optim.Optimizer]:
    """A model after two SGD steps: BN statistics and momentum buffers are not at their defaults."""
    model = build_model(spec)
    opt = torch.optim.SGD(model.parameters(), lr=0.01, momentum=0.9, weight_decay=5e-4)
    for _ in range(2):
        opt.zero_grad()
        F.cross_entropy(model(torch.randn(2, 3, 64, 96)), torch.randint(0, 7, (2, 64, 96))).backward()
        opt.step()
    return model, opt


def full_state(spec: ModelSpec, model: SegNet, opt: torch.optim.Optimizer) -> dict[str, Any]:
    """What a trainer stores, including values that need converting (numpy scalars, paths)."""
    return {
        "spec": spec, "model": model.state_dict(), "optimizer": opt.state_dict(), "epoch": 3, "step": 12,
        "rng": {"torch": torch.get_rng_state(), "python": random.getstate(),
                "numpy": torch.from_numpy(np.random.get_state()[1].astype(np.int64))},
        "config": {"dataset": Path("data/demo"), "lr": 0.01, "patch": (64, 96)},
        "history": [{"epoch": 1, "val_miou": np.float64(0.25), "seen": np.int64(7)}],
        "class_weights": torch.rand(7), "dataset_sha256": "ab" * 32,
    }


def test_round_trip_restores_weights_outputs_and_training_state(
        spec: ModelSpec, trained: tuple[SegNet, torch.optim.Optimizer], tmp_path: Path) -> None:
    model, opt = trained
    path = tmp_path / "run" / "last.pt"
    saved = full_state(spec, model, opt)
    save_checkpoint(path, saved)
    assert os.listdir(path.parent) == ["last.pt"]  # no temporary file left behind

    state = load_checkpoint(path)
    assert (state["format"], state["version"], state["torch_version"]) == ("osmseg-checkpoint", 1, torch.__version__)
    assert ModelSpec.from_dict(state["spec"]) == spec
    assert state["config"]["dataset"] == "data/demo" and state["config"]["patch"] == (64, 96)
    assert state["history"] == [{"epoch": 1, "val_miou": 0.25, "seen": 7}]
    assert type(state["history"][0]["val_miou"]) is float
    assert state["rng"]["python"] == saved["rng"]["python"]  # random.setstate() takes it back
    assert torch.equal(state["rng"]["torch"], saved["rng"]["torch"])
    assert torch.equal(state["rng"]["numpy"], saved["rng"]["numpy"])
    for key, value in model.state_dict().items():
        assert torch.equal(state["model"][key], value), key

    again = torch.optim.SGD(build_model(spec).parameters(), lr=1.0)
    again.load_state_dict(state["optimizer"])  # momentum buffers come back whole
    assert torch.equal(again.state_dict()["state"][0]["momentum_buffer"], opt.state_dict()["state"][0]["momentum_buffer"])

    loaded, loaded_spec = model_from_checkpoint(path)
    assert loaded_spec == spec and not loaded.training
    x = torch.randn(2, 3, 64, 96)
    with torch.no_grad():
        assert torch.equal(loaded(x), model.eval()(x))


def test_overwrite_is_atomic_and_a_refused_state_keeps_the_old_file(
        spec: ModelSpec, trained: tuple[SegNet, torch.optim.Optimizer], tmp_path: Path) -> None:
    model, _ = trained
    path = tmp_path / "best.pt"
    save_checkpoint(path, {"spec": asdict(spec), "model": model.state_dict(), "epoch": 1})
    save_checkpoint(path, {"spec": spec, "model": model.state_dict(), "epoch": 2})
    before = path.read_bytes()
    with pytest.raises(CheckpointError, match=r"state\['rng'\]\['numpy'\] is a numpy.ndarray.*store a tensor or a list"):
        save_checkpoint(path, {"spec": spec, "model": model.state_dict(), "rng": {"numpy": np.zeros(3)}})
    with pytest.raises(CheckpointError, match=r"lacks \['model'\]"):
        save_checkpoint(path, {"spec": spec})
    assert path.read_bytes() == before and os.listdir(tmp_path) == ["best.pt"]
    assert load_checkpoint(path)["epoch"] == 2


def one_line(exc: pytest.ExceptionInfo[BaseException]) -> str:
    message = str(exc.value)
    assert "\n" not in message and message
    return message


def test_missing_file_and_folder(tmp_path: Path) -> None:
    with pytest.raises(CheckpointError) as exc:
        load_checkpoint(tmp_path / "nope.pt")
    assert one_line(exc) == f"checkpoint {tmp_path / 'nope.pt'} not found"
    with pytest.raises(CheckpointError, match="is a folder"):
        model_from_checkpoint(tmp_path)


def test_truncated_file(spec: ModelSpec, trained: tuple[SegNet, torch.optim.Optimizer], tmp_path: Path) -> None:
    path = tmp_path / "last.pt"
    save_checkpoint(path, {"spec": spec, "model": trained[0].state_dict()})
    data = path.read_bytes()
    for cut in (len(data) // 2, len(data) - 30, 10, 0):
        path.write_bytes(data[:cut])
        with pytest.raises(CheckpointError) as exc:
            load_checkpoint(path)
        assert one_line(exc) == f"{path} is not a checkpoint (corrupt or truncated); train again or restore it"


def test_random_bytes(tmp_path: Path) -> None:
    path = tmp_path / "model.pt"
    path.write_bytes(np.random.default_rng(0).bytes(4096))
    with pytest.raises(CheckpointError, match="corrupt or truncated") as exc:
        model_from_checkpoint(path)
    one_line(exc)


def test_files_that_are_not_ours(spec: ModelSpec, trained: tuple[SegNet, torch.optim.Optimizer], tmp_path: Path) -> None:
    model, _ = trained
    torch.save(model.state_dict(), tmp_path / "weights.pth")  # a bare state dict
    with pytest.raises(CheckpointError, match="is not an osmseg checkpoint") as exc:
        load_checkpoint(tmp_path / "weights.pth")
    one_line(exc)
    torch.save(model, tmp_path / "module.pth")  # a pickled nn.Module: weights_only refuses to run it
    with pytest.raises(CheckpointError, match="holds Python objects") as exc:
        load_checkpoint(tmp_path / "module.pth")
    one_line(exc)
    good = {"spec": asdict(spec), "model": model.state_dict(), "format": "osmseg-checkpoint"}
    torch.save({**good, "version": 99}, tmp_path / "future.pt")
    with pytest.raises(CheckpointError, match="version 99, this osmseg reads up to 1; upgrade"):
        load_checkpoint(tmp_path / "future.pt")
    torch.save({**good, "version": 1, "spec": {**good["spec"], "num_classes": 0}}, tmp_path / "badspec.pt")
    with pytest.raises(CheckpointError, match="bad model spec: num_classes must be >= 1") as exc:
        load_checkpoint(tmp_path / "badspec.pt")
    one_line(exc)


def test_weights_that_do_not_fit_the_spec(spec: ModelSpec, tmp_path: Path) -> None:
    """A 7-class model's weights stored under a 14-class spec (airsegnet13)."""
    path = tmp_path / "mixed.pt"
    wrong_spec = model_spec("airsegnet13", spec.width, input_size=spec.input_size)
    save_checkpoint(path, {"spec": wrong_spec, "model": build_model(spec).state_dict()})
    with pytest.raises(CheckpointError) as exc:
        model_from_checkpoint(path)
    assert one_line(exc) == (f"{path}: weights do not fit its spec (segnet, 14 classes, width 0.0625): "
                             "classifier.weight is (7, 4, 3, 3), expected (14, 4, 3, 3); the checkpoint is inconsistent")
    wider = replace(spec, width=0.125)
    save_checkpoint(path, {"spec": wider, "model": build_model(spec).state_dict()})
    with pytest.raises(CheckpointError, match="weights do not fit its spec"):
        model_from_checkpoint(path)


def test_distributed_prefixes_are_accepted(spec: ModelSpec, tmp_path: Path) -> None:
    model = build_model(spec).eval()
    wrapped = {f"module.{k}": v for k, v in model.state_dict().items()}  # DistributedDataParallel's keys
    save_checkpoint(tmp_path / "ddp.pt", {"spec": spec, "model": wrapped})
    loaded, _ = model_from_checkpoint(tmp_path / "ddp.pt")
    x = torch.randn(1, 3, 64, 64)
    with torch.no_grad():
        assert torch.equal(loaded(x), model(x))


def test_spec_checks_its_fields(spec: ModelSpec) -> None:
    with pytest.raises(ConfigError, match="model spec must have the keys"):
        ModelSpec.from_dict({"arch": "segnet"})
    with pytest.raises(ConfigError, match="class_table ids must be integers in 0..2"):
        replace(spec, num_classes=3)
    with pytest.raises(ConfigError, match="ignore_index"):
        replace(spec, ignore_index=9)
    assert spec.palette()[1].tolist() == spec.class_table["classes"][1]["color"]


def test_a_sigterm_while_a_checkpoint_is_written_lets_the_write_finish_then_stops(
        spec: ModelSpec, trained: tuple[SegNet, torch.optim.Optimizer], tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """What CI hit: a SIGTERM inside torch.save's zip writer surfaced as torch's own RuntimeError
    ("unexpected pos") with a traceback, instead of the command's one line and exit 143."""
    import signal

    from osmseg.runtime.processes import Terminated, terminate_by_exception

    model, _ = trained
    real_save = torch.save

    def killed_while_saving(obj: Any, f: Any) -> None:
        os.kill(os.getpid(), signal.SIGTERM)  # Python runs the handler before this line returns
        real_save(obj, f)

    monkeypatch.setattr(torch, "save", killed_while_saving)
    before = signal.getsignal(signal.SIGTERM)
    terminate_by_exception()
    try:
        with pytest.raises(Terminated):
            save_checkpoint(tmp_path / "best.pt", {"spec": spec, "model": model.state_dict(), "epoch": 4})
    finally:
        signal.signal(signal.SIGTERM, before)
    assert os.listdir(tmp_path) == ["best.pt"]  # whole, and no temporary file left
    assert load_checkpoint(tmp_path / "best.pt")["epoch"] == 4
