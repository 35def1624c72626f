"""NXtomo files written by ESRF's ``nxtomo`` library: entries, image keys, units, pixel size, round trip."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from nanoct.cli import run
from nanoct.core.errors import NanoctError
from nanoct.core.geometry import get_preset
from nanoct.core.operators import RayTransform
from nanoct.evaluation.metrics import psnr
from nanoct.io.scanio import detect_format, line_integrals, read_scan
from nanoct.io.store import DataStore
from nanoct.recon.batch import reconstruct_dataset
from nanoct.sim.phantoms import random_phantom

nxtomo = pytest.importorskip("nxtomo")
pint = pytest.importorskip("pint")
from nxtomo.nxobject.nxdetector import ImageKey  # noqa: E402

UREG = pint.get_application_registry()
K, R, L = 10, 4, 17
PIXEL = 65e-9  # effective pixel at the sample, metres


@pytest.fixture(scope="module")
def truth():
    rng = np.random.default_rng(5)
    sino = rng.uniform(0, 2, (K, R, L)).astype(np.float32)
    flat = rng.uniform(800, 1200, (R, L)).astype(np.float32)
    dark = rng.uniform(5, 15, (R, L)).astype(np.float32)
    proj = ((flat - dark) * np.exp(-sino) + dark).astype(np.float32)
    return {"sino": sino, "flat": flat, "dark": dark, "proj": proj, "deg": np.linspace(0, 180, K, endpoint=False)}


def _nx(t, *, unit="degree", extra_keys=True, proj=None, deg=None, sample_pixel=True):
    """An NXtomo as the library builds it: darks, flats, projections, then an alignment and an invalid frame."""
    proj = t["proj"] if proj is None else proj
    deg = t["deg"] if deg is None else deg
    k = len(proj)
    frames = [t["dark"][None]] * 2 + [t["flat"][None]] * 2 + [proj]
    keys = [ImageKey.DARK_FIELD] * 2 + [ImageKey.FLAT_FIELD] * 2 + [ImageKey.PROJECTION] * k
    angles = [0.0] * 4 + list(deg)
    if extra_keys:  # an alignment frame (image_key 0, image_key_control -1) and an invalid frame of garbage
        frames += [np.full((1, R, L), 7.0, np.float32), np.full((1, R, L), np.nan, np.float32)]
        keys += [ImageKey.ALIGNMENT, ImageKey.INVALID]
        angles += [0.0, 0.0]
    nx = nxtomo.NXtomo()
    nx.instrument.detector.data = np.concatenate(frames).astype(np.float32)
    nx.instrument.detector.image_key_control = np.array(keys)
    values = np.asarray(angles)
    nx.sample.rotation_angle = (np.deg2rad(values) if unit == "rad" else values) * UREG(unit)
    nx.instrument.detector.x_pixel_size = 6.5e-6 * UREG.meter
    nx.instrument.detector.y_pixel_size = 6.5e-6 * UREG.meter
    if sample_pixel:
        nx.sample.x_pixel_size = PIXEL * UREG.meter
        nx.sample.y_pixel_size = PIXEL * UREG.meter
    return nx


@pytest.mark.parametrize("unit", ["degree", "rad"])
def test_a_file_written_by_nxtomo_is_read(tmp_path, truth, unit):
    path = tmp_path / "scan.nx"
    _nx(truth, unit=unit).save(str(path), data_path="entry0000")
    assert detect_format(path) == "nxtomo"
    scan = read_scan(path)
    assert scan.n_views == K and scan.flats.shape == (2, R, L) and scan.darks.shape == (2, R, L)
    np.testing.assert_allclose(scan.angles, np.deg2rad(truth["deg"]), atol=1e-12)
    np.testing.assert_allclose(line_integrals(scan), truth["sino"], atol=2e-5)  # alignment/invalid frames left out
    assert scan.source["entry"] == "entry0000"
    assert scan.source["image_key"].endswith("image_key_control")
    assert scan.source["raw_pixel_size_m"] == pytest.approx([PIXEL, PIXEL])
    assert scan.source["pixel_size_from"].endswith("sample/x_pixel_size")
    assert any("alignment" in note for note in scan.source["notes"])


def test_the_detector_pixel_size_is_used_without_a_sample_one(tmp_path, truth):
    path = tmp_path / "scan.nx"
    _nx(truth, sample_pixel=False).save(str(path), data_path="entry0000")
    scan = read_scan(path)
    assert scan.source["raw_pixel_size_m"] == pytest.approx([6.5e-6, 6.5e-6])
    assert scan.source["pixel_size_from"].endswith("detector/x_pixel_size")


def test_several_entries_need_entry(tmp_path, truth, capsys):
    path = tmp_path / "two.nx"
    _nx(truth).save(str(path), data_path="entry0000")
    _nx(truth, proj=truth["proj"][:6], deg=truth["deg"][:6] * 2).save(str(path), data_path="scan_b")
    with pytest.raises(NanoctError, match="2 NXtomo entries .*entry0000, scan_b.*--entry"):
        read_scan(path)
    assert read_scan(path, entry="scan_b").n_views == 6
    assert read_scan(path, entry="entry0000").n_views == K
    with pytest.raises(NanoctError, match="present: entry0000, scan_b"):
        read_scan(path, entry="entry0001")
    assert run(["import", str(path), "--out", str(tmp_path / "d"), "--entry", "nope"]) == 2
    assert "no such NXtomo entry" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("unknown-key", "image key"),
        ("length-units", "not a unit of radian"),
        ("count-units", "'counts' .count., which is not a unit of radian"),
        ("radians-labelled-degrees", "look like radians"),
        ("frame-count", "one key and one angle per frame"),
        ("no-nxtomo-entry", "no known layout"),
    ],
)
def test_odd_nxtomo_files_are_refused(tmp_path, truth, case, message):
    path = tmp_path / "scan.nx"
    _nx(truth).save(str(path), data_path="entry0000")
    with h5py.File(path, "r+") as f:
        angles = f["entry0000/sample/rotation_angle"]
        if case == "unknown-key":
            keys = f["entry0000/instrument/detector/image_key_control"]
            keys[0] = 7
        elif case == "length-units":
            angles.attrs["units"] = "mm"
        elif case == "count-units":  # dimensionless in pint like an angle, but not one
            angles.attrs["units"] = "counts"
        elif case == "radians-labelled-degrees":
            angles[...] = np.deg2rad(angles[()])
        elif case == "frame-count":
            del f["entry0000/instrument/detector/image_key_control"]
            f["entry0000/instrument/detector/image_key_control"] = np.zeros(3, int)
        elif case == "no-nxtomo-entry":
            f["entry0000"].attrs["definition"] = "NXsomething"
            del f["entry0000/definition"]
    with pytest.raises(NanoctError, match=message):
        read_scan(path)
    if case == "radians-labelled-degrees":  # angles given separately replace the file's
        np.savetxt(tmp_path / "a.txt", truth["deg"])
        np.testing.assert_allclose(read_scan(path, angles_file=tmp_path / "a.txt").angles, np.deg2rad(truth["deg"]))


def test_a_truncated_nxtomo_file_is_refused(tmp_path, truth):
    path = tmp_path / "scan.nx"
    _nx(truth).save(str(path), data_path="entry0000")
    data = path.read_bytes()
    for fraction in (0.5, 0.95):
        cut = tmp_path / f"cut{fraction}.nx"
        cut.write_bytes(data[: int(len(data) * fraction)])
        with pytest.raises(NanoctError, match="truncated|complete"):
            read_scan(cut)


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    """Phantoms -> intensities -> a file written by nxtomo (pixel 65 nm) -> nanoct import with binning 2."""
    tmp = tmp_path_factory.mktemp("nx")
    g = get_preset("tiny-parallel")
    rng = np.random.default_rng(2)
    phantoms = np.stack([random_phantom(np.random.default_rng(40 + s), g.n) for s in range(2)])
    line = np.stack([RayTransform(g).forward(p) for p in phantoms]).transpose(1, 0, 2) / 8.0  # (K, 2 rows, L)
    line = np.repeat(line, 2, axis=1)  # 4 detector rows, binned back to 2 slices
    flat = rng.uniform(900, 1100, line.shape[1:]).astype(np.float32)
    dark = rng.uniform(5, 10, line.shape[1:]).astype(np.float32)
    proj = ((flat - dark) * np.exp(-line) + dark).astype(np.float32)
    nx = nxtomo.NXtomo()
    nx.instrument.detector.data = np.concatenate([dark[None], flat[None], proj])
    nx.instrument.detector.image_key_control = np.r_[2, 1, np.zeros(len(proj), int)]
    nx.sample.rotation_angle = np.r_[0.0, 0.0, np.rad2deg(g.angles)] * UREG.degree
    nx.sample.x_pixel_size = PIXEL * UREG.meter
    nx.sample.y_pixel_size = PIXEL * UREG.meter
    src = tmp / "scan.nx"
    nx.save(str(src), data_path="entry0000")
    out = tmp / "data"
    # the binned detector (45 pixels) keeps the field of view: image 45 pixels of twice the size
    code = run(["import", str(src), "--out", str(out), "--binning", "2", "--size", "45"])
    return {"code": code, "out": out, "phantoms": phantoms, "geometry": g}


def test_nxtomo_round_trip_import_and_reconstruct(imported, capsys):
    assert imported["code"] == 0
    store = DataStore.open(imported["out"])
    assert store.n == 2 and store.geometry.n_angles == imported["geometry"].n_angles
    assert store.meta["scan"]["pixel_size_m"] == pytest.approx([2 * PIXEL, 2 * PIXEL])
    assert store.meta["scan"]["raw_pixel_size_m"] == pytest.approx([PIXEL, PIXEL])
    reconstruct_dataset(imported["out"], "fbp", workers=0, progress=False)
    images = store.read_reconstruction("fbp")
    for image, phantom in zip(images, imported["phantoms"]):
        truth_binned = phantom[:62, :62].reshape(31, 2, 31, 2).mean(axis=(1, 3)) / 8.0 * 2  # pixel twice as wide
        centre = image[7:38, 7:38]
        assert psnr(centre, truth_binned) > 20.0  # measured 22.7 and 23.5 dB
        assert np.corrcoef(centre.ravel(), truth_binned.ravel())[0, 1] > 0.95  # measured 0.988 and 0.980


def test_a_beamline_shifts_file_goes_in_and_comes_out_in_raw_pixels_and_nm(imported, tmp_path, capsys):
    """A nabu file (raw detector pixels) fixes Dremel's motion on the binned data set; the export gives it back."""
    g = DataStore.open(imported["out"]).geometry
    horizontal = np.round(np.random.default_rng(9).normal(0, 1.5, g.n_angles), 3)
    beamline = tmp_path / "movements.txt"
    np.savetxt(beamline, np.c_[horizontal, np.zeros(g.n_angles)])  # as nabu's estimate_motion writes it
    params = ["-w", "0", "-q", "--param", "n_iter=1", "--param", f"shifts_from={beamline}"]
    params += ["--param", "fix_shifts=true"]
    assert run(["reconstruct", str(imported["out"]), "--method", "dremel", "--name", "fixed", *params]) == 0
    stored = DataStore.open(imported["out"]).read_shifts("fixed", [0])[0]
    np.testing.assert_allclose(stored, -horizontal / 2, atol=1e-5)  # binned pixels, nanoct's sign
    out = tmp_path / "shifts.txt"
    assert run(["export", str(imported["out"]), "--name", "fixed", "--out", str(out)]) == 0
    np.testing.assert_allclose(np.loadtxt(out), np.c_[horizontal, np.zeros(g.n_angles)], atol=2e-5)
    nm = [float(line.split("#")[1].split()[0]) for line in out.read_text().splitlines() if not line.startswith("#")]
    np.testing.assert_allclose(nm, horizontal * PIXEL * 1e9, atol=2e-3)


def test_a_virtual_dataset_with_missing_sources_is_refused(tmp_path, truth):
    """nxtomo links the acquisition files as virtual datasets; a missing source would read as zeros."""
    frames = np.concatenate([truth["dark"][None], truth["flat"][None], truth["proj"]])
    with h5py.File(tmp_path / "acquisition.h5", "w") as f:
        f["frames"] = frames
    layout = h5py.VirtualLayout(shape=frames.shape, dtype=np.float32)
    layout[:] = h5py.VirtualSource("acquisition.h5", "frames", shape=frames.shape)
    path = tmp_path / "linked.nx"
    with h5py.File(path, "w") as f:
        f.create_virtual_dataset("entry/instrument/detector/data", layout, fillvalue=0)
        f["entry/instrument/detector/image_key"] = np.r_[2, 1, np.zeros(K, int)]
        f["entry/sample/rotation_angle"] = np.r_[0.0, 0.0, truth["deg"]]
    np.testing.assert_allclose(line_integrals(read_scan(path)), truth["sino"], atol=2e-5)  # sources next to it
    (tmp_path / "acquisition.h5").rename(tmp_path / "elsewhere.h5")
    with pytest.raises(NanoctError, match="source file.*acquisition.h5 is missing"):
        read_scan(path)


def test_views_left_out_by_the_import_keep_their_rows_in_the_exported_shifts(tmp_path, capsys):
    """A NaN view dropped and the 360-degree view of a [0, 360] scan: the export still has one row per
    projection of the file (what nabu expects), and reading it back fixes the same motion."""
    g = get_preset("tiny-parallel")
    line = RayTransform(g).forward(random_phantom(np.random.default_rng(5), g.n))[:, None, :] / 8.0
    proj = np.exp(-line).astype(np.float32)
    proj[4] = np.nan
    nx = nxtomo.NXtomo()
    nx.instrument.detector.data = np.concatenate([proj, proj[:1]])  # normalised already: no flats
    nx.instrument.detector.image_key_control = np.zeros(g.n_angles + 1, int)
    nx.sample.rotation_angle = np.r_[np.rad2deg(g.angles), 360.0] * UREG.degree
    nx.sample.x_pixel_size = PIXEL * UREG.meter
    src = tmp_path / "scan.nx"
    nx.save(str(src), data_path="entry0000")
    out = tmp_path / "data"
    assert run(["import", str(src), "--out", str(out), "--drop-bad-views"]) == 0
    err = capsys.readouterr().err
    assert "left out 1 of 141 projections with NaN" in err and "left out 1 view(s) repeating" in err
    store = DataStore.open(out)
    assert store.geometry.n_angles == g.n_angles - 1 and store.meta["scan"]["left_out_views"] == [4, 140]
    assert run(["info", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "pixel      65 nm" in printed and "note       left out 1 view(s) repeating" in printed
    horizontal = np.round(np.random.default_rng(10).normal(0, 1, g.n_angles + 1), 3)
    beamline = tmp_path / "movements.txt"
    np.savetxt(beamline, np.c_[horizontal, np.zeros(g.n_angles + 1)])  # one row per projection of the file
    params = ["-w", "0", "-q", "--param", "n_iter=1", "--param", f"shifts_from={beamline}"]
    assert run(["reconstruct", str(out), "--method", "dremel", *params, "--param", "fix_shifts=true"]) == 0
    kept = np.delete(horizontal, [4, 140])
    np.testing.assert_allclose(DataStore.open(out).read_shifts("dremel", [0])[0], -kept, atol=1e-5)
    exported = tmp_path / "shifts.txt"
    assert run(["export", str(out), "--name", "dremel", "--out", str(exported)]) == 0
    table = np.loadtxt(exported)
    assert table.shape == (g.n_angles + 1, 2)
    np.testing.assert_allclose(np.delete(table[:, 0], [4, 140]), kept, atol=2e-5)
    np.testing.assert_allclose(table[4, 0], (horizontal[3] + horizontal[5]) / 2, atol=2e-5)
