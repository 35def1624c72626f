"""Tiled inference: window, tile layout, equality with the untiled output where the receptive field fits."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from nanoct.learn.tiling import batch_seed, edge_window, parallel_tiles, predict_tiled, tile_starts


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


def test_parallel_workers_give_the_same_output_as_one(rng):
    """Batches computed by several threads are blended in tile order with the same seeds: the output equals
    that of one worker bit for bit, for a network whose output depends on the seed of its call."""
    seeds: list[int] = []

    def noisy(x: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
        seeds.append(seed)
        noise = np.random.default_rng(seed).normal(0, 0.1, x.shape).astype(np.float32)
        return x + noise, 0.1 + np.abs(noise)

    image = rng.uniform(0, 1, (75, 61)).astype(np.float32)
    one = predict_tiled(image, noisy, 20, overlap=6, margin=2, batch=2, seed=7)
    one_seeds, seeds[:] = list(seeds), []
    for workers in (2, 5):
        many = predict_tiled(image, noisy, 20, overlap=6, margin=2, batch=2, seed=7, workers=workers)
        assert np.array_equal(one[0], many[0]) and np.array_equal(one[1], many[1])
        assert sorted(seeds) == sorted(one_seeds) and len(set(one_seeds)) == len(one_seeds) > 6
        seeds[:] = []


def test_parallel_tiles_with_a_flow_network_equals_sequential_tiles(rng):
    """A conditional invertible network (a tiny CiUNetRes, 4 antithetic latent samples) called from two
    threads with one torch thread each gives the sequential prediction with two torch threads to float32
    rounding (the summation order of a convolution depends on the thread count); the thread count comes
    back afterwards, and a non-CPU device gets one worker and no change."""
    from nanoct.learn.calibration import Inference
    from nanoct.learn.models import build_model

    torch.manual_seed(0)
    model = build_model(
        "ciunet-res", n_scales=3, blocks_per_scale=1, pre_blocks=1, cond_channels=(4, 4, 8), hidden_ratio=1.0
    )
    infer = Inference(model, {"n_samples": 4, "antithetic": True}, True, "cpu")
    image = rng.uniform(0, 1, (40, 36)).astype(np.float32)
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        expected = predict_tiled(image, infer, 16, overlap=6, margin=2, batch=2, seed=3)
        with parallel_tiles("cpu") as workers:
            assert workers == 2 and torch.get_num_threads() == 1
            got = predict_tiled(image, infer, 16, overlap=6, margin=2, batch=2, seed=3, workers=workers)
        assert torch.get_num_threads() == 2
        with parallel_tiles("cuda") as workers:
            assert workers == 1 and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
    np.testing.assert_allclose(got[0], expected[0], rtol=0, atol=1e-5)
    np.testing.assert_allclose(got[1], expected[1], rtol=0, atol=1e-5)
    assert np.isfinite(got[1]).all() and got[1].min() > 0


def test_parallel_tiles_workers_run_one_openmp_thread_each():
    """Each worker thread takes torch's thread count (one) before the network's first operation, so a
    convolution in a fresh thread does not start a team of OpenMP threads of its own."""
    import ctypes
    import os

    maps = f"/proc/{os.getpid()}/maps"
    loaded = open(maps).read().split() if os.path.exists(maps) else []
    # torch's own libgomp: other packages (finufft) may have loaded a copy of their own first
    libs = [path for path in loaded if "libgomp" in path and os.sep + "torch" + os.sep in path]
    if not libs:
        pytest.skip("no GNU OpenMP library loaded by torch here")
    gomp = ctypes.CDLL(libs[0])
    team: list[int] = []

    def network(x: np.ndarray, seed: int) -> tuple[np.ndarray, None]:
        team.append(gomp.omp_get_max_threads())  # before any torch operation in this thread
        return x, None

    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        with parallel_tiles("cpu") as workers:
            predict_tiled(np.zeros((60, 60), np.float32), network, 20, overlap=6, margin=2, batch=1, workers=workers)
    finally:
        torch.set_num_threads(before)
    assert len(team) == 16 and set(team) == {1}


def test_parallel_workers_stop_at_an_error():
    """A network error in one batch reaches the caller, and the slice stops there: at most the few batches
    already submitted (the window of workers + 1) are computed, not the rest."""
    calls: list[int] = []

    def failing(x: np.ndarray, seed: int) -> tuple[np.ndarray, None]:
        calls.append(seed)
        if seed == batch_seed(1, 1):  # the second batch of the image seeded 1
            raise ValueError("broken batch")
        return x, None

    with pytest.raises(ValueError, match="broken batch"):
        predict_tiled(np.zeros((100, 100), np.float32), failing, 20, overlap=6, margin=2, batch=1, seed=1, workers=2)
    assert 2 <= len(calls) <= 6  # of 49 batches


def test_batch_seeds_differ_between_images_and_a_small_image_shows_its_progress(capsys):
    """Each batch of tiles of each image draws its own latent samples: no image's k-th batch shares the seed of
    another image's batch (the earlier ``seed * 1_000_003 + k`` gave image 0's batch k the seed of image k's
    first); an image smaller than a tile, padded, still shows its progress bar."""
    seeds = [batch_seed(image, k) for image in range(50) for k in range(40)]
    assert len(set(seeds)) == len(seeds) and batch_seed(7, 0) == 7
    seen: list[int] = []

    def network(x: np.ndarray, seed: int) -> tuple[np.ndarray, None]:
        seen.append(seed)
        return x, None

    predict_tiled(np.zeros((60, 60), np.float32), network, 20, overlap=6, margin=2, batch=4, seed=0)
    predict_tiled(np.zeros((60, 60), np.float32), network, 20, overlap=6, margin=2, batch=4, seed=1)
    assert len(set(seen)) == len(seen) == 8  # 16 tiles in 4 batches, two images
    out, _ = predict_tiled(np.ones((12, 30), np.float32), network, 20, overlap=6, margin=2, progress=True, desc="s")
    assert out.shape == (12, 30) and "s: 100%" in capsys.readouterr().err
