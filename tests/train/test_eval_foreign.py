"""``osmseg eval`` on foreign labelled data: Inria Austin's building masks through a class mapping."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner
from conftest import TEST_DATA, shared_path

from osmseg.cli.main import cli


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny AirSegNet13-shaped model trained for one epoch (the mapping needs a 'building' class)."""
    out = tmp_path_factory.mktemp("run")
    args = ["-q", "train", str(TEST_DATA / "tinyseg"), "--out", str(out), "--config",
            str(TEST_DATA / "train" / "tiny.yaml"), "--epochs", "1"]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    return out / "best.pt"


@pytest.mark.parametrize(("mode", "resolution"), [("split-join", None), ("rescale", None), ("split-join", "0.6")])
def test_inria_austin_through_the_buildings_mapping(checkpoint: Path, tmp_path: Path, mode: str,
                                                    resolution: str | None) -> None:
    root = shared_path("inria-austin")
    args = ["-q", "eval", str(checkpoint), "--pair", str(root / "image.tif"), str(root / "buildings.tif"),
            "--mapping", "inria-buildings", "--mode", mode, "--out", str(tmp_path)]
    if resolution:
        args += ["--resolution", resolution]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert set(metrics["per_class"]) == {"background", "building"}
    assert metrics["num_pixels"] == 1000 * 1000  # every label pixel compared once, on the label's grid
    assert metrics["per_class"]["building"]["support"] > 0
    assert metrics["evaluated"]["mode"] == mode and metrics["evaluated"]["mapping"] == "inria-buildings"
    assert (tmp_path / "panels.png").stat().st_size > 1000
