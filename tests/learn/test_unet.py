"""UNet: shapes with padding and crop-back, feature maps per scale, sigmoid range, PostProcessor API."""

from __future__ import annotations

import re

import pytest
import torch

from nanoct.core.errors import NanoctError
from nanoct.learn.base import PostProcessor
from nanoct.learn.models import build_model, model_names
from nanoct.learn.unet import PAPER_CHANNELS, UNet, UNetPost, padded_size

SMALL = (4, 4, 8, 8, 16)


@pytest.mark.parametrize("n", [63, 127, 255])
def test_shapes_crop_back_and_features(n):
    torch.manual_seed(0)
    net = UNet(channels=SMALL)
    x = torch.randn(2, 1, n, n)
    out, enc, dec = net.forward_features(x)
    assert out.shape == x.shape
    p = padded_size(n, 5)
    assert p == {63: 64, 127: 128, 255: 256}[n]
    assert [tuple(t.shape) for t in enc] == [(2, c, p >> i, p >> i) for i, c in enumerate(SMALL)]
    assert [tuple(t.shape) for t in dec] == [(2, c, p >> i, p >> i) for i, c in enumerate(SMALL)]
    assert dec[-1] is enc[-1]  # bottleneck
    assert torch.equal(net(x), out)  # forward == forward_features[0]


def test_non_square_and_exact_multiple():
    net = UNet(channels=SMALL).eval()
    assert net(torch.randn(1, 1, 40, 50)).shape == (1, 1, 40, 50)
    assert net(torch.randn(1, 1, 64, 64)).shape == (1, 1, 64, 64)
    assert net(torch.randn(1, 1, 5, 5)).shape == (1, 1, 5, 5)  # pad > size: replicate fallback


def test_paper_defaults_and_sigmoid_range():
    net = UNet()
    assert net.scales == 5 and net.channels == list(PAPER_CHANNELS)
    assert min(PAPER_CHANNELS) == 32 and max(PAPER_CHANNELS) == 128
    with torch.no_grad():
        out = net.eval()(100 * torch.randn(1, 1, 63, 63))
    assert out.min() >= 0 and out.max() <= 1
    raw = UNet(channels=SMALL, use_sigmoid=False).eval()
    with torch.no_grad():
        assert raw(50 * torch.randn(1, 1, 31, 31)).min() < 0


def test_downsampling_is_strided_conv_and_upsampling_bilinear():
    net = UNet(channels=SMALL)
    convs = [m for m in net.down.modules() if isinstance(m, torch.nn.Conv2d)]
    assert convs[0].stride == (2, 2) and not any(isinstance(m, torch.nn.MaxPool2d) for m in net.modules())
    skip_convs = [b.skip_conv[0] for b in net.up]
    assert all(c.out_channels == 4 and c.kernel_size == (1, 1) for c in skip_convs)


def test_skip_connections_carry_gradient():
    net = UNet(channels=SMALL)
    x = torch.randn(2, 1, 32, 32)
    net(x).sum().backward()
    assert all(b.skip_conv[0].weight.grad.abs().sum() > 0 for b in net.up)


def test_bad_arguments():
    with pytest.raises(ValueError):
        UNet(channels=(4, 8), skip_channels=(4, 4, 4))
    with pytest.raises(ValueError):
        UNet(pad_mode="circularish")
    with pytest.raises(NanoctError):
        build_model("unet", channels=[])
    with pytest.raises(NanoctError):
        build_model("unet", depth=3)
    with pytest.raises(NanoctError, match="unknown"):
        build_model("resnet-9000")


@pytest.mark.parametrize(
    ("name", "kwargs", "expect"),
    [
        ("unet", {"channels": "nan"}, "channels='nan' must be a non-empty list of integers"),
        ("unet", {"channels": [4.7, 8]}, "channels=4.7 must be an integer"),  # not truncated to 4
        ("unet", {"skip_channels": True}, "skip_channels=True"),
        ("ciunet", {"n_scales": 2.5}, "n_scales=2.5"),
        ("ciunet", {"blocks_per_scale": 0}, "blocks_per_scale=0"),
        ("cinn", {"cond_channels": "x"}, "cond_channels='x'"),
        ("cinn", {"fc_dim": 64.5}, "fc_dim=64.5"),
    ],
)
def test_architecture_numbers_must_be_whole(name, kwargs, expect):
    with pytest.raises(NanoctError, match=re.escape(expect)):
        build_model(name, **kwargs)


def test_postprocessor_interface():
    assert "unet" in model_names()
    model = build_model("unet", channels=list(SMALL))
    assert isinstance(model, PostProcessor) and isinstance(model, UNetPost) and model.name == "unet"
    assert model.hparams == {
        "channels": list(SMALL),
        "skip_channels": 4,
        "use_sigmoid": True,
        "use_norm": True,
        "pad_mode": "reflect",
        "out_bias": 0.0,
    }
    assert build_model("unet", **model.hparams).hparams == model.hparams
    x_tilde, x = torch.rand(3, 1, 31, 31), torch.rand(3, 1, 31, 31)
    loss, logs = model.loss(x_tilde, x)
    assert loss.ndim == 0 and loss.requires_grad and logs == {"mse": pytest.approx(float(loss.detach()))}
    assert torch.allclose(loss, torch.mean((model(x_tilde) - x) ** 2))
    mean, std = model.eval().reconstruct(x_tilde)
    assert std is None and mean.shape == x.shape and not mean.requires_grad


def test_channels_last_matches_contiguous():
    torch.manual_seed(1)
    net = UNet(channels=SMALL).eval()
    x = torch.randn(2, 1, 63, 63)
    with torch.no_grad():
        a = net(x)
        b = net.to(memory_format=torch.channels_last)(x.contiguous(memory_format=torch.channels_last))
    assert torch.allclose(a, b, atol=1e-5)


def test_output_bias_starts_near_the_zero_background():
    torch.manual_seed(0)
    net = UNetPost(channels=[4, 4, 4, 4, 4], out_bias=-6.0).eval()
    with torch.no_grad():
        out = net(torch.rand(2, 1, 31, 31))
    assert net.hparams["out_bias"] == -6.0
    assert float(out.mean()) < 0.02  # sigmoid(-6) = 0.0025 plus the random first layers
    default = UNetPost(channels=[4, 4, 4, 4, 4]).eval()
    with torch.no_grad():
        assert float(default(torch.rand(2, 1, 31, 31)).mean()) > 0.2  # PyTorch's default start: ~0.5


def test_range_loss_weighs_each_image_by_its_own_range():
    """``loss_scale="range"``: the batch mean of each image's MSE over its target's (max - min)^2, so a faint
    image with the same relative error weighs as a bright one; recorded in hparams, the default is not."""
    torch.manual_seed(0)
    model = build_model("unet", channels=list(SMALL), loss_scale="range")
    assert model.hparams["loss_scale"] == "range" and "loss_scale" not in build_model("unet").hparams
    assert build_model("unet", **model.hparams).hparams == model.hparams
    x_tilde = torch.rand(2, 1, 31, 31)
    x = torch.rand(2, 1, 31, 31) * torch.tensor([1.0, 0.003]).view(2, 1, 1, 1)
    loss, logs = model.loss(x_tilde, x)
    out = model(x_tilde)
    spread = x.amax(dim=(1, 2, 3)) - x.amin(dim=(1, 2, 3))
    by_hand = torch.mean(torch.mean((out - x) ** 2, dim=(1, 2, 3)) / spread**2)
    assert torch.allclose(loss, by_hand) and loss.requires_grad
    assert logs["relative_mse"] == pytest.approx(float(by_hand)) and logs["mse"] == pytest.approx(
        float(torch.mean((out - x) ** 2))
    )
    # the faint image dominates the relative loss (its error is large against its range), not the absolute one
    per_image = torch.mean((out - x) ** 2, dim=(1, 2, 3)) / spread**2
    assert per_image[1] > 100 * per_image[0]
    with pytest.raises(NanoctError, match="loss_scale must be one of absolute, range, got 'relative'"):
        build_model("unet", loss_scale="relative")


def test_residual_unet_starts_at_its_input_and_learns_a_correction():
    """``residual=True``: the output is ``x_tilde - UNet(x_tilde)`` with a linear last convolution that starts
    at zero, so the untrained network returns its input exactly; a few steps on a constant offset learn it.
    Recorded in hparams (not when False); a sigmoid or an output bias with it is refused."""
    torch.manual_seed(0)
    model = build_model("unet", channels=list(SMALL), residual=True)
    assert model.hparams["residual"] is True and model.hparams["use_sigmoid"] is False
    assert "residual" not in build_model("unet").hparams and build_model("unet").hparams["use_sigmoid"] is True
    assert build_model("unet", **model.hparams).hparams == model.hparams
    x_tilde = torch.rand(4, 1, 31, 31)
    assert torch.equal(model.eval().reconstruct(x_tilde)[0], x_tilde)
    model.train()
    target = x_tilde - 0.3  # the input with an offset: the correction to learn is a constant 0.3
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    first = float(model.loss(x_tilde, target)[0])
    assert first == pytest.approx(0.09, rel=1e-5)  # the input's own error: 0.3 squared
    for _ in range(60):
        opt.zero_grad()
        loss, _ = model.loss(x_tilde, target)
        loss.backward()
        opt.step()
    assert float(loss) < 0.01 * first
    assert torch.allclose(model.loss(x_tilde, target)[0], torch.mean((model(x_tilde) - target) ** 2))
    for bad in ({"use_sigmoid": True}, {"out_bias": -7.0}):
        with pytest.raises(NanoctError, match="residual UNet"):
            build_model("unet", residual=True, **bad)
    # --param residual=False arrives as a string: read as the word it is, anything else refused
    assert "residual" not in build_model("unet", residual="False").hparams
    assert build_model("unet", residual="TRUE", channels=list(SMALL)).hparams["residual"] is True
    with pytest.raises(NanoctError, match="residual must be true or false"):
        build_model("unet", residual="yes")
    plain = build_model("unet", use_norm="false", channels=list(SMALL))
    assert plain.hparams["use_norm"] is False and not any(isinstance(m, torch.nn.BatchNorm2d) for m in plain.modules())
