"""Dataset output: sample files, GeoTIFF georeferencing, manifest + verify, datasheet, attribution, pictures, zip."""

from __future__ import annotations

import json
import os
import zipfile
from dataclasses import replace
from pathlib import Path

import mercantile
import numpy as np
import pytest
import rasterio
from PIL import Image

from osmseg.builder.filters import FilterConfig
from osmseg.classes import load_class_table
from osmseg.errors import ConfigError, DatasetError
from osmseg.grid import SampleGrid, sample_grid
from osmseg.images import read_label
from osmseg.output import (
    command_line,
    make_zip,
    read_manifest,
    rejection_entry,
    sample_entry,
    summary_entry,
    verify,
    write_attribution,
    write_class_histogram,
    write_datasheet,
    write_manifest,
    write_overview,
    write_sample,
)
from osmseg.output.manifest import (
    FORMAT_VERSION,
    AreaRecord,
    DatasetManifest,
    Provenance,
    Rejection,
    ToolInfo,
    class_totals,
)
from osmseg.output.overview import MARGIN, legend_height

TABLE = load_class_table("classes13.toml")
GRID = sample_grid(13.4050, 52.5200, zoom=18)
OSM_TIME = "2024-05-01T12:00:00Z"
IMAGERY = {"provider": "xyz", "template": "https://tiles.example/{z}/{x}/{y}.jpg", "attribution": "Imagery © Example Aerial Co."}
OSM = {"source": "file", "path": "berlin.osm.pbf", "attribution": "© OpenStreetMap contributors"}


def synthetic_sample(seed: int, grid: SampleGrid = GRID) -> tuple[np.ndarray, np.ndarray]:
    """A smooth RGB image and blocky labels: class ``(block_row + block_col + seed) % 14`` per 128 px block."""
    rows, cols = np.indices((grid.height, grid.width))
    rgb = np.stack([(rows // 5) % 256, (cols // 5) % 256, ((rows + cols + 40 * seed) // 10) % 256], axis=-1).astype(np.uint8)
    labels = ((rows // 128 + cols // 128 + seed) % TABLE.num_classes).astype(np.uint8)
    return rgb, labels


@pytest.fixture(scope="module")
def sample_arrays() -> tuple[np.ndarray, np.ndarray]:
    return synthetic_sample(0)


def files_in(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


# --- one sample --------------------------------------------------------------------------


def test_write_sample_is_byte_identical_on_rewrite(tmp_path: Path, sample_arrays) -> None:
    rgb, labels = sample_arrays
    first = write_sample(tmp_path / "a", "s0", rgb, labels, TABLE, GRID)
    second = write_sample(tmp_path / "b", "s0", rgb, labels, TABLE, GRID)
    again = write_sample(tmp_path / "a", "s0", rgb, labels, TABLE, GRID)  # over itself
    assert first == second == again
    assert sorted(first.files) == ["geo/s0.qml", "geo/s0.tif", "images/s0.png", "labels/s0.png", "segmented/s0.png"]
    a, b = files_in(tmp_path / "a"), files_in(tmp_path / "b")
    assert a == b
    assert not [name for name in a if Path(name).name.startswith(".")], "temp files left behind"


def test_returned_hashes_and_histogram_match_the_files(tmp_path: Path, sample_arrays) -> None:
    import hashlib

    rgb, labels = sample_arrays
    out = write_sample(tmp_path, "s0", rgb, labels, TABLE, GRID)
    for rel, digest in out.files.items():
        assert hashlib.sha256((tmp_path / rel).read_bytes()).hexdigest() == digest
    counts = np.bincount(labels.ravel(), minlength=TABLE.num_classes)
    assert out.class_histogram == {TABLE.by_id[i].name: int(counts[i]) for i in range(TABLE.num_classes)}
    assert sum(out.class_histogram.values()) == 1280 * 1280


def test_pngs_decode_to_the_inputs(tmp_path: Path, sample_arrays) -> None:
    rgb, labels = sample_arrays
    write_sample(tmp_path, "s0", rgb, labels, TABLE, GRID)
    with Image.open(tmp_path / "labels/s0.png") as im:
        assert im.mode == "L" and im.size == (1280, 1280)
        assert np.array_equal(np.asarray(im), labels)
        assert "transparency" not in im.info and not im.text  # no metadata chunks (e.g. dates)
    with Image.open(tmp_path / "segmented/s0.png") as im:
        assert im.mode == "RGB"
        seg = np.asarray(im)
    assert np.array_equal(seg, TABLE.colorize(labels))
    # block (0, 0) is class 0 (black), block (0, 1) class 1 (building yellow)
    assert tuple(seg[10, 10]) == (0, 0, 0) and tuple(seg[10, 130]) == TABLE.by_name["building"].color
    with Image.open(tmp_path / "images/s0.png") as im:
        assert np.array_equal(np.asarray(im), rgb)
    assert np.array_equal(read_label(tmp_path / "labels/s0.png"), labels)


def test_jpeg_images_are_deterministic_and_faithful(tmp_path: Path, sample_arrays) -> None:
    rgb, labels = sample_arrays
    a = write_sample(tmp_path / "a", "s0", rgb, labels, TABLE, GRID, image_format="jpg")
    b = write_sample(tmp_path / "b", "s0", rgb, labels, TABLE, GRID, image_format="jpg")
    assert a == b and "images/s0.jpg" in a.files
    with Image.open(tmp_path / "a/images/s0.jpg") as im:
        assert im.format == "JPEG" and "exif" not in im.info
        decoded = np.asarray(im).astype(int)
    assert np.abs(decoded - rgb).mean() < 2.0
    low = write_sample(tmp_path / "c", "s0", rgb, labels, TABLE, GRID, image_format="jpg", jpeg_quality=30)
    assert low.files["images/s0.jpg"] != a.files["images/s0.jpg"]


def test_geotiff_is_georeferenced_and_holds_the_labels(tmp_path: Path, sample_arrays) -> None:
    rgb, labels = sample_arrays
    write_sample(tmp_path, "s0", rgb, labels, TABLE, GRID)
    with rasterio.open(tmp_path / "geo/s0.tif") as src:
        assert src.crs.to_epsg() == 3857
        assert src.transform == GRID.transform
        assert tuple(src.bounds) == pytest.approx(tuple(GRID.xy_bounds))
        assert (src.count, src.dtypes[0], src.nodata) == (1, "uint8", None)
        assert src.block_shapes == [(256, 256)] and src.compression.name == "deflate"
        assert np.array_equal(src.read(1), labels)
        cmap = src.colormap(1)
        for c in (TABLE.unlabeled, *TABLE.classes):
            assert cmap[c.id][:3] == c.color
        assert src.descriptions[0].startswith("class id")
        assert src.tags(1)["CLASS_8"] == "water"
        # pixel (0, 0) is the north-west corner of the north-west tile of the grid
        x, y = src.xy(0, 0, offset="ul")
    nw = mercantile.xy_bounds(GRID.tiles[0])
    assert (x, y) == pytest.approx((nw.left, nw.top))
    assert not list(tmp_path.glob("geo/*.aux.xml")), "GDAL sidecar written"
    assert np.array_equal(read_label(tmp_path / "geo/s0.tif"), labels)


def test_a_cog_photo_marks_the_pixels_without_imagery_in_an_internal_mask(tmp_path: Path, sample_arrays) -> None:
    """Missing imagery (here a band of columns and a corner) is masked, not just black: rasterio's
    dataset_mask() gives 0 exactly there, at full size and in the overviews; rio-cogeo still
    validates the file, no .msk sidecar is written; a photo with every pixel has no mask."""
    from rio_cogeo.cogeo import cog_validate
    rgb, labels = sample_arrays
    valid = np.ones(labels.shape, bool)
    valid[:, 1000:] = False
    valid[:300, :200] = False
    rgb = np.where(valid[:, :, None], np.maximum(rgb, 1), 0).astype(np.uint8)
    write_sample(tmp_path / "cut", "s0", rgb, labels, TABLE, GRID, "cog", valid=valid)
    path = tmp_path / "cut" / "images" / "s0.tif"
    assert cog_validate(str(path))[0], cog_validate(str(path))
    assert sorted(p.name for p in path.parent.iterdir()) == ["s0.tif"]
    with rasterio.open(path) as src:
        assert src.mask_flag_enums == ([rasterio.enums.MaskFlags.per_dataset],) * 3
        assert np.array_equal(src.dataset_mask(), np.where(valid, 255, 0))
        assert np.array_equal(src.read().transpose(1, 2, 0), rgb)  # the pixels themselves are as given
        masked = src.read(1, masked=True)
        assert np.array_equal(masked.mask, ~valid)
        half = src.dataset_mask(out_shape=(640, 640))
        assert (half[:, 502:] == 0).all() and (half[160:, :498] == 255).all()
    write_sample(tmp_path / "whole", "s0", rgb, labels, TABLE, GRID, "cog", valid=np.ones(labels.shape, bool))
    with rasterio.open(tmp_path / "whole" / "images" / "s0.tif") as src:
        assert src.mask_flag_enums == ([rasterio.enums.MaskFlags.all_valid],) * 3


def test_bad_input_gives_one_line_errors(tmp_path: Path, sample_arrays) -> None:
    rgb, labels = sample_arrays
    with pytest.raises(ConfigError, match="sample name"):
        write_sample(tmp_path, "../evil", rgb, labels, TABLE, GRID)
    with pytest.raises(ConfigError, match="image format"):
        write_sample(tmp_path, "s0", rgb, labels, TABLE, GRID, image_format="webp")
    with pytest.raises(DatasetError, match="must be"):
        write_sample(tmp_path, "s0", rgb[:100], labels, TABLE, GRID)
    stray = labels.copy()
    stray[0, 0] = 200
    with pytest.raises(DatasetError, match=r"class ids \[200\]"):
        write_sample(tmp_path, "s0", rgb, stray, TABLE, GRID)
    assert not list(tmp_path.rglob("*")), "nothing is written for a refused sample"


def test_a_failed_write_leaves_the_old_file_intact(tmp_path: Path, sample_arrays, monkeypatch) -> None:
    rgb, labels = sample_arrays
    write_sample(tmp_path, "s0", rgb, labels, TABLE, GRID)
    before = files_in(tmp_path)

    def crash(src, dst):  # the process dies at the moment of the rename
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(KeyboardInterrupt):
        write_sample(tmp_path, "s0", rgb, (labels + 1) % 14, TABLE, GRID)
    monkeypatch.undo()
    assert files_in(tmp_path) == before  # old files untouched, temp file removed


# --- manifest ----------------------------------------------------------------------------


def build_dataset(out: Path, n: int = 3, image_format: str = "png") -> DatasetManifest:
    """Write ``n`` samples and the manifest the way the builder does."""
    samples, rejected = [], []
    centres = [(13.40 + 0.01 * i, 52.52 - 0.01 * i) for i in range(n)]
    for i, (lon, lat) in enumerate(centres):
        grid = sample_grid(lon, lat, zoom=18)
        rgb, labels = synthetic_sample(i, grid)
        written = write_sample(out, f"berlin_{i:04d}", rgb, labels, TABLE, grid, image_format=image_format)
        samples.append(sample_entry(f"berlin_{i:04d}", grid, written, imagery=IMAGERY, osm=OSM, osm_timestamp=OSM_TIME))
    rejected.append(rejection_entry(13.5, 52.4, Rejection("unlabeled", "91.0% unlabeled >= 70.0%"), attempt=1))
    rejected.append(rejection_entry(13.6, 52.3, Rejection("unlabeled", "75.5% unlabeled >= 70.0%"), attempt=2))
    rejected.append(rejection_entry(13.7, 52.2, Rejection("low_contrast", "grey-level std 2.1 < 8"), attempt=4))
    manifest = DatasetManifest(
        format_version=FORMAT_VERSION, tool=ToolInfo("osmseg", "0.1.0"),
        command=command_line(["osmseg", "build", "--city", "Berlin", "--samples", str(n), "--seed", "7"]), seed=7,
        area=AreaRecord(name="Berlin", kind="urban", lat=52.52, lon=13.405, radius_km=5.0), zoom=18, grid_size=5,
        image_format=image_format, classes=TABLE, filters=FilterConfig().to_dict(), imagery=Provenance(IMAGERY),
        osm=Provenance(OSM), samples=samples, rejected=rejected,
        summary=summary_entry(samples, rejected, requested=n, max_attempts=10 * n))
    write_manifest(out, manifest)
    return manifest


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> tuple[Path, DatasetManifest]:
    out = tmp_path_factory.mktemp("ds") / "berlin"
    return out, build_dataset(out)


def test_sample_entry_records_where_and_what(dataset) -> None:
    out, _ = dataset
    written = json.loads((out / "manifest.json").read_text())  # what a user reads
    s = written["samples"][0]
    assert s["center"] == {"lon": 13.40, "lat": 52.52}
    grid = sample_grid(13.40, 52.52, zoom=18)
    assert s["bbox_wgs84"] == list(grid.bbox) and s["bounds_3857"] == list(grid.xy_bounds)
    assert len(s["tiles"]) == 25 and s["tiles"][12]["quadkey"] == mercantile.quadkey(mercantile.tile(13.40, 52.52, 18))
    assert s["osm"]["timestamp"] == OSM_TIME and s["imagery"] == IMAGERY
    assert written["summary"] == {
        "requested": 3, "accepted": 3, "rejected": 3, "attempts": 6, "max_attempts": 30,
        "rejected_by_reason": {"unlabeled": 2, "low_contrast": 1}, "complete": True,
    }


def test_manifest_is_deterministic_sorted_json(tmp_path: Path, dataset) -> None:
    out, manifest = dataset
    text = (out / "manifest.json").read_bytes()
    assert text.decode() == json.dumps(manifest.to_json(), sort_keys=True, indent=2, ensure_ascii=False) + "\n"
    write_manifest(tmp_path, read_manifest(out))
    assert (tmp_path / "manifest.json").read_bytes() == text
    assert text.endswith(b"}\n")
    keys = list(json.loads(text))
    assert keys == sorted(keys)
    assert read_manifest(out).to_json() == manifest.to_json()


def test_verify_accepts_an_intact_dataset_and_catches_changes(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    build_dataset(out, n=2)
    assert verify(out) == []
    # flip one byte in a label PNG's compressed data
    path = out / "labels/berlin_0001.png"
    data = bytearray(path.read_bytes())
    data[-20] ^= 0xFF
    path.write_bytes(bytes(data))
    (out / "segmented/berlin_0000.png").unlink()
    (out / "images/stray.png").write_bytes(b"x")
    (out / "images/.berlin_0000.png.abc.tmp").write_bytes(b"x")  # interrupted write: ignored
    assert verify(out) == [
        "segmented/berlin_0000.png: missing",
        "labels/berlin_0001.png: modified (sha256 differs from the manifest)",
        "images/stray.png: not listed in the manifest",
    ]


def test_malformed_manifests_are_reported_in_one_line(tmp_path: Path, dataset) -> None:
    _, manifest = dataset
    with pytest.raises(DatasetError, match="not found"):
        read_manifest(tmp_path)
    (tmp_path / "manifest.json").write_text("{not json")
    with pytest.raises(DatasetError, match="not valid JSON"):
        read_manifest(tmp_path)
    broken = {k: v for k, v in manifest.to_json().items() if k != "seed"}
    with pytest.raises(DatasetError, match=r"missing keys \['seed'\]"):
        DatasetManifest.from_json(broken)
    escaping = manifest.to_json()
    escaping["samples"][0]["files"] = {"../../etc/passwd": "0"}  # type: ignore[call-overload,index]
    with pytest.raises(DatasetError, match="outside the dataset"):
        DatasetManifest.from_json(escaping)
    nan = replace(manifest, samples=[replace(manifest.samples[0], ground_resolution_m=float("nan"))])
    with pytest.raises(DatasetError, match="not JSON-serialisable"):
        write_manifest(tmp_path, nan)


def test_command_line_drops_secrets() -> None:
    line = command_line([
        "osmseg", "build", "--city", "São Paulo", "--bing-key", "S3CRET", "--mapbox-token=S3CRET",
        "--imagery", "xyz:https://api.example.com/{z}/{x}/{y}?access_token=S3CRET&style=sat",
        "--osm", "https://user:S3CRET@osm.example.org/api",
    ])
    assert "S3CRET" not in line
    assert "'São Paulo'" in line and "style=sat" in line and "--bing-key REDACTED" in line


# --- datasheet and attribution ------------------------------------------------------------


def test_datasheet_is_filled_with_the_builds_numbers(dataset) -> None:
    out, manifest = dataset
    path = write_datasheet(out, manifest)
    text = path.read_text(encoding="utf-8")
    for section in ("Motivation", "Composition", "Collection process", "Preprocessing / cleaning / labeling",
                    "Uses", "Distribution", "Maintenance"):
        assert f"\n## {section}\n" in text
    totals = class_totals(manifest.samples)
    all_px = 3 * 1280 * 1280
    assert sum(totals.values()) == all_px
    water = totals["water"]
    assert f"| 8 | water | #77f2f2 (119, 242, 242) | {water:,} | {100 * water / all_px:.2f}% |" in text
    assert "3 samples (requested 3)" in text
    assert "seed 7" in text and manifest.command in text
    assert "zoom 18: 0.363 m per pixel" in text  # cos(52.5°) * 0.597 m
    ids = [int(line.split("|")[1]) for line in text.splitlines() if line.startswith("  | ") and "#" in line]
    assert ids == list(range(14))  # classes listed by id
    assert "| `unlabeled` | 2 |" in text and "| `low_contrast` | 1 |" in text
    assert "| `max_unlabeled` | 0.7 |" in text and "| `min_contrast` | 8 |" in text
    assert OSM_TIME in text and "**Berlin** (urban)" in text and "6 centres drawn (limit 30)" in text
    assert IMAGERY["attribution"] in text
    write_datasheet(out, manifest)
    assert path.read_text(encoding="utf-8") == text


def test_attribution_names_odbl_and_the_imagery_terms(dataset) -> None:
    out, manifest = dataset
    text = write_attribution(out, manifest).read_text(encoding="utf-8")
    assert "© OpenStreetMap contributors" in text and "ODbL" in text and "Derivative Database" in text
    assert "Produced Work" in text and "https://www.openstreetmap.org/copyright" in text
    assert "Provider: **xyz**" in text and "Imagery © Example Aerial Co." in text
    bing = replace(manifest, imagery=Provenance({"provider": "bing", "attribution": "Imagery © Microsoft",
                                                 "copyright": "© 2024 Maxar", "brand_logo_uri": "https://dev.example/logo.png"}))
    text = write_attribution(out, bing).read_text(encoding="utf-8")
    assert "Copyright: © 2024 Maxar" in text and "logo" in text


# --- pictures ------------------------------------------------------------------------------


def test_overview_shows_samples_and_a_full_legend(tmp_path: Path, dataset) -> None:
    out, manifest = dataset
    path = write_overview(out, manifest.samples, TABLE, max_samples=2, thumb=64)
    first = path.read_bytes()
    with Image.open(path) as im:
        sheet = np.asarray(im.convert("RGB"))
    width = 3 * 64 + 4 * MARGIN
    assert sheet.shape[1] == width
    legend = sheet[-legend_height(TABLE, width):]
    colours = {tuple(c) for c in legend.reshape(-1, 3)}
    for c in (TABLE.unlabeled, *TABLE.classes):
        assert c.color in colours, f"legend lacks {c.name}"
    # the colour-mask thumbnail of sample 0 is the class colours of its labels
    with Image.open(out / "labels/berlin_0000.png") as im:
        small = np.asarray(im.resize((64, 64), Image.Resampling.NEAREST))
    top = MARGIN + 14 + 4 + 14
    assert np.array_equal(sheet[top:top + 64, 2 * MARGIN + 64:2 * MARGIN + 128], TABLE.colorize(small))
    write_overview(out, manifest.samples, TABLE, max_samples=2, thumb=64)
    assert path.read_bytes() == first
    gone = [replace(manifest.samples[0], name="x", files={"images/x.png": "0", "labels/x.png": "0"})]
    with pytest.raises(DatasetError, match="missing"):
        write_overview(out, gone, TABLE)


def test_class_histogram_bars_are_proportional(tmp_path: Path) -> None:
    totals = {"building": 3000, "water": 1000}
    path = write_class_histogram(tmp_path, totals, TABLE)
    with Image.open(path) as im:
        chart = np.asarray(im.convert("RGB"))
    def area(color: tuple[int, int, int]) -> int:
        return int(np.all(chart == color, axis=-1).sum())
    building, water = area(TABLE.by_name["building"].color), area(TABLE.by_name["water"].color)
    assert building == pytest.approx(3 * water, rel=0.02)
    assert area(TABLE.by_name["park"].color) == 0  # a class with no pixels has no bar body


# --- zip -----------------------------------------------------------------------------------


def test_zip_is_deterministic_and_skips_hidden_state(tmp_path: Path, dataset) -> None:
    out, manifest = dataset
    write_datasheet(out, manifest)
    (out / ".state").mkdir(exist_ok=True)
    (out / ".state" / "progress.json").write_text("{}")
    (out / ".manifest.json.x.tmp").write_text("partial")
    a = make_zip(out, tmp_path / "a.zip")
    os.utime(out / "manifest.json", (0, 1_700_000_000))  # newer mtime must not matter
    b = make_zip(out, out / "berlin.zip")  # inside the folder: not packed into itself
    assert a.read_bytes() == b.read_bytes()
    with zipfile.ZipFile(a) as zf:
        names = zf.namelist()
        assert names == sorted(names)
        assert "berlin/manifest.json" in names and "berlin/DATASHEET.md" in names
        assert "berlin/geo/berlin_0002.tif" in names and "berlin/images/berlin_0000.png" in names
        assert not [n for n in names if "/." in n or n.endswith(".zip")]
        assert {i.date_time for i in zf.infolist()} == {(1980, 1, 1, 0, 0, 0)}
        assert {i.external_attr >> 16 for i in zf.infolist()} == {0o100644}
        assert zf.read("berlin/manifest.json") == (out / "manifest.json").read_bytes()
        assert zf.testzip() is None
    (out / "berlin.zip").unlink()


def test_zip_of_a_missing_folder_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="not a folder"):
        make_zip(tmp_path / "nope", tmp_path / "x.zip")


def test_sweeping_temp_files_spares_live_writers_and_removes_what_killed_ones_left(tmp_path: Path) -> None:
    """A rerun (or a shard starting beside others on one folder) removes a killed writer's litter,
    never the file a live process is writing."""
    import os
    import subprocess
    import sys
    import time

    from osmseg.output.atomic import FOREIGN_TEMP_SECONDS, _owner, sweep_temp_files, temp_path_for

    live = temp_path_for(tmp_path / "a.png")  # this process: alive
    assert live.name.startswith(f".a.png.{_owner()}.") and live.name.endswith(".tmp")
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    host = _owner().rsplit("-", 1)[0]
    dead = tmp_path / f".b.png.{host}-{int(gone.stdout)}.x1y2.tmp"
    other_new = tmp_path / ".c.png.othernode-12.x1y2.tmp"
    other_old = tmp_path / ".d.png.othernode-12.x1y2.tmp"
    legacy = tmp_path / ".e.png.abc123.tmp"
    for path in (dead, other_new, other_old, legacy):
        path.write_bytes(b"partial")
    old = time.time() - FOREIGN_TEMP_SECONDS - 60
    os.utime(other_old, (old, old))
    assert sweep_temp_files(tmp_path) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([live.name, other_new.name])


@pytest.mark.parametrize("process", ["command", "build worker"])
def test_a_sigterm_just_after_a_temporary_file_is_created_still_removes_it(
        tmp_path: Path, monkeypatch, process: str) -> None:
    """The window CI hit twice: ``kill`` between mkstemp and the writer knowing the name left a .tmp
    (in the command's process, then in a build worker's, whose SIGTERM handler is its own)."""
    import signal

    from osmseg.builder import workers
    from osmseg.output import atomic
    from osmseg.runtime.processes import Terminated, terminate_by_exception

    create = atomic.temp_path_for

    def killed_on_creation(path: Path) -> Path:
        tmp = create(path)
        os.kill(os.getpid(), signal.SIGTERM)  # its handler runs before this function returns
        return tmp

    monkeypatch.setattr(atomic, "temp_path_for", killed_on_creation)
    before = signal.getsignal(signal.SIGTERM)
    if process == "command":
        terminate_by_exception()
    else:
        signal.signal(signal.SIGTERM, workers._on_terminate)
    try:
        with pytest.raises(Terminated if process == "command" else workers._Stop), \
                atomic.atomic_path(tmp_path / "DATASHEET.md") as tmp:
            tmp.write_text("never reached")
    finally:
        signal.signal(signal.SIGTERM, before)
    assert sorted(p.name for p in tmp_path.iterdir()) == []
