"""`nanoct stack` from the command line: a refused or interrupted run leaves nothing that blocks a rerun,
the summary, and the stack's motion exported as nabu's shifts file (nabu's sign, checked on shifted data)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from nanoct.cli import run
from nanoct.core.errors import NanoctError
from nanoct.io.store import DataStore
from nanoct.sim.analytic import ellipse_sinogram, stack_phantom
from nanoct.workflows import stack as stack_batch

L, K, S = 96, 120, 2


def _horizontal(phi):
    """A motion as nabu's file gives it: the projection of view k displaced by h_k towards higher columns."""
    return 1.5 * np.cos(2 * phi) + np.linspace(-1, 1, phi.size) + np.random.default_rng(4).uniform(-1, 1, phi.size)


@pytest.fixture
def scan(tmp_path):
    """Line integrals (K, S, L) whose views are moved by scipy.ndimage.shift(row, h_k), and their angles."""
    phi = np.arange(K) * np.pi / K
    h = _horizontal(phi)
    clean = np.stack([ellipse_sinogram(e, phi, L, subsamples=2) for e in stack_phantom(L, S, seed=3)])
    moved = np.stack([[ndimage.shift(row, hk, order=3, mode="nearest") for row, hk in zip(s, h)] for s in clean])
    np.save(tmp_path / "scan.npy", moved.transpose(1, 0, 2).astype(np.float32))
    return tmp_path / "scan.npy", phi, h


def _without_translation(values, phi):
    basis = np.stack([np.ones(phi.size), np.cos(phi), np.sin(phi)], axis=1)
    return values - basis @ np.linalg.lstsq(basis, values, rcond=None)[0]


def test_one_command_from_the_raw_file_to_slices_and_the_motion_as_nabu_reads_it(scan, tmp_path, capsys):
    path, phi, h = scan
    store = tmp_path / "store"
    argv = ["stack", str(path), "--store", str(store), "--angles", "0:180", "--line-integrals", "-w", "0", "-q"]
    assert run(argv) == 0
    out = capsys.readouterr().out
    for word in ("axis", "axis by", "motion", f"{S} of {S}", "reconstructions/fbp_stack"):
        assert word in out, out
    shifts = tmp_path / "shifts.txt"
    assert run(["export", str(store), "--name", "fbp_stack", "--out", str(shifts), "-q"]) == 0
    assert capsys.readouterr().out == ""
    table = np.loadtxt(shifts)
    assert table.shape == (K, 2) and not table[:, 1].any()
    stored = DataStore.open(store).recons.shared_shifts("fbp_stack")
    np.testing.assert_allclose(table[:, 0], -stored, atol=2e-6)  # nabu's sign: horizontal = -d
    # the exported motion is the one applied with nabu's convention (up to a constant and a translation)
    found, true = _without_translation(table[:, 0], phi), _without_translation(h, phi)
    assert np.sqrt(np.mean((found - true) ** 2)) < 0.35 * np.std(true), (found - true).std()
    assert np.corrcoef(found, true)[0, 1] > 0.9


def test_a_refused_stack_leaves_nothing_that_blocks_a_corrected_rerun(scan, tmp_path, capsys, monkeypatch):
    path, _, _ = scan
    store = tmp_path / "store"
    assert run(["import", str(path), "--out", str(store), "--angles", "0:180", "--line-integrals", "-q"]) == 0
    real = stack_batch.horizontal_motion

    def refuse_auto(store, params, *args, **kwargs):
        if params["center"] == "auto":
            raise NanoctError("the rotation axis cannot be determined from these views; give --center-offset")
        return real(store, params, *args, **kwargs)

    monkeypatch.setattr(stack_batch, "horizontal_motion", refuse_auto)
    assert run(["stack", str(store), "-w", "0", "-q"]) == 2
    assert "cannot be determined" in capsys.readouterr().err
    assert run(["stack", str(store), "-w", "0", "-q"]) == 2  # the same rerun: refused for the same reason
    capsys.readouterr()
    assert run(["stack", str(store), "--center-offset", "0", "-w", "0", "-q"]) == 0
    assert DataStore.open(store).reconstruction_done("fbp_stack").all()


def test_an_interrupted_stack_is_resumed_or_rerun_with_other_options(scan, tmp_path, capsys, monkeypatch):
    path, _, _ = scan
    store = tmp_path / "store"
    assert run(["import", str(path), "--out", str(store), "--angles", "0:180", "--line-integrals", "-q"]) == 0

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(stack_batch, "_reconstruct_slice", interrupted)
    monkeypatch.setattr(stack_batch, "_gridrec_block", interrupted)  # --method fbp runs gridrec where it can
    assert run(["stack", str(store), "--center-offset", "0", "-w", "0", "-q"]) == 130
    monkeypatch.undo()
    assert run(["stack", str(store), "--center-offset", "0.5", "-w", "0", "-q"]) == 0  # corrected: runs
    data = DataStore.open(store)
    assert data.reconstruction_done("fbp_stack").all() and data.recons.params("fbp_stack")["center"] == 0.5
    # finished slices are work: other options then need --overwrite (or another --name)
    assert run(["stack", str(store), "--center-offset", "0", "-w", "0", "-q"]) == 2
    assert "other parameters" in capsys.readouterr().err


def test_dremel_options_on_a_scan_with_air_are_used_with_refine_or_named_as_unused(scan, tmp_path, capsys):
    """Air around the object: the centroids give the motion, and --dremel-binning alone is named as not used;
    a given --refine runs Dremel and projection matching there (it used to be dropped for the centroids)."""
    path, _, _ = scan
    store = tmp_path / "store"
    argv = ["import", str(path), "--out", str(store), "--angles", "0:180", "--line-integrals", "-q"]
    assert run(argv) == 0
    assert run(["stack", str(store), "--dremel-binning", "4", "-w", "0", "-q"]) == 0
    out = capsys.readouterr().out
    assert "note     --dremel-binning not used: air is seen" in out and "--refine" in out
    info = DataStore.open(store).recons.motion_info("fbp_stack")
    assert info["horizontal_method"] == "centroid"
    # the former spelling --binning still works, named as typed, with a note on its new name
    assert run(["stack", str(store), "--binning", "4", "--name", "old", "-w", "0", "-q"]) == 0
    out = capsys.readouterr().out
    assert "note     --binning not used: air is seen" in out
    assert "note     --binning is the former spelling of --dremel-binning" in out
    assert run(["stack", str(store), "--binning", "4", "--dremel-binning", "2", "--name", "both", "-w", "0"]) == 2
    assert "--binning: the former spelling of --dremel-binning" in capsys.readouterr().err
    argv = ["stack", str(store), "--refine", "2,1", "--dremel-binning", "4", "--name", "refined", "-w", "0", "-q"]
    assert run(argv) == 0
    assert "not used" not in capsys.readouterr().out
    assert DataStore.open(store).recons.motion_info("refined")["horizontal_method"] == "dremel+matching"
