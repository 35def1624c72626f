"""Projection matching: the own-view term, edge extension, vertical moves, and motion recovered without air."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.core.geometry import Geometry
from nanoct.motion.matching import _own_views, _static_projections, apply_vertical, extend_edges, match_projections
from nanoct.recon.fbp import ramp_filter
from nanoct.recon.stack import corrected_fbp, reproject
from scan_cases import analytic_projections, gauge_free_rms, moved


@pytest.mark.parametrize("seed", range(3))
def test_own_view_term_is_the_view_back_projected_alone_and_reprojected(seed):
    rng = np.random.default_rng(seed)
    k_views, n = int(rng.integers(5, 12)), int(rng.integers(16, 33))
    angles = np.sort(rng.uniform(0, np.pi, k_views))
    geometry = Geometry.from_angles(angles, n, n, center_offset=float(rng.uniform(-2, 2)))
    sino = rng.standard_normal((k_views, n))
    shifts = rng.uniform(-1.5, 1.5, k_views)
    filtered = np.zeros((k_views, n + 3))
    filtered[:, 1:-2] = ramp_filter(sino, 1.0, "ram-lak") * geometry.angle_weights[:, None]
    centre = (n - 1) / 2 + geometry.center_offset
    own = _own_views(filtered, np.cos(angles), np.sin(angles), shifts, n, centre, 1.0)
    for k in range(k_views):  # the direct way: FBP of view k alone, reprojected at its angle
        alone = np.zeros_like(sino)
        alone[k] = sino[k]
        direct = reproject(geometry, corrected_fbp(geometry, alone, shifts))[k]
        assert np.allclose(own[k], direct, atol=1e-4 * np.abs(direct).max())


def test_static_model_leaves_every_view_out():
    angles = np.arange(24) * np.pi / 24
    proj = analytic_projections(angles, 32, 2, 0.0)
    geometry = Geometry.from_angles(angles, 48, 48)
    model = _static_projections(proj, geometry, np.zeros(24), 8, "ram-lak")
    k = 5  # changing view k changes every model view but its own
    changed = proj.copy()
    changed[k] += np.random.default_rng(0).standard_normal(changed[k].shape)
    other = _static_projections(changed, geometry, np.zeros(24), 8, "ram-lak")
    diff = np.abs(other - model).max(axis=(1, 2))
    assert diff[k] < 1e-4 * diff.max() and (np.delete(diff, k) > 0).all()


def test_extend_edges_and_apply_vertical():
    sino = np.arange(12, dtype=np.float64).reshape(2, 6) + 1
    ext = extend_edges(sino, 3)
    assert ext.shape == (2, 12) and np.array_equal(ext[:, 3:9], sino)
    assert ext[0, 2] == pytest.approx(sino[0, 0], rel=0.2) and 0 < ext[0, 0] < ext[0, 1] < ext[0, 2]
    proj = np.zeros((1, 9, 4), dtype=np.float32)
    proj[0, 4] = 1
    up = apply_vertical(proj, np.array([2.0]))  # out(z) = m(z - v): row 4 moves to row 6
    assert up[0, 6].mean() == pytest.approx(1.0, abs=1e-3) and np.abs(up[0, 4]).max() < 1e-3


def test_matching_recovers_motion_of_an_object_wider_than_the_detector():
    angles = np.arange(90) * np.pi / 90
    proj = analytic_projections(angles, 96, 12, 1.5)[:, :, 16:-16]  # 64 columns: no air at the edges
    rng = np.random.default_rng(3)
    horizontal = rng.standard_normal(angles.size) + 0.8 * np.cos(2 * angles)  # 1.1 px RMS beyond the gauge
    vertical = 0.3 * rng.standard_normal(angles.size)
    result = match_projections(moved(proj, horizontal, vertical), angles, 1.5, schedule=(2, 1), vertical=vertical)
    error = gauge_free_rms(result.horizontal, horizontal, angles)  # measured 0.26 px
    assert error < 0.4 and error < 0.35 * gauge_free_rms(0 * horizontal, horizontal, angles)


def test_matching_of_a_few_rows_binned_to_one():
    """Four rows binned by four leave one row: no vertical shift to register (it once raised numpy's gradient
    error from nanoct stack on a four-slice store), the horizontal motion is still recovered."""
    angles = np.arange(90) * np.pi / 90
    proj = analytic_projections(angles, 96, 4, 1.5)[:, :, 16:-16]
    horizontal = np.random.default_rng(4).standard_normal(angles.size)
    result = match_projections(moved(proj, horizontal, 0 * horizontal), angles, 1.5, schedule=(4, 2, 1))
    assert np.all(np.isfinite(result.horizontal)) and np.all(np.isfinite(result.vertical))
    error = gauge_free_rms(result.horizontal, horizontal, angles)
    assert error < 0.5 * gauge_free_rms(0 * horizontal, horizontal, angles)


def test_matching_bad_input():
    with pytest.raises(NanoctError, match="views, rows, columns"):
        match_projections(np.zeros((4, 8)), np.zeros(4), 0.0)
    with pytest.raises(NanoctError, match="angles"):
        match_projections(np.zeros((4, 8, 8)), np.zeros(3), 0.0)
