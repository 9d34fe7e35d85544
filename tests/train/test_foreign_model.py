"""A segmentation model osmseg did not train, read through a class mapping (training/inference/foreign.py).

The models are made here: a 1x1 convolution that scores each pixel by how near its colour lies to
each of a few "foreign" classes' colours (the nearest wins), its channels in an order of their own
that the mapping TOML turns into osmseg's classes. The same weights as TorchScript (torch.jit) and
as ONNX (built with onnx.helper, run by onnxruntime: no torch on that path) segment a photo drawn
in those colours back to its class ids exactly. Refusals name the file and what to fix.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import pytest
import torch
from onnx import TensorProto, helper, numpy_helper

from osmseg.classes import ClassDef, ClassTable, load_class_table
from osmseg.errors import ConfigError
from training.inference.foreign import load_foreign_model, read_class_mapping

BASE = load_class_table("classes13.toml")
SKY = ClassDef(id=14, name="sky", color=(135, 206, 235))
TABLE = ClassTable(name="osm13+sky", classes=(*BASE.classes, SKY), unlabeled=BASE.unlabeled)  # what a ground view shows
#: torch 2.14 calls TorchScript deprecated; the models made here are TorchScript on purpose (users still have them)
pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit.:FutureWarning")
#: the foreign model's channels, in its own order: osmseg class names
CHANNELS = ("sky", "building", "unlabeled", "highway", "tree")


def with_sky(table: ClassTable) -> ClassTable:
    """What localization does to the mapping's table for a ground view (its panorama_table): adds the sky."""
    return TABLE if table.name == BASE.name else table


def weights(channels: tuple[str, ...] = CHANNELS, table: ClassTable = TABLE) -> tuple[np.ndarray, np.ndarray]:
    """A 1x1 convolution whose channel c scores -|x - colour_c|^2 (+ what all share): the nearest colour wins."""
    colours = np.array([table.by_name[n].color[:3] for n in channels], np.float32) / 255.0
    return (2 * colours)[:, :, None, None], -(colours ** 2).sum(axis=1)


def torchscript_model(path: Path) -> Path:
    conv = torch.nn.Conv2d(3, len(CHANNELS), 1)
    w, b = weights()
    with torch.no_grad():
        conv.weight.copy_(torch.from_numpy(w))
        conv.bias.copy_(torch.from_numpy(b))
    torch.jit.save(torch.jit.script(conv), str(path))
    return path


def onnx_model(path: Path, channels: tuple[str, ...] = CHANNELS, table: ClassTable = TABLE,
               rows: int | str = "h", cols: int | str = "w") -> Path:
    w, b = weights(channels, table)
    graph = helper.make_graph(
        [helper.make_node("Conv", ["x", "w", "b"], ["y"])], "colours",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3, rows, cols])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, len(channels), rows, cols])],
        [numpy_helper.from_array(w, "w"), numpy_helper.from_array(b, "b")])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def mapping(path: Path, extra: str = "", classes: dict[int, str] | None = None,
            channels: tuple[str, ...] = CHANNELS) -> Path:
    named = classes if classes is not None else {i: n for i, n in enumerate(channels) if n != "unlabeled"}
    body = "\n".join(f'{k} = "{v}"' for k, v in named.items())
    path.write_text(f'table = "classes13.toml"\nmean = [0, 0, 0]\nstd = [1, 1, 1]\n{extra}\n[classes]\n{body}\n')
    return path


def photo() -> tuple[np.ndarray, np.ndarray]:
    """Class ids of a made-up street view (sky over buildings and trees, a road below) and its colours."""
    labels = np.full((60, 90), TABLE.by_name["sky"].id, np.uint8)
    labels[25:45, 10:40] = TABLE.by_name["building"].id
    labels[20:45, 50:70] = TABLE.by_name["tree"].id
    labels[45:, :] = TABLE.by_name["highway"].id
    labels[45:50, 80:] = TABLE.unlabeled.id
    return labels, np.take(TABLE.palette(), labels, axis=0).astype(np.uint8)


@pytest.mark.parametrize("make", [torchscript_model, onnx_model], ids=["torchscript", "onnx"])
def test_a_foreign_model_segments_a_photo_into_osmseg_classes_through_its_mapping(make, tmp_path: Path) -> None:
    labels, rgb = photo()
    model = load_foreign_model(make(tmp_path / ("m.onnx" if make is onnx_model else "m.pt")), mapping(tmp_path / "m.toml"),
                               with_sky)
    assert np.array_equal(model.segment(rgb), labels)
    # the model at its own input size: scores resized back to the photo's
    small = load_foreign_model(model.path, mapping(tmp_path / "s.toml", "size = [30, 45]"), with_sky)
    got = small.segment(rgb)
    assert got.shape == labels.shape and (got == labels).mean() > 0.95
    # a channel the mapping leaves out is unlabeled: here the sky
    no_sky = load_foreign_model(model.path, mapping(tmp_path / "n.toml", classes={1: "building", 3: "highway",
                                                                                    4: "tree"}), with_sky)
    assert (no_sky.segment(rgb)[labels == TABLE.by_name["sky"].id] == TABLE.unlabeled.id).all()


def test_a_mapping_or_model_that_cannot_be_read_says_what_to_fix(tmp_path: Path) -> None:
    ts = torchscript_model(tmp_path / "m.pt")
    cases = [
        (lambda: read_class_mapping(mapping(tmp_path / "a.toml", classes={0: "lava"})), "'lava' (channel 0) is no class"),
        (lambda: read_class_mapping(mapping(tmp_path / "b.toml", classes={})), "give a [classes] table"),
        (lambda: load_foreign_model(ts, mapping(tmp_path / "c.toml", classes={7: "sky"}), with_sky).segment(photo()[1]),
         "names channel 7, but m.pt gives 5 channels"),
        (lambda: load_foreign_model(ts, None), "needs --ground-model-classes FILE.toml"),
        (lambda: load_foreign_model(tmp_path / "state.pt", mapping(tmp_path / "d.toml"), with_sky), "not a TorchScript model"),
        (lambda: load_foreign_model(tmp_path / "m.h5", mapping(tmp_path / "e.toml"), with_sky), "TorchScript (.pt, .ts) or ONNX"),
        (lambda: load_foreign_model(onnx_model(tmp_path / "fixed.onnx", rows=32, cols=32), mapping(tmp_path / "f.toml"),
                                    with_sky).segment(photo()[1]), "failed on a 1x3x60x90 image"),
    ]
    torch.save(torch.nn.Conv2d(3, 5, 1).state_dict(), tmp_path / "state.pt")  # weights, not a TorchScript model
    (tmp_path / "m.h5").write_bytes(b"\x89HDF")
    for call, message in cases:
        with pytest.raises(ConfigError, match=None) as err:
            call()
        assert message in str(err.value) and "\n" not in str(err.value), str(err.value)
