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
