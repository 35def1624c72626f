"""One motion for a whole stack: joint Dremel estimate, shifts files as start or fixed motion, export."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.core.geometry import get_preset, remove_translation
from nanoct.core.operators import RayTransform
from nanoct.io.scanio import read_shifts, write_shifts
from nanoct.io.store import DataStore, create_scan
from nanoct.recon.batch import reconstruct_dataset
from nanoct.recon.dremel import dremel
from nanoct.recon.shared import write_store_shifts
from nanoct.sim.motion import MotionParams, sample_motion
from nanoct.sim.phantoms import random_phantom


def _stack(seed: int = 21, slices: int = 3):
    """``slices`` phantoms projected with ONE motion (translation only): (geometry, sinograms, true t . e_u)."""
    g = get_preset("tiny-parallel")
    rng = np.random.default_rng(seed)
    motion = sample_motion(rng, g.n_angles, MotionParams.for_kind(g.kind))
    motion[:, 2] = 0.0
    op = RayTransform(g, motion, oversample=2)
    sinos = np.stack([op.forward(random_phantom(rng, g.n, oversample=2)) for _ in range(slices)])
    true = motion[:, 0] * np.cos(g.angles) + motion[:, 1] * np.sin(g.angles)
    return g, sinos, true


@pytest.fixture(scope="module")
def stack():
    return _stack()


def _scan(path, stack, shared=True):
    g, sinos, _ = stack
    return create_scan(path, g, sinos, scan={"shared_motion": shared, "source": "test"})


def test_remove_translation():
    phi = np.linspace(0, np.pi, 40, endpoint=False)
    rest = np.sin(3 * phi)
    out = remove_translation(rest + 1.5 * np.cos(phi) - 0.7 * np.sin(phi), phi)
    np.testing.assert_allclose(out, remove_translation(rest, phi), atol=1e-12)
    basis = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    np.testing.assert_allclose(basis.T @ out, 0, atol=1e-10)  # orthogonal to the translation term


def test_shared_motion_recovered_on_imported_stack(tmp_path, stack):
    g, _, true = stack
    store = _scan(tmp_path / "scan", stack)
    name = reconstruct_dataset(store.path, "dremel", workers=0, progress=False)
    assert name == "dremel"
    store = DataStore.open(store.path)
    assert store.reconstruction_params(name) == {"method": "dremel", "motion_slices": "all"}
    shifts = store.read_shifts(name)
    assert shifts.shape == (3, g.n_angles) and np.isfinite(shifts).all()
    assert np.all(shifts == shifts[0])  # one motion for every slice
    shared = store.recons.shared_shifts(name)
    np.testing.assert_array_equal(shared, shifts[0])
    corr = np.corrcoef(remove_translation(shared, g.angles), remove_translation(true, g.angles))[0, 1]
    assert corr >= 0.8, corr
    # exported as a shifts file and read back as the same motion
    out = write_store_shifts(store.path, name, tmp_path / "shifts.txt")
    np.testing.assert_allclose(read_shifts(out, g.n_angles), shared, atol=1e-5)


def test_joint_motion_refined_per_slice_on_measured_stack(tmp_path, stack):
    """A measured stack (open beam not at zero): every slice starts from the joint motion and refines it."""
    g, sinos, _ = stack
    measured = sinos + np.float32(0.3 * sinos.max())
    store = create_scan(tmp_path / "scan", g, measured, scan={"shared_motion": True, "source": "test"})
    reconstruct_dataset(store.path, "dremel", params={"n_iter": 3}, workers=0, progress=False)
    store = DataStore.open(store.path)
    joint, shifts = store.recons.shared_shifts("dremel"), store.read_shifts("dremel")
    assert not np.array_equal(shifts[1], joint) and not np.array_equal(shifts[0], shifts[1])
    direct = dremel(g, measured[1], n_iter=3, shifts0=joint)
    np.testing.assert_allclose(shifts[1], direct.motion, atol=1e-6)
    np.testing.assert_allclose(store.read_reconstruction("dremel", [1])[0], direct.image, atol=1e-6)
    # exported as the stack's one motion: the joint estimate
    joint_file = write_store_shifts(store.path, "dremel", tmp_path / "joint.txt")
    np.testing.assert_allclose(read_shifts(joint_file, g.n_angles), joint, atol=1e-5)


def test_joint_estimate_not_redone_on_resume(tmp_path, stack, monkeypatch):
    import nanoct.recon.batch as batch

    store = _scan(tmp_path / "scan", stack)
    reconstruct_dataset(store.path, "dremel", params={"n_iter": 3}, workers=0, progress=False)
    store.recons.invalidate("dremel", [1])
    monkeypatch.setattr(batch, "joint_shifts", lambda *a, **k: pytest.fail("estimated again"))
    reconstruct_dataset(store.path, "dremel", params={"n_iter": 3}, workers=0, progress=False)
    assert DataStore.open(store.path).reconstruction_done("dremel").all()


def test_chosen_slices_on_simulated_store(tiny_store):
    """A simulated store (one motion per sample) estimates a shared one only when asked."""
    test = tiny_store.indices("test")
    chosen = f"{test[1]},{test[0]}"
    params = {"n_iter": 3, "motion_slices": chosen}
    name = reconstruct_dataset(
        tiny_store.path, "dremel", split="test", params=params, name="dj", workers=0, progress=False
    )
    store = DataStore.open(tiny_store.path)
    assert store.reconstruction_params(name)["motion_slices"] == f"{min(test[:2])},{max(test[:2])}"
    shifts = store.read_shifts(name, test)
    assert np.all(shifts == store.recons.shared_shifts(name))
    with pytest.raises(NanoctError, match="motion_slices"):
        reconstruct_dataset(
            tiny_store.path, "dremel", params={"motion_slices": "999"}, name="dk", workers=0, progress=False
        )
    assert "dk" not in store.reconstruction_names()


def test_fixed_shifts_from_file_used_as_given(tmp_path, stack):
    g, _, true = stack
    store = _scan(tmp_path / "scan", stack)
    path = write_shifts(tmp_path / "given.txt", true, angles=g.angles)
    params = {"n_iter": 3, "shifts_from": str(path), "fix_shifts": True}
    reconstruct_dataset(store.path, "dremel", params=params, workers=0, progress=False)
    store = DataStore.open(store.path)
    np.testing.assert_allclose(store.read_shifts("dremel"), np.tile(true, (3, 1)), atol=1e-5)
    assert store.reconstruction_params("dremel")["shifts_from"] == str(path.resolve())
    assert "motion_slices" not in store.reconstruction_params("dremel")
    direct = dremel(g, stack[1][0], n_iter=3, shifts0=true, fix_shifts=True)
    np.testing.assert_allclose(store.read_reconstruction("dremel", [0])[0], direct.image, atol=1e-6)


def test_an_axis_and_shifts_fit_another_axis_with_the_difference_added(stack):
    """Reconstructing view k about axis a with shift e_k is reconstructing it about a - e_k: FBP with (a, e)
    equals FBP with (c, e + c - a), up to the interpolation of the shifted views."""
    from nanoct.core.geometry import Geometry
    from nanoct.recon.fbp import fbp

    g, sinos, true = stack
    a, c = 1.3, -0.4
    first = fbp(Geometry.from_angles(g.angles, g.n, g.n_det, center_offset=a), sinos[0], shifts=true).image
    moved = fbp(Geometry.from_angles(g.angles, g.n, g.n_det, center_offset=c), sinos[0], shifts=true + (c - a)).image
    wrong = fbp(Geometry.from_angles(g.angles, g.n, g.n_det, center_offset=c), sinos[0], shifts=true).image
    assert np.abs(moved - first).max() < 0.05 * np.abs(first).max() < np.abs(wrong - first).max()


def test_shifts_recorded_with_another_axis_are_brought_to_the_data_sets(tmp_path, stack):
    from nanoct.io.shiftfile import shifts_axis
    from nanoct.recon.shared import read_store_shifts

    g, _, true = stack
    store = _scan(tmp_path / "scan", stack)  # axis offset 0 (the preset's)
    plain = write_shifts(tmp_path / "plain.txt", true)
    assert shifts_axis(plain) is None
    np.testing.assert_allclose(read_store_shifts(plain, store), true, atol=1e-6)
    other = write_shifts(tmp_path / "other.txt", true, axis=1.5)
    assert shifts_axis(other) == 1.5
    notes: list[str] = []
    np.testing.assert_allclose(read_store_shifts(other, store, notes), true - 1.5, atol=1e-6)
    assert "go with the axis +1.500 raw px; brought to this data set's axis +0.000 raw px" in notes[0]
    reconstruct_dataset(store.path, "dremel", params={"n_iter": 1}, workers=0, progress=False)
    exported = write_store_shifts(store.path, "dremel", tmp_path / "exported.txt")
    assert shifts_axis(exported) == 0.0  # the data set's own axis: read back unchanged
    np.testing.assert_allclose(
        read_store_shifts(exported, store), DataStore.open(store.path).read_shifts("dremel", [0])[0], atol=1e-5
    )


def test_shifts_file_as_start_motion(tiny_store, tmp_path):
    g = tiny_store.geometry
    test = tiny_store.indices("test")[:1]
    path = write_shifts(tmp_path / "start.txt", np.full(g.n_angles, 0.5))
    params = {"n_iter": 1, "shifts_from": str(path), "correction_start": 1}
    reconstruct_dataset(tiny_store.path, "dremel", split="test", params=params, name="ds", workers=0, progress=False)
    store = DataStore.open(tiny_store.path)
    np.testing.assert_allclose(store.read_shifts("ds", test), 0.5)  # started there, not corrected in 1 sweep
    assert store.recons.shared_shifts("ds") is None  # a start motion, each sample then has its own


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"shifts_from": "WRONG"}, r"--param shifts_from.*has 5 views, the data set 140"),
        ({"fix_shifts": True}, "needs the motion to use"),
        ({"shifts_from": "MISSING"}, "--param shifts_from.*cannot read"),
    ],
)
def test_bad_motion_parameters_write_nothing(tmp_path, stack, params, message):
    store = _scan(tmp_path / "scan", stack)
    wrong = write_shifts(tmp_path / "wrong.txt", np.zeros(5))
    values = {k: {"WRONG": str(wrong), "MISSING": str(tmp_path / "none.txt")}.get(v, v) for k, v in params.items()}
    with pytest.raises(NanoctError, match=message):
        reconstruct_dataset(store.path, "dremel", params=values, workers=0, progress=False)
    assert DataStore.open(store.path).reconstruction_names() == []


def test_export_needs_a_sample_for_per_sample_motion(tiny_store, tmp_path):
    test = tiny_store.indices("test")
    reconstruct_dataset(
        tiny_store.path, "dremel", split="test", params={"n_iter": 2}, name="de", workers=0, progress=False
    )
    with pytest.raises(NanoctError, match="choose the sample"):
        write_store_shifts(tiny_store.path, "de", tmp_path / "s.txt")
    out = write_store_shifts(tiny_store.path, "de", tmp_path / "s.txt", sample=int(test[0]))
    expected = DataStore.open(tiny_store.path).read_shifts("de", test[:1])[0]
    np.testing.assert_allclose(read_shifts(out, tiny_store.geometry.n_angles), expected, atol=1e-5)
    with pytest.raises(NanoctError, match="no reconstruction 'nope'"):
        write_store_shifts(tiny_store.path, "nope", tmp_path / "t.txt")


def test_dremel_fix_shifts_keeps_given_shifts(stack):
    g, sinos, true = stack
    fixed = dremel(g, sinos[0], n_iter=3, shifts0=true, fix_shifts=True)
    np.testing.assert_array_equal(fixed.motion, true.astype(np.float32))
    zero = np.zeros(g.n_angles)
    assert np.abs(dremel(g, sinos[0], n_iter=3, shifts0=zero).motion).max() > 0.5  # corrected when free
    assert np.abs(dremel(g, sinos[0], n_iter=3, shifts0=zero, fix_shifts=True).motion).max() == 0


def test_cli_wrong_shifts_file_one_error_nothing_written(tmp_path, stack, monkeypatch, capsys):
    import sys

    from nanoct.cli import main

    store = _scan(tmp_path / "scan", stack)
    wrong = write_shifts(tmp_path / "wrong.txt", np.zeros(5))
    args = ["reconstruct", store.path, "--method", "dremel", "--param", f"shifts_from={wrong}", "--param"]
    monkeypatch.setattr(sys, "argv", ["nanoct", *map(str, args), "fix_shifts=true", "-q"])
    with pytest.raises(SystemExit) as exc:
        main()
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1 and "has 5 views, the data set 140" in err[0]
    assert DataStore.open(store.path).reconstruction_names() == []


def test_a_moved_shifts_file_resumes_and_another_is_refused(tmp_path, stack, monkeypatch):
    """The shifts file's content, not its path, is part of the reconstruction: the same file named by another
    path (moved) resumes with nothing redone; another motion under the moved path is refused."""
    import nanoct.recon.batch as batch_mod

    g, _, true = stack
    store = _scan(tmp_path / "scan", stack)
    (tmp_path / "a").mkdir()
    first = write_shifts(tmp_path / "a" / "given.txt", true, angles=g.angles)
    params = {"n_iter": 1, "fix_shifts": True}
    reconstruct_dataset(store.path, "dremel", params=params | {"shifts_from": str(first)}, workers=0, progress=False)
    recorded = DataStore.open(store.path).reconstruction_params("dremel")
    assert len(recorded["shifts_from_sha256"]) == 64
    moved = tmp_path / "b" / "given.txt"
    moved.parent.mkdir()
    first.rename(moved)
    monkeypatch.setattr(batch_mod, "_reconstruct_into", lambda *a: pytest.fail("redone"))
    reconstruct_dataset(store.path, "dremel", params=params | {"shifts_from": str(moved)}, workers=0, progress=False)
    assert DataStore.open(store.path).reconstruction_params("dremel") == recorded | {
        "shifts_from": str(moved.resolve())
    }
    write_shifts(moved, true + 0.25, angles=g.angles)
    with pytest.raises(NanoctError, match="differs in: shifts_from_sha256"):
        reconstruct_dataset(
            store.path, "dremel", params=params | {"shifts_from": str(moved)}, workers=0, progress=False
        )
