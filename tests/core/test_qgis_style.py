"""QGIS names the classes the manifest names: ``geo/NAME.qml`` beside every label GeoTIFF.

A dataset is built through the real CLI (tinycity, ``--image-format cog``, ``--zip``). Its styles
are read back with other readers than the writer's (``xml.etree``): ``xml.dom.minidom`` and, where
the machine has it, QGIS itself (``qgis.core`` of the system Python, in a subprocess): the layer
QGIS makes of ``geo/NAME.tif`` must come with a paletted renderer whose legend reads the class
names, where without the style it reads the pixel values "0", "1", ... The colours and names in
the style are checked against the GeoTIFF's own colour table and ``CLASS_<id>`` tags (rasterio)
and the manifest's class table. ``osmseg verify`` and the zip must cover the style files.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import zipfile
from pathlib import Path
from xml.dom import minidom

import pytest
import rasterio
from click.testing import CliRunner
from conftest import TINYCITY, TINYCITY_CENTRE

from osmseg.cli.main import cli
from osmseg.output.manifest import verify

LON, LAT = TINYCITY_CENTRE
SYSTEM_PYTHON = "/usr/bin/python3"  # where Debian's python3-qgis puts QGIS's Python bindings


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory, imagery_tif: Path) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("styled") / "ds"
    result = CliRunner().invoke(cli, [
        "-q", "build", "--lat", str(LAT), "--lon", str(LON), "--radius-km", "0.08", "--samples", "2", "--seed", "1",
        "--image-format", "cog", "--imagery", f"geotiff:{imagery_tif}", "--osm", str(TINYCITY), "--out", str(out),
        "--cache-dir", str(out.parent / "cache"), "--zip"], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return out, json.loads((out / "manifest.json").read_text())


def palette_of(qml: Path) -> dict[int, tuple[str, str]]:
    """{value: (colour, label)} of the paletted renderer of a QGIS style, read with minidom."""
    root = minidom.parse(str(qml)).documentElement
    assert root is not None and root.tagName == "qgis"
    (renderer,) = root.getElementsByTagName("rasterrenderer")
    assert (renderer.getAttribute("type"), renderer.getAttribute("band")) == ("paletted", "1")
    entries = renderer.getElementsByTagName("paletteEntry")
    assert [e.getAttribute("alpha") for e in entries] == ["255"] * len(entries)
    return {int(e.getAttribute("value")): (e.getAttribute("color"), e.getAttribute("label")) for e in entries}


def test_every_label_geotiff_has_a_style_with_its_class_colours_and_names(built: tuple[Path, dict]) -> None:
    out, manifest = built
    by_id = {c["id"]: c for c in manifest["classes"]["classes"]}
    assert len(manifest["samples"]) == 2
    for sample in manifest["samples"]:
        name = sample["name"]
        assert f"geo/{name}.qml" in sample["files"]  # listed, with its sha256, like every sample file
        palette = palette_of(out / "geo" / f"{name}.qml")
        with rasterio.open(out / "geo" / f"{name}.tif") as src:
            colours, tags = src.colormap(1), src.tags(1)
        # the raster's own colour table and class tags, as rasterio reads them
        assert palette == {i: ("#{:02x}{:02x}{:02x}".format(*colours[i][:3]), tags[f"CLASS_{i}"]) for i in by_id}
        assert {i: label for i, (_, label) in palette.items()} == {i: c["name"] for i, c in by_id.items()}
        assert palette[8] == ("#{:02x}{:02x}{:02x}".format(*by_id[8]["color"]), "water")


def test_verify_and_the_zip_cover_the_styles(built: tuple[Path, dict], tmp_path: Path) -> None:
    out, manifest = built
    name = manifest["samples"][0]["name"]
    style = out / "geo" / f"{name}.qml"
    with zipfile.ZipFile(out.parent / f"{out.name}.zip") as zf:
        assert zf.read(f"{out.name}/geo/{name}.qml") == style.read_bytes()
    copy = tmp_path / "ds"
    shutil.copytree(out, copy)
    assert verify(copy) == []
    (copy / "geo" / f"{name}.qml").write_text(style.read_text().replace('label="water"', 'label="sea"'))
    assert verify(copy) == [f"geo/{name}.qml: modified (sha256 differs from the manifest)"]
    (copy / "geo" / f"{name}.qml").unlink()
    assert verify(copy) == [f"geo/{name}.qml: missing"]


QGIS_SCRIPT = """
import os, sys
os.environ["QT_QPA_PLATFORM"] = "offscreen"
from qgis.core import QgsApplication, QgsRasterLayer
app = QgsApplication([], False)
app.initQgis()
layer = QgsRasterLayer(sys.argv[1], "labels", "gdal")
renderer = layer.renderer()
print(layer.isValid(), renderer.type())
for text, colour in renderer.legendSymbologyItems():
    print(text + "\\t" + colour.name())
sys.stdout.flush()
os._exit(0)  # QGIS's exitQgis() and teardown crash headless; everything needed is printed
"""


def qgis_legend(tif: Path) -> tuple[str, list[tuple[str, str]]]:
    """(renderer type, legend entries (text, colour)) of the layer QGIS makes of ``tif``."""
    run = subprocess.run([SYSTEM_PYTHON, "-c", QGIS_SCRIPT, str(tif)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    head, *lines = run.stdout.splitlines()
    assert head.startswith("True "), run.stdout  # a valid layer
    return head.split()[1], [tuple(line.split("\t")) for line in lines]  # type: ignore[misc]


def test_qgis_itself_shows_the_class_names_in_the_legend(built: tuple[Path, dict], tmp_path: Path) -> None:
    probe = subprocess.run([SYSTEM_PYTHON, "-c", "import qgis.core"], capture_output=True)
    if probe.returncode != 0:
        pytest.skip("QGIS's Python bindings are not installed here (Debian: python3-qgis)")
    out, manifest = built
    name = manifest["samples"][0]["name"]
    kind, legend = qgis_legend(out / "geo" / f"{name}.tif")
    classes = sorted(manifest["classes"]["classes"], key=lambda c: c["id"])
    assert kind == "paletted"
    assert legend == [(c["name"], "#{:02x}{:02x}{:02x}".format(*c["color"])) for c in classes]
    # the check has teeth: without its style, QGIS labels the same raster's entries by value
    bare = tmp_path / "bare.tif"
    shutil.copy(out / "geo" / f"{name}.tif", bare)
    kind, legend = qgis_legend(bare)
    assert kind == "paletted" and legend[:3] == [("0", "#000000"), ("1", legend[1][1]), ("2", legend[2][1])]
