"""Vertical shift per view from the row profiles."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.motion.vertical import (
    MAX_MISFIT_RATIO,
    MIN_PROFILE_SNR,
    row_profiles,
    vertical_motion,
    vertical_shifts,
)
from scan_cases import analytic_projections, gauge_free_rms, known_motion, moved


def test_constructed_stack_vertical_shifts_recovered():
    angles = np.arange(90) * np.pi / 90
    proj = analytic_projections(angles, 64, 40, 1.0)
    horizontal, vertical = known_motion(angles, seed=1)
    data = moved(proj, horizontal, vertical) + 0.3  # an open beam at 0.3 absorbance changes nothing
    estimate = vertical_shifts(row_profiles(data))
    assert estimate.mean() == pytest.approx(0.0, abs=1e-9)
    assert gauge_free_rms(estimate, vertical, angles, vertical=True) < 0.1
    assert gauge_free_rms(-estimate, vertical, angles, vertical=True) > 0.3  # the sign matters


def test_real_i13_vertical_motion_recovered(i13):
    li, angles = i13
    horizontal, vertical = known_motion(angles)
    estimate = vertical_shifts(row_profiles(moved(li, horizontal, vertical)))
    assert gauge_free_rms(estimate, vertical, angles, vertical=True) < 0.1


def test_bad_profiles():
    with pytest.raises(NanoctError, match="at least 4 rows"):
        vertical_shifts(np.zeros((5, 3)))
    with pytest.raises(NanoctError, match="NaN"):
        vertical_shifts(np.full((5, 8), np.nan))
    with pytest.raises(NanoctError, match="views, rows, columns"):
        row_profiles(np.zeros((5, 8)))


@pytest.mark.parametrize("tilt", [3.0, -2.0])
def test_tilt_from_profiles_on_a_limited_angle_series_of_the_real_scan(i13, tilt):
    import scipy.ndimage as ndi

    from nanoct.motion.axis import remove_air
    from nanoct.motion.vertical import tilt_from_profiles

    li, angles = i13
    views = np.abs(np.rad2deg(angles) - 90) <= 76  # a tilt series of +-76 degrees: no opposite views
    rng = np.random.default_rng(1)
    jitter = rng.normal(0, 1.0, views.sum())  # and vertical motion of 1 px RMS
    data = np.stack(
        [ndi.shift(ndi.rotate(p, tilt, reshape=False, order=3, mode="nearest"), (-v, 0), order=3, mode="nearest")
         for p, v in zip(li[views], jitter)]
    )  # fmt: skip
    clean = remove_air(data.transpose(1, 0, 2))[0].transpose(1, 0, 2)
    found, grid, scores = tilt_from_profiles(clean)
    assert found == pytest.approx(tilt, abs=0.5)  # measured 3.03 and -1.98 degrees
    assert grid.size == scores.size and scores.min() < 0.8 * scores.max()


def _phantom_stack_profiles() -> tuple[np.ndarray, np.ndarray]:
    """Row profiles of a still stack of 4 phantom slices, each repeated over 28 rows (60 views, 63 columns)."""
    from nanoct.sim.analytic import ellipse_sinogram, stack_phantom

    phi = np.linspace(0, np.pi, 60, endpoint=False)
    slices = [ellipse_sinogram(e, phi, 63) for e in stack_phantom(63, 4, seed=1)]
    sino = np.stack([slices[r * 4 // 112] for r in range(112)], axis=1)  # (K, R, L), nothing moves
    return row_profiles(sino / sino.max()), phi


def test_vertical_motion_is_zero_where_the_profiles_show_none():
    rng = np.random.default_rng(0)
    flat = vertical_motion(5.0 + rng.normal(0, 0.1, (60, 112)))  # flat profiles with noise
    assert not flat.significant and not flat.shifts.any() and flat.raw_rms > 1.0  # the raw estimate invents motion
    assert flat.profile_snr < MIN_PROFILE_SNR and "too little structure" in flat.note and "set to zero" in flat.note
    still, _ = _phantom_stack_profiles()  # slices that differ by less than the views' own mass variation
    guarded = vertical_motion(still)
    assert not guarded.significant and not guarded.shifts.any()
    assert guarded.misfit_ratio > MAX_MISFIT_RATIO or guarded.profile_snr < MIN_PROFILE_SNR


def test_vertical_motion_keeps_real_motion(i13):
    li, angles = i13
    horizontal, vertical = known_motion(angles)
    found = vertical_motion(row_profiles(moved(li, horizontal, vertical)))
    assert found.significant and found.misfit_ratio < 0.05 and "kept" in found.note  # measured 0.006
    assert gauge_free_rms(found.shifts, vertical, angles, vertical=True) < 0.1
    wide = vertical_motion(row_profiles(moved(li, horizontal, vertical)[:, 76:, 40:120]))  # wider than the field
    assert wide.significant and wide.misfit_ratio < MAX_MISFIT_RATIO  # measured 0.70
    small = 0.3 * np.random.default_rng(2).normal(size=angles.size)  # a jitter of 0.3 px is still found
    jitter = vertical_motion(row_profiles(moved(li, np.zeros_like(small), small)))
    assert jitter.significant and gauge_free_rms(jitter.shifts, small, angles, vertical=True) < 0.05
    still = vertical_motion(row_profiles(li))  # the still scan: its 0.01 px RMS of raw shifts set to zero
    assert not still.significant and not still.shifts.any() and still.to_dict()["raw_rms"] < 0.05
