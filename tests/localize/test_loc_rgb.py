"""The automated pipeline of the dissertation's §5.3, end to end on RGB images.

An aerial photo segmented by an AirSegNet-style checkpoint and a ground panorama photo
segmented by a ground model trained with ``osmseg train`` on CamVid-layout data (the shipped
``camvid.toml`` class table, void = 11), both trained inside the test on the seeded scenes of
``tests/data/rgbpipe/data.py``; the panorama goes through split-join (616 px wide, 160 px
windows); the masks become landmarks and profiles; both methods answer through ``osmseg
localize``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from click.testing import CliRunner

from osmseg.cli.main import cli as osmseg_main

pytest.importorskip("torch")
#: make test-slow: two trainings (30 s); each step runs in make test on its own (segmenting an RGB
#: image with a checkpoint in localize: test_loc_match; loading CamVid-layout data: test_data)
pytestmark = pytest.mark.slow

HERE = Path(__file__).resolve().parents[1]  # tests/
CONFIGS = HERE / "data" / "train"


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    import sys

    sys.path.insert(0, str(HERE / "data" / "rgbpipe"))
    import data as rgbpipe

    root = tmp_path_factory.mktemp("rgbpipe")
    paths = rgbpipe.generate(root)
    runner = CliRunner()
    for name, dataset, config, extra in (("aerial_run", paths["aerial_set"], "learn.yaml", []),
                                         ("ground_run", paths["ground_set"], "pano.yaml", ["--classes", "camvid.toml"])):
        result = runner.invoke(osmseg_main, ["-q", "train", str(dataset), "--out", str(root / name),
                                             "--config", str(CONFIGS / config), *extra])
        assert result.exit_code == 0, result.output
        paths[name] = root / name / "best.pt"
    return paths


def test_camvid_layout_trains_with_void_11_ignored(trained: dict[str, Path]) -> None:
    from training.models.checkpoint import model_from_checkpoint

    _, spec = model_from_checkpoint(trained["ground_run"])
    assert spec.num_classes == 12 and spec.ignore_index == 11
    assert spec.table.by_id[11].name == "Unlabelled" and spec.table.by_id[0].name == "Sky"


def test_rgb_aerial_and_rgb_panorama_localize_through_both_methods(trained: dict[str, Path], tmp_path: Path) -> None:
    truth = trained["truth"].read_text().strip()
    tx, ty = (float(v) for v in truth.split(","))
    base = ["localize", "--aerial", str(trained["aerial"]), "--aerial-checkpoint", str(trained["aerial_run"]),
            "--ground", str(trained["query"]), "--ground-checkpoint", str(trained["ground_run"]),
            "--aerial-resolution", "0.5", "--truth", truth, "--json"]
    runner = CliRunner()
    res = runner.invoke(osmseg_main, [*base, "--method", "profile", "--min-kappa", "0.2"])  # segmented: lower
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["method"] == "profile" and not out["unanswered"]
    assert math.hypot(out["map"]["x"] - tx, out["map"]["y"] - ty) * 0.5 <= 3.0, out["map"]
    assert out["ground_landmarks"] > 3 and out["aerial_landmarks"] > 20
    res = runner.invoke(osmseg_main, [*base, "--method", "paper"])
    assert res.exit_code == 0, res.output
    paper = json.loads(res.stdout)
    assert paper["method"] == "paper" and paper["ground_landmarks"] == out["ground_landmarks"]
