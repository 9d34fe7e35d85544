"""Shared test fixtures: where the real data of others lives, and skipping when it is absent."""

from __future__ import annotations

import fcntl
import json
import os
import re
import shutil
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"
TEST_DATA = Path(__file__).resolve().parent / "data"
#: A small hand-made OSM town (tests/data/tinycity) and the centre of its sampling area.
TINYCITY = TEST_DATA / "tinycity" / "tinycity.osm"
TINYCITY_CENTRE = (24.94, 60.17)  # lon, lat

pytest_plugins = ["servers"]  # the http_server fixture: a scripted HTTP server on 127.0.0.1


def shared_path(*parts: str) -> Path:
    """Path inside ../shared/data, skipping the calling test when it is absent."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real data not available: {path} (../shared/data is absent on this machine)")
    return path


def table_rows(lines: Sequence[str]) -> list[dict[str, str]]:
    """A printed table read as a person reads it: ``lines[0]`` the labels, the rest rows of values.
    Cells are what two or more spaces separate (a label of two words is one cell). Asserts one
    label per value in every row and each label over its value (their left or right edges line
    up); returns every row as {label: value}."""
    def cells(line: str) -> list[re.Match[str]]:
        return list(re.finditer(r"\S+(?: \S+)*", line))

    labels = cells(lines[0])
    rows = []
    for line in lines[1:]:
        values = cells(line)
        assert len(values) == len(labels), f"{len(labels)} labels over {len(values)} values:\n{lines[0]}\n{line}"
        for label, value in zip(labels, values):
            assert label.start() == value.start() or label.end() == value.end(), (
                f"{label.group()!r} is not over {value.group()!r}:\n{lines[0]}\n{line}")
        rows.append({label.group(): value.group() for label, value in zip(labels, values)})
    return rows


def table_after(text: str, labels: Sequence[str], rows: int) -> list[dict[str, str]]:
    """The first table of ``text`` whose header starts with ``labels[0]`` and holds every label of
    ``labels``, read with its next ``rows`` lines (:func:`table_rows`)."""
    lines = text.splitlines()
    at = next((i for i, line in enumerate(lines) if line.startswith(labels[0]) and all(w in line for w in labels)),
              None)
    assert at is not None, f"no table headed {list(labels)} in:\n{text}"
    assert len(lines) >= at + 1 + rows, f"fewer than {rows} rows under {lines[at]!r}"
    return table_rows(lines[at:at + 1 + rows])


@pytest.fixture
def shared_data() -> Path:
    """Root of ../shared/data (real imagery and OSM extracts made by others)."""
    if not SHARED_DATA.exists():
        pytest.skip("../shared/data is absent on this machine")
    return SHARED_DATA


def write_dataset_manifest(folder: Path, classes: Mapping[str, Any], samples: Sequence[Mapping[str, Any]]) -> Path:
    """A ``manifest.json`` that passes the dataset schema, for tests that make a dataset folder by
    hand (label masks only): ``samples`` give at least ``name`` and ``ground_resolution_m``."""
    rows = [{"center": None, "bbox_wgs84": [], "bounds_3857": [], "zoom": 18, "tiles": [], "imagery": {}, "osm": {},
             "class_histogram": {}, "files": {f"labels/{s['name']}.png": "0" * 64}, **s} for s in samples]
    manifest = {"format": "osmseg-dataset", "format_version": 1, "tool": {}, "command": "", "seed": 0, "area": {},
                "zoom": 18, "grid_size": len(rows), "filters": {}, "imagery": {}, "osm": {}, "rejected": [],
                "summary": {}, "classes": dict(classes), "samples": rows}
    path = Path(folder) / "manifest.json"
    path.write_text(json.dumps(manifest), encoding="utf-8")
    return path


@pytest.fixture(scope="session")
def imagery_tif(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A GeoTIFF in EPSG:3067 (not the tiles' CRS) painted from tinycity's labels over a 9x9-tile
    block: imagery whose every pixel says which class OSM puts there, for builds to line up with."""
    import rasterio
    from rasterio.warp import calculate_default_transform, reproject

    from osmseg.classes import load_class_table
    from osmseg.demo.render import render_aerial
    from osmseg.grid import sample_grid
    from osmseg.osm.features import read_features
    from osmseg.rasterize import rasterize

    table = load_class_table("classes13.toml")
    grid = sample_grid(*TINYCITY_CENTRE, 18, size=9)
    labels = rasterize(read_features([TINYCITY], grid, table), grid, table)
    rgb = render_aerial(labels, seed=3).transpose(2, 0, 1)
    dst_crs = "EPSG:3067"
    transform, width, height = calculate_default_transform(
        "EPSG:3857", dst_crs, grid.width, grid.height, *grid.xy_bounds)
    path = tmp_path_factory.mktemp("imagery") / "tinycity-tm35fin.tif"
    with rasterio.open(path, "w", driver="GTiff", width=width, height=height, count=3, dtype="uint8",
                       crs=dst_crs, transform=transform) as dst:
        for band in range(3):
            reproject(rgb[band], rasterio.band(dst, band + 1), src_transform=grid.transform,
                      src_crs="EPSG:3857", dst_transform=transform, dst_crs=dst_crs)
    return path


def made_once(tmp_path_factory: pytest.TempPathFactory, name: str, make: Callable[[Path], None]) -> Path:
    """The folder ``name`` that ``make(folder)`` fills, made once per test run and shared by every
    process of it: under pytest-xdist each worker has its own temporary folder, all in one parent,
    so the first worker to ask makes it there holding a lock, and the others wait for it and read
    it. For long read-only results several modules use; a test that changes files copies them
    first (``shutil.copytree``). A ``make`` that fails is tried again, afresh, by the next asker."""
    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    folder, done = root / name, root / f"{name}.done"
    with (root / f"{name}.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not done.exists():
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir()
            make(folder)
            done.touch()
    return folder


@pytest.fixture(scope="session")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``osmseg demo --no-train`` as a new user runs it (4 Helsinki samples replayed, 12 rendered
    panoramas localized, pictures drawn): ``demo/`` (dataset/ and localize/) and the command's
    ``stdout.txt`` and ``stderr.txt`` beside it. Session-scoped and made once for all workers
    (:func:`made_once`): half a minute of CPU that test_demo, test_data, test_loc_pictures and
    test_printed_tables each paid before. Read only: test_demo's ``verify`` checks every file's
    sha256 against the manifest, so a test that wrote into it would be caught."""
    def make(folder: Path) -> None:
        from click.testing import CliRunner

        from osmseg.cli.main import cli

        result = CliRunner().invoke(cli, ["demo", "--out", str(folder / "demo"), "--no-train"])
        assert result.exit_code == 0, result.output
        (folder / "stdout.txt").write_text(result.stdout)
        (folder / "stderr.txt").write_text(result.stderr)

    return made_once(tmp_path_factory, "demo-run", make)


# tests/data/*/data.py are generator scripts (run by hand), not test modules
collect_ignore_glob = ["data/*"]
