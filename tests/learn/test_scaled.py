"""Per-image intensity normalisation: scale equivariance, the loss it passes on, checkpoints, tiles."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nanoct.core.errors import NanoctError
from nanoct.learn.calibration import Inference
from nanoct.learn.models import build_model
from nanoct.learn.scaled import SCALE_FACTOR, ImageScaled, image_scale
from nanoct.learn.tiling import predict_tiled

pytestmark = pytest.mark.usefixtures("one_thread")

FLOW = {"n_scales": 3, "blocks_per_scale": 1, "pre_blocks": 1, "cond_channels": (4, 4, 8), "hidden_ratio": 1.0}
UNET = {"channels": (4, 4, 8), "skip_channels": 2}


def test_image_scale_is_twice_the_99th_percentile_per_image(images):
    x_tilde, _ = images(3, 20, 20, 0)
    x_tilde[1] *= -50.0  # the absolute value counts
    s = image_scale(x_tilde)
    assert s.shape == (3, 1, 1, 1)
    for i in range(3):
        expected = SCALE_FACTOR * np.percentile(np.abs(x_tilde[i].numpy()), 99)
        assert float(s[i]) == pytest.approx(expected, rel=1e-5)
    assert float(image_scale(np.zeros((8, 8)))) == pytest.approx(1e-6)  # floored: an empty image stays finite
    assert float(image_scale(x_tilde[2, 0].numpy())) == pytest.approx(float(s[2]), rel=1e-6)


@pytest.mark.parametrize(("name", "kwargs"), [("ciunet-res", FLOW), ("unet", UNET)])
def test_reconstruct_is_equivariant_to_the_input_scale(name, kwargs, images, perturb):
    """f(c x) = c f(x) for mean and std, for each image of a batch on its own; the plain network is not."""
    torch.manual_seed(0)
    model = build_model(name, normalize="image", **kwargs)
    assert isinstance(model, ImageScaled) and model.name == name
    perturb(model, 0.05)
    model.eval()
    x_tilde, _ = images(2, 16, 16, 1)
    call = {"n_samples": 4, "seed": 5} if model.has_uncertainty else {}
    c = torch.tensor([0.01, 30.0]).view(2, 1, 1, 1)
    mean, std = model.reconstruct(x_tilde, **call)
    mean_c, std_c = model.reconstruct(c * x_tilde, **call)
    # float32 rounding of the division only: within 1e-5 of each image's largest value
    torch.testing.assert_close(mean_c / c, mean, rtol=0, atol=1e-5 * float(mean.abs().max()))
    if std is not None:
        torch.testing.assert_close(std_c / c, std, rtol=0, atol=1e-5 * float(std.abs().max()))
    plain = model.inner
    m1, _ = plain.reconstruct(x_tilde, **call)
    m2, _ = plain.reconstruct(c * x_tilde, **call)
    assert (m2 - c * m1).abs().max() > 1e-3 * (c * m1).abs().max()


@pytest.mark.parametrize(("name", "kwargs"), [("ciunet-res", FLOW), ("unet", UNET)])
def test_loss_is_the_inner_loss_on_normalised_pairs(name, kwargs, images):
    torch.manual_seed(1)
    model = build_model(name, normalize="image", **kwargs)
    x_tilde, x = images(2, 16, 16, 2)
    x_tilde, x = 0.003 * x_tilde, 0.003 * x
    s = image_scale(x_tilde)
    model.data_init(x_tilde, x)
    torch.manual_seed(3)  # the flow's training-mode target noise draws the same numbers in both calls
    loss, logs = model.loss(x_tilde, x)
    torch.manual_seed(3)
    inner_loss, inner_logs = model.inner.loss(x_tilde / s, x / s)
    torch.testing.assert_close(loss, inner_loss)
    assert logs.keys() == inner_logs.keys()


def test_checkpoint_hparams_rebuild_the_wrapper_and_its_weights(perturb):
    torch.manual_seed(0)
    model = build_model("ciunet-res", normalize="image", **FLOW)
    perturb(model)
    assert model.hparams["normalize"] == "image"
    again = build_model("ciunet-res", **model.hparams)
    again.load_state_dict(model.state_dict())
    assert isinstance(again, ImageScaled)
    assert "normalize" not in build_model("ciunet-res", **FLOW).hparams  # off by default: old checkpoints rebuild
    with pytest.raises(NanoctError, match="normalize='pixel' is unknown"):
        build_model("unet", normalize="pixel")


def test_tiles_share_the_whole_image_scale(rng):
    """With the whole image's scale passed to each tile, one tile covering the image is the untiled prediction;
    each tile's own scale would differ on an image whose brightness varies across it."""
    torch.manual_seed(0)
    model = build_model("ciunet-res", normalize="image", **FLOW)
    infer = Inference(model, {"n_samples": 2}, True, "cpu")
    image = rng.uniform(0, 1, (24, 24)).astype(np.float32) * np.linspace(0.01, 1, 24, dtype=np.float32)
    whole = infer(image[None], 3)
    scale = float(image_scale(image))
    one_tile = predict_tiled(image, lambda t, seed: infer(t, seed, scale=scale), 24, overlap=6, margin=2, seed=3)
    np.testing.assert_allclose(one_tile[0], whole[0][0], rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(one_tile[1], whole[1][0], rtol=1e-5, atol=1e-9)
