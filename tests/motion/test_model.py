"""The smooth motion model: exact on its own kind of motion, averages noise, leaves jitter out."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.motion.model import fit_motion_model, motion_basis

K = 900
PHI = np.arange(K) * np.pi / K


def _smooth():
    t = np.linspace(-1, 1, K)
    return 2.0 + 3.0 * t - 1.5 * t**3 + 0.8 * np.cos(2 * PHI) - 0.4 * np.sin(3 * PHI)


def test_recovers_a_motion_of_its_kind():
    model = fit_motion_model(_smooth(), PHI)
    assert np.allclose(model.shifts, _smooth(), atol=1e-9) and model.residual_rms < 1e-9


def test_averages_noisy_estimates():
    noisy = _smooth() + np.random.default_rng(0).normal(0, 0.5, K)
    model = fit_motion_model(noisy, PHI)
    raw = np.sqrt(np.mean((noisy - _smooth()) ** 2))
    fitted = np.sqrt(np.mean((model.shifts - _smooth()) ** 2))
    assert fitted < raw / 5
    assert model.residual_rms == pytest.approx(0.5, rel=0.1)  # the noise is what it leaves out


def test_leaves_jitter_out():
    jitter = np.random.default_rng(1).uniform(-2, 2, K)
    model = fit_motion_model(_smooth() + jitter, PHI)
    assert model.residual_rms == pytest.approx(np.std(jitter), rel=0.1)


def test_basis_and_errors():
    assert motion_basis(PHI, 2, 1).shape == (K, 5)
    with pytest.raises(ValueError, match="lower degree"):
        fit_motion_model(np.zeros(6), PHI[:6], degree=3, harmonics=1)
