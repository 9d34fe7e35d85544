"""The parts of ``benchmarks/bench_real_heldout.py`` its figures rest on.

* The per-pixel baseline (``benchmarks/pixel_baseline.py``) learns what pixel colours can tell
  (two colours under noise: IoU near 1 on an image it did not see) and nothing more (roofs of
  the ground's own colours: no better than a guess); its scores are IoU and accuracy as
  counted by hand.
* The Kampala dataset builder (``benchmarks/kampala.py``, real data in ``../shared/data``;
  skipped without it) writes a CamVid folder the trainer reads, whose train/val and test
  mosaics come from disjoint tiles (west and east of the block, read back from each file's
  georeference), with ~0.075 m pixels in EPSG:3857 and building labels that match the
  footprints' area tile by tile (shapely) and sit on the roofs' edges.
"""

from __future__ import annotations

import doctest
import sys
from pathlib import Path

import mercantile
import numpy as np
import pytest
import rasterio
from conftest import REPO_ROOT, shared_path
from PIL import Image

sys.path.insert(0, str(REPO_ROOT / "benchmarks"))
pytest.importorskip("sklearn", reason="the pixel baseline needs scikit-learn (the bench extra)")

import kampala
import pixel_baseline
from pixel_baseline import building_scores, fit_baseline

ROOF, GROUND = (200, 90, 60), (80, 140, 70)


def scene(seed: int, roof: tuple[int, int, int] = ROOF, noise: float = 25.0) -> tuple[np.ndarray, np.ndarray]:
    """A 192x192 image of ground with 12 random rectangular roofs, Gaussian noise on every pixel."""
    rng = np.random.default_rng(seed)
    truth = np.zeros((192, 192), dtype=bool)
    for _ in range(12):
        top, left = rng.integers(0, 160, size=2)
        h, w = rng.integers(8, 32, size=2)
        truth[top:top + h, left:left + w] = True
    rgb = np.where(truth[:, :, None], np.array(roof, float), np.array(GROUND, float))
    rgb += rng.normal(0, noise, rgb.shape)
    return np.clip(rgb, 0, 255).astype(np.uint8), truth


def fitted(seeds: range, balanced: bool, roof: tuple[int, int, int] = ROOF) -> pixel_baseline.Fitted:
    scenes = [scene(s, roof) for s in seeds]
    return fit_baseline([s[0] for s in scenes], [s[1] for s in scenes], [np.ones_like(s[1]) for s in scenes],
                        samples=20_000, seed=0, balanced=balanced)


def test_scores_are_iou_and_accuracy_counted_by_hand() -> None:
    pred = np.array([[1, 1, 0, 0], [1, 0, 0, 0]], bool)
    truth = np.array([[1, 0, 0, 0], [1, 1, 0, 0]], bool)
    valid = np.array([[1, 1, 1, 1], [1, 1, 1, 0]], bool)
    # over the 7 valid pixels: both say building at 2, one says it at 2 more, 3 agree on ground
    assert building_scores(pred, truth, valid) == {"building_iou": 0.5, "pixel_accuracy": round(5 / 7, 4),
                                                   "pixels": 7}
    assert doctest.testmod(pixel_baseline).failed == 0


@pytest.mark.parametrize("balanced", [True, False])
def test_baseline_learns_two_colours_under_noise(balanced: bool) -> None:
    model = fitted(range(3), balanced)
    image, truth = scene(99)  # an image it has not seen
    scores = building_scores(model.predict(image), truth, np.ones_like(truth))
    assert scores["building_iou"] > 0.9, scores
    assert scores["pixel_accuracy"] > 0.97, scores


def test_baseline_cannot_see_roofs_of_the_grounds_colour() -> None:
    """Roofs drawn in the ground's colour: nothing in a pixel or its neighbourhood says where
    they are, so the balanced baseline does no better than a guess (and knows it cannot
    score the way it did on colours)."""
    model = fitted(range(3), balanced=True, roof=GROUND)
    image, truth = scene(99, roof=GROUND)
    scores = building_scores(model.predict(image), truth, np.ones_like(truth))
    guess = truth.mean()  # IoU of predicting building everywhere
    assert scores["building_iou"] < guess + 0.1, (scores, guess)
    assert scores["building_iou"] < 0.5


# -- the Kampala dataset (real data) ----------------------------------------------------------


@pytest.fixture(scope="module")
def kampala_dataset(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    shared = shared_path("kampala-oam").parent
    out = tmp_path_factory.mktemp("kampala") / "kampala-z21"
    return out, kampala.build_kampala(shared, out, seed=0)


def tiles_of(path: Path) -> set[tuple[int, int]]:
    """The z21 tiles an image covers, read from its own georeference (a tile per 256 px block)."""
    with rasterio.open(path) as ds:
        assert ds.crs.to_epsg() == 3857
        found = set()
        for row in range(128, ds.height, 256):
            for col in range(128, ds.width, 256):
                lon, lat = mercantile.lnglat(*(ds.transform * (col, row)))
                tile = mercantile.tile(lon, lat, kampala.ZOOM)
                found.add((tile.x, tile.y))
    return found


def test_kampala_splits_are_disjoint_west_and_east(kampala_dataset: tuple[Path, dict]) -> None:
    from training.datasets.patches import discover_camvid

    root, _ = kampala_dataset
    splits = discover_camvid(root)  # as the trainer reads the folder
    assert {s: len(f) for s, f in splits.items()} == {"train": 4, "val": 1, "test": 2}
    tiles = {s: [tiles_of(f.image) for f in files] for s, files in splits.items()}
    every = [t for per_split in tiles.values() for per_image in per_split for t in per_image]
    assert len(every) == len(set(every)) == 12 * 8 + 4 * 4  # both blocks, no tile twice
    west = {t for s in ("train", "val") for per_image in tiles[s] for t in per_image}
    east = {t for per_image in tiles["test"] for t in per_image}
    assert max(x for x, _ in west) < min(x for x, _ in east)
    assert len(west) == 7 * 8 + 4 * 4 and len(east) == 5 * 8


def test_the_ceiling_dataset_trains_on_the_test_mosaics_too(tmp_path: Path,
                                                            kampala_dataset: tuple[Path, dict]) -> None:
    """--fit-test: every test mosaic is also in train/ (same pixels, same labels, same place), the
    held-out dataset's splits otherwise unchanged."""
    from training.datasets.patches import discover_camvid

    root, _ = kampala_dataset
    fitted = tmp_path / "fit"
    kampala.build_kampala(shared_path("kampala-oam").parent, fitted, seed=0, fit_test=True)
    splits = discover_camvid(fitted)
    assert {s: len(f) for s, f in splits.items()} == {"train": 6, "val": 1, "test": 2}
    for test in discover_camvid(root)["test"]:
        copy = fitted / "train" / f"fit-{test.image.name}"
        for a, b in ((test.image, copy), (test.label, fitted / "trainannot" / copy.name)):
            with rasterio.open(a) as x, rasterio.open(b) as y:
                assert x.transform == y.transform and np.array_equal(x.read(), y.read())
    held_out = {f.image.name for f in discover_camvid(root)["train"]}
    assert held_out < {f.image.name for f in splits["train"]}


def test_kampala_pixels_are_about_75_mm_on_the_ground(kampala_dataset: tuple[Path, dict]) -> None:
    from osmseg.grid import ground_pixel_size
    from training.datasets.patches import dataset_resolution, discover_camvid

    root, _ = kampala_dataset
    for image in sorted(root.glob("*/*.tif")):
        with rasterio.open(image) as ds:
            assert ds.res == pytest.approx((0.0746, 0.0746), abs=1e-4)  # Web Mercator metres at z21
            ground = ground_pixel_size(ds.crs, ds.transform, ds.width, ds.height)
            assert ground is not None and 0.07 < ground < 0.08
    assert dataset_resolution(root, discover_camvid(root)["train"]) == pytest.approx(0.0744, abs=5e-4)


def test_kampala_labels_match_the_footprints_and_roofs(kampala_dataset: tuple[Path, dict]) -> None:
    from shapely.geometry import box

    from osmseg.quality import edge_alignment

    root, summary = kampala_dataset
    polygons = kampala.footprints_3857(shared_path("kampala-oam", "osm-buildings.geojson"))
    compared = 0
    for mosaic in summary["mosaics"]:
        labels = np.asarray(Image.open(root / f"{mosaic['split']}annot" / f"{mosaic['name']}.tif"))  # PIL, not rasterio
        labelled = labels != kampala.UNLABELED
        share = (labels == kampala.BUILDING).sum() / labelled.sum()
        assert 0.1 < share < 0.65, (mosaic["name"], share)  # a built-up town, not empty, not all roof
        assert labelled.mean() > 0.95
        with rasterio.open(root / mosaic["split"] / f"{mosaic['name']}.tif") as ds:
            rgb, transform = ds.read().transpose(1, 2, 0), ds.transform
        # each tile: footprint area (shapely) = building pixels, but for the unlabeled (transparent) pixels
        for row in range(0, labels.shape[0], 256):
            for col in range(0, labels.shape[1], 256):
                block = labels[row:row + 256, col:col + 256]
                holes = int((block == kampala.UNLABELED).sum())
                x0, y0 = transform * (col, row)
                x1, y1 = transform * (col + 256, row + 256)
                tile = box(min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1))
                area_px = sum(p.intersection(tile).area for p in polygons) / abs(transform.a * transform.e)
                error = abs((block == kampala.BUILDING).sum() - area_px)
                assert error <= 0.02 * area_px + 60 + holes, (mosaic["name"], row, col, area_px, holes)
                compared += 1
        fit = edge_alignment(rgb, labels == kampala.BUILDING)
        assert max(abs(fit.best[0]), abs(fit.best[1])) <= 3 and fit.at_zero > 1.2 * fit.far, (mosaic["name"], fit)
    assert compared == 12 * 8 + 4 * 4
