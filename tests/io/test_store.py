import json
import os
import re
import shutil

import numpy as np
import pytest

from nanoct.core.errors import NanoctError, StoreError
from nanoct.core.geometry import get_preset
from nanoct.io.store import DataStore, split_assignment
from nanoct.recon.batch import reconstruct_dataset


def test_paper_split_proportions():
    labels = split_assignment(32095, seed=0)
    assert np.bincount(labels).tolist() == [30490, 1284, 321]
    assert not np.array_equal(labels, split_assignment(32095, seed=1))
    np.testing.assert_array_equal(labels, split_assignment(32095, seed=0))


@pytest.mark.parametrize("n", [1, 2, 3, 10, 99])
def test_small_splits(n):
    counts = np.bincount(split_assignment(n, 0), minlength=3)
    assert counts.sum() == n
    if n >= 3:
        assert counts[1] >= 1 and counts[2] >= 1


def test_split_validation():
    with pytest.raises(ValueError, match="sum"):
        split_assignment(10, 0, (0.5, 0.5, 0.5))
    with pytest.raises(ValueError, match="positive"):
        split_assignment(0, 0)


def test_layout(tiny_store):
    g = tiny_store.geometry
    root = tiny_store.path
    meta = json.loads((root / "zarr.json").read_text())["attributes"]["nanoct"]
    assert meta["geometry"] == g.to_dict() and meta["seed"] == 3 and meta["n"] == 12
    assert "simulation" in meta and "version" in meta
    import zarr

    grp = zarr.open_group(str(root), mode="r")
    expect = {
        "phantoms": ((12, 63, 63), "float32"),
        "sinograms": ((12, *g.sino_shape), "float32"),
        "sinograms_eta": ((12, *g.sino_shape), "float32"),
        "motion": ((12, g.n_angles, 3), "float32"),
        "eta": ((12, g.n_angles), "float32"),
        "split": ((12,), "int8"),
        "done": ((12,), "bool"),
    }
    for name, (shape, dtype) in expect.items():
        assert grp[name].shape == shape and str(grp[name].dtype) == dtype, name
        if name != "split":
            assert grp[name].chunks == (1, *shape[1:]), name  # one chunk per sample
    assert tiny_store.done.all()
    info = tiny_store.info()
    assert info["complete"] and info["splits"] == {"train": 6, "val": 3, "test": 3}


def test_reconstruction_roundtrip_and_params(tiny_store, tmp_path):
    store = DataStore.open(tiny_store.path, mode="r+")
    store.prepare_reconstruction("unit", {"a": 1}, shifts=True)
    assert "unit" in store.reconstruction_names() and "unit_shifts" not in store.reconstruction_names()
    img = np.full(store.geometry.image_shape, 0.5, np.float32)
    store.write_reconstruction("unit", 4, img, np.arange(store.geometry.n_angles, dtype=np.float32))
    assert store.reconstruction_done("unit").sum() == 1
    np.testing.assert_array_equal(store.read_reconstruction("unit", [4])[0], img)
    with pytest.raises(StoreError, match="missing"):
        store.read_reconstruction("unit", [3, 4])
    store.prepare_reconstruction("unit", {"a": 1})  # same params: fine, keeps the work
    assert store.reconstruction_done("unit")[4]
    with pytest.raises(StoreError, match="other parameters"):
        store.prepare_reconstruction("unit", {"a": 2})
    with pytest.raises(StoreError, match="no reconstruction 'nope'"):
        store.read_reconstruction("nope")
    store.delete_reconstruction("unit")
    assert "unit" not in store.reconstruction_names()


def test_listing_while_another_process_writes_metadata_warns_nothing(tiny_store, tmp_path):
    """Zarr writes zarr.json as zarr.<hex>.partial and renames it; a listing from another process in that
    moment saw an unknown object and printed Zarr's warning to a user's terminal (a concurrency test failed
    on the extra stderr line)."""
    import shutil
    import warnings

    path = tmp_path / "copy"
    shutil.copytree(tiny_store.path, path)
    store = DataStore.open(path, mode="r+")
    store.prepare_reconstruction("unit", {"a": 1})
    (path / "reconstructions" / ("zarr." + "0" * 32 + ".partial")).write_text("{}")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert "unit" in DataStore.open(path).reconstruction_names()


def test_create_refuses_a_different_dataset(tiny_store):
    g = get_preset("tiny-parallel")
    meta = tiny_store.meta
    with pytest.raises(StoreError, match="differs in: seed"):
        DataStore.create(tiny_store.path, g, 12, 4, meta["simulation"], tuple(meta["split_fractions"]))
    with pytest.raises(StoreError, match="geometry"):
        DataStore.create(
            tiny_store.path, get_preset("tiny-fan"), 12, 3, meta["simulation"], tuple(meta["split_fractions"])
        )
    same = DataStore.create(tiny_store.path, g, 12, 3, meta["simulation"], tuple(meta["split_fractions"]))
    assert same.done.all()


def test_missing_foreign_and_damaged_stores(tmp_path, tiny_store):
    with pytest.raises(StoreError, match="no nanoct data set"):
        DataStore.open(tmp_path / "nothing")
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(StoreError, match="not a nanoct data set"):
        DataStore.create(foreign, get_preset("tiny-parallel"), 2, 0, {})
    assert sorted(p.name for p in foreign.iterdir()) == ["notes.txt"]  # untouched
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "zarr.json").write_text("{not json")
    with pytest.raises(StoreError, match="damaged"):
        DataStore.open(broken)
    # an array's metadata emptied or overwritten: the file is named with what to do, when the store is opened
    copy = tmp_path / "copy"
    shutil.copytree(tiny_store.path, copy)
    reconstruct_dataset(copy, "fbp", workers=0, progress=False)
    for meta, content, remedy in (
        (copy / "sinograms" / "zarr.json", b"", "delete it and generate it again"),
        (copy / "reconstructions" / "fbp" / "zarr.json", b"\xff\xfe", "run the command that made 'fbp' again"),
    ):
        good = meta.read_bytes()
        meta.write_bytes(content)
        with pytest.raises(StoreError, match=re.escape(f"{meta} is damaged")) as info:
            DataStore.open(copy)
        assert remedy in str(info.value)
        meta.write_bytes(good)
    assert DataStore.open(copy).reconstruction_done("fbp").all()


def test_damaged_chunk_is_reported(tmp_path):
    from nanoct.sim.generate import generate_dataset

    store = generate_dataset(tmp_path / "d", get_preset("tiny-parallel"), 2, workers=0, progress=False)
    chunk = next((store.path / "sinograms" / "c").rglob("*"))
    while chunk.is_dir():
        chunk = next(chunk.iterdir())
    chunk.write_bytes(b"garbage")
    with pytest.raises(StoreError, match="unreadable chunk"):
        for i in range(2):
            store.read_sample(i)


def test_no_leftovers_when_creation_fails(tmp_path, monkeypatch):
    import nanoct.io.store as store_mod

    def boom(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(store_mod, "split_assignment", boom)
    with pytest.raises(RuntimeError):
        DataStore.create(tmp_path / "d", get_preset("tiny-parallel"), 3, 0, {})
    assert list(tmp_path.iterdir()) == []


class _Killed(BaseException):
    """Like SIGKILL for Zarr's atomic write: not an Exception, so its clean-up does not run."""


def _killed_write(monkeypatch, write):
    """Run ``write`` with the rename of Zarr's temporary chunk file failing as a kill would."""
    import pathlib

    def killed_replace(self, target):
        raise _Killed

    with monkeypatch.context() as m:
        m.setattr(pathlib.Path, "replace", killed_replace)
        with pytest.raises(_Killed):
            write()


@pytest.mark.slow
def test_partial_chunk_writes_are_removed_on_resume(tmp_path, monkeypatch):
    from nanoct.sim.generate import generate_dataset

    g = get_preset("tiny-parallel")
    store = generate_dataset(tmp_path / "d", g, 4, seed=0, workers=0, progress=False)
    store.prepare_reconstruction("unit", {"a": 1})
    img = np.ones(g.image_shape, np.float32)
    _killed_write(monkeypatch, lambda: store.write_reconstruction("unit", 2, img))
    _killed_write(monkeypatch, lambda: store._array("phantoms").__setitem__(1, img))
    left = sorted(p.relative_to(store.path).parts[0] for p in store.path.rglob("*.partial"))
    assert left == ["phantoms", "reconstructions"]  # the real Zarr file names
    assert not store.reconstruction_done("unit")[2]

    store.prepare_reconstruction("unit", {"a": 1})  # resuming the reconstruction clears only its own arrays
    assert [p.relative_to(store.path).parts[0] for p in store.path.rglob("*.partial")] == ["phantoms"]
    generate_dataset(tmp_path / "d", g, 4, seed=0, workers=0, progress=False)  # resuming generation clears the rest
    assert not list(store.path.rglob("*.partial"))
    store.write_reconstruction("unit", 2, img)
    np.testing.assert_array_equal(store.read_reconstruction("unit", [2])[0], img)


def test_remove_partial_writes_matches_only_zarr_temporaries(tmp_path):
    store = DataStore.create(tmp_path / "d", get_preset("tiny-parallel"), 2, 0, {}, (0.5, 0.5, 0.0))
    chunk_dir = store.path / "phantoms" / "c" / "0" / "0"
    chunk_dir.mkdir(parents=True)
    stale = chunk_dir / f"0.{'ab' * 16}.partial"
    keep = [chunk_dir / "0", chunk_dir / "notes.partial", chunk_dir / "0.abc.partial"]
    for p in [stale, *keep]:
        p.write_bytes(b"x")
    assert store.remove_partial_writes(["phantoms", "missing"]) == [stale]
    assert all(p.exists() for p in keep) and not stale.exists()


def test_stale_creation_of_a_killed_process_is_removed(tmp_path):
    import subprocess
    import sys

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    stale = tmp_path / f".d.creating-{int(dead.stdout)}-0123abcd"  # the process that made it is gone
    older = tmp_path / ".d.creating-89abcdef"  # the name of an earlier nanoct (no process id)
    alive = tmp_path / f".d.creating-{os.getppid()}-deadbeef"  # a creation still under way
    for p in (stale, older, alive):
        (p / "phantoms").mkdir(parents=True)
    DataStore.create(tmp_path / "d", get_preset("tiny-parallel"), 2, 0, {})
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([alive.name, "d"])


def test_write_into_a_deleted_reconstruction_is_a_store_error(tmp_path):
    store = DataStore.create(tmp_path / "d", get_preset("tiny-parallel"), 2, 0, {})
    store.prepare_reconstruction("x", {"a": 1}, shifts=True)
    DataStore.open(tmp_path / "d", mode="r+").delete_reconstruction("x")  # another run's --overwrite
    with pytest.raises(StoreError, match="deleted while this run was writing"):
        store.write_reconstruction("x", 0, np.zeros(store.geometry.image_shape, np.float32))


@pytest.mark.slow
def test_lost_chunks_read_as_nan_are_refused_and_repaired(tmp_path):
    from nanoct.sim.generate import generate_dataset

    g = get_preset("tiny-parallel")
    store = generate_dataset(tmp_path / "d", g, 3, seed=1, workers=0, progress=False)
    phantom = store.read_phantoms([2])
    store.prepare_reconstruction("x", {"a": 1}, shifts=True)
    for i in range(3):
        store.write_reconstruction("x", i, phantom[0] + i, shifts=np.full(g.n_angles, i, np.float32))
    (store.path / "phantoms" / "c" / "2" / "0" / "0").unlink()
    (store.path / "reconstructions" / "x_shifts" / "c" / "1" / "0").unlink()
    with pytest.raises(StoreError, match=r"phantoms.*sample\(s\) \[2\] have missing data.*nanoct generate"):
        store.read_phantoms([0, 2])
    with pytest.raises(StoreError, match=r"x_shifts.*\[1\].*nanoct reconstruct"):
        store.read_shifts("x", [0, 1])
    np.testing.assert_array_equal(store.read_shifts("x", [2]), np.full((1, g.n_angles), 2, np.float32))
    assert store.verify() == {"samples": [2], "reconstructions/x": [1]}
    store.prepare_reconstruction("x", {"a": 1}, shifts=True)  # resuming marks the damaged sample for redoing
    assert store.reconstruction_done("x").tolist() == [True, False, True]
    generate_dataset(tmp_path / "d", g, 3, seed=1, workers=0, progress=False)
    np.testing.assert_array_equal(store.read_phantoms([2]), phantom)


@pytest.mark.parametrize("name", ["a/b", "..", ".x", "", " ", "a\\b", "x_shifts", "tab\there"])
def test_bad_reconstruction_names(tmp_path, name):
    store = DataStore.create(tmp_path / "d", get_preset("tiny-parallel"), 2, 0, {})
    with pytest.raises(NanoctError, match="--name"):
        store.prepare_reconstruction(name, {})
    with pytest.raises(NanoctError, match="--name"):
        store.delete_reconstruction(name)
    assert "reconstructions" not in [p.name for p in store.path.iterdir()]


def test_read_array_matches_read_sample_and_names_missing_arrays(tiny_store, tmp_path):
    from nanoct.io.store import create_scan

    idx = [1, 4]
    np.testing.assert_array_equal(tiny_store.read_array("eta", idx), [tiny_store.read_sample(i).eta for i in idx])
    scan = create_scan(tmp_path / "scan", tiny_store.geometry, tiny_store.read_array("sinograms", idx), {"file": "x"})
    with pytest.raises(StoreError, match="has no 'eta' array"):
        scan.read_array("eta", [0])
