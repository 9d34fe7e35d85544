"""A ``--image-format cog`` dataset read the way torchgeo users read it, by torchgeo alone.

torchgeo (an independent reader: no osmseg code reads the files here) indexes ``images/*.tif``
and ``geo/*.tif`` as two ``RasterDataset`` subclasses, intersects them and samples random
patches through a ``DataLoader``. The tests check that torchgeo sees the grid osmseg wrote
(EPSG:3857, the samples' pixel size), that its samples are what the files hold, and that mask and
image samples line up: the imagery is painted from the same OSM data (``osmseg.demo.render``, in
ETRS-TM35FIN as in tests/core/test_build.py), so building pixels of a mask must sit on roof colour.

torchgeo 0.8 facts these tests rely on (torchgeo/datasets/geo.py, torchgeo/samplers/):

* a query is a tuple of slices in the dataset CRS, ``ds[xmin:xmax, ymin:ymax]`` (the step, i.e.
  the resolution, and the time slice default to the dataset's); samples are dicts with ``crs``,
  ``bounds`` (the query), ``image`` (float32, C x H x W, values not rescaled) or ``mask`` (int64,
  H x W);
* the index is a GeoDataFrame of file footprints in path order; where footprints overlap,
  ``rasterio.merge.merge`` (method "first") takes each pixel from the first file, by sorted path,
  that has a valid pixel there -- every pixel, as osmseg declares no nodata;
* ``RandomGeoSampler(generator=...)`` seeds only the offset inside a footprint: the footprint is
  drawn with ``torch.multinomial`` on torch's global RNG, so the global seed must be fixed too.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torchgeo")

import rasterio
import torch
from affine import Affine
from click.testing import CliRunner
from conftest import TINYCITY, TINYCITY_CENTRE
from PIL import Image
from rasterio.enums import ColorInterp
from rio_cogeo.cogeo import cog_validate
from torch.utils.data import DataLoader
from torchgeo.datasets import IntersectionDataset, RasterDataset, stack_samples
from torchgeo.samplers import RandomGeoSampler

from osmseg.classes import load_class_table
from osmseg.cli.main import cli
from osmseg.demo.render import IDS13, MATERIALS

LON, LAT = TINYCITY_CENTRE
TABLE = load_class_table("classes13.toml")
SIDE = 1280  # pixels per sample side (5 x 5 tiles of 256 px)
PATCH, PATCHES, BATCH = 768, 12, 4  # 768 px: most patches hold a few roofs
MATERIAL = {IDS13[name]: np.array(rgb, float) for name, rgb in MATERIALS.items()}
BUILDING = IDS13["building"]
VEGETATION = {IDS13["tree"], IDS13["park"], IDS13["natural"], IDS13["grass"]}  # too alike by mean colour
MIN_PIXELS = 2000  # classes with fewer pixels in a patch are not judged by colour


class AerialImages(RasterDataset):
    """``images/*.tif`` of an osmseg dataset: RGB photos (torchgeo's custom-raster recipe)."""

    filename_glob = "*.tif"
    is_image = True
    all_bands = ("red", "green", "blue")
    rgb_bands = ("red", "green", "blue")


class ClassMasks(RasterDataset):
    """``geo/*.tif`` of an osmseg dataset: class ids."""

    filename_glob = "*.tif"
    is_image = False


@pytest.fixture(scope="module")
def out(tmp_path_factory: pytest.TempPathFactory, imagery_tif: Path) -> Path:
    """A 3-sample COG dataset built through the real CLI (its samples overlap each other)."""
    out = tmp_path_factory.mktemp("cogds") / "ds"
    result = CliRunner().invoke(cli, [
        "-q", "build", "--lat", str(LAT), "--lon", str(LON), "--radius-km", "0.08", "--samples", "3",
        "--seed", "1", "--image-format", "cog", "--imagery", f"geotiff:{imagery_tif}", "--osm", str(TINYCITY),
        "--out", str(out), "--cache-dir", str(out.parent / "cache")], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="module")
def samples(out: Path) -> list[dict]:
    """The manifest's samples, in file-name order (torchgeo's index order)."""
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["image_format"] == "cog" and len(manifest["samples"]) == 3
    return sorted(manifest["samples"], key=lambda s: s["name"])


@pytest.fixture(scope="module")
def dataset(out: Path) -> IntersectionDataset:
    images, masks = AerialImages(out / "images"), ClassMasks(out / "geo")
    return images & masks


def pixel_size(sample: dict) -> float:
    xmin, _, xmax, _ = sample["bounds_3857"]
    return (xmax - xmin) / SIDE


def read_labels_png(out: Path, name: str) -> np.ndarray:
    with Image.open(out / "labels" / f"{name}.png") as im:
        assert im.mode == "L"
        return np.asarray(im)


def read_cog(path: Path) -> np.ndarray:
    with rasterio.open(path) as src:
        return src.read()


class Mosaic:
    """The samples' files pasted on their common Web Mercator pixel grid, read with PIL and
    rasterio: what torchgeo's merge should return for any box on that grid.

    Files are pasted in reverse path order, so where samples overlap the first file by path
    wins, as in ``rasterio.merge`` (method "first") over torchgeo's path-ordered index.
    """

    def __init__(self, out: Path, samples: list[dict]) -> None:
        self.res = pixel_size(samples[0])
        bounds = np.array([s["bounds_3857"] for s in samples])
        self.left, self.top = bounds[:, 0].min(), bounds[:, 3].max()
        width = self.col(bounds[:, 2].max())
        height = self.row(bounds[:, 1].min())
        self.image = np.zeros((3, height, width), np.uint8)
        self.labels = np.zeros((height, width), np.uint8)
        self.owner = np.full((height, width), -1)  # index of the sample whose pixels are pasted
        self.windows = []
        for s in samples:
            row, col = self.row(s["bounds_3857"][3]), self.col(s["bounds_3857"][0])
            self.windows.append((slice(row, row + SIDE), slice(col, col + SIDE)))
        for i in reversed(range(len(samples))):
            rows, cols = self.windows[i]
            name = samples[i]["name"]
            self.image[:, rows, cols] = read_cog(out / "images" / f"{name}.tif")
            self.labels[rows, cols] = read_labels_png(out, name)
            self.owner[rows, cols] = i

    def _index(self, offset: float) -> int:
        pixels = offset / self.res
        assert abs(pixels - round(pixels)) < 1e-6, f"{offset} m is off the common pixel grid"
        return round(pixels)

    def col(self, x: float) -> int:
        return self._index(x - self.left)

    def row(self, y: float) -> int:
        return self._index(self.top - y)

    def window(self, xs: slice, ys: slice) -> tuple[slice, slice]:
        return slice(self.row(ys.stop), self.row(ys.start)), slice(self.col(xs.start), self.col(xs.stop))


@pytest.fixture(scope="module")
def mosaic(out: Path, samples: list[dict]) -> Mosaic:
    return Mosaic(out, samples)


def nearest_material(rgb_mean: np.ndarray, brightness_free: bool) -> int:
    """Class id whose material colour is nearest ``rgb_mean``; with ``brightness_free``, up to a
    brightness shift equal on the three channels (render_aerial varies each roof's brightness by
    up to +-38 that way, so one dark roof in a patch can look like bare ground)."""
    def distance(cid: int) -> float:
        diff = rgb_mean - MATERIAL[cid]
        if brightness_free:
            diff = diff - diff.mean()
        return float(np.linalg.norm(diff))
    return min(MATERIAL, key=distance)


def misplaced_classes(image: np.ndarray, mask: np.ndarray) -> list[tuple[int, int]]:
    """``(class, looks like)`` for each non-vegetation class of a patch (3 x H x W image, H x W mask)
    whose pixels do not show that class's material."""
    pixels = image.transpose(1, 2, 0).astype(float)
    wrong = []
    for cid in np.unique(mask):
        cid = int(cid)
        if cid in VEGETATION or (mask == cid).sum() < MIN_PIXELS:
            continue
        looks = nearest_material(pixels[mask == cid].mean(axis=0), brightness_free=cid == BUILDING)
        if looks != cid:
            wrong.append((cid, looks))
    return wrong


def test_torchgeo_indexes_the_files_in_web_mercator_at_the_samples_pixel_size(
        out: Path, samples: list[dict], dataset: IntersectionDataset) -> None:
    images, masks = dataset.datasets
    assert [Path(p).name for p in images.index.filepath] == [f"{s['name']}.tif" for s in samples]
    assert [Path(p).name for p in masks.index.filepath] == [f"{s['name']}.tif" for s in samples]
    for ds in (images, masks, dataset):
        assert ds.crs.to_epsg() == 3857
        for s in samples:
            assert ds.res == pytest.approx((pixel_size(s), pixel_size(s)), rel=1e-12)
    # the footprints torchgeo indexed are the manifest's bounds
    for geometry, s in zip(masks.index.geometry, samples):
        assert geometry.bounds == pytest.approx(tuple(s["bounds_3857"]), abs=1e-6)
    # 3 image footprints x 3 mask footprints, all overlapping pairwise
    assert len(dataset) == 9
    # torchgeo picks the class colours up from the colour table; the photos have none
    assert masks.cmap[BUILDING][:3] == tuple(TABLE.by_name["building"].color)
    assert not images.cmap


def test_random_patches_from_a_dataloader_are_the_files_pixels_and_line_up(
        samples: list[dict], dataset: IntersectionDataset, mosaic: Mosaic) -> None:
    label_ids = set(np.unique(mosaic.labels).tolist())
    assert label_ids <= {c.id for c in (TABLE.unlabeled, *TABLE.classes)}
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)  # RandomGeoSampler draws the footprint on the global RNG
        sampler = RandomGeoSampler(dataset, size=PATCH, length=PATCHES, generator=torch.Generator().manual_seed(0))
        loader = DataLoader(dataset, batch_size=BATCH, sampler=sampler, collate_fn=stack_samples)
        batches = list(loader)
    assert len(batches) == PATCHES // BATCH
    building_pixels, judged, with_roofs, misaligned_failures = [], 0, 0, 0
    for batch in batches:
        assert batch["image"].shape == (BATCH, 3, PATCH, PATCH) and batch["image"].dtype == torch.float32
        assert batch["mask"].shape == (BATCH, PATCH, PATCH) and batch["mask"].dtype == torch.int64
        for image, mask, (xs, ys, _), crs in zip(batch["image"], batch["mask"], batch["bounds"], batch["crs"]):
            assert crs.to_epsg() == 3857
            image, mask = image.numpy(), mask.numpy()
            # photo values as stored (uint8 range, not rescaled), only class ids of the labels
            assert image.min() >= 0 and image.max() <= 255 and (image == np.round(image)).all()
            assert set(np.unique(mask).tolist()) <= label_ids
            # exactly the files' pixels at that place (first file by path where samples overlap)
            rows, cols = mosaic.window(xs, ys)
            assert np.array_equal(mask, mosaic.labels[rows, cols])
            assert np.array_equal(image, mosaic.image[:, rows, cols])
            # line-up: each class of the mask sits on its material in the image
            assert misplaced_classes(image, mask) == [], f"patch at x={xs.start:.1f} y={ys.start:.1f}"
            judged += 1
            with_roofs += (mask == BUILDING).sum() >= MIN_PIXELS
            building_pixels.append(image.transpose(1, 2, 0)[mask == BUILDING])
            # the check has teeth: the same mask 24 px (14 m) off is caught
            misaligned_failures += bool(misplaced_classes(image, np.roll(mask, (24, 24), axis=(0, 1))))
    assert judged == PATCHES and with_roofs >= PATCHES // 2
    # all roofs of all patches together: the building material itself, no brightness allowance
    roofs = np.concatenate(building_pixels)
    assert len(roofs) > 10 * MIN_PIXELS
    assert nearest_material(roofs.mean(axis=0), brightness_free=False) == BUILDING
    assert misaligned_failures >= PATCHES * 3 // 4


def test_a_query_at_a_samples_bounds_gives_its_label_png_and_its_cog_where_no_earlier_file_covers(
        out: Path, samples: list[dict], dataset: IntersectionDataset, mosaic: Mosaic) -> None:
    """The samples overlap pairwise. Overlapping label files agree pixel for pixel, so the mask at a
    sample's box is its labels PNG exactly. Overlapping photos need not: each sample's photo is its
    own bilinear warp of the source (GDAL's approximate transformer), so the same ground may differ
    by a grey level or two between samples, and torchgeo's merge takes the pixel of the first file
    by path. So the photo at sample i's box is its COG wherever no earlier sample covers it (all of
    it for the first sample), and the earlier sample's pixel elsewhere."""
    for i, s in enumerate(samples):
        xmin, ymin, xmax, ymax = s["bounds_3857"]
        got = dataset[xmin:xmax, ymin:ymax]
        assert got["crs"].to_epsg() == 3857
        assert got["image"].shape == (3, SIDE, SIDE) and got["mask"].shape == (SIDE, SIDE)
        mask, image = got["mask"].numpy(), got["image"].numpy()
        assert np.array_equal(mask, read_labels_png(out, s["name"]))
        own = read_cog(out / "images" / f"{s['name']}.tif")
        rows, cols = mosaic.windows[i]
        mine = mosaic.owner[rows, cols] == i  # pixels no earlier-sorted sample covers
        assert mine.all() == (i == 0)
        assert np.array_equal(image[:, mine], own[:, mine])
        assert np.array_equal(image, mosaic.image[:, rows, cols])
        assert np.abs(image[:, ~mine] - own[:, ~mine]).max(initial=0) <= 3  # same ground, other warp
    # where samples overlap, their labels agree: the mosaic (first sample's labels on top) is
    # every sample's labels PNG in its window, which makes the mask mosaic independent of order
    for i, s in enumerate(samples):
        assert np.array_equal(mosaic.labels[mosaic.windows[i]], read_labels_png(out, s["name"]))


def test_rasterio_and_rio_cogeo_see_the_same_grid_and_valid_cogs(out: Path, samples: list[dict]) -> None:
    for s in samples:
        xmin, ymin, xmax, ymax = s["bounds_3857"]
        res = pixel_size(s)
        expected = Affine(res, 0.0, xmin, 0.0, -res, ymax)
        image_path, label_path = out / "images" / f"{s['name']}.tif", out / "geo" / f"{s['name']}.tif"
        for path in (image_path, label_path):
            valid, errors, _ = cog_validate(str(path))
            assert valid, (path, errors)
            with rasterio.open(path) as src:
                assert src.crs.to_epsg() == 3857
                assert src.transform.almost_equals(expected, precision=1e-9)
                assert src.bounds == pytest.approx((xmin, ymin, xmax, ymax), abs=1e-6)
                assert src.shape == (SIDE, SIDE) and src.dtypes == ("uint8",) * src.count
                assert src.nodata is None and src.block_shapes[0] == (256, 256)
                assert src.overviews(1) == [2, 4, 8]
        with rasterio.open(image_path) as src:
            assert src.colorinterp == (ColorInterp.red, ColorInterp.green, ColorInterp.blue)
        classes = read_labels_png(out, s["name"])
        with rasterio.open(label_path) as src:
            assert src.count == 1 and np.array_equal(src.read(1), classes)
        # the stored overviews of the class ids are nearest-neighbour: only class ids of the mask
        for level, factor in enumerate((2, 4, 8)):
            with rasterio.open(label_path, overview_level=level) as ov:
                assert ov.shape == (SIDE // factor, SIDE // factor)
                assert set(np.unique(ov.read(1))) <= set(np.unique(classes))
                assert ov.transform.almost_equals(expected * Affine.scale(factor), precision=1e-9)


def test_missing_imagery_is_masked_in_the_image_cog_and_torchgeo_still_reads_it(tmp_path: Path) -> None:
    """A local GeoTIFF that covers only the west 3 of a sample's 5 tile columns, and a build that
    keeps such samples (``--max-missing-imagery 0.5``): images/NAME.tif marks the east 2 columns
    in its internal mask (rasterio's dataset_mask(), an independent reader), not only with black
    pixels; rio-cogeo validates it; torchgeo indexes and reads it, and the globbed ``geo/`` folder
    with the QGIS styles beside the rasters (torchgeo's default glob "*" sees them too)."""
    import mercantile
    from rasterio.transform import from_origin

    from osmseg.demo.render import render_aerial
    from osmseg.grid import sample_grid
    from osmseg.osm.features import read_features
    from osmseg.rasterize import rasterize

    tile = mercantile.tile(LON, LAT, 18)
    w, s, e, n = mercantile.bounds(tile)
    lon, lat = (w + e) / 2, (s + n) / 2  # a tile centre: the one sample's block is known
    grid = sample_grid(lon, lat, 18)
    labels = rasterize(read_features([TINYCITY], grid, TABLE), grid, TABLE)
    covered = 3 * 256  # columns with imagery
    rgb = render_aerial(labels, seed=5)[:, :covered].transpose(2, 0, 1)
    left, _, _, top = grid.xy_bounds
    source = tmp_path / "west.tif"
    with rasterio.open(source, "w", driver="GTiff", width=covered, height=SIDE, count=3, dtype="uint8",
                       crs="EPSG:3857", transform=from_origin(left, top, grid.pixel_size, grid.pixel_size)) as dst:
        dst.write(rgb)
    out = tmp_path / "ds"
    result = CliRunner().invoke(cli, [
        "-q", "build", "--lat", str(lat), "--lon", str(lon), "--radius-km", "0.001", "--samples", "1",
        "--seed", "1", "--image-format", "cog", "--imagery", f"geotiff:{source}", "--osm", str(TINYCITY),
        "--max-missing-imagery", "0.5", "--out", str(out), "--cache-dir", str(tmp_path / "cache")],
        catch_exceptions=False)
    assert result.exit_code == 0, result.output
    (sample,) = json.loads((out / "manifest.json").read_text())["samples"]
    assert sample["imagery"]["valid_fraction"] == pytest.approx(0.6, abs=0.005)
    path = out / "images" / f"{sample['name']}.tif"
    assert cog_validate(str(path))[0], cog_validate(str(path))
    with rasterio.open(path) as src:
        mask = src.dataset_mask()
        assert (mask[:, :covered - 1] == 255).all() and (mask[:, covered + 1:] == 0).all()
        assert np.array_equal(src.read(masked=True).mask.any(axis=0), mask == 0)
    images = AerialImages(out / "images")
    xmin, ymin, xmax, ymax = sample["bounds_3857"]
    got = images[xmin:xmax, ymin:ymax]["image"].numpy()
    assert got.shape == (3, SIDE, SIDE)
    assert np.array_equal(got[:, :, :covered - 1], read_cog(path)[:, :, :covered - 1])
    assert (got[:, :, covered + 1:] == 0).all()

    class AnyFile(RasterDataset):  # torchgeo's default filename_glob "*": the .qml files are globbed too
        is_image = False

    assert sorted(Path(p).name for p in AnyFile(out / "geo").index.filepath) == [f"{sample['name']}.tif"]
