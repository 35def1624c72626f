"""Vertical shift per view from the row profiles."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.motion.vertical import row_profiles, vertical_shifts
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
