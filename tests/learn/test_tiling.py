"""Tiled inference: window, tile layout, equality with the untiled output where the receptive field fits."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from nanoct.learn.tiling import edge_window, predict_tiled, tile_starts


def test_tile_starts_cover_the_image():
    assert tile_starts(63, 63, 16) == [0]
    assert tile_starts(40, 63, 16) == [0]
    starts = tile_starts(200, 63, 16)
    assert starts[0] == 0 and starts[-1] == 200 - 63
    assert all(b - a <= 63 - 16 for a, b in zip(starts, starts[1:]))
    with pytest.raises(ValueError, match="overlap"):
        tile_starts(100, 10, 10)


def test_edge_window_zero_margin_and_ramp():
    w = edge_window(32, 10, 2, first=False, last=False)
    assert w[:2].tolist() == [0, 0] and w[-2:].tolist() == [0, 0]
    assert np.all(np.diff(w[:10]) >= 0) and np.all(w[10:-10] == 1)
    # two neighbouring tiles' ramps over their shared pixels sum to one (a partition of unity)
    left, right = edge_window(32, 10, 2, True, False), edge_window(32, 10, 2, False, True)
    np.testing.assert_allclose(left[-10:] + right[:10], 1.0)
    assert np.all(edge_window(32, 10, 2, True, True) == 1)
    with pytest.raises(ValueError, match="overlap"):
        edge_window(32, 4, 2, False, False)


class _Local(nn.Module):
    """Two 3x3 convolutions with zero padding: receptive field radius 2; a 'std' from a third."""

    def __init__(self) -> None:
        super().__init__()
        torch.manual_seed(0)
        self.a = nn.Conv2d(1, 4, 3, padding=1)
        self.b, self.c = nn.Conv2d(4, 1, 3, padding=1), nn.Conv2d(4, 1, 3, padding=1)

    def __call__(self, x: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
        with torch.no_grad():
            h = torch.tanh(self.a(torch.from_numpy(np.asarray(x, np.float32))[:, None]))
            return self.b(h)[:, 0].numpy(), torch.nn.functional.softplus(self.c(h))[:, 0].numpy()


def test_tiled_equals_untiled_where_the_receptive_field_fits(rng):
    """A network of receptive-field radius 2 with margin 2: tiled = untiled to float32 rounding (1e-5)
    for the mean and the std; with margin 0 the tile borders show (the test can fail)."""
    net, image = _Local(), rng.uniform(0, 1, (150, 131)).astype(np.float32)
    whole_mean, whole_std = net(image[None])
    mean, std = predict_tiled(image, net, 40, overlap=10, margin=2, batch=5)
    np.testing.assert_allclose(mean, whole_mean[0], atol=1e-5)
    np.testing.assert_allclose(std, whole_std[0], atol=1e-5)
    seamy, _ = predict_tiled(image, net, 40, overlap=10, margin=0, batch=5)
    assert np.abs(seamy - whole_mean[0]).max() > 1e-3
    # smaller than a tile: padded to the tile and cropped back
    small = image[:30, :25]
    got, _ = predict_tiled(small, net, 40, overlap=10, margin=2)
    assert got.shape == (30, 25)
    np.testing.assert_allclose(got[:-2, :-2], net(small[None])[0][0][:-2, :-2], atol=1e-5)


def test_tiled_output_is_a_convex_blend_of_the_tiles():
    """A network whose output depends on the whole tile (a global mean): the stitched output lies between the
    tiles' outputs at every pixel, and a constant output comes back exactly."""

    def global_mean(x: np.ndarray, seed: int) -> tuple[np.ndarray, None]:
        return x + x.mean(axis=(1, 2), keepdims=True), None

    image = np.add.outer(np.arange(90.0), np.arange(70.0)).astype(np.float32) / 160
    mean, std = predict_tiled(image, global_mean, 32, overlap=8, margin=2)
    assert std is None
    tile_means = [image[y : y + 32, x : x + 32].mean() for y in tile_starts(90, 32, 8) for x in tile_starts(70, 32, 8)]
    assert np.all(mean - image >= min(tile_means) - 1e-5) and np.all(mean - image <= max(tile_means) + 1e-5)
    const, _ = predict_tiled(image, lambda x, s: (np.full_like(x, 0.25), None), 32, overlap=8, margin=2)
    np.testing.assert_allclose(const, 0.25, rtol=1e-6)
