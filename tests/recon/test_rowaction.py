"""The shared row-action core: the per-matrix cache, the float64 row product, the default relaxation."""

import numpy as np
import scipy.sparse as sp

from nanoct.core.geometry import get_preset
from nanoct.core.operators import system_matrix
from nanoct.recon.rowaction import (
    auto_relaxation,
    matrix_cache,
    row_dot_f64,
    row_norms_squared,
    unsigned_indices,
)


def test_matrix_cache_is_per_matrix_object():
    a = sp.random(30, 20, density=0.3, format="csr", dtype=np.float32, random_state=1)
    b = a.copy()
    b.data *= 2
    calls = []
    first = matrix_cache(a, "k", lambda m: calls.append(1) or m.sum())
    assert matrix_cache(a, "k", lambda m: calls.append(1) or -1.0) == first and calls == [1]
    assert matrix_cache(a, "other", lambda m: "x") == "x"
    np.testing.assert_allclose(row_norms_squared(b), 4 * row_norms_squared(a), rtol=1e-6)
    np.testing.assert_allclose(row_norms_squared(a), np.asarray(a.multiply(a).sum(axis=1)).ravel(), rtol=1e-6)
    assert row_norms_squared(a) is row_norms_squared(a)


def test_row_dot_f64_sums_float32_products_in_order():
    mat = system_matrix(get_preset("tiny-parallel"))
    x = np.random.default_rng(3).uniform(0, 1, mat.shape[1]).astype(np.float32)
    for r in (0, 700, 5000):
        p0, p1 = mat.indptr[r], mat.indptr[r + 1]
        expected = 0.0
        for q in range(p0, p1):
            expected += float(np.float32(mat.data[q] * x[mat.indices[q]]))
        for ind in (mat.indices, unsigned_indices(mat)):
            assert row_dot_f64(ind, mat.data, x, p0, p1) == expected


def test_auto_relaxation():
    assert auto_relaxation(4) == 1.0 and auto_relaxation(140) == 8 / 140
