"""Inputs that were accepted with a wrong answer, each met as a user meets it: through the CLI.

Issue 18, item 6:

* a class table giving two classes one colour (the colour masks become ambiguous): refused;
* an image that cannot be a 360° panorama (a 224x1232 portrait) given as one to ``osmseg
  localize``, ``localize-pairs`` or ``localize-bench``'s rendered panoramas: refused, photos (``--fov``) still work;
* ``osmseg build --zoom`` finer than a local GeoTIFF's pixels: warned once, with the zoom that matches;
* a build that keeps fewer samples than asked: one "incomplete" line (exit 0: see :func:`test_a_build_that_keeps_fewer_samples_than_asked_says_so`);
* an OSM file, a tile folder or a remote source with nothing over the area: said so, before the
  first attempt where that can be known, else in the final error;
* a 16-bit or paletted GeoTIFF: ``build`` and ``predict`` read the same colours from it.

The data is made here: tinycity's OSM file, the GeoTIFF painted from it (``imagery_tif``), masks
and panoramas rendered by the project, and servers on 127.0.0.1.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner, Result
from conftest import REPO_ROOT, TEST_DATA, TINYCITY, TINYCITY_CENTRE
from PIL import Image
from rasterio.windows import Window

from osmseg.classes import ClassTable, load_class_table
from osmseg.cli.main import cli
from osmseg.datafiles import DATA_DIR

LON, LAT = TINYCITY_CENTRE
TILES = TEST_DATA / "imagery" / "tiles"  # z18 tiles of a 3x3 block in Berlin
BERLIN = ("--lat", "52.52", "--lon", "13.405")


def run(*args: str) -> Result:
    return CliRunner().invoke(cli, list(args))


def error_line(result: Result) -> str:
    """The one ``Error:`` line of a failed command (no traceback, nothing else after it)."""
    assert "Traceback" not in result.output, result.output
    lines = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(lines) == 1, result.output
    return lines[0]


def build_args(out: Path, imagery: str, *extra: str, samples: int = 2, where: tuple[str, ...] = ()) -> list[str]:
    return ["build", *(where or ("--lat", str(LAT), "--lon", str(LON))), "--radius-km", "0.05", "--samples",
            str(samples), "--seed", "1", "--imagery", imagery, "--osm", str(TINYCITY), "--out", str(out),
            "--cache-dir", str(out.parent / "cache"), "--workers", "1", *extra]


def images_of(dataset: Path) -> dict[str, np.ndarray]:
    return {p.name: np.asarray(Image.open(p)) for p in sorted((dataset / "images").glob("*.png"))}


# --------------------------------------------------------------------------- a. class tables


def test_a_class_table_giving_two_classes_one_colour_is_refused_in_one_line(tmp_path: Path, imagery_tif: Path) -> None:
    text = (DATA_DIR / "classes13.toml").read_text(encoding="utf-8")
    assert text.count("color = [0, 100, 0]") == 1  # natural's dark green
    (tmp_path / "mine.toml").write_text(text.replace("color = [0, 100, 0]", "color = [255, 255, 0]"))  # building's
    result = run(*build_args(tmp_path / "ds", f"geotiff:{imagery_tif}", "--classes", str(tmp_path / "mine.toml")))
    assert result.exit_code == 2
    line = error_line(result)
    assert "'building'" in line and "'natural'" in line and "[255, 255, 0]" in line, line
    assert not (tmp_path / "ds").exists()


@pytest.mark.parametrize("name", ["classes13.toml", "classes6.toml", "camvid.toml"])
def test_the_shipped_class_tables_load_with_a_colour_per_class(name: str) -> None:
    table = load_class_table(name)
    colours = [c.color for c in (table.unlabeled, *table.classes)]
    assert len(set(colours)) == len(colours) == len(table.classes) + 1
    # as a manifest or checkpoint records it and reads it back (camvid's unlabeled is void, 11)
    again = ClassTable.from_dict(json.loads(json.dumps(table.to_dict())))
    def ids(t: ClassTable) -> list[tuple[int, str, tuple[int, ...]]]:  # what the recorded form holds
        return [(c.id, c.name, tuple(c.color)) for c in (t.unlabeled, *t.classes)]
    assert ids(again) == ids(table)


# --------------------------------------------------------------------------- b. panoramas


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """An aerial mask of tinycity (0.3 m/px), the panorama rendered at its centre (1232x224), that
    panorama turned into a 224x1232 portrait, a 90° photo cut from it, and their class table."""
    from localization.bench.render import render_panorama
    from osmseg.grid import sample_grid
    from osmseg.osm.features import read_features
    from osmseg.rasterize import rasterize

    root = tmp_path_factory.mktemp("scene")
    table = load_class_table("classes13.toml")
    grid = sample_grid(LON, LAT, 18, size=3)
    mask = rasterize(read_features([TINYCITY], grid, table), grid, table)
    Image.fromarray(mask).save(root / "aerial.png")
    pano = render_panorama(mask, table, 0.3, (384.0, 384.0)).labels
    assert pano.shape == (224, 1232)
    Image.fromarray(pano).save(root / "pano.png")
    Image.fromarray(np.ascontiguousarray(pano.T)).save(root / "portrait.png")
    Image.fromarray(np.ascontiguousarray(pano[:, 462:770])).save(root / "photo.png")  # 308 columns: 90° ahead
    sky = (DATA_DIR / "classes13.toml").read_text() + '\n[[classes]]\nid = 14\nname = "sky"\ncolor = [135, 206, 250]\n'
    (root / "ground.toml").write_text(sky)
    return {name: root / f"{name}.png" for name in ("aerial", "pano", "portrait", "photo")} | {
        "table": root / "ground.toml"}


def localize(scene: dict[str, Path], ground: str, *extra: str) -> Result:
    return run("localize", "--aerial", str(scene["aerial"]), "--aerial-table", "classes13.toml", "--aerial-resolution", "0.3",
               "--ground", str(scene[ground]), "--ground-landmarks", "aerial13", "--ground-table", str(scene["table"]),
               *extra)


@pytest.mark.parametrize("method", ["profile", "paper"])
def test_a_portrait_image_is_refused_as_a_panorama(scene: dict[str, Path], method: str) -> None:
    result = localize(scene, "portrait", "--method", method)
    assert result.exit_code == 2, result.output  # was: exit 0, confidence 1.000, every posterior 1.0
    line = error_line(result)
    assert "portrait.png is 224x1232 pixels, which cannot be a 360° panorama" in line, line
    assert ("--fov" if method == "profile" else "--no-panorama") in line


def test_panoramas_and_photos_of_their_shape_are_still_localized(scene: dict[str, Path]) -> None:
    pano = localize(scene, "pano")
    assert pano.exit_code == 0, pano.output
    assert "confidence" in pano.stderr
    photo = localize(scene, "photo", "--fov", "90")
    assert photo.exit_code == 0, photo.output
    crop = localize(scene, "portrait", "--method", "paper", "--no-panorama")  # an aerial crop has no such shape
    assert "cannot be" not in crop.output
    tall_photo = localize(scene, "portrait", "--fov", "90")
    assert tall_photo.exit_code == 2 and "cannot be a photo 90° wide" in error_line(tall_photo)


def test_localize_bench_refuses_portrait_panoramas(tmp_path: Path, scene: dict[str, Path]) -> None:
    pairs = tmp_path / "pairs"
    for side, text in (("aerial", "100 100 Building\n300 120 Road\n500 600 Tree\n"),
                       ("ground", "100 100 Building\n150 120 Road\n200 600 Tree\n")):
        (pairs / side).mkdir(parents=True)
        (pairs / side / "a.txt").write_text(text)
    result = run("localize-pairs", str(pairs), "--out", str(tmp_path / "out"), "--aerial-size", "750x750",
                 "--ground-size", "224x1232", "--methods", "paper")
    assert result.exit_code == 2 and "224x1232 pixels, which cannot be a 360° panorama" in error_line(result)
    rendered = run("localize-bench", str(scene["aerial"]), "--aerial-resolution", "0.3", "--out", str(tmp_path / "r"),
                   "--viewpoints", "1", "--pano-width", "224", "--pano-height", "1232")
    assert rendered.exit_code == 2 and "cannot be a 360° panorama" in error_line(rendered)


# --------------------------------------------------------------------------- c. zoom finer than a raster


def osmseg_process(*args: str) -> subprocess.CompletedProcess[str]:
    """``python -m osmseg ARGS`` in a process of its own: the log lines a user's terminal shows."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO_ROOT), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, "-m", "osmseg", *args], env=env, capture_output=True, text=True,
                          timeout=300)


def test_build_warns_once_when_the_zoom_upsamples_a_geotiff(tmp_path: Path, imagery_tif: Path) -> None:
    fine = osmseg_process(*build_args(tmp_path / "z20", f"geotiff:{imagery_tif}", "--zoom", "20", "--max-tries",
                                      "2")[:-2], "--workers", "2")
    assert fine.returncode in (0, 1), fine.stderr  # the warning is the point, not what the filters kept
    warnings = [line for line in fine.stderr.splitlines() if "upsampled" in line]
    assert len(warnings) == 1, fine.stderr  # once per build, not once per worker
    assert "0.298 m pixels" in warnings[0] and "--zoom 20" in warnings[0], warnings[0]
    assert "upsampled 4.0x" in warnings[0] and "--zoom 18 matches the raster" in warnings[0], warnings[0]
    matched = osmseg_process(*build_args(tmp_path / "z18", f"geotiff:{imagery_tif}", "--zoom", "18"))
    assert matched.returncode == 0 and "upsampled" not in matched.stderr, matched.stderr


# --------------------------------------------------------------------------- d. fewer samples than asked


def test_a_build_that_keeps_fewer_samples_than_asked_says_so(tmp_path: Path, imagery_tif: Path) -> None:
    """1 of 8: exit 0 (the dataset is written, complete for its options, and a rerun gives the same
    one), with one line saying how many, why, and what to change."""
    args = build_args(tmp_path / "ds", f"geotiff:{imagery_tif}", "--max-tries", "1", samples=8)
    args[args.index("--radius-km") + 1] = "0.3"
    for _ in range(2):  # the rerun says it again, and changes nothing
        result = run(*args)
        assert result.exit_code == 0, result.output
        assert len(list((tmp_path / "ds" / "images").glob("*.png"))) == 1
        lines = [line for line in result.stderr.splitlines() if line.startswith("incomplete:")]
        assert lines == ["incomplete: the dataset holds 1 of the 8 samples asked for: 7 slots gave up after "
                         "--max-tries 1 rejected attempt (reasons above and in manifest.json); the same command "
                         "gives the same dataset again: for more, build into a new --out with a higher "
                         "--max-tries, looser filters or a larger area"], result.stderr
    summary = json.loads((tmp_path / "ds" / "manifest.json").read_text())["summary"]
    assert (summary["accepted"], summary["requested"], summary["complete"]) == (1, 8, False)


# --------------------------------------------------------------------------- e. sources that miss the area


@pytest.mark.parametrize("header", [True, False])
def test_an_osm_file_of_another_place_is_refused_before_anything_is_built(tmp_path: Path, header: bool) -> None:
    osm = TINYCITY
    if not header:  # no <bounds>: the extent of its nodes tells
        osm = tmp_path / "nobounds.osm"
        osm.write_text("".join(line for line in TINYCITY.read_text().splitlines(True) if "<bounds" not in line))
    args = build_args(tmp_path / "ds", f"xyz:file://{TILES}/{{z}}/{{x}}/{{y}}.png", where=BERLIN)
    args[args.index(str(TINYCITY))] = str(osm)
    result = run(*args)
    assert result.exit_code == 2, result.output  # was: 20 attempts, then "loosen the filters"
    line = error_line(result)
    assert f"--osm {osm} covers lon 24.93" in line and "which misses the sampling area (lon 13.3" in line, line
    assert ("its header's bounds" if header else "the extent of its nodes") in line
    assert not (tmp_path / "ds").exists()


@pytest.mark.parametrize(("where", "zoom", "says"), [
    ((), "18", "sample where the tiles are"),  # tinycity: the tiles are in Berlin
    (BERLIN, "19", "the folder has tiles at zoom 18: give one of them as --zoom"),
    (("--bbox", "23,59,26,61"), "18", "sample where the tiles are"),  # too many tiles to try: the folder is listed
])
def test_a_tile_folder_without_a_tile_over_the_area_is_refused(tmp_path: Path, where: tuple[str, ...], zoom: str,
                                                                says: str) -> None:
    args = build_args(tmp_path / "ds", f"xyz:file://{TILES}/{{z}}/{{x}}/{{y}}.png", "--zoom", zoom, where=where)
    if where and where[0] == "--bbox":
        del args[args.index("--radius-km"):args.index("--radius-km") + 2]
    result = run(*args)
    assert result.exit_code == 2, result.output
    line = error_line(result)
    assert f"has no tile at zoom {zoom} over the sampling area" in line and says in line, line
    assert not (tmp_path / "ds").exists()


def test_a_tile_folder_is_not_needed_where_samples_may_lack_imagery(tmp_path: Path) -> None:
    """Labels alone (no imagery kept or asked for): an empty folder is what the user meant."""
    (tmp_path / "none").mkdir()
    result = run(*build_args(tmp_path / "ds", f"xyz:file://{tmp_path}/none/{{z}}/{{x}}/{{y}}.png",
                             "--max-missing-imagery", "1", "--max-placeholder-tiles", "25", "--min-contrast", "0",
                             "--max-tries", "3"))
    assert "has no tile" not in result.output


def test_a_server_with_no_imagery_there_is_named_in_the_final_error(tmp_path: Path, http_server) -> None:
    # a tile's 404 is asked 3 times before it counts as "no imagery", 0.5 s then 1 s apart by default:
    # 0.01 s here (the waits are tests/test_http.py's; this test is about the final error)
    result = run(*build_args(tmp_path / "ds", "xyz:" + http_server.url("/t/{z}/{x}/{y}.png"), "--max-tries", "2",
                             "--retry-delay", "0.01"))
    assert result.exit_code == 1, result.output  # every tile answered 404
    line = error_line(result)
    assert "all 4 attempts were rejected for missing imagery" in line, line
    assert "has no imagery over the sampling area at --zoom 18" in line and "loosen the filters" not in line


def test_an_osm_service_with_no_data_there_is_named_in_the_final_error(tmp_path: Path, imagery_tif: Path,
                                                                        http_server) -> None:
    from servers import Reply

    http_server.script("/api/0.6/map", Reply(200, '<?xml version="1.0"?>\n<osm version="0.6" generator="t"/>\n',
                                             {"Content-Type": "text/xml; charset=utf-8"}))
    args = build_args(tmp_path / "ds", f"geotiff:{imagery_tif}", "--max-tries", "2")
    args[args.index(str(TINYCITY))] = "api:" + http_server.url("/api/0.6")
    result = run(*args)
    assert result.exit_code == 1, result.output
    line = error_line(result)
    assert "had no object of any class in any of the 4 attempts' areas, so it has no data there" in line, line


# --------------------------------------------------------------------------- f. 16-bit and paletted GeoTIFFs


def variants(source: Path, folder: Path, window: Window | None = None) -> dict[str, Path]:
    """``source`` (8-bit RGB) as 16-bit (full range), 12-bit (NBITS=12), paletted (64 colours), and
    that palette expanded to 8-bit RGB by numpy: pairs that must read as the same colours."""
    folder.mkdir(parents=True, exist_ok=True)
    with rasterio.open(source) as src:
        rgb = src.read(window=window)
        profile = dict(src.profile, width=rgb.shape[2], height=rgb.shape[1],
                       transform=src.window_transform(window) if window else src.transform)
    paths = {name: folder / f"{name}.tif" for name in ("rgb8", "rgb16", "rgb12", "palette", "expanded")}
    with rasterio.open(paths["rgb8"], "w", **profile) as dst:
        dst.write(rgb)
    with rasterio.open(paths["rgb16"], "w", **dict(profile, dtype="uint16")) as dst:
        dst.write(rgb.astype(np.uint16) * 257)
    with rasterio.open(paths["rgb12"], "w", **dict(profile, dtype="uint16", nbits=12)) as dst:
        dst.write(np.rint(rgb.astype(np.float64) * 4095 / 255).astype(np.uint16))
    quantized = Image.fromarray(rgb.transpose(1, 2, 0)).quantize(64, dither=Image.Dither.NONE)
    index = np.asarray(quantized)
    colours = np.array(quantized.getpalette()[:3 * 64], np.uint8).reshape(64, 3)
    with rasterio.open(paths["palette"], "w", **dict(profile, count=1, photometric="palette")) as dst:
        dst.write(index, 1)
        dst.write_colormap(1, {i: (*map(int, c), 255) for i, c in enumerate(colours)})
    with rasterio.open(paths["expanded"], "w", **profile) as dst:
        dst.write(colours[index].transpose(2, 0, 1))
    return paths


def test_build_reads_16_bit_and_paletted_geotiffs_as_their_8_bit_colours(tmp_path: Path, imagery_tif: Path) -> None:
    tifs = variants(imagery_tif, tmp_path / "tifs")
    built = {}
    for name, path in tifs.items():
        result = run("-q", *build_args(tmp_path / name, f"geotiff:{path}"))
        assert result.exit_code == 0, result.output  # was: "is uint16, not 8-bit" / "is a paletted raster"
        built[name] = images_of(tmp_path / name)
    assert len(built["rgb8"]) == 2
    for name, same_as in (("rgb16", "rgb8"), ("rgb12", "rgb8"), ("palette", "expanded")):
        assert built[name].keys() == built[same_as].keys()
        for key, pixels in built[name].items():
            assert np.array_equal(pixels, built[same_as][key]), (name, key)


def test_predict_reads_16_bit_and_paletted_geotiffs_as_build_does(tmp_path: Path, imagery_tif: Path) -> None:
    torch = pytest.importorskip("torch")
    from training.models.checkpoint import save_checkpoint
    from training.models.networks import build_model, model_spec

    tifs = variants(imagery_tif, tmp_path / "tifs", Window(900, 900, 200, 160))
    torch.manual_seed(0)  # an untrained network: any colour change changes its classes somewhere
    spec = model_spec("airsegnet6", 0.0625, input_size=(64, 96))
    save_checkpoint(tmp_path / "model.pt", {"spec": spec, "model": build_model(spec).state_dict()})
    result = run("-q", "predict", str(tmp_path / "model.pt"), *map(str, tifs.values()), "--out", str(tmp_path / "p"),
                 "--device", "cpu")
    assert result.exit_code == 0, result.output

    def mask(name: str) -> np.ndarray:
        with rasterio.open(tmp_path / "p" / f"{name}.tif") as ds:
            return ds.read(1)
    assert len(np.unique(mask("rgb8"))) > 1
    assert np.array_equal(mask("rgb16"), mask("rgb8")) and np.array_equal(mask("rgb12"), mask("rgb8"))
    assert np.array_equal(mask("palette"), mask("expanded"))  # was: the palette's indices, read as grey


def test_build_and_predict_see_the_same_colours_of_16_bit_and_paletted_rasters(tmp_path: Path,
                                                                             imagery_tif: Path) -> None:
    """The one reading rule, read back by each reader: osmseg.images.read_rgb, the builder's
    provider on a grid that is the raster's own, predict's block reader; the colours expected are
    the 8-bit source's and the numpy-expanded palette's, as rasterio reads them."""
    from osmseg.grid import sample_grid
    from osmseg.imagery.geotiff import GeoTiffProvider
    from osmseg.images import read_rgb
    from training.inference.windows import RasterSource

    grid = sample_grid(LON, LAT, 18, size=1)  # a 256x256 raster on the sample's grid: the warp is the identity
    with rasterio.open(imagery_tif) as src:
        profile = dict(src.profile, crs="EPSG:3857", transform=grid.transform, width=256, height=256)
        pixels = src.read(window=Window(1000, 1000, 256, 256))
    with rasterio.open(tmp_path / "on-grid.tif", "w", **profile) as dst:
        dst.write(pixels)
    tifs = variants(tmp_path / "on-grid.tif", tmp_path / "tifs")
    with rasterio.open(tifs["expanded"]) as ds:
        expanded = ds.read().transpose(1, 2, 0)
    for name, path in tifs.items():
        want = expanded if name in ("palette", "expanded") else pixels.transpose(1, 2, 0)
        assert np.array_equal(read_rgb(path), want), name
        assert np.array_equal(GeoTiffProvider(path).fetch(grid).rgb, want), name
        with rasterio.open(path) as ds:
            assert np.array_equal(RasterSource(ds, path.name).read((0, 256, 0, 256)), want), name
