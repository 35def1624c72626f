"""A motion carried by the model of RESESOP and its eta estimate; Dremel's measured-data peak refinement."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from nanoct.core.geometry import Geometry, get_preset
from nanoct.core.operators import system_matrix
from nanoct.recon.dremel import dremel
from nanoct.recon.eta import eta_from_residual
from nanoct.recon.measured import read_moved
from nanoct.recon.resesop import resesop
from nanoct.sim.simulate import SimulationConfig, simulate_sample

N = 40
ANGLES = np.linspace(0, np.pi, 48, endpoint=False)


def _phantom() -> np.ndarray:
    yy, xx = np.mgrid[:N, :N] - (N - 1) / 2
    img = (np.hypot(yy, xx) <= 10).astype(np.float32) * 0.5
    img[np.hypot(yy - 3, xx + 2) <= 4] = 1.0
    return img


def _psnr(x: np.ndarray, gt: np.ndarray) -> float:
    return float(10 * np.log10((gt.max() - gt.min()) ** 2 / np.mean((x - gt) ** 2)))


@pytest.fixture(scope="module")
def moved_scan():
    """The phantom's sinogram and the sinogram of the phantom moved by an integer shift per view (exact)."""
    g = Geometry.from_angles(ANGLES, N, N)
    x = _phantom()
    clean = (system_matrix(g) @ x.ravel()).reshape(g.sino_shape).astype(np.float32)
    d = np.round(3 * np.sin(np.linspace(0, 2 * np.pi, ANGLES.size))).astype(int)
    # p_k(u) = P_k(u + d_k): the object moved by d_k along e_u (its projection is zero near the edges)
    moved = np.stack([np.roll(view, -dk) for view, dk in zip(clean, d)])
    assert np.abs(clean[:, :6]).max() == 0 and np.abs(clean[:, -6:]).max() == 0
    return g, x, clean, moved, d.astype(np.float64)


def test_read_moved_is_a_linear_shift_holding_the_edges() -> None:
    rng = np.random.default_rng(0)
    sino = rng.normal(size=(5, 17)) + 2.0
    d = np.array([0.0, 1.0, -2.5, 0.3, 7.75])
    expected = np.stack([ndimage.shift(v, dk, order=1, mode="nearest") for v, dk in zip(sino, d)])
    np.testing.assert_allclose(read_moved(sino, d), expected, atol=1e-12)
    np.testing.assert_array_equal(read_moved(sino, np.zeros(5)), sino)
    with pytest.raises(ValueError, match="shifts"):
        read_moved(sino, np.zeros(4))


def test_the_fourier_read_keeps_the_noise_where_the_linear_one_halves_it() -> None:
    """A band-limited shift is all-pass: white noise keeps its variance at a half-pixel shift (the linear read
    keeps (1 - f)^2 + f^2 = 1/2 of it); whole-pixel shifts equal the linear read away from the ends; a smooth
    view moves by d_k to the right, as the linear read moves it (independent check: the shifted Gaussian)."""
    rng = np.random.default_rng(1)
    noise = rng.normal(size=(400, 64))
    half = np.full(400, 0.5)
    inner = slice(8, 56)
    assert read_moved(noise, half)[:, inner].var() == pytest.approx(0.5, abs=0.03)
    assert read_moved(noise, half, "fourier")[:, inner].var() == pytest.approx(1.0, abs=0.03)
    whole = rng.integers(-3, 4, size=400).astype(np.float64)
    np.testing.assert_allclose(read_moved(noise, whole, "fourier")[:, inner], read_moved(noise, whole)[:, inner],
                               atol=1e-9)  # fmt: skip
    u = np.arange(64.0)
    d = np.array([0.3, -1.7, 2.45])
    views = np.exp(-((u - 30.0) ** 2) / 40.0)[None].repeat(3, axis=0) + 0.37  # on an open beam of 0.37
    expected = np.exp(-((u[None] - d[:, None] - 30.0) ** 2) / 40.0) + 0.37
    np.testing.assert_allclose(read_moved(views, d, "fourier"), expected, atol=1e-6)
    with pytest.raises(ValueError, match="interpolation='cubic' is unknown"):
        read_moved(views, d, "cubic")


def test_resesop_with_the_motion_is_resesop_on_the_unmoved_data(moved_scan) -> None:
    g, x, clean, moved, d = moved_scan
    eta = np.full(g.n_angles, 0.02)
    unmoved = resesop(g, clean, eta, n_iter=6)
    carried = resesop(g, moved, eta, n_iter=6, shifts=d)
    np.testing.assert_allclose(carried.image, unmoved.image, atol=1e-6)
    wrong_sign = resesop(g, moved, eta, n_iter=6, shifts=-d)
    plain = resesop(g, moved, eta, n_iter=6)
    assert _psnr(carried.image, x) > _psnr(plain.image, x) + 5.0
    assert _psnr(carried.image, x) > _psnr(wrong_sign.image, x) + 5.0


def test_eta_after_the_motion_is_the_error_left(moved_scan) -> None:
    g, x, _, moved, d = moved_scan
    after = eta_from_residual(g, moved, x, shifts=d)
    before = eta_from_residual(g, moved, x)
    assert after.max() < 1e-4  # the true image with the true motion: nothing left
    assert before.max() > 1.0
    # Dremel's motion is in the convention of ``shifts``: its eta is far below the unmoved model's
    est = dremel(g, moved, n_iter=16)
    assert np.median(eta_from_residual(g, moved, est.image, shifts=est.motion)) < 0.5 * np.median(
        eta_from_residual(g, moved, est.image)
    )


def test_dremel_refines_its_peak_on_measured_data_only(moved_scan) -> None:
    g, _, _, moved, _ = moved_scan
    measured = moved + np.float32(0.4)  # the open beam of a measured scan
    assert dremel(g, measured, n_iter=2).params["subpixel"] is True
    assert dremel(g, measured, n_iter=2, subpixel=False).params["subpixel"] is False
    assert dremel(g, moved, n_iter=2).params["subpixel"] is False
    sim = get_preset("tiny-parallel")
    y = simulate_sample(sim, SimulationConfig(), 0, 1).sinogram
    assert dremel(sim, y, n_iter=2).image.tobytes() == dremel(sim, y, n_iter=2, subpixel=False).image.tobytes()


def test_runaway_shifts_names_the_bound():
    from nanoct.recon.dremel import MAX_SHIFT_FRACTION, runaway_shifts

    g = get_preset("tiny-parallel")  # 91 detector pixels: the bound is 22.75 px
    assert MAX_SHIFT_FRACTION * g.n_det == 22.75
    assert runaway_shifts(np.full(g.n_angles, 22.7), g) is None and runaway_shifts(np.zeros(0), g) is None
    reason = runaway_shifts(np.r_[np.zeros(g.n_angles - 1), -23.0], g)
    assert reason is not None and "23.0 px" in reason and "91-pixel detector (22.8 px)" in reason
