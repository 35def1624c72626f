"""Measured scans end to end: import every format, reconstruct, export, and bad input via the CLI."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import tifffile

from nanoct.cli import run
from nanoct.core.geometry import Geometry, get_preset
from nanoct.core.operators import RayTransform
from nanoct.evaluation.metrics import psnr
from nanoct.io.readers import READERS
from nanoct.io.store import DataStore
from nanoct.recon.batch import reconstruct_dataset
from nanoct.sim.motion import MotionParams, sample_motion
from nanoct.sim.phantoms import random_phantom
from scan_files import WRITERS, ScanData

OFFSET = 2.0  # rotation axis 2 raw detector pixels right of the detector centre
SLICES = 3


@pytest.fixture(scope="module")
def scan():
    """A 3-slice stack of tiny-parallel data with one shared motion, uneven angles, an axis offset, flats and darks."""
    base = get_preset("tiny-parallel")
    rng = np.random.default_rng(11)
    angles = np.sort(base.angles + rng.uniform(-0.2, 0.2, base.n_angles) * (np.pi / base.n_angles))
    geometry = Geometry.from_angles(angles, base.n, base.n_det, center_offset=OFFSET)
    motion = sample_motion(rng, base.n_angles, MotionParams.for_kind("parallel"))
    phantoms = np.stack([random_phantom(np.random.default_rng(100 + s), base.n) for s in range(SLICES)])
    op = RayTransform(geometry, motion)
    sino = np.stack([op.forward(p) for p in phantoms])  # (S, K, L)
    line = sino.transpose(1, 0, 2) / 8.0  # (K, R, L); scaled so the transmissions stay well above 0
    flat = rng.uniform(900, 1100, (SLICES, base.n_det)).astype(np.float32)
    dark = rng.uniform(5, 10, (SLICES, base.n_det)).astype(np.float32)
    proj = ((flat - dark) * np.exp(-line) + dark).astype(np.float32)
    return {
        "geometry": geometry, "phantoms": phantoms, "sino": sino / 8.0, "motion": motion, "proj": proj,
        "flats": np.stack([flat] * 2), "darks": np.stack([dark] * 2), "deg": np.rad2deg(angles),
    }  # fmt: skip


def _write(tmp_path, scan, fmt):
    """An NXtomo file (``fmt`` "nxtomo") or a ``.npy`` stack with its angles, flats and darks files beside it."""
    if fmt == "nxtomo":
        path = tmp_path / "scan.nxs"
        frames = np.concatenate([scan["darks"], scan["flats"], scan["proj"]])
        keys = np.r_[[2, 2, 1, 1], np.zeros(len(scan["proj"]), int)]
        with h5py.File(path, "w") as f:
            f["entry/instrument/detector/data"] = frames
            f["entry/instrument/detector/image_key"] = keys
            f["entry/sample/rotation_angle"] = np.r_[np.zeros(4), scan["deg"]]
        return path, []
    np.savetxt(tmp_path / "angles.txt", scan["deg"])
    extra = ["--angles", str(tmp_path / "angles.txt"), "--flats", str(tmp_path / "f.npy"), "--darks"]
    np.save(tmp_path / "f.npy", scan["flats"])
    np.save(tmp_path / "d.npy", scan["darks"])
    extra.append(str(tmp_path / "d.npy"))
    np.save(tmp_path / "scan.npy", scan["proj"])
    return tmp_path / "scan.npy", extra


@pytest.mark.slow
@pytest.mark.parametrize("fmt", READERS)
def test_import_every_format(tmp_path, scan, fmt, capsys):
    """Every registered format, written by its writer (``scan_files.WRITERS``) from the same intensities."""
    written = WRITERS[fmt](tmp_path, ScanData(scan["proj"], scan["flats"], scan["darks"], scan["deg"]))
    src, extra = written.path, written.cli_args()
    out = tmp_path / "data"
    assert run(["import", str(src), "--out", str(out), "--center-offset", str(OFFSET), *extra]) == 0
    store = DataStore.open(out)
    assert store.is_scan and store.n == SLICES and (store.indices("test") == np.arange(SLICES)).all()
    assert store.geometry.center_offset == pytest.approx(OFFSET)
    np.testing.assert_allclose(store.geometry.angles, np.deg2rad(scan["deg"]), rtol=1e-10)
    for s in range(SLICES):
        np.testing.assert_allclose(store.read_sample(s).sinogram, scan["sino"][s], atol=2e-4)
    # the same import again is a no-op; info says what the data set is
    assert run(["import", str(src), "--out", str(out), "--center-offset", str(OFFSET), *extra]) == 0
    capsys.readouterr()
    assert run(["info", str(out)]) == 0
    assert "no ground truth" in capsys.readouterr().out


def test_the_same_import_again_rewrites_lost_damaged_and_unwritten_slices(tmp_path, scan, capsys):
    src, _ = _write(tmp_path, scan, "nxtomo")
    args = ["import", str(src), "--center-offset", str(OFFSET)]
    assert run([*args, "--out", str(tmp_path / "ref"), "-q"]) == 0
    out = tmp_path / "data"
    assert run([*args, "--out", str(out), "-q"]) == 0
    store = DataStore.open(out, mode="r+")
    (out / "sinograms" / "c" / "0" / "0" / "0").unlink()  # a lost chunk
    (out / "sinograms" / "c" / "1" / "0" / "0").write_bytes(b"xx")  # an unreadable one
    store._array("done")[2] = False  # a slice an interrupted import did not finish
    assert run(["info", str(out), "--check", "-q"]) == 2
    assert "rerun 'nanoct import'" in capsys.readouterr().err
    assert run([*args, "--out", str(out), "-q"]) == 0
    assert run(["info", str(out), "--check", "-q"]) == 0
    for s in range(SLICES):
        ref = tmp_path / "ref" / "sinograms" / "c" / str(s) / "0" / "0"
        assert (out / "sinograms" / "c" / str(s) / "0" / "0").read_bytes() == ref.read_bytes()
    assert DataStore.open(out).complete_scan(DataStore.open(out).read_array("sinograms", range(SLICES))).size == 0


def test_the_same_import_from_another_path_resumes_and_another_file_is_refused(tmp_path, scan, capsys):
    """The kept import is the same one from any path to the file; other options or other data are refused,
    naming what differs, and nothing is written."""
    src, _ = _write(tmp_path, scan, "nxtomo")
    out = tmp_path / "data"
    assert run(["import", str(src), "--out", str(out), "--center-offset", str(OFFSET), "-q"]) == 0
    chunks = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    (tmp_path / "moved").mkdir()
    moved = tmp_path / "moved" / "copy.nxs"
    moved.write_bytes(src.read_bytes())
    assert run(["import", str(moved), "--out", str(out), "--center-offset", str(OFFSET), "-q"]) == 0
    assert run(["import", str(moved), "--out", str(out), "--center-offset", "1", "-q"]) == 2
    err = capsys.readouterr().err
    assert "holds an import of " in err and "center_offset_raw 2.0 (this import: 1.0)" in err
    with h5py.File(moved, "r+") as f:  # another file under the same options
        f["entry/instrument/detector/data"][4, 1, 10] *= 0.5
    assert run(["import", str(moved), "--out", str(out), "--center-offset", str(OFFSET), "-q"]) == 2
    assert "slice 1 differs from this import's" in capsys.readouterr().err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == chunks  # nothing written


def test_a_refused_import_names_the_option_changed_before_the_axis_it_moved(tmp_path, scan, capsys):
    """The same import with --open-beam added: the axis --center-offset auto estimates moves with it, and the
    refusal names the option the user changed, not the estimate that followed from it."""
    src, _ = _write(tmp_path, scan, "nxtomo")
    args = ["import", str(src), "--out", str(tmp_path / "data"), "--center-offset", "auto", "-q"]
    assert run(args) == 0
    capsys.readouterr()
    assert run([*args, "--open-beam", "--air-columns", "0:3,88:91"]) == 2
    err = capsys.readouterr().err
    assert "corrections.open_beam False (this import: True), set by --open-beam" in err, err
    assert "set by --air-columns" in err and "axis" not in err and err.count("\n") == 1
    assert run([*args, "--binning", "2"]) == 2
    assert "binning 1 (this import: 2), set by --binning;" in capsys.readouterr().err
    # --stripes fills in its method's parameters: the refusal names --stripes, not --stripe-params
    assert run([*args, "--stripes", "all"]) == 2
    err = capsys.readouterr().err
    assert "corrections.stripes None (this import: 'all'), set by --stripes" in err and "stripe_params" not in err


def test_binning_says_which_pixels_it_leaves_out(tmp_path, scan, capsys):
    src, _ = _write(tmp_path, scan, "nxtomo")  # 3 rows x 91 columns
    assert run(["import", str(src), "--out", str(tmp_path / "b2"), "--binning", "2", "--center-offset", "1"]) == 0
    err = capsys.readouterr().err
    assert "--binning 2 keeps 90 of the 91 detector columns selected (the last 1 are left out" in err
    assert "keeps 2 of the 3 rows selected" in err
    notes = DataStore.open(tmp_path / "b2").meta["scan"]["notes"]
    assert DataStore.open(tmp_path / "b2").n == 1 and sum("--binning 2" in note for note in notes) == 2
    assert run(["import", str(src), "--out", str(tmp_path / "c"), "--crop", "1,91", "--binning", "2"]) == 0
    assert "detector columns selected" not in capsys.readouterr().err


@pytest.fixture(scope="module")
def imported(tmp_path_factory, scan):
    """The scan imported from NXtomo twice: with the true axis offset and with offset 0."""
    tmp = tmp_path_factory.mktemp("imported")
    src, _ = _write(tmp, scan, "nxtomo")
    stores = {}
    for offset in (OFFSET, 0.0):
        out = tmp / f"data{offset}"
        assert run(["import", str(src), "--out", str(out), "--center-offset", str(offset), "--size", "63"]) == 0
        reconstruct_dataset(out, "fbp", workers=0, progress=False)
        stores[offset] = out
    return stores


@pytest.mark.slow
def test_fbp_with_the_offset_is_sharper(imported, scan):
    def mean_psnr(path):
        images = DataStore.open(path).read_reconstruction("fbp")
        return np.mean([psnr(i, p / 8.0) for i, p in zip(images, scan["phantoms"])])

    assert mean_psnr(imported[OFFSET]) > mean_psnr(imported[0.0]) + 2.0


@pytest.mark.parametrize("suffix", [".tif", ".npy", ".h5"])
def test_export_round_trip(imported, tmp_path, suffix):
    out = tmp_path / f"fbp{suffix}"
    assert run(["export", str(imported[OFFSET]), "--name", "fbp", "--out", str(out)]) == 0
    if suffix == ".tif":
        back = tifffile.imread(out)
    elif suffix == ".npy":
        back = np.load(out)
    else:
        with h5py.File(out) as f:
            back = f["data"][()]
    np.testing.assert_array_equal(back, DataStore.open(imported[OFFSET]).read_reconstruction("fbp"))


def test_evaluate_and_export_explain_what_a_scan_lacks(imported, tmp_path, capsys):
    assert run(["evaluate", str(imported[OFFSET])]) == 2
    assert "ground truth" in capsys.readouterr().err
    assert run(["export", str(imported[OFFSET]), "--name", "fbp", "--out", str(tmp_path / "s.txt")]) == 2
    assert "no estimated shifts" in capsys.readouterr().err
    assert run(["export", str(imported[OFFSET]), "--name", "fbp", "--std", "--out", str(tmp_path / "s.npy")]) == 2
    assert "no std" in capsys.readouterr().err
    assert not (tmp_path / "s.txt").exists() and not (tmp_path / "s.npy").exists()


def _bad(tmp_path, scan, case):
    src, extra = _write(tmp_path, scan, "npy")
    if case == "missing-key":
        with h5py.File(tmp_path / "x.h5", "w") as f:
            f["exchange/data"] = scan["proj"]
        return [str(tmp_path / "x.h5")], "theta"
    if case == "angle-count":
        np.savetxt(tmp_path / "angles.txt", scan["deg"][:-1])
        return [str(src), *extra], "angle"
    if case == "flats-shape":
        np.save(tmp_path / "f.npy", scan["flats"][:, :, :-2])
        return [str(src), *extra], "flats have shape"
    if case == "nonpositive":
        np.save(tmp_path / "scan.npy", np.zeros_like(scan["proj"]))
        return [str(src), *extra], "<= 0"
    if case == "nan":
        bad = scan["proj"].copy()
        bad[3, 1, 4] = np.nan
        np.save(tmp_path / "scan.npy", bad)
        return [str(src), *extra], "NaN"
    if case == "unknown-format":
        return [str(src), "--format", "edf", *extra], "unknown"
    if case == "bad-crop":
        return [str(src), "--crop", "50,20", *extra], "--crop"
    if case == "axis-outside":  # binned by 2: the axis 25 binned pixels from the centre of 45 columns
        return [str(src), "--binning", "2", "--center-offset", "50", *extra], "--center-offset 50: the rotation axis"
    if case == "size-absurd":
        return [str(src), "--size", "100000", *extra], "--size 100000 is more than 4 times"
    if case == "binning-wider":
        return [str(src), "--crop", "0,40", "--binning", "41", *extra], "--binning 41 must be between 1 and the 40"
    raise AssertionError(case)


@pytest.mark.parametrize(
    "case",
    [
        "missing-key",
        "angle-count",
        "flats-shape",
        "nonpositive",
        "nan",
        "unknown-format",
        "bad-crop",
        "axis-outside",
        "size-absurd",
        "binning-wider",
    ],
)
def test_bad_input_gives_one_error_line_and_writes_nothing(tmp_path, scan, case, capsys):
    args, message = _bad(tmp_path, scan, case)
    out = tmp_path / "data"
    assert run(["import", *args, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("error:") == 1 and message in err and "Traceback" not in err
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".data")]


@pytest.mark.slow
def test_dremel_on_the_imported_stack_recovers_the_shared_shifts_and_exports_them(imported, scan, tmp_path):
    """Import -> Dremel estimates one shift per view for the stack (correlation with the truth >= 0.8)."""
    from nanoct.io.scanio import read_shifts

    store_path = imported[OFFSET]
    reconstruct_dataset(store_path, "dremel", workers=0, progress=False)
    out = tmp_path / "shifts.txt"
    assert run(["export", str(store_path), "--name", "dremel", "--out", str(out)]) == 0
    g = DataStore.open(store_path).geometry
    shifts = read_shifts(out, g.n_angles)
    phi = g.angles
    true = scan["motion"][:, 0] * np.cos(phi) + scan["motion"][:, 1] * np.sin(phi)  # t . e_u
    basis = np.c_[np.cos(phi), np.sin(phi)]  # a translation the image absorbs: compare without it

    def detrend(v):
        return v - basis @ np.linalg.lstsq(basis, v, rcond=None)[0]

    assert np.corrcoef(detrend(shifts), detrend(true))[0, 1] >= 0.8
    # the exported file is read back as the fixed motion of another reconstruction
    assert run(["reconstruct", str(store_path), "--method", "dremel", "--name", "fixed", "-w", "0", "-q",
                "--param", f"shifts_from={out}", "--param", "fix_shifts=true"]) == 0  # fmt: skip
    np.testing.assert_allclose(DataStore.open(store_path).read_shifts("fixed", [1])[0], shifts, atol=1e-5)


@pytest.mark.slow
def test_predict_on_an_imported_scan_of_the_training_geometry(tmp_path, imported):
    """A network trained on simulated tiny-parallel data post-processes a scan with the same views and detector."""
    from nanoct.learn.train import TrainConfig, train
    from nanoct.sim.generate import generate_dataset

    sim = tmp_path / "sim"
    generate_dataset(sim, get_preset("tiny-parallel"), 8, seed=3, workers=0, progress=False,
                     split_fractions=(0.5, 0.25, 0.25))  # fmt: skip
    reconstruct_dataset(sim, "fbp", workers=0, progress=False)
    config = TrainConfig("unet", "fbp", epochs=1, batch_size=2, model_kwargs={"channels": [4, 4, 8, 8, 16]})
    run_dir = train(sim, tmp_path / "run", config, progress=False)
    g = get_preset("tiny-parallel")
    np.save(tmp_path / "sino.npy", DataStore.open(sim).read_sample(0).sinogram)  # a "measured" slice
    np.savetxt(tmp_path / "angles.txt", np.rad2deg(g.angles))
    scan = tmp_path / "scan"
    assert run(["import", str(tmp_path / "sino.npy"), "--angles", str(tmp_path / "angles.txt"), "--line-integrals",
                "--size", str(g.n), "--out", str(scan)]) == 0  # fmt: skip
    assert DataStore.open(scan).geometry == g  # uniform views read from a file are the preset's geometry
    reconstruct_dataset(scan, "fbp", workers=0, progress=False)
    assert run(["predict", str(scan), "--run", str(run_dir), "-q"]) == 0
    out = DataStore.open(scan).read_reconstruction("fbp+unet")
    assert out.shape == (1, g.n, g.n) and np.isfinite(out).all()
    # the scan with uneven angles and an axis offset is another geometry: refused with one clear line
    assert run(["predict", str(imported[OFFSET]), "--run", str(run_dir), "-q"]) == 2


def _fbp_of_imported(tmp_path, name, sino, deg, *extra):
    np.save(tmp_path / f"{name}.npy", sino)
    np.savetxt(tmp_path / f"{name}.txt", deg)
    out = tmp_path / name
    assert run(["import", str(tmp_path / f"{name}.npy"), "--angles", str(tmp_path / f"{name}.txt"), "--line-integrals",
                "--out", str(out), *extra]) == 0  # fmt: skip
    reconstruct_dataset(out, "fbp", workers=0, progress=False)
    return DataStore.open(out).read_reconstruction("fbp")[0]


def test_views_in_any_order_and_repeated_views_give_the_same_image(tmp_path, capsys):
    """Views whose angles are not monotone stay in acquisition order, a view repeating an angle is left out
    (the first is kept); the image does not change."""
    g = get_preset("tiny-parallel")
    sino = RayTransform(g).forward(random_phantom(np.random.default_rng(3), g.n))
    deg = np.rad2deg(g.angles)
    reference = _fbp_of_imported(tmp_path, "sorted", sino, deg)
    order = np.random.default_rng(4).permutation(g.n_angles)
    shuffled = _fbp_of_imported(tmp_path, "shuffled", sino[order], deg[order])
    assert "not monotone" in capsys.readouterr().err
    np.testing.assert_allclose(shuffled, reference, atol=1e-4 * np.abs(reference).max())
    # views 10 and 50 measured again at the end (with other data): the repeats are left out
    repeated = _fbp_of_imported(tmp_path, "repeated", np.r_[sino, sino[[10, 50]] + 5.0], np.r_[deg, deg[[10, 50]]])
    assert "left out 2 view(s) repeating the angle of an earlier view (modulo 360 degrees): 140, 141" in (
        capsys.readouterr().err
    )
    np.testing.assert_array_equal(repeated, reference)
    full_turn = _fbp_of_imported(tmp_path, "turn", np.r_[sino, sino[:1]], np.r_[deg, 360.0])  # 0 and 360 degrees
    assert "left out 1 view(s)" in capsys.readouterr().err
    np.testing.assert_array_equal(full_turn, reference)
    np.testing.assert_allclose(DataStore.open(tmp_path / "shuffled").geometry.angles, g.angles[order], rtol=1e-12)


def test_drop_bad_views_leaves_out_nan_projections_and_says_so(tmp_path, scan, capsys):
    src, extra = _write(tmp_path, scan, "npy")
    bad = scan["proj"].copy()
    bad[5, 0, :] = np.nan
    np.save(src, bad)
    assert run(["import", str(src), "--out", str(tmp_path / "refused"), *extra]) == 2
    err = capsys.readouterr().err
    assert "projections 5 (angles" in err and "--drop-bad-views" in err
    out = tmp_path / "data"
    assert run(["import", str(src), "--out", str(out), "--drop-bad-views", *extra]) == 0
    assert "note: left out 1 of" in capsys.readouterr().err
    store = DataStore.open(out)
    np.testing.assert_allclose(store.geometry.angles, np.deg2rad(np.delete(scan["deg"], 5)), rtol=1e-10)
    np.testing.assert_allclose(store.read_sample(1).sinogram, np.delete(scan["sino"][1], 5, axis=0), atol=2e-4)
    # the row selection decides: NaN outside the imported rows is no reason to refuse or drop
    assert run(["import", str(src), "--out", str(tmp_path / "rows"), "--rows", "1:3", *extra]) == 0
