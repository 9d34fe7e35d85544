"""Inputs that were accepted with a wrong answer, each met as a user meets it: through the CLI.

Issue 18, item 6:

* a class table giving two classes one colour (the colour masks become ambiguous): refused;
* an image that cannot be a 360° panorama (a 224x1232 portrait) given as one to ``osmseg
  localize``, ``localize-bench`` pairs or rendered panoramas: refused, photos (``--fov``) still work;
* ``osmseg build --zoom`` finer than a local GeoTIFF's pixels: warned once, with the zoom that matches;
* a build that keeps fewer samples than asked: one "incomplete" line (exit 0: see :func:`test_a_build_that_keeps_fewer_samples_than_asked_says_so`);
* an OSM file, a tile folder or a remote source with nothing over the area: said so, before the
  first attempt where that can be known, else in the final error;
* a 16-bit or paletted GeoTIFF: ``build`` and ``predict`` read the same colours from it.

The data is made here: tinycity's OSM file, the GeoTIFF painted from it (``imagery_tif``), masks
and panoramas rendered by the project, and servers on 127.0.0.1.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner, Result
from PIL import Image
from rasterio.windows import Window

from osmseg.classes import load_class_table
from osmseg.cli.main import cli
from osmseg.datafiles import DATA_DIR

from conftest import REPO_ROOT, TEST_DATA, TINYCITY, TINYCITY_CENTRE

LON, LAT = TINYCITY_CENTRE
TILES = TEST_DATA / "imagery" / "tiles"  # z18 tiles of a 3x3 block in Berlin
BERLIN = ("--lat", "52.52", "--lon", "13.405")


def run(*args: str) -> Result:
    return CliRunner().invoke(cli, list(args))


def error_line(result: Result) -> str:
    """The one ``Error:`` line of a failed command (no traceback, nothing else after it)."""
    assert "Traceback" not in result.output, result.output
    lines = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(lines) == 1, result.output
    return lines[0]


def build_args(out: Path, imagery: str, *extra: str, samples: int = 2, where: tuple[str, ...] = ()) -> list[str]:
    return ["build", *(where or ("--lat", str(LAT), "--lon", str(LON))), "--radius-km", "0.05", "--samples",
            str(samples), "--seed", "1", "--imagery", imagery, "--osm", str(TINYCITY), "--out", str(out),
            "--cache-dir", str(out.parent / "cache"), "--workers", "1", *extra]


def images_of(dataset: Path) -> dict[str, np.ndarray]:
    return {p.name: np.asarray(Image.open(p)) for p in sorted((dataset / "images").glob("*.png"))}


# --------------------------------------------------------------------------- a. class tables


def test_a_class_table_giving_two_classes_one_colour_is_refused_in_one_line(tmp_path: Path, imagery_tif: Path) -> None:
    text = (DATA_DIR / "classes13.toml").read_text(encoding="utf-8")
    assert text.count("color = [0, 100, 0]") == 1  # natural's dark green
    (tmp_path / "mine.toml").write_text(text.replace("color = [0, 100, 0]", "color = [255, 255, 0]"))  # building's
    result = run(*build_args(tmp_path / "ds", f"geotiff:{imagery_tif}", "--classes", str(tmp_path / "mine.toml")))
    assert result.exit_code == 2
    line = error_line(result)
    assert "'building'" in line and "'natural'" in line and "[255, 255, 0]" in line, line
    assert not (tmp_path / "ds").exists()


@pytest.mark.parametrize("name", ["classes13.toml", "classes6.toml", "camvid.toml"])
def test_the_shipped_class_tables_load_with_a_colour_per_class(name: str) -> None:
    table = load_class_table(name)
    colours = [c.color for c in (table.unlabeled, *table.classes)]
    assert len(set(colours)) == len(colours) == len(table.classes) + 1
