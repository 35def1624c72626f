"""The shared row-action core: the per-matrix cache, the float64 row product, the default relaxation."""

import numpy as np
import pytest
import scipy.sparse as sp

from nanoct.core.geometry import get_preset
from nanoct.core.operators import RayTransform, system_matrix
from nanoct.recon.dremel import dremel
from nanoct.recon.kaczmarz import kaczmarz
from nanoct.recon.resesop import resesop
from nanoct.recon.rowaction import (
    auto_relaxation,
    matrix_cache,
    row_dot_f64,
    row_norms_squared,
    unsigned_indices,
)
from nanoct.sim.phantoms import random_phantom


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


# ---------------------------------------------------------------------------------- projectors
@pytest.mark.parametrize("method", ["kaczmarz", pytest.param("dremel", marks=pytest.mark.slow), "resesop"])
def test_matrix_free_projector_gives_the_matrix_results(method: str, tmp_path) -> None:
    """Same iterates within 1e-3 (relative) from the cached matrix and the traced rays."""
    g = get_preset("tiny-parallel")
    x = random_phantom(np.random.default_rng(0), g.n)
    motion = np.zeros((g.n_angles, 3))
    motion[:, :2] = np.random.default_rng(1).uniform(-1.5, 1.5, (g.n_angles, 2))
    y = RayTransform(g, motion=motion)(x)
    mat = system_matrix(g, directory=tmp_path)
    run = {
        "kaczmarz": lambda **kw: kaczmarz(g, y, n_iter=3, **kw),
        "dremel": lambda **kw: dremel(g, y, n_iter=3, residual="exact", **kw),
        "resesop": lambda **kw: resesop(g, y, np.full(g.n_angles, 0.5), n_iter=3, residual="exact", **kw),
    }[method]
    a, b = run(matrix=mat), run(projector="matrixfree")
    assert np.linalg.norm(a.image - b.image) < 1e-3 * np.linalg.norm(a.image)
    np.testing.assert_allclose(a.residuals, b.residuals, rtol=1e-4)
    if method == "dremel":
        assert np.abs(a.motion - b.motion).max() <= 0.5  # one up-sampled lag at most
    assert b.params["projector"] == "matrixfree"


@pytest.mark.slow
def test_matrix_free_dremel_with_threads_per_view_gives_the_same_bytes(monkeypatch) -> None:
    """Splitting each view over threads (forced for a tiny view) changes nothing."""
    import nanoct.core.matrixfree as mf

    g = get_preset("tiny-parallel")
    x = random_phantom(np.random.default_rng(0), g.n)
    y = RayTransform(g)(x)
    one = dremel(g, y, n_iter=2, projector="matrixfree")
    monkeypatch.setattr(mf, "PARALLEL_MIN_WORK", 0)
    assert mf.use_threads(g)
    many = dremel(g, y, n_iter=2, projector="matrixfree")
    np.testing.assert_array_equal(one.image, many.image)
    np.testing.assert_array_equal(one.motion, many.motion)
