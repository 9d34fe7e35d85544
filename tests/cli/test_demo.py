"""The README's first command: ``osmseg demo`` builds a dataset offline from embedded fixtures."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from localization.cli.demo import DEMO_VIEWPOINTS
from osmseg import __version__
from osmseg.cli.main import cli
from osmseg.demo import DEMO_CASSETTE, DEMO_SAMPLES


def test_demo_builds_offline_and_says_what_it_used(demo_run: Path) -> None:
    """``osmseg demo --no-train`` (run once for the session: conftest's ``demo_run``)."""
    out = demo_run / "demo" / "dataset"
    stdout, stderr = (demo_run / "stdout.txt").read_text(), (demo_run / "stderr.txt").read_text()
    assert stdout.strip() == str(out / "manifest.json")
    assert "Helsinki" in stderr and DEMO_CASSETTE.name in stderr and str(out) in stderr
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["summary"]["accepted"] == DEMO_SAMPLES
    assert manifest["imagery"]["provider"] == "bing" and manifest["osm"]["source"] == "api"
    assert "demo-key" not in (out / "manifest.json").read_text()
    # real Helsinki OSM: buildings, roads, footways and vegetation in every sample
    for sample in manifest["samples"]:
        labels = np.asarray(Image.open(out / "labels" / f"{sample['name']}.png"))
        names = {name for name, n in sample["class_histogram"].items() if n > 1000}
        assert {"building", "highway", "footway"} <= names, names
        assert labels.shape == (1280, 1280)
    verified = CliRunner().invoke(cli, ["verify", str(out), "--alignment", "building"])
    assert verified.exit_code == 0
    offsets = json.loads(verified.stdout)["alignment"]["offsets"].values()
    assert all(o["dx"] == 0 and o["dy"] == 0 for o in offsets)
    # a class missing from a sample is said to be missing, not reported as lined up at (0, 0)
    water = json.loads(CliRunner().invoke(cli, ["verify", str(out), "--alignment", "water"]).stdout)
    noted = {name for name, o in water["alignment"]["offsets"].items() if o["dx"] is None}
    assert noted == {s["name"] for s in manifest["samples"] if not s["class_histogram"].get("water")}
    assert all(water["alignment"]["offsets"][n]["note"] == "no water pixels in this sample" for n in noted)
    unknown = CliRunner().invoke(cli, ["verify", str(out), "--alignment", "lava"])
    assert unknown.exit_code == 2 and "'lava': not a class of this dataset; use one of building" in unknown.output
    # then panoramas rendered from those masks were localized in them, with pictures
    loc = demo_run / "demo" / "localize"
    results = json.loads((loc / "results.json").read_text())
    assert results["summary"]["n"] == DEMO_VIEWPOINTS and {r["scene"] for r in results["viewpoints"]} == {
        s["name"] for s in manifest["samples"]}
    assert sorted(p.name for p in (loc / "views").glob("*_map.png"))[:1] == ["0000_helsinki_00000_map.png"]
    assert (loc / "errors.png").stat().st_size > 1000 and "rendered panoramas" in stderr


def test_version_and_help() -> None:
    result = CliRunner().invoke(cli, ["--version"])
    assert result.exit_code == 0 and __version__ in result.output
    result = CliRunner().invoke(cli, ["--help"])
    assert all(cmd in result.output for cmd in ("build", "demo", "verify"))


@pytest.mark.slow  # make test-slow: 23 s, training the demo model; make demo runs the same code
def test_demo_trains_and_evaluates_after_the_build(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    result = CliRunner().invoke(cli, ["demo", "--out", str(out), "--epochs", "1", "--no-localize"])
    assert result.exit_code == 0, result.output
    for picture in ("panels.png", "confusion_matrix.png", "per_class_iou.png", "curves.png"):
        assert (out / "eval" / picture).stat().st_size > 1000
    metrics = json.loads((out / "eval" / "metrics.json").read_text())
    assert "test" in metrics["evaluated"]["images"] and 0 <= metrics["pixel_accuracy"] <= 1
    assert "panels.png" in result.stderr and (out / "run" / "model.pt").is_file()
    assert not (out / "localize").exists()
