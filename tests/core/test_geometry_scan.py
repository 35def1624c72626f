"""Scan geometries: explicit view angles and a rotation-axis offset (measured data)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from nanoct.core.geometry import Geometry, get_preset
from nanoct.core.operators import RayTransform, system_matrix


def test_presets_describe_themselves_as_before():
    """The new fields stay out of preset descriptions (stored data sets and cache keys)."""
    g = get_preset("tiny-parallel")
    assert g.to_dict() == {
        "kind": "parallel",
        "n": 63,
        "n_angles": 140,
        "n_det": 91,
        "det_spacing": 1.0,
        "angle_range": math.pi,
        "source_radius": 0.0,
        "detector_radius": 0.0,
    }
    assert "center_offset" not in g.key() and "view_angles" not in g.key()


@pytest.mark.parametrize("kind", ["parallel", "fan"])
def test_round_trip_through_json(kind):
    base = get_preset(f"tiny-{kind}")
    rng = np.random.default_rng(0)
    g = Geometry.from_angles(
        rng.uniform(0, 360, base.n_angles), base.n, base.n_det, kind=kind, degrees=True, center_offset=-2.5,
        source_radius=base.source_radius, detector_radius=base.detector_radius,
    )  # fmt: skip
    again = Geometry.from_dict(json.loads(json.dumps(g.to_dict())))
    assert again == g
    assert again.key() == g.key() != base.key()
    np.testing.assert_allclose(g.angles, np.deg2rad(np.asarray(again.view_angles) * 180 / np.pi))


@pytest.mark.parametrize("kind", ["parallel", "fan"])
def test_explicit_uniform_angles_give_the_preset_operator(kind):
    g = get_preset(f"tiny-{kind}")
    explicit = Geometry.from_angles(
        g.angles, g.n, g.n_det, kind=kind, source_radius=g.source_radius, detector_radius=g.detector_radius
    )
    x = np.random.default_rng(1).random(g.image_shape, dtype=np.float32)
    np.testing.assert_array_equal(RayTransform(explicit).forward(x), RayTransform(g).forward(x))
    np.testing.assert_allclose(explicit.angle_weights, g.angle_weights, rtol=1e-12)


def test_permuted_angles_permute_the_views():
    g = get_preset("tiny-parallel")
    perm = np.random.default_rng(2).permutation(g.n_angles)
    shuffled = Geometry.from_angles(g.angles[perm], g.n, g.n_det)
    x = np.random.default_rng(3).random(g.image_shape, dtype=np.float32)
    np.testing.assert_array_equal(RayTransform(shuffled).forward(x), RayTransform(g).forward(x)[perm])
    np.testing.assert_allclose(shuffled.angle_weights, g.angle_weights[perm], rtol=1e-12)


@pytest.mark.parametrize("kind", ["parallel", "fan"])
@pytest.mark.parametrize("offset", [3.0, -4.0])
def test_rotation_axis_is_seen_at_centre_plus_offset(kind, offset):
    """A point on the rotation axis projects onto detector pixel (L-1)/2 + offset in every view."""
    base = get_preset(f"tiny-{kind}")
    g = Geometry.from_angles(
        base.angles, base.n, base.n_det, kind=kind, center_offset=offset,
        source_radius=base.source_radius, detector_radius=base.detector_radius,
    )  # fmt: skip
    x = np.zeros(g.image_shape, dtype=np.float32)
    x[g.n // 2, g.n // 2] = 1.0  # pixel centred on the axis (N odd)
    sino = RayTransform(g).forward(x)
    assert (sino.argmax(axis=1) == (g.n_det - 1) / 2 + offset).all()
    # and a point off the axis moves by the offset too (the sinusoid is shifted, not deformed)
    x[:] = 0
    x[10, 40] = 1.0
    centroid = lambda s: (s * np.arange(g.n_det)).sum(1) / s.sum(1)  # noqa: E731
    shifted, plain = RayTransform(g).forward(x), RayTransform(base).forward(x)
    np.testing.assert_allclose(centroid(shifted) - centroid(plain), offset, atol=1e-3)


def test_system_matrix_follows_the_offset(tmp_path):
    base = get_preset("tiny-parallel")
    g = Geometry.from_angles(base.angles[::-1], base.n, base.n_det, center_offset=1.5)
    x = np.random.default_rng(4).random(g.image_shape, dtype=np.float32)
    mat = system_matrix(g, directory=tmp_path)
    np.testing.assert_allclose((mat @ x.ravel()).reshape(g.sino_shape), RayTransform(g).forward(x), atol=1e-4)


def test_angle_weights_of_an_uneven_scan():
    # parallel views at 0, 10, 30 and 90 degrees on the circle of period 180
    g = Geometry.from_angles([0, 10, 30, 90], 15, 25, degrees=True)
    gaps = np.deg2rad(np.array([10, 20, 60, 90]))  # to the next view, wrapping 90 -> 180
    expected = 0.5 * (gaps + np.roll(gaps, 1))
    np.testing.assert_allclose(g.angle_weights, expected, rtol=1e-12)
    assert g.angle_weights.sum() == pytest.approx(math.pi)
    # a 360-degree parallel scan counts every direction twice: weights halve
    full = Geometry.from_angles(np.arange(0, 360, 2.0), 15, 25, degrees=True)
    np.testing.assert_allclose(full.angle_weights, np.deg2rad(1.0), rtol=1e-12)


@pytest.mark.parametrize(
    ("angles", "n_angles", "message"),
    [
        ([0.0, 0.1], 3, "n_angles=3"),
        ([0.0, float("nan"), 0.2], 3, "NaN"),
        ([0.0, 0.1, 2 * math.pi], 3, "repeats"),
    ],
)
def test_bad_view_angles(angles, n_angles, message):
    with pytest.raises(ValueError, match=message):
        Geometry("parallel", 15, n_angles, 25, view_angles=tuple(angles))


def test_bad_center_offset():
    with pytest.raises(ValueError, match="center_offset"):
        Geometry("parallel", 15, 4, 25, center_offset=float("inf"))


def _phantom(n):
    from nanoct.sim.phantoms import random_phantom

    return random_phantom(np.random.default_rng(7), n).astype(np.float32)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["parallel", "fan"])
def test_fbp_with_the_scan_offset_is_sharper_than_without(kind):
    from nanoct.evaluation.metrics import psnr
    from nanoct.recon.fbp import fbp

    base = get_preset(f"tiny-{kind}")
    scan = Geometry.from_angles(
        base.angles, base.n, base.n_det, kind=kind, center_offset=2.5,
        source_radius=base.source_radius, detector_radius=base.detector_radius,
    )  # fmt: skip
    x = _phantom(base.n)
    sino = RayTransform(scan).forward(x)
    right, wrong = fbp(scan, sino).image, fbp(base, sino).image
    assert psnr(right, x) > psnr(wrong, x) + 3.0
    assert psnr(right, x) == pytest.approx(psnr(fbp(base, RayTransform(base).forward(x)).image, x), abs=1.0)


def test_fbp_weights_explicit_angles():
    from nanoct.recon.fbp import fbp

    base = get_preset("tiny-parallel")
    x = _phantom(base.n)
    reference = fbp(base, RayTransform(base).forward(x)).image
    perm = np.random.default_rng(8).permutation(base.n_angles)
    shuffled = Geometry.from_angles(base.angles[perm], base.n, base.n_det)
    np.testing.assert_allclose(fbp(shuffled, RayTransform(shuffled).forward(x)).image, reference, atol=1e-5)
    # the same directions scanned over 360 degrees (twice the views) give the same image
    full = Geometry.from_angles(np.r_[base.angles, base.angles + np.pi], base.n, base.n_det)
    np.testing.assert_allclose(fbp(full, RayTransform(full).forward(x)).image, reference, atol=1e-4)
