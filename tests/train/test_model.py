"""SegNet: shapes, size, gradients, unpooling by indices, memory formats, presets, VGG weights."""

from __future__ import annotations

import urllib.error
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from osmseg.classes import load_class_table
from osmseg.errors import ConfigError
from training.models.networks import SegNet, build_model, load_encoder_weights, model_spec

TINY = 0.0625


@pytest.fixture(autouse=True)
def _threads() -> Iterator[None]:
    """Two cores are shared by several test runs: stay on at most two threads."""
    before = torch.get_num_threads()
    torch.set_num_threads(min(2, before))
    torch.manual_seed(0)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def vgg() -> nn.Module:
    """torchvision's vgg16_bn (random init) with random BN statistics, so buffers matter too."""
    from torchvision.models import vgg16_bn

    torch.manual_seed(1)
    model = vgg16_bn(weights=None)
    model.classifier = nn.Sequential(nn.Linear(8, 4))  # drop the 100M-parameter head: keys stay "classifier.*"
    for m in model.features:
        if isinstance(m, nn.BatchNorm2d):
            m.running_mean.uniform_(-0.5, 0.5)
            m.running_var.uniform_(0.5, 2.0)
            nn.init.uniform_(m.weight, 0.5, 1.5)
            nn.init.uniform_(m.bias, -0.2, 0.2)
            m.num_batches_tracked.fill_(7)
    return model.eval()


@pytest.fixture(scope="module")
def full() -> SegNet:
    """The paper-size network (width 1.0, CamVid's 11 classes + void)."""
    torch.manual_seed(2)
    return SegNet(num_classes=12, width=1.0)


def n_params(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


@pytest.mark.parametrize("size", [(64, 96), (360, 480), (100, 130), (33, 47), (32, 32)])
def test_output_has_input_size_and_class_channels(size: tuple[int, int]) -> None:
    net = SegNet(num_classes=7, width=TINY).eval()
    with torch.no_grad():
        out = net(torch.randn(2 if size != (360, 480) else 1, 3, *size))
    assert out.shape[1:] == (7, *size)
    assert torch.isfinite(out).all()


def test_bad_input_is_a_one_line_config_error() -> None:
    net = SegNet(num_classes=3, width=TINY)
    with pytest.raises(ConfigError, match="at least 32x32 pixels, got 31x64"):
        net(torch.zeros(1, 3, 31, 64))
    with pytest.raises(ConfigError, match=r"must be \(N, 3, H, W\), got \(1, 1, 64, 64\)"):
        net(torch.zeros(1, 1, 64, 64))
    with pytest.raises(ConfigError):
        SegNet(num_classes=0)


def test_paper_size_parameter_count(full: SegNet) -> None:
    total, encoder = n_params(full), n_params(full.encoder)
    print(f"SegNet width 1.0, 12 classes: {total:,} parameters (encoder {encoder:,})")
    assert encoder == 14_723_136  # VGG16's 13 convolutions (14,714,688) + their BatchNorms
    assert 29_300_000 < total < 29_600_000  # the paper's Table 6: 29.5 M
    first = full.encoder.features[0]
    assert (first.in_channels, first.out_channels) == (3, 64)


def test_tiny_width_is_small_and_trains() -> None:
    net = SegNet(num_classes=7, width=TINY)
    assert net.encoder.features[0].out_channels == 4 and n_params(net) < 150_000
    x, y = torch.randn(2, 3, 64, 96), torch.randint(0, 7, (2, 64, 96))
    opt = torch.optim.SGD(net.parameters(), lr=0.05, momentum=0.9)
    losses = []
    for _ in range(8):  # the same batch: the loss must fall
        opt.zero_grad()
        loss = F.cross_entropy(net(x), y)
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < losses[0]


def test_gradients_reach_every_parameter() -> None:
    net = SegNet(num_classes=5, width=TINY)
    F.cross_entropy(net(torch.randn(2, 3, 64, 64)), torch.randint(0, 5, (2, 64, 64))).backward()
    for name, p in net.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
    assert net.encoder.features[0].weight.grad.abs().sum() > 0


def test_decoder_unpools_to_the_encoder_argmax_positions() -> None:
    """The deepest decoder stage sees the last encoder activation at its 2x2 maxima, zeros elsewhere."""
    net = SegNet(num_classes=4, width=TINY).eval()
    seen: dict[str, torch.Tensor] = {}
    net.encoder.features[42].register_forward_hook(lambda m, i, o: seen.__setitem__("act", o.clone()))
    net.decoder[0].register_forward_pre_hook(lambda m, i: seen.__setitem__("unpooled", i[0].clone()))
    with torch.no_grad():
        net(torch.randn(1, 3, 64, 96))
    act, unpooled = seen["act"], seen["unpooled"]
    assert act.shape == unpooled.shape == (1, 32, 4, 6)
    window_max = F.max_pool2d(act, 2).repeat_interleave(2, dim=2).repeat_interleave(2, dim=3)
    expected = torch.where(act == window_max, act, torch.zeros_like(act))
    assert torch.equal(unpooled, expected)
    assert (unpooled > 0).sum() > 0 and (unpooled == 0).sum() >= 3 * unpooled.numel() // 4


def test_skips_add_the_encoder_features_to_the_unpooled_decoder_input() -> None:
    """segnet-skip: each decoder stage's input is SegNet's unpooled tensor plus the features its
    encoder stage pooled; the weights are SegNet's, so one state dict serves both."""
    plain, skip = SegNet(num_classes=4, width=TINY).eval(), SegNet(num_classes=4, width=TINY, skips=True).eval()
    skip.load_state_dict(plain.state_dict())  # the same keys and shapes
    seen: dict[str, torch.Tensor] = {}
    skip.encoder.features[5].register_forward_hook(lambda m, i, o: seen.__setitem__("stage1", o.clone()))
    skip.unpool.register_forward_hook(lambda m, i, o: seen.__setitem__("unpooled", o.clone()))  # its last call
    skip.decoder[4].register_forward_pre_hook(lambda m, i: seen.__setitem__("input", i[0].clone()))
    x = torch.randn(1, 3, 64, 96)
    with torch.no_grad():
        differ = not torch.equal(plain(x), skip(x))
    # the shallowest decoder stage's input: unpooled features plus stage 1's (64x96, before its pooling)
    assert seen["input"].shape == seen["stage1"].shape == (1, 4, 64, 96)
    torch.testing.assert_close(seen["input"], seen["unpooled"] + seen["stage1"])
    assert differ and seen["stage1"].abs().sum() > 0


def test_unpool_puts_values_where_the_maxima_were() -> None:
    """One pool/unpool pair of the model on a crafted tensor with known argmax positions."""
    net = SegNet(num_classes=2, width=TINY)
    x = torch.tensor([[[[1.0, 9.0, 2.0, 0.0], [3.0, 4.0, 0.0, 8.0], [7.0, 0.0, 5.0, 6.0], [0.0, 1.0, 2.0, 3.0]]]])
    pooled, indices = net.encoder.features[6](x)
    assert pooled.flatten().tolist() == [9.0, 8.0, 7.0, 6.0]
    back = net.unpool(pooled, indices, output_size=x.shape[-2:])
    assert back[0, 0].tolist() == [[0, 9, 0, 0], [0, 0, 0, 8], [7, 0, 0, 6], [0, 0, 0, 0]]


def test_channels_last_gives_the_same_logits() -> None:
    net = SegNet(num_classes=6, width=TINY).eval()
    x = torch.randn(2, 3, 100, 130)
    with torch.no_grad():
        plain = net(x)
        net = net.to(memory_format=torch.channels_last)
        cl = net(x.contiguous(memory_format=torch.channels_last))
    assert cl.is_contiguous(memory_format=torch.channels_last)
    torch.testing.assert_close(cl, plain, rtol=1e-4, atol=1e-4)


def test_autocast_runs_and_agrees() -> None:
    net = SegNet(num_classes=6, width=TINY).eval()
    x = torch.randn(1, 3, 64, 96)
    with torch.no_grad():
        ref = net(x)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            low = net(x)
    assert low.dtype == torch.bfloat16 and low.shape == ref.shape
    assert (low.float().argmax(1) == ref.argmax(1)).float().mean() > 0.9


def test_presets_fill_outputs_from_the_class_tables() -> None:
    six, thirteen = model_spec("airsegnet6", TINY), model_spec("airsegnet13", TINY, ignore_unlabeled=False)
    assert (six.num_classes, thirteen.num_classes) == (7, 14)
    assert (six.ignore_index, thirteen.ignore_index) == (0, None)
    assert six.class_table == load_class_table("classes6.toml").to_dict()
    by_id = load_class_table("classes13.toml").by_id
    assert thirteen.class_names == [by_id[i].name for i in range(14)]
    assert six.mean == (0.485, 0.456, 0.406) and six.input_size == (360, 480)
    net = build_model(six).eval()
    with torch.no_grad():
        assert net(torch.zeros(1, 3, 64, 64)).shape == (1, 7, 64, 64)


def test_free_names_need_a_class_table() -> None:
    with pytest.raises(ConfigError, match="unknown model 'camvid'"):
        model_spec("camvid", TINY)
    table = {"name": "camvid", "classes": [{"id": i, "name": f"c{i}", "color": [i, i, i]} for i in range(12)]}
    spec = model_spec("segnet-camvid", TINY, ignore_unlabeled=False, class_table=table, input_size=(64, 96))
    assert spec.num_classes == 12 and spec.input_size == (64, 96)
    assert model_spec("x", TINY, class_table=load_class_table("classes6.toml")).num_classes == 7


def _check_encoder_is_vgg(net: SegNet, vgg: nn.Module) -> None:
    ours = net.encoder.features.state_dict()
    for key, value in vgg.features.state_dict().items():
        assert torch.equal(ours[key], value), key
    net.eval()
    x = torch.randn(2, 3, 40, 56)
    with torch.no_grad():
        stage1, _ = net.encoder.features[:7](x)
        expected = vgg.features[:7](x)
        assert torch.equal(net.encoder.features[:6](x), vgg.features[:6](x))
    torch.testing.assert_close(stage1, expected, rtol=0, atol=0)


@pytest.mark.parametrize("layout", ["full", "features"])
def test_encoder_takes_a_local_vgg16_bn_file(layout: str, vgg: nn.Module, full: SegNet, tmp_path: Path) -> None:
    path = tmp_path / "vgg16_bn.pth"
    torch.save(vgg.state_dict() if layout == "full" else vgg.features.state_dict(), path)
    decoder_before = full.classifier.weight.clone()
    load_encoder_weights(full, path)
    _check_encoder_is_vgg(full, vgg)
    assert torch.equal(full.classifier.weight, decoder_before)  # the decoder is left alone


def test_imagenet_weights_come_from_torch_hub(vgg: nn.Module, full: SegNet, monkeypatch: pytest.MonkeyPatch) -> None:
    urls: list[str] = []

    def fake_download(url: str, **kwargs: object) -> dict[str, torch.Tensor]:
        urls.append(url)
        return vgg.state_dict()

    monkeypatch.setattr(torch.hub, "load_state_dict_from_url", fake_download)
    load_encoder_weights(full, "imagenet")
    assert urls == ["https://download.pytorch.org/models/vgg16_bn-6c64b313.pth"]
    _check_encoder_is_vgg(full, vgg)


def test_imagenet_weights_offline_is_a_clear_error(full: SegNet, monkeypatch: pytest.MonkeyPatch) -> None:
    def offline(url: str, **kwargs: object) -> None:
        raise urllib.error.URLError("[Errno -3] Temporary failure in name resolution")

    monkeypatch.setattr(torch.hub, "load_state_dict_from_url", offline)
    with pytest.raises(ConfigError, match="ImageNet weights need the network.*pass a local .pth of vgg16_bn instead"):
        load_encoder_weights(full, "imagenet")


def test_encoder_weights_bad_sources(vgg: nn.Module, full: SegNet, tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="need width 1.0"):
        load_encoder_weights(SegNet(num_classes=3, width=TINY), "imagenet")
    with pytest.raises(ConfigError, match="not found"):
        load_encoder_weights(full, tmp_path / "nope.pth")
    (tmp_path / "junk.pth").write_bytes(b"not a state dict")
    with pytest.raises(ConfigError, match="not a readable vgg16_bn state dict"):
        load_encoder_weights(full, tmp_path / "junk.pth")
    wrong = {k: v for k, v in vgg.features.state_dict().items() if not k.startswith("40.")}
    torch.save(wrong, tmp_path / "short.pth")
    with pytest.raises(ConfigError, match=r"features\.40\.weight missing"):
        load_encoder_weights(full, tmp_path / "short.pth")
    torch.save({"0.weight": torch.zeros(8, 3, 3, 3)}, tmp_path / "narrow.pth")
    with pytest.raises(ConfigError, match=r"features\.0\.weight \(8, 3, 3, 3\) instead of \(64, 3, 3, 3\)"):
        load_encoder_weights(full, tmp_path / "narrow.pth")
