"""``osmseg eval`` and ``osmseg predict`` on a dataset built at another ground resolution than the
model's training data: Inria's real Austin tile built as docs/imagery.md shows (zoom 19, about
0.26 m pixels, PNG samples), and a model whose training data had finer pixels (the README's
Kampala drone tiles: 0.075 m). Skipped without ``../shared/data``.

Before, eval said nothing of the difference, and ``--resolution model`` could not resample
the dataset's PNGs ("... is not georeferenced: --resolution cannot apply", once per image),
although the manifest records each sample's ground resolution and bounds. Now the manifest places
each PNG: without ``--resolution`` one warning names ``--resolution model``; with it the PNGs are
resampled exactly as GeoTIFFs of the same samples are (the same dataset built with
``--image-format cog`` gives the very same metrics), and any message about the inputs is said
once for all of them.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import rasterio
import rasterio.features
from click.testing import CliRunner, Result
from conftest import TEST_DATA, shared_path
from PIL import Image
from pyproj import Transformer

from osmseg.cli.main import cli

TRAINED_AT = 0.13  # m per pixel: finer than Austin's, as the README's Kampala drone tiles (0.075 m; fewer windows here)
SAMPLES = 4


def osmseg(*args: object) -> Result:
    return CliRunner().invoke(cli, [str(a) for a in args])


def austin_buildings(folder: Path) -> Path:
    """Austin's own building mask as WGS84 polygons (what docs/imagery.md makes with ``rio shapes``)."""
    with rasterio.open(shared_path("inria-austin", "buildings.tif")) as ds:
        mask = ds.read(1)
        to_wgs84 = Transformer.from_crs(ds.crs, "EPSG:4326", always_xy=True)
        shapes = list(rasterio.features.shapes(mask, mask=mask > 0, transform=ds.transform))
    features = [{"type": "Feature", "properties": {}, "geometry": {
        "type": "Polygon", "coordinates": [[list(to_wgs84.transform(x, y)) for x, y in ring]
                                           for ring in geometry["coordinates"]]}} for geometry, _ in shapes]
    path = folder / "austin-buildings.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    return path


@pytest.fixture(scope="module")
def austin(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """docs/imagery.md's Austin dataset (4 of its 9 samples) as PNGs and as COGs, and a model trained on
    finer pixels."""
    folder = tmp_path_factory.mktemp("austin")
    geojson = austin_buildings(folder)
    built = {}
    for kind in ("png", "cog"):
        out = folder / f"austin-{kind}"
        result = osmseg("-q", "build", "--bbox", "-97.78318,30.22278,-97.78004,30.22550", "--zoom", 19,
                        "--sample-tiles", 1, "--no-overlap", "--samples", SAMPLES, "--image-format", kind,
                        "--imagery", f"geotiff:{shared_path('inria-austin', 'image.tif')}",
                        "--osm", f"geojson:{geojson}:building=yes", "--min-classes", 1, "--max-unlabeled", 0.99,
                        "--cache-dir", folder / "cache", "--out", out)
        assert result.exit_code == 0, result.output
        built[kind] = out
    samples = json.loads((built["png"] / "manifest.json").read_text())["samples"]
    assert len(samples) == SAMPLES and all(0.25 < s["ground_resolution_m"] < 0.27 for s in samples)
    # the model: trained on a copy whose manifest says its pixels are finer
    fine = Path(shutil.copytree(built["png"], folder / "as-if-kampala"))
    manifest = json.loads((fine / "manifest.json").read_text())
    for sample in manifest["samples"]:
        sample["ground_resolution_m"] = TRAINED_AT
    (fine / "manifest.json").write_text(json.dumps(manifest))
    run = folder / "run"
    result = osmseg("-q", "train", fine, "--out", run, "--config", TEST_DATA / "train" / "tiny.yaml", "--epochs", 1)
    assert result.exit_code == 0, result.output
    return {**built, "checkpoint": run / "best.pt"}


def warnings_of(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]


def test_eval_of_a_dataset_at_another_resolution_says_so_once(austin: dict[str, Path], tmp_path: Path,
                                                               caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level("WARNING"):
        result = osmseg("eval", austin["checkpoint"], austin["png"], "--out", tmp_path / "eval")
    assert result.exit_code == 0, result.output
    said = [w for w in warnings_of(caplog) if "m pixels" in w]
    assert len(said) == 1, warnings_of(caplog)
    assert f"all {SAMPLES} images" in said[0] and "0.258 m pixels" in said[0] and "0.13 m pixels" in said[0]
    assert "--resolution model" in said[0] and "2.0x smaller" in said[0]


def test_eval_resolution_model_resamples_a_datasets_pngs_as_its_geotiffs(austin: dict[str, Path], tmp_path: Path,
                                                                        caplog: pytest.LogCaptureFixture) -> None:
    metrics = {}
    for run, data, extra in [("png", austin["png"], ["--resolution", "model"]),
                             ("cog", austin["cog"], ["--resolution", "model"]),
                             ("as-is", austin["png"], []),
                             ("metres", austin["png"], ["--resolution", str(TRAINED_AT)])]:
        caplog.clear()
        with caplog.at_level("WARNING"):
            result = osmseg("eval", austin["checkpoint"], data, "--out", tmp_path / run, *extra)
        assert result.exit_code == 0, result.output
        said = [w for w in warnings_of(caplog) if "georeferenced" in w or "m pixels" in w]
        assert said == [] if extra else len(said) == 1, warnings_of(caplog)
        metrics[run] = json.loads((tmp_path / run / "metrics.json").read_text())
    assert metrics["png"]["evaluated"]["resolution_m"] == TRAINED_AT
    # the PNGs placed by the manifest are resampled exactly as the GeoTIFFs of the same samples
    assert metrics["png"]["confusion_matrix"] == metrics["cog"]["confusion_matrix"]
    assert metrics["png"]["confusion_matrix"] == metrics["metres"]["confusion_matrix"]
    # and resampled they were: the model saw them at another size than as they are
    assert metrics["png"]["confusion_matrix"] != metrics["as-is"]["confusion_matrix"]
    # labels compared on their own grid: every pixel once
    assert metrics["png"]["num_pixels"] == metrics["as-is"]["num_pixels"] == SAMPLES * 256 * 256


def test_predict_places_a_datasets_images_and_says_an_unplaced_one_once(austin: dict[str, Path], tmp_path: Path,
                                                                        caplog: pytest.LogCaptureFixture) -> None:
    """A dataset's PNGs given to predict are placed by their manifest too; PNGs outside a dataset
    cannot be resampled, and that is said once for all of them, with their count."""
    images = sorted((austin["png"] / "images").glob("*.png"))
    loose = tmp_path / "loose"
    loose.mkdir()
    for image in images[:3]:
        shutil.copy(image, loose / image.name.replace("bbox", "photo"))
    with caplog.at_level("WARNING"):
        result = osmseg("predict", austin["checkpoint"], *images[:2], *sorted(loose.iterdir()),
                        "--resolution", "model", "--out", tmp_path / "masks")
    assert result.exit_code == 0, result.output
    said = [w for w in warnings_of(caplog) if "--resolution" in w]
    assert len(said) == 1, warnings_of(caplog)
    assert said[0].startswith("3 of the 5 images") and "not georeferenced" in said[0], said[0]
    assert "bbox_" not in said[0]  # the dataset's images were placed
    for image in images[:2]:  # masks on each input's own grid
        with Image.open(tmp_path / "masks" / image.name) as mask:
            assert mask.size == (256, 256)
