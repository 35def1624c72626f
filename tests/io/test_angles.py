"""Angles from outside the scan file: evenly spaced ranges, a selection of a file's values, HDF5 datasets."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.io.angles import read_angles, split_h5_spec, uniform_spec
from nanoct.io.scanio import ReaderOptions, read_scan


def test_specs_are_told_apart(tmp_path):
    assert uniform_spec("0:360") == (0.0, 360.0) and uniform_spec("-60.5:+60") == (-60.5, 60.0)
    assert uniform_spec("angles.txt") is None and split_h5_spec("0:360") is None
    assert split_h5_spec("/d/scan.nxs:/entry/theta") == (tmp_path.__class__("/d/scan.nxs"), "/entry/theta")
    assert split_h5_spec("scan.h5:entry/theta")[1] == "/entry/theta"
    with pytest.raises(NanoctError, match="equal"):
        uniform_spec("5:5")


def test_evenly_spaced_angles_for_a_sinogram(tmp_path):
    np.save(tmp_path / "s.npy", np.ones((8, 5), np.float32))
    scan = read_scan(tmp_path / "s.npy", angles_file="0:360", is_line_integral=True)
    np.testing.assert_allclose(scan.angles, np.arange(8) * np.pi / 4)
    rad = read_scan(tmp_path / "s.npy", angles_file="0:3.2", options=ReaderOptions(angle_units="rad"))
    np.testing.assert_allclose(rad.angles, np.arange(8) * 0.4)


def test_a_selection_of_an_angles_file(tmp_path):
    values = np.r_[np.zeros(3), np.linspace(-90, 90, 10, endpoint=False), np.full(2, 5.0)]
    np.savetxt(tmp_path / "a.txt", values)
    np.testing.assert_allclose(
        np.rad2deg(read_angles(tmp_path / "a.txt", select=(3, 13))), np.linspace(-90, 90, 10, endpoint=False)
    )
    with pytest.raises(NanoctError, match="--angles-select 3:99"):
        read_angles(tmp_path / "a.txt", select=(3, 99))


def test_stated_units_skip_the_span_check_and_bad_values_are_named(tmp_path):
    with h5py.File(tmp_path / "a.h5", "w") as f:
        f["rad"] = np.linspace(0, np.pi, 12)  # no units attribute: read as degrees, refused as radians
        f["bad"] = np.r_[np.linspace(0, 180, 11), np.nan]
    with pytest.raises(NanoctError, match="look like radians.*--angles-units rad"):
        read_angles(f"{tmp_path / 'a.h5'}:/rad")
    np.testing.assert_allclose(read_angles(f"{tmp_path / 'a.h5'}:/rad", units="rad"), np.linspace(0, np.pi, 12))
    with pytest.raises(NanoctError, match="NaN"):
        read_angles(f"{tmp_path / 'a.h5'}:/bad", units="deg")
    with pytest.raises(NanoctError, match="--angles-units 'grad'"):
        read_angles(tmp_path / "x.txt", units="grad")


def test_an_angles_file_longer_than_the_scan_names_angles_select(tmp_path):
    """More values than projections (the flats' and darks' lines too): the refusal names --angles-select."""
    np.save(tmp_path / "s.npy", np.ones((8, 2, 5), np.float32))
    np.savetxt(tmp_path / "long.txt", np.arange(11.0))
    np.savetxt(tmp_path / "short.txt", np.arange(6.0))
    with pytest.raises(NanoctError, match=r"11 angle\(s\) for 8 projection\(s\).*--angles-select FIRST:STOP"):
        read_scan(tmp_path / "s.npy", angles_file=tmp_path / "long.txt", is_line_integral=True)
    with pytest.raises(NanoctError, match=r"6 angle\(s\) for 8 projection\(s\)") as short:
        read_scan(tmp_path / "s.npy", angles_file=tmp_path / "short.txt", is_line_integral=True)
    assert "--angles-select" not in str(short.value)  # too few values: no selection helps
    chosen = read_scan(
        tmp_path / "s.npy", angles_file=tmp_path / "long.txt", is_line_integral=True,
        options=ReaderOptions(angles_select=(2, 10)),
    )  # fmt: skip
    np.testing.assert_allclose(np.rad2deg(chosen.angles), np.arange(2.0, 10.0))
    with h5py.File(tmp_path / "s.nxs", "w") as f:  # a scan file's own angles replaced by the file's
        f["entry/instrument/detector/data"] = np.ones((8, 2, 5), np.float32)
        f["entry/instrument/detector/image_key"] = np.zeros(8, int)
        f["entry/sample/rotation_angle"] = np.linspace(0, 180, 8, endpoint=False)
    with pytest.raises(NanoctError, match=r"--angles .*long.txt: 11 angle\(s\) for 8 .*--angles-select FIRST:STOP"):
        read_scan(tmp_path / "s.nxs", angles_file=tmp_path / "long.txt", is_line_integral=True)
