"""Fourier ring correlation: limits, an independent DFT, a known crossing, the half-bit closed form."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.evaluation.frc import frc, frc_resolution, half_bit_threshold, ring_counts


def _direct_frc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """FRC by explicit DFT matrices and a loop over the samples (no np.fft)."""
    n, m = a.shape
    wn = np.exp(-2j * np.pi * np.outer(np.arange(n), np.arange(n)) / n)
    wm = np.exp(-2j * np.pi * np.outer(np.arange(m), np.arange(m)) / m)
    fa, fb = wn @ a @ wm.T, wn @ b @ wm.T
    step = 1.0 / min(n, m)
    rings = int(np.floor(0.5 / step + 0.5)) + 1
    cross, pa, pb = np.zeros(rings), np.zeros(rings), np.zeros(rings)
    for i in range(n):
        for j in range(m):
            fi = i / n if i <= n // 2 else i / n - 1
            fj = j / m if j <= m // 2 else j / m - 1
            r = int(np.floor(np.hypot(fi, fj) / step + 0.5))
            if r < rings:
                cross[r] += (fa[i, j] * np.conj(fb[i, j])).real
                pa[r] += abs(fa[i, j]) ** 2
                pb[r] += abs(fb[i, j]) ** 2
    return cross / np.sqrt(pa * pb)


def test_identical_images_correlate_fully() -> None:
    image = np.random.default_rng(0).normal(size=(64, 64))
    freq, curve = frc(image, image)
    assert freq[0] == 0.0 and freq[-1] == pytest.approx(0.5)
    np.testing.assert_allclose(curve, 1.0, atol=1e-12)


def test_independent_noise_correlates_near_zero() -> None:
    rng = np.random.default_rng(1)
    freq, curve = frc(rng.normal(size=(128, 128)), rng.normal(size=(128, 128)))
    counts = ring_counts((128, 128))
    # each ring's FRC of independent noise has a standard deviation of about 1/sqrt(n)
    assert np.all(np.abs(curve[2:]) < 4.5 / np.sqrt(counts[2:]))
    assert abs(curve[5:].mean()) < 0.02


def test_matches_a_direct_dft_and_is_sign_and_transpose_safe() -> None:
    rng = np.random.default_rng(2)
    a, b = rng.normal(size=(12, 16)), rng.normal(size=(12, 16))
    b = 0.6 * a + b  # correlated, not identical
    _, curve = frc(a, b)
    np.testing.assert_allclose(curve, _direct_frc(a, b), atol=1e-10)
    np.testing.assert_allclose(frc(b, a)[1], curve, atol=1e-12)  # symmetric
    np.testing.assert_allclose(frc(-a, -b)[1], curve, atol=1e-12)  # a common sign drops out
    np.testing.assert_allclose(frc(a, -a)[1], -1.0, atol=1e-12)  # anti-correlated: -1, not +1
    sq_a, sq_b = a[:, :12], b[:, :12]
    np.testing.assert_allclose(frc(sq_a.T, sq_b.T)[1], frc(sq_a, sq_b)[1], atol=1e-12)
    assert frc(a[:, :12], b[:, :12])[1][3] != pytest.approx(frc(a[:, :12], b[:, ::-1][:, :12])[1][3])


def test_band_limited_pair_crosses_where_the_spectra_say() -> None:
    # a = s + n1, b = s + n2 with signal/noise power R(f) = 10 exp(-(f/0.1)^2): FRC = R / (1 + R),
    # which is 1/7 where R = 1/6, at f = 0.1 sqrt(ln 60) = 0.2024 cycles/pixel.
    rng = np.random.default_rng(3)
    shape = (8, 256, 256)
    f = np.hypot(*np.meshgrid(np.fft.fftfreq(256), np.fft.fftfreq(256), indexing="ij"))
    gain = np.sqrt(10.0 * np.exp(-((f / 0.1) ** 2)))
    signal = np.real(np.fft.ifft2(np.fft.fft2(rng.normal(size=shape)) * gain))
    a, b = signal + rng.normal(size=shape), signal + rng.normal(size=shape)
    freq, curve = frc(a, b)
    crossing, period = frc_resolution(freq, curve, "1/7")
    assert crossing == pytest.approx(0.1 * np.sqrt(np.log(60.0)), abs=0.006)
    assert period == pytest.approx(1.0 / crossing)
    counts = 8 * ring_counts((256, 256))
    ratio = 10.0 * np.exp(-((freq / 0.1) ** 2))
    expected, _ = frc_resolution(freq, ratio / (1.0 + ratio), "half-bit", counts=counts)
    half_bit, _ = frc_resolution(freq, curve, "half-bit", counts=counts)
    assert half_bit == pytest.approx(expected, abs=0.006)
    assert half_bit < crossing  # the half-bit curve (-> 0.1716) lies above 1/7 on every ring


def test_half_bit_threshold_matches_its_published_form() -> None:
    n = np.array([1.0, 10.0, 100.0, 1e4, 1e8])
    published = (0.2071 + 1.9102 / np.sqrt(n)) / (1.2071 + 0.9102 / np.sqrt(n))
    np.testing.assert_allclose(half_bit_threshold(n), published, atol=1e-4)
    assert half_bit_threshold([1e12])[0] == pytest.approx((np.sqrt(2) - 1) / 2 / (1 + (np.sqrt(2) - 1) / 2), abs=1e-5)
    assert half_bit_threshold([0])[0] == 1.0


def test_resolution_interpolates_the_crossing_and_says_when_there_is_none() -> None:
    freq = np.linspace(0, 0.5, 11)
    curve = 1.0 - 2.0 * freq  # crosses 1/7 at f = 3/7
    crossing, period = frc_resolution(freq, curve)
    assert crossing == pytest.approx(3.0 / 7.0) and period == pytest.approx(7.0 / 3.0)
    assert frc_resolution(freq, np.ones(11)) == (None, None)
    # default ring counts of the half-bit curve: those of a square image of side 1 / freq[1]
    freq20, _ = frc(np.ones((20, 20)), np.ones((20, 20)))
    assert frc_resolution(freq20, np.full(freq20.size, 0.5), "half-bit") == frc_resolution(
        freq20, np.full(freq20.size, 0.5), "half-bit", counts=ring_counts((20, 20))
    )


def test_bad_input_is_refused() -> None:
    with pytest.raises(NanoctError, match="one shape"):
        frc(np.zeros((4, 4)), np.zeros((4, 5)))
    with pytest.raises(NanoctError, match="NaN"):
        frc(np.full((4, 4), np.nan), np.zeros((4, 4)))
    with pytest.raises(NanoctError, match="mask"):
        frc(np.zeros((4, 4)), np.zeros((4, 4)), mask=np.ones((3, 3)))
    with pytest.raises(NanoctError, match="threshold"):
        frc_resolution([0, 0.5], [1, 0], "fsc")
