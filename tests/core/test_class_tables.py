"""Class tables: what cannot be compared is refused, what a shipped mapping relates still works.

Issue 31, items 1 and 4, met as a user meets them, through the CLI:

* ``osmseg eval`` of a checkpoint on labels of another class table (a CamVid model on a 13-class
  dataset, a tinyseg model on one) scored one class's pixels as another's with exit 0: refused
  (exit 2, one line naming both tables); ``predict`` into a dataset folder of another table too;
* AirSegNet6 on a 13-class dataset still evaluates through ``classes6.toml``, and AirSegNet13 on
  a 6-class dataset now does too (its outputs mapped the same way) instead of being refused;
* ``osmseg train --classes`` no longer reads a dataset's labels as another table's;
* ``--init`` of a file that is neither a checkpoint nor vgg16_bn weights says so;
* a broken class table (two classes of one name or colour, ids not 0..N, a field missing, bad
  TOML) is refused by ``build`` and ``train`` before anything is built, naming the file.

Checkpoints are made with the project's own ``save_checkpoint`` (untrained, tiny): the class
table a checkpoint carries is what is under test, not what it learnt.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result
from conftest import TEST_DATA, TINYCITY, TINYCITY_CENTRE, write_dataset_manifest
from PIL import Image

from osmseg.classes import ClassTable, load_class_table
from osmseg.cli.main import cli
from osmseg.datafiles import DATA_DIR

torch = pytest.importorskip("torch")

TINYSEG = TEST_DATA / "tinyseg"
TINY_YAML = TEST_DATA / "train" / "tiny.yaml"


@pytest.fixture(scope="module", autouse=True)
def one_thread() -> Iterator[None]:
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def osmseg(*args: object) -> Result:
    return CliRunner().invoke(cli, ["-q", *(str(a) for a in args)])


def error_line(result: Result) -> str:
    """The one ``Error:`` line of a failed command (no traceback)."""
    assert "Traceback" not in result.output, result.output
    lines = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(lines) == 1, result.output
    return lines[0]


def checkpoint(path: Path, name: str, table: str | dict[str, object] | None = None) -> Path:
    """An untrained tiny checkpoint of model ``name`` predicting ``table``'s classes."""
    from training.models.checkpoint import save_checkpoint
    from training.models.networks import build_model, model_spec

    torch.manual_seed(0)
    spec = model_spec(name, 0.0625, class_table=table, input_size=(64, 96))
    save_checkpoint(path, {"spec": spec, "model": build_model(spec).state_dict()})
    return path


def dataset(root: Path, table: ClassTable, ids: list[int], samples: int = 2) -> Path:
    """A dataset folder as ``osmseg build`` leaves it (images/, labels/, manifest.json naming
    ``table``) whose labels hold the class ids ``ids`` in vertical bands."""
    rng = np.random.default_rng(0)
    for folder in ("images", "labels"):
        (root / folder).mkdir(parents=True, exist_ok=True)
    rows = []
    for i in range(samples):
        label = np.zeros((64, 96), np.uint8)
        for k, class_id in enumerate(ids):
            label[:, k * 96 // len(ids):(k + 1) * 96 // len(ids)] = class_id
        rgb = np.clip(table.colorize(label).astype(int) + rng.integers(-20, 20, (64, 96, 3)), 0, 255).astype(np.uint8)
        Image.fromarray(rgb).save(root / "images" / f"s{i}.png")
        Image.fromarray(label).save(root / "labels" / f"s{i}.png")
        rows.append({"name": f"s{i}", "ground_resolution_m": 0.5})
    write_dataset_manifest(root, table.to_dict(), rows)
    return root


@pytest.fixture(scope="module")
def models(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("models")
    tinyseg = json.loads((TINYSEG / "manifest.json").read_text())["classes"]
    return {"tinyseg": checkpoint(folder / "tinyseg.pt", "tiny", tinyseg),
            "camvid": checkpoint(folder / "camvid.pt", "camvidnet", "camvid.toml"),
            "airsegnet13": checkpoint(folder / "airsegnet13.pt", "airsegnet13"),
            "airsegnet6": checkpoint(folder / "airsegnet6.pt", "airsegnet6")}


@pytest.fixture(scope="module")
def datasets(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("datasets")
    t13, t6 = load_class_table("classes13.toml"), load_class_table("classes6.toml")
    return {"13": dataset(folder / "ds13", t13, [0, 1, 2, 3, 4], samples=6),  # ids a 5-class model has too
            "6": dataset(folder / "ds6", t6, [0, 1, 2, 3, 4, 5, 6])}


# --------------------------------------------------------------------------- eval and predict


@pytest.mark.parametrize(("model", "data", "detail"), [
    ("camvid", "13", "unlabeled is id 0 in the labels, 11 in the model"),   # was: exit 0, Sky for unlabeled
    ("tinyseg", "13", "id 4 is 'natural' in the labels, 'water' in the model"),  # was: exit 0, natural as water
    ("camvid", "6", "unlabeled is id 0 in the labels, 11 in the model"),
])
def test_eval_refuses_labels_of_a_table_the_model_does_not_predict(models: dict[str, Path], datasets: dict[str, Path],
                                                                   tmp_path: Path, model: str, data: str,
                                                                   detail: str) -> None:
    result = osmseg("eval", models[model], datasets[data], "--out", tmp_path / "eval", "--device", "cpu")
    assert result.exit_code == 2, result.output
    line = error_line(result)
    model_table = {"camvid": "'camvid'", "tinyseg": "'tinyseg'"}[model]
    data_table = {"13": "'osm13'", "6": "'osm6'"}[data]
    assert f"{models[model]} predicts the classes of {model_table}" in line, line
    assert f"{datasets[data] / 'manifest.json'} is labelled with {data_table}" in line and detail in line, line
    assert "--mapping" in line and "--classes" not in line  # an option eval has, and none it has not
    assert not (tmp_path / "eval").exists()


def test_eval_compares_through_the_shipped_mapping_both_ways(models: dict[str, Path], datasets: dict[str, Path],
                                                             tmp_path: Path) -> None:
    """AirSegNet6 on 13 classes (labels mapped, as before) and AirSegNet13 on 6 (outputs mapped;
    was refused): the scores are those of the predicted masks mapped by hand through classes6."""
    lookup = load_class_table("classes6.toml").lookup_from_base()
    for model, data, mapped in (("airsegnet6", "13", "labels"), ("airsegnet13", "6", "outputs")):
        out = tmp_path / model
        result = osmseg("eval", models[model], datasets[data], "--out", out, "--device", "cpu")
        assert result.exit_code == 0, result.output
        metrics = json.loads((out / "metrics.json").read_text())
        assert set(metrics["per_class"]) == {c.name for c in load_class_table("classes6.toml").by_id.values()}
        masks = tmp_path / f"{model}-masks"
        images = sorted((datasets[data] / "images").glob("*.png"))
        assert osmseg("predict", models[model], *images, "--out", masks, "--device", "cpu").exit_code == 0
        right = total = 0
        for image in images:
            truth = np.asarray(Image.open(datasets[data] / "labels" / image.name))
            pred = np.asarray(Image.open(masks / image.name))
            truth, pred = (lookup[truth], pred) if mapped == "labels" else (truth, lookup[pred])
            scored = truth != 0  # unlabeled ignored
            right += int((pred[scored] == truth[scored]).sum())
            total += int(scored.sum())
        assert metrics["num_pixels"] == total
        assert metrics["pixel_accuracy"] == pytest.approx(right / total)


def test_eval_of_pairs_reads_the_table_a_geotiff_label_carries(models: dict[str, Path], datasets: dict[str, Path],
                                                               tmp_path: Path) -> None:
    """A --pair label written by osmseg (geo/NAME.tif: class tags and colours) says its table: a
    CamVid model is refused on it (was: scored as CamVid ids), AirSegNet13 compares through classes6."""
    import rasterio
    from rasterio.transform import from_origin

    from osmseg.output.geotiff import write_class_metadata

    labels = np.asarray(Image.open(datasets["6"] / "labels" / "s0.png"))
    label = tmp_path / "s0.tif"
    with rasterio.open(label, "w", driver="GTiff", width=96, height=64, count=1, dtype="uint8", crs="EPSG:3857",
                       transform=from_origin(2776000, 8437000, 0.5, 0.5)) as out:
        out.write(labels, 1)
        write_class_metadata(out, load_class_table("classes6.toml"))
    image = datasets["6"] / "images" / "s0.png"
    refused = osmseg("eval", models["camvid"], "--pair", image, label, "--out", tmp_path / "camvid", "--device", "cpu")
    assert refused.exit_code == 2, refused.output
    line = error_line(refused)
    assert f"but {label} is labelled with 'osm6'" in line and "predicts the classes of 'camvid'" in line, line
    mapped = osmseg("eval", models["airsegnet13"], "--pair", image, label, "--out", tmp_path / "a13", "--device", "cpu")
    assert mapped.exit_code == 0, mapped.output
    assert "natural" in json.loads((tmp_path / "a13" / "metrics.json").read_text())["per_class"]  # osm6's classes


def test_predict_refuses_to_write_masks_into_a_dataset_of_another_table(models: dict[str, Path],
                                                                        datasets: dict[str, Path],
                                                                        tmp_path: Path) -> None:
    data = Path(shutil.copytree(datasets["13"], tmp_path / "ds13"))
    image = data / "images" / "s0.png"
    before = (data / "labels" / "s0.png").read_bytes()
    for out in (data / "labels", data):
        result = osmseg("predict", models["camvid"], image, "--out", out, "--device", "cpu")
        assert result.exit_code == 2, result.output
        line = error_line(result)
        assert "predicts the classes of 'camvid'" in line and f"--out {out} is" in line and "'osm13'" in line, line
    assert (data / "labels" / "s0.png").read_bytes() == before  # was: overwritten by CamVid ids
    assert not (data / "s0.png").exists()
    # masks of the dataset's own table may go there, and any model's anywhere else
    assert osmseg("predict", models["airsegnet13"], image, "--out", data / "labels", "--device", "cpu").exit_code == 0
    assert osmseg("predict", models["camvid"], image, "--out", tmp_path / "masks", "--device", "cpu").exit_code == 0


# --------------------------------------------------------------------------- train


def test_train_refuses_a_class_table_that_misreads_the_dataset_labels(tmp_path: Path, datasets: dict[str, Path]) -> None:
    """--classes used to replace the table of a dataset that has one: tinyseg's water (4) was
    learnt as classes13's natural, silently."""
    for table, detail in (("classes13.toml", "id 4 is 'water' in the labels, 'natural' in the model"),
                          ("camvid.toml", "unlabeled is id 0 in the labels, 11 in the model")):
        result = osmseg("train", TINYSEG, "--out", tmp_path / "run", "--config", TINY_YAML, "--epochs", 1,
                        "--model", "mine", "--classes", table)
        assert result.exit_code == 2, result.output
        line = error_line(result)
        assert f"--classes {table} predicts the classes of" in line and "is labelled with 'tinyseg'" in line, line
        assert detail in line, line
        assert not (tmp_path / "run").exists()
    # a table that maps the dataset's is learnt through its mapping, as airsegnet6 is
    result = osmseg("train", datasets["13"], "--out", tmp_path / "run6", "--config", TINY_YAML, "--epochs", 1,
                    "--model", "mine", "--classes", "classes6.toml", "--split-by", "image")
    assert result.exit_code == 0, result.output
    from training.models.checkpoint import load_checkpoint

    assert load_checkpoint(tmp_path / "run6" / "last.pt")["spec"]["class_table"]["name"] == "osm6"
    # without a table of its own, --classes says what a folder's labels mean, and a preset learns through the mapping
    bare = Path(shutil.copytree(datasets["13"], tmp_path / "bare", ignore=shutil.ignore_patterns("manifest.json")))
    result = osmseg("train", bare, "--out", tmp_path / "bare-run", "--config", TINY_YAML, "--epochs", 1,
                    "--model", "airsegnet6", "--classes", "classes13.toml", "--split-by", "image")
    assert result.exit_code == 0, result.output


@pytest.mark.parametrize("width", ["0.125", "1.0"])
def test_init_of_a_file_that_is_neither_checkpoint_nor_weights_is_refused_up_front(tmp_path: Path, width: str) -> None:
    notes = tmp_path / "notes.txt"
    notes.write_text("not weights at all\n")
    result = osmseg("train", TINYSEG, "--out", tmp_path / "run", "--config", TINY_YAML, "--epochs", 1,
                    "--width", width, "--init", notes)
    assert result.exit_code == 2, result.output
    line = error_line(result)
    assert f"--init {notes} is neither a checkpoint of an osmseg run" in line, line  # was: "need width 1.0"
    assert "VGG16-BN encoder weights need width" not in line
    assert not (tmp_path / "run").exists()  # was, at width 1.0: refused after the run folder was made


# --------------------------------------------------------------------------- broken class tables

BROKEN = {  # name: (how classes13.toml is broken, what the one line says)
    "two classes of one name": (('name = "grass"', 'name = "natural"'),
                                "classes 'natural' (id 3) and 'natural' (id 4) have the same name"),
    "names alike": (('name = "grass"', 'name = "Dirt_Road"'), "differ only in case or punctuation"),
    "two classes of one colour": (("color = [0, 100, 0]", "color = [255, 255, 0]"), "have the same colour"),
    "ids not 0..N": (("id = 13", "id = 20"), "class ids, unlabeled included, must be 0..13 each once (id 13 is missing"),
    "an id twice": (("id = 13", "id = 12"), "(id 12 is given twice"),
    "a colour missing": (("color = [0, 100, 0]\n", ""), "class 'natural' lacks 'color'"),
    "a name missing": (('name = "grass"\n', ""), "[[classes]] entry 4 lacks 'name'"),
    "no unlabeled": (('unlabeled = { id = 0, name = "unlabeled", color = [0, 0, 0] }\n', ""),
                     "lacks the unlabeled class"),
    "an id not a number": (("id = 13", 'id = "tree"'), "class 'tree': id must be an integer 0..255, got 'tree'"),
    "bad TOML": (("[[classes]]\nid = 13", "[[classes]\nid = 13"), "not valid TOML"),
}


def broken_table(folder: Path, case: str) -> Path:
    (old, new), _ = BROKEN[case]
    text = (DATA_DIR / "classes13.toml").read_text(encoding="utf-8")
    assert text.count(old) >= 1
    path = folder / "mine.toml"
    path.write_text(text.replace(old, new, 1), encoding="utf-8")
    return path


@pytest.mark.parametrize("case", list(BROKEN))
def test_a_broken_class_table_is_refused_before_anything_is_built(tmp_path: Path, imagery_tif: Path, case: str) -> None:
    table = broken_table(tmp_path, case)
    lon, lat = TINYCITY_CENTRE
    build = osmseg("build", "--lat", lat, "--lon", lon, "--radius-km", 0.05, "--samples", 2, "--seed", 1,
                   "--imagery", f"geotiff:{imagery_tif}", "--osm", TINYCITY, "--out", tmp_path / "ds",
                   "--cache-dir", tmp_path / "cache", "--workers", 1, "--classes", table)
    train = osmseg("train", TINYSEG, "--out", tmp_path / "run", "--config", TINY_YAML, "--epochs", 1,
                   "--model", "mine", "--classes", table)
    for result in (build, train):
        assert result.exit_code == 2, result.output
        line = error_line(result)
        assert str(table) in line and BROKEN[case][1] in line, line
        assert "Error(" not in line  # no Python repr (was: "malformed class table (KeyError('color'))")
    assert not (tmp_path / "ds").exists() and not (tmp_path / "run").exists()
