"""Kaczmarz (ART) kernel: numba vs numpy oracle, convergence, view orders, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from nanoct.core.geometry import Geometry, get_preset
from nanoct.core.operators import RayTransform, system_matrix
from nanoct.recon.kaczmarz import kaczmarz, kaczmarz_reference
from nanoct.recon.rowaction import view_order

SMALL = Geometry("parallel", 6, 5, 7)  # 35 rays x 36 pixels


def random_csr(geometry: Geometry, seed: int = 0) -> sp.csr_matrix:
    """Random sparse float32 matrix with an empty row and a row of explicit zeros."""
    rng = np.random.default_rng(seed)
    m, n = geometry.n_angles * geometry.n_det, geometry.n * geometry.n
    dense = rng.uniform(0.1, 1.0, (m, n)) * (rng.uniform(size=(m, n)) < 0.3)
    dense[3] = 0.0
    mat = sp.csr_matrix(dense, dtype=np.float32)
    # row 10 holds stored zeros only
    row = sp.csr_matrix((np.zeros(3, np.float32), np.array([1, 4, 9]), np.array([0, 3])), shape=(1, n))
    mat = sp.vstack([mat[:10], row, mat[11:]]).tocsr()
    mat.sort_indices()
    assert mat[10].nnz == 3 and mat[3].nnz == 0
    return mat


@pytest.mark.parametrize("order", ["sequential", "random", "golden"])
@pytest.mark.parametrize("omega", [1.0, 0.3, 1.7])
def test_kernel_matches_numpy_reference(order, omega):
    mat = random_csr(SMALL)
    y = np.random.default_rng(1).normal(size=SMALL.sino_shape).astype(np.float32)
    res = kaczmarz(SMALL, y, n_iter=3, relaxation=omega, order=order, nonneg=False, seed=7, matrix=mat)
    ref = np.zeros(36)
    rng = np.random.default_rng(7)
    for _ in range(3):
        kaczmarz_reference(mat, y.ravel().astype(np.float64), ref, view_order(5, order, rng), 7, omega)
    assert np.all(np.isfinite(res.image))
    np.testing.assert_allclose(res.image.ravel(), ref, rtol=1e-5, atol=1e-5 * np.abs(ref).max())


def test_zero_rows_skipped_no_nan():
    mat = random_csr(SMALL)
    y = np.ones(SMALL.sino_shape, np.float32)
    res = kaczmarz(SMALL, y, n_iter=2, nonneg=False, matrix=mat)
    assert np.all(np.isfinite(res.image)) and np.all(np.isfinite(res.residuals))


def test_nonneg_projection():
    mat = random_csr(SMALL)
    y = np.random.default_rng(2).normal(size=SMALL.sino_shape).astype(np.float32)
    free = kaczmarz(SMALL, y, n_iter=2, nonneg=False, matrix=mat).image
    pos = kaczmarz(SMALL, y, n_iter=2, nonneg=True, matrix=mat).image
    assert free.min() < 0 and pos.min() >= 0


@pytest.mark.parametrize("name", ["tiny-parallel", "tiny-fan"])
def test_converges_on_consistent_data(name, consistent, psnr):
    g, x, y = consistent(name)
    res = kaczmarz(g, y, n_iter=15, relaxation=1.0)
    r = np.asarray(res.residuals)
    assert res.stop_reason == "max_iter" and len(r) == 15
    assert np.all(np.diff(r) <= 1e-3 * r[0])  # (numerically) non-increasing
    assert r[-1] < 0.02 * np.linalg.norm(y)
    assert psnr(res.image, x) > 30


def test_accepts_unperturbed_operator_and_rejects_moved_one(consistent):
    g, x, y = consistent("tiny-parallel")
    a = kaczmarz(RayTransform(g), y, n_iter=1).image
    b = kaczmarz(g, y, n_iter=1).image
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="without motion"):
        kaczmarz(RayTransform(g, np.ones((g.n_angles, 3))), y)


def test_callback_stops(consistent):
    g, x, y = consistent("tiny-parallel")
    res = kaczmarz(g, y, n_iter=10, callback=lambda i, im, motion: i == 2)
    assert res.stop_reason == "callback" and res.iterations == 3


def test_view_orders():
    rng = np.random.default_rng(0)
    for order in ("sequential", "random", "golden"):
        v = view_order(140, order, rng)
        assert sorted(v.tolist()) == list(range(140))
    gold = view_order(140, "golden")
    assert np.min(np.abs(np.diff(gold))) >= 140 // 5  # consecutive views are far apart


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(relaxation=0.0), "relaxation"),
        (dict(relaxation=2.0), "relaxation"),
        (dict(relaxation=-0.5), "relaxation"),
        (dict(n_iter=0), "n_iter"),
        (dict(order="spiral"), "order"),
        (dict(x0=np.zeros((3, 3))), "x0"),
    ],
)
def test_bad_parameters(kwargs, match, consistent):
    g, x, y = consistent("tiny-parallel")
    with pytest.raises(ValueError, match=match):
        kaczmarz(g, y, **kwargs)


def test_bad_sinogram(consistent):
    g, x, y = consistent("tiny-parallel")
    bad = y.copy()
    bad[3, 4] = np.nan
    with pytest.raises(ValueError, match="sino"):
        kaczmarz(g, bad)
    bad[3, 4] = np.inf
    with pytest.raises(ValueError, match="sino"):
        kaczmarz(g, bad)
    with pytest.raises(ValueError, match="sino"):
        kaczmarz(g, y[:, :-1])
    with pytest.raises(ValueError, match="matrix"):
        kaczmarz(SMALL, np.zeros(SMALL.sino_shape), matrix=random_csr(SMALL)[:-1])


def test_row_dot_and_residual_norm_match_float64():
    """float32-accumulated row products agree with a float64 dot to float32 rounding."""
    from nanoct.recon.rowaction import residual_norm, row_dot, unsigned_indices

    g = get_preset("tiny-parallel")
    mat = system_matrix(g)
    ind = unsigned_indices(mat)
    assert ind.dtype.kind == "u" and np.shares_memory(ind, mat.indices)
    x = np.random.default_rng(3).uniform(0, 1, mat.shape[1]).astype(np.float32)
    ref = mat.astype(np.float64) @ x.astype(np.float64)
    got = np.array([row_dot(ind, mat.data, x, mat.indptr[r], mat.indptr[r + 1]) for r in range(mat.shape[0])])
    np.testing.assert_allclose(got, ref, rtol=1e-6, atol=1e-6 * np.abs(ref).max())
    y = (ref + np.random.default_rng(4).normal(size=ref.size)).astype(np.float32)
    exact = np.linalg.norm(ref - y.astype(np.float64))
    for indices in (mat.indices, ind):
        assert abs(residual_norm(mat.indptr, indices, mat.data, y, x) - exact) <= 1e-5 * exact
