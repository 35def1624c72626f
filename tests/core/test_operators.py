"""Tests for nanoct.core.operators: adjointness, the motion model, mass conservation, the
oversampled model, the cached system matrix and input validation.

Motion convention under test (module docstring of ``operators``): at view k the scanner sees
``x_k(r) = x(R(theta_k) r + t_k)``; motion rows are ``(t1 px, t2 px, theta deg)``.
"""

from __future__ import annotations

import math
import os
import time

import numpy as np
import pytest
import scipy.sparse as sp
from scipy import ndimage

from nanoct.core import operators
from nanoct.core.geometry import Geometry, get_preset
from nanoct.core.operators import RayTransform, cache_dir, system_matrix
from nanoct.sim.phantoms import downsample, random_phantom


@pytest.fixture(scope="module", autouse=True)
def _cache_dir(tmp_path_factory: pytest.TempPathFactory):
    """Keep the operator cache out of the home directory; start and end with a clean LRU."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setitem(os.environ, "NANOCT_CACHE", str(tmp_path_factory.mktemp("nanoct-cache")))
        operators._load_or_build.cache_clear()
        yield
        operators._load_or_build.cache_clear()


# ---------------------------------------------------------------------------------- helpers
def coords(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Physical coordinates (r1, r2) of the pixel centres of an (n, n) image."""
    c = (n - 1) / 2
    rows, cols = np.mgrid[:n, :n]
    return cols - c, c - rows


def blobs(n: int) -> np.ndarray:
    """A smooth, asymmetric test object (three Gaussians) well inside the field of view."""
    r1, r2 = coords(n)
    x = (
        np.exp(-((r1 - 5) ** 2 + (r2 - 3) ** 2) / (2 * 4.0**2))
        + 0.6 * np.exp(-((r1 + 8) ** 2 + (r2 + 6) ** 2) / (2 * 3.0**2))
        + 0.4 * np.exp(-((r1 + 2) ** 2 + (r2 - 10) ** 2) / (2 * 2.5**2))
    )
    return x.astype(np.float32)


def random_motion(rng: np.random.Generator, k: int, shift: float = 2.0, rot: float = 1.0) -> np.ndarray:
    return np.column_stack([rng.uniform(-shift, shift, (k, 2)), rng.uniform(-rot, rot, k)]).astype(np.float32)


def warp(x: np.ndarray, t: np.ndarray, theta_deg: float, order: int) -> np.ndarray:
    """x_k(r) = x(R(theta) r + t) sampled on the pixel centres, by interpolation."""
    n = x.shape[0]
    c = (n - 1) / 2
    r1, r2 = coords(n)
    th = math.radians(theta_deg)
    q1 = math.cos(th) * r1 - math.sin(th) * r2 + t[0]
    q2 = math.sin(th) * r1 + math.cos(th) * r2 + t[1]
    return ndimage.map_coordinates(x, [c - q2, q1 + c], order=order, mode="constant", cval=0.0)


def rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(np.asarray(a, np.float64) - b) / np.linalg.norm(np.asarray(b, np.float64)))


# ---------------------------------------------------------------------------------- adjointness
@pytest.mark.parametrize("name", ["tiny-parallel", "tiny-fan"])
@pytest.mark.parametrize("oversample", [1, 2])
@pytest.mark.parametrize("moving", [False, True])
def test_adjointness(name: str, oversample: int, moving: bool) -> None:
    g = get_preset(name)
    rng = np.random.default_rng((1, oversample, moving))
    motion = random_motion(rng, g.n_angles) if moving else None
    op = RayTransform(g, motion, oversample=oversample)
    assert op.domain_shape == (g.n * oversample,) * 2
    assert op.range_shape == g.sino_shape
    x = rng.random(op.domain_shape).astype(np.float32)
    y = rng.standard_normal(op.range_shape).astype(np.float32)
    ax, aty = op.forward(x), op.adjoint(y)
    assert ax.shape == op.range_shape and ax.dtype == np.float32
    assert aty.shape == op.domain_shape and aty.dtype == np.float32
    lhs = np.vdot(ax.astype(np.float64), y)
    rhs = np.vdot(x.astype(np.float64), aty)
    assert abs(lhs - rhs) / (np.linalg.norm(ax) * np.linalg.norm(y)) < 1e-4

    # With structured (transpose-asymmetric) x and y the same measure exposes a transposed or
    # mirrored adjoint: it must stay tiny for the real one and be large for the wrong ones.
    r1, r2 = coords(g.n * oversample)
    bump = np.exp(-((r1 / oversample - 12) ** 2 + (r2 / oversample - 6) ** 2) / 18).astype(np.float32)
    xs = x + 5 * bump  # a bump off the diagonals: moved by a transpose or a flip
    ys = op.forward(xs) + y
    axs, atys = op.forward(xs), op.adjoint(ys)
    lhs = np.vdot(axs.astype(np.float64), ys)
    scale = np.linalg.norm(axs) * np.linalg.norm(ys)
    assert abs(lhs - np.vdot(xs.astype(np.float64), atys)) / scale < 1e-4
    for wrong in (atys.T, atys[::-1], atys[:, ::-1]):
        assert abs(lhs - np.vdot(xs.astype(np.float64), wrong)) / scale > 1e-2


@pytest.mark.parametrize("projector", ["linear", "strip", "distance_driven"])
def test_adjointness_other_parallel_projectors(projector: str) -> None:
    """The other parallel projectors are also (numerically) adjoint pairs in ASTRA."""
    g = get_preset("tiny-parallel")
    rng = np.random.default_rng(7)
    op = RayTransform(g, random_motion(rng, g.n_angles), projector=projector)
    x = rng.random(op.domain_shape).astype(np.float32)
    y = rng.random(op.range_shape).astype(np.float32)
    ax, aty = op(x), op.adjoint(y)
    err = abs(np.vdot(ax.astype(np.float64), y) - np.vdot(x.astype(np.float64), aty))
    assert err / (np.linalg.norm(ax) * np.linalg.norm(y)) < 1e-3


def test_zero_motion_equals_no_motion() -> None:
    g = get_preset("tiny-fan")
    x = blobs(g.n)
    np.testing.assert_array_equal(RayTransform(g, np.zeros((g.n_angles, 3)))(x), RayTransform(g)(x))


# ---------------------------------------------------------------------------------- system matrix
@pytest.mark.parametrize("name", ["tiny-parallel", "tiny-fan"])
def test_system_matrix_matches_operator(name: str, tmp_path) -> None:
    g = get_preset(name)
    mat = system_matrix(g, directory=tmp_path)
    assert sp.isspmatrix_csr(mat) or isinstance(mat, sp.csr_array)
    assert mat.shape == (g.n_angles * g.n_det, g.n * g.n)
    assert mat.dtype == np.float32
    rng = np.random.default_rng(3)
    x = rng.random(g.image_shape).astype(np.float32)
    y = rng.standard_normal(g.sino_shape).astype(np.float32)
    op = RayTransform(g)
    ax = op(x)
    # row k*L + l <-> ray (k, l); column row*N + col <-> pixel x[row, col]
    np.testing.assert_allclose((mat @ x.ravel()).reshape(g.sino_shape), ax, rtol=0, atol=1e-5 * np.abs(ax).max())
    aty = op.adjoint(y)
    np.testing.assert_allclose((mat.T @ y.ravel()).reshape(g.image_shape), aty, rtol=0, atol=1e-5 * np.abs(aty).max())
    # column order is really row-major in the image (a transposed image is far off)
    assert rel(mat @ x.T.ravel(), ax.ravel()) > 0.05


def test_system_matrix_is_cached_on_disk(tmp_path, monkeypatch) -> None:
    g = get_preset("tiny-parallel")
    operators._load_or_build.cache_clear()
    first = system_matrix(g, directory=tmp_path)
    files = sorted(tmp_path.iterdir())
    assert len(files) == 1 and files[0].suffix == ".npz"  # no temporary file left behind
    assert "parallel" in files[0].name and "line" in files[0].name
    # same process: the in-memory cache answers
    assert system_matrix(g, directory=tmp_path) is first

    # fresh process-level cache: the file is loaded, not rebuilt
    operators._load_or_build.cache_clear()

    def no_build(*args, **kwargs):
        raise AssertionError("the matrix was rebuilt although a valid cache file exists")

    monkeypatch.setattr(operators, "_build_matrix", no_build)
    loaded = system_matrix(g, directory=tmp_path)
    assert loaded is not first
    assert loaded.shape == first.shape and loaded.dtype == np.float32
    assert (loaded != first).nnz == 0
    operators._load_or_build.cache_clear()


@pytest.mark.slow
def test_system_matrix_different_projector_gets_own_file(tmp_path) -> None:
    g = get_preset("tiny-parallel")
    line = system_matrix(g, directory=tmp_path)
    strip = system_matrix(g, "strip", directory=tmp_path)
    assert len(list(tmp_path.glob("*.npz"))) == 2
    assert (line != strip).nnz > 0


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["garbage", "truncated", "wrong_shape", "wrong_dtype"])
def test_system_matrix_damaged_cache_is_rebuilt(tmp_path, damage: str) -> None:
    g = get_preset("tiny-fan")
    operators._load_or_build.cache_clear()
    good = system_matrix(g, directory=tmp_path).copy()
    (path,) = tmp_path.glob("*.npz")
    if damage == "garbage":
        path.write_bytes(b"this is not an npz file")
    elif damage == "truncated":
        path.write_bytes(path.read_bytes()[:200])
    elif damage == "wrong_shape":
        sp.save_npz(path, sp.random(10, 20, density=0.2, format="csr", dtype=np.float32))
    else:
        sp.save_npz(path, good.astype(np.float64))
    operators._load_or_build.cache_clear()
    rebuilt = system_matrix(g, directory=tmp_path)
    assert rebuilt.shape == good.shape and rebuilt.dtype == np.float32
    assert (rebuilt != good).nnz == 0
    # the file was repaired
    fixed = sp.load_npz(path)
    assert fixed.shape == good.shape and fixed.dtype == np.float32
    operators._load_or_build.cache_clear()


def test_stale_build_temporaries_are_removed(tmp_path) -> None:
    """A killed build leaves its temporary; the next build removes it once it is old, not while it may be in use."""
    g = get_preset("tiny-fan")
    operators._load_or_build.cache_clear()
    system_matrix(g, directory=tmp_path)
    (path,) = tmp_path.glob("*.npz")
    old, recent = (tmp_path / f"{path.stem}.{pid}.7.tmp.npz" for pid in (111, 222))
    other = tmp_path / "another-matrix.111.7.tmp.npz"
    for p in (old, recent, other):
        p.write_bytes(b"half a matrix")
    hours_ago = time.time() - 2 * operators.STALE_BUILD_SECONDS
    os.utime(old, (hours_ago, hours_ago))
    os.utime(other, (hours_ago, hours_ago))
    path.unlink()
    operators._load_or_build.cache_clear()
    system_matrix(g, directory=tmp_path)
    assert path.exists() and not old.exists()
    assert recent.exists() and other.exists()  # possibly another writer's; another matrix's
    operators._load_or_build.cache_clear()


def test_system_matrix_uses_env_cache_dir(tmp_path, monkeypatch) -> None:
    target = tmp_path / "env-cache"
    monkeypatch.setenv("NANOCT_CACHE", str(target))
    assert cache_dir() == target
    operators._load_or_build.cache_clear()
    system_matrix(get_preset("tiny-fan"))
    assert len(list(target.glob("*.npz"))) == 1
    operators._load_or_build.cache_clear()


# ---------------------------------------------------------------------------------- motion model
@pytest.mark.parametrize("t1", [3, -2])
def test_integer_shift_is_detector_shift_at_view_zero(t1: int) -> None:
    """Parallel view 0 has e_u = (1, 0): x(r + t) with t = (t1, 0) moves the object by -t1,
    so the moved projection is the unmoved one shifted by -t1 pixels, p_m[l] = p[l + t1]."""
    g = get_preset("tiny-parallel")
    x = blobs(g.n)
    motion = np.zeros((g.n_angles, 3))
    motion[:, 0] = t1
    moved = RayTransform(g, motion)(x)[0]
    still = RayTransform(g)(x)[0]
    L, m = g.n_det, 5
    idx = np.arange(m, L - m)
    np.testing.assert_allclose(moved[idx], still[idx + t1], rtol=0, atol=1e-6)
    # the opposite direction is clearly wrong
    assert np.abs(moved[idx] - still[idx - t1]).max() > 0.2 * still.max()
    # the centroid moves by -t1
    s = np.arange(L) - (L - 1) / 2
    assert (moved * s).sum() / moved.sum() == pytest.approx((still * s).sum() / still.sum() - t1, abs=1e-3)


def test_shift_along_r2_does_not_change_view_zero_but_view_90() -> None:
    g = get_preset("tiny-parallel")  # view 70 is 90 degrees: e_u = (0, 1)
    x = blobs(g.n)
    motion = np.zeros((g.n_angles, 3))
    motion[:, 1] = 2
    moved = RayTransform(g, motion)(x)
    still = RayTransform(g)(x)
    np.testing.assert_allclose(moved[0], still[0], atol=1e-6)
    idx = np.arange(5, g.n_det - 5)
    np.testing.assert_allclose(moved[70, idx], still[70, idx + 2], atol=1e-5)


def test_subpixel_shift_is_detector_shift_every_view() -> None:
    """p_k(s) = p_k_unmoved(s + t_k . e_u(phi_k)) in parallel beam, up to interpolation."""
    g = get_preset("tiny-parallel")
    x = blobs(g.n)
    rng = np.random.default_rng(11)
    motion = np.zeros((g.n_angles, 3))
    motion[:, :2] = rng.uniform(-2, 2, (g.n_angles, 2))
    moved = RayTransform(g, motion)(x)
    still = RayTransform(g)(x)
    s = np.arange(g.n_det) - (g.n_det - 1) / 2
    shift = motion[:, 0] * np.cos(g.angles) + motion[:, 1] * np.sin(g.angles)
    good = np.array([rel(moved[k], np.interp(s + shift[k], s, still[k])) for k in range(g.n_angles)])
    flipped = np.array([rel(moved[k], np.interp(s - shift[k], s, still[k])) for k in range(g.n_angles)])
    # measured: good mean 0.007, max 0.083; flipped mean 0.28
    assert good.mean() < 0.02
    assert good.max() < 0.15
    assert flipped.mean() > 0.15


@pytest.mark.slow
@pytest.mark.parametrize(
    "name, projector, tol",
    [("tiny-parallel", "line", 0.04), ("tiny-parallel", "strip", 0.01), ("tiny-fan", None, 0.04)],
)
@pytest.mark.parametrize("order", [1, 3])
def test_motion_matches_warp_then_project(name: str, projector: str | None, tol: float, order: int) -> None:
    """Exact ray motion agrees with warping the image to x(R r + t) and projecting it with
    the unperturbed operator; flipping the sign of t or theta is much worse.

    Measured worst tested view: line 0.029 (near-axis-aligned views, where the line
    projector's weights change most under a small tilt of the rays; 5e-4 at other angles),
    strip 0.005, fan 0.028; flipped t >= 0.44, flipped theta >= 0.065."""
    g = get_preset(name)
    x = blobs(g.n)
    K = g.n_angles
    views = np.linspace(0, K - 1, 6).round().astype(int)
    rng = np.random.default_rng(5)
    # shifts of 2-3 px along and across the detector axis of each tested view (so flipping t
    # moves the projection by 4-6 px), rotations of 4-6 degrees, random signs
    signs = rng.choice([-1.0, 1.0], size=(K, 3))
    along, across = signs[:, :2].T * rng.uniform(2.0, 3.0, (2, K))
    c, s = np.cos(g.angles), np.sin(g.angles)
    motion = np.column_stack([along * c - across * s, along * s + across * c, signs[:, 2] * rng.uniform(4.0, 6.0, K)])
    exact = RayTransform(g, motion, projector=projector)(x)
    still = RayTransform(g, projector=projector)
    for k in views:
        t, th = motion[k, :2], motion[k, 2]
        errs = {
            label: rel(still(warp(x, st * t, sth * th, order))[k], exact[k])
            for label, st, sth in (("ok", 1, 1), ("-t", -1, 1), ("-theta", 1, -1))
        }
        assert errs["ok"] < tol, (k, errs)
        assert errs["-t"] > 5 * errs["ok"] and errs["-t"] > 0.2, (k, errs)
        assert errs["-theta"] > 2.5 * errs["ok"] and errs["-theta"] > 0.04, (k, errs)


@pytest.mark.parametrize("name", ["tiny-parallel", "tiny-fan"])
def test_moved_point_lands_where_the_model_says(name: str) -> None:
    """A point r0 of x appears in x_k at r = R(theta)^-1 (r0 - t); its projection's centroid
    follows the unmoved geometry's formula for that position."""
    g = get_preset(name)
    n, K = g.n, g.n_angles
    row, col = 20, 45
    r0 = np.array([col - (n - 1) / 2, (n - 1) / 2 - row])
    x = np.zeros(g.image_shape, np.float32)
    x[row, col] = 1
    rng = np.random.default_rng(2)
    motion = random_motion(rng, K, shift=3.0, rot=10.0).astype(np.float64)
    projector = "strip" if g.kind == "parallel" else None
    sino = RayTransform(g, motion, projector=projector)(x)
    u = (np.arange(g.n_det) - (g.n_det - 1) / 2) * g.det_spacing
    cent = (sino * u).sum(axis=1) / sino.sum(axis=1)
    th = np.deg2rad(motion[:, 2])
    d = r0[None, :] - motion[:, :2]
    p1 = np.cos(th) * d[:, 0] + np.sin(th) * d[:, 1]  # R(-theta) d
    p2 = -np.sin(th) * d[:, 0] + np.cos(th) * d[:, 1]
    c, s = np.cos(g.angles), np.sin(g.angles)
    along = p1 * c + p2 * s
    if g.kind == "parallel":
        expected, tol = along, 0.06
    else:
        R, D = g.source_radius, g.detector_radius
        expected, tol = along * (R + D) / (R - p1 * s + p2 * c), 0.5
    np.testing.assert_allclose(cent, expected, atol=tol)


# ---------------------------------------------------------------------------------- mass
@pytest.mark.parametrize(
    "projector, tol", [("strip", 1e-4), ("distance_driven", 1e-4), ("line", 1.5e-2), ("linear", 1.5e-2)]
)
@pytest.mark.parametrize("moving", [False, True])
def test_parallel_view_sums_equal_image_sum(projector: str, tol: float, moving: bool) -> None:
    """With det_spacing 1, sum_l p_k(l) approximates the integral of p_k over s, which is the
    image's mass, in every view (also moved, as long as the object stays in the field).
    Exact for the area-based projectors; measured worst views on this phantom: line 6.8e-3,
    linear 4.8e-3, distance_driven 8e-6, strip 1.3e-6."""
    g = get_preset("tiny-parallel")
    x = random_phantom(np.random.default_rng((0, 0)), g.n)
    rng = np.random.default_rng(4)
    motion = random_motion(rng, g.n_angles) if moving else None
    sino = RayTransform(g, motion, projector=projector)(x)
    np.testing.assert_allclose(sino.sum(axis=1, dtype=np.float64), x.sum(dtype=np.float64), rtol=tol)


@pytest.mark.parametrize("moving", [False, True])
def test_parallel_view_sums_with_oversample(moving: bool) -> None:
    """Fine pixels have area 1/oversample^2: the mass is x_fine.sum() / 4 for oversample 2."""
    g = get_preset("tiny-parallel")
    fine = random_phantom(np.random.default_rng((0, 0)), g.n, oversample=2)
    motion = random_motion(np.random.default_rng(4), g.n_angles) if moving else None
    sino = RayTransform(g, motion, projector="strip", oversample=2)(fine)
    np.testing.assert_allclose(sino.sum(axis=1, dtype=np.float64), fine.sum(dtype=np.float64) / 4, rtol=1e-4)


def test_parallel_view_sum_scales_with_det_spacing() -> None:
    g = Geometry("parallel", 63, 20, 183, det_spacing=0.5)
    x = blobs(g.n)
    sino = RayTransform(g, projector="strip")(x)
    np.testing.assert_allclose(sino.sum(axis=1) * g.det_spacing, x.sum(), rtol=1e-4)


# Fan beam: for a flat detector, sum_u p(u) du = integral of x(r) w(r, phi) dr with the weight
# w = (R + D) / ((R - r.e_src) cos(gamma)) that depends on the point (magnification times the
# obliquity of the ray through it); the view sums are therefore not exactly proportional to the
# image sum and are not tested against it.


# ---------------------------------------------------------------------------------- oversampling
@pytest.mark.parametrize("name", ["tiny-parallel", "tiny-fan"])
@pytest.mark.parametrize("moving", [False, True])
def test_oversample_of_block_replicated_image(name: str, moving: bool) -> None:
    """Line integrals of a piecewise constant image do not depend on how finely it is
    pixelated: oversample=2 of the block-replicated image equals oversample=1 (measured
    relative L2 difference <= 5e-5)."""
    g = get_preset(name)
    rng = np.random.default_rng(9)
    motion = random_motion(rng, g.n_angles) if moving else None
    x = rng.random(g.image_shape).astype(np.float32)
    coarse = RayTransform(g, motion)(x)
    fine = RayTransform(g, motion, oversample=2)(np.kron(x, np.ones((2, 2), np.float32)))
    assert rel(fine, coarse) < 1e-3
    # sanity: a one-sub-pixel shift of the fine image is detected
    shifted = np.roll(np.kron(x, np.ones((2, 2), np.float32)), 1, axis=1)
    assert rel(RayTransform(g, motion, oversample=2)(shifted), coarse) > 10 * rel(fine, coarse)


def test_oversample_of_phantom_close_to_coarse() -> None:
    """The finer model of the same continuous phantom stays close to the coarse one."""
    g = get_preset("tiny-parallel")
    fine_img = random_phantom(np.random.default_rng((0, 3)), g.n, oversample=2)
    coarse = RayTransform(g)(downsample(fine_img, 2))
    fine = RayTransform(g, oversample=2)(fine_img)
    assert rel(fine, coarse) < 0.02  # measured 0.014 (partial-volume pixels at the edges)


# ---------------------------------------------------------------------------------- validation
@pytest.fixture(scope="module")
def par_op() -> RayTransform:
    return RayTransform(get_preset("tiny-parallel"))


@pytest.mark.parametrize(
    "image, match",
    [
        (np.zeros((63, 62), np.float32), "image"),
        (np.zeros((62, 63), np.float32), "image"),
        (np.zeros((126, 126), np.float32), "image"),
        (np.zeros(63 * 63, np.float32), "image"),
        (np.full((63, 63), np.nan, np.float32), "image.*NaN"),
        (np.where(np.eye(63) > 0, np.inf, 0).astype(np.float32), "image.*infinite"),
        (np.zeros((63, 63), np.complex64), "image"),
    ],
)
def test_forward_rejects_bad_images(par_op: RayTransform, image: np.ndarray, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        par_op.forward(image)


@pytest.mark.parametrize(
    "sino, match",
    [
        (np.zeros((91, 140), np.float32), "sinogram"),  # transposed
        (np.zeros((140, 90), np.float32), "sinogram"),
        (np.full((140, 91), np.nan, np.float32), "sinogram.*NaN"),
    ],
)
def test_adjoint_rejects_bad_sinograms(par_op: RayTransform, sino: np.ndarray, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        par_op.adjoint(sino)


def test_forward_accepts_float64_and_int(par_op: RayTransform) -> None:
    x = blobs(63)
    ref = par_op(x)
    np.testing.assert_allclose(par_op(x.astype(np.float64)), ref, atol=1e-6)
    assert par_op(np.ones((63, 63), np.int64)).dtype == np.float32


@pytest.mark.parametrize(
    "motion",
    [
        np.zeros((139, 3)),
        np.zeros((140, 2)),
        np.zeros((3, 140)),
        np.zeros(140 * 3),
        np.full((140, 3), np.nan),
    ],
)
def test_bad_motion_raises(motion: np.ndarray) -> None:
    with pytest.raises(ValueError, match="motion"):
        RayTransform(get_preset("tiny-parallel"), motion)


@pytest.mark.parametrize(
    "name, projector",
    [
        ("tiny-parallel", "nonsense"),
        ("tiny-parallel", "line_fanflat"),
        ("tiny-parallel", "cuda"),
        ("tiny-fan", "line"),
        ("tiny-fan", "strip"),
    ],
)
def test_unknown_projector_raises(name: str, projector: str, tmp_path) -> None:
    g = get_preset(name)
    with pytest.raises(ValueError, match="projector"):
        RayTransform(g, projector=projector)
    with pytest.raises(ValueError, match="projector"):
        system_matrix(g, projector, directory=tmp_path)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("oversample", [0, -1, 1.5, "2"])
def test_bad_oversample_raises(oversample) -> None:
    with pytest.raises(ValueError, match="oversample"):
        RayTransform(get_preset("tiny-parallel"), oversample=oversample)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["tiny-parallel", "tiny-fan"])
def test_oversampled_system_matrix_matches_forward(name: str, tmp_path) -> None:
    g = get_preset(name)
    mat = system_matrix(g, oversample=2, directory=tmp_path)
    assert mat.shape == (g.n_angles * g.n_det, (2 * g.n) ** 2) and mat.dtype == np.float32
    x = np.random.default_rng(0).random((2 * g.n, 2 * g.n)).astype(np.float32)
    np.testing.assert_allclose(
        (mat @ x.ravel()).reshape(g.sino_shape), RayTransform(g, oversample=2).forward(x), rtol=1e-5, atol=1e-4
    )
    assert system_matrix(g, directory=tmp_path).shape[1] == g.n**2  # a separate cache entry
