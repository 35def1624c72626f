"""Dremel: cross-correlation shift estimator, shift recovery under translation, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.geometry import get_preset
from nanoct.core.operators import RayTransform
from nanoct.recon.dremel import dremel, shift_cross_corr
from nanoct.sim.motion import MotionParams, sample_motion
from nanoct.sim.phantoms import downsample, random_phantom


def signal(n, shift):
    """Smooth non-symmetric test projection, moved by ``shift`` samples to larger indices."""
    t = np.arange(n) - shift
    return (
        np.exp(-(((t - 0.45 * n) / 6.0) ** 2))
        + 0.6 * np.exp(-(((t - 0.3 * n) / 3.0) ** 2))
        + 0.3 * (np.tanh(t - 0.6 * n) - np.tanh(t - 0.7 * n))
    )


@pytest.mark.parametrize("f_sr", [2, 4])
@pytest.mark.parametrize("shift", [0.0, 0.3, -0.75, 1.6, -2.45, 5.2, -11.9])
def test_shift_estimator_recovers_subpixel_shifts(f_sr, shift):
    z = signal(91, 0.0)
    y = signal(91, -shift)  # y[n] = z[n + shift]
    est = shift_cross_corr(z, y, f_sr=f_sr)
    assert abs(est - shift) <= 1.0 / f_sr
    assert abs(est * f_sr - round(est * f_sr)) < 1e-12  # quantised to 1 / f_sr
    assert abs(shift_cross_corr(z, y, f_sr=f_sr, subpixel=True) - shift) <= 1.0 / f_sr


def test_shift_estimator_sign_matches_geometry():
    """Object shift t moves the parallel projection: p_moved(s) = p(s + t . e_u)."""
    g = get_preset("tiny-parallel")
    x = random_phantom(np.random.default_rng(3), g.n)
    t = np.array([1.5, -0.5])
    motion = np.zeros((g.n_angles, 3))
    motion[:, :2] = t
    y0, y1 = RayTransform(g).forward(x), RayTransform(g, motion).forward(x)
    tu = t[0] * np.cos(g.angles) + t[1] * np.sin(g.angles)
    est = np.array([shift_cross_corr(y0[k], y1[k]) for k in range(g.n_angles)])
    # discretisation of the projector: not exactly a rigid shift on the detector
    assert np.abs(est - tu).max() <= 0.75
    assert np.sqrt(np.mean((est - tu) ** 2)) < 0.25


def test_shift_estimator_bad_input():
    with pytest.raises(ValueError, match="same length"):
        shift_cross_corr(np.ones(5), np.ones(6))
    with pytest.raises(ValueError, match="f_sr"):
        shift_cross_corr(np.ones(5), np.ones(5), f_sr=0)
    with pytest.raises(ValueError, match="z"):
        shift_cross_corr(np.array([1.0, np.nan]), np.ones(2))


def translated(name, seed):
    g = get_preset(name)
    rng = np.random.default_rng(seed)
    fine = random_phantom(rng, g.n, oversample=2)
    motion = sample_motion(rng, g.n_angles, MotionParams.for_kind(g.kind))
    motion[:, 2] = 0.0  # translation only
    y = RayTransform(g, motion, oversample=2).forward(fine)
    true = motion[:, 0] * np.cos(g.angles) + motion[:, 1] * np.sin(g.angles)
    return g, downsample(fine, 2), y, true


def gauge_free(est, true, phi):
    """Remove the global translation ``a cos(phi) + b sin(phi)`` of the error.

    A common translation of all views can be absorbed by translating the image: the data do
    not determine it, so shift estimates are compared up to it (as images are compared up to
    registration)."""
    basis = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    coef, *_ = np.linalg.lstsq(basis, est - true, rcond=None)
    return est - basis @ coef


@pytest.mark.slow
def test_recovers_translations_parallel():
    corr, corr_fixed = [], []
    for seed in range(11, 17):
        g, gt, y, true = translated("tiny-parallel", seed)
        res = dremel(g, y)
        assert res.motion.shape == (g.n_angles,) and res.motion.dtype == np.float32
        assert res.stop_reason == "max_iter" and res.iterations == 32
        assert np.sqrt(np.mean((res.motion - true) ** 2)) < 0.5
        corr.append(np.corrcoef(res.motion, true)[0, 1])
        corr_fixed.append(np.corrcoef(gauge_free(res.motion, true, g.angles), true)[0, 1])
    assert np.median(corr) >= 0.9 and min(corr) >= 0.8
    assert min(corr_fixed) >= 0.9


def test_correction_improves_image(psnr):
    g, gt, y, true = translated("tiny-parallel", 11)
    res = dremel(g, y)
    # the same view steps without correction (shifts stay 0)
    plain = dremel(g, y, correction_start=32)
    assert np.abs(plain.motion).max() == 0
    assert psnr(res.image, gt) > psnr(plain.image, gt) + 1.0


def test_fan_beam(psnr):
    g, gt, y, true = translated("tiny-fan", 13)
    res = dremel(g, y)
    plain = dremel(g, y, correction_start=32)
    assert np.corrcoef(res.motion, true)[0, 1] >= 0.7
    assert psnr(res.image, gt) > psnr(plain.image, gt)


@pytest.mark.parametrize("name", ["tiny-parallel", "tiny-fan"])
def test_consistent_data(name, consistent, psnr):
    g, x, y = consistent(name, seed=8)
    res = dremel(g, y, residual="exact")
    r = np.asarray(res.residuals)
    assert r[-1] < 0.1 * r[0]
    assert np.abs(res.motion).max() <= 0.5
    assert psnr(res.image, x) > 25
    # with correction disabled it is plain (SART-normalised) block Kaczmarz and converges
    nocorr = dremel(g, y, correction_start=32, residual="exact", n_iter=20)
    assert np.all(np.diff(nocorr.residuals) <= 1e-3 * nocorr.residuals[0])


def test_running_residual_and_callback():
    g, gt, y, true = translated("tiny-parallel", 11)
    seen = []
    res = dremel(g, y, n_iter=5, callback=lambda i, x, s: seen.append(s.copy()) or i == 2)
    assert res.stop_reason == "callback" and res.iterations == 3 and len(seen) == 3
    assert np.all(np.isfinite(res.residuals))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(relaxation=0.0), "relaxation"),
        (dict(relaxation=2.5), "relaxation"),
        (dict(shift_relaxation=0.0), "shift_relaxation"),
        (dict(shift_relaxation=1.5), "shift_relaxation"),
        (dict(n_iter=0), "n_iter"),
        (dict(correction_start=-1), "correction_start"),
        (dict(f_sr=0), "f_sr"),
        (dict(order="zigzag"), "order"),
        (dict(shifts0=np.zeros(3)), "shifts0"),
    ],
)
def test_bad_parameters(kwargs, match):
    g = get_preset("tiny-parallel")
    y = np.zeros(g.sino_shape, np.float32)
    with pytest.raises(ValueError, match=match):
        dremel(g, y, **kwargs)


def test_bad_sinogram():
    g = get_preset("tiny-parallel")
    y = np.zeros(g.sino_shape, np.float32)
    y[1, 1] = np.inf
    with pytest.raises(ValueError, match="sino"):
        dremel(g, y)
    with pytest.raises(ValueError, match="sino"):
        dremel(g, np.zeros((g.n_angles + 1, g.n_det)))


def _numba_shift(z, y, f_sr, weighting="additive", subpixel=False):
    """The compiled estimator used inside :func:`dremel` (up-sampling + direct lag correlation)."""
    from nanoct.recon.dremel import WEIGHTINGS, _upsample_centre, _xcorr_shift

    n_sr = f_sr * z.size
    zc, yc, work = np.empty(n_sr), np.empty(n_sr), np.empty(n_sr)
    zm = _upsample_centre(np.asarray(z, np.float64), f_sr, zc)
    ym = _upsample_centre(np.asarray(y, np.float64), f_sr, yc)
    return _xcorr_shift(zc, zm, yc, ym, f_sr, WEIGHTINGS.index(weighting), subpixel, work)


def test_upsampling_matches_numpy_interp():
    from nanoct.recon.dremel import _upsample_centre

    rng = np.random.default_rng(0)
    for n, f_sr in [(2, 1), (7, 2), (91, 3), (363, 2), (50, 4)]:
        s = rng.normal(size=n)
        out = np.empty(f_sr * n)
        mean = _upsample_centre(s, f_sr, out)
        up = np.interp(np.arange(f_sr * n) / f_sr, np.arange(n, dtype=np.float64), s)
        np.testing.assert_allclose(out + mean, up, rtol=0, atol=1e-12)
        assert abs(mean - up.mean()) <= 1e-12


@pytest.mark.parametrize("weighting", ["additive", "overlap", "none"])
def test_numba_correlation_matches_numpy_argmax(weighting):
    """The direct lag-window correlation in numba picks the same lag as the FFT version."""
    rng = np.random.default_rng(123)
    checked = 0
    for trial in range(300):
        n = int(rng.choice([5, 16, 91, 180, 363]))
        f_sr = int(rng.choice([1, 2, 2, 3]))
        kind = trial % 3
        if kind == 0:  # white noise
            z, y = rng.normal(size=n), rng.normal(size=n)
        elif kind == 1:  # projection-like: a shifted, rescaled and noisy copy
            z = np.clip(signal(n, 0.0) + 0.1 * rng.normal(size=n), 0, None)
            y = np.clip(signal(n, rng.uniform(-0.2, 0.2) * n) * rng.uniform(0.8, 1.2), 0, None)
        else:  # positive with a baseline (large means: the bias terms matter)
            z, y = rng.uniform(0.5, 1.5, n), rng.uniform(0.5, 1.5, n)
        ref = shift_cross_corr(z, y, f_sr=f_sr, weighting=weighting)
        assert _numba_shift(z, y, f_sr, weighting) == ref
        ref_sub = shift_cross_corr(z, y, f_sr=f_sr, weighting=weighting, subpixel=True)
        assert abs(_numba_shift(z, y, f_sr, weighting, True) - ref_sub) <= 1e-9 * max(1.0, abs(ref_sub))
        checked += 1
    assert checked == 300


def test_numba_correlation_zero_signal_matches_numpy():
    """A zero model projection (first view from the empty start image) gives the same lag."""
    y = signal(91, 0.0)
    for f_sr in (1, 2):
        assert _numba_shift(np.zeros(91), y, f_sr) == shift_cross_corr(np.zeros(91), y, f_sr=f_sr)
    assert shift_cross_corr(np.zeros(91), y) == 0.0  # no evidence of a shift: none is applied


def test_first_view_from_empty_image_gets_no_spurious_shift():
    g, gt, y, true = translated("tiny-parallel", 11)
    res = dremel(g, y, n_iter=1, order="sequential")
    assert res.motion[0] == 0.0  # view 0 sees an empty model: an arg-max over a flat correlation gave -45 px
    assert np.abs(res.motion[1:]).max() > 0
