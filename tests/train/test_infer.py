"""Inference: window grids, split-join (crop and blend), rescale, TTA, PNG/GeoTIFF in and out.

The models here are small fixed networks whose answers are known: ``ColourModel`` gives each
pixel the class whose colour is nearest (a per-pixel function, so every window and every
flip agrees on it), ``ContextModel`` adds a 5x5 convolution and the window's mean colour, so
its output depends on which window a pixel is seen in: block-wise processing only matches
whole-image processing if every block sees exactly the right windows.
"""

from __future__ import annotations

import tracemalloc
from xml.dom import minidom

import numpy as np
import pytest
import rasterio
import torch
from conftest import shared_path
from PIL import Image
from rasterio.crs import CRS
from rasterio.transform import from_origin
from rio_cogeo.cogeo import cog_validate
from torch import nn

from osmseg.errors import ConfigError, ImageryError
from osmseg.output.geotiff import read_class_table
from osmseg.runtime.progress import Step
from training.inference.predict import predict_file
from training.inference.tiling import WindowGrid, blend_weight, letterbox
from training.inference.windows import InferenceOptions, predict_array
from training.models.spec import ModelSpec

torch.set_num_threads(1)

# class id -> colour; ids 1, 2, 5 and 6 have no colour: the model never predicts them
COLOURS = {0: (0, 0, 0), 3: (220, 40, 40), 4: (40, 190, 60), 7: (50, 70, 220), 8: (235, 235, 235)}
NUM_CLASSES = 9
BRIGHT = [3, 4, 7, 8]


def make_spec(input_size: tuple[int, int] = (360, 480), ignore_index: int | None = None) -> ModelSpec:
    table = {"name": "test", "classes": [{"id": i, "name": f"c{i}", "color": list(c)} for i, c in COLOURS.items()]}
    return ModelSpec("segnet", "test", NUM_CLASSES, 1.0, table, ignore_index, input_size=input_size)


class ColourModel(nn.Module):
    """Nearest class colour as a fixed 1x1 convolution.

    Logit k = 2 c_k.x - |c_k|^2, which is |x|^2 - |x - c_k|^2: minus the squared RGB distance
    to colour c_k up to a per-pixel constant, so argmax (and softmax) pick the nearest
    colour.  Ids without a colour get -1e4: the model never predicts them.
    """

    def __init__(self, spec: ModelSpec) -> None:
        super().__init__()
        weight = torch.zeros(NUM_CLASSES, 3)
        bias = torch.full((NUM_CLASSES,), -1e4)
        for i, c in COLOURS.items():
            colour = torch.tensor(c, dtype=torch.float32) / 255.0
            weight[i], bias[i] = 2 * colour, -(colour ** 2).sum()
        self.register_buffer("weight", weight[:, :, None, None])
        self.register_buffer("bias", bias)
        self.register_buffer("mean", torch.tensor(spec.mean).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor(spec.std).view(1, 3, 1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return nn.functional.conv2d(x * self.std + self.mean, self.weight, self.bias)


class ContextModel(ColourModel):
    """Colour logits + a fixed 5x5 convolution + the window's mean colour (window-dependent)."""

    def __init__(self, spec: ModelSpec) -> None:
        super().__init__(spec)
        gen = torch.Generator().manual_seed(3)
        self.conv = nn.Conv2d(3, NUM_CLASSES, 5, padding=2)
        self.mix = nn.Linear(3, NUM_CLASSES)
        with torch.no_grad():
            for p in (*self.conv.parameters(), *self.mix.parameters()):
                p.copy_(torch.randn(p.shape, generator=gen) * 0.3)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return super().forward(x) + self.conv(x) + self.mix(x.mean(dim=(2, 3)))[:, :, None, None]


def blocky(height: int, width: int, cell: int, ids: list[int], seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """An image of random ``cell``-sized squares of class colours (+ noise) and its true classes."""
    rng = np.random.default_rng(seed)
    coarse = rng.choice(ids, size=(height // cell + 1, width // cell + 1))
    truth = np.repeat(np.repeat(coarse, cell, 0), cell, 1)[:height, :width].astype(np.uint8)
    lut = np.zeros((256, 3), dtype=np.int16)
    for i, c in COLOURS.items():
        lut[i] = c
    noisy = lut[truth] + rng.integers(-12, 13, size=(height, width, 3))
    return np.clip(noisy, 0, 255).astype(np.uint8), truth


def write_tif(path, pixels: np.ndarray, crs: str = "EPSG:32633", **extra) -> None:
    bands = pixels[:, :, None] if pixels.ndim == 2 else pixels
    profile = {"driver": "GTiff", "height": bands.shape[0], "width": bands.shape[1], "count": bands.shape[2],
               "dtype": bands.dtype.name, "crs": crs, "transform": from_origin(500000, 5100000, 0.5, 0.5), **extra}
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(bands.transpose(2, 0, 1))


def one_line_error(excinfo: pytest.ExceptionInfo, name: str) -> None:
    message = str(excinfo.value)
    assert "\n" not in message and name in message, message


# ----------------------------------------------------------------------------- window geometry

@pytest.mark.parametrize("height,width", [(1, 1), (359, 479), (360, 480), (361, 481), (1000, 733),
                                          (1280, 1280), (2048, 2048), (90, 5000)])
@pytest.mark.parametrize("overlap", [0, 1, 96, 300])
def test_windows_cover_every_pixel_and_keep_regions_tile(height: int, width: int, overlap: int) -> None:
    grid = WindowGrid.build(height, width, (360, 480), overlap)
    cover = np.zeros((height, width), dtype=np.int32)
    kept = np.zeros((height, width), dtype=np.int32)
    for i in range(len(grid)):
        top, bottom, left, right = grid.window(i)
        assert (bottom - top, right - left) == (360, 480) and top >= 0 and left >= 0
        assert bottom <= max(height, 360) and right <= max(width, 480)
        cover[top:bottom, left:right] += 1
        k = grid.keep(i)
        assert top <= k[0] < k[1] <= bottom and left <= k[2] < k[3] <= right
        kept[k[0]:k[1], k[2]:k[3]] += 1
    assert cover.min() >= 1
    assert (kept == 1).all()
    for starts, length, size in ((grid.row_starts, height, 360), (grid.col_starts, width, 480)):
        assert starts[0] == 0
        if length >= size:  # the last window ends at the border; neighbours overlap enough
            assert starts[-1] + size == length
            assert all(a + size - b >= overlap for a, b in zip(starts, starts[1:]))


def test_overlap_must_be_smaller_than_a_window() -> None:
    with pytest.raises(ConfigError, match="overlap"):
        WindowGrid.build(1000, 1000, (360, 480), 360)
    with pytest.raises(ConfigError, match="overlap"):
        predict_array(ColourModel(make_spec()), np.zeros((10, 10, 3), np.uint8), make_spec(), overlap=-1)


@pytest.mark.parametrize("join", ["crop", "blend"])
@pytest.mark.parametrize("block_size", [None, 1, 300, 1000])
def test_blocks_tile_the_image_and_list_every_window_they_touch(join: str, block_size: int | None) -> None:
    grid = WindowGrid.build(1000, 1733, (360, 480), 96)
    owned = np.zeros((1000, 1733), dtype=np.int32)
    for block in grid.blocks(block_size, join):
        top, bottom, left, right = block.box
        owned[top:bottom, left:right] += 1
        touching = []
        for i in range(len(grid)):
            r = grid.keep(i) if join == "crop" else grid.window(i)
            if r[0] < bottom and top < r[1] and r[2] < right and left < r[3]:
                touching.append(i)
                w = grid.window(i)
                assert block.read[0] <= w[0] and block.read[2] <= w[2]
                assert min(w[1], 1000) <= block.read[1] and min(w[3], 1733) <= block.read[3]
        assert list(block.windows) == touching
    assert (owned == 1).all()


def test_blend_weight_is_positive_and_cross_fades_to_one() -> None:
    w = blend_weight((360, 480), (90, 120))
    assert w.min() > 0 and w.max() == 1.0
    assert np.allclose(w[:, -120:] + w[:, :120], w[:, 200:201])  # two windows 360 px apart sum to 1 per row


# ----------------------------------------------------------------------------- split-join

@pytest.mark.parametrize("join", ["crop", "blend"])
def test_split_join_gives_every_pixel_its_colour_class(join: str) -> None:
    spec = make_spec()
    image, truth = blocky(1000, 733, 23, list(COLOURS))
    pred = predict_array(ColourModel(spec), image, spec, join=join)
    assert pred.shape == truth.shape and pred.dtype == np.uint8
    assert (pred == truth).all()
    small, small_truth = blocky(200, 301, 7, list(COLOURS), seed=1)  # smaller than a window: padded
    assert (predict_array(ColourModel(spec), small, spec, join=join) == small_truth).all()
    for shape in ((1, 1), (2, 3), (1, 700)):
        tiny, tiny_truth = blocky(*shape, 1, list(COLOURS), seed=sum(shape))
        assert (predict_array(ColourModel(spec), tiny, spec, join=join) == tiny_truth).all()
        if shape[1] < 480:  # rescale enlarges it: every pixel survives
            assert (predict_array(ColourModel(spec), tiny, spec, mode="rescale") == tiny_truth).all()


@pytest.mark.parametrize("join", ["crop", "blend"])
def test_block_wise_prediction_equals_whole_image_prediction(join: str) -> None:
    spec = make_spec()
    model = ContextModel(spec)
    image, _ = blocky(900, 1300, 31, list(COLOURS), seed=2)
    whole = predict_array(model, image, spec, join=join, block_size=None)
    for block_size in (250, 700):
        assert np.array_equal(predict_array(model, image, spec, join=join, block_size=block_size, batch_size=3), whole)
    # the test can fail: the context model answers differently when the windows differ
    assert not np.array_equal(predict_array(model, image[:, :700], spec, join=join, block_size=None), whole[:, :700])


def test_crop_and_blend_differ_only_where_windows_disagree() -> None:
    spec = make_spec()
    image, truth = blocky(700, 900, 31, list(COLOURS), seed=4)
    crop = predict_array(ContextModel(spec), image, spec, join="crop")
    blend = predict_array(ContextModel(spec), image, spec, join="blend")
    assert 0.9 < (crop == blend).mean() < 1.0


def test_ignored_class_is_never_predicted() -> None:
    spec = make_spec(ignore_index=0)
    image, truth = blocky(400, 500, 40, list(COLOURS), seed=5)
    assert (truth == 0).any()
    for mode in ("split-join", "rescale"):
        pred = predict_array(ColourModel(spec), image, spec, mode=mode)
        assert not (pred == 0).any()
    assert (predict_array(ColourModel(spec), image, spec)[truth != 0] == truth[truth != 0]).all()


def test_a_model_with_the_wrong_number_of_classes_is_refused() -> None:
    spec = make_spec()
    with pytest.raises(ConfigError, match="num_classes") as excinfo:
        predict_array(nn.Conv2d(3, 5, 1), np.zeros((100, 100, 3), np.uint8), spec)
    one_line_error(excinfo, "(1, 5, 360, 480)")


def test_progress_reports_every_window() -> None:
    spec, steps = make_spec(), []
    predict_array(ColourModel(spec), np.zeros((1000, 733, 3), np.uint8), spec, batch_size=3, progress=steps.append)
    calls = [(s.done, s.total) for s in steps]
    assert calls[0] == (0, 8) and calls[-1] == (8, 8) and [d for d, _ in calls] == sorted(d for d, _ in calls)
    assert {s.unit for s in steps} == {"window"} and steps[-1].finished


# ----------------------------------------------------------------------------- rescale

@pytest.mark.parametrize("height,width", [(500, 300), (301, 1000), (1280, 1280), (100, 150), (37, 2000)])
def test_rescale_keeps_shape_class_ids_and_never_shows_the_bars(height: int, width: int) -> None:
    spec = make_spec()
    image, truth = blocky(height, width, max(8, min(height, width) // 6), BRIGHT, seed=height)
    pred = predict_array(ColourModel(spec), image, spec, mode="rescale")
    assert pred.shape == (height, width) and pred.dtype == np.uint8
    assert set(np.unique(pred).tolist()) <= set(BRIGHT)  # no black (bars), no interpolated ids
    if min(height, width) >= 100:
        assert (pred == truth).mean() > 0.9


def test_rescale_letterbox_is_centred() -> None:
    assert letterbox(500, 300) == (0, 360, 132, 348)
    assert letterbox(360, 480) == (0, 360, 0, 480)


# ----------------------------------------------------------------------------- test-time augmentation

@pytest.mark.parametrize("mode,join", [("split-join", "blend"), ("split-join", "crop"), ("rescale", "blend")])
def test_tta_with_a_flip_equivariant_model_changes_nothing(mode: str, join: str) -> None:
    spec = make_spec(input_size=(64, 64) if mode == "rescale" else (360, 480))  # square: rotations too
    image, _ = blocky(500, 611, 13, list(COLOURS), seed=6)
    plain = predict_array(ColourModel(spec), image, spec, mode=mode, join=join)
    assert np.array_equal(predict_array(ColourModel(spec), image, spec, mode=mode, join=join, tta=True), plain)


@pytest.mark.parametrize("size", [(32, 48), (48, 48)])
def test_tta_makes_a_direction_sensitive_model_flip_equivariant(size: tuple[int, int]) -> None:
    spec = make_spec(input_size=size)
    torch.manual_seed(0)
    model = nn.Conv2d(3, NUM_CLASSES, 3, padding=1)
    image, _ = blocky(*size, 4, list(COLOURS), seed=7)
    ops = {"hflip": lambda a: a[:, ::-1], "vflip": lambda a: a[::-1]}
    if size[0] == size[1]:
        ops |= {"rot90": lambda a: np.rot90(a), "transpose": lambda a: a.swapaxes(0, 1)}
    tta = predict_array(model, image, spec, tta=True)
    for name, op in ops.items():
        assert np.array_equal(predict_array(model, op(image), spec, tta=True), op(tta)), name
    # without TTA the model is not equivariant, so the check above can fail
    assert not np.array_equal(predict_array(model, image[:, ::-1], spec), predict_array(model, image, spec)[:, ::-1])


def test_segnet_integration() -> None:
    from training.models.networks import SegNet

    spec = ModelSpec("segnet", "tiny", NUM_CLASSES, 0.0625, make_spec().class_table, 0)
    torch.manual_seed(0)
    model = SegNet(NUM_CLASSES, width=0.0625)
    image, _ = blocky(400, 500, 20, list(COLOURS), seed=8)
    for mode, join in (("split-join", "blend"), ("split-join", "crop"), ("rescale", "blend")):
        pred = predict_array(model, image, spec, mode=mode, join=join)
        assert pred.shape == (400, 500) and pred.dtype == np.uint8
        assert set(np.unique(pred).tolist()) <= set(range(1, NUM_CLASSES))  # 0 is ignored: never predicted
    whole = predict_array(model, image, spec, block_size=None)
    assert np.array_equal(predict_array(model, image, spec, block_size=200), whole)


# ----------------------------------------------------------------------------- files

def test_geotiff_in_geotiff_out_keeps_georeference(tmp_path) -> None:
    spec = make_spec()
    image, truth = blocky(333, 517, 19, list(COLOURS), seed=9)
    write_tif(tmp_path / "in.tif", image)
    out = predict_file(ColourModel(spec), spec, tmp_path / "in.tif", tmp_path / "out" / "mask.tif",
                       InferenceOptions(block_size=200), colour_dst=tmp_path / "out" / "colour.png")
    with rasterio.open(tmp_path / "in.tif") as src, rasterio.open(out) as ds:
        assert ds.crs == CRS.from_epsg(32633) == src.crs and ds.transform == src.transform
        assert (ds.count, ds.dtypes[0], ds.width, ds.height) == (1, "uint8", 517, 333)
        assert ds.compression.value.lower() == "deflate" and ds.profile["tiled"]
        assert ds.colormap(1)[3] == (*COLOURS[3], 255) and ds.colormap(1)[8] == (*COLOURS[8], 255)
        assert np.array_equal(ds.read(1), truth)
        # the class metadata convention of every osmseg GeoTIFF (dataset labels alike)
        assert ds.tags(1)["CLASS_3"] == "c3" and ds.tags()["CLASS_TABLE"] == "test"
        assert read_class_table(ds).to_dict() == spec.table.to_dict()
    assert cog_validate(str(out))[0], cog_validate(str(out))  # a Cloud-Optimized GeoTIFF, by rio-cogeo
    colour = np.asarray(Image.open(tmp_path / "out" / "colour.png"))
    assert np.array_equal(colour, spec.palette()[truth])
    # beside the mask its QGIS style, naming the classes in QGIS's legend (read with another XML library)
    entries = minidom.parse(str(tmp_path / "out" / "mask.qml")).getElementsByTagName("paletteEntry")
    assert [(e.getAttribute("value"), e.getAttribute("label")) for e in entries] == \
        [(str(c.id), c.name) for c in sorted((spec.table.unlabeled, *spec.table.classes), key=lambda c: c.id)]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["colour.png", "mask.qml", "mask.tif"]  # no temp files
    assert out.stat().st_mode & 0o777 == 0o644  # readable by others, like the dataset files


@pytest.mark.parametrize("suffix", [".tif", ".png"])
def test_resolution_resamples_the_input_and_returns_classes_on_its_grid(tmp_path, suffix: str) -> None:
    """0.5 m pixels predicted at 1.0 m: a quarter of the windows, the mask back on the 0.5 m grid."""
    spec = make_spec()
    image, truth = blocky(720, 960, 40, list(COLOURS), seed=4)
    write_tif(tmp_path / "in.tif", image)  # 0.5 m pixels in UTM 33N
    runs = {}
    for target in (None, 1.0):
        steps: list[Step] = []
        out = predict_file(ColourModel(spec), spec, tmp_path / "in.tif", tmp_path / f"{target}{suffix}",
                           resolution_m=target, progress=steps.append)
        calls = [(s.done, s.total) for s in steps]
        mask = np.asarray(Image.open(out)) if suffix == ".png" else rasterio.open(out).read(1)
        runs[target] = (calls[-1][1], mask)
    (whole_windows, whole), (coarse_windows, coarse) = runs[None], runs[1.0]
    assert coarse.shape == whole.shape == truth.shape
    assert np.array_equal(whole, truth)
    assert coarse_windows < whole_windows / 2  # the model saw the image at half the size
    assert (coarse == truth).mean() > 0.97  # the same classes, but for a pixel's width along cell edges
    if suffix == ".tif":
        with rasterio.open(tmp_path / "1.0.tif") as ds, rasterio.open(tmp_path / "in.tif") as src:
            assert ds.transform == src.transform and ds.crs == src.crs
            assert read_class_table(ds).to_dict() == spec.table.to_dict()
        assert cog_validate(str(tmp_path / "1.0.tif"))[0]
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []  # no staging files left


@pytest.mark.parametrize("join", ["crop", "blend"])
def test_geotiff_block_wise_equals_whole_image(tmp_path, join: str) -> None:
    spec = make_spec()
    model = ContextModel(spec)
    image, _ = blocky(900, 1100, 29, list(COLOURS), seed=10)
    write_tif(tmp_path / "in.tif", image, tiled=True, blockxsize=128, blockysize=128, compress="deflate")
    predict_file(model, spec, tmp_path / "in.tif", tmp_path / "mask.tif", InferenceOptions(join=join, block_size=300),
                 colour_dst=tmp_path / "colour.tif")
    with rasterio.open(tmp_path / "mask.tif") as ds:
        blocks = ds.read(1)
    assert np.array_equal(blocks, predict_array(model, image, spec, join=join, block_size=None))
    with rasterio.open(tmp_path / "colour.tif") as ds:
        assert ds.count == 3 and ds.crs == CRS.from_epsg(32633)
        assert np.array_equal(ds.read().transpose(1, 2, 0), spec.palette()[blocks])


def test_rescale_geotiff(tmp_path) -> None:
    spec = make_spec()
    image, truth = blocky(700, 1000, 60, BRIGHT, seed=11)
    write_tif(tmp_path / "in.tif", image)
    predict_file(ColourModel(spec), spec, tmp_path / "in.tif", tmp_path / "mask.tif",
                 InferenceOptions(mode="rescale", block_size=256))
    with rasterio.open(tmp_path / "mask.tif") as ds:
        pred = ds.read(1)
        assert ds.transform == from_origin(500000, 5100000, 0.5, 0.5) and ds.crs == CRS.from_epsg(32633)
    assert pred.shape == truth.shape and set(np.unique(pred).tolist()) <= set(BRIGHT)
    assert (pred == truth).mean() > 0.9


def test_png_and_jpeg_in_png_out(tmp_path) -> None:
    spec = make_spec()
    image, truth = blocky(300, 410, 30, list(COLOURS), seed=12)
    Image.fromarray(image).save(tmp_path / "in.png")
    Image.fromarray(image).save(tmp_path / "in.jpg", quality=95)
    predict_file(ColourModel(spec), spec, tmp_path / "in.png", tmp_path / "mask.png", colour_dst=tmp_path / "c.png")
    with Image.open(tmp_path / "mask.png") as mask:
        assert mask.mode == "L" and np.array_equal(np.asarray(mask), truth)
    assert np.array_equal(np.asarray(Image.open(tmp_path / "c.png")), spec.palette()[truth])
    predict_file(ColourModel(spec), spec, tmp_path / "in.jpg", tmp_path / "jmask.png", InferenceOptions(mode="rescale"))
    jpeg = np.asarray(Image.open(tmp_path / "jmask.png"))
    assert jpeg.shape == truth.shape and (jpeg == truth).mean() > 0.9


def test_band_counts(tmp_path) -> None:
    spec = make_spec()
    model = ColourModel(spec)
    image, truth = blocky(200, 260, 20, list(COLOURS), seed=13)
    grey = image[:, :, 1]
    alpha = np.random.default_rng(0).integers(0, 256, size=grey.shape, dtype=np.uint8)
    expected_grey = predict_array(model, np.repeat(grey[:, :, None], 3, axis=2), spec)
    opaque = np.where(alpha >= 128, truth, 0)  # transparent pixels get class 0: no image there
    cases = {
        "grey.tif": (grey, expected_grey), "rgba.tif": (np.dstack([image, alpha]), opaque),
        "grey.png": (grey, expected_grey), "rgba.png": (np.dstack([image, alpha]), opaque),
    }
    for name, (pixels, expected) in cases.items():
        if name.endswith(".tif"):
            write_tif(tmp_path / name, pixels)
        else:
            Image.fromarray(pixels).save(tmp_path / name)
        predict_file(model, spec, tmp_path / name, tmp_path / f"{name}.mask.png")
        assert np.array_equal(np.asarray(Image.open(tmp_path / f"{name}.mask.png")), expected), name
    write_tif(tmp_path / "two.tif", np.dstack([grey, alpha]))
    Image.fromarray(np.dstack([grey, alpha])).save(tmp_path / "two.png")
    write_tif(tmp_path / "deep.tif", image.astype(np.uint16) * 257)  # 16 bits scaled, as osmseg build reads them
    predict_file(model, spec, tmp_path / "deep.tif", tmp_path / "deep.mask.png")
    assert np.array_equal(np.asarray(Image.open(tmp_path / "deep.mask.png")), truth)
    write_tif(tmp_path / "float.tif", image.astype(np.float32))
    for name, what in (("two.tif", "2 bands"), ("two.png", "2 bands"), ("float.tif", "float32")):
        with pytest.raises(ImageryError, match=what) as excinfo:
            predict_file(model, spec, tmp_path / name, tmp_path / "x.png")
        one_line_error(excinfo, name)
    with pytest.raises(ImageryError, match="bands"):
        predict_array(model, np.zeros((50, 50, 2), np.uint8), spec)
    with pytest.raises(ImageryError, match="float32"):
        predict_array(model, np.zeros((50, 50, 3), np.float32), spec)


def test_unreadable_inputs_give_one_line_errors_and_no_output(tmp_path) -> None:
    spec = make_spec()
    model = ColourModel(spec)
    image, _ = blocky(300, 300, 20, list(COLOURS))
    (tmp_path / "garbage.png").write_bytes(b"this is not an image at all")
    (tmp_path / "garbage.tif").write_bytes(b"II*\x00 not really a tiff")
    Image.fromarray(image).save(tmp_path / "whole.png")
    data = (tmp_path / "whole.png").read_bytes()
    (tmp_path / "truncated.png").write_bytes(data[: len(data) // 2])
    write_tif(tmp_path / "whole.tif", image, compress="deflate", tiled=True, blockxsize=64, blockysize=64)
    data = (tmp_path / "whole.tif").read_bytes()
    (tmp_path / "truncated.tif").write_bytes(data[: len(data) // 2])
    for name in ("garbage.png", "garbage.tif", "truncated.png", "truncated.tif", "missing.png"):
        with pytest.raises(ImageryError) as excinfo:
            predict_file(model, spec, tmp_path / name, tmp_path / "out" / f"{name}.tif")
        one_line_error(excinfo, name)
    assert not (tmp_path / "out").exists() or list((tmp_path / "out").iterdir()) == []
    with pytest.raises(ConfigError, match=".jpg"):
        predict_file(model, spec, tmp_path / "whole.png", tmp_path / "mask.jpg")
    with pytest.raises(ConfigError, match="mode"):
        predict_file(model, spec, tmp_path / "whole.png", tmp_path / "mask.png", InferenceOptions(mode="tiles"))
    with pytest.raises(ConfigError, match="overwrite"):
        predict_file(model, spec, tmp_path / "whole.tif", tmp_path / "whole.tif")


# ----------------------------------------------------------------------------- real 2048x2048 orthophoto

def test_manila_orthophoto_blockwise_equals_whole_and_keeps_georeference(tmp_path) -> None:
    src = shared_path("oam-rgb", "manila.tif")
    spec = make_spec()
    model = ContextModel(spec)
    peaks = {}
    for name, block_size in (("blocks", 1024), ("whole", None)):
        tracemalloc.start()
        predict_file(model, spec, src, tmp_path / f"{name}.tif", InferenceOptions(block_size=block_size))
        peaks[name] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    print(f"\nmanila 2048x2048, blend, {NUM_CLASSES} classes: peak traced memory "
          f"block-wise (1024) {peaks['blocks'] / 2**20:.0f} MiB, whole image {peaks['whole'] / 2**20:.0f} MiB")
    with rasterio.open(src) as ds, rasterio.open(tmp_path / "blocks.tif") as a:
        assert a.crs == ds.crs == CRS.from_epsg(3395) and a.transform == ds.transform
        assert (a.width, a.height) == (2048, 2048)
        blocks = a.read(1)
    with rasterio.open(tmp_path / "whole.tif") as b:
        assert np.array_equal(blocks, b.read(1))
    assert peaks["blocks"] < peaks["whole"] / 2
    predict_file(model, spec, src, tmp_path / "rescale.tif", InferenceOptions(mode="rescale"))
    with rasterio.open(tmp_path / "rescale.tif") as r:
        assert r.crs == CRS.from_epsg(3395) and r.shape == (2048, 2048)


def test_a_geotiff_in_a_local_engineering_crs_is_predicted_without_a_ground_resolution(tmp_path) -> None:
    """Drone software writes rasters in a LOCAL_CS: not on the Earth, so no ground pixel size, no error."""
    spec = make_spec()
    image, truth = blocky(200, 300, 20, list(COLOURS), seed=2)
    local = 'LOCAL_CS["site grid",UNIT["metre",1],AXIS["X",EAST],AXIS["Y",NORTH]]'
    write_tif(tmp_path / "site.tif", image, crs=CRS.from_wkt(local))
    out = predict_file(ColourModel(spec), spec, tmp_path / "site.tif", tmp_path / "site_mask.tif", resolution_m=0.3)
    with rasterio.open(out) as ds:
        assert np.array_equal(ds.read(1), truth)


@pytest.mark.parametrize("kind", ["nodata", "alpha-png"])
def test_pixels_the_input_marks_empty_get_class_0(tmp_path, kind: str) -> None:
    """An orthophoto's nodata collar or a transparent PNG area: no image there, so no class (0)."""
    spec = make_spec()
    image, truth = blocky(240, 320, 20, [3, 4, 7, 8], seed=5)  # 0 is never one of the true classes
    if kind == "nodata":
        image[:, :100] = 0
        write_tif(tmp_path / "in.tif", image, nodata=0)
        src, dst = tmp_path / "in.tif", tmp_path / "out.tif"
    else:
        alpha = np.full(image.shape[:2], 255, np.uint8)
        alpha[:, :100] = 0
        Image.fromarray(np.dstack([image, alpha])).save(tmp_path / "in.png")
        src, dst = tmp_path / "in.png", tmp_path / "out.png"
    for resolution in (None, 1.0):
        out = predict_file(ColourModel(spec), spec, src, dst, resolution_m=resolution)
        mask = rasterio.open(out).read(1) if kind == "nodata" else np.asarray(Image.open(out))
        assert (mask[:, :100] == 0).all()
        if resolution is None:
            assert np.array_equal(mask[:, 100:], truth[:, 100:])
        else:  # predicted at half the size: the same classes, but for a pixel's width at the edges
            assert (mask[:, 102:] == truth[:, 102:]).mean() > 0.95


def test_a_class_table_with_its_void_at_11_survives_a_geotiff(tmp_path) -> None:
    """CamVid's table (void = 11): the unlabeled id is written and read back; osmseg's tables write no such tag."""
    from osmseg.classes import load_class_table
    from osmseg.output.geotiff import write_class_metadata

    for name, tagged in (("camvid.toml", True), ("classes13.toml", False)):
        table = load_class_table(name)
        path = tmp_path / f"{name}.tif"
        with rasterio.open(path, "w", driver="GTiff", width=4, height=4, count=1, dtype="uint8",
                           crs=CRS.from_epsg(3857), transform=from_origin(0, 4, 1, 1)) as dst:
            dst.write(np.full((1, 4, 4), table.unlabeled.id, np.uint8))
            write_class_metadata(dst, table)
        with rasterio.open(path) as ds:
            back = read_class_table(ds)
            assert back is not None and back.unlabeled.id == table.unlabeled.id  # classes13 lists by rule order:
            assert {i: (c.name, c.color) for i, c in back.by_id.items()} == \
                {i: (c.name, c.color) for i, c in table.by_id.items()}          # compare by id
            assert back.unlabeled.name == ("Unlabelled" if tagged else "unlabeled")
            assert ("CLASS_UNLABELED" in ds.tags()) == tagged
            assert ds.descriptions[0].endswith(f"{table.unlabeled.id} = {table.unlabeled.name}")
