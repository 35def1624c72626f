"""Paganin phase retrieval: the closed form of a Gaussian object, Fresnel propagation, and nabu."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.preprocess.phase import paganin, paganin_filter, wavelength_m

ENERGY, DISTANCE, PIXEL, DELTA_BETA = 20.0, 0.05, 1e-6, 100.0


def _gaussian_object(n=128, width_px=8.0, peak=0.5):
    """``mu T`` of a Gaussian thickness and the TIE intensity at DISTANCE, both in closed form.

    With ``g = exp(-mu T)``: ``I = g - (z delta / mu) laplacian(g)``, ``laplacian(g) = g (mu^2
    |grad T|^2 - mu laplacian(T))``, and for ``mu T = peak exp(-r^2 / (2 s^2))``: ``mu |grad T| =
    mu T r / s^2``, ``mu laplacian(T) = mu T (r^2 / s^2 - 2) / s^2``; ``z delta / mu = z (delta / beta)
    lambda / (4 pi)``.
    """
    s = width_px * PIXEL
    y, x = (np.mgrid[0:n, 0:n] - (n - 1) / 2) * PIXEL
    r2 = x**2 + y**2
    mut = peak * np.exp(-r2 / (2 * s**2))
    g = np.exp(-mut)
    lap_g = g * ((mut**2) * r2 / s**4 - mut * (r2 / s**2 - 2) / s**2)
    coeff = DISTANCE * DELTA_BETA * wavelength_m(ENERGY) / (4 * np.pi)
    return mut, g - coeff * lap_g


def _retrieve(intensity, delta_beta=DELTA_BETA):
    out = paganin(intensity[None], delta_beta=delta_beta, energy_kev=ENERGY, distance_m=DISTANCE, pixel_size_m=PIXEL)
    return -np.log(out[0].astype(np.float64))


def test_inverts_the_tie_forward_model_in_closed_form():
    mut, intensity = _gaussian_object()
    assert np.abs(-np.log(intensity) - mut).max() > 0.1  # the phase contrast is strong
    error = np.abs(_retrieve(intensity) - mut).max()
    assert error < 1e-4 * mut.max()  # measured 8e-8: the filter is the exact inverse
    # a factor 2 off in delta/beta (or in the filter's constant) is caught
    assert np.abs(_retrieve(intensity, 2 * DELTA_BETA) - mut).max() > 0.1 * mut.max()


def test_recovers_a_fresnel_propagated_weak_object():
    """Near-field Fresnel propagation of the wave ``exp(-mu T / 2 - i k delta T)``, an independent forward model."""
    n = 256
    mut, _ = _gaussian_object(n=n, width_px=10.0, peak=0.2)
    lam = wavelength_m(ENERGY)
    beta_t = mut * lam / (4 * np.pi)  # beta T from mu T
    wave = np.exp(-2 * np.pi / lam * (beta_t + 1j * DELTA_BETA * beta_t))
    f2 = np.fft.fftfreq(n, PIXEL)[:, None] ** 2 + np.fft.fftfreq(n, PIXEL)[None, :] ** 2
    propagated = np.fft.ifft2(np.fft.fft2(wave) * np.exp(-1j * np.pi * lam * DISTANCE * f2))
    intensity = np.abs(propagated) ** 2
    assert np.abs(-np.log(intensity) - mut).max() > 0.05
    assert np.abs(_retrieve(intensity) - mut).max() < 0.02 * mut.max()  # measured 1 %
    for wrong in (DELTA_BETA / 2, 2 * DELTA_BETA):  # measured 17 % and 22 %
        assert np.abs(_retrieve(intensity, wrong) - mut).max() > 0.1 * mut.max()


def test_matches_nabu():
    phase = pytest.importorskip("nabu.preproc.phase")
    rng = np.random.default_rng(2)
    radio = 1 + 0.1 * rng.standard_normal((48, 64))  # 2 x 48 and 2 x 64 are fast lengths for both
    params = {"delta_beta": 250.0, "energy_kev": 17.5, "distance_m": 0.3}
    ours = paganin(radio[None], pixel_size_m=0.65e-6, **params)[0]
    nabu = phase.PaganinPhaseRetrieval(
        radio.shape, distance=params["distance_m"], energy=params["energy_kev"],
        delta_beta=params["delta_beta"], pixel_size=0.65e-6, padding="edge",
    ).apply_filter(radio)  # fmt: skip
    np.testing.assert_allclose(ours, nabu, rtol=1e-5, atol=1e-6)


def test_filter_values_and_bad_parameters():
    # 12.39841984 keV: a wavelength of 1 angstrom
    filt = paganin_filter((4, 8), delta_beta=10.0, energy_kev=12.39841984, distance_m=1.0, pixel_size_m=1e-6)
    assert filt.shape == (4, 5) and filt[0, 0] == 1.0
    f = 1 / 8e-6  # the first column frequency, cycles per metre
    assert filt[0, 1] == pytest.approx(1 / (1 + np.pi * 1e-10 * 1.0 * 10.0 * f**2), rel=1e-6)
    with pytest.raises(NanoctError, match="--energy-kev"):
        paganin(np.ones((1, 4, 4)), delta_beta=1.0, energy_kev=0.0, distance_m=1.0, pixel_size_m=1e-6)
    with pytest.raises(NanoctError, match="finite"):
        paganin(np.full((1, 4, 4), np.nan), delta_beta=1.0, energy_kev=1.0, distance_m=1.0, pixel_size_m=1e-6)
