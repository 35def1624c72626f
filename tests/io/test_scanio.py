"""Reading measured scans: every supported format, flat/dark correction, and bad input."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import tifffile

from nanoct.core.errors import NanoctError
from nanoct.io.scanio import (
    detect_format,
    line_integrals,
    read_scan,
    read_shifts,
    sinograms,
    write_images,
    write_shifts,
)

K, R, L = 12, 3, 21


@pytest.fixture(scope="module")
def truth():
    """Line integrals, flats, darks and the intensities a detector would record."""
    rng = np.random.default_rng(0)
    sino = rng.uniform(0, 2, (K, R, L)).astype(np.float32)
    flat = rng.uniform(800, 1200, (R, L)).astype(np.float32)
    dark = rng.uniform(5, 15, (R, L)).astype(np.float32)
    flats = flat + rng.normal(0, 1, (4, R, L)).astype(np.float32)
    darks = dark + rng.normal(0, 0.1, (3, R, L)).astype(np.float32)
    dark_mean = darks.mean(0)
    intensity = (flats.mean(0) - dark_mean) * np.exp(-sino) + dark_mean  # what the correction must invert
    angles_deg = np.sort(rng.uniform(0, 180, K))
    return {"sino": sino, "flats": flats, "darks": darks, "proj": intensity.astype(np.float32), "deg": angles_deg}


def _write_nxtomo(path, t, *, angles=None):
    frames = np.concatenate([t["darks"], t["flats"], t["proj"]])
    keys = np.r_[np.full(len(t["darks"]), 2), np.full(len(t["flats"]), 1), np.zeros(K, int)]
    deg = np.r_[np.zeros(len(t["darks"]) + len(t["flats"])), t["deg"]] if angles is None else angles
    with h5py.File(path, "w") as f:
        f["entry/instrument/detector/data"] = frames
        f["entry/instrument/detector/image_key"] = keys
        f["entry/sample/rotation_angle"] = deg
    return path


def _write_dxchange(path, t):
    with h5py.File(path, "w") as f:
        f["exchange/data"] = t["proj"]
        f["exchange/data_white"] = t["flats"]
        f["exchange/data_dark"] = t["darks"]
        f["exchange/theta"] = t["deg"]
    return path


def _darks(tmp_path):
    np.save(tmp_path / "d.npy", np.full((2, R, L), 10.0, np.float32))
    return tmp_path / "d.npy"


def _check(scan, t):
    np.testing.assert_allclose(scan.angles, np.deg2rad(t["deg"]), rtol=1e-12)
    np.testing.assert_allclose(line_integrals(scan), t["sino"], atol=2e-5)


def test_nxtomo(tmp_path, truth):
    path = _write_nxtomo(tmp_path / "scan.nxs", truth)
    assert detect_format(path) == "nxtomo"
    scan = read_scan(path)
    assert scan.flats.shape == (4, R, L) and scan.darks.shape == (3, R, L)
    _check(scan, truth)


def test_dxchange(tmp_path, truth):
    path = _write_dxchange(tmp_path / "scan.h5", truth)
    assert detect_format(path) == "dxchange"
    _check(read_scan(path), truth)


@pytest.mark.parametrize("layout", ["multipage", "folder"])
def test_tiff(tmp_path, truth, layout):
    if layout == "multipage":
        path = tmp_path / "proj.tif"
        tifffile.imwrite(path, truth["proj"], photometric="minisblack")
    else:
        path = tmp_path / "proj"
        path.mkdir()
        for k, image in enumerate(truth["proj"]):
            tifffile.imwrite(path / f"proj_{k:04d}.tif", image)
    tifffile.imwrite(tmp_path / "flat.tif", truth["flats"], photometric="minisblack")
    tifffile.imwrite(tmp_path / "dark.tif", truth["darks"], photometric="minisblack")
    np.savetxt(tmp_path / "angles.txt", truth["deg"])
    scan = read_scan(
        path, angles_file=tmp_path / "angles.txt", flats=tmp_path / "flat.tif", darks=tmp_path / "dark.tif"
    )
    assert detect_format(path) == "tiff"
    _check(scan, truth)


def test_npy_sinogram_already_line_integrals(tmp_path, truth):
    np.save(tmp_path / "sino.npy", truth["sino"][:, 1])
    np.savetxt(tmp_path / "angles.txt", np.deg2rad(truth["deg"]))
    scan = read_scan(tmp_path / "sino.npy", angles_file=tmp_path / "angles.txt", degrees=False, is_line_integral=True)
    assert scan.projections.shape == (K, 1, L)
    _check(scan, {**truth, "sino": truth["sino"][:, 1:2]})


def test_dead_pixels_within_tolerance_are_floored(truth):
    from nanoct.io.scanio import RawScan

    proj = truth["proj"].copy()
    proj[0, 0, 0] = 0.0  # below the dark: transmission < 0
    scan = RawScan(proj, np.deg2rad(truth["deg"]), flats=truth["flats"], darks=truth["darks"])
    out = line_integrals(scan, tolerance=0.01, floor=1e-6)
    assert out[0, 0, 0] == pytest.approx(-np.log(1e-6), rel=1e-5)
    with pytest.raises(NanoctError, match="<= 0"):
        line_integrals(scan, tolerance=0.0)


def test_sinograms_select_crop_and_bin(truth):
    sino = sinograms(truth["sino"], rows=slice(0, 2), crop=(1, 21), binning=2)
    assert sino.shape == (1, K, 10)
    expected = truth["sino"][:, 0:2, 1:21].reshape(K, 1, 2, 10, 2).mean(axis=(2, 4))[:, 0]
    np.testing.assert_allclose(sino[0], expected, rtol=1e-6)
    assert sinograms(truth["sino"]).shape == (R, K, L)


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("missing", "does not exist"),
        ("unknown-extension", "--format"),
        ("hdf5-without-layout", "neither NXtomo"),
        ("angle-count", "angle"),
        ("flats-shape", "flats have shape"),
        ("nan", "NaN"),
        ("no-angles", "--angles"),
        ("bad-format", "unknown"),
        ("too-many-nonpositive", "<= 0"),
        ("flats-below-darks", "flat minus dark is not positive"),
    ],
)
def test_bad_input(tmp_path, truth, case, message):
    def run():
        if case == "missing":
            return read_scan(tmp_path / "nope.h5")
        if case == "unknown-extension":
            (tmp_path / "scan.xyz").write_text("x")
            return read_scan(tmp_path / "scan.xyz")
        if case == "hdf5-without-layout":
            with h5py.File(tmp_path / "other.h5", "w") as f:
                f["something"] = np.zeros(3)
            return read_scan(tmp_path / "other.h5")
        if case == "angle-count":
            return read_scan(_write_nxtomo(tmp_path / "s.nxs", truth, angles=np.zeros(3)))
        if case == "flats-shape":
            np.save(tmp_path / "p.npy", truth["proj"])
            np.save(tmp_path / "f.npy", truth["flats"][:, :, :-1])
            np.savetxt(tmp_path / "a.txt", truth["deg"])
            return read_scan(tmp_path / "p.npy", angles_file=tmp_path / "a.txt", flats=tmp_path / "f.npy")
        if case == "nan":
            bad = truth["proj"].copy()
            bad[2, 1, 3] = np.nan
            np.save(tmp_path / "p.npy", bad)
            np.savetxt(tmp_path / "a.txt", truth["deg"])
            return line_integrals(read_scan(tmp_path / "p.npy", angles_file=tmp_path / "a.txt"))
        if case == "no-angles":
            np.save(tmp_path / "p.npy", truth["proj"])
            return read_scan(tmp_path / "p.npy")
        if case == "bad-format":
            return read_scan(_write_dxchange(tmp_path / "s.h5", truth), fmt="edf")
        if case == "too-many-nonpositive":
            proj = truth["proj"].copy()
            proj[:, 0] = 0.0  # a third of the detector below the dark current
            np.save(tmp_path / "p.npy", proj)
            np.savetxt(tmp_path / "a.txt", truth["deg"])
            return line_integrals(read_scan(tmp_path / "p.npy", angles_file=tmp_path / "a.txt", darks=_darks(tmp_path)))
        if case == "flats-below-darks":
            path = tmp_path / "s.h5"
            with h5py.File(path, "w") as f:
                f["exchange/data"] = truth["proj"]
                f["exchange/data_white"] = truth["darks"]  # flats and darks swapped
                f["exchange/data_dark"] = truth["flats"]
                f["exchange/theta"] = truth["deg"]
            return line_integrals(read_scan(path))
        raise AssertionError(case)

    with pytest.raises(NanoctError, match=message):
        run()


@pytest.mark.parametrize("suffix", [".tif", ".npy", ".h5"])
def test_export_round_trip(tmp_path, suffix):
    images = np.random.default_rng(3).random((4, 9, 9)).astype(np.float32)
    path = write_images(tmp_path / f"recon{suffix}", images, attrs={"name": "dremel"})
    if suffix == ".tif":
        back = tifffile.imread(path)
    elif suffix == ".npy":
        back = np.load(path)
    else:
        with h5py.File(path) as f:
            back = f["data"][()]
            assert f["data"].attrs["name"] == "dremel"
    np.testing.assert_array_equal(back, images)
    assert back.dtype == np.float32
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # no temporary left


def test_shifts_round_trip(tmp_path):
    shifts = np.random.default_rng(4).normal(0, 1.5, 17)
    path = write_shifts(tmp_path / "shifts.txt", shifts, angles=np.linspace(0, np.pi, 17, endpoint=False))
    np.testing.assert_allclose(read_shifts(path, 17), shifts, atol=1e-6)
    one_column = tmp_path / "plain.txt"
    np.savetxt(one_column, shifts)
    np.testing.assert_allclose(read_shifts(one_column, 17), shifts)
    with pytest.raises(NanoctError, match="has 17 views"):
        read_shifts(path, 16)
    (tmp_path / "bad.txt").write_text("# view shift_px\n0 1.0\n0 2.0\n")
    with pytest.raises(NanoctError, match="once each"):
        read_shifts(tmp_path / "bad.txt", 2)


def test_export_refuses_unknown_extension_and_nan(tmp_path):
    with pytest.raises(NanoctError, match="export format"):
        write_images(tmp_path / "x.png", np.zeros((1, 3, 3)))
    with pytest.raises(NanoctError, match="NaN"):
        write_shifts(tmp_path / "s.txt", [0.0, np.nan])
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("layout", ["column", "two-column", "one-line"])
def test_angle_file_layouts(tmp_path, layout):
    from nanoct.io.scanio import read_angles

    deg = np.array([0.0, 1.5, 3.0, 4.5])
    path = tmp_path / "angles.txt"
    if layout == "column":
        np.savetxt(path, deg)
    elif layout == "two-column":
        np.savetxt(path, np.c_[np.arange(4), deg], header="view angle")
    else:
        path.write_text(" ".join(map(str, deg)) + "\n")
    np.testing.assert_allclose(read_angles(path), np.deg2rad(deg))
    np.testing.assert_allclose(read_angles(path, degrees=False), deg)


def test_a_dead_flat_pixel_gives_line_integral_zero(truth):
    from nanoct.io.scanio import RawScan

    flats = truth["flats"].copy()
    flats[:, 1, 4] = truth["darks"][:, 1, 4].mean()  # no open-beam signal in one pixel
    out = line_integrals(
        RawScan(truth["proj"], np.deg2rad(truth["deg"]), flats=flats, darks=truth["darks"]), tolerance=0.05
    )
    assert (out[:, 1, 4] == 0).all()
    np.testing.assert_allclose(np.delete(out.reshape(K, -1), 1 * L + 4, axis=1),
                               np.delete(truth["sino"].reshape(K, -1), 1 * L + 4, axis=1), atol=2e-5)  # fmt: skip


def test_selection_outside_the_detector_and_bad_options_are_refused(tmp_path, truth):
    from nanoct.io.scanio import import_scan

    np.save(tmp_path / "p.npy", truth["sino"])
    np.savetxt(tmp_path / "a.txt", truth["deg"])
    common = {"angles_file": tmp_path / "a.txt", "is_line_integral": True}
    with pytest.raises(NanoctError, match="--rows"):
        sinograms(truth["sino"], rows=slice(2, 10))
    with pytest.raises(NanoctError, match="--rows"):
        import_scan(tmp_path / "p.npy", tmp_path / "out", rows=slice(2, 10), **common)
    with pytest.raises(NanoctError, match="n=0"):
        import_scan(tmp_path / "p.npy", tmp_path / "out", size=0, **common)
    with pytest.raises(NanoctError, match="--tolerance"):
        import_scan(tmp_path / "p.npy", tmp_path / "out", tolerance=1.5, **common)
    assert not (tmp_path / "out").exists()
