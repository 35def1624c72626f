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


def test_dead_pixels_within_tolerance_are_filled_from_their_row(truth):
    from nanoct.io.scanio import RawScan

    proj = truth["proj"].copy()
    proj[0, 0, 0] = proj[3, 1, 5] = proj[3, 1, 6] = 0.0  # below the dark: transmission < 0
    scan = RawScan(proj, np.deg2rad(truth["deg"]), flats=truth["flats"], darks=truth["darks"])
    out = line_integrals(scan, tolerance=0.01, floor=1e-6)
    good = line_integrals(RawScan(truth["proj"], scan.angles, flats=truth["flats"], darks=truth["darks"]))
    assert out[0, 0, 0] == pytest.approx(good[0, 0, 1], rel=1e-6)  # the edge: its nearest neighbour
    np.testing.assert_allclose(out[3, 1, 5:7], good[3, 1, 4] + (good[3, 1, 7] - good[3, 1, 4]) * np.array([1, 2]) / 3)
    unchanged = np.ones(out.shape, bool)
    unchanged[0, 0, 0] = unchanged[3, 1, 5] = unchanged[3, 1, 6] = False
    np.testing.assert_array_equal(out[unchanged], good[unchanged])
    with pytest.raises(NanoctError, match="<= 0"):
        line_integrals(scan, tolerance=0.0)


def test_raw_counts_without_flats_are_refused(truth):
    from nanoct.io.scanio import MAX_TRANSMISSION, RawScan

    counts = RawScan(truth["proj"], np.deg2rad(truth["deg"]))  # hundreds of counts, no flats
    with pytest.raises(NanoctError, match="raw counts, whose -log is no line integral"):
        line_integrals(counts)
    assert np.median(line_integrals(counts, normalised_later=True)) < -np.log(MAX_TRANSMISSION)
    transmissions = RawScan(truth["proj"] / truth["flats"].mean(axis=0), counts.angles)
    assert np.isfinite(line_integrals(transmissions)).all()


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
        ("hdf5-without-layout", "no known layout"),
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
            proj = truth["proj"] / truth["flats"].mean(axis=0)  # transmissions
            proj[:, 0] = 0.0  # a third of the detector at zero
            np.save(tmp_path / "p.npy", proj)
            np.savetxt(tmp_path / "a.txt", truth["deg"])
            return line_integrals(read_scan(tmp_path / "p.npy", angles_file=tmp_path / "a.txt"))
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


def test_the_flat_tolerance_is_apart_from_the_transmissions(truth):
    """A dead flat pixel above `tolerance` is refused, unless `flat_tolerance` (a reader of a few rows) allows it."""
    from nanoct.io.scanio import RawScan

    flats = truth["flats"].copy()
    flats[:, 1, 4] = truth["darks"][:, 1, 4].mean()
    scan = RawScan(truth["proj"], np.deg2rad(truth["deg"]), flats=flats, darks=truth["darks"])
    with pytest.raises(NanoctError, match="flat minus dark is not positive"):
        line_integrals(scan, tolerance=1e-6)
    out = line_integrals(scan, tolerance=1e-6, flat_tolerance=0.5)
    assert (out[:, 1, 4] == 0).all() and np.isfinite(out).all()


def test_selection_outside_the_detector_and_bad_options_are_refused(tmp_path, truth):
    from nanoct.workflows.importscan import import_scan

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


# ------------------------------------------------------------------------- nabu shifts files
def test_shifts_file_is_nabus_translation_movements_layout(tmp_path):
    """K rows 'horizontal vertical' that np.loadtxt (nabu's reader) reads into (K, 2); horizontal = -shift."""
    shifts = np.random.default_rng(6).normal(0, 2, 9)
    path = write_shifts(tmp_path / "s.txt", shifts, pixel_size_m=50e-9, notes=["left out 1 of 10 projections"])
    table = np.loadtxt(path)
    assert table.shape == (9, 2)
    np.testing.assert_allclose(table[:, 0], -shifts, atol=1e-6)
    np.testing.assert_array_equal(table[:, 1], 0.0)
    text = path.read_text()
    assert text.startswith("# horizontal vertical") and "left out 1 of 10" in text
    row = text.splitlines()[-1]  # nm of the horizontal value as a comment after the row
    assert row.split("#")[1].strip() == f"{-shifts[-1] * 50:.3f} nm"
    np.testing.assert_allclose(read_shifts(path, 9), shifts, atol=1e-6)
    np.testing.assert_allclose(read_shifts(path, 9, binning=2), shifts / 2, atol=1e-6)  # raw -> binned pixels


def test_nabus_own_reader_reads_the_shifts_file(tmp_path):
    utils = pytest.importorskip("nabu.resources.utils")
    shifts = np.random.default_rng(7).normal(0, 2, 12)
    path = write_shifts(tmp_path / "s.txt", shifts, pixel_size_m=40e-9, angles=np.linspace(0, np.pi, 12))
    # as nabu's ProcessConfig reads translation_movements_file
    table = utils.get_values_from_file(str(path), shape=(12, 2), any_size=True)
    assert table.shape == (12, 2)
    np.testing.assert_allclose(table[:, 0], -shifts, atol=1e-6)


def test_shifts_file_sign_is_nabus(tmp_path):
    """nabu's convention (its test_fbp_axis_corr): a sinogram whose row k is moved by
    scipy.ndimage.shift(row, h_k) is corrected with axis_correction h_k. The rows nanoct writes
    for a moving object must be those h_k: the moved sinogram matches the shifted rows, not the
    rows shifted the other way."""
    from scipy.ndimage import shift

    from nanoct.core.geometry import get_preset
    from nanoct.core.operators import RayTransform
    from nanoct.sim.phantoms import random_phantom

    g = get_preset("tiny-parallel")
    x = random_phantom(np.random.default_rng(1), g.n)
    rng = np.random.default_rng(8)
    motion = np.zeros((g.n_angles, 3))
    motion[:, :2] = rng.uniform(-3, 3, (g.n_angles, 2))
    moved = RayTransform(g, motion).forward(x)
    still = RayTransform(g).forward(x)
    phi = g.angles
    t_dot_eu = motion[:, 0] * np.cos(phi) + motion[:, 1] * np.sin(phi)  # nanoct's shift (Dremel's sign)
    horizontal = np.loadtxt(write_shifts(tmp_path / "s.txt", t_dot_eu))[:, 0]

    def error(h):
        rows = np.stack([shift(still[k], h[k], order=1) for k in range(g.n_angles)])
        return np.abs(rows - moved)[:, 8:-8].mean()

    assert error(horizontal) < 0.1 * error(-horizontal)


def test_view_column_and_ambiguous_shift_files(tmp_path):
    shifts = np.array([0.5, -1.0, 2.0, 0.25])
    legacy = tmp_path / "legacy.txt"
    legacy.write_text("# view shift_px (object shift along the detector axis, detector pixels; nanoct)\n"
                      + "".join(f"{k} {v}\n" for k, v in enumerate(shifts)))  # fmt: skip
    np.testing.assert_allclose(read_shifts(legacy, 4, binning=2), shifts)  # the data set's pixels, as written
    ambiguous = tmp_path / "ambiguous.txt"
    np.savetxt(ambiguous, np.c_[np.arange(4), shifts])
    with pytest.raises(NanoctError, match="view numbers"):
        read_shifts(ambiguous, 4)
    vertical = tmp_path / "vertical.txt"
    np.savetxt(vertical, np.c_[shifts, [0, 0, 0.5, 0]])
    with pytest.raises(NanoctError, match="vertical shifts up to 0.5"):
        read_shifts(vertical, 4)
    three = tmp_path / "three.txt"
    np.savetxt(three, np.c_[shifts, shifts, shifts])
    with pytest.raises(NanoctError, match="3 columns"):
        read_shifts(three, 4)
    beamline = tmp_path / "beamline.txt"  # numpy.savetxt of nabu's (K, 2) array, no header
    np.savetxt(beamline, np.c_[-shifts, np.zeros(4)])
    np.testing.assert_allclose(read_shifts(beamline, 4), shifts)


# ------------------------------------------------------------------------- odd imports
def test_truncated_files_are_refused(tmp_path, truth):
    full = _write_dxchange(tmp_path / "full.h5", truth).read_bytes()
    (tmp_path / "cut.h5").write_bytes(full[: len(full) * 3 // 4])
    with pytest.raises(NanoctError, match="cut.h5.*complete"):
        read_scan(tmp_path / "cut.h5", fmt="dxchange")
    np.savetxt(tmp_path / "a.txt", truth["deg"])
    for layout in ("pages", "contiguous"):
        tif = tmp_path / f"{layout}.tif"
        if layout == "pages":
            with tifffile.TiffWriter(tif) as w:
                for image in truth["proj"]:
                    w.write(image, contiguous=False)
        else:
            tifffile.imwrite(tif, truth["proj"])
        assert read_scan(tif, angles_file=tmp_path / "a.txt").n_views == K  # one series per page: every page read
        data = tif.read_bytes()
        for fraction in (0.5, 0.97):
            cut = tmp_path / f"cut_{layout}_{fraction}.tif"
            cut.write_bytes(data[: int(len(data) * fraction)])
            with pytest.raises(NanoctError, match=f"{cut.name}.*(truncated|damaged)"):
                read_scan(cut, angles_file=tmp_path / "a.txt")
    np.save(tmp_path / "p.npy", truth["proj"])
    (tmp_path / "cut.npy").write_bytes((tmp_path / "p.npy").read_bytes()[:-100])
    with pytest.raises(NanoctError, match="cut.npy.*complete"):
        read_scan(tmp_path / "cut.npy", angles_file=tmp_path / "a.txt")


def test_a_tiff_folder_with_an_odd_image_names_it(tmp_path, truth):
    folder = tmp_path / "proj"
    folder.mkdir()
    for k, image in enumerate(truth["proj"]):
        tifffile.imwrite(folder / f"p_{k:03d}.tif", image if k != 5 else image[:, :-1])
    np.savetxt(tmp_path / "a.txt", truth["deg"])
    with pytest.raises(NanoctError, match="p_005.tif has shape"):
        read_scan(folder, angles_file=tmp_path / "a.txt")


def test_flats_of_another_shape_name_the_file(tmp_path, truth):
    np.save(tmp_path / "p.npy", truth["proj"])
    np.savetxt(tmp_path / "a.txt", truth["deg"])
    np.save(tmp_path / "binned_flats.npy", truth["flats"][:, :, ::2])
    with pytest.raises(NanoctError, match="binned_flats.npy: flats have shape .* same detector size and binning"):
        read_scan(tmp_path / "p.npy", angles_file=tmp_path / "a.txt", flats=tmp_path / "binned_flats.npy")


def test_data_exchange_flats_of_another_shape_name_the_file(tmp_path, truth):
    path = tmp_path / "s.h5"
    with h5py.File(path, "w") as f:
        f["exchange/data"], f["exchange/theta"] = truth["proj"], truth["deg"]
        f["exchange/data_white"] = truth["flats"][:, :, :-1]
    with pytest.raises(NanoctError, match="s.h5: flats have shape"):
        read_scan(path)


def test_nan_frames_are_named_or_left_out(truth):
    from nanoct.io.scanio import RawScan, drop_bad_views

    proj = truth["proj"].copy()
    proj[3] = np.nan
    proj[7, 1, 2] = np.inf
    flats = truth["flats"].copy()
    flats[1, 0, 0] = np.nan
    scan = RawScan(proj, np.deg2rad(truth["deg"]), flats=flats, darks=truth["darks"], source={"file": "x.nxs"})
    with pytest.raises(NanoctError, match=r"x.nxs: projections 3, 7 \(angles .*\) hold NaN.*--drop-bad-views"):
        line_integrals(scan)
    kept, notes = drop_bad_views(scan, drop=True)
    assert kept.n_views == K - 2 and kept.flats.shape[0] == 3
    np.testing.assert_array_equal(kept.angles, np.delete(scan.angles, [3, 7]))
    np.testing.assert_allclose(line_integrals(kept), np.delete(truth["sino"], [3, 7], axis=0), atol=5e-3)
    assert notes == [
        "left out 2 of 12 projections with NaN or infinite values (3, 7)",
        "left out 1 of 4 flats with NaN or infinite values (1)",
    ]
    every = RawScan(np.full_like(proj, np.nan), scan.angles)
    with pytest.raises(NanoctError, match="every one of the 12 projections"):
        drop_bad_views(every, drop=True)


@pytest.mark.parametrize(
    ("values", "radians", "message"),
    [
        (np.zeros(K), False, "all 12 views have the angle 0"),
        (np.linspace(0, np.pi, K), False, "look like radians"),
        (np.linspace(0, 360, K), True, "look like degrees"),
        (np.r_[np.linspace(0, 180, K - 1), np.nan], False, "NaN"),
    ],
)
def test_angles_that_cannot_be_meant_are_refused(tmp_path, truth, values, radians, message):
    np.save(tmp_path / "p.npy", truth["proj"])
    np.savetxt(tmp_path / "a.txt", values)
    with pytest.raises(NanoctError, match=message):
        read_scan(tmp_path / "p.npy", angles_file=tmp_path / "a.txt", degrees=not radians)


def test_shifts_file_keeps_a_row_for_every_projection_of_the_scan(tmp_path):
    """Views an import left out get an interpolated, marked row (nabu counts every projection); reading skips them."""
    shifts = np.array([1.0, 2.0, 4.0, 5.0])
    path = write_shifts(tmp_path / "s.txt", shifts, left_out=[2, 5])
    table = np.loadtxt(path)
    np.testing.assert_allclose(table[:, 0], [-1.0, -2.0, -3.0, -4.0, -5.0, -5.0])  # interpolated in rows 2 and 5
    marked = [k for k, line in enumerate(path.read_text().splitlines()[-6:]) if "left out by the import" in line]
    assert marked == [2, 5]
    np.testing.assert_allclose(read_shifts(path, 4, left_out=[2, 5]), shifts)
    np.testing.assert_allclose(read_shifts(path, 6), [1.0, 2.0, 3.0, 4.0, 5.0, 5.0])  # a data set with all views
    with pytest.raises(NanoctError, match="has 6 views, the data set 3 .2 more projections"):
        read_shifts(path, 3, left_out=[2, 5])
    with pytest.raises(NanoctError, match="do not fit 6 projections"):
        write_shifts(tmp_path / "t.txt", shifts, left_out=[2, 9])


def test_nabus_motion_estimator_writes_the_rows_nanoct_writes(tmp_path):
    """nabu's own MotionEstimation (phase correlation of opposite views of a 360-degree scan, linear drift
    model) on projections of an object nanoct moved, turned into a translation_movements_file as nabu's
    ``generate_translations_movements_file`` does, gives the rows nanoct writes for the true motion."""
    motion_module = pytest.importorskip("nabu.estimation.motion")
    from nanoct.core.geometry import Geometry
    from nanoct.core.operators import RayTransform
    from nanoct.sim.phantoms import random_phantom

    k = 360
    phi = np.arange(k) * 2 * np.pi / k
    drift = np.zeros((k, 3))
    drift[:, :2] = (phi / (2 * np.pi))[:, None] * [3.0, -2.0]  # a linear drift: nabu's degree-1 model
    sino = RayTransform(Geometry.from_angles(phi, 63, 91), drift).forward(random_phantom(np.random.default_rng(1), 63))
    radios = np.repeat(sino[:, None, :], 16, axis=1).astype(np.float32)
    half = k // 2
    est = motion_module.MotionEstimation(radios[:half], radios[half:], phi[:half], phi[half:])
    est.estimate_horizontal_motion(degree=1)
    est.estimate_vertical_motion(degree=1)
    txy, tz = est.apply_fit_horiz(angles=phi), est.apply_fit_vertic(angles=phi)
    detector = est.project_sample_motion_onto_detector(txy, tz, phi, cor=0)
    nabu_rows = -detector[:, ::-1]  # as generate_translations_movements_file writes them
    ours = np.loadtxt(write_shifts(tmp_path / "s.txt", drift[:, 0] * np.cos(phi) + drift[:, 1] * np.sin(phi)))
    assert np.abs(ours[:, 0]).max() > 3.0
    np.testing.assert_allclose(nabu_rows[:, 0], ours[:, 0], atol=0.25)  # measured: 0.12 px at most


@pytest.mark.parametrize("fmt", ["nxtomo", "dxchange", "npy", "tiff", "tiff-folder"])
def test_reading_a_detector_window_equals_reading_all_and_cutting(tmp_path, truth, fmt):
    extra = {}
    if fmt == "nxtomo":
        path = _write_nxtomo(tmp_path / "s.nxs", truth)
    elif fmt == "dxchange":
        path = _write_dxchange(tmp_path / "s.h5", truth)
    else:
        np.savetxt(tmp_path / "a.txt", truth["deg"])
        np.save(tmp_path / "f.npy", truth["flats"])
        tifffile.imwrite(tmp_path / "d.tif", truth["darks"], photometric="minisblack")
        extra = {"angles_file": tmp_path / "a.txt", "flats": tmp_path / "f.npy", "darks": tmp_path / "d.tif"}
        path = tmp_path / {"npy": "s.npy", "tiff": "s.tif"}.get(fmt, "folder")
        if fmt == "npy":
            np.save(path, truth["proj"])
        elif fmt == "tiff":
            tifffile.imwrite(path, truth["proj"], photometric="minisblack")
        else:
            path.mkdir()
            for k, image in enumerate(truth["proj"]):
                tifffile.imwrite(path / f"p_{k:03d}.tif", image)
    full = read_scan(path, **extra)
    part = read_scan(path, rows=slice(1, 3), crop=(4, 15), **extra)
    assert part.source["detector_shape"] == [R, L] == full.source["detector_shape"]
    for name in ("projections", "flats", "darks"):
        np.testing.assert_array_equal(getattr(part, name), getattr(full, name)[:, 1:3, 4:15])
    with pytest.raises(NanoctError, match="--crop 4,40: the scan has 21 detector columns"):
        read_scan(path, crop=(4, 40), **extra)
