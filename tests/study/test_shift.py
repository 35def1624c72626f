"""The shifted test sets of the uncertainty study: simulation changes and the table."""

from __future__ import annotations

import pytest

from nanoct.core.errors import NanoctError
from nanoct.sim.simulate import SimulationConfig
from nanoct.study.shift import SHIFTS, format_shift_table, shift_config, shift_study


def test_shift_configs_change_one_thing():
    base = SimulationConfig()
    m = base.motion
    big = shift_config("motion_x1.5", base, 10.0)
    assert big.motion.max_shift == 1.5 * m.max_shift and big.motion.amplitude_range[1] == 1.5 * m.amplitude_range[1]
    assert big.motion.jitter_std_mean == pytest.approx(1.5 * m.jitter_std_mean) and big.noise_std == base.noise_std
    small = shift_config("motion_x0.5", base, 10.0)
    assert small.motion.max_shift == 0.5 * m.max_shift and small.perturbed
    assert shift_config("noise", base, 10.0).noise_std == pytest.approx(0.1)
    assert shift_config("noise", base, 10.0).motion == m
    assert not shift_config("unperturbed", base, 10.0).perturbed
    other = shift_config("phantoms", base, 10.0)
    assert other.phantoms == "ellipses" and other.motion == m and other.noise_std == base.noise_std
    assert base.phantoms == "shapes"
    assert set(SHIFTS) == {"motion_x0.5", "motion_x1.5", "noise", "unperturbed", "phantoms"}
    with pytest.raises(NanoctError, match="unknown shift"):
        shift_config("rotation", base, 1.0)


def test_shift_table_and_missing_study(tmp_path):
    row = {
        "psnr_mean": 30.0,
        "coverage": 0.9,
        "coverage_by_width": [0.8, 0.95],
        "std_error_corr": 0.7,
        "std_error_spearman": 0.6,
        "partial_corr_given_baseline": 0.3,
        "edge_corr": 0.5,
        "fraction_flagged": None,
    }
    text = format_shift_table({"noise": {"dremel+cinn-res": row}})
    assert "| noise | dremel+cinn-res | 30.00 | 90.0 | 80.0 / 95.0 | 0.700 | 0.600 | 0.300 | 0.500 | - |" in text
    with pytest.raises(Exception, match="tiny"):
        shift_study(tmp_path / "tiny")
