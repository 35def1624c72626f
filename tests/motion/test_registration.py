"""Batched sub-pixel 2-D registration: known shifts of band-limited images, sign and tapering."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.ndimage as ndi

from nanoct.motion.registration import register_shifts, taper_window


def _pairs(shifts, seed=0):
    """Crops of a smooth random field and of the same field moved by ``shifts`` (``b(y) = a(y + s)``)."""
    rng = np.random.default_rng(seed)
    big = ndi.gaussian_filter(rng.standard_normal((len(shifts), 128, 160)), (0, 2, 2))
    spectra = np.fft.fft2(big)
    moved = np.stack([np.fft.ifft2(ndi.fourier_shift(f, -s)).real for f, s in zip(spectra, shifts)])
    return big[:, 32:96, 40:120], moved[:, 32:96, 40:120]


def test_known_shifts_recovered_with_their_sign():
    shifts = np.random.default_rng(1).uniform(-2.5, 2.5, (12, 2))
    a, b = _pairs(shifts)
    found = register_shifts(a, b, sigma=0, margin=(16, 16))
    assert np.sqrt(np.mean((found - shifts) ** 2)) < 0.05
    assert np.sqrt(np.mean((register_shifts(b, a, sigma=0, margin=(16, 16)) + shifts) ** 2)) < 0.05


def test_a_smooth_background_does_not_pull_the_lag():
    shifts = np.array([[0.7, -1.3], [-0.4, 2.2]])
    a, b = _pairs(shifts, seed=3)
    background = 3 * a.std() * np.linspace(0, 1, a.shape[2])[None, None, :]  # a tilted open beam in both
    found = register_shifts(a + background, b + background, sigma=4, margin=(16, 16))
    assert np.abs(found - shifts).max() < 0.1


def test_taper_window_and_bad_input():
    w = taper_window((20, 30), (4, 6))
    assert w.shape == (20, 30) and w[10, 15] == 1 and w[0, 0] < 0.05 and np.allclose(w, w[::-1, ::-1])
    with pytest.raises(ValueError, match="same shape"):
        register_shifts(np.zeros((2, 8, 8)), np.zeros((2, 8, 9)))
