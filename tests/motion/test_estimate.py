"""3-D motion of the real I13 scan with a known motion added: vertical, horizontal, axis, and the record."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.motion.estimate import estimate_motion
from scan_cases import gauge_free_rms, known_motion, moved


def test_real_scan_with_added_motion_recovered_in_both_directions(i13):
    li, angles = i13
    horizontal, vertical = known_motion(angles)
    result = estimate_motion(moved(li, horizontal, vertical), angles)
    assert result.horizontal_method == "centroid" and result.axis.air_removed
    assert gauge_free_rms(result.horizontal, horizontal, angles) <= 0.25
    assert gauge_free_rms(result.vertical, vertical, angles, vertical=True) <= 0.25
    still = estimate_motion(li, angles)  # the scan as measured: no motion worth the name, the axis as the estimators
    assert np.sqrt(np.mean(still.vertical**2)) < 0.1 and abs(still.axis.offset - 6.2) <= 0.5


@pytest.mark.slow
def test_real_scan_wider_than_the_field_of_view(i13):
    li, angles = i13
    horizontal, vertical = known_motion(angles)
    data = moved(li, horizontal, vertical)[:, 76:, 40:120]  # the container's walls cut: no air anywhere
    result = estimate_motion(data, angles)
    assert result.horizontal_method == "matching" and not result.axis.air_removed
    assert gauge_free_rms(result.horizontal, horizontal, angles) <= 0.2  # measured 0.038 px (0.30 before the autofocus)
    assert gauge_free_rms(result.vertical, vertical, angles, vertical=True) <= 0.25


def test_estimate_motion_bad_input():
    with pytest.raises(NanoctError, match="do not match"):
        estimate_motion(np.zeros((4, 8, 8)), np.zeros(3))
    with pytest.raises(NanoctError, match="horizontal estimator"):
        estimate_motion(np.zeros((4, 8, 8)), np.zeros(4), horizontal="magic")


@pytest.mark.slow
def test_limited_angle_tilt_series_with_jumps_between_frames():
    from scan_cases import analytic_projections

    angles = np.deg2rad(np.linspace(-76, 76, 39))  # no two views 180 degrees apart: prealigned, focus axis
    proj = np.pad(analytic_projections(angles, 64, 24, 2.0, seed=5), ((0, 0), (0, 0), (24, 24)))
    rng = np.random.default_rng(0)
    horizontal = np.clip(np.cumsum(rng.normal(0, 5, angles.size)), -20, 20)  # jumps of up to ~10 px
    horizontal -= horizontal.mean()
    vertical = np.clip(np.cumsum(rng.normal(0, 2, angles.size)), -5, 5)
    result = estimate_motion(moved(proj, horizontal, vertical), angles)
    assert result.record["prealign"] and result.axis.used == ("focus",)
    assert "sharpness" in result.axis.estimates and abs(result.tilt_deg) < 0.5  # measured -0.21 degrees
    assert gauge_free_rms(result.horizontal, horizontal, angles) < 0.3  # measured 0.12 px (vertical 0.019)
    assert gauge_free_rms(result.vertical, vertical, angles, vertical=True) < 0.3
    # the axis that goes with the shifts: reconstructing with axis c and shifts e_k is axis c - e_k per view
    basis = np.stack([np.ones_like(angles), np.cos(angles), np.sin(angles)], axis=1)
    constant = np.linalg.lstsq(basis, result.horizontal - horizontal, rcond=None)[0][0]
    assert result.axis.offset - constant == pytest.approx(2.0, abs=0.3)  # measured +0.05 px off


def test_top_level_names():
    import nanoct
    from nanoct.motion.axis import estimate_axis

    assert nanoct.estimate_motion is estimate_motion and nanoct.estimate_axis is estimate_axis
    assert {"estimate_motion", "estimate_axis"} <= set(nanoct.__all__)


@pytest.mark.slow
def test_real_tilt_series_matches_the_acquiring_groups_alignment():
    """ETSpy's STEM needle (+-76 degrees, jumps of ~20 px), binned 4 x 4: nanoct's automatic alignment
    against the group's, per component in full-size pixels (targets 1.5 px and 0.5 degree)."""
    from scan_cases import needle_errors, needle_series

    proj, angles, ref = needle_series(binning=2)
    result = estimate_motion(proj, angles)
    assert result.horizontal_method == "centroid" and result.record["prealign"]  # air found on counts
    assert result.record["tilt_method"] == "centroid axis of row groups"
    errors = needle_errors(result.horizontal, result.vertical, result.axis.offset, result.tilt_deg, angles, ref, 4)
    assert errors["horizontal"] <= 0.3 and errors["vertical"] <= 0.4  # measured 0.03 and 0.14 px
    assert abs(errors["tilt"]) <= 0.3  # measured 2.84 degrees against ETSpy's 2.79
    assert abs(errors["axis"]) <= 1.5  # measured +0.53 px
