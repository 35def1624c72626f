"""Measured data for the row-action methods: open-beam level, objects wider than the field of view, noise stop."""

from __future__ import annotations

import numpy as np
import pytest

import nanoct
from nanoct.core.geometry import Geometry, get_preset
from nanoct.core.operators import system_matrix
from nanoct.recon.dremel import dremel
from nanoct.recon.eta import eta_from_residual
from nanoct.recon.kaczmarz import kaczmarz
from nanoct.recon.measured import (
    air_level,
    extend_sinogram,
    looks_measured,
    noise_level,
    padded_geometry,
    prepare_measured,
)
from nanoct.recon.resesop import resesop
from nanoct.sim.simulate import SimulationConfig, simulate_sample

N = 40
ANGLES = np.linspace(0, np.pi, 48, endpoint=False)


def _disc_phantom(n: int, radius: float) -> np.ndarray:
    yy, xx = np.mgrid[:n, :n] - (n - 1) / 2
    img = (np.hypot(yy, xx) <= radius).astype(np.float32) * 0.5
    img[(np.hypot(yy - 4, xx + 3) <= radius / 3)] = 1.0
    return img


def _score(x: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> float:
    return float(10 * np.log10((gt[mask].max() - gt[mask].min()) ** 2 / np.mean((x[mask] - gt[mask]) ** 2)))


def _disc(n: int) -> np.ndarray:
    yy, xx = np.mgrid[:n, :n] - (n - 1) / 2
    return np.hypot(yy, xx) <= (n - 1) / 2


def test_helpers_closed_forms() -> None:
    sino = np.zeros((3, 20))
    sino += np.array([0.1, -0.2, 0.4])[:, None]
    sino[:, 8:12] += 5.0  # the object, away from the edges
    np.testing.assert_allclose(air_level(sino), [0.1, -0.2, 0.4])
    ext = extend_sinogram(sino, 4)
    assert ext.shape == (3, 28)
    np.testing.assert_allclose(ext[:, 4:-4], sino, rtol=1e-6)
    np.testing.assert_allclose(ext[:, 0], 0.0, atol=1e-7)  # cos^2 reaches zero at the far end
    np.testing.assert_allclose(ext[:, 3], sino[:, 0] * np.cos(np.pi / 8) ** 2, rtol=1e-6)  # one pixel out
    g = Geometry.from_angles(ANGLES, 30, 20, center_offset=1.5)
    big, margin = padded_geometry(g, 5)
    assert (big.n, big.n_det, margin, big.center_offset) == (40, 30, 5, 1.5)
    assert np.array_equal(big.angles, g.angles)


def test_noise_level_of_white_noise() -> None:
    rng = np.random.default_rng(0)
    s = np.linspace(0, 3, 200)[None, :] * np.ones((50, 1)) + rng.normal(0, 0.05, (50, 200))
    assert noise_level(s) == pytest.approx(0.05, rel=0.05)


@pytest.mark.parametrize("preset", ["tiny-parallel", "tiny-fan"])
def test_simulations_are_not_taken_for_measured_data(preset: str) -> None:
    g = get_preset(preset)
    sample = simulate_sample(g, SimulationConfig(), 0, 0)
    assert not looks_measured(sample.sinogram)
    assert prepare_measured(g, sample.sinogram, "auto", None) is None


def test_defaults_keep_the_bytes_of_a_simulation() -> None:
    g = get_preset("tiny-parallel")
    y = simulate_sample(g, SimulationConfig(), 0, 1).sinogram
    for solver, extra in ((dremel, {"n_iter": 3}), (kaczmarz, {"n_iter": 3})):
        a, b = solver(g, y, **extra), solver(g, y, measured="off", **extra)
        assert a.image.tobytes() == b.image.tobytes() and "measured_data" not in a.params
    eta = np.full(g.n_angles, 0.1)
    assert resesop(g, y, eta).image.tobytes() == resesop(g, y, eta, measured="off").image.tobytes()


@pytest.fixture(scope="module")
def offset_scan():
    """A faint disc phantom inside the field of view, axis 5 px off centre; its sinogram, plus air at 0.4 +- 0.05."""
    g = Geometry.from_angles(ANGLES, N, N, center_offset=5.0)
    x = 0.1 * _disc_phantom(N, 12)  # line integrals up to 1.3: the air level is a third of that, as in a real scan
    y = (system_matrix(g) @ x.ravel()).reshape(g.sino_shape)
    level = 0.4 + 0.05 * np.sin(3 * ANGLES)
    return g, x, y.astype(np.float32), (y + level[:, None]).astype(np.float32), level


def test_open_beam_level_found_and_removed(offset_scan) -> None:
    g, x, clean, measured, level = offset_scan
    assert looks_measured(measured) and not looks_measured(clean)
    np.testing.assert_allclose(air_level(measured), level, atol=1e-5)
    data = prepare_measured(g, measured, "auto", 0)
    np.testing.assert_allclose(data.sinogram, clean, atol=1e-5)


@pytest.mark.parametrize("method", ["kaczmarz", "dremel", "resesop"])
def test_open_beam_level_does_not_spoil_the_methods(offset_scan, method: str) -> None:
    """With the defaults a scan whose air reads 0.4 reconstructs about as well as the clean one; without, far worse."""
    g, x, clean, measured, level = offset_scan
    run = getattr(nanoct, method)
    extra = {"eta": np.full(g.n_angles, 0.05)} if method == "resesop" else {}
    mask = _disc(N)
    ref = _score(run(clean, g, n_iter=8, **extra).image, x, mask)
    auto = run(measured, g, n_iter=8, **extra)
    off = run(measured, g, n_iter=8, measured="off", **extra)
    assert auto.params["measured_data"]["air_level_mean"] == pytest.approx(level.mean(), abs=1e-4)
    assert _score(auto.image, x, mask) > ref - 3.0  # the larger grid converges a little more slowly
    assert _score(auto.image, x, mask) > _score(off.image, x, mask) + 5.0


def test_object_wider_than_the_field_of_view() -> None:
    """A phantom twice the detector's width: the extension onto a larger grid beats the disc of the detector."""
    wide = Geometry.from_angles(ANGLES, 2 * N, 2 * N)
    x = _disc_phantom(2 * N, 34)
    full = (system_matrix(wide) @ x.ravel()).reshape(wide.sino_shape)
    cut = full[:, N // 2 : N // 2 + N].astype(np.float32)  # the central half of the detector
    g = Geometry.from_angles(ANGLES, N, N)
    inner = x[N // 2 : N // 2 + N, N // 2 : N // 2 + N]
    mask = _disc(N)
    assert looks_measured(cut)
    off = kaczmarz(g, cut, n_iter=20, measured="off").image
    extend = kaczmarz(g, cut, n_iter=20, measured="extend", pad=N // 2)
    assert extend.image.shape == (N, N) and extend.params["measured_data"]["pad"] == N // 2
    assert extend.params["measured_data"]["air_level_mean"] == 0.0
    assert (extend.params["measured"], extend.params["pad"]) == ("extend", N // 2)  # as asked, not the inner "off"
    assert _score(extend.image, inner, mask) > _score(off, inner, mask) + 10.0
    # the default also removes the edge level as if it were air: the structure is kept, a constant is lost
    auto = kaczmarz(g, cut, n_iter=20).image

    def centred(a: np.ndarray) -> np.ndarray:
        return a - a[mask].mean() + inner[mask].mean()

    assert _score(centred(auto), inner, mask) > _score(centred(off), inner, mask) + 10.0
    d = dremel(g, cut, n_iter=8)
    assert d.image.shape == (N, N) and np.abs(d.motion).max() < 1.0  # nothing moves


def test_discrepancy_stop_needs_no_truth(offset_scan) -> None:
    """Noisy measured data: Kaczmarz stops by the discrepancy principle with the estimated noise level."""
    g, x, _, measured, _ = offset_scan
    noisy = measured + np.random.default_rng(3).normal(0, 0.3, measured.shape).astype(np.float32)
    r = kaczmarz(g, noisy, n_iter=50)
    bound = r.params["measured_data"]["discrepancy"]
    assert r.stop_reason == "discrepancy" and r.iterations < 50 and r.residuals[-1] <= bound
    assert r.params["measured_data"]["noise"] == pytest.approx(0.3, rel=0.2)
    assert all(res > bound for res in r.residuals[:-1])


def test_resesop_takes_the_estimated_noise_as_delta(offset_scan) -> None:
    g, _, _, measured, _ = offset_scan
    noisy = measured + np.random.default_rng(4).normal(0, 0.2, measured.shape).astype(np.float32)
    auto = resesop(g, noisy, np.zeros(g.n_angles))
    plain = resesop(g, noisy, np.zeros(g.n_angles), delta=0.0)
    assert auto.params["delta"] == pytest.approx(auto.params["measured_data"]["noise"])
    assert auto.params["delta"] > 0.1
    # stripes of the noise's width: fewer updates than the plain SESOP-Kaczmarz of delta = 0
    assert sum(auto.params["n_updates"]) < 0.8 * sum(plain.params["n_updates"])


def test_eta_from_residual_leaves_out_the_open_beam(offset_scan) -> None:
    g, x, clean, measured, _ = offset_scan
    start = 0.9 * x  # a first reconstruction with an error
    plain = eta_from_residual(g, clean, start)
    np.testing.assert_allclose(eta_from_residual(g, measured, start), 0.5 * plain, atol=1e-4)  # measured: half
    np.testing.assert_allclose(eta_from_residual(g, measured, start, scale=1.0), plain, atol=1e-4)
    assert eta_from_residual(g, measured, start, measured="off").min() > 0.3


def test_a_matrix_keeps_the_data_as_given_unless_asked(offset_scan) -> None:
    g, _, _, measured, _ = offset_scan
    mat = system_matrix(g)
    a = kaczmarz(g, measured, n_iter=2, matrix=mat)
    assert "measured_data" not in a.params
    with pytest.raises(ValueError, match="pad=0"):
        kaczmarz(g, measured, n_iter=2, matrix=mat, measured="on")
    b = kaczmarz(g, measured, n_iter=2, matrix=mat, measured="on", pad=0)
    assert b.params["measured_data"]["pad"] == 0


def test_callback_sees_the_requested_grid(offset_scan) -> None:
    g, _, _, measured, _ = offset_scan
    shapes = []
    dremel(g, measured, n_iter=2, callback=lambda it, x, s: shapes.append((x.shape, s.shape)))
    assert shapes == [((N, N), (g.n_angles,))] * 2
