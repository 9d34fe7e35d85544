"""``osmseg build`` end to end through the real CLI, on local sources made by the project.

The OSM data is ``tests/data/tinycity/tinycity.osm``; the imagery is a GeoTIFF rendered
from the same OSM data (``osmseg.demo.render``) in a *different* CRS (ETRS-TM35FIN, the
Finnish national grid), so the builder must warp it onto each sample's Web Mercator grid.
Because the imagery was painted from the labels, a correct build puts every class on pixels
of that class's material: that is the line-up check.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from conftest import TEST_DATA, TINYCITY, TINYCITY_CENTRE
from PIL import Image
from rio_cogeo.cogeo import cog_validate
from servers import ScriptedServer

from osmseg.classes import load_class_table
from osmseg.cli.main import cli
from osmseg.demo.render import IDS13, MATERIALS

LON, LAT = TINYCITY_CENTRE
TABLE = load_class_table("classes13.toml")


def build_args(out: Path, imagery: Path, *extra: str, samples: int = 3) -> list[str]:
    return ["build", "--lat", str(LAT), "--lon", str(LON), "--radius-km", "0.08", "--samples", str(samples),
            "--seed", "1", "--imagery", f"geotiff:{imagery}", "--osm", str(TINYCITY), "--out", str(out),
            "--cache-dir", str(out.parent / "cache"), *extra]


def run_cli(*args: str) -> click.testing.Result:  # noqa: F821
    return CliRunner().invoke(cli, ["-q", *args], catch_exceptions=False)


def tree_bytes(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` except the resumable-state folder, by relative path."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and ".osmseg-build" not in p.parts}


def test_build_writes_a_dataset_whose_masks_line_up_with_the_imagery(tmp_path: Path, imagery_tif: Path) -> None:
    out = tmp_path / "ds"
    result = run_cli(*build_args(out, imagery_tif))
    assert result.exit_code == 0, result.output
    assert result.stdout.strip() == str(out / "manifest.json")
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["summary"]["accepted"] == 3 and manifest["seed"] == 1
    for sample in manifest["samples"]:
        name = sample["name"]
        labels = np.asarray(Image.open(out / "labels" / f"{name}.png"))
        image = np.asarray(Image.open(out / "images" / f"{name}.png")).astype(float)
        colour = np.asarray(Image.open(out / "segmented" / f"{name}.png"))
        assert labels.shape == (1280, 1280) and image.shape == (1280, 1280, 3)
        assert (colour == TABLE.colorize(labels)).all()
        present = [c for c in np.unique(labels) if (labels == c).sum() > 2000]
        assert len(present) >= 4
        # each class sits on pixels painted with that class's material, not another's
        materials = {IDS13[n]: np.array(rgb, float) for n, rgb in MATERIALS.items()}
        for c in present:
            if c in (IDS13["tree"], IDS13["park"], IDS13["natural"], IDS13["grass"]):
                continue  # vegetation materials are too alike to tell apart by mean colour
            mean = image[labels == c].mean(axis=0)
            nearest = min(materials, key=lambda k: np.linalg.norm(materials[k] - mean))
            assert nearest == c, f"{name}: class {c} pixels look like class {nearest}"
        with rasterio.open(out / "geo" / f"{name}.tif") as geo:
            assert geo.crs.to_epsg() == 3857
            assert (geo.read(1) == labels).all()
    for extra in ("DATASHEET.md", "ATTRIBUTION.md", "overview.png", "class_histogram.png"):
        assert (out / extra).stat().st_size > 0
    # each build setting is written once (format 2), and together they are what decided the content
    from osmseg.output.manifest import TOP_LEVEL_SETTINGS, read_manifest, verify

    assert manifest["format_version"] == 2 and not set(manifest["config"]) & set(TOP_LEVEL_SETTINGS)
    identity = read_manifest(out).build_identity()
    assert identity == json.loads((out / ".osmseg-build" / "config.json").read_text())
    # a format-1 manifest (every setting again in config) is still read and verified
    old = dict(manifest, format_version=1, config=identity)
    (out / "manifest.json").write_text(json.dumps(old, indent=2, sort_keys=True) + "\n")
    assert verify(out) == [] and read_manifest(out).build_identity() == identity


def test_cog_images_and_labels_share_one_grid_and_are_cloud_optimized(tmp_path: Path, imagery_tif: Path) -> None:
    """--image-format cog: images/NAME.tif on exactly geo/NAME.tif's grid, both COGs by rio-cogeo's
    validator, the photo's pixels those of the PNG build (lossless), class names in the label tags."""
    png_out, cog_out = tmp_path / "png" / "ds", tmp_path / "cog" / "ds"
    assert run_cli(*build_args(png_out, imagery_tif, samples=2)).exit_code == 0
    assert run_cli(*build_args(cog_out, imagery_tif, "--image-format", "cog", samples=2)).exit_code == 0
    manifest = json.loads((cog_out / "manifest.json").read_text())
    assert manifest["image_format"] == "cog"
    for sample in manifest["samples"]:
        name = sample["name"]
        assert set(sample["files"]) == {f"images/{name}.tif", f"segmented/{name}.png", f"labels/{name}.png",
                                        f"geo/{name}.tif", f"geo/{name}.qml"}
        image_path, label_path = cog_out / "images" / f"{name}.tif", cog_out / "geo" / f"{name}.tif"
        for path in (image_path, label_path):
            valid, errors, _ = cog_validate(str(path))
            assert valid, (path, errors)
        with rasterio.open(image_path) as image, rasterio.open(label_path) as label:
            assert image.crs.to_epsg() == label.crs.to_epsg() == 3857
            assert image.transform == label.transform and image.shape == label.shape == (1280, 1280)
            assert image.count == 3 and label.count == 1 and image.block_shapes[0] == (256, 256)
            assert image.overviews(1) == label.overviews(1) == [2, 4, 8]
            assert label.nodata is None  # class 0 is a label, not missing data (osmseg.output.geotiff)
            png = np.asarray(Image.open(png_out / "images" / f"{name}.png"))
            assert np.array_equal(image.read().transpose(1, 2, 0), png)
            classes = label.read(1)
            assert np.array_equal(classes, np.asarray(Image.open(cog_out / "labels" / f"{name}.png")))
            # nearest-neighbour overviews: every overview pixel is a class id of the full mask
            assert set(np.unique(label.read(1, out_shape=(320, 320)))) <= set(np.unique(classes))
            names = {int(k.split("_")[1]): v for k, v in label.tags(1).items() if k.startswith("CLASS_")}
            assert names == {c["id"]: c["name"] for c in manifest["classes"]["classes"]}
            assert label.tags()["CLASS_TABLE"] == manifest["classes"]["name"]
            assert label.colormap(1)[1][:3] == tuple(TABLE.by_name["building"].color)
        # the bounds in the manifest are the GeoTIFF's
        assert tuple(sample["bounds_3857"]) == pytest.approx(tuple(rasterio.open(label_path).bounds))


def test_interrupted_build_resumes_to_identical_bytes(tmp_path: Path, imagery_tif: Path) -> None:
    """kill -9 in the middle, rerun the same command: same files as a build never interrupted."""
    whole = tmp_path / "whole" / "ds"
    assert run_cli(*build_args(whole, imagery_tif, samples=4)).exit_code == 0

    killed = tmp_path / "killed" / "ds"
    cmd = [sys.executable, "-m", "osmseg", "-q", *build_args(killed, imagery_tif, samples=4)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    slots = killed / ".osmseg-build" / "slots"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None and len(list(slots.glob("*.json"))) < 1:
        time.sleep(0.02)
    assert proc.poll() is None, f"build exited early: {proc.communicate()[1].decode()[-500:]}"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (killed / "manifest.json").exists(), "the build finished before it could be killed"

    result = run_cli(*build_args(killed, imagery_tif, samples=4))
    assert result.exit_code == 0, result.output
    assert tree_bytes(killed) == tree_bytes(whole)


def test_shards_together_give_the_single_run_dataset(tmp_path: Path, imagery_tif: Path) -> None:
    single = tmp_path / "single" / "ds"
    sharded = tmp_path / "sharded" / "ds"
    assert run_cli(*build_args(single, imagery_tif, samples=4)).exit_code == 0
    first = run_cli(*build_args(sharded, imagery_tif, "--shard", "1/2", samples=4))
    assert first.exit_code == 0 and not (sharded / "manifest.json").exists()
    second = run_cli(*build_args(sharded, imagery_tif, "--shard", "2/2", samples=4))
    assert second.exit_code == 0
    assert tree_bytes(sharded) == tree_bytes(single)


def test_the_last_shard_to_finish_reports_the_dataset_not_its_own_share(tmp_path: Path, imagery_tif: Path) -> None:
    """Shard 2/2 of a 1-sample build owns no slot: it finishes the dataset and exits 0."""
    out = tmp_path / "ds"
    assert run_cli(*build_args(out, imagery_tif, "--shard", "1/2", samples=1)).exit_code == 0
    last = CliRunner().invoke(cli, build_args(out, imagery_tif, "--shard", "2/2", samples=1))
    assert last.exit_code == 0, last.output
    assert "the dataset holds 1" in last.stderr and (out / "manifest.json").exists()


def test_classes6_build_maps_the_13_classes_and_zips(tmp_path: Path, imagery_tif: Path) -> None:
    out = tmp_path / "ds6"
    assert run_cli(*build_args(out, imagery_tif, "--classes", "classes6.toml", "--zip", samples=1)).exit_code == 0
    with zipfile.ZipFile(tmp_path / "ds6.zip") as zf:
        names = zf.namelist()
    assert "ds6/manifest.json" in names or "manifest.json" in names
    assert any(n.endswith(".tif") for n in names) and not any(".osmseg-build" in n for n in names)
    manifest = json.loads((out / "manifest.json").read_text())
    labels = np.asarray(Image.open(out / "labels" / f"{manifest['samples'][0]['name']}.png"))
    assert set(np.unique(labels)) <= set(range(7))
    assert [c["name"] for c in manifest["classes"]["classes"]][1:] == [
        "building", "highway", "natural", "water", "footway", "dirt road"]


def test_rerun_into_a_folder_of_another_build_is_refused(tmp_path: Path, imagery_tif: Path) -> None:
    out = tmp_path / "ds"
    assert run_cli(*build_args(out, imagery_tif, samples=1)).exit_code == 0
    before = tree_bytes(out)
    result = CliRunner().invoke(cli, ["-q", *build_args(out, imagery_tif, "--zoom", "17", samples=1)])
    assert result.exit_code == 1
    assert "different build" in result.output and "zoom" in result.output
    assert tree_bytes(out) == before


def test_a_folder_with_no_accepted_sample_is_taken_over_by_the_corrected_command(
        tmp_path: Path, imagery_tif: Path) -> None:
    """Filters too strict: every attempt rejected, no sample. The corrected command is not refused,
    and the old options' records are gone (the result equals a build into a fresh folder)."""
    out = tmp_path / "ds"
    strict = CliRunner().invoke(cli, ["-q", *build_args(out, imagery_tif, "--min-classes", "30", "--max-tries", "2",
                                                         samples=1)])
    assert strict.exit_code == 1 and "no sample was accepted" in strict.output
    assert any((out / ".osmseg-build" / "attempts").glob("*.json"))
    fixed = run_cli(*build_args(out, imagery_tif, samples=1))
    assert fixed.exit_code == 0, fixed.output
    fresh = tmp_path / "fresh" / "ds"
    assert run_cli(*build_args(fresh, imagery_tif, samples=1)).exit_code == 0
    assert tree_bytes(out) == tree_bytes(fresh)


def test_a_build_stops_when_another_command_takes_its_folder_over(tmp_path: Path) -> None:
    """Two commands with other options on one folder (say, shards started with a typo): the one
    that lost the folder stops at its next record instead of mixing its samples in."""
    from osmseg.builder.records import Attempt
    from osmseg.builder.state import BuildState
    from osmseg.errors import DatasetError
    from osmseg.output.manifest import Point, RejectionRecord

    rejected = Attempt.rejected(RejectionRecord(Point(0, 0), "unlabeled", "all unlabeled"))
    first, second = BuildState(tmp_path), BuildState(tmp_path)
    first.check_config({"seed": 1})
    second.check_config({"seed": 2})  # nothing accepted yet: the folder is taken over
    with pytest.raises(DatasetError, match="taken over by a build with other options"):
        first.record_attempt(0, 0, rejected)
    second.record_attempt(0, 0, rejected)
    assert second.attempt(0, 0) == rejected  # read back as the value it was


@pytest.mark.parametrize(
    ("args", "code", "says"),
    [
        (["build", "--city", "Atlantis", "--out", "x"], 2, "Berlin"),
        (["build", "--city", "Berlin", "--lat", "1", "--out", "x"], 2, "exactly one"),
        (["build", "--bbox", "1,2,3", "--out", "x", "--imagery", "xyz:file:///tmp/{z}/{x}/{y}.png"], 2, "W,S,E,N"),
        (["build", "--city", "Berlin", "--out", "x", "--osm", "/no/such/file.osm.pbf",
          "--imagery", "xyz:file:///tmp/{z}/{x}/{y}.png"], 2, "not found"),
        (["build", "--city", "Berlin", "--out", "x", "--imagery", "bing"], 2, "BING_MAPS_KEY"),
        (["build", "--city", "Berlin", "--out", "x", "--imagery", "carrier-pigeon"], 2, "imagery"),
        (["build", "--city", "Berlin", "--radius-km", "nan", "--out", "x", "--imagery", "Esri.WorldImagery"], 2,
         "finite radius"),
        (["build", "--city", "Paris", "--zoom", "20", "--out", "x", "--imagery", "GeoportailFrance.orthos"], 2,
         "use --zoom 19 or lower"),
        (["build", "--city", "Paris", "--out", "x", "--imagery", f"geotiff:{TEST_DATA}/imagery/utm-rgb.tif"], 2,
         "misses the sampling area"),
    ],
)
def test_bad_input_gives_one_line_and_a_usage_exit(tmp_path: Path, args: list[str], code: int, says: str,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("BING_MAPS_KEY", raising=False)
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == code, result.output
    assert says in result.output
    assert "Traceback" not in result.output
    assert not (tmp_path / "x" / "manifest.json").exists()


def test_osm_objects_that_cannot_be_placed_are_said_loudly_and_recorded(tmp_path: Path, imagery_tif: Path,
                                                                         http_server: ScriptedServer) -> None:
    """An OSM API answer whose ways come without their nodes: a warning on stderr, and counts in
    the manifest, instead of a silently empty mask."""
    from servers import Reply

    xml = re.sub(r"<node [^>]*/>\n|<node [^>]*>.*?</node>\n", "", TINYCITY.read_text(), flags=re.S)
    assert "<node" not in xml and "<way" in xml
    http_server.script("/api/0.6/map", Reply(200, xml, {"Content-Type": "text/xml; charset=utf-8"}))
    args = build_args(tmp_path / "ds", imagery_tif, "--max-tries", "2", "--max-unlabeled", "1", "--min-classes", "0",
                      samples=1)
    args[args.index(str(TINYCITY))] = "api:" + http_server.url("/api/0.6")
    result = CliRunner().invoke(cli, args)  # not -q: the summary is what a user reads
    assert "OSM objects that match a class were not drawn" in result.stderr, result.output
    assert "Traceback" not in result.output
    state = [json.loads(p.read_text()) for p in (tmp_path / "ds" / ".osmseg-build" / "attempts").glob("*.json")]
    assert state and all(r.get("osm_unplaced", 0) > 10 for r in state)
    assert all(any("no node with a location" in p for p in r["osm_problems"]) for r in state)


def test_geojson_tags_that_no_class_draws_are_refused_up_front(tmp_path: Path, imagery_tif: Path) -> None:
    (tmp_path / "f.geojson").write_text('{"type": "FeatureCollection", "features": []}')
    args = build_args(tmp_path / "ds", imagery_tif, samples=1)
    args[args.index(str(TINYCITY))] = f"geojson:{tmp_path / 'f.geojson'}:shop=bakery"
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 2 and "no class of osm13 has a rule for these tags" in result.output
    assert not (tmp_path / "ds").exists()


def test_malformed_osm_file_fails_with_one_line(tmp_path: Path, imagery_tif: Path) -> None:
    broken = tmp_path / "broken.osm"
    broken.write_bytes(TINYCITY.read_bytes()[:5000])
    args = build_args(tmp_path / "ds", imagery_tif, samples=1)
    args[args.index(str(TINYCITY))] = str(broken)
    result = CliRunner().invoke(cli, ["-q", *args])
    assert result.exit_code == 1
    message = result.output.strip()
    assert message.startswith("Error:") and "\n" not in message and "broken" in message


@pytest.mark.parametrize("args", [
    ["--city", "Helsinki", "--samples", "4", "--no-overlap", "--imagery", "xyz:https://t.example/{z}/{x}/{y}.png"],
    ["--lat", "52.520008", "--lon", "13.404954", "--radius-km", "2", "--max-missing-imagery", "0.123456789",
     "--min-contrast", "3.25", "--zoom", "19", "--image-format", "cog", "--osm", "overpass", "--imagery", "Esri.WorldImagery"],
    ["--bbox", "24.9,60.1,25.0,60.2", "--classes", "classes6.toml", "--max-unlabeled", "0.5", "--min-classes", "3",
     "--sample-tiles", "3",
     "--max-placeholder-tiles", "2", "--max-tries", "4", "--seed", "9", "--imagery", "bing"],
])
def test_the_recorded_command_reads_back_as_the_same_build(args: list[str], tmp_path: Path) -> None:
    """The manifest's command comes from the build command's own option table: run as it is
    written, it describes the same dataset (every content value, none lost to rounding), and
    every option of ``osmseg build`` either appears in it or is declared as not changing content."""
    import shlex

    from osmseg.cli.build import (
        NOT_CONTENT,
        BuildOptions,
        build_command,
        build_config,
        content_options,
        recorded_command,
    )
    from osmseg.output import command_line

    def parse(argv: list[str]):
        ctx = build_command.make_context("build", [*argv, "--out", str(tmp_path / "out")])
        return build_config(BuildOptions.from_params(ctx.params))

    config = parse(args)
    line = command_line(recorded_command(config))
    words = shlex.split(line)
    assert words[:2] == ["osmseg", "build"] and "--out" not in words
    assert parse(words[2:]).identity() == config.identity()
    names = {p.name for p in build_command.params}
    assert names == set(content_options(config)) | NOT_CONTENT  # no option unaccounted for
    given = {name for name, value in content_options(config).items() if value is not None and value is not False}
    assert {max(p.opts, key=len) for p in build_command.params if p.name in given} == {
        w for w in words if w.startswith("--")}
