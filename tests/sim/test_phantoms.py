"""Tests for nanoct.sim.phantoms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nanoct.sim.phantoms import (
    FOV_FRACTION,
    PhantomSpec,
    Shape,
    downsample,
    family_phantom,
    pixel_centers,
    random_ellipse_phantom,
    random_phantom,
    random_phantom_spec,
    rasterize,
)

SEEDS = range(40)


def rng(seed: int, index: int = 0) -> np.random.Generator:
    return np.random.default_rng((seed, index))


@pytest.mark.parametrize("n, oversample", [(16, 1), (64, 1), (64, 2), (255, 2), (33, 3)])
def test_shape_dtype_range(n: int, oversample: int) -> None:
    x = random_phantom(rng(0), n, oversample=oversample)
    assert x.shape == (n * oversample, n * oversample)
    assert x.dtype == np.float32
    assert x.min() >= 0.0 and x.max() <= 1.0


@pytest.mark.parametrize("seed", SEEDS)
def test_background_zero_and_not_empty(seed: int) -> None:
    x = random_phantom(rng(seed), 64)
    assert x[0, 0] == x[0, -1] == x[-1, 0] == x[-1, -1] == 0.0
    # The main shape (density >= 0.1) covers a good part of the field of view.
    assert np.count_nonzero(x) > 0.02 * x.size


def test_deterministic() -> None:
    a = random_phantom(rng(7, 3), 128, oversample=2)
    b = random_phantom(rng(7, 3), 128, oversample=2)
    assert a.tobytes() == b.tobytes()
    assert random_phantom_spec(rng(7, 3), 128) == random_phantom_spec(rng(7, 3), 128)


def test_different_seeds_differ() -> None:
    images = [random_phantom(rng(0, i), 64).tobytes() for i in range(10)]
    assert len(set(images)) == 10
    assert random_phantom(rng(1, 0), 64).tobytes() != random_phantom(rng(2, 0), 64).tobytes()


@pytest.mark.parametrize("oversample", [1, 2, 3])
def test_random_phantom_composes_spec_and_rasterize(oversample: int) -> None:
    expected = rasterize(random_phantom_spec(rng(5), 48), 48, oversample)
    np.testing.assert_array_equal(random_phantom(rng(5), 48, oversample=oversample), expected)


def test_pixel_centers_convention() -> None:
    r1, r2 = pixel_centers(5)
    np.testing.assert_array_equal(r1.ravel(), [-2, -1, 0, 1, 2])
    np.testing.assert_array_equal(r2.ravel(), [2, 1, 0, -1, -2])
    # Fine centres average to the coarse centres.
    f1, f2 = pixel_centers(5, 4)
    np.testing.assert_allclose(f1.reshape(5, 4).mean(axis=1), r1.ravel())
    np.testing.assert_allclose(f2.reshape(5, 4).mean(axis=1), r2.ravel())


def test_orientation_convention() -> None:
    # A small disc at r1 = +10 (right), r2 = +5 (up) must land at col = c + 10, row = c - 5.
    n = 33
    c = (n - 1) // 2
    spec = PhantomSpec((Shape("ellipse", (10.0, 5.0), (1.2, 1.2), 0.0, 1.0),))
    x = rasterize(spec, n)
    rows, cols = np.nonzero(x)
    assert (rows.mean(), cols.mean()) == (c - 5, c + 10)
    # A rectangle rotated by 90 degrees swaps its extents.
    wide = PhantomSpec((Shape("rectangle", (0.0, 0.0), (8.0, 2.0), 90.0, 1.0),))
    rows, cols = np.nonzero(rasterize(wide, n))
    assert np.ptp(rows) > np.ptp(cols)


@pytest.mark.parametrize("seed", range(8))
def test_oversampled_downsample_matches_coarse(seed: int) -> None:
    n = 128
    spec = random_phantom_spec(rng(seed), n)
    coarse = rasterize(spec, n)
    fine = downsample(rasterize(spec, n, 2), 2)
    assert fine.shape == coarse.shape and fine.dtype == np.float32
    assert np.abs(fine - coarse).mean() < 0.01
    assert fine.sum() == pytest.approx(coarse.sum(), rel=0.03)


def test_downsample_block_mean() -> None:
    fine = np.arange(16, dtype=np.float32).reshape(4, 4)
    np.testing.assert_allclose(downsample(fine, 2), [[2.5, 4.5], [10.5, 12.5]])
    np.testing.assert_array_equal(downsample(fine, 1), fine)


@pytest.mark.parametrize("seed", SEEDS)
def test_main_shape_inside_inscribed_circle(seed: int) -> None:
    n = 64
    spec = random_phantom_spec(rng(seed), n)
    main = spec.main
    assert math.hypot(*main.center) + main.bounding_radius <= FOV_FRACTION * (n - 1) / 2 + 1e-9
    x = rasterize(spec, n, 2)
    r1, r2 = pixel_centers(n, 2)
    radius = np.hypot(r1, r2)
    assert radius[x > 0].max() <= FOV_FRACTION * (n - 1) / 2


def _boundary(shape: Shape, m: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """Points on the outline of a shape."""
    a, b = shape.half_axes
    t = np.linspace(0.0, 2.0 * np.pi, m, endpoint=False)
    if shape.kind == "ellipse":
        u, v = a * np.cos(t), b * np.sin(t)
    else:
        s = np.linspace(-1.0, 1.0, m // 4)
        u = np.concatenate([a * s, a * s, -a + 0 * s, a + 0 * s])
        v = np.concatenate([-b + 0 * s, b + 0 * s, b * s, b * s])
    th = np.deg2rad(shape.angle)
    r1 = shape.center[0] + np.cos(th) * u - np.sin(th) * v
    r2 = shape.center[1] + np.sin(th) * u + np.cos(th) * v
    return r1, r2


@pytest.mark.parametrize("seed", SEEDS)
def test_subshapes_strictly_inside_main(seed: int) -> None:
    spec = random_phantom_spec(rng(seed), 255)
    main = spec.main
    # Shrink the main shape slightly: the sub-shapes must still fit.
    shrunk = Shape(main.kind, main.center, tuple(0.99 * h for h in main.half_axes), main.angle, 1.0)
    for sub in spec.subshapes:
        assert shrunk.contains(*_boundary(sub)).all()


def test_shape_statistics() -> None:
    specs = [random_phantom_spec(rng(1, i), 64) for i in range(200)]
    counts = {len(s.subshapes) for s in specs}
    assert counts == {0, 1, 2, 3}
    kinds = {s.main.kind for s in specs}
    assert kinds == {"ellipse", "rectangle"}
    assert {sub.kind for s in specs for sub in s.subshapes} == {"ellipse", "rectangle"}
    assert all(0.1 <= s.main.density <= 1.0 for s in specs)
    assert all(0.0 <= sub.density <= 1.0 for s in specs for sub in s.subshapes)


@pytest.mark.parametrize("n", [15, 0, -3, 16.0, 20.5, "64", True])
def test_bad_n(n: object) -> None:
    with pytest.raises(ValueError, match="n="):
        random_phantom(rng(0), n)  # type: ignore[arg-type]


@pytest.mark.parametrize("oversample", [0, -1, 1.5, 2.0, None])
def test_bad_oversample(oversample: object) -> None:
    with pytest.raises(ValueError, match="oversample="):
        random_phantom(rng(0), 32, oversample=oversample)  # type: ignore[arg-type]


def test_bad_downsample_shape() -> None:
    with pytest.raises(ValueError, match="divisible"):
        downsample(np.zeros((5, 6), dtype=np.float32), 2)


def test_bad_rng() -> None:
    with pytest.raises(TypeError, match="Generator"):
        random_phantom(np.random.RandomState(0), 32)  # type: ignore[arg-type]


def test_bad_shape() -> None:
    with pytest.raises(ValueError, match="kind="):
        Shape("triangle", (0.0, 0.0), (1.0, 1.0), 0.0, 0.5)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="density="):
        Shape("ellipse", (0.0, 0.0), (1.0, 1.0), 0.0, 1.5)
    with pytest.raises(ValueError, match="half_axes="):
        Shape("ellipse", (0.0, 0.0), (0.0, 1.0), 0.0, 0.5)


@pytest.mark.parametrize("seed", range(20))
def test_ellipse_family_is_a_head_inside_the_field_of_view(seed: int) -> None:
    """Shepp-Logan-like: values in [0, 1], zero outside the allowed disc, a rim denser than the body's middle."""
    n = 64
    x = random_ellipse_phantom(rng(seed), n, oversample=2)
    assert x.shape == (2 * n, 2 * n) and x.dtype == np.float32
    assert x.min() >= 0.0 and x.max() <= 1.0
    r1, r2 = pixel_centers(n, 2)
    outside = np.hypot(r1, r2) > FOV_FRACTION * (n - 1) / 2
    assert not x[outside].any() and np.count_nonzero(x) > 0.1 * x.size
    assert x.max() >= 0.6  # the rim


def test_ellipse_family_differs_from_the_training_generator() -> None:
    """Same generator state, other family: other images; more distinct grey levels (overlapping additive ellipses)."""
    for i in range(5):
        a, b = random_phantom(rng(3, i), 64), random_ellipse_phantom(rng(3, i), 64)
        assert a.tobytes() != b.tobytes()
        assert len(np.unique(b)) > len(np.unique(a))
    np.testing.assert_array_equal(
        family_phantom("shapes", rng(4), 48, oversample=2), random_phantom(rng(4), 48, oversample=2)
    )
    np.testing.assert_array_equal(family_phantom("ellipses", rng(4), 48), random_ellipse_phantom(rng(4), 48))
    assert random_ellipse_phantom(rng(4), 48).tobytes() == random_ellipse_phantom(rng(4), 48).tobytes()
    with pytest.raises(ValueError, match="phantom family 'disks' is unknown"):
        family_phantom("disks", rng(0), 48)
