"""Open-beam normalisation: a constructed open beam with a known level per view, and the real I13 scan."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tifffile

from nanoct.core.errors import NanoctError
from nanoct.preprocess.openbeam import estimate_open_beam, normalize_open_beam, poly_terms, robust_noise

I13 = Path(__file__).resolve().parents[1] / "data" / "realdata" / "i13-24737-tiff"


def _scan(levels, *, rows=24, cols=64, width=0.5, noise=0.004, seed=0, profile=None):
    """Transmissions of a cylinder (centre column, ``width`` of the detector) under a known open beam."""
    rng = np.random.default_rng(seed)
    u = np.arange(cols) / (cols - 1) - 0.5
    chord = np.sqrt(np.clip((width / 2) ** 2 - u**2, 0, None)) / (width / 2)
    obj = np.exp(-1.5 * chord)  # absorbance up to 1.5 in the middle
    beam = np.ones((rows, cols)) if profile is None else profile
    data = np.stack([lv * beam * obj[None, :] for lv in levels])
    return (data * (1 + noise * rng.standard_normal(data.shape))).astype(np.float32)


def test_known_levels_recovered_per_view():
    levels = 0.67 * (1 - 0.002 * np.arange(12))  # beam decay
    beam = estimate_open_beam(_scan(levels))
    np.testing.assert_allclose(beam.levels, levels, rtol=2e-3)
    air = -np.log(normalize_open_beam(_scan(levels), beam))[:, :, :8]
    assert abs(air.mean()) < 2e-3


def test_object_filling_most_of_the_detector():
    levels = np.full(6, 0.7)
    data = _scan(levels, width=0.9)  # 5 % air on each side
    beam = estimate_open_beam(data)
    np.testing.assert_allclose(beam.levels, levels, rtol=3e-3)
    assert np.all(beam.air_fraction <= 8 / 64)  # the 4 + 4 columns outside the object


def test_no_air_is_refused_with_the_fix():
    data = _scan(np.full(4, 0.7), width=1.6)  # wider than the detector: no air at all
    with pytest.raises(NanoctError, match=r"no flat air region found in view 0.*--air-columns"):
        estimate_open_beam(data)


def test_a_quadratic_beam_profile():
    rows, cols = 20, 80
    u = np.arange(cols) / (cols - 1) - 0.5
    w = np.arange(rows) / (rows - 1) - 0.5
    profile = 1 - 0.2 * u[None, :] ** 2 + 0.03 * u[None, :] + 0.02 * w[:, None]  # falls off to the sides
    levels = np.array([0.6, 0.65, 0.7])
    data = _scan(levels, rows=rows, cols=cols, width=0.5, noise=0.0, profile=profile)
    data[:, :5] = levels[:, None, None] * profile[None, :5]  # the object below row 5: air above it
    # the top rows alone, all air (exact), and the whole views with their air found (the object's
    # faintest edge pixels, within the band of the air, count as air: 0.16 % off)
    for columns, rtol in (([(0, 80)], 1e-5), (None, 3e-3)):
        beam = estimate_open_beam(data[:, :5] if columns else data, columns=columns, degree=2)
        for k, level in enumerate(levels):
            np.testing.assert_allclose(beam.field(k), level * profile[: beam.shape[0]], rtol=rtol)
    auto = estimate_open_beam(data)  # auto: degree 2, since air reaches the middle columns
    np.testing.assert_allclose(auto.field(1), levels[1] * profile, rtol=3e-3)
    # degree 0 cannot follow the profile: its air is off by the profile's spread
    scalar = -np.log(normalize_open_beam(data, estimate_open_beam(data, degree=0)))
    assert np.abs(scalar[:, :, :5]).max() > 0.02


def test_surface_needs_air_on_both_sides():
    data = _scan(np.full(3, 0.7), cols=64)
    with pytest.raises(NanoctError, match="does not determine a surface of degree 1"):
        estimate_open_beam(data, columns=[(0, 8)], degree=1)
    with pytest.raises(NanoctError, match="does not determine a surface of degree 2"):
        estimate_open_beam(data, columns=[(0, 8), (56, 64)], degree=2)
    # auto: one side only -> one level per view; both sides -> a plane
    assert not estimate_open_beam(data, columns=[(0, 8)]).coefficients[:, 1:].any()
    assert estimate_open_beam(data, columns=[(0, 8), (56, 64)]).coefficients[:, 3:].sum() == 0
    with pytest.raises(NanoctError, match="must satisfy"):
        estimate_open_beam(data, columns=[(60, 70)])
    with pytest.raises(NanoctError, match="--open-beam-degree 3"):
        estimate_open_beam(data, degree=3)


def test_poly_terms_and_robust_noise():
    u, w = np.array([2.0]), np.array([3.0])
    assert [t.item() for t in poly_terms(u, w, 2)] == [1.0, 2.0, 3.0, 4.0, 6.0, 9.0]
    noise = np.random.default_rng(5).normal(0, 0.1, (50, 400))
    assert robust_noise(noise) == pytest.approx(0.1, rel=0.03)


def test_real_i13_air_below_002():
    flat = tifffile.imread(I13 / "flat_00001.tiff").astype(np.float64)
    dark = tifffile.imread(I13 / "dark_00001.tiff").astype(np.float64)
    paths = sorted((I13 / "tiffs").glob("raw_*.tiff"))[::6]
    raw = np.stack([tifffile.imread(p) for p in paths]).astype(np.float64)
    gain = flat - dark
    trans = np.where(gain > 0, (raw - dark) / np.where(gain > 0, gain, 1), 1).astype(np.float32)
    strips = np.concatenate([trans[:, 5:130, 2:28], trans[:, 5:130, 137:158]], axis=2)
    assert -np.log(strips).mean() > 0.3  # the flat does not match the open beam
    after = -np.log(normalize_open_beam(trans, estimate_open_beam(trans, degree=2)))
    air = np.concatenate([after[:, 5:130, 2:28], after[:, 5:130, 137:158]], axis=2)
    assert abs(air.mean()) < 0.02
    assert np.abs(air.mean(axis=(1, 2))).max() < 0.02


def test_single_row_sinogram():
    levels = np.linspace(0.9, 0.8, 10)
    data = _scan(levels, rows=1, cols=200, width=0.9)  # 10 air pixels each side
    np.testing.assert_allclose(estimate_open_beam(data).levels, levels, rtol=5e-3)


def test_real_neutron_automatic_matches_open_beam_columns():
    raw = tifffile.imread(I13.parent / "neutron-360-sinogram" / "sinogram_360_neutron_image.tif")
    data = raw[::10].astype(np.float32)[:, None, :]
    given = estimate_open_beam(data, columns=[(0, 30)]).levels
    auto = estimate_open_beam(data)  # air on both sides: a plane per view
    at_left = np.array([auto.field(k)[0, :30].mean() for k in range(data.shape[0])])
    assert np.all(np.abs(at_left / given - 1) < 0.01)  # 1 % noise per pixel
