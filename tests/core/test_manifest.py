"""The manifest as every package reads it (osmseg.output.manifest): typed, versioned, and written
back byte for byte. A user checks three things: a dataset built now reads and writes back the same
bytes; a dataset of the first format version (older osmseg) is still read; a manifest of a version
this osmseg does not know is refused in one line that says what to do."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner
from conftest import TEST_DATA
from test_build import build_args, run_cli

from osmseg.cli.main import cli
from osmseg.errors import DatasetError
from osmseg.output.manifest import (
    FORMAT_VERSION,
    READ_VERSIONS,
    DatasetManifest,
    manifest_text,
    read_manifest,
    verify,
    write_manifest,
)

TINYSEG = TEST_DATA / "tinyseg"  # a hand-made dataset of format version 1


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory, imagery_tif: Path) -> Path:
    """A dataset built by ``osmseg build``, with rejected attempts (a strict unlabeled threshold)."""
    out = tmp_path_factory.mktemp("built") / "ds"
    result = run_cli(*build_args(out, imagery_tif, "--max-unlabeled", "0.65", samples=3))
    assert result.exit_code == 0, result.output
    return out


def test_a_built_manifest_read_and_written_again_is_the_same_bytes(built: Path, tmp_path: Path) -> None:
    text = (built / "manifest.json").read_text(encoding="utf-8")
    manifest = read_manifest(built)
    assert manifest.format_version == FORMAT_VERSION == 2
    assert manifest.rejected and manifest.samples and all(s.overlap_group is not None for s in manifest.samples)
    assert manifest_text(manifest) == text
    assert json.dumps(manifest.to_json(), sort_keys=True, indent=2, ensure_ascii=False) + "\n" == text
    assert DatasetManifest.from_json(json.loads(text)).to_json() == json.loads(text)
    write_manifest(tmp_path, manifest)
    assert (tmp_path / "manifest.json").read_bytes() == (built / "manifest.json").read_bytes()


def test_a_built_manifest_reads_as_attributes(built: Path) -> None:
    """What the JSON says, the typed manifest says: a few of the fields readers use."""
    data = json.loads((built / "manifest.json").read_text(encoding="utf-8"))
    manifest = read_manifest(built)
    first = manifest.samples[0]
    assert first.name == data["samples"][0]["name"] and list(first.bounds_3857 or ()) == data["samples"][0]["bounds_3857"]
    assert first.ground_resolution_m == data["samples"][0]["ground_resolution_m"]
    assert manifest.summary.accepted == data["summary"]["accepted"] == len(manifest.samples)
    assert [r.reason for r in manifest.rejected] == [r["reason"] for r in data["rejected"]]
    assert manifest.classes.to_dict() == data["classes"] and manifest.command == data["command"]


def test_a_version_1_manifest_is_read(tmp_path: Path) -> None:
    """Format 1 (osmseg before 0.5) kept every build setting in ``config`` and lacks what came later
    without a new version (``config`` itself in a dataset made by hand, the overlap groups, the
    summary's overlap counts): read, with those None, and its files verified."""
    manifest = read_manifest(TINYSEG)
    assert manifest.format_version == 1 and 1 in READ_VERSIONS
    assert len(manifest.samples) == 12 and manifest.classes.name == "tinyseg"
    assert manifest.samples[0].overlap_group is None and manifest.summary.overlap_groups is None
    assert manifest.samples[0].ground_resolution_m is None and manifest.build_identity() == {}
    assert manifest_text(manifest) == (TINYSEG / "manifest.json").read_text(encoding="utf-8")
    copy = tmp_path / "tinyseg"
    shutil.copytree(TINYSEG, copy, ignore=shutil.ignore_patterns("*.py"))
    assert verify(copy) == []


@pytest.mark.parametrize("version", [3, 0, "2", None])
def test_an_unknown_version_is_refused_in_one_line(tmp_path: Path, version: object) -> None:
    data = json.loads((TINYSEG / "manifest.json").read_text(encoding="utf-8"))
    data["format_version"] = version
    (tmp_path / "manifest.json").write_text(json.dumps(data), encoding="utf-8")
    with pytest.raises(DatasetError) as info:
        read_manifest(tmp_path)
    message = str(info.value)
    assert "\n" not in message and f"format_version {version!r}" in message
    assert "rebuild the dataset with this osmseg" in message and "(1, 2)" in message
    result = CliRunner().invoke(cli, ["verify", str(tmp_path)])  # what a user sees
    assert result.exit_code != 0 and result.stderr.count("\n") == 1 and "format_version" in result.stderr
