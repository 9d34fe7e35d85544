"""Every error a user meets says what to change in the words of the command they ran.

Issue 31, item 4, through the CLI as a user meets each message:

* a message names only options the command has (``osmseg eval`` advised ``--classes``, ``train``
  ``--val-fraction``), or says whose they are (``osmseg build --no-overlap``);
* no Python names reach a user: field names (``margin_m, save_panoramas``), exception reprs and
  class names (``KeyError('unlabeled')``, ``(TypeError)``), tracebacks;
* usage errors exit 2;
* ``osmseg localize-region --osm FILE --bbox`` over an area the file does not cover says so, naming the
  file's extent as ``osmseg build`` does (was: "no block holds a place that fits the query").

:func:`test_every_error_names_only_what_the_command_has` walks the messages this issue touched,
one command line each; click's own parameter table says which options a command has.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import click
import numpy as np
import pytest
from click.testing import CliRunner, Result
from conftest import TEST_DATA, TINYCITY, TINYCITY_CENTRE, write_dataset_manifest
from PIL import Image

from osmseg.cli.main import cli

TINYSEG = TEST_DATA / "tinyseg"
TINY_YAML = TEST_DATA / "train" / "tiny.yaml"
OPTION = re.compile(r"(?<![\w-])--?[a-z][a-z0-9-]*")
PYTHON_NAME = re.compile(r"(?<![\w./-])[a-z]+(?:_[a-z0-9]+)+(?![\w./-])")  # snake_case, outside paths
EXCEPTION = re.compile(r"\b[A-Z]\w*(?:Error|Exception)\b|\w+\(['\"]|Traceback")


def run(*args: object) -> Result:
    return CliRunner().invoke(cli, [str(a) for a in args])


def options_of(command: str) -> set[str]:
    """Every option spelling of ``osmseg COMMAND`` (its own and the group's -v/-q/--progress)."""
    ctx = click.Context(cli)
    found: set[str] = {"--help", "-h"}
    for param in [*cli.get_command(ctx, command).params, *cli.params]:  # type: ignore[union-attr]
        if isinstance(param, click.Option):
            found |= set(param.opts) | set(param.secondary_opts)
    return found


def named_options(line: str, command: str) -> list[tuple[str, str]]:
    """``(command, option)`` for each option ``line`` names: the command a clause names
    (``osmseg build --no-overlap``), else the one that printed it."""
    named = []
    for match in OPTION.finditer(line):
        clause = re.split(r"[;:()]|, or ", line[:match.start()])[-1]
        others = re.findall(r"\bosmseg ([a-z-]+)", clause)
        named.append((others[-1] if others else command, match.group()))
    return named


def check_words(result: Result, command: str, allowed: set[str] = frozenset()) -> str:  # type: ignore[assignment]
    """The one error line of ``result``, checked: options of the command it names, no Python names."""
    assert "Traceback" not in result.output, result.output
    lines = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(lines) == 1, result.output
    line = lines[0].removeprefix("Error: ")
    for owner, option in named_options(line, command):
        assert option in options_of(owner), f"osmseg {owner} has no {option}: {line}"
    words = " ".join(w for w in line.split() if "/" not in w)  # paths may hold anything
    assert not EXCEPTION.search(words), line
    assert not [w for w in PYTHON_NAME.findall(words) if w not in allowed], line
    return line


# --------------------------------------------------------------------------- the walk


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory, imagery_tif: Path) -> dict[str, Path]:
    """What the command lines below read: a tiny CamVid checkpoint, a 13-class dataset, a 2-image
    dataset, a 3-sample dataset whose samples overlap, and a file that is no cassette."""
    torch = pytest.importorskip("torch")
    from osmseg.classes import load_class_table
    from training.models.checkpoint import save_checkpoint
    from training.models.networks import build_model, model_spec

    root = tmp_path_factory.mktemp("scene")
    torch.manual_seed(0)
    spec = model_spec("camvidnet", 0.0625, class_table="camvid.toml", input_size=(64, 96))
    save_checkpoint(root / "camvid.pt", {"spec": spec, "model": build_model(spec).state_dict()})
    tinyseg = json.loads((TINYSEG / "manifest.json").read_text())["classes"]
    for name, count, table in (("ds13", 2, load_class_table("classes13.toml").to_dict()), ("two", 2, tinyseg),
                               ("overlapping", 3, tinyseg)):
        for folder in ("images", "labels"):
            (root / name / folder).mkdir(parents=True)
            for i in range(count):
                shutil.copy(TINYSEG / folder / f"tinyseg_00{i}.png", root / name / folder / f"s{i}.png")
        write_dataset_manifest(root / name, table, [
            {"name": f"s{i}", "ground_resolution_m": 0.5, "bounds_3857": [0.0, 0.0, 80.0, 64.0]}
            for i in range(count)])
    (root / "two" / "manifest.json").unlink()  # images/ + labels/ + classes.toml: no footprints
    (root / "two" / "classes.toml").write_text(
        'name = "tinyseg"\nunlabeled = { id = 0, name = "unlabeled", color = [0, 0, 0] }\n' + "".join(
            f'[[classes]]\nid = {c["id"]}\nname = "{c["name"]}"\ncolor = {c["color"]}\n'
            for c in tinyseg["classes"] if c["id"]))
    (root / "notes.yaml").write_text("not a cassette\n")
    return {"root": root, "camvid": root / "camvid.pt", "ds13": root / "ds13", "two": root / "two",
            "overlapping": root / "overlapping", "notes": root / "notes.yaml", "imagery": imagery_tif}


def build_line(s: dict[str, Path], out: Path, *extra: object) -> list[object]:
    lon, lat = TINYCITY_CENTRE
    return ["build", "--lat", lat, "--lon", lon, "--radius-km", 0.05, "--samples", 1, "--imagery",
            f"geotiff:{s['imagery']}", "--osm", TINYCITY, "--out", out / "built", "--cache-dir",
            out / "cache", "--workers", 1, *extra]


def train_line(s: dict[str, Path], out: Path, data: str, *extra: object) -> list[object]:
    return ["train", s[data], "--out", out / "run", "--config", TINY_YAML, "--epochs", 1, *extra]


def bench_line(s: dict[str, Path], out: Path, *extra: object) -> list[object]:
    return ["localize-bench", s["ds13"], "--out", out / "bench", "--viewpoints", 2, "--no-plots", *extra]


#: (id, command, what to run, exit status): the messages issue 31 found wrong, and their neighbours
CASES = [
    ("bench margin", "localize-bench", lambda s, out: bench_line(s, out, "--margin", -1), 2),  # was: margin_m, save_panoramas...
    ("bench panoramas", "localize-bench", lambda s, out: bench_line(s, out, "--save-panoramas", -1), 2),
    ("bench top-k", "localize-bench", lambda s, out: bench_line(s, out, "--top-k", 0), 2),
    ("bench confusion", "localize-bench", lambda s, out: bench_line(s, out, "--confusion", 2), 2),  # was: miss_prob
    ("bench miss-small", "localize-bench", lambda s, out: bench_line(s, out, "--miss-small", -1), 2),  # was: miss_small_px
    ("bench offset", "localize-bench", lambda s, out: bench_line(s, out, "--offset", -1), 2),  # was: offset_m
    ("bench min-size", "localize-bench", lambda s, out: bench_line(s, out, "--min-size", -1), 2),  # was: min_size
    ("bench stand-on", "localize-bench", lambda s, out: bench_line(s, out, "--stand-on", "lava"), 2),  # was: stand_on classes
    ("bench seed", "localize-bench", lambda s, out: bench_line(s, out, "--seed", -1), 2),  # was: a traceback
    ("train seed", "train", lambda s, out: train_line(s, out, "two", "--seed", -1), 2),  # was: a traceback
    ("train steps", "train", lambda s, out: train_line(s, out, "two", "--max-steps-per-epoch", -1), 2),  # was: a traceback
    ("train batch", "train", lambda s, out: train_line(s, out, "two", "--batch-size", 0), 2),  # was: batch_size
    ("train too few", "train", lambda s, out: train_line(s, out, "two"), 1),  # was: --val-fraction/--test-fraction
    ("train overlap", "train", lambda s, out: train_line(s, out, "overlapping"), 1),  # was: build's --no-overlap as train's
    ("train preset", "train", lambda s, out: train_line(s, out, "two", "--model", "airsegnet13"), 2),
    ("eval tables", "eval", lambda s, out: ["eval", s["camvid"], s["ds13"], "--out", out / "eval"], 2),
    ("eval panels", "eval", lambda s, out: ["eval", s["camvid"], s["ds13"], "--out", out / "eval", "--panels", 0],
     2),  # was: exit 1, "give at least one (title, image, ground truth, prediction) row"
    ("predict batch", "predict", lambda s, out: ["predict", s["camvid"], s["ds13"] / "images" / "s0.png", "--out",
                                            out / "masks", "--batch-size", 0], 2),
    ("build min-classes", "build", lambda s, out: build_line(s, out, "--min-classes", -1), 2),  # was: filter min_classes
    ("build min-contrast", "build", lambda s, out: build_line(s, out, "--min-contrast", 300), 2),  # was: min_contrast
    ("build record", "build", lambda s, out: build_line(s, out, "--record", s["notes"]), 2),  # was: a traceback
    ("build replay", "build", lambda s, out: build_line(s, out, "--replay", s["notes"]), 2),  # was: "(TypeError)"
]


@pytest.mark.parametrize(("command", "line", "status"), [pytest.param(*c[1:], id=c[0]) for c in CASES])
def test_every_error_names_only_what_the_command_has(scene: dict[str, Path], tmp_path: Path, command: str, line,
                                                     status: int) -> None:
    from training.run.config import FIELDS

    result = run(*line(scene, tmp_path))
    assert result.exit_code == status, result.output
    allowed = set(FIELDS) if command == "train" else set()  # train's --config file keys are the user's words
    check_words(result, command, allowed)
    if status == 2:  # a usage error is refused before anything is written
        assert not [p.name for p in tmp_path.iterdir() if p.name != "cache"], result.output


def test_the_checker_sees_what_it_must() -> None:
    """The walk above would see each kind of fault the issue reported."""
    assert named_options("--aerial-size x; run osmseg build --no-overlap, or train with --split-by image", "localize") \
        == [("localize", "--aerial-size"), ("build", "--no-overlap"), ("localize", "--split-by")]
    for line in ("margin_m, save_panoramas and pictures must be >= 0", "malformed (KeyError('unlabeled'))",
                 "not a vcrpy cassette (TypeError)"):
        assert PYTHON_NAME.search(line) or EXCEPTION.search(line), line
    assert not PYTHON_NAME.search("tinyseg_000.png")  # file names are not Python names
    assert not EXCEPTION.search("Error-free text naming --mapping")


# --------------------------------------------------------------------------- a region without data


def test_a_region_search_over_an_area_the_osm_file_does_not_cover_says_so(tmp_path: Path) -> None:
    view = np.full((224, 1232), 14, np.uint8)  # sky above, road below, two buildings
    view[112:] = 2
    view[60:112, 100:300] = view[60:112, 700:900] = 1
    Image.fromarray(view).save(tmp_path / "query.png")
    args = ["localize-region", "--ground", tmp_path / "query.png", "--ground-landmarks", "aerial13", "--ground-table",
            "classes13.toml", "--osm", TINYCITY, "--cache-dir", tmp_path / "cache", "--out", tmp_path / "out"]
    result = run(*args, "--bbox", "10.0,50.0,10.003,50.002")  # Germany; the file is of Helsinki
    assert result.exit_code == 2, result.output  # was: exit 0, "no block of the region holds a place that fits"
    line = check_words(result, "localize-region")
    assert line.startswith(f"--osm {TINYCITY} covers lon 24.93572..24.94358, lat 60.16766..60.17207 (its header's "
                           "bounds), which misses the region (lon 10.00000..10.00300, lat 50.00000..50.00200)"), line
    assert not (tmp_path / "out").exists()
    lon, lat = TINYCITY_CENTRE  # over the file's data the search runs
    covered = run(*args, "--lat", lat, "--lon", lon, "--radius-km", 0.1)
    assert covered.exit_code == 0, covered.output
