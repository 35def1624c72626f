"""The corrections pipeline: the order of its steps, its record for provenance, its refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.preprocess import (
    Corrections,
    apply_corrections,
    estimate_open_beam,
    normalize_open_beam,
    paganin,
    parse_columns,
    parse_stripe_params,
    remove_outliers,
    remove_stripes,
)


def _scan(rng, views=8, rows=6, cols=96):
    """Transmissions of a cylinder under an open beam decaying from 0.7, with zingers and a bad pixel."""
    u = np.arange(cols) / (cols - 1) - 0.5
    obj = np.exp(-1.2 * np.sqrt(np.clip(0.3**2 - u**2, 0, None)) / 0.3)
    levels = 0.7 * (1 - 0.003 * np.arange(views))
    data = levels[:, None, None] * obj[None, None, :] * np.ones((views, rows, cols))
    data *= 1 + 0.003 * rng.standard_normal(data.shape)
    data[:, :, 40] *= 1.02  # a detector pixel off by 2 %: a stripe
    data[2, 3, 10] *= 2.5  # a zinger in the air
    return data.astype(np.float32), levels


FULL = Corrections(
    outliers=5.0, open_beam=True, delta_beta=50.0, energy_kev=20.0, distance_m=0.05, pixel_size_m=1e-6,
    stripes="sorting", stripe_params={"size": 11},
)  # fmt: skip


def test_steps_in_order(rng):
    data, levels = _scan(rng)
    result = apply_corrections(data, FULL)
    step, _ = remove_outliers(data, threshold=5.0)
    beam = estimate_open_beam(step)
    phase = {"delta_beta": 50.0, "energy_kev": 20.0, "distance_m": 0.05, "pixel_size_m": 1e-6}
    step = paganin(normalize_open_beam(step, beam), **phase)
    expected = remove_stripes(-np.log(np.maximum(step, 1e-6)), "sorting", {"size": 11})
    np.testing.assert_allclose(result.line_integrals, expected, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(result.open_beam_levels, levels, rtol=3e-3)
    assert len(result.notes) == 4 and result.notes[0].startswith("outliers: 1 pixels")
    assert abs(result.line_integrals[:, :, :8].mean()) < 0.01  # air at 0


def test_line_integrals_in_give_the_same(rng):
    data, _ = _scan(rng)
    from_trans = apply_corrections(data, FULL).line_integrals
    from_lines = apply_corrections(-np.log(data), FULL, kind="line_integrals").line_integrals
    np.testing.assert_allclose(from_lines, from_trans, atol=2e-5)
    plain = apply_corrections(-np.log(data), Corrections(stripes="all"), kind="line_integrals")
    np.testing.assert_allclose(plain.line_integrals, remove_stripes(-np.log(data), "all"), rtol=1e-6)


def test_nothing_on_is_minus_log(rng):
    data, _ = _scan(rng)
    result = apply_corrections(data, Corrections())
    np.testing.assert_allclose(result.line_integrals, -np.log(data), rtol=1e-6)
    assert result.notes == [] and not Corrections().any and FULL.any


def test_record_round_trip():
    corr = Corrections(outliers=4.0, open_beam=True, air_columns=parse_columns("0:30,480:503"), stripes="all")
    record = json.loads(json.dumps(corr.to_dict()))
    assert record["air_columns"] == [[0, 30], [480, 503]]
    assert record["stripe_params"] == {"snr": 3.0, "la_size": 51, "sm_size": 21, "drop_ratio": 0.1}
    assert Corrections.from_dict(record) == corr
    assert Corrections.from_dict(FULL.to_dict()) == FULL
    assert hash(Corrections.from_dict(FULL.to_dict())) == hash(FULL) != hash(corr)
    parsed = Corrections(stripes="all", stripe_params=parse_stripe_params("snr=2.5, la_size=61"))
    assert parsed.stripe_params == {"snr": 2.5, "la_size": 61, "sm_size": 21, "drop_ratio": 0.1}


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"delta_beta": 100.0}, "--delta-beta needs --energy-kev"),
        ({"energy_kev": 20.0}, "only with --delta-beta"),
        ({"air_columns": ((0, 3),)}, "--air-columns needs --open-beam"),
        ({"outliers": -1.0}, "--outliers -1.0"),
        ({"open_beam_degree": 3}, "--open-beam-degree 3 must be 0, 1, 2 or auto"),
        ({"stripes": "wavelet"}, "--stripes 'wavelet'"),
        ({"stripe_params": {"size": 3}}, "only with --stripes"),
    ],
)
def test_bad_corrections(kwargs, message):
    with pytest.raises(NanoctError, match=message):
        Corrections(**kwargs)


def test_bad_input():
    with pytest.raises(NanoctError, match="unknown correction 'ring'"):
        Corrections.from_dict({"ring": 1})
    with pytest.raises(NanoctError, match="FIRST:STOP"):
        parse_columns("0-30")
    with pytest.raises(NanoctError, match="NAME=NUMBER"):
        parse_stripe_params("snr:3")
    with pytest.raises(NanoctError, match="whole numbers"):
        Corrections(stripes="all", stripe_params={"la_size": 51.5})
    with pytest.raises(NanoctError, match="must be \\(views, rows, columns\\)"):
        apply_corrections(np.ones((4, 4)), Corrections())
