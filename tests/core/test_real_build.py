"""A build from real data made by others: Kampala drone tiles + OSM building footprints.

``../shared/data/kampala-oam`` is the one place with real imagery and real OSM together (the
tiles are a local XYZ folder, the footprints GeoJSON without tags). The build reads them the
way a user would, through ``--imagery xyz:file://...`` and ``--osm geojson:...``, and the test
proves the masks line up with the roofs: building outlines sit on the strongest image edges.
"""

from __future__ import annotations

import json
from pathlib import Path

import mercantile
import numpy as np
from click.testing import CliRunner
from conftest import shared_path
from PIL import Image

from osmseg.cli.main import cli
from osmseg.quality import edge_alignment

# 5x5 grids whose centre tile is in this range lie inside the complete z21 block
CENTRE_X, CENTRE_Y = (1238450, 1238457), (1046530, 1046533)


def centre_bbox() -> str:
    west = mercantile.bounds(CENTRE_X[0], CENTRE_Y[0], 21).west
    east = mercantile.bounds(CENTRE_X[1], CENTRE_Y[0], 21).east
    north = mercantile.bounds(CENTRE_X[0], CENTRE_Y[0], 21).north
    south = mercantile.bounds(CENTRE_X[0], CENTRE_Y[1], 21).south
    return f"{west + 1e-7},{south + 1e-7},{east - 1e-7},{north - 1e-7}"


def test_kampala_build_masks_sit_on_the_roofs(tmp_path: Path) -> None:
    root = shared_path("kampala-oam")
    out = tmp_path / "kampala"
    args = [
        "-q", "build", "--bbox", centre_bbox(), "--zoom", "21", "--samples", "3", "--seed", "5",
        "--imagery", f"xyz:file://{root}/tiles/OAM-{{x}}-{{y}}-{{z}}.png",
        "--osm", f"geojson:{root}/osm-buildings.geojson:building=yes",
        # one class (buildings) is all this source has; RGBA tiles have a few empty pixels
        "--min-classes", "1", "--max-unlabeled", "0.99", "--max-missing-imagery", "0.01",
        "--cache-dir", str(tmp_path / "cache"), "--out", str(out),
    ]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["summary"]["accepted"] == 3
    for sample in manifest["samples"]:
        assert sample["zoom"] == 21 and 0.07 < sample["ground_resolution_m"] < 0.08
        rgb = np.asarray(Image.open(out / "images" / f"{sample['name']}.png"))
        mask = np.asarray(Image.open(out / "labels" / f"{sample['name']}.png")) == 1
        assert 0.02 < mask.mean() < 0.7
        fit = edge_alignment(rgb, mask)
        # within 2 px (15 cm at z21): finer than OSM footprints are traced
        assert max(abs(fit.best[0]), abs(fit.best[1])) <= 2, (sample["name"], fit)
        assert fit.at_zero > 1.2 * fit.far, (sample["name"], fit)
    verified = CliRunner().invoke(cli, ["verify", str(out), "--alignment", "building"])
    assert verified.exit_code == 0, verified.output
    assert json.loads(verified.stdout)["problems"] == []
