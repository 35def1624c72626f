"""Tests for nanoct.core.geometry: presets, validation, serialisation and the axis conventions.

The convention tests project single bright pixels with :class:`nanoct.core.operators.RayTransform`
and compare where they land with the formulas of the ``geometry`` module docstring, so a
swapped axis, a flipped sign or a wrong angle origin fails here.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os

import numpy as np
import pytest

from nanoct.core.geometry import PRESETS, Geometry, get_preset, preset_names
from nanoct.core.operators import RayTransform

PAPER_N = 255
PAPER = {"parallel": {"K": 567, "L": 363}, "fan": {"K": 133, "L": 723, "R": 7773.4}}


@pytest.fixture(scope="module", autouse=True)
def _cache_dir(tmp_path_factory: pytest.TempPathFactory):
    """Keep any operator cache out of the home directory."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setitem(os.environ, "NANOCT_CACHE", str(tmp_path_factory.mktemp("nanoct-cache")))
        yield


def centred(n: int) -> np.ndarray:
    """Detector/image coordinate (i - (n-1)/2) of index i."""
    return np.arange(n) - (n - 1) / 2


def point_image(n: int, row: int, col: int) -> np.ndarray:
    x = np.zeros((n, n), dtype=np.float32)
    x[row, col] = 1.0
    return x


# ---------------------------------------------------------------------------------- presets
def test_preset_names() -> None:
    names = preset_names()
    assert names == sorted(PRESETS)
    assert set(names) == {f"{s}-{k}" for s in ("paper", "small", "tiny") for k in ("parallel", "fan")}


def test_paper_parallel_numbers() -> None:
    g = get_preset("paper-parallel")
    assert (g.kind, g.n, g.n_angles, g.n_det) == ("parallel", 255, 567, 363)
    assert g.det_spacing == 1.0
    assert g.angle_range == pytest.approx(math.pi, abs=1e-15)
    assert g.magnification == 1.0
    phi = g.angles
    assert phi.shape == (567,) and phi.dtype == np.float64
    assert phi[0] == 0.0
    assert phi[-1] < math.pi  # [0, pi): the end point is not a view
    np.testing.assert_allclose(np.diff(phi), math.pi / 567, rtol=0, atol=1e-12)
    assert g.image_shape == (255, 255)
    assert g.sino_shape == (567, 363)


def test_paper_fan_numbers() -> None:
    g = get_preset("paper-fan")
    assert (g.kind, g.n, g.n_angles, g.n_det) == ("fan", 255, 133, 723)
    assert g.source_radius == 7773.4
    assert g.angle_range == pytest.approx(2 * math.pi, abs=1e-15)
    phi = g.angles
    assert phi[0] == 0.0 and phi[-1] < 2 * math.pi
    np.testing.assert_allclose(np.diff(phi), 2 * math.pi / 133, rtol=0, atol=1e-12)
    # The paper gives no detector distance; the package's documented choice is a detector as
    # far behind the axis as the source is in front (magnification 2, 1 px pixels).
    assert g.detector_radius == g.source_radius
    assert g.magnification == pytest.approx(2.0)
    assert g.sino_shape == (133, 723)


@pytest.mark.parametrize("size, n", [("small", 127), ("tiny", 63)])
@pytest.mark.parametrize("kind", ["parallel", "fan"])
def test_scaled_presets_keep_ratios(size: str, n: int, kind: str) -> None:
    g = get_preset(f"{size}-{kind}")
    p = PAPER[kind]
    assert g.kind == kind and g.n == n
    scale = n / PAPER_N
    # K/N kept: K is the scaled number of views, rounded (within one view).
    assert abs(g.n_angles - p["K"] * scale) <= 1
    # L/N kept: L is odd (a central pixel on the axis) and the smallest odd count >= the
    # scaled one (tiny-parallel: 89.68 -> 91), plus 2 where the rounding would leave the
    # corners' shadow on the outermost pixel centres (tiny-fan: 178.6 -> 179 -> 181).
    assert g.n_det % 2 == 1
    assert 0 <= g.n_det - p["L"] * scale < 4
    assert abs(g.n_det / g.n - p["L"] / PAPER_N) < 4 / g.n
    assert abs(g.n_angles / g.n - p["K"] / PAPER_N) < 1 / g.n
    if kind == "fan":
        assert g.source_radius == pytest.approx(p["R"] * scale, rel=1e-12)
        assert g.angle_range == pytest.approx(2 * math.pi)
    else:
        assert g.angle_range == pytest.approx(math.pi)


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_preset_is_unique_object_per_name_and_valid(name: str) -> None:
    g = get_preset(name)
    assert g is PRESETS[name]
    assert g.n_det % 2 == 1
    assert g.n_angles == len(g.angles)


def test_unknown_preset_lists_names() -> None:
    with pytest.raises(ValueError, match="huge-parallel") as info:
        get_preset("huge-parallel")
    for name in preset_names():
        assert name in str(info.value)


# ---------------------------------------------------------------------------------- coverage
@pytest.mark.parametrize("name", sorted(PRESETS))
def test_presets_cover_image(name: str) -> None:
    assert get_preset(name).covers_image()


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(PRESETS))
def test_inscribed_disc_leaves_edge_pixels_empty(name: str) -> None:
    """A disc filling the image (radius N/2) never reaches the outermost detector pixels."""
    g = get_preset(name)
    r = centred(g.n)
    disc = ((r[None, :] ** 2 + r[:, None] ** 2) <= (g.n / 2) ** 2).astype(np.float32)
    sino = RayTransform(g)(disc)
    assert sino.max() > 0.5 * g.n  # the disc is really seen
    assert np.all(sino[:, 0] == 0) and np.all(sino[:, -1] == 0)


@pytest.mark.slow
@pytest.mark.parametrize(
    "name",
    [name for name in sorted(PRESETS)],
)
def test_full_square_leaves_edge_pixels_empty(name: str) -> None:
    """An image of ones (the whole square) leaves the first and last pixel empty in every view."""
    g = get_preset(name)
    sino = RayTransform(g)(np.ones(g.image_shape, dtype=np.float32))
    assert sino[:, 1:-1].max() > g.n  # seen
    assert np.all(sino[:, 0] == 0) and np.all(sino[:, -1] == 0)


def _fine_detector(g: Geometry, factor: int, extra: int) -> Geometry:
    """The same geometry with a `factor` times finer detector, wider by `extra` pixel widths."""
    return dataclasses.replace(g, n_det=(g.n_det + 2 * extra) * factor, det_spacing=g.det_spacing / factor)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(PRESETS))
def test_covers_image_matches_shadow_of_image(name: str) -> None:
    """Independent check of covers_image: the image's shadow, sampled on a detector 8 times
    finer and wider than the preset's, lies within the preset detector's extent, and its
    outermost lit sample is near the analytic reach (so the formula is tight, not loose)."""
    g = get_preset(name)
    factor, extra = 8, 4
    fine = _fine_detector(g, factor, extra)
    sino = RayTransform(fine)(np.ones(g.image_shape, dtype=np.float32))
    u = centred(fine.n_det) * fine.det_spacing
    lit = np.abs(u[(sino > 0).any(axis=0)])
    half_det = g.n_det * g.det_spacing / 2
    radius = g.n / 2 * math.sqrt(2)
    if g.kind == "parallel":
        reach = radius
    else:
        reach = (g.source_radius + g.detector_radius) * radius / math.sqrt(g.source_radius**2 - radius**2)
    assert lit.max() <= half_det
    assert lit.max() <= reach + 1e-6
    assert lit.max() > reach - 2 * fine.det_spacing


def test_covers_image_false_when_detector_too_small() -> None:
    for g in (
        Geometry("parallel", 63, 20, 87),  # half 43.5 < 44.55
        Geometry("fan", 63, 20, 179, 1.0, 2 * math.pi, 150.0, 150.0),  # reach 93.3 > 89.5
    ):
        assert not g.covers_image()
        sino = RayTransform(g)(np.ones(g.image_shape, dtype=np.float32))
        assert sino[:, 0].max() > 0 and sino[:, -1].max() > 0  # truncated
    # boundary: the image's circumscribed radius is 31.5 sqrt(2) = 44.55 px; the outermost
    # pixel centres must lie beyond it
    assert not Geometry("parallel", 63, 20, 90).covers_image()  # centres at +-44.5
    assert Geometry("parallel", 63, 20, 91).covers_image()  # centres at +-45.0


# ---------------------------------------------------------------------------------- validation
@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(kind="parallel", n=0, n_angles=10, n_det=11), "n=0"),
        (dict(kind="parallel", n=-5, n_angles=10, n_det=11), "n=-5"),
        (dict(kind="parallel", n=63.0, n_angles=10, n_det=11), "n=63.0"),
        (dict(kind="parallel", n=63, n_angles=0, n_det=11), "n_angles=0"),
        (dict(kind="parallel", n=63, n_angles=10, n_det=0), "n_det=0"),
        (dict(kind="parallel", n=63, n_angles=10, n_det=91, det_spacing=0.0), "det_spacing"),
        (dict(kind="parallel", n=63, n_angles=10, n_det=91, angle_range=0.0), "angle_range"),
        (dict(kind="parallel", n=63, n_angles=10, n_det=91, angle_range=7.0), "angle_range"),
        (dict(kind="cone", n=63, n_angles=10, n_det=91), "cone"),
        (dict(kind="fan", n=63, n_angles=10, n_det=91, source_radius=10.0), "source_radius"),
        (dict(kind="fan", n=63, n_angles=10, n_det=91, source_radius=44.0), "source_radius"),
        (dict(kind="fan", n=63, n_angles=10, n_det=91), "source_radius"),
        (
            dict(kind="fan", n=63, n_angles=10, n_det=91, source_radius=500.0, detector_radius=-1.0),
            "detector_radius",
        ),
    ],
)
def test_invalid_fields_raise(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        Geometry(**kwargs)


def test_fan_source_radius_boundary() -> None:
    half_diag = 63 * math.sqrt(0.5)
    Geometry("fan", 63, 10, 91, 1.0, 2 * math.pi, half_diag + 1e-6, 0.0)
    with pytest.raises(ValueError):
        Geometry("fan", 63, 10, 91, 1.0, 2 * math.pi, half_diag, 0.0)


# ---------------------------------------------------------------------------------- (de)serialisation
@pytest.mark.parametrize("name", sorted(PRESETS))
def test_dict_round_trip(name: str) -> None:
    g = get_preset(name)
    d = g.to_dict()
    # scan-only fields (explicit angles, axis offset) are left out while at their defaults
    assert set(d) == {f.name for f in dataclasses.fields(Geometry)} - {"view_angles", "center_offset"}
    assert Geometry.from_dict(d) == g
    # through JSON, as stored with the data sets
    back = Geometry.from_dict(json.loads(json.dumps(d)))
    assert back == g and back.key() == g.key()
    assert hash(back) == hash(g)


def test_keys_are_distinct() -> None:
    keys = {get_preset(name).key() for name in preset_names()}
    assert len(keys) == len(PRESETS)
    g = get_preset("tiny-parallel")
    assert dataclasses.replace(g, det_spacing=0.5).key() != g.key()


def test_numpy_integer_fields_serialise_to_json() -> None:
    g = Geometry("parallel", np.int64(63), np.int64(140), np.int64(91))
    assert Geometry.from_dict(json.loads(json.dumps(g.to_dict()))) == g


@pytest.mark.parametrize(
    "other",
    [
        dict(kind="parallel", n=np.int64(63), n_angles=140, n_det=91),
        dict(kind="parallel", n=63, n_angles=140, n_det=91, det_spacing=1),
    ],
    ids=["np.int64", "int-spacing"],
)
def test_equal_geometries_have_equal_keys(other: dict) -> None:
    g = get_preset("tiny-parallel")
    h = Geometry(**other)
    assert h == g
    assert h.key() == g.key()


def test_bool_is_not_a_size() -> None:
    with pytest.raises(ValueError, match="n="):
        Geometry("parallel", True, 10, 11)


def test_from_dict_rejects_unknown_and_invalid() -> None:
    d = get_preset("tiny-fan").to_dict()
    with pytest.raises(TypeError):
        Geometry.from_dict({**d, "bogus": 1})
    with pytest.raises(ValueError, match="source_radius"):
        Geometry.from_dict({**d, "source_radius": 1.0})


# ---------------------------------------------------------------------------------- conventions
def test_parallel_point_lands_at_r1_then_r2() -> None:
    """A bright pixel at (row, col) projects to s = r1 at view 0 and s = r2 at 90 degrees.

    r1 = col - (N-1)/2 (right), r2 = (N-1)/2 - row (up); pixel l sits at s = l - (L-1)/2.
    Rows and columns are chosen so that r1 != r2, r1 != -r2 and neither is zero.
    """
    g = get_preset("tiny-parallel")  # K = 140: view 70 is exactly 90 degrees
    n, L = g.n, g.n_det
    row, col = 20, 45
    r1, r2 = col - (n - 1) / 2, (n - 1) / 2 - row
    assert (r1, r2) == (14.0, 11.0)
    sino = RayTransform(g)(point_image(n, row, col))
    s = centred(L) * g.det_spacing

    k90 = int(np.argmin(np.abs(g.angles - math.pi / 2)))
    assert g.angles[k90] == pytest.approx(math.pi / 2)
    # at these two views the rays are grid-aligned: all of the pixel goes to one detector pixel
    assert s[np.argmax(sino[0])] == r1
    assert sino[0].sum() == pytest.approx(1.0, abs=1e-5)
    assert np.count_nonzero(sino[0]) == 1
    assert s[np.argmax(sino[k90])] == r2
    assert np.count_nonzero(sino[k90]) == 1
    # near 45 and 135 degrees: s = (r1 + r2)/sqrt 2 and (r2 - r1)/sqrt 2
    k45, k135 = k90 // 2, 3 * k90 // 2
    cent = (sino * s).sum(axis=1) / sino.sum(axis=1)
    assert cent[k45] == pytest.approx((r1 + r2) / math.sqrt(2), abs=0.5)
    assert cent[k135] == pytest.approx((r2 - r1) / math.sqrt(2), abs=0.5)


def test_parallel_point_sinusoid_every_view() -> None:
    """With the area-weighting 'strip' projector the centroid of a point's projection follows
    s(phi) = r1 cos(phi) + r2 sin(phi) at every view to a twentieth of a pixel."""
    g = get_preset("tiny-parallel")
    n = g.n
    s = centred(g.n_det)
    for row, col in ((20, 45), (50, 10), (31, 40)):
        r1, r2 = col - (n - 1) / 2, (n - 1) / 2 - row
        sino = RayTransform(g, projector="strip")(point_image(n, row, col))
        np.testing.assert_allclose(sino.sum(axis=1), 1.0, atol=1e-4)
        cent = (sino * s).sum(axis=1) / sino.sum(axis=1)
        expected = r1 * np.cos(g.angles) + r2 * np.sin(g.angles)
        np.testing.assert_allclose(cent, expected, atol=0.05)
        # the transposed / mirrored conventions are far off
        wrong = r2 * np.cos(g.angles) + r1 * np.sin(g.angles)
        assert np.abs(cent - wrong).max() > 2


def test_parallel_det_spacing_scales_detector_coordinate() -> None:
    g = Geometry("parallel", 63, 4, 183, det_spacing=0.5)
    row, col = 20, 45
    sino = RayTransform(g, projector="strip")(point_image(63, row, col))
    s = centred(g.n_det) * g.det_spacing
    cent = (sino * s).sum(axis=1) / sino.sum(axis=1)
    assert cent[0] == pytest.approx(14.0, abs=0.02)
    assert cent[2] == pytest.approx(11.0, abs=0.02)  # view 2 of 4 over pi: 90 degrees
    assert sino[0].sum() == pytest.approx(2.0, rel=1e-4)  # 1 / det_spacing


def test_fan_point_projection_follows_documented_geometry() -> None:
    """Fan beam: source at R (sin, -cos), flat detector at D (-sin, cos), pixel axis
    (cos, sin). A point r lands at u = (r1 c + r2 s) (R + D) / (R - r1 s + r2 c).

    A short source distance makes the magnification strongly depend on the side of the axis
    a point is on, so a source on the wrong side fails.
    """
    R = D = 100.0
    g = Geometry("fan", 63, 8, 301, 1.0, 2 * math.pi, R, D)
    n = g.n
    u = centred(g.n_det) * g.det_spacing
    phi = g.angles
    c, s = np.cos(phi), np.sin(phi)
    for row, col in ((51, 45), (11, 45), (31, 10)):  # r2 = -20, +20; r1 = -21
        r1, r2 = col - (n - 1) / 2, (n - 1) / 2 - row
        sino = RayTransform(g)(point_image(n, row, col))
        assert (sino.sum(axis=1) > 0).all()
        cent = (sino * u).sum(axis=1) / sino.sum(axis=1)
        expected = (r1 * c + r2 * s) * (R + D) / (R - r1 * s + r2 * c)
        np.testing.assert_allclose(cent, expected, atol=0.6)
    # explicit: at view 0 (rays going up), the point below the axis is magnified more
    below = RayTransform(g)(point_image(n, 51, 45))[0]
    above = RayTransform(g)(point_image(n, 11, 45))[0]
    assert u[np.argmax(below)] == pytest.approx(14 * 200 / 80, abs=1)  # 35
    assert u[np.argmax(above)] == pytest.approx(14 * 200 / 120, abs=1)  # 23.3


def test_tiny_fan_point_at_view_zero() -> None:
    g = get_preset("tiny-fan")
    n = g.n
    row, col = 20, 45
    r1, r2 = col - (n - 1) / 2, (n - 1) / 2 - row
    sino = RayTransform(g)(point_image(n, row, col))
    u = centred(g.n_det) * g.det_spacing
    expected = r1 * (g.source_radius + g.detector_radius) / (g.source_radius + r2)
    assert abs(u[np.argmax(sino[0])] - expected) <= 0.5
