"""Tests for nanoct.core.matrixfree: traced rays against ASTRA's cached ``line`` rows,
adjointness of the fused kernels, thread-independence of the block back projection, and the
projector choice of the row-action methods."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from nanoct.core.geometry import Geometry, get_preset
from nanoct.core.matrixfree import (
    RAY_ENTRIES_PER_N,
    ParallelRays,
    backproject_traced,
    backproject_traced_serial,
    backproject_view,
    backproject_view_serial,
    column_sums,
    matrix_bytes,
    project_view,
    project_view_serial,
    ray_add,
    ray_block,
    ray_dot,
    ray_set,
    ray_setup,
    ray_trace,
    residual_norm_free,
    trace_view,
    trace_view_serial,
    view_buffer,
)
from nanoct.core.operators import system_matrix
from nanoct.recon.rowaction import AUTO_MATRIX_BYTES, resolve_projector

TINY = get_preset("tiny-parallel")
GEOMETRIES = [
    TINY,
    dataclasses.replace(TINY, center_offset=2.3, det_spacing=0.7),
    Geometry(kind="parallel", n=40, n_angles=64, n_det=70, det_spacing=1.3, center_offset=-4.6),
    Geometry(kind="parallel", n=31, n_angles=8, n_det=45),  # views at 0, 45, 90, ...: axis-parallel and diagonal rays
]


def traced_zero_pixels(g: Geometry, k: int, l: int) -> np.ndarray:
    """The pixels that ray_set visits for ray (k, l), zero weights included."""
    rays = ParallelRays(g)
    setup = ray_setup(rays.params[k], g.n)
    row = np.full(g.n * g.n, np.nan)
    ray_set(row, g.n, setup, setup[6] + l * setup[7], 1.0)
    return np.flatnonzero(~np.isnan(row))


def traced_rows(g: Geometry, k: int) -> np.ndarray:
    """Dense (L, N*N) rows of view k built with ray_set."""
    rays = ParallelRays(g)
    setup = ray_setup(rays.params[k], g.n)
    rows = np.zeros((g.n_det, g.n * g.n))
    for l in range(g.n_det):
        ray_set(rows[l], g.n, setup, setup[6] + l * setup[7], 1.0)
    return rows


@pytest.mark.parametrize("g", GEOMETRIES)
def test_ray_trace_stores_the_weights_of_ray_set_and_ray_dot(g: Geometry) -> None:
    rays = ParallelRays(g)
    x = np.random.default_rng(3).random(g.n * g.n)
    idx = np.empty(RAY_ENTRIES_PER_N * g.n, np.int64)
    wts = np.empty(RAY_ENTRIES_PER_N * g.n)
    for k in range(0, g.n_angles, max(1, g.n_angles // 9)):
        rows = traced_rows(g, k)
        setup = ray_setup(rays.params[k], g.n)
        for l in range(g.n_det):
            cnt, tdot, tsq = ray_trace(x, g.n, setup, setup[6] + l * setup[7], idx, wts)
            nz = idx[:cnt][wts[:cnt] != 0.0]
            assert len(set(nz.tolist())) == nz.size  # each pixel at most once with a weight
            assert set(idx[:cnt].tolist()) <= set(np.flatnonzero(rows[l] != 0).tolist()) | set(
                traced_zero_pixels(g, k, l).tolist()
            )  # zero-weight entries only on pixels the line model visits
            row = np.zeros(g.n * g.n)
            np.add.at(row, idx[:cnt], wts[:cnt])
            np.testing.assert_array_equal(row != 0, rows[l] != 0)  # same pixels, same orientation
            # the same weights, the shared ones rounded to float32 as in the cached matrix
            np.testing.assert_allclose(row, rows[l], rtol=1e-7, atol=1e-7)
            dot, _, sq = ray_dot(x, g.n, setup, setup[6] + l * setup[7])
            assert tdot == pytest.approx(dot, rel=1e-12, abs=1e-12)
            assert tdot == pytest.approx(wts[:cnt] @ x[idx[:cnt]], rel=1e-12, abs=1e-12)
            assert tsq == pytest.approx(sq, rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("g", GEOMETRIES)
def test_traced_rays_match_the_cached_line_matrix_row_by_row(g: Geometry, tmp_path) -> None:
    mat = system_matrix(g, directory=tmp_path)
    diffs = []
    for k in range(g.n_angles):
        ref = mat[k * g.n_det : (k + 1) * g.n_det].toarray()
        traced = traced_rows(g, k)
        diffs.append(np.abs(traced - ref)[(ref != 0) | (traced != 0)])
    diff = np.concatenate(diffs)
    # weights are 0 .. 1.42; ASTRA accumulates the crossings in float32, and a weight's slope
    # in the crossing is 1 / |rx / ry|, large for nearly axis-parallel rays
    assert diff.max() < 1e-2
    assert np.quantile(diff, 0.999) < 1e-3


@pytest.mark.parametrize("g", GEOMETRIES[:3])
def test_ray_dot_and_residual_agree_with_the_matrix(g: Geometry, tmp_path) -> None:
    mat = system_matrix(g, directory=tmp_path)
    rng = np.random.default_rng(0)
    x = rng.random(g.n * g.n).astype(np.float32)
    y = rng.random(g.n_angles * g.n_det).astype(np.float32)
    rays = ParallelRays(g)
    ax = mat @ x.astype(np.float64)
    sums = np.asarray(mat.sum(axis=1)).ravel()
    norms = np.asarray(mat.multiply(mat).sum(axis=1)).ravel()
    got = np.zeros((3, ax.size))
    for k in range(g.n_angles):
        setup = ray_setup(rays.params[k], g.n)
        for l in range(g.n_det):
            got[:, k * g.n_det + l] = ray_dot(x, g.n, setup, setup[6] + l * setup[7])
    for a, b in zip(got, (ax, sums, norms), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-3, atol=2e-3 * np.abs(b).max())
    ref = np.linalg.norm(ax - y)
    assert abs(residual_norm_free(rays.params, g.n, g.n_det, y, x) - ref) < 1e-3 * ref
    np.testing.assert_allclose(column_sums(rays.params, g.n, g.n_det), mat.sum(axis=0).A1, rtol=1e-3, atol=1e-2)


@pytest.mark.parametrize("threads", [False, True])
def test_projection_and_back_projection_are_adjoint(threads: bool) -> None:
    """<A_k x, v> = <x, A_k^T v> per view, for the threaded and the one-thread kernels."""
    g = GEOMETRIES[2]
    rays = ParallelRays(g)
    rng = np.random.default_rng(1)
    x = rng.standard_normal(g.n * g.n)
    proj, back = (project_view, backproject_view) if threads else (project_view_serial, backproject_view_serial)
    for k in range(0, g.n_angles, 7):
        v = rng.standard_normal(g.n_det)
        p, rs = np.zeros(g.n_det), np.zeros(g.n_det)
        proj(rays.params[k], g.n, g.n_det, x, p, rs, ray_block(g))
        bp = np.zeros(g.n * g.n)
        back(rays.params[k], g.n, g.n_det, v, bp, bp, False, False, ray_block(g))
        assert np.isclose(p @ v, x @ bp, rtol=1e-10)
        np.testing.assert_allclose(rs, traced_rows(g, k).sum(axis=1), rtol=1e-7)  # float32 shared weights


def test_threaded_back_projection_equals_the_one_thread_order() -> None:
    """Blocks of one phase touch disjoint pixels: with clipping and scaling, same bytes."""
    g = dataclasses.replace(TINY, det_spacing=0.5)
    rays = ParallelRays(g)
    rng = np.random.default_rng(2)
    scale = rng.random(g.n * g.n).astype(np.float32)
    for k in (0, 17, 35, 70):
        coef = rng.standard_normal(g.n_det)
        a = rng.random(g.n * g.n).astype(np.float32)
        b = a.copy()
        backproject_view(rays.params[k], g.n, g.n_det, coef, a, scale, True, True, ray_block(g))
        backproject_view_serial(rays.params[k], g.n, g.n_det, coef, b, scale, True, True, ray_block(g))
        np.testing.assert_array_equal(a, b)
        assert a.min() >= 0.0


def test_matrix_bytes_estimate(tmp_path) -> None:
    g = get_preset("tiny-parallel")
    mat = system_matrix(g, directory=tmp_path)
    actual = mat.data.nbytes + mat.indices.nbytes
    assert actual <= matrix_bytes(g) <= 1.1 * actual


def test_resolve_projector() -> None:
    paper = get_preset("paper-parallel")
    big = Geometry(kind="parallel", n=511, n_angles=1137, n_det=727)
    assert matrix_bytes(paper) < AUTO_MATRIX_BYTES < matrix_bytes(big)
    assert resolve_projector("auto", paper) == "matrix"
    assert resolve_projector("auto", big) == "matrixfree"
    assert resolve_projector("auto", big, matrix=object()) == "matrix"
    assert resolve_projector("matrixfree", paper) == "matrixfree"
    assert resolve_projector("auto", dataclasses.replace(get_preset("paper-fan"), n=1023)) == "matrix"
    with pytest.raises(ValueError, match="parallel beam only"):
        resolve_projector("matrixfree", get_preset("tiny-fan"))
    with pytest.raises(ValueError, match="matrix=None"):
        resolve_projector("matrixfree", paper, matrix=object())


def test_parallel_rays_refuses_fan_beam() -> None:
    with pytest.raises(ValueError, match="projector='matrix'"):
        ParallelRays(get_preset("tiny-fan"))


@pytest.mark.parametrize("threads", [False, True])
@pytest.mark.parametrize("g", GEOMETRIES)
def test_buffered_view_equals_project_view_and_backproject_view(g: Geometry, threads: bool) -> None:
    """A view traced once into its buffer: the projections of project_view (to rounding), the row
    sums of the traced rows, and the same bytes as backproject_view (clipped and scaled)."""
    rays = ParallelRays(g)
    rng = np.random.default_rng(4)
    x = rng.random(g.n * g.n)
    scale = rng.random(g.n * g.n).astype(np.float32)
    buf = view_buffer(g)
    block = ray_block(g)
    trace, back = (trace_view, backproject_traced) if threads else (trace_view_serial, backproject_traced_serial)
    for k in range(0, g.n_angles, max(1, g.n_angles // 7)):
        p, rs, p_ref, rs_ref = (np.zeros(g.n_det) for _ in range(4))
        trace(rays.params[k], g.n, g.n_det, x, p, rs, *buf, block)
        project_view_serial(rays.params[k], g.n, g.n_det, x, p_ref, rs_ref, block)
        np.testing.assert_allclose(p, p_ref, rtol=1e-12, atol=1e-12)
        rows = traced_rows(g, k)
        np.testing.assert_allclose(rs, rows.sum(axis=1), rtol=1e-7, atol=1e-7)  # float32 shared weights
        np.testing.assert_allclose(p, rows @ x, rtol=1e-7, atol=1e-7)
        coef = rng.standard_normal(g.n_det)
        coef[::5] = 0.0
        a = (rng.random(g.n * g.n) - 0.3).clip(0.0).astype(np.float32)
        b = a.copy()
        back(rays.params[k], g.n, g.n_det, coef, a, scale, True, True, block, *buf)
        backproject_view_serial(rays.params[k], g.n, g.n_det, coef, b, scale, True, True, block)
        np.testing.assert_array_equal(a, b)
        c = np.zeros(g.n * g.n)
        back(rays.params[k], g.n, g.n_det, coef, c, c, False, False, block, *buf)
        np.testing.assert_allclose(c, rows.T @ coef, rtol=1e-6, atol=1e-6)  # A_k^T, not A_k


def test_view_buffer_is_capped(monkeypatch) -> None:
    import nanoct.core.matrixfree as mf

    g = GEOMETRIES[2]
    code, shared, rows = view_buffer(g)
    assert code.shape == shared.shape == (g.n_det, g.n) and rows.shape == (g.n_det, 4)
    assert (code.dtype, shared.dtype, rows.dtype) == (np.int32, np.float32, np.int32)
    monkeypatch.setattr(mf, "VIEW_BUFFER_BYTES", 8 * g.n * g.n_det - 1)
    assert view_buffer(g) is None


@pytest.mark.parametrize("seed", range(40))
def test_interior_and_edge_lines_match_the_per_pixel_model_on_random_geometries(seed: int) -> None:
    """Small, odd geometries (N down to 1, rays missing the image, grazing its edges, any angle):
    every kernel's ray equals the per-pixel reference ``ray_set``."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 14))
    g = Geometry(
        kind="parallel", n=n, n_angles=int(rng.integers(1, 9)), n_det=int(rng.integers(1, 3 * n + 4)),
        det_spacing=float(rng.uniform(0.3, 2.5)), center_offset=float(rng.uniform(-n, n)),
    )  # fmt: skip
    rays = ParallelRays(g)
    x = rng.random(n * n)
    idx = np.empty(RAY_ENTRIES_PER_N * n, np.int64)
    wts = np.empty(RAY_ENTRIES_PER_N * n)
    buf = view_buffer(g)
    for k in range(g.n_angles):
        rows = traced_rows(g, k)
        setup = ray_setup(rays.params[k], n)
        for l in range(g.n_det):
            c0 = setup[6] + l * setup[7]
            cnt, dot, sq = ray_trace(x, n, setup, c0, idx, wts)
            row = np.zeros(n * n)
            np.add.at(row, idx[:cnt], wts[:cnt])
            np.testing.assert_allclose(row, rows[l], rtol=1e-7, atol=1e-7)
            assert ray_dot(x, n, setup, c0)[0] == pytest.approx(rows[l] @ x, rel=1e-7, abs=1e-7)
            added = np.zeros(n * n)
            ray_add(added, n, setup, c0, 1.0, added, False, False)
            np.testing.assert_allclose(added, rows[l], rtol=1e-7, atol=1e-7)
        p, rs = np.zeros(g.n_det), np.zeros(g.n_det)
        trace_view_serial(rays.params[k], n, g.n_det, x, p, rs, *buf, ray_block(g))
        np.testing.assert_allclose(p, rows @ x, rtol=1e-7, atol=1e-7)
        coef = rng.standard_normal(g.n_det)
        back = np.zeros(n * n)
        backproject_traced_serial(rays.params[k], n, g.n_det, coef, back, back, False, False, ray_block(g), *buf)
        np.testing.assert_allclose(back, rows.T @ coef, rtol=1e-6, atol=1e-6)
        scale = rng.random(n * n).astype(np.float32)
        a = (rng.random(n * n) - 0.3).clip(0.0).astype(np.float32)
        b = a.copy()
        backproject_traced_serial(rays.params[k], n, g.n_det, coef, a, scale, True, True, ray_block(g), *buf)
        backproject_view_serial(rays.params[k], n, g.n_det, coef, b, scale, True, True, ray_block(g))
        np.testing.assert_array_equal(a, b)  # buffered and traced twice: the same bytes
