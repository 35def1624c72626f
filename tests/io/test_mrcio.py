"""MRC / IMOD tilt series written by mrcfile: angles from .rawtlt/.tlt, the tilt-axis orientation, damage."""

from __future__ import annotations

import mrcfile
import numpy as np
import pytest

from nanoct.cli import run
from nanoct.core.errors import NanoctError
from nanoct.io.mrcio import find_tilt_file
from nanoct.io.scanio import ReaderOptions, detect_format, read_scan

K, NY, NX = 13, 5, 7
TILTS = np.linspace(-60, 60, K)


@pytest.fixture
def series(tmp_path):
    stack = np.random.default_rng(1).uniform(0.2, 1.0, (K, NY, NX)).astype(np.float32)
    path = tmp_path / "tomo.st"
    with mrcfile.new(path) as mrc:
        mrc.set_data(stack)
        mrc.set_image_stack()
        mrc.voxel_size = (2.5, 3.0, 1.0)  # angstrom, x y z
    np.savetxt(tmp_path / "tomo.rawtlt", TILTS, fmt="%.2f")
    return path, stack


def test_a_tilt_series_with_its_rawtlt_file(series):
    path, stack = series
    assert detect_format(path) == "mrc" and find_tilt_file(path) == path.with_suffix(".rawtlt")
    scan = read_scan(path)
    np.testing.assert_array_equal(scan.projections, stack)  # each image row one slice (IMOD's axis)
    np.testing.assert_allclose(np.rad2deg(scan.angles), TILTS, atol=1e-9)
    assert scan.source["raw_pixel_size_m"] == pytest.approx([2.5e-10, 3.0e-10])
    part = read_scan(path, rows=slice(1, 3), crop=(2, 6))
    np.testing.assert_array_equal(part.projections, stack[:, 1:3, 2:6])


def test_the_tilt_axis_along_the_rows_transposes_each_image(series, tmp_path):
    path, stack = series
    rows = ReaderOptions(tilt_axis="rows")
    scan = read_scan(path, options=rows)
    np.testing.assert_array_equal(scan.projections, stack.transpose(0, 2, 1))  # each image column one slice
    assert scan.source["raw_pixel_size_m"] == pytest.approx([3.0e-10, 2.5e-10])
    part = read_scan(path, rows=slice(2, 5), crop=(1, 4), options=rows)
    np.testing.assert_array_equal(part.projections, stack.transpose(0, 2, 1)[:, 2:5, 1:4])
    # the same series written with the axis along the rows reads back as the original with its axis vertical
    turned = tmp_path / "turned.mrc"
    with mrcfile.new(turned) as mrc:
        mrc.set_data(np.ascontiguousarray(stack.transpose(0, 2, 1)))
    np.savetxt(tmp_path / "turned.tlt", TILTS)
    np.testing.assert_array_equal(read_scan(turned, options=rows).projections, stack)


def test_tilt_angle_files_and_their_errors(series, tmp_path):
    path, _ = series
    aligned = tmp_path / "tomo.ali"
    aligned.write_bytes(path.read_bytes())
    np.savetxt(tmp_path / "tomo.tlt", TILTS + 0.5)
    assert find_tilt_file(aligned) == tmp_path / "tomo.tlt"  # an aligned stack takes the aligned angles
    np.testing.assert_allclose(np.rad2deg(read_scan(aligned).angles), TILTS + 0.5)
    np.savetxt(tmp_path / "short.txt", TILTS[:-1])
    with pytest.raises(NanoctError, match="13 images but 12 tilt angle"):
        read_scan(path, angles_file=tmp_path / "short.txt")
    (tmp_path / "tomo.rawtlt").unlink()
    (tmp_path / "tomo.tlt").unlink()
    with pytest.raises(NanoctError, match="no tomo.rawtlt or tomo.tlt"):
        read_scan(path)
    with pytest.raises(NanoctError, match="--tilt-axis"):
        read_scan(path, angles_file="-60:60", options=ReaderOptions(tilt_axis="diagonal"))


def test_a_truncated_mrc_is_one_error_line(series, tmp_path, capsys):
    path, _ = series
    path.write_bytes(path.read_bytes()[:-100])
    with pytest.raises(NanoctError, match="cannot read .* as MRC"):
        read_scan(path)
    assert run(["import", str(path), "--out", str(tmp_path / "o"), "--line-integrals"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and len(err.strip().splitlines()) == 1 and not (tmp_path / "o").exists()


def test_import_a_tilt_series_with_one_command(series, tmp_path, capsys):
    path, _ = series
    out = tmp_path / "data"
    assert run(["import", str(path), "--out", str(out), "--line-integrals", "--tilt-axis", "rows"]) == 0
    assert f"{NX} slice(s), {K} views x {NY} detector pixels" in capsys.readouterr().out
