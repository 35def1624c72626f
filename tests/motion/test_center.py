"""Axis offset from opposite views, and its separation from the motion."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.motion.center import (
    centroid_motion,
    fit_center,
    fourier_shift,
    opposite_pairs,
    separate_center,
    xcorr_shifts,
)
from nanoct.sim.analytic import ellipse_sinogram, stack_phantom

L, K = 256, 360


def _scan(offset, shifts=None, k=K, full=np.pi):
    angles = np.arange(k) * full / k
    slices = stack_phantom(200, 2, seed=3)
    sino = np.stack([ellipse_sinogram(e, angles, L, shifts=shifts, center_offset=offset, subsamples=2) for e in slices])
    return sino, angles


def test_xcorr_shifts_sub_pixel_and_sign():
    x = np.arange(300.0)
    b = np.exp(-(((x - 140) / 9) ** 2))[None].repeat(3, 0) + np.exp(-(((x - 170) / 3) ** 2))
    true = np.array([2.37, -5.81, 0.0])
    a = fourier_shift(b, true)
    assert xcorr_shifts(a, b) == pytest.approx(true, abs=1e-3)
    assert xcorr_shifts(a, b, max_shift=3)[1] == pytest.approx(-3, abs=1.01)  # window respected


@pytest.mark.parametrize("full", [np.pi, 2 * np.pi])
@pytest.mark.parametrize("offset", [0.0, 3.3, -7.62])
def test_known_offset_without_motion(offset, full):
    sino, angles = _scan(offset, full=full)
    assert fit_center(sino, angles) == pytest.approx(offset, abs=0.05)


def test_known_offset_with_known_motion():
    d = np.random.default_rng(0).uniform(-4, 4, K)
    sino, angles = _scan(2.4, shifts=d)
    assert abs(fit_center(sino, angles) - 2.4) > 0.3  # the motion at the paired views biases the raw fit
    assert fit_center(sino, angles, shifts=d) == pytest.approx(2.4, abs=0.05)


def test_pairs_of_a_half_and_a_full_turn():
    k, j, _ = opposite_pairs(np.arange(8) * np.pi / 8)
    assert {(int(a), int(b)) for a, b in zip(k, j)} == {(0, 7), (7, 0)}
    k, j, mismatch = opposite_pairs(np.arange(8) * np.pi / 4)
    assert np.array_equal(j, (k + 4) % 8) and np.allclose(mismatch, 0)
    with pytest.raises(NanoctError, match="center-offset"):
        fit_center(np.zeros((4, 16)), np.linspace(0, 1, 4))


def test_separate_center_keeps_the_views_and_removes_the_constant():
    phi = np.arange(K) * np.pi / K
    d = 1.5 + 0.8 * np.cos(2 * phi) + 0.3 * np.sin(phi)
    c, d2 = separate_center(2.0, d, phi)
    assert np.allclose(-c + d2, -2.0 + d)
    basis = np.stack([np.ones(K), np.cos(phi), np.sin(phi)], 1)
    assert np.linalg.lstsq(basis, d2, rcond=None)[0][0] == pytest.approx(0, abs=1e-12)


def test_centroids_give_axis_and_shifts_and_flag_a_truncated_object():
    d = np.random.default_rng(2).uniform(-3, 3, K)
    sino, angles = _scan(4.1, shifts=d)
    center, shifts, spread = centroid_motion(sino, angles)
    basis = np.stack([np.ones(K), np.cos(angles), np.sin(angles)], axis=1)
    coef = np.linalg.lstsq(basis, d, rcond=None)[0]
    assert spread < 1e-3 and center == pytest.approx(4.1 - coef[0], abs=0.01)
    assert np.abs(shifts - (d - basis @ coef)).max() < 0.02
    # an object wider than the detector in some views: its mass changes from view to view
    assert centroid_motion(sino[..., 60:200], angles)[2] > 0.01
