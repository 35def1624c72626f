"""RESESOP-Kaczmarz: numba vs literal numpy Algorithm 2, discrepancy stop, eta = 0, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.geometry import Geometry, get_preset
from nanoct.core.operators import RayTransform, system_matrix
from nanoct.recon.kaczmarz import kaczmarz
from nanoct.recon.resesop import resesop, resesop_reference
from nanoct.recon.rowaction import view_order
from nanoct.sim.motion import MotionParams, sample_motion
from nanoct.sim.phantoms import downsample, random_phantom

SMALL = Geometry("parallel", 6, 5, 7)


def small_problem(seed=0):
    import scipy.sparse as sp

    rng = np.random.default_rng(seed)
    dense = rng.uniform(0.1, 1.0, (35, 36)) * (rng.uniform(size=(35, 36)) < 0.3)
    dense[4] = 0.0
    mat = sp.csr_matrix(dense, dtype=np.float32)
    mat.sort_indices()
    x = rng.uniform(0, 1, 36)
    y = (mat @ x).astype(np.float32).reshape(SMALL.sino_shape) + rng.normal(0, 0.05, SMALL.sino_shape).astype(
        np.float32
    )
    return mat, y


@pytest.mark.parametrize("order", ["sequential", "random"])
@pytest.mark.parametrize("eta_value", [0.0, 0.02, 0.1])
def test_kernel_matches_literal_algorithm(order, eta_value):
    mat, y = small_problem()
    eta = np.full(5, eta_value, np.float32)
    res = resesop(SMALL, y, eta, tau=1.1, n_iter=4, order=order, nonneg=False, seed=3, matrix=mat)
    ref = np.zeros(36)
    rng = np.random.default_rng(3)
    state: dict = {}
    width = np.full(35, eta_value, dtype=np.float64)
    for n_upd in res.params["n_updates"]:
        got = resesop_reference(mat, y.ravel().astype(np.float64), ref, width, 1.1, view_order(5, order, rng), 7, state)
        assert got == n_upd
    assert np.all(np.isfinite(res.image))
    np.testing.assert_allclose(res.image.ravel(), ref, rtol=1e-4, atol=1e-5 * np.abs(ref).max())


def test_two_directions_are_used():
    """With eta = 0 the second search direction changes the iterate (vs plain Kaczmarz)."""
    mat, y = small_problem()
    a = resesop(SMALL, y, np.zeros(5), n_iter=1, order="sequential", nonneg=False, matrix=mat).image
    b = kaczmarz(SMALL, y, n_iter=1, order="sequential", nonneg=False, matrix=mat).image
    assert np.abs(a - b).max() > 1e-3


@pytest.mark.parametrize("name", ["tiny-parallel", "tiny-fan"])
def test_eta_zero_converges_like_kaczmarz(name, consistent, psnr):
    g, x, y = consistent(name)
    res = resesop(g, y, np.zeros(g.n_angles), n_iter=15, order="random", residual="exact")
    r = np.asarray(res.residuals)
    assert res.stop_reason == "max_iter"
    assert r[-1] < 0.5 * r[2] and r[-1] < 0.02 * np.linalg.norm(y)
    assert psnr(res.image, x) > 30
    kz = kaczmarz(g, y, n_iter=15, relaxation=1.0).image
    assert np.linalg.norm(res.image - kz) < 0.1 * np.linalg.norm(x)


@pytest.mark.parametrize("name", ["tiny-parallel", "tiny-fan"])
def test_discrepancy_stop_with_positive_eta(name, consistent, psnr):
    g, x, y = consistent(name)
    eta = np.full(g.n_angles, 0.01 * y.max(), np.float32)
    res = resesop(g, y, eta, tau=1.5, n_iter=20)
    assert res.stop_reason == "discrepancy" and res.iterations < 20
    # the returned image meets the discrepancy principle for every ray
    resid = np.abs(system_matrix(g) @ res.image.ravel() - y.ravel())
    assert resid.max() <= 1.5 * eta[0] * (1 + 1e-4)
    assert psnr(res.image, x) > 25
    sticky = resesop(g, y, eta, tau=1.5, n_iter=20, stop_rule="sticky")
    assert sticky.stop_reason == "discrepancy" and sticky.iterations <= res.iterations


def test_per_ray_eta_equals_per_view_eta(consistent):
    g, x, y = consistent("tiny-parallel")
    eta = np.linspace(0.1, 0.3, g.n_angles).astype(np.float32)
    a = resesop(g, y, eta, n_iter=3).image
    b = resesop(g, y, np.repeat(eta[:, None], g.n_det, 1), n_iter=3).image
    np.testing.assert_array_equal(a, b)


def test_perturbed_data_beats_unregularised(psnr):
    """Translation-only motion: RESESOP with the true eta beats SESOP-Kaczmarz (eta = 0)."""
    g = get_preset("tiny-parallel")
    rng = np.random.default_rng(77)
    fine = random_phantom(rng, g.n, oversample=2)
    gt = downsample(fine, 2)
    motion = sample_motion(rng, g.n_angles, MotionParams.for_kind("parallel", jitter=False))
    y = RayTransform(g, motion, oversample=2).forward(fine)
    eta = np.abs(y - RayTransform(g, oversample=2).forward(fine)).max(axis=1)
    good = resesop(g, y, eta)
    plain = resesop(g, y, np.zeros_like(eta))
    assert psnr(good.image, gt) > psnr(plain.image, gt) + 1.0


@pytest.mark.parametrize(
    ("eta", "kwargs", "match"),
    [
        (-np.ones(140), {}, "eta"),
        (np.ones(139), {}, "eta"),
        (np.ones((140, 90)), {}, "eta"),
        (1.0, {}, "eta"),
        (np.full(140, np.nan), {}, "eta"),
        (np.ones(140), dict(tau=1.0), "tau"),
        (np.ones(140), dict(eta_scale=-1.0), "eta_scale"),
        (np.ones(140), dict(delta=-0.1), "delta"),
        (np.ones(140), dict(n_iter=0), "n_iter"),
        (np.ones(140), dict(stop_rule="never"), "stop_rule"),
    ],
)
def test_bad_input(eta, kwargs, match, consistent):
    g, x, y = consistent("tiny-parallel")
    with pytest.raises(ValueError, match=match):
        resesop(g, y, eta, **kwargs)


def test_bad_sinogram(consistent):
    g, x, y = consistent("tiny-parallel")
    y = y.copy()
    y[0, 0] = np.nan
    with pytest.raises(ValueError, match="sino"):
        resesop(g, y, np.ones(g.n_angles))
    with pytest.raises(ValueError, match="sino"):
        resesop(g, y[:-1], np.ones(g.n_angles))
