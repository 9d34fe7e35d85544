"""Training recipes: what a run learns by, how it is recorded, how random crops are drawn.

The default (``osmseg``) and the dissertation's (``paper``) recipes through the real command
line on ``tests/data/tinyseg``; resuming a run made before recipes existed (its checkpoint has
the paper's settings and no ``recipe``); random crops drawn from (seed, epoch, index) only.
"""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result

torch = pytest.importorskip("torch")

from conftest import TEST_DATA  # noqa: E402

from osmseg.cli.main import cli  # noqa: E402
from osmseg.errors import ConfigError, DatasetError  # noqa: E402
from osmseg.images import read_label  # noqa: E402
from training.datasets.patches import discover  # noqa: E402
from training.datasets.sampling import CROPS_PER_IMAGE, RandomCrops  # noqa: E402
from training.models.checkpoint import load_checkpoint, save_checkpoint  # noqa: E402
from training.run.config import TrainConfig  # noqa: E402
from training.run.recipe import RECIPE_FIELDS  # noqa: E402

TINYSEG = TEST_DATA / "tinyseg"
TINY = TEST_DATA / "train" / "tiny.yaml"


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def osmseg(*args: object) -> Result:
    return CliRunner().invoke(cli, ["-q", *(str(a) for a in args)])


def optimizer_kind(state: dict) -> str:
    """What optimiser wrote this state dict: AdamW keeps two moments, SGD a momentum buffer."""
    keys = {k for s in state["state"].values() for k in s}
    return "adamw" if "exp_avg_sq" in keys else "sgd" if "momentum_buffer" in keys else "?"


def test_each_recipe_trains_by_its_own_settings_and_records_them(tmp_path: Path) -> None:
    for recipe, optimizer, batches in (("osmseg", "adamw", 7), ("paper", "sgd", None)):
        run = tmp_path / recipe
        result = osmseg("train", TINYSEG, "--out", run, "--config", TINY, "--epochs", 1, "--recipe", recipe)
        assert result.exit_code == 0, result.output
        last = load_checkpoint(run / "last.pt")
        assert last["config"]["recipe"] == recipe
        assert all(last["config"][k] is not None for k in RECIPE_FIELDS if k != "steps_per_epoch")
        assert optimizer_kind(last["optimizer"]) == optimizer
        steps = last["scheduler"]["last_epoch"]
        if batches is not None:  # tiny.yaml: 7 steps of random crops
            assert steps == batches
        else:  # the paper's grid: 4 patches of each training image, 4 a batch
            train = last["splits"]["train"]
            assert steps == -(-4 * len(train) // 4)
        weights = last["class_weights"]
        assert (weights is None) == (recipe == "osmseg")  # median-frequency weights are the paper's


def test_a_setting_on_the_command_line_overrides_the_recipe_and_nothing_else(tmp_path: Path) -> None:
    run = tmp_path / "run"
    result = osmseg("train", TINYSEG, "--out", run, "--config", TINY, "--epochs", 1, "--recipe", "paper",
                    "--lr", "0.02", "--class-weights", "sqrt-median-frequency")
    assert result.exit_code == 0, result.output
    config = load_checkpoint(run / "last.pt")["config"]
    assert (config["optimizer"], config["lr"], config["class_weights"], config["sampling"]) == \
        ("sgd", 0.02, "sqrt-median-frequency", "grid")
    weights = load_checkpoint(run / "last.pt")["class_weights"]
    mf = TrainConfig(dataset=TINYSEG, out_dir=run, recipe="paper")  # the same split, median-frequency
    assert mf.settings.class_weights == "median-frequency" and weights is not None
    present = weights[weights > 0]
    assert float(present.max() / present.min()) < 20  # square roots: the spread of the weights shrinks


def test_bad_recipe_settings_are_usage_errors(tmp_path: Path) -> None:
    result = osmseg("train", TINYSEG, "--out", tmp_path / "run", "--recipe", "fast")
    assert result.exit_code == 2 and "fast" in result.output
    bad = tmp_path / "bad.yaml"
    bad.write_text(TINY.read_text() + "optimizer: adam\n")
    result = osmseg("train", TINYSEG, "--out", tmp_path / "run", "--config", bad)
    assert result.exit_code == 2 and "optimizer must be one of adamw, sgd" in result.output
    assert not (tmp_path / "run").exists()
    with pytest.raises(ConfigError, match="warmup"):
        TrainConfig(dataset=TINYSEG, out_dir=tmp_path, warmup=1.5)


def test_a_run_from_before_recipes_resumes_by_the_paper_recipe_only(tmp_path: Path) -> None:
    """An osmseg 0.4 checkpoint has the paper's settings and no recipe: resuming it by the new
    default would change how it learns mid-run, so that is refused and the message names the way."""
    old = tmp_path / "old.yaml"  # tiny.yaml as 0.4 had it: no random-crop settings
    old.write_text("".join(line for line in TINY.open() if not line.startswith(("crop:", "steps_per_epoch:"))))
    run = tmp_path / "run"
    result = osmseg("train", TINYSEG, "--out", run, "--config", old, "--epochs", 1, "--recipe", "paper")
    assert result.exit_code == 0, result.output
    for name in ("last.pt", "best.pt"):  # what 0.4 wrote: no recipe, none of its new settings
        state = load_checkpoint(run / name)
        for key in ("recipe", "optimizer", "warmup", "sampling", "crop", "steps_per_epoch"):
            del state["config"][key]
        save_checkpoint(run / name, state)
    before = (run / "last.pt").read_bytes()
    refused = osmseg("train", TINYSEG, "--out", run, "--config", old, "--epochs", 1)
    assert refused.exit_code == 2 and "--recipe paper" in refused.output, refused.output
    assert (run / "last.pt").read_bytes() == before
    resumed = osmseg("train", TINYSEG, "--out", run, "--config", old, "--epochs", 1, "--recipe", "paper")
    assert resumed.exit_code == 0, resumed.output  # the same run: nothing left to do
    with (run / "log.csv").open(newline="") as f:
        assert [int(r["epoch"]) for r in csv.DictReader(f)] == [1]


def test_random_crops_depend_on_seed_epoch_and_index_only(tmp_path: Path) -> None:
    files = discover(TINYSEG)[:4]
    a = RandomCrops(files, 64, 16, seed=3, augment=True, cache_images=0)
    b = RandomCrops(list(reversed(files))[::-1], 64, 16, seed=3, augment=True, cache_images=8)
    for index in (0, 5, 15):  # another cache, another process, another order of asking: the same pair
        xa, ya = a[index]
        xb, yb = b[index]
        assert torch.equal(xa, xb) and torch.equal(ya, yb) and xa.shape == (3, 64, 64) and ya.shape == (64, 64)
    first = [a[i][1] for i in range(16)]
    a.set_epoch(1)
    assert not all(torch.equal(x, a[i][1]) for i, x in enumerate(first))  # a new epoch, new crops
    with pytest.raises(IndexError):
        a[16]


def test_a_random_crop_is_a_window_of_its_image_and_label(tmp_path: Path) -> None:
    """Without augmentation a crop is a window of one training image, and its label the same
    window of that image's label: every pixel where the annotator put it."""
    from numpy.lib.stride_tricks import sliding_window_view

    from osmseg.images import read_label, read_rgb

    files = discover(TINYSEG)
    crops = RandomCrops(files, 48, 4 * CROPS_PER_IMAGE, seed=0, augment=False, mean=(0, 0, 0), std=(1, 1, 1))
    pairs = [(read_rgb(f.image), read_label(f.label)) for f in files]
    chosen = set()
    for index in range(len(crops)):
        x, y = crops[index]
        image = (x.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
        found = []
        for i, (rgb, lab) in enumerate(pairs):
            corners = (sliding_window_view(rgb, (4, 4, 3))[..., 0, :, :, :] == image[:4, :4]).all(axis=(-3, -2, -1))
            for t, left in zip(*np.nonzero(corners)):
                if t + 48 <= rgb.shape[0] and left + 48 <= rgb.shape[1] and \
                        np.array_equal(rgb[t:t + 48, left:left + 48], image):
                    found.append(i)
                    assert np.array_equal(lab[t:t + 48, left:left + 48], y.numpy()), (index, i, t, left)
        assert found, f"crop {index} is not a window of any training image"
        chosen.add(found[0])
    assert len(chosen) > 1  # crops come from several images


def test_crops_larger_than_an_image_are_refused_in_one_line(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="smaller than the 256-px random crop; use a smaller --crop"):
        RandomCrops(discover(TINYSEG), 256, 8)
    data = Path(shutil.copytree(TINYSEG, tmp_path / "data", ignore=shutil.ignore_patterns("data.py")))
    result = osmseg("train", data, "--out", tmp_path / "run", "--config", TINY, "--crop", 256)
    assert result.exit_code == 1 and "use a smaller --crop" in result.output


def rare_class_dataset(root: Path) -> Path:
    """Two 256x256 samples of class 1, one holding a 6x6 block of class 2 (0.03 % of the
    pixels), its image red there and grey elsewhere."""
    from PIL import Image

    for name, rare in (("a", True), ("b", False)):
        label = np.ones((256, 256), np.uint8)
        if rare:
            label[150:156, 90:96] = 2
        rgb = np.where((label == 2)[..., None], np.array([255, 0, 0], np.uint8), np.array([128, 128, 128], np.uint8))
        for folder, array in (("images", rgb), ("labels", label)):
            (root / folder).mkdir(parents=True, exist_ok=True)
            Image.fromarray(array).save(root / folder / f"{name}.png")
    return root


def test_balanced_crops_centre_a_share_of_the_crops_on_a_rare_class(tmp_path: Path) -> None:
    """A class of 36 pixels in 131072 is in about one plain crop of sixteen; with every group
    of crops balanced, half are centred on it (two classes, drawn uniformly), and its label
    pixels still lie under its red image pixels after the crop is turned and mirrored."""
    files = discover(rare_class_dataset(tmp_path))
    counts = np.stack([np.bincount(read_label(f.label).ravel(), minlength=3)
                       for f in files])

    def holding_rare(balance: float) -> float:
        crops = RandomCrops(files, 64, 256, seed=1, augment=True, mean=(0, 0, 0), std=(1, 1, 1),
                            balance=balance, class_pixels=counts)
        held = 0
        for index in range(len(crops)):
            x, y = crops[index]
            red = x[0] - x[1] > 0.3  # red after any colour jitter; grey has R == G
            assert torch.equal(red, y == 2), index  # the label turned with its image
            held += bool((y == 2).any())
        return held / len(crops)

    plain, balanced = holding_rare(0.0), holding_rare(1.0)
    assert plain < 0.2 and balanced > 0.35, (plain, balanced)
    assert holding_rare(1.0) == balanced  # seeded: the same crops again


def test_the_network_is_chosen_recorded_and_rebuilt_from_the_checkpoint(tmp_path: Path) -> None:
    """--arch segnet (the dissertation's network) and the default segnet-skip: the checkpoint's
    spec says which, predict rebuilds that one, and a run resumes only as the network it is
    (a run from before --arch existed is a segnet, and the refusal says so)."""
    from training.models.checkpoint import model_from_checkpoint

    runs = {}
    for arch in ("segnet", "segnet-skip"):
        run = tmp_path / arch
        extra = ("--arch", arch) if arch == "segnet" else ()
        result = osmseg("train", TINYSEG, "--out", run, "--config", TINY, "--epochs", 1, *extra)
        assert result.exit_code == 0, result.output
        state = load_checkpoint(run / "best.pt")
        assert state["spec"]["arch"] == arch and state["config"]["arch"] == arch
        model, _ = model_from_checkpoint(run / "best.pt")
        assert model.skips == (arch == "segnet-skip")
        runs[arch] = run
    refused = osmseg("train", TINYSEG, "--out", runs["segnet"], "--config", TINY, "--epochs", 1)
    assert refused.exit_code == 2 and "--arch segnet" in refused.output, refused.output
    for name in ("last.pt", "best.pt"):  # as a run from before --arch wrote it
        state = load_checkpoint(runs["segnet"] / name)
        del state["config"]["arch"]
        save_checkpoint(runs["segnet"] / name, state)
    again = osmseg("train", TINYSEG, "--out", runs["segnet"], "--config", TINY, "--epochs", 1, "--arch", "segnet")
    assert again.exit_code == 0, again.output
    assert "holds a run with other settings" not in again.output  # resumed: nothing left to do


def test_validation_on_tiles_smaller_than_the_patch_runs_on_patches_the_size_of_the_tiles(tmp_path: Path) -> None:
    """256x256 tiles (XYZ, fAIr, SpaceNet chips) against the 360x480 validation patch: the run
    validates on 256x256 patches, every labelled pixel of the validation tile counted."""
    from PIL import Image

    from training.datasets.patches import fitted_patch

    rng = np.random.default_rng(0)
    for i in range(4):
        label = np.ones((256, 256), np.uint8)
        label[:, 128:] = 2
        rgb = np.where((label == 2)[..., None], 200, 40).astype(np.uint8) + rng.integers(0, 20, (256, 256, 3), np.uint8)
        for folder, array in (("images", rgb), ("labels", label)):
            (tmp_path / "data" / folder).mkdir(parents=True, exist_ok=True)
            Image.fromarray(array).save(tmp_path / "data" / folder / f"tile{i}.png")
    (tmp_path / "data" / "classes.toml").write_text(
        'name = "halves"\nunlabeled = { id = 0, name = "unlabeled", color = [0, 0, 0] }\n'
        '[[classes]]\nid = 1\nname = "dark"\ncolor = [40, 40, 40]\n'
        '[[classes]]\nid = 2\nname = "light"\ncolor = [200, 200, 200]\n', encoding="utf-8")
    assert fitted_patch((360, 480), discover(tmp_path / "data")) == (256, 256)
    result = osmseg("train", tmp_path / "data", "--out", tmp_path / "run", "--model", "tiny", "--width", 0.125,
                    "--crop", 64, "--batch-size", 2, "--steps-per-epoch", 2, "--epochs", 1, "--loader-workers", 0,
                    "--device", "cpu")
    assert result.exit_code == 0, result.output
    with (tmp_path / "run" / "log.csv").open(encoding="utf-8") as f:
        (row,) = list(csv.DictReader(f))
    assert 0.0 <= float(row["val_pixel_accuracy"]) <= 1.0 and row["val_miou"] != ""


def striped_dataset(root: Path) -> Path:
    """Two 256x256 samples of vertical stripes 16 px wide: class 1 grey, class 2 red."""
    from PIL import Image

    label = np.broadcast_to((1 + (np.arange(256) // 16) % 2).astype(np.uint8), (256, 256))
    rgb = np.where((label == 2)[..., None], np.array([255, 0, 0], np.uint8), np.array([128, 128, 128], np.uint8))
    for name in ("a", "b"):
        for folder, array in (("images", rgb), ("labels", label)):
            (root / folder).mkdir(parents=True, exist_ok=True)
            Image.fromarray(np.ascontiguousarray(array)).save(root / folder / f"{name}.png")
    return root


def test_zoomed_out_crops_see_more_ground_at_the_crop_size_with_labels_under_their_pixels(tmp_path: Path) -> None:
    """--crop-scale 2: a 64-px crop spans 64 to 128 image pixels, so it holds up to twice the
    stripes of a plain crop; it is still 64 px, and away from the stripes' edges (which the
    antialiased resampling blurs) red pixels are exactly those labelled red."""
    from training.datasets.augment import AugmentConfig

    files = discover(striped_dataset(tmp_path))

    def stripes(scale: float) -> list[float]:
        crops = RandomCrops(files, 64, 64, seed=5, augment=AugmentConfig.overhead(0.0, scale), mean=(0, 0, 0),
                            std=(1, 1, 1))
        widths = []
        for index in range(len(crops)):
            x, y = crops[index]
            assert x.shape == (3, 64, 64) and y.shape == (64, 64)
            lab = y.numpy()
            inner = np.ones_like(lab, bool)  # the label is the same two pixels away on every side
            for axis in (0, 1):
                for shift in (-2, -1, 1, 2):
                    inner &= np.roll(lab, shift, axis) == lab
            inner[:2], inner[-2:], inner[:, :2], inner[:, -2:] = False, False, False, False
            red = (x[0] - x[1] > 0.3).numpy()
            assert inner.sum() > 1000 and np.array_equal(red[inner], lab[inner] == 2), index
            changes = max(int((lab[:, 1:] != lab[:, :-1]).sum(axis=1).max()),
                          int((lab[1:] != lab[:-1]).sum(axis=0).max()))  # stripes turned or not
            widths.append(64 / (changes + 1))
        return widths

    plain, zoomed = stripes(1.0), stripes(2.0)
    assert min(plain) >= 12.8  # at most 5 stripes of 16 px in 64
    assert 8 <= np.mean(zoomed) < 0.85 * np.mean(plain) and min(zoomed) >= 6.4  # up to twice as many


def test_zoom_and_colour_jitter_are_recipe_settings_recorded_in_the_run(tmp_path: Path) -> None:
    run = tmp_path / "run"
    result = osmseg("train", TINYSEG, "--out", run, "--config", TINY, "--epochs", 1, "--crop-scale", 1.5,
                    "--jitter", 0)
    assert result.exit_code == 0, result.output
    config = load_checkpoint(run / "last.pt")["config"]
    assert (config["crop_scale"], config["jitter"], config["crop"]) == (1.5, 0.0, 64)
    refused = osmseg("train", TINYSEG, "--out", tmp_path / "paper", "--config", TINY, "--recipe", "paper",
                     "--crop-scale", 1.5)
    assert refused.exit_code == 2 and "crop_scale needs sampling random" in refused.output, refused.output
    assert not (tmp_path / "paper").exists()
