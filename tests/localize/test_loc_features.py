"""Landmark features from a SegNet encoder (localization.paper.features) and ``osmseg localize --feature-threshold``.

The network is a real SegNet at width 1/16, randomly initialised with a fixed seed and saved
as a real checkpoint: its features mean nothing, but they are deterministic and exactly
translation-equivariant in the interior of an image, which is all the tests need. The
deepest stage's cells are 32 px and see 212 px (VGG16's receptive field at pool5), so two
identical patches on a plain background, aligned to the 32 px grid and at least ~110 px from
the image edges and from anything else, must get *exactly* the same feature vector.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from localization.cli.localize import localize_command
from localization.common.landmarks import Landmarks, landmarks_from_mask, load_landmark_classes
from localization.paper.features import FeatureEdges, dropped_edges, landmark_features
from localization.paper.graph import cliques_fast
from localization.paper.match import class_adjacency
from osmseg.errors import ConfigError

CLASSES = ("building", "road")
BUILDING, HIGHWAY = 1, 2  # ids in classes6.toml (the airsegnet6 checkpoint's table)
# three patches on a grey 640x320 image: two identical (A, B) and one different (C)
CENTRES = {"A": (160, 160), "B": (480, 160), "C": (320, 160)}
W, H = 640, 320


@pytest.fixture(scope="module")
def net(tmp_path_factory):
    """(model, spec, checkpoint path) of a tiny random SegNet, seed 0."""
    torch = pytest.importorskip("torch")
    from training.models.checkpoint import save_checkpoint
    from training.models.networks import build_model, model_spec

    torch.manual_seed(0)
    spec = model_spec("airsegnet6", 0.0625, input_size=(64, 96))
    model = build_model(spec).eval()
    path = tmp_path_factory.mktemp("net") / "model.pt"
    save_checkpoint(path, {"spec": spec, "model": model.state_dict()})
    return model, spec, path


def manual_encoding(model, spec, image: np.ndarray) -> np.ndarray:
    """The encoder's output ``(C, h, w)`` for an image whose sides are multiples of 32, normalised by hand."""
    import torch

    x = torch.from_numpy(image).permute(2, 0, 1)[None].float() / 255.0
    x = (x - torch.tensor(spec.mean).view(1, 3, 1, 1)) / torch.tensor(spec.std).view(1, 3, 1, 1)
    with torch.no_grad():
        return model.encoder(x)[0][0].double().numpy()


def patches_image() -> np.ndarray:
    rng = np.random.default_rng(0)
    image = np.full((H, W, 3), 120, np.uint8)
    same, other = rng.integers(0, 255, (2, 32, 32, 3), dtype=np.uint8)
    for name, (x, y) in CENTRES.items():
        image[y - 16:y + 16, x - 16:x + 16] = other if name == "C" else same
    return image


def patch_landmarks() -> Landmarks:
    xy = np.array([CENTRES[n] for n in "ABC"], dtype=float) - 0.5  # the centroids of the 32x32 patches
    return Landmarks(xy, np.array([0, 0, 1]), CLASSES, W, H)


# --------------------------------------------------------------------------- the features


def test_features_are_the_encoder_output_sampled_at_the_landmarks(net) -> None:
    model, spec, path = net
    image = np.random.default_rng(1).integers(0, 255, (96, 128, 3), dtype=np.uint8)  # 3x4 cells of 32 px
    cells = manual_encoding(model, spec, image)
    xy = np.array([[47.5, 15.5],    # centre of cell (row 0, col 1)
                   [31.5, 79.5],    # halfway between the centres of cells (2, 0) and (2, 1)
                   [0.0, 0.0],      # before the first cell centre: the corner cell's value
                   [127.0, 50.0]])  # y between rows 1 (47.5) and 2 (79.5) by 2.5/32, x past the last centre
    features = landmark_features(image, Landmarks(xy, np.zeros(4, int), CLASSES, 128, 96), path)
    assert features.shape == (4, spec.width * 512)
    np.testing.assert_allclose(features[0], cells[:, 0, 1], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(features[1], (cells[:, 2, 0] + cells[:, 2, 1]) / 2, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(features[2], cells[:, 0, 0], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(features[3], cells[:, 1, 3] * (29.5 / 32) + cells[:, 2, 3] * (2.5 / 32),
                               rtol=1e-5, atol=1e-6)
    # a component landmark: the mean over its pixels' cells, 3 pixels in cell (0, 0) and 1 in (1, 2)
    pixels = (np.array([[0, 0], [31, 31], [5, 9], [64, 32]]),)
    comp = Landmarks(np.array([[25.0, 18.0]]), [0], CLASSES, 128, 96, pixels=pixels)
    np.testing.assert_allclose(landmark_features(image, comp, (model, spec))[0],
                               (3 * cells[:, 0, 0] + cells[:, 1, 2]) / 4, rtol=1e-5, atol=1e-6)
    # a chosen stage: stage 3 has 16 channels (256 / 16) in cells of 8 px
    assert landmark_features(image, Landmarks(xy, np.zeros(4, int), CLASSES, 128, 96), path, stage=3).shape == (4, 16)


def test_an_image_of_any_size_is_resized_and_its_coordinates_scaled(net) -> None:
    model, spec, _ = net
    image = np.random.default_rng(2).integers(0, 255, (70, 100, 3), dtype=np.uint8)  # -> 96x64 (3x2 cells)
    xy = np.array([[10.0, 20.0], [60.0, 35.0], [99.0, 69.0]])
    got = landmark_features(image, Landmarks(xy, np.zeros(3, int), CLASSES, 100, 70), (model, spec))
    resized = np.asarray(Image.fromarray(image).resize((96, 64), Image.Resampling.BILINEAR))
    scaled = (xy + 0.5) * [96 / 100, 64 / 70] - 0.5  # the same points, pixel centres kept
    want = landmark_features(resized, Landmarks(scaled, np.zeros(3, int), CLASSES, 96, 64), (model, spec))
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
    assert not np.allclose(got[0], got[1])


def test_identical_patches_have_equal_features_and_lose_their_edge(net) -> None:
    model, spec, path = net
    lm = patch_landmarks()
    features = landmark_features(patches_image(), lm, path)
    a, b, c = features
    assert np.linalg.norm(a) > 0.1
    assert np.linalg.norm(a - b) <= 1e-6 * np.linalg.norm(a)  # identical surroundings: equal features
    assert np.linalg.norm(a - c) > 0.1 * np.linalg.norm(a)    # another patch: another feature
    for edges in (FeatureEdges(0.5), FeatureEdges(0.002, metric="cosine", reduce="none"),
                  FeatureEdges(0.02, metric="euclidean", reduce="none")):
        drop = edges.mask(patches_image(), lm, (model, spec))
        assert drop.astype(int).tolist() == [[0, 1, 0], [1, 0, 0], [0, 0, 0]], edges
    # the whole image in one window: edges A-B (building-building), A-C, B-C (building-road)
    one = np.ones(3, bool)
    np.testing.assert_allclose(class_adjacency(one, lm), [[1 / 3, 2 / 3], [2 / 3, 0]])
    np.testing.assert_allclose(class_adjacency(one, lm, drop=drop), [[0, 1], [1, 0]])  # A-B is gone
    assert dropped_edges(drop, cliques_fast(lm, 400)) == {"pairs": 1, "edges": 3, "dropped": 1}
    assert dropped_edges(drop, cliques_fast(lm, 100)) == {"pairs": 1, "edges": 0, "dropped": 0}  # no window holds two


def test_feature_errors_are_one_line_config_errors(net, monkeypatch) -> None:
    model, spec, path = net
    lm = patch_landmarks()
    with pytest.raises(ConfigError, match="the image is 128x96 but the landmarks are of a 640x320 image"):
        landmark_features(np.zeros((96, 128, 3), np.uint8), lm, path)
    with pytest.raises(ConfigError, match="stage must be 1..5"):
        landmark_features(patches_image(), lm, path, stage=6)
    with pytest.raises(ConfigError, match="metric in"):
        FeatureEdges(0.5, metric="manhattan")
    with pytest.raises(ConfigError, match="threshold > 0"):
        FeatureEdges(0.0)
    with pytest.raises(ConfigError, match="needs an RGB image"):
        FeatureEdges(0.5).masks({"aerial": (None, lm, path), "ground": (None, lm, None)})
    with pytest.raises(ConfigError, match="give --feature-checkpoint"):
        FeatureEdges(0.5).masks({"aerial": (patches_image(), lm, None), "ground": (None, lm, None)})
    monkeypatch.setitem(sys.modules, "torch", None)  # as if the train extra were not installed
    with pytest.raises(ConfigError, match=r"pip install 'osmseg\[train\]'"):
        landmark_features(patches_image(), lm, path)


# --------------------------------------------------------------------------- the command


def write_scene(tmp_path: Path) -> dict[str, str]:
    """The patches photo, its mask (A and B buildings, C a road), a ground landmark file; CLI arguments."""
    mask = np.zeros((H, W), np.uint8)
    for name, (x, y) in CENTRES.items():
        mask[y - 16:y + 16, x - 16:x + 16] = HIGHWAY if name == "C" else BUILDING
    Image.fromarray(mask).save(tmp_path / "aerial_mask.png")
    Image.fromarray(patches_image()).save(tmp_path / "aerial.png")
    (tmp_path / "ground.txt").write_text("100 40 Building\n300 40 Building\n200 80 Road\n")
    return {"--aerial": str(tmp_path / "aerial_mask.png"), "--aerial-table": "classes6.toml",
            "--aerial-landmarks": "airsegnet6", "--ground": str(tmp_path / "ground.txt"), "--ground-size": "616x112",
            "--window": "400"}


def run(args: dict[str, str]):
    """``osmseg localize`` with the paper method: feature edges are its graph's."""
    return CliRunner().invoke(localize_command, ["--method", "paper", *[v for kv in args.items() for v in kv]])


def test_cli_drops_the_edge_between_look_alike_landmarks(net, tmp_path) -> None:
    _, _, path = net
    args = write_scene(tmp_path)
    args.update({"--aerial-image": str(tmp_path / "aerial.png"), "--feature-checkpoint": str(path)})
    out = tmp_path / "out"
    res = run({**args, "--feature-threshold": "0.5", "--out": str(out)})
    assert res.exit_code == 0, res.output
    saved = json.loads((out / "result.json").read_text())
    assert saved["aerial_landmarks"] == 3
    assert saved["feature_edges"] == {"threshold": 0.5, "metric": "cosine", "reduce": "pca", "components": 8,
                                      "stage": 5, "aerial": {"pairs": 1, "edges": 3, "dropped": 1}, "ground": None}
    # the ground graph has the two building-road edges only (its buildings are 200 px apart, its
    # window 112 px): without A-B the aerial graph is the same, 2/sqrt(5) with it (eq. 3.3)
    assert [c["likelihood"] for c in saved["candidates"]] == [1.0] * 3
    del args["--feature-checkpoint"]  # without a threshold it would be refused
    plain = run({**args, "--out": str(tmp_path / "plain")})
    assert plain.exit_code == 0, plain.output
    kept = json.loads((tmp_path / "plain" / "result.json").read_text())
    assert "feature_edges" not in kept
    assert [c["likelihood"] for c in kept["candidates"]] == pytest.approx([2 / 5 ** 0.5] * 3)


def test_cli_segmented_photo_gives_its_own_features(net, tmp_path) -> None:
    """An RGB aerial image segmented by the checkpoint: the same photo and encoder give the features."""
    from training.inference.windows import predict_array

    model, spec, path = net
    args = write_scene(tmp_path)
    del args["--aerial-table"]
    args.update({"--aerial": str(tmp_path / "aerial.png"), "--aerial-checkpoint": str(path),
                 "--feature-threshold": "0.5", "--out": str(tmp_path / "out")})
    res = run(args)
    assert res.exit_code == 0, res.output
    saved = json.loads((tmp_path / "out" / "result.json").read_text())
    # the same pairs by hand: segment the photo, take its landmarks, their features, the close pairs
    photo = patches_image()
    lm = landmarks_from_mask(predict_array(model, photo, spec), spec.table,
                             load_landmark_classes("airsegnet6"))
    expected = int(np.triu(FeatureEdges(0.5).mask(photo, lm, (model, spec)), k=1).sum())
    assert saved["aerial_landmarks"] == len(lm) >= 2
    assert saved["feature_edges"]["aerial"]["pairs"] == expected and saved["feature_edges"]["ground"] is None


@pytest.mark.parametrize("case, code, words", [
    ("no rgb side", 2, "--feature-threshold needs an RGB image: give --aerial-image or --ground-image"),
    ("no checkpoint", 2, "needs an encoder for the aerial image's features: give --feature-checkpoint"),
    ("missing checkpoint", 2, "does not exist"),
    ("corrupt checkpoint", 1, "is not a checkpoint (corrupt or truncated)"),
    ("photo of another size", 2, "--aerial-image small.png is 64x32; the aerial landmarks need the 640x320 RGB photo"),
    ("umap without umap-learn", 2, "pip install umap-learn"),
    ("options without a threshold", 2, "--feature-checkpoint, --feature-metric set how --feature-threshold removes"),
])
def test_cli_feature_options_bad_input_is_one_line(net, tmp_path, case: str, code: int, words: str) -> None:
    _, _, path = net
    args = {**write_scene(tmp_path), "--feature-threshold": "0.5"}
    if case == "no checkpoint":
        args["--aerial-image"] = str(tmp_path / "aerial.png")
    elif case == "missing checkpoint":
        args.update({"--aerial-image": str(tmp_path / "aerial.png"), "--feature-checkpoint": str(tmp_path / "no.pt")})
    elif case == "corrupt checkpoint":
        (tmp_path / "bad.pt").write_bytes(b"PK\x03\x04 not really a zip")
        args.update({"--aerial-image": str(tmp_path / "aerial.png"), "--feature-checkpoint": str(tmp_path / "bad.pt")})
    elif case == "photo of another size":
        Image.fromarray(np.zeros((32, 64, 3), np.uint8)).save(tmp_path / "small.png")
        args.update({"--aerial-image": str(tmp_path / "small.png"), "--feature-checkpoint": str(path)})
    elif case == "umap without umap-learn":
        if importlib.util.find_spec("umap") is not None:
            pytest.skip("umap-learn is installed")
        args.update({"--aerial-image": str(tmp_path / "aerial.png"), "--feature-checkpoint": str(path),
                     "--feature-reduce": "umap"})
    elif case == "options without a threshold":
        del args["--feature-threshold"]
        args.update({"--feature-checkpoint": str(path), "--feature-metric": "euclidean"})
    res = run(args)
    assert res.exit_code == code, res.output
    lines = res.stderr.strip().splitlines()
    assert words in lines[-1] and "Traceback" not in res.output
    assert len([line for line in lines if line.startswith("Error")]) == 1
