"""The axis from every estimator: real I13, a constructed open beam, 360-degree, interlaced and limited-angle scans."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.motion.axis import AGREEMENT_PX, axis_rows, estimate_axis, remove_air
from nanoct.motion.estimate import start_axis
from nanoct.sim.analytic import ellipse_sinogram, stack_phantom

L, OFFSET = 128, 3.3


def _sinograms(angles, n_rows=2, offset=OFFSET, shifts=None):
    return np.stack(
        [ellipse_sinogram(e, angles, L, center_offset=offset, shifts=shifts) for e in stack_phantom(L, n_rows, seed=4)]
    )


def test_real_i13_axis_within_half_a_pixel_of_the_independent_estimates(i13):
    """Mirror of the 0/180-degree views: +6.4 px; algotom's find_center_vo: +6.0 (the scan's README)."""
    li, angles = i13
    sino = li.transpose(1, 0, 2)
    estimate = estimate_axis(sino[axis_rows(sino.shape[0])], angles)
    assert estimate.air_removed and {"mirror", "vo"} <= set(estimate.estimates)
    assert abs(estimate.offset - 6.2) <= 0.5, estimate
    # the open beam removed: air reads about zero instead of 0.4
    clean, found = remove_air(sino[60:70])
    assert found and abs(np.median(clean[:, :, :20])) < 0.02 < abs(np.median(sino[60:70, :, :20]) - 0.3)


@pytest.mark.parametrize("level", [0.0, 0.4])
def test_open_beam_offset_does_not_move_the_axis(level):
    angles = np.arange(180) * np.pi / 180
    noise = 0.005 * np.random.default_rng(0).standard_normal((2, angles.size, L))
    estimate = estimate_axis(_sinograms(angles) + level + noise, angles)
    assert estimate.air_removed and estimate.used == ("centroid",)  # trusted once the air is removed
    for name in ("mirror", "vo", "centroid"):
        assert estimate.estimates[name] == pytest.approx(OFFSET, abs=0.1), (name, estimate)


def test_an_open_beam_the_fit_leaves_behind_is_caught_by_the_mass_check():
    angles = np.arange(180) * np.pi / 180
    ramp = 0.4 * (1 + 0.05 * np.linspace(-1, 1, L))  # noise-free: the air band sees one side of the ramp
    estimate = estimate_axis(_sinograms(angles) + ramp, angles)
    assert estimate.used == ("mirror", "vo") and any("mass varies" in note for note in estimate.notes)
    assert estimate.offset == pytest.approx(OFFSET, abs=0.15)


@pytest.mark.parametrize("layout", ["360", "interlaced"])
def test_every_opposite_pair_counts(layout):
    if layout == "360":
        angles = np.arange(240) * 2 * np.pi / 240
    else:  # two passes over 180 degrees, the second offset by half a step and a turn
        angles = np.concatenate([np.arange(90) * np.pi / 90, np.pi + (np.arange(90) + 0.5) * np.pi / 90])
    estimate = estimate_axis(_sinograms(angles), angles)
    assert estimate.estimates["mirror"] == pytest.approx(OFFSET, abs=0.1)
    assert estimate.offset == pytest.approx(OFFSET, abs=0.1)


def test_limited_angle_uses_the_sharpness_of_reconstructions():
    angles = np.deg2rad(np.linspace(-60, 60, 61))
    estimate = estimate_axis(_sinograms(angles, n_rows=1) + 0.0, angles)
    assert "mirror" not in estimate.estimates and "vo" not in estimate.estimates
    assert estimate.used in (("centroid",), ("sharpness",))
    assert estimate.offset == pytest.approx(OFFSET, abs=0.5)


@pytest.mark.slow
def test_real_i13_cut_to_120_degrees_does_not_take_a_sharpness_bound_for_the_axis(i13):
    """The first 61 views (-88 to +32 degrees) of rows 60:75: the sharpness score falls to its
    search bound (+20 px); the axis (+6.2 on the whole scan) comes from the centroid, with a warning."""
    li, angles = i13
    sino = li.transpose(1, 0, 2)[60:75, :61]
    estimate = estimate_axis(sino[axis_rows(sino.shape[0])], angles[:61])
    assert estimate.estimates["sharpness"] == pytest.approx(20.0) and estimate.used == ("centroid",)
    assert abs(estimate.offset - 6.2) <= 1.5 and any(note.startswith("warning") for note in estimate.notes)
    with pytest.raises(NanoctError, match="no estimator .*--center-offset"):  # and without the centroid
        estimate_axis(np.zeros_like(sino[:8]), angles[:61])
    assert start_axis(np.zeros_like(sino[:8]), angles[:61]) == 0.0  # projection matching starts at the centre


def test_limited_angle_without_air_falls_back_to_sharpness():
    angles = np.deg2rad(np.linspace(-60, 60, 61))
    sino = _sinograms(angles, n_rows=1)[:, :, 16:-16]  # the object wider than the detector: no air
    estimate = estimate_axis(sino, angles)
    assert estimate.used == ("sharpness",)
    assert estimate.offset == pytest.approx(OFFSET, abs=0.6)


def test_motion_biases_the_mirror_and_the_estimators_warn():
    angles = np.arange(180) * np.pi / 180
    shifts = np.zeros(angles.size)
    shifts[-3:] = 3.0  # the last views moved: the first/last mirror match sees it
    estimate = estimate_axis(_sinograms(angles, shifts=shifts), angles)
    basis = np.stack([np.ones_like(angles), np.cos(angles), np.sin(angles)], axis=1)
    constant = np.linalg.lstsq(basis, shifts, rcond=None)[0][0]  # the centroid leaves the shifts without one
    assert estimate.used == ("centroid",) and estimate.offset == pytest.approx(OFFSET - constant, abs=0.1)
    assert abs(estimate.estimates["mirror"] - OFFSET) > AGREEMENT_PX
    assert any(note.startswith("warning") for note in estimate.notes)


def test_bad_input():
    angles = np.arange(10) * np.pi / 10
    with pytest.raises(NanoctError, match="do not match"):
        estimate_axis(np.zeros((1, 9, 16)), angles)
    with pytest.raises(NanoctError, match="NaN"):
        estimate_axis(np.full((1, 10, 16), np.nan), angles)


@pytest.mark.parametrize("tilt", [0.0, 2.0])
def test_axis_tilt_on_the_real_scan_rotated_on_the_detector(i13, tilt):
    import scipy.ndimage as ndi

    from nanoct.motion.axis import axis_tilt

    li, angles = i13
    data = np.stack([ndi.rotate(p, tilt, reshape=False, order=3, mode="nearest") for p in li]) if tilt else li
    found = axis_tilt(data.transpose(1, 0, 2), angles)
    assert found.tilt_deg == pytest.approx(tilt, abs=0.5)  # measured: 0.02 and 1.85 degrees
    assert found.offset_at(67, li.shape[1]) == pytest.approx(6.3, abs=0.5)


def test_axis_tilt_needs_opposite_views():
    from nanoct.motion.axis import axis_tilt

    with pytest.raises(NanoctError, match="180 degrees"):
        axis_tilt(np.ones((8, 5, 16)), np.deg2rad(np.linspace(-50, 50, 5)))


@pytest.mark.parametrize("tilt", [2.5, -1.5])
def test_axis_tilt_of_a_limited_angle_series_from_the_centroids(tilt):
    """+-70 degrees, no opposite view, air around the object: the centroid axis of row groups, rotated back
    until vertical, gives the tilt with its sign (each projection rotated as the I13 test rotates it) and
    the axis at the middle row; the first-order line alone finds 1.53 and -0.80 degrees."""
    import scipy.ndimage as ndi

    from nanoct.motion.axis import limited_angle_tilt
    from scan_cases import analytic_projections

    angles = np.deg2rad(np.linspace(-70, 70, 36))
    proj = np.clip(analytic_projections(angles, 64, 48, 2.0, seed=5), 0.0, None)  # rows of negative density: empty
    proj = np.pad(proj, ((0, 0), (8, 8), (32, 32)))
    rotated = np.stack([ndi.rotate(p, tilt, reshape=False, order=3, mode="nearest") for p in proj])
    found, trials = limited_angle_tilt(rotated, angles)
    assert found.tilt_deg == pytest.approx(tilt, abs=0.2)  # measured 2.56 and -1.39 degrees
    assert found.center == pytest.approx(2.0, abs=0.3) and len(trials) <= 5


def test_remove_air_on_counts_scales_back():
    """Line integrals in counts (a STEM series: 20 counts of background, the object up to ~2e4): the air is
    found on the data divided by their 99th percentile and the background removed in counts."""
    counts = 20000.0 * _sinograms(np.linspace(0, np.pi, 30, endpoint=False), n_rows=3) + 20.0
    assert np.percentile(counts, 99) > 1e4
    clean, air = remove_air(counts)
    assert air
    np.testing.assert_allclose(clean, counts - 20.0, atol=0.05)


def test_noisy_air_at_zero_is_air():
    """Noise of 0.06 per pixel on line integrals up to 8.6 (as bench_large.py's scan): the open-beam estimator
    finds no air, the outer columns still read zero within the noise (nanoct stack then takes its centroid
    path); cut to the object's middle (wider than the detector) or with an open beam of 0.4 not removed they
    do not."""
    from nanoct.core.errors import NanoctError
    from nanoct.motion.axis import air_at_zero
    from nanoct.preprocess.openbeam import estimate_open_beam

    angles = np.arange(0, 180, 2) * np.pi / 180
    sino = 10 * _sinograms(angles)  # line integrals up to 8.6
    noisy = sino + 0.06 * np.random.default_rng(1).standard_normal(sino.shape)
    with pytest.raises(NanoctError, match="no (flat )?air"):
        estimate_open_beam(np.exp(-noisy.transpose(1, 0, 2)))
    assert remove_air(noisy)[1] is False and air_at_zero(noisy)
    clean, found = remove_air(noisy, zero_air=True)
    assert found and np.array_equal(clean, noisy)
    assert not air_at_zero(noisy[:, :, L // 4 : -L // 4])
    assert not air_at_zero(noisy + 0.4)


def test_a_large_half_turn_is_searched_coarse_to_fine_as_find_center_vo_would(monkeypatch):
    """The bounded search (binned columns, averaged views) on a sinogram forced above the bound."""
    from algotom.prep.calculation import find_center_vo

    import nanoct.motion.axis as axis

    angles = np.arange(721) * np.pi / 720  # 0..180 degrees inclusive
    sino = _sinograms(angles, n_rows=2)
    direct = find_center_vo(sino[0], start=L / 4, stop=3 * L / 4) - (L - 1) / 2
    monkeypatch.setattr(axis, "VO_FULL_VALUES", 1000)
    monkeypatch.setattr(axis, "VO_FINE_VALUES", 180 * L)  # views averaged by 4 at full width
    bounded = axis.estimate_axis(sino, angles).estimates["vo"]
    assert bounded == pytest.approx(OFFSET, abs=0.3) and bounded == pytest.approx(direct, abs=0.3)


def test_a_wide_limited_angle_series_is_scored_on_binned_columns(monkeypatch):
    """192 columns scored binned by 2 (the bound forced to 100): the axis within 0.6 binned pixels."""
    import nanoct.motion.axis as axis

    angles = np.deg2rad(np.linspace(-60, 60, 61))
    wide = np.stack([ellipse_sinogram(e, angles, 256, center_offset=OFFSET) for e in stack_phantom(256, 1, seed=4)])
    sino = wide[:, :, 32:-32]  # no air: the sharpness applies
    monkeypatch.setattr(axis, "SHARPNESS_MAX_COLS", 100)
    estimate = axis.estimate_axis(sino, angles)
    assert estimate.used == ("sharpness",) and estimate.offset == pytest.approx(OFFSET, abs=2 * 0.6)
    assert estimate.offset % 0.2 == pytest.approx(0.0, abs=1e-6) or estimate.offset % 0.2 == pytest.approx(0.2)


def test_air_at_zero_in_noisy_data_trusts_the_centroid_of_a_moving_object():
    """Noise of 0.05 in absorbance (0.6 % of the largest line integral) hides the flat columns from
    the open-beam fit; the outer columns at zero still show the air, so the centroid, unbiased by
    motion, gives the axis (mirror and vo are 4 px off)."""
    angles = np.arange(360) * np.pi / 360
    rng = np.random.default_rng(3)
    shifts = 3.0 * np.sin(3 * angles) + rng.uniform(-1, 1, angles.size)  # a moving object
    clean = 10 * _sinograms(angles, shifts=shifts)
    sino = clean + 0.05 * rng.standard_normal(clean.shape)
    assert not remove_air(sino)[1] and remove_air(sino, zero_air=True)[1]
    basis = np.stack([np.ones_like(angles), np.cos(angles), np.sin(angles)], axis=1)
    constant = np.linalg.lstsq(basis, shifts, rcond=None)[0][0]
    estimate = estimate_axis(sino, angles)
    assert estimate.air_removed and estimate.used == ("centroid",)
    assert estimate.offset == pytest.approx(OFFSET - constant, abs=0.1)
