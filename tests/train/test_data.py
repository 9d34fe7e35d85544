"""training.datasets.patches / training.datasets.augment: pairing, checks, patches, splits, augmentation, weights."""

from __future__ import annotations

import itertools
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import TEST_DATA
from PIL import Image

from osmseg.classes import ClassTable
from osmseg.errors import DatasetError
from osmseg.images import read_label, read_rgb
from training.datasets.augment import GEOMETRIC, OVERHEAD, STREET, Draw, orient
from training.datasets.patches import (
    PatchDataset,
    SampleFiles,
    dataset_class_table,
    discover,
    discover_camvid,
    discover_dataset,
    files_by_name,
    median_frequency_weights,
    patch_boxes,
    validate,
    weights_from_histograms,
)
from training.datasets.splits import make_splits, read_splits, write_splits

torch.set_num_threads(1)
TINY = TEST_DATA / "tinyseg"
MEAN, STD = (0.4, 0.5, 0.6), (0.2, 0.25, 0.3)
PALETTE = np.array([[0, 0, 0], [250, 30, 30], [30, 250, 30], [30, 30, 250], [240, 240, 40]], dtype=np.uint8)


def one_line(exc: pytest.ExceptionInfo) -> str:
    message = str(exc.value)
    assert "\n" not in message and message
    return message


def write_pair(root: Path, name: str, label: np.ndarray, image: np.ndarray | None = None) -> SampleFiles:
    """Write images/NAME.png (class colours of ``label`` unless ``image`` is given) and labels/NAME.png."""
    (root / "images").mkdir(parents=True, exist_ok=True)
    (root / "labels").mkdir(parents=True, exist_ok=True)
    rgb = PALETTE[label % len(PALETTE)] if image is None else image
    Image.fromarray(rgb, "RGB").save(root / "images" / f"{name}.png")
    Image.fromarray(label.astype(np.uint8), "L").save(root / "labels" / f"{name}.png")
    return SampleFiles(name, root / "images" / f"{name}.png", root / "labels" / f"{name}.png")


def unnormalise(x: torch.Tensor) -> np.ndarray:
    """(3, H, W) normalised tensor -> (H, W, 3) uint8 image."""
    rgb = x * torch.tensor(STD)[:, None, None] + torch.tensor(MEAN)[:, None, None]
    return (rgb * 255).round().clamp(0, 255).to(torch.uint8).permute(1, 2, 0).numpy()


def decode_classes(rgb: np.ndarray) -> np.ndarray:
    """Class of each pixel from its colour: the nearest palette entry."""
    dist = ((rgb[:, :, None, :].astype(np.int32) - PALETTE[None, None].astype(np.int32)) ** 2).sum(-1)
    return dist.argmin(-1)


# ------------------------------------------------------------------------------- patches
def test_patch_boxes_of_a_sample_are_six_disjoint_patches_inside_it() -> None:
    boxes = patch_boxes(1280, 1280)
    assert len(boxes) == 6
    cover = np.zeros((1280, 1280), dtype=int)
    for top, left in boxes:
        assert 0 <= top and top + 360 <= 1280 and 0 <= left and left + 480 <= 1280
        cover[top:top + 360, left:left + 480] += 1
    assert cover.max() == 1 and cover.sum() == 6 * 360 * 480
    rows, cols = np.nonzero(cover)
    assert (rows.min(), 1279 - rows.max(), cols.min(), 1279 - cols.max()) == (100, 100, 160, 160)  # centred


def test_patch_boxes_of_too_small_image_is_a_one_line_error() -> None:
    with pytest.raises(DatasetError) as exc:
        patch_boxes(300, 1280)
    assert "smaller than the 480x360 patch" in one_line(exc)
    assert patch_boxes(64, 80, (64, 80)) == [(0, 0)]


# ------------------------------------------------------------------------------ discover
def test_discover_pairs_tinyseg_by_name() -> None:
    files = discover(TINY)
    assert [f.name for f in files] == [f"tinyseg_{i:03d}" for i in range(12)]
    assert all(f.image.parent.name == "images" and f.label.parent.name == "labels" for f in files)
    assert all(f.image.stem == f.label.stem == f.name for f in files)


def test_discover_errors_are_one_line_and_name_the_problem(tmp_path: Path) -> None:
    with pytest.raises(DatasetError) as exc:
        discover(tmp_path / "nowhere")
    assert "no such dataset folder" in one_line(exc)
    (tmp_path / "images").mkdir()
    with pytest.raises(DatasetError) as exc:
        discover(tmp_path)
    assert "no labels/ folder" in one_line(exc)
    label = np.zeros((8, 8), dtype=np.uint8)
    for name in ("a", "b", "c", "d", "e"):
        write_pair(tmp_path, name, label)
    for name in ("b", "c", "d", "e"):
        (tmp_path / "labels" / f"{name}.png").unlink()
    with pytest.raises(DatasetError) as exc:
        discover(tmp_path)
    assert "no label for 4 images: b, c, d and 1 more" in one_line(exc)
    for name in ("b", "c", "d", "e"):
        (tmp_path / "images" / f"{name}.png").unlink()
    (tmp_path / "images" / ".a.png.x1.tmp").write_bytes(b"half-written")  # hidden temp files are ignored
    (tmp_path / "labels" / "orphan.png").write_bytes((tmp_path / "labels" / "a.png").read_bytes())
    assert [f.name for f in discover(tmp_path)] == ["a"]
    (tmp_path / "images" / "z.png").write_bytes(b"not a png at all")
    (tmp_path / "labels" / "z.png").write_bytes((tmp_path / "labels" / "a.png").read_bytes())
    with pytest.raises(DatasetError) as exc:
        discover(tmp_path)
    assert "z.png: cannot read this image" in one_line(exc)
    (tmp_path / "images" / "z.png").unlink()
    shutil.copy(tmp_path / "images" / "a.png", tmp_path / "images" / "a.jpg")
    with pytest.raises(DatasetError) as exc:
        discover(tmp_path)
    assert "two files for sample 'a'" in one_line(exc)


def test_size_mismatch_is_a_one_line_error_naming_file_and_sizes(tmp_path: Path) -> None:
    f = write_pair(tmp_path, "a", np.zeros((8, 8), dtype=np.uint8))
    Image.fromarray(np.zeros((6, 10), dtype=np.uint8), "L").save(f.label)
    for call in (lambda: validate([f], 5), lambda: PatchDataset([f], None)):
        with pytest.raises(DatasetError) as exc:
            call()
        message = one_line(exc)
        assert str(f.label) in message and "10x6" in message and "8x8" in message


def test_unknown_class_ids_are_a_one_line_error_naming_file_and_ids(tmp_path: Path) -> None:
    label = np.ones((8, 8), dtype=np.uint8)
    label[0, :3] = [9, 7, 9]
    good = write_pair(tmp_path, "good", np.ones((8, 8), dtype=np.uint8))
    bad = write_pair(tmp_path, "bad", label)
    with pytest.raises(DatasetError) as exc:
        validate([good, bad], 5)
    message = one_line(exc)
    assert str(bad.label) in message and "class ids 7, 9 " in message
    ds = PatchDataset([good, bad], (4, 4), num_classes=5)
    assert ds[0][1].max() == 1  # the good file loads: the check is per file, when first decoded
    with pytest.raises(DatasetError) as exc:
        ds[4]
    assert str(bad.label) in one_line(exc)
    assert validate([good, bad], 10)[1].tolist() == [0, 61, 0, 0, 0, 0, 0, 1, 0, 2]  # histograms


def test_colour_mask_given_as_label_is_refused(tmp_path: Path) -> None:
    f = write_pair(tmp_path, "a", np.zeros((8, 8), dtype=np.uint8))
    Image.fromarray(PALETTE[np.zeros((8, 8), dtype=int)], "RGB").save(f.label)
    with pytest.raises(DatasetError) as exc:
        read_label(f.label)
    assert "single-band" in one_line(exc)


def test_camvid_layout_loads_with_its_given_splits(tmp_path: Path) -> None:
    files = discover(TINY)
    for split, chosen in (("train", files[:5]), ("val", files[5:7]), ("test", files[7:])):
        (tmp_path / split).mkdir()
        (tmp_path / f"{split}annot").mkdir()
        for f in chosen:
            shutil.copy(f.image, tmp_path / split / f.image.name)
            shutil.copy(f.label, tmp_path / f"{split}annot" / f.label.name)
    splits = discover_camvid(tmp_path)
    assert {k: len(v) for k, v in splits.items()} == {"train": 5, "val": 2, "test": 5}
    assert splits["val"][0].label == tmp_path / "valannot" / "tinyseg_005.png"
    all_files, given = discover_dataset(tmp_path)
    assert len(all_files) == 12 and given is not None and given["val"] == ["tinyseg_005", "tinyseg_006"]
    assert discover_dataset(TINY)[1] is None
    shutil.rmtree(tmp_path / "trainannot")
    with pytest.raises(DatasetError) as exc:
        discover_camvid(tmp_path)
    assert "no trainannot/ folder" in one_line(exc)


# --------------------------------------------------------------------------- class table
def test_class_table_from_manifest_toml_or_error(tmp_path: Path) -> None:
    table = dataset_class_table(TINY)
    assert table.name == "tinyseg" and table.num_classes == 5
    assert table.by_name["water"].color == (119, 242, 242) and table.unlabeled.name == "unlabeled"
    assert ClassTable.from_dict(table.to_dict()).to_dict() == table.to_dict()
    assert dataset_class_table(TINY, "classes6.toml").num_classes == 7
    with pytest.raises(DatasetError) as exc:
        dataset_class_table(tmp_path)
    assert "--classes" in one_line(exc)
    (tmp_path / "classes.toml").write_text(
        'name = "two"\nunlabeled = { id = 0, name = "unlabeled", color = [0, 0, 0] }\n'
        '[[classes]]\nid = 1\nname = "building"\ncolor = [255, 0, 0]\n')
    assert [c.name for c in dataset_class_table(tmp_path).classes] == ["building"]
    manifest = json.loads((TINY / "manifest.json").read_text())
    manifest["classes"] = {"classes": [{"id": 1, "name": "x", "color": [1, 2, 3]}]}
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DatasetError) as exc:
        dataset_class_table(tmp_path)
    assert "with the unlabeled id (0)" in one_line(exc)


# -------------------------------------------------------------------------------- splits
NAMES = [f"img_{i:03d}" for i in range(30)]


def test_splits_are_by_image_two_thirds_one_third_and_seeded() -> None:
    s = make_splits(NAMES, seed=7)
    assert {k: len(v) for k, v in s.items()} == {"train": 17, "val": 3, "test": 10}
    assert sorted(itertools.chain(*s.values())) == NAMES  # every image exactly once
    assert make_splits(list(reversed(NAMES)), seed=7) == s  # listing order does not matter
    rng = np.random.default_rng(1)
    assert make_splits(list(rng.permutation(NAMES)), seed=7) == s
    assert make_splits(NAMES, seed=8)["test"] != s["test"]
    small = make_splits(["a", "b", "c", "d"], seed=0)  # the demo: 4 images
    assert [len(small[k]) for k in ("train", "val", "test")] == [2, 1, 1]
    with pytest.raises(DatasetError):
        make_splits(["a", "a", "b"], seed=0)


def test_splits_file_round_trip_and_errors(tmp_path: Path) -> None:
    s = make_splits(NAMES, seed=3)
    path = write_splits(tmp_path / "splits.json", s, seed=3)
    assert read_splits(path) == s
    assert [f.name for f in files_by_name(discover(TINY), ["tinyseg_003", "tinyseg_001"])] == ["tinyseg_003", "tinyseg_001"]
    with pytest.raises(DatasetError) as exc:
        files_by_name(discover(TINY), ["nope"])
    assert "'nope'" in one_line(exc)
    path.write_text('{"splits": {"train": ["a", "b"], "test": ["b"]}}')
    with pytest.raises(DatasetError) as exc:
        read_splits(path)
    assert "'b' is in both train and test" in one_line(exc)
    path.write_text("{not json")
    with pytest.raises(DatasetError) as exc:
        read_splits(path)
    assert "delete it" in one_line(exc)


# --------------------------------------------------------------------------------- items
def test_items_have_the_right_types_shapes_and_normalisation() -> None:
    files = discover(TINY)
    ds = PatchDataset(files, (64, 80), MEAN, STD, augment=False, num_classes=5)
    assert len(ds) == 48  # 12 images x 2x2 patches
    x, y = ds[5]  # second image, top-right patch
    assert x.dtype == torch.float32 and x.shape == (3, 64, 80)
    assert y.dtype == torch.int64 and y.shape == (64, 80)
    image, label = read_rgb(files[1].image), read_label(files[1].label)
    assert np.array_equal(unnormalise(x), image[:64, 80:])
    assert torch.equal(y, torch.from_numpy(label[:64, 80:].astype(np.int64)))
    assert abs(float(x.mean())) < 3 and set(y.unique().tolist()) <= {0, 1, 2, 3, 4}
    whole = PatchDataset(files, None, MEAN, STD)
    assert len(whole) == 12 and whole[0][0].shape == (3, 128, 160)


def test_decoded_images_are_cached_per_file_with_a_bound() -> None:
    ds = PatchDataset(discover(TINY)[:3], (64, 80), cache_images=2)
    assert ds.load(0)[0] is ds.load(0)[0]  # the four patches of an image share one decode
    ds.load(1)
    ds.load(2)
    assert list(ds._cache) == [1, 2]  # least recently used evicted
    with pytest.raises(ValueError):
        ds.load(1)[0][0, 0, 0] = 1  # cached arrays are read-only


def test_label_lut_maps_ids_after_checking_them() -> None:
    lut = np.zeros(256, dtype=np.uint8)
    lut[[1, 2]] = 1  # building + highway -> 1, everything else -> 0
    ds = PatchDataset(discover(TINY)[:1], None, num_classes=5, label_lut=lut)
    raw = read_label(discover(TINY)[0].label)
    assert torch.equal(ds[0][1], torch.from_numpy(np.isin(raw, [1, 2]).astype(np.int64)))


# --------------------------------------------------------------------------- augmentation
@pytest.fixture
def coded(tmp_path: Path) -> list[SampleFiles]:
    """Two square 96x96 images of random class ids, each pixel painted in its class's colour,
    and one non-square 64x96 image."""
    rng = np.random.default_rng(5)
    return [write_pair(tmp_path, "sq0", rng.integers(0, 5, (96, 96)).astype(np.uint8)),
            write_pair(tmp_path, "sq1", rng.integers(0, 5, (96, 96)).astype(np.uint8)),
            write_pair(tmp_path, "wide", rng.integers(0, 5, (64, 96)).astype(np.uint8))]


DIHEDRAL = [Draw(k=k, hflip=h) for k in range(4) for h in (False, True)]


def test_augmentation_keeps_image_and_mask_aligned(coded: list[SampleFiles]) -> None:
    ds = PatchDataset(coded, (32, 48), MEAN, STD, augment=GEOMETRIC, seed=11)
    assert len(ds) == 6 + 6 + 4
    labels = [read_label(f.label) for f in coded]
    used: set[int] = set()
    for epoch in range(4):
        ds.set_epoch(epoch)
        for i in range(len(ds)):
            x, y = ds[i]
            assert np.array_equal(decode_classes(unnormalise(x)), y.numpy())  # colour still encodes the class
            fi, (top, left, h, w) = ds.items[i]
            matches = [j for j, d in enumerate(DIHEDRAL)
                       if np.array_equal(orient(labels[fi], d)[top:top + h, left:left + w], y.numpy())]
            assert len(matches) == 1  # exactly one symmetry of the whole image, then the patch
            if coded[fi].name == "wide":
                assert DIHEDRAL[matches[0]].k in (0, 2)  # no quarter turns of a non-square image
            used.add(matches[0])
    assert used == set(range(8))  # all eight symmetries occur


def test_augmentation_is_a_function_of_seed_epoch_and_index(coded: list[SampleFiles]) -> None:
    def items(seed: int, epoch: int) -> list[torch.Tensor]:
        ds = PatchDataset(coded, (32, 48), MEAN, STD, augment=True, seed=seed)
        ds.set_epoch(epoch)
        return [ds[i][0] for i in range(len(ds))]

    first = items(3, 1)
    assert all(torch.equal(a, b) for a, b in zip(first, items(3, 1)))  # a fresh dataset draws the same
    assert any(not torch.equal(a, b) for a, b in zip(first, items(3, 2)))  # another epoch differs
    assert any(not torch.equal(a, b) for a, b in zip(first, items(4, 1)))  # another seed differs
    plain = PatchDataset(coded, (32, 48), MEAN, STD, augment=False)
    plain.set_epoch(1)
    assert [torch.equal(a, plain[i][0]) for i, a in enumerate(items(3, 1))].count(True) < len(first)


def test_colour_jitter_is_mild_and_leaves_the_mask_alone(coded: list[SampleFiles]) -> None:
    jittered = PatchDataset(coded, (32, 48), MEAN, STD, augment=OVERHEAD, seed=2)
    geometric = PatchDataset(coded, (32, 48), MEAN, STD, augment=GEOMETRIC, seed=2)
    changed = 0
    for i in range(len(jittered)):
        (xj, yj), (xg, yg) = jittered[i], geometric[i]
        assert torch.equal(yj, yg)  # same geometry drawn, mask untouched by colour
        diff = np.abs(unnormalise(xj).astype(int) - unnormalise(xg).astype(int))
        changed += int(diff.max() > 0)
        assert diff.mean() < 0.12 * 255
        assert np.array_equal(decode_classes(unnormalise(xj)), yj.numpy())
    assert changed == len(jittered)


def test_street_augmentation_never_turns_or_flips_upside_down(coded: list[SampleFiles]) -> None:
    ds = PatchDataset(coded[:1], None, MEAN, STD, augment=STREET, seed=0)
    label = read_label(coded[0].label)
    seen = set()
    for epoch in range(12):
        ds.set_epoch(epoch)
        y = ds[0][1].numpy()
        seen.add(next(j for j, d in enumerate(DIHEDRAL) if np.array_equal(orient(label, d), y)))
    assert seen == {0, 1}  # identity and left-right mirror only


def test_augmentation_does_not_depend_on_workers(coded: list[SampleFiles]) -> None:
    ds = PatchDataset(coded, (32, 48), MEAN, STD, augment=True, seed=9)
    loader = torch.utils.data.DataLoader(ds, batch_size=4, num_workers=2, persistent_workers=True)
    for epoch in (0, 1):
        ds.set_epoch(epoch)  # must reach the persistent workers too
        batched = torch.cat([x for x, _ in loader])
        direct = torch.stack([ds[i][0] for i in range(len(ds))])
        assert torch.equal(batched, direct), f"epoch {epoch}"


# -------------------------------------------------------------------------------- weights
def test_median_frequency_weights_by_hand() -> None:
    a = np.array([[1, 1], [1, 2]])
    b = np.array([[2, 2], [0, 0]])
    # ignoring 0: freq(1) = 3/4, freq(2) = (1+2)/(4+2) = 1/2, median 5/8; class 3 absent -> 0
    w = median_frequency_weights([a, b], 4, ignore_index=0)
    assert w.dtype == torch.float32
    assert np.allclose(w.numpy(), [0, 5 / 6, 5 / 4, 0])
    # 0 as a class: freq(0) = 2/4, freq(1) = 3/4, freq(2) = 3/8, median 1/2
    assert np.allclose(median_frequency_weights([a, b], 4, ignore_index=None).numpy(), [1, 2 / 3, 4 / 3, 0])
    hist = validate(discover(TINY), 5)
    assert torch.equal(weights_from_histograms(hist, 0),
                       median_frequency_weights((read_label(f.label) for f in discover(TINY)), 5, 0))
    with pytest.raises(DatasetError):
        median_frequency_weights([np.zeros((2, 2), dtype=np.uint8)], 3, ignore_index=0)


# ------------------------------------------------------------------------ osmseg demo output
@pytest.fixture(scope="module")
def demo_dataset(demo_run: Path) -> Path:
    """The dataset ``osmseg demo`` builds (conftest's ``demo_run``, made once for the session)."""
    return demo_run / "demo" / "dataset"


def test_osmseg_demo_output_loads(demo_dataset: Path) -> None:
    files, given = discover_dataset(demo_dataset)
    assert len(files) == 4 and given is None
    table = dataset_class_table(demo_dataset)
    assert table.num_classes == 14 and table.by_name["building"].id == 1
    hist = validate(files, table.num_classes)
    assert hist.sum() == 4 * 1280 * 1280
    ds = PatchDataset(files, (360, 480), augment=True, num_classes=table.num_classes, cache_images=1)
    assert len(ds) == 24
    x, y = ds[23]
    assert x.shape == (3, 360, 480) and y.shape == (360, 480) and int(y.max()) < 14
    weights = median_frequency_weights((read_label(f.label) for f in files), table.num_classes, 0)
    assert weights[0] == 0 and (weights[hist.sum(0) > 0][1:] > 0).all()


def test_real_geotiff_image_and_foreign_mask_read() -> None:
    from conftest import shared_path

    folder = shared_path("inria-austin")
    image, label = read_rgb(folder / "image.tif"), read_label(folder / "buildings.tif")
    assert image.shape == (1000, 1000, 3) and image.dtype == np.uint8 and image.std() > 10
    assert label.shape == (1000, 1000) and set(np.unique(label).tolist()) == {0, 255}
    files = [SampleFiles("austin", folder / "image.tif", folder / "buildings.tif")]
    lut = np.zeros(256, dtype=np.uint8)
    lut[255] = 1  # Inria's building mask -> class 1
    ds = PatchDataset(files, (360, 480), label_lut=lut)
    assert len(ds) == 2 * 2 and set(ds[0][1].unique().tolist()) <= {0, 1}
