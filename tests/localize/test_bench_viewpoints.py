"""Where ``osmseg localize-bench`` cannot place its viewpoints, its one error line says why, first
what to change, with the numbers the user gave.

On the README's Kampala dataset (real drone tiles, OSM building footprints only: every pixel is
building or unlabeled) ``--viewpoints 4`` said "only 0 standable pixels at least 268 px from the
border, 1 viewpoints asked: lower --viewpoints or --margin, or use another mask": one viewpoint
where four were asked, the margin in pixels where ``--margin`` takes metres, no mask named, and
advice that cannot help (``--margin 0`` failed the same way). The cause is that the mask holds no
pixel of the classes viewpoints stand on by default, and ``--stand-on`` is the option that helps.
Skipped without ``../shared/data``.
"""

from __future__ import annotations

import shlex
from pathlib import Path

import pytest
from click.testing import CliRunner, Result
from conftest import SHARED_DATA, shared_path
from test_readme_chain import chain

from osmseg.cli.main import cli


def osmseg(*args: object) -> Result:
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.fixture(scope="module")
def kampala(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The README's Kampala build ("Example with local data only"), /data/ the real data's folder."""
    shared_path("kampala-oam")
    folder = tmp_path_factory.mktemp("kampala")
    args = [a.replace("/data/", f"{SHARED_DATA}/") for a in shlex.split(chain()[0])[1:]]
    args[args.index("--out") + 1] = str(folder / "kampala")
    result = osmseg("-q", *args, "--cache-dir", folder / "cache")
    assert result.exit_code == 0, result.output
    return folder / "kampala"


def error_line(result: Result) -> str:
    assert result.exit_code == 2 and "Traceback" not in result.output, result.output
    lines = [line for line in result.stderr.splitlines() if line.startswith("Error:")]
    assert len(lines) == 1, result.stderr
    return lines[0]


@pytest.mark.parametrize("margin", [None, "0"])
def test_a_mask_without_standable_classes_says_so_and_names_stand_on(kampala: Path, tmp_path: Path,
                                                                     margin: str | None) -> None:
    extra = ["--margin", margin] if margin else []
    line = error_line(osmseg("localize-bench", kampala, "--viewpoints", 4, *extra, "--out", tmp_path / "b"))
    mask = kampala / "labels" / "bbox_00000.png"
    assert line.startswith("Error: no pixel of the standable classes (")  # the cause first
    assert "highway" in line and "footway" in line  # the classes viewpoints stand on by default
    assert f"in {mask}" in line  # the mask
    held = line.split("give --stand-on CLASS")[1]
    assert "unlabeled (" in held and "building (" in held and "highway" not in held  # what the mask holds
    assert "1 viewpoints" not in line and " px" not in line


def test_the_advice_works_and_a_margin_too_wide_is_said_in_metres(kampala: Path, tmp_path: Path) -> None:
    ok = osmseg("-q", "localize-bench", kampala, "--viewpoints", 4, "--stand-on", "unlabeled", "--methods", "profile",
                "--no-negatives", "--no-plots", "--out", tmp_path / "b")
    assert ok.exit_code == 0, ok.output
    # the samples are 768 px of 7.5 cm: 57 m; 30 m from every border leaves no room
    line = error_line(osmseg("localize-bench", kampala, "--viewpoints", 40, "--stand-on", "unlabeled",
                             "--margin", 30, "--out", tmp_path / "c"))
    assert "at least 30 m (" in line and "from the border of" in line
    assert "5 of the 40 viewpoints asked, spread over 8 masks" in line and "lower --margin" in line
    mask = kampala / "labels" / "bbox_00000.png"
    line = error_line(osmseg("localize-bench", mask, "--aerial-resolution", 0.075, "--viewpoints", 1_000_000, "--stand-on",
                             "unlabeled", "--out", tmp_path / "d"))
    assert line.startswith("Error: only ") and "1,000,000 viewpoints asked" in line and f"border of {mask}" in line
