"""`nanoct import` and `nanoct stack` on the real I13 scan: one axis, and a known 3-D motion recovered."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import zarr

from nanoct.cli import run
from nanoct.io.store import DataStore
from scan_cases import gauge_free_rms, known_motion, moved

I13 = Path(__file__).resolve().parents[1] / "data" / "realdata" / "i13-24737-tiff"


def _angles(tmp_path):
    path = tmp_path / "angles.txt"
    np.savetxt(path, np.loadtxt(I13 / "angles.txt")[10:101])
    return path


def test_import_and_stack_give_the_same_axis_on_the_real_scan(tmp_path):
    store = tmp_path / "store"
    flats, darks = str(I13 / "flat_00001.tiff"), str(I13 / "dark_00001.tiff")
    args = ["import", str(I13 / "tiffs"), "--out", str(store), "--angles", str(_angles(tmp_path)), "--flats", flats,
            "--darks", darks, "--center-offset", "auto"]  # fmt: skip
    assert run(args) == 0
    data = DataStore.open(store)
    axis = data.meta["scan"]["axis"]
    assert abs(axis["offset"] - 6.2) <= 0.5 and set(axis["estimates"]) >= {"mirror", "vo"}
    assert run(["stack", str(store), "--workers", "0", "-q"]) == 0
    info = DataStore.open(store).recons.motion_info("fbp_stack")
    assert info["center_offset"] == pytest.approx(data.geometry.center_offset, abs=0.1)  # import = stack
    assert abs(info["tilt"]["tilt_deg"]) < 0.3 and np.sqrt(np.mean(np.square(info["vertical"]))) < 0.1


def test_the_real_scan_streams_from_its_files(tmp_path):
    """`stack SCAN --out` on the TIFF folder: its dead flat pixels gather in some rows (0.6 % of the first
    block's), which the whole-detector tolerance of the import would refuse; the axis agrees with the import's."""
    flats, darks = str(I13 / "flat_00001.tiff"), str(I13 / "dark_00001.tiff")
    out = tmp_path / "slices.zarr"
    args = ["stack", str(I13 / "tiffs"), "--out", str(out), "--angles", str(_angles(tmp_path)), "--flats", flats,
            "--darks", darks, "--block", "16", "-w", "0", "-q"]  # fmt: skip
    assert run(args) == 0
    group = zarr.open_group(str(out), mode="r")
    assert group["slices"].shape[0] == 135 and np.isfinite(group["slices"][67]).all()
    assert abs(group.attrs["info"]["center_offset"] - 6.17) <= 0.5  # the mirror / find_center_vo consensus


def test_stack_recovers_a_known_3d_motion_added_to_the_real_scan(tmp_path, i13_line_integrals):
    li, angles = i13_line_integrals
    horizontal, vertical = known_motion(angles)
    np.save(tmp_path / "moved.npy", moved(li, horizontal, vertical).astype(np.float32))
    store = tmp_path / "store"
    args = ["import", str(tmp_path / "moved.npy"), "--out", str(store), "--angles", str(_angles(tmp_path)),
            "--line-integrals", "--center-offset", "auto"]  # fmt: skip
    assert run(args) == 0
    assert run(["stack", str(store), "--workers", "0", "-q"]) == 0
    data = DataStore.open(store)
    info = data.recons.motion_info("fbp_stack")
    assert info["horizontal_method"] == "centroid" and info["vertical_method"] == "row profiles"
    assert gauge_free_rms(np.asarray(info["vertical"]), vertical, angles, vertical=True) <= 0.25
    assert gauge_free_rms(data.recons.shared_shifts("fbp_stack"), horizontal, angles) <= 0.25
    assert run(["export", str(store), "--name", "fbp_stack", "--out", str(tmp_path / "shifts.txt"), "-q"]) == 0
    table = np.loadtxt(tmp_path / "shifts.txt")
    assert gauge_free_rms(-table[:, 1], vertical, angles, vertical=True) <= 0.25  # nabu's sign


@pytest.fixture(scope="module")
def i13_line_integrals(tmp_path_factory):
    from nanoct.io.scanio import line_integrals, read_scan

    path = _angles(tmp_path_factory.mktemp("angles"))
    scan = read_scan(I13 / "tiffs", angles_file=path, flats=I13 / "flat_00001.tiff", darks=I13 / "dark_00001.tiff")
    return line_integrals(scan).astype(np.float64), np.deg2rad(np.loadtxt(path))


def test_the_vertical_motion_goes_into_nabus_file(tmp_path):
    from nanoct.io.scanio import write_shifts

    path = write_shifts(tmp_path / "s.txt", [0.5, -0.25], vertical=[1.0, -2.0])
    assert np.loadtxt(path).tolist() == [[-0.5, -1.0], [0.25, 2.0]]  # nabu's sign: displacement of the projection
    assert np.loadtxt(write_shifts(tmp_path / "z.txt", [0.5, -0.25]))[:, 1].tolist() == [0.0, 0.0]


@pytest.mark.slow
def test_stack_without_air_recovers_a_known_motion_stored_or_streamed(tmp_path, i13_line_integrals):
    """The crop wider than the field of view: autofocus and matching (recorded), within 0.4 px; streamed alike."""
    import zarr

    li, angles = i13_line_integrals
    horizontal, vertical = known_motion(angles)
    crop = moved(li, horizontal, vertical)[:, 76:108, 40:120]  # 32 rows inside the sample: no air
    np.save(tmp_path / "moved.npy", crop.astype(np.float32))
    common = ["--angles", str(_angles(tmp_path)), "--line-integrals", "-w", "0", "-q"]
    assert run(["stack", str(tmp_path / "moved.npy"), "--store", str(tmp_path / "store"), *common]) == 0
    data = DataStore.open(tmp_path / "store")
    info = data.recons.motion_info("fbp_stack")
    assert info["horizontal_method"] == "focus+matching" and info["focus"]["accepted"] == [True, True]
    assert "tilt_deg" not in info["tilt"]  # the opposite views of a truncated object gave -6.2 degrees for ~0
    shifts = data.recons.shared_shifts("fbp_stack")
    assert gauge_free_rms(shifts, horizontal, angles) <= 0.4  # Dremel + matching (--refine 2,2,2,1): 0.97 px
    assert info["vertical_guard"]["significant"]
    assert gauge_free_rms(np.asarray(info["vertical"]), vertical, angles, vertical=True) <= 0.25
    # the axis that goes with the shifts: within 0.5 px of the whole scan's (6.2 px: mirror and find_center_vo)
    basis = np.stack([np.ones_like(angles), np.cos(angles), np.sin(angles)], axis=1)
    constant = np.linalg.lstsq(basis, shifts - horizontal, rcond=None)[0][0]
    assert abs(info["center_offset"] - constant - 6.2) <= 0.5
    # the streamed rows (`stack SCAN --out`) take the same path and find the same motion
    assert run(["stack", str(tmp_path / "moved.npy"), "--out", str(tmp_path / "s.zarr"), *common]) == 0
    streamed = dict(zarr.open_group(str(tmp_path / "s.zarr"), mode="r").attrs["info"])
    assert streamed["horizontal_method"] == "focus+matching" and streamed["vertical_guard"]["significant"]
    np.testing.assert_allclose(streamed["vertical"], info["vertical"], atol=1e-3)
    assert gauge_free_rms(np.asarray(streamed["shifts"]), shifts, angles) < 0.02
    assert streamed["center_offset"] == pytest.approx(info["center_offset"], abs=0.05)


@pytest.mark.slow
def test_stack_aligns_the_real_tilt_series_as_its_acquiring_group(tmp_path):
    """`nanoct import --line-integrals --tilt-axis rows` and `nanoct stack` on ETSpy's STEM needle (+-76
    degrees, counts): automatic, against the group's alignment in full-size pixels (about 30 s)."""
    from scan_cases import NEEDLE, needle_errors, needle_series

    _, angles, ref = needle_series()
    store = tmp_path / "needle"
    args = ["import", str(NEEDLE / "needle_bin2.mrc"), "--out", str(store), "--line-integrals", "--tilt-axis", "rows"]
    assert run([*args, "--center-offset", "auto", "-q"]) == 0
    assert run(["stack", str(store), "--workers", "0", "-q"]) == 0
    data = DataStore.open(store)
    info = data.recons.motion_info("fbp_stack")
    shifts = data.recons.shared_shifts("fbp_stack")
    errors = needle_errors(shifts, info["vertical"], info["center_offset"], info["tilt"]["tilt_deg"], angles, ref, 2)
    assert info["horizontal_method"] == "centroid"
    assert errors["horizontal"] <= 0.4 and errors["vertical"] <= 0.4  # measured 0.13 and 0.10 px
    assert abs(errors["tilt"]) <= 0.3 and abs(errors["axis"]) <= 1.0  # measured 2.83 against 2.79 degrees; +0.14 px
    assert np.isfinite(data.read_reconstruction("fbp_stack", [64])).all()


def test_the_axis_tilt_of_the_real_scan_is_not_made_by_undoing_its_motion(tmp_path, i13_line_integrals):
    """Undoing a drift of 3 px must hold the open beam at the view edges: filled with zeros it made the
    mirror axis of each row group depend on the row's open-beam level (a tilt of 3 degrees on this scan)."""
    from nanoct.core.geometry import Geometry
    from nanoct.io.store import create_scan
    from nanoct.workflows.stack import _tilt

    li, angles = i13_line_integrals
    t = np.linspace(0.0, 1.0, angles.size)
    drift = 3.0 * t - 1.5 + 1.2 * np.sin(4 * np.pi * t)  # the semi-real benchmarks' motion, without jitter
    sinos = moved(li, drift, np.zeros_like(drift)).transpose(1, 0, 2)
    geometry = Geometry.from_angles(angles, li.shape[2], li.shape[2], center_offset=6.2)
    store = create_scan(tmp_path / "moved", geometry, sinos, {"file": "I13 24737 moved", "format": "npy"})
    tilt = _tilt(store, np.zeros(angles.size), drift)["tilt"]
    assert abs(tilt["tilt_deg"]) < 0.3, tilt  # the scan has none (unmoved: -0.002 degrees)
