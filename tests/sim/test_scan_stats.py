"""Binning, axis, noise and motion statistics of a measured scan, against direct computations."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.core.geometry import Geometry
from nanoct.io.rawscan import axis_after
from nanoct.sim.analytic import Ellipse, ellipse_sinogram
from nanoct.sim.scan_stats import air_noise, bin_sinograms, binned_geometry, binned_offset, motion_stats


def test_binning_averages_columns_and_slices(rng):
    x = rng.normal(size=(5, 3, 8))
    got = bin_sinograms(x, 2)
    direct = np.array([[[x[2 * s : 2 * s + 2, k, 2 * c : 2 * c + 2].mean() for c in range(4)] for k in range(3)]
                       for s in range(2)])  # fmt: skip
    np.testing.assert_allclose(got, direct, rtol=1e-6)  # the fifth slice, alone in its group, is left out
    one = bin_sinograms(x[:1], 2)  # fewer slices than the binning: columns only
    np.testing.assert_allclose(one[0], x[0].reshape(3, 4, 2).mean(axis=2), rtol=1e-6)
    np.testing.assert_array_equal(bin_sinograms(x, 1), x.astype(np.float32))


@pytest.mark.parametrize(("offset", "binning"), [(0.0, 2), (6.16, 2), (-3.3, 4), (2.5, 5)])
def test_binned_offset_follows_the_axis_seen_on_the_detector(offset, binning):
    n_det = 80
    assert binned_offset(offset, n_det, binning) == pytest.approx(axis_after(offset, n_det, None, binning))
    # a disc on the axis projects to the axis column in every view: its centroid after binning
    sino = ellipse_sinogram([Ellipse(0, 0, 10.0, 10.0, 0, 1.0)], np.linspace(0, 3, 7), n_det,
                            center_offset=offset, subsamples=16)  # fmt: skip
    binned = bin_sinograms(sino[None], binning)[0]
    columns = np.arange(binned.shape[1])
    centroid = (binned * columns).sum(axis=1) / binned.sum(axis=1)
    np.testing.assert_allclose(centroid - (binned.shape[1] - 1) / 2, binned_offset(offset, n_det, binning), atol=0.02)


def test_binned_geometry_keeps_the_views_and_refuses_a_binning_that_does_not_divide():
    g = Geometry.from_angles(np.linspace(-1.5, 1.6, 20), 60, 60, center_offset=2.0)
    b = binned_geometry(g, 3, 2.0)
    np.testing.assert_array_equal(b.angles, g.angles)
    assert (b.n, b.n_det, b.center_offset) == (20, 20, pytest.approx(binned_offset(2.0, 60, 3)))
    with pytest.raises(NanoctError, match=r"--bin 7 does not divide the scan.s detector width 60; .*--binning 7"):
        binned_geometry(g, 7, 2.0)
    with pytest.raises(NanoctError, match="--bin 0 must be a whole number"):
        binned_geometry(g, 0, 2.0)


@pytest.mark.parametrize("sigma", [0.003, 0.05])
def test_air_noise_recovers_a_known_sigma_under_an_open_beam_with_a_slope(sigma, rng):
    angles = np.linspace(0, np.pi, 60, endpoint=False)
    clean = ellipse_sinogram([Ellipse(0, 0, 14, 10, 0.2, 0.2)], angles, 64)
    level = 0.4 + 0.02 * np.linspace(-1, 1, 64)[None, :] + 0.01 * np.cos(angles)[:, None]
    sinos = np.stack([clean + level + rng.normal(0, sigma, clean.shape) for _ in range(4)])
    found = air_noise(sinos)
    assert found["sigma"] == pytest.approx(sigma, rel=0.07)
    assert found["band_px"] == 6 and found["air_level"] == pytest.approx(0.4, abs=0.02)


def test_air_noise_refuses_a_detector_too_narrow():
    with pytest.raises(NanoctError, match="too narrow"):
        air_noise(np.zeros((1, 5, 4)))


def test_motion_stats_split_a_smooth_motion_from_its_jitter(rng):
    k = 400
    t = np.arange(k) / k
    smooth = 0.8 * np.sin(2 * np.pi * 2 * t) + 0.3
    jitter = 0.1
    stats = motion_stats(smooth + rng.normal(0, jitter, k))
    assert stats["amplitude"] == pytest.approx(0.8, rel=0.1)
    assert stats["jitter"] == pytest.approx(jitter, rel=0.12)
    assert motion_stats(smooth)["jitter"] < 0.01  # a smooth motion has (nearly) no jitter
    with pytest.raises(NanoctError, match="non-finite"):
        motion_stats(np.array([0.0, np.nan, 1.0]))
