"""eta estimators for scans without ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.core.geometry import get_preset
from nanoct.core.operators import system_matrix
from nanoct.recon.eta import eta_from_reference, eta_from_residual, fit_scale
from nanoct.sim.simulate import SimulationConfig, simulate_sample


@pytest.fixture(scope="module")
def geometry():
    return get_preset("tiny-parallel")


def test_residual_is_zero_on_consistent_data_and_finds_a_bump(geometry):
    x = np.random.default_rng(0).random(geometry.image_shape, dtype=np.float32)
    y = (system_matrix(geometry) @ x.ravel()).reshape(geometry.sino_shape)
    assert np.abs(eta_from_residual(geometry, y, x)).max() < 1e-4
    bumped = y.copy()
    bumped[7, 30:33] += np.array([0.1, -0.4, 0.2], np.float32)
    eta = eta_from_residual(geometry, bumped, x, scale=2.0)
    assert eta[7] == pytest.approx(0.8, rel=1e-4)
    assert np.delete(eta, 7).max() < 1e-4


def test_residual_above_the_matrix_size_needs_no_matrix(geometry, monkeypatch):
    """Where reconstructions trace their rays, the residual builds no matrix either: the same levels."""
    import nanoct.recon.eta as eta_module
    import nanoct.recon.rowaction as rowaction

    x = np.random.default_rng(0).random(geometry.image_shape, dtype=np.float32)
    y = (system_matrix(geometry) @ x.ravel()).reshape(geometry.sino_shape)
    y[3, 20:40] += 0.5
    with_matrix = eta_from_residual(geometry, y, x)
    monkeypatch.setattr(rowaction, "AUTO_MATRIX_BYTES", 0)
    monkeypatch.setattr(eta_module, "system_matrix", lambda *a, **k: pytest.fail("built the matrix"))
    traced = eta_from_residual(geometry, y, x)
    # ASTRA's projection and its cached matrix accumulate in float32 in different orders
    tol = 5e-4 * float(np.abs(y).max())
    np.testing.assert_allclose(traced, with_matrix, rtol=0, atol=tol)
    assert traced[3] == pytest.approx(0.5, abs=tol)


def test_residual_of_the_true_image_tracks_the_true_eta(geometry):
    """On simulated motion data (2x finer simulation grid) the residual of the phantom follows eta."""
    config = SimulationConfig.for_geometry(geometry)
    true, estimate = [], []
    for index in range(3):
        s = simulate_sample(geometry, config, seed=5, index=index)
        true.append(s.eta)
        estimate.append(eta_from_residual(geometry, s.sinogram, s.phantom))
    true, estimate = np.concatenate(true), np.concatenate(estimate)
    assert np.corrcoef(true, estimate)[0, 1] > 0.9
    assert fit_scale(true, estimate) == pytest.approx(1.0, abs=0.3)


def test_reference_statistics():
    etas = np.random.default_rng(1).random((5, 7)).astype(np.float32)
    for stat in ("median", "mean", "max"):
        np.testing.assert_allclose(eta_from_reference(etas, statistic=stat), getattr(np, stat)(etas, axis=0), rtol=1e-6)
    with pytest.raises(NanoctError, match="statistic"):
        eta_from_reference(etas, statistic="mode")
    with pytest.raises(NanoctError, match="no samples"):
        eta_from_reference(np.zeros((0, 7)))


def test_fit_scale():
    t = np.random.default_rng(2).random(50)
    assert fit_scale(t, 2 * t) == pytest.approx(0.5)
    with pytest.raises(NanoctError, match="zero everywhere"):
        fit_scale(t, np.zeros(50))


def test_bad_input(geometry):
    y = np.zeros(geometry.sino_shape, np.float32)
    x = np.zeros(geometry.image_shape, np.float32)
    with pytest.raises(ValueError, match="sinogram has shape"):
        eta_from_residual(geometry, y[:, :-1], x)
    with pytest.raises(NanoctError, match="scale"):
        eta_from_residual(geometry, y, x, scale=-1.0)
    x[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        eta_from_residual(geometry, y, x)
