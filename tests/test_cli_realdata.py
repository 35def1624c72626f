"""The measured scans of tests/data/realdata import with one command each, and a NeXus file goes from
raw file to slices with one more."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nanoct.cli import run
from nanoct.io.store import DataStore

REAL = Path(__file__).resolve().parent / "data" / "realdata"
I13 = REAL / "i13-24737-tiff"

COMMANDS = {
    "k11-nexus": ([str(REAL / "k11-18014-nexus" / "k11-18014.nxs")], (22, 3001, 26), "diamond"),
    "i13-tiff": (
        [
            str(I13 / "tiffs"),
            "--flats",
            str(I13 / "flat_00001.tiff"),
            "--darks",
            str(I13 / "dark_00001.tiff"),
            "--angles",
            str(I13 / "angles.txt"),
            "--angles-select",
            "10:101",
        ],
        (135, 91, 160),
        "tiff",
    ),  # fmt: skip
    "neutron-sinogram": (
        [str(REAL / "neutron-360-sinogram" / "sinogram_360_neutron_image.tif"), "--angles", "0:360", "--open-beam"],
        (1, 459, 503),
        "tiff",
    ),
}


@pytest.mark.parametrize("scan", list(COMMANDS))
def test_each_real_scan_imports_with_one_command(scan, tmp_path, capsys):
    argv, (slices, views, cols), fmt = COMMANDS[scan]
    assert run(["import", *argv, "--out", str(tmp_path / "data")]) == 0
    assert f"{slices} slice(s), {views} views x {cols} detector pixels" in capsys.readouterr().out
    store = DataStore.open(tmp_path / "data")
    assert store.meta["scan"]["format"] == fmt and store.n == slices
    sino = store.read_array("sinograms", [0])[0]
    assert sino.shape == (views, cols) and np.isfinite(sino).all()
    assert run(["import", *argv, "--out", str(tmp_path / "again"), "-q"]) == 0
    assert capsys.readouterr().out == ""
    # show draws a measured slice (sinogram and FBP; a scan has no phantom or unperturbed data)
    assert run(["show", str(tmp_path / "data"), "--index", str(slices - 1), "--out", str(tmp_path / "s.png")]) == 0
    assert (tmp_path / "s.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_raw_counts_without_flats_are_refused_unless_normalised_by_their_air(tmp_path, capsys):
    neutron = REAL / "neutron-360-sinogram" / "sinogram_360_neutron_image.tif"
    argv = ["import", str(neutron), "--angles", "0:360", "--out", str(tmp_path / "d")]
    assert run(argv) == 2 and not (tmp_path / "d").exists()
    err = capsys.readouterr().err
    assert "raw counts, whose -log is no line integral" in err and "--open-beam" in err
    assert run(["stack", str(neutron), "--angles", "0:360", "--out", str(tmp_path / "s.zarr"), "-w", "0"]) == 2
    assert "raw counts" in capsys.readouterr().err and not (tmp_path / "s.zarr").exists()
    assert run([*argv, "--open-beam", "-q"]) == 0  # air near 0, the object positive
    sino = DataStore.open(tmp_path / "d").read_array("sinograms", [0])[0]
    assert abs(np.median(sino[:, 2:27])) < 0.02 and sino.max() > 0.5


def test_the_i13_angles_file_lists_more_values_than_projections(tmp_path, capsys):
    argv = [str(I13 / "tiffs"), "--angles", str(I13 / "angles.txt"), "--out", str(tmp_path / "d")]
    assert run(["import", *argv]) == 2
    assert "111 angle(s) for 91 projection(s)" in capsys.readouterr().err


@pytest.mark.slow
def test_the_diamond_nexus_file_from_raw_file_to_slices(tmp_path, capsys):
    nxs = REAL / "k11-18014-nexus" / "k11-18014.nxs"
    argv = ["stack", str(nxs), "--store", str(tmp_path / "k11"), "--rows", "8:11", "-w", "0", "-q"]
    assert run(argv) == 0
    out = capsys.readouterr().out
    assert "axis" in out and "3 of 3" in out and "motion" in out and "shifts   by" in out
    assert run(["export", str(tmp_path / "k11"), "--name", "fbp_stack", "--out", str(tmp_path / "s.tif")]) == 0
    assert run(["export", str(tmp_path / "k11"), "--name", "fbp_stack", "--out", str(tmp_path / "m.txt")]) == 0
    assert np.loadtxt(tmp_path / "m.txt").shape == (3001, 2)


@pytest.mark.slow
def test_dremel_keeps_its_start_where_the_shift_estimate_runs_away(tmp_path, capsys):
    """The noise-dominated 26-column K11 crop: every slice's estimate ran to about 43 px; each is
    rejected (a quarter of the detector, 6.5 px), the joint motion stays at zero, and the CLI warns."""
    nxs = REAL / "k11-18014-nexus" / "k11-18014.nxs"
    assert run(["import", str(nxs), "--rows", "8:11", "--out", str(tmp_path / "k"), "-q"]) == 0
    assert run(["reconstruct", str(tmp_path / "k"), "--method", "dremel", "-w", "0", "-q"]) == 0
    err = capsys.readouterr().err
    assert "3 of 3 slices of the joint motion: Dremel's shift estimate rejected" in err and "(6.5 px)" in err
    assert "warning: 3 sample(s) of dremel (0-2) kept their start shifts; sample " in err  # each slice's refinement
    store = DataStore.open(tmp_path / "k")
    np.testing.assert_array_equal(store.read_shifts("dremel", range(store.n)), 0.0)
    assert np.isfinite(store.read_reconstruction("dremel")).all()


@pytest.mark.slow
def test_a_rejected_slice_stays_pending_until_it_is_noted(tmp_path, capsys, monkeypatch):
    """A run stopped after a slice was written but before its rejection was noted redoes that slice: the note
    counts every rejected slice once, over the stopped run and the resumed one."""
    import nanoct.recon.batch as batch

    nxs = REAL / "k11-18014-nexus" / "k11-18014.nxs"
    assert run(["import", str(nxs), "--rows", "8:11", "--out", str(tmp_path / "k"), "-q"]) == 0
    noted = batch.shift_check_recorder

    def stop_at_the_second(store, name):
        record = noted(store, name)

        def stop(outcome):
            if outcome[0] == 1:
                raise KeyboardInterrupt
            record(outcome)

        return stop

    monkeypatch.setattr(batch, "shift_check_recorder", stop_at_the_second)
    argv = ["reconstruct", str(tmp_path / "k"), "--method", "dremel", "-w", "0", "-q"]
    assert run(argv) == 130  # interrupted
    store = DataStore.open(tmp_path / "k")
    assert store.reconstruction_done("dremel").tolist() == [True, False, False]
    assert list(store.reconstruction_note("dremel", "sample_shift_check")) == ["0"]
    monkeypatch.setattr(batch, "shift_check_recorder", noted)
    capsys.readouterr()
    assert run(argv) == 0
    assert "warning: 3 sample(s) of dremel (0-2) kept their start shifts" in capsys.readouterr().err
    assert sorted(DataStore.open(tmp_path / "k").reconstruction_note("dremel", "sample_shift_check")) == ["0", "1", "2"]


@pytest.mark.slow
def test_the_axis_warning_of_a_binned_import_says_its_pixels(tmp_path, capsys):
    """The estimators run on the unbinned columns read; the headline offset is in binned pixels (the mirror
    match's -6.08 unbinned: the held-out views reject find_center_vo's -5.25)."""
    neutron = REAL / "neutron-360-sinogram" / "sinogram_360_neutron_image.tif"
    argv = ["import", str(neutron), "--angles", "0:360", "--open-beam", "--center-offset", "auto"]
    assert run([*argv, "--binning", "2", "--out", str(tmp_path / "b")]) == 0
    out, err = capsys.readouterr()
    assert "251 detector pixels" in out and "axis offset -2.79 px" in out
    assert "(mirror -6.08, vo -5.25); motion or a wrong axis; values in unbinned detector pixels" in err
    assert run([*argv, "--out", str(tmp_path / "u")]) == 0
    assert "(mirror -6.08, vo -5.25); motion or a wrong axis\n" in capsys.readouterr().err
