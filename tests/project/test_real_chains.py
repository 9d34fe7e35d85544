"""The commands users chain, run in order on the real data in ``../shared/data`` (skipped without it).

* **build -> localize-bench with the geometry renderer** (Kotka's real OSM): a dataset built from
  an OSM file is benched with views ray-cast from the same file. The dataset's manifest records
  its class table by name and colours only; the renderer needs the table's OSM tag rules, and
  takes them from the table file the build was given (``config.classes``). Before, this chain
  ended in a traceback (``TypeError: Need keys to filter on.``), for a mapped table (classes6)
  too. The imagery of such a build does not matter to a localization bench: here it is the
  builder's own label mask of the area as a GeoTIFF (``benchmarks/osm_mask.py``, what
  ``docs/localization.md`` uses), with ``--min-contrast 0``.
* **the README's training chain** (Kampala's drone tiles and OSM footprints, Inria's Austin
  tile): read out of README.md and run as written, in order (``tests/project/test_readme_chain.py``).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import REPO_ROOT, shared_path
from PIL import Image

from osmseg.cli.main import cli

KOTKA_LON, KOTKA_LAT = 26.9475, 60.5337


@pytest.fixture(scope="module")
def kotka_imagery(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A GeoTIFF over the Kotka test area (the builder's mask of the OSM there, 9x9 z18 tiles)."""
    pbf = shared_path("helsinki-osm", "kotka.osm.pbf")
    out = tmp_path_factory.mktemp("kotka") / "kotka.tif"
    subprocess.run([sys.executable, str(REPO_ROOT / "benchmarks" / "osm_mask.py"), str(pbf), str(out),
                    "--lon", str(KOTKA_LON), "--lat", str(KOTKA_LAT), "--size", "9"],
                   check=True, capture_output=True)
    return out


@pytest.mark.parametrize("classes", ["classes13.toml", "classes6.toml"])
def test_a_dataset_built_from_osm_is_benched_with_views_drawn_from_that_osm(
        kotka_imagery: Path, tmp_path: Path, classes: str) -> None:
    pbf = shared_path("helsinki-osm", "kotka.osm.pbf")
    data = tmp_path / "kotka"
    built = CliRunner().invoke(cli, [
        "-q", "build", "--lat", str(KOTKA_LAT), "--lon", str(KOTKA_LON), "--radius-km", "0.1", "--samples", "2",
        "--osm", str(pbf), "--imagery", f"geotiff:{kotka_imagery}", "--classes", classes,
        "--max-unlabeled", "0.95", "--min-contrast", "0", "--cache-dir", str(tmp_path / "cache"), "--out", str(data)])
    assert built.exit_code == 0, built.output

    out = tmp_path / "bench"
    bench = CliRunner().invoke(cli, [
        "-q", "localize-bench", str(data), "--renderer", "geometry", "--osm", str(pbf), "--fov", "90",
        "--view-heading", "unknown", "--viewpoints", "4", "--methods", "profile", "--save-panoramas", "1",
        "--out", str(out)])

    assert bench.exit_code == 0, bench.output
    assert "Traceback" not in bench.output
    results = json.loads((out / "results.json").read_text())
    assert results["settings"]["renderer"] == "geometry"
    assert results["methods"]["profile"]["n"] == 4
    # the saved view was drawn from the OSM in the dataset's classes: a building stands in it
    manifest = json.loads((data / "manifest.json").read_text())
    building = next(c["id"] for c in manifest["classes"]["classes"] if c["name"] == "building")
    view = np.asarray(Image.open(next((out / "panoramas").glob("*.png"))))
    assert view.ndim == 2 and (view == building).any()


def test_a_dataset_whose_class_table_file_is_gone_says_so_in_one_line(kotka_imagery: Path, tmp_path: Path) -> None:
    """A table the build read from a path that is not there any more: the recorded table names
    the classes but cannot draw OSM, and the bench says what to do instead of a traceback."""
    pbf = shared_path("helsinki-osm", "kotka.osm.pbf")
    table = tmp_path / "mine.toml"
    table.write_bytes((REPO_ROOT / "data_manifests" / "classes13.toml").read_bytes())  # a copy of the user's
    data = tmp_path / "kotka"
    built = CliRunner().invoke(cli, [
        "-q", "build", "--lat", str(KOTKA_LAT), "--lon", str(KOTKA_LON), "--radius-km", "0.1", "--samples", "1",
        "--osm", str(pbf), "--imagery", f"geotiff:{kotka_imagery}", "--classes", str(table),
        "--max-unlabeled", "0.95", "--min-contrast", "0", "--cache-dir", str(tmp_path / "cache"), "--out", str(data)])
    assert built.exit_code == 0, built.output
    table.unlink()

    bench = CliRunner().invoke(cli, [
        "localize-bench", str(data), "--renderer", "geometry", "--osm", str(pbf), "--viewpoints", "2",
        "--methods", "profile", "--out", str(tmp_path / "bench")])

    assert bench.exit_code == 2, bench.output
    assert "Traceback" not in bench.output
    error = [line for line in bench.output.splitlines() if line.startswith("Error:")]
    assert len(error) == 1 and "no OSM tag rules" in error[0] and "'osm13'" in error[0], bench.output
