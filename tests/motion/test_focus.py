"""Autofocus of the slow horizontal motion: its back projection, its gradients, and a motion recovered."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.core.geometry import Geometry
from nanoct.motion.focus import _back_project, _shift_gradient, focus_smooth, smooth_basis, tv_score
from nanoct.recon.fbp import ramp_filter
from nanoct.recon.stack import corrected_fbp
from scan_cases import analytic_projections, gauge_free_rms, moved


@pytest.mark.parametrize("seed", range(2))
def test_back_projection_is_nanocts_fbp_with_shifts(seed):
    rng = np.random.default_rng(seed)
    k_views, n = 30, 24
    angles = np.arange(k_views) * np.pi / k_views
    center = float(rng.uniform(-2, 2))
    sino = analytic_projections(angles, n, 1, center, seed=seed)[:, 0]
    shifts = rng.uniform(-1.5, 1.5, k_views)
    geometry = Geometry.from_angles(angles, n, n, center_offset=center)
    reference = corrected_fbp(geometry, sino, shifts, filter="hann")
    filtered = ramp_filter(sino, 1.0, "hann")[None] * geometry.angle_weights[None, :, None]
    ours = _back_project(filtered, np.cos(angles), np.sin(angles), shifts, (n - 1) / 2 + center, n)[0]
    grid = np.arange(n) - (n - 1) / 2
    inside = np.hypot(*np.meshgrid(grid, grid, indexing="ij")) < 0.4 * n  # every ray read on the detector
    flips = {"as is": ours, "rows flipped": ours[::-1], "columns flipped": ours[:, ::-1]}
    errors = {name: np.abs(image - reference)[inside].max() for name, image in flips.items()}
    assert min(errors.values()) < 1e-4 * np.abs(reference).max(), errors


def test_gradients_match_finite_differences():
    rng = np.random.default_rng(4)
    filtered = rng.standard_normal((2, 12, 30))
    angles = np.sort(rng.uniform(0, np.pi, 12))
    cos, sin = np.cos(angles), np.sin(angles)
    shifts = rng.uniform(-1, 1, 12)
    weight = rng.standard_normal((2, 16, 16))
    grad = _shift_gradient(filtered, cos, sin, shifts, 14.3, weight)
    for k in (0, 5, 11):
        step = np.zeros(12)
        step[k] = 1e-5
        plus = (weight * _back_project(filtered, cos, sin, shifts + step, 14.3, 16)).sum()
        minus = (weight * _back_project(filtered, cos, sin, shifts - step, 14.3, 16)).sum()
        assert grad[k] == pytest.approx((plus - minus) / 2e-5, rel=1e-4, abs=1e-6)
    images = rng.standard_normal((2, 9, 9))
    mask = rng.uniform(size=(8, 8)) < 0.7
    _, g = tv_score(images, mask, 0.1)
    for index in ((0, 3, 4), (1, 0, 0), (1, 8, 2)):
        step = np.zeros_like(images)
        step[index] = 1e-6
        numeric = (tv_score(images + step, mask, 0.1)[0] - tv_score(images - step, mask, 0.1)[0]) / 2e-6
        assert g[index] == pytest.approx(numeric, rel=1e-5, abs=1e-8)


def test_smooth_basis():
    basis = smooth_basis(10, 3, constant=True)
    assert basis.shape == (10, 4) and np.allclose(basis[:, 0], 1.0)
    assert np.allclose(basis.T @ basis, np.diag([10, 5, 5, 5]))  # the DCT-II cosines are orthogonal


@pytest.mark.slow
def test_focus_recovers_slow_motion_of_a_real_scan_wider_than_the_field_of_view(i13):
    li, angles = i13
    t = np.linspace(-1, 1, angles.size)
    horizontal = 1.5 * np.cos(1.5 * np.pi * t) + 0.8 * np.sin(2.5 * np.pi * t)  # slow over the views
    data = moved(li, horizontal, 0 * horizontal)[:, 76:, 40:120]  # the container's walls cut: no air anywhere
    before = gauge_free_rms(0 * horizontal, horizontal, angles)
    result = focus_smooth(data, angles, 6.2, modes=8)
    error = gauge_free_rms(result.horizontal, horizontal, angles)  # measured 0.05 px
    assert before > 0.8 and error < 0.15 and result.score < result.score_start, (before, error)


def test_focus_that_runs_to_its_bounds_is_not_used():
    rng = np.random.default_rng(0)
    angles = np.arange(90) * np.pi / 90
    start = np.zeros(90)
    noise = rng.normal(0, 1, (90, 8, 26))  # no structure to focus: the score falls far beyond a 0.1 px bound
    result = focus_smooth(noise, angles, 0.0, start, max_shift=0.1)
    assert not result.accepted and np.array_equal(result.horizontal, start) and result.score < result.score_start


def test_focus_bad_input():
    with pytest.raises(NanoctError, match="do not match"):
        focus_smooth(np.zeros((4, 8, 8)), np.zeros(3), 0.0)
