"""Data-set generation: determinism across worker counts, kill-and-resume, no-op reruns."""

import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zarr

from nanoct.core.geometry import get_preset
from nanoct.io.store import DataStore
from nanoct.recon.batch import reconstruct_dataset
from nanoct.sim.generate import generate_dataset


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _done_count(path: Path) -> int:
    try:
        return int(np.asarray(zarr.open_group(str(path), mode="r")["done"][:]).sum())
    except Exception:
        return 0


@pytest.mark.slow
def test_same_bytes_for_any_worker_count(tmp_path):
    g = get_preset("tiny-fan")
    serial = generate_dataset(tmp_path / "serial", g, 8, seed=11, workers=0, progress=False)
    dask = generate_dataset(tmp_path / "dask", g, 8, seed=11, workers=2, progress=False)
    a, b = _files(serial.path), _files(dask.path)
    assert a.keys() == b.keys() and len(a) > 8 * 5
    assert all(a[k] == b[k] for k in a)


@pytest.mark.slow
def test_kill_and_resume_gives_the_same_bytes(tmp_path):
    n = 400
    cmd = [
        sys.executable,
        "-m",
        "nanoct",
        "generate",
        "--preset",
        "tiny-parallel",
        "--n",
        str(n),
        "--seed",
        "2",
        "--workers",
        "0",
        "-q",
    ]
    killed = tmp_path / "killed"
    proc = subprocess.Popen([*cmd, "--out", str(killed)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    while _done_count(killed) < 20 and proc.poll() is None:  # no deadline: pytest-timeout bounds a hang
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    partial = _done_count(killed)
    assert 0 < partial < n, f"the run was not interrupted mid-way ({partial} of {n} done); make n larger"
    subprocess.run([*cmd, "--out", str(killed)], check=True, capture_output=True)
    reference = generate_dataset(tmp_path / "ref", get_preset("tiny-parallel"), n, seed=2, workers=0, progress=False)
    a, b = _files(killed), _files(reference.path)
    assert a.keys() == b.keys()
    assert [k for k in a if a[k] != b[k]] == []


def test_second_run_is_a_noop_and_reconstruct_resumes(tmp_path, capsys):
    g = get_preset("tiny-parallel")
    path = tmp_path / "d"
    generate_dataset(path, g, 6, seed=0, workers=0, progress=False)
    stamps = {p: p.stat().st_mtime_ns for p in path.rglob("*") if p.is_file()}
    time.sleep(0.02)
    generate_dataset(path, g, 6, seed=0, workers=0, progress=False)
    assert {p: p.stat().st_mtime_ns for p in path.rglob("*") if p.is_file()} == stamps

    store = DataStore.open(path, mode="r+")
    reconstruct_dataset(path, "fbp", split="test", workers=0, progress=False)
    done = store.reconstruction_done("fbp")
    assert done.sum() == len(store.indices("test")) and done[store.indices("test")].all()
    # a later run over all samples adds only the missing ones and keeps the earlier results
    first = store.read_reconstruction("fbp", store.indices("test"))
    capsys.readouterr()
    reconstruct_dataset(path, "fbp", split="all", workers=0, progress=True)
    assert store.reconstruction_done("fbp").all()
    bar = capsys.readouterr().err  # counts the samples made by the first run, out of all
    assert f"{done.sum()}/6" in bar and "6/6" in bar
    np.testing.assert_array_equal(first, store.read_reconstruction("fbp", store.indices("test")))
    assert store.reconstruction_params("fbp") == {"method": "fbp"}


def test_bad_arguments(tmp_path):
    from nanoct.core.errors import NanoctError

    g = get_preset("tiny-parallel")
    with pytest.raises(NanoctError, match="positive"):
        generate_dataset(tmp_path / "x", g, 0, workers=0)
    with pytest.raises(NanoctError, match="seed"):
        generate_dataset(tmp_path / "x", g, 3, seed=-1, workers=0)
    assert not (tmp_path / "x").exists()
    with pytest.raises(NanoctError, match="unknown"):
        reconstruct_dataset(tmp_path / "x", "sart", workers=0)


def test_a_set_made_again_at_the_same_path_in_one_process_is_the_new_one(tmp_path):
    """The per-process store handle (``open_cached``) is not the deleted store's: the second set holds its own
    seed's samples (bytes equal to that seed's set made elsewhere), not the first one's."""
    import shutil

    preset = get_preset("tiny-parallel")
    path = tmp_path / "again"
    generate_dataset(path, preset, 2, seed=11, workers=0, progress=False)
    first = DataStore.open(path).read_phantoms([0, 1])
    reconstruct_dataset(path, "fbp", workers=0, progress=False)
    shutil.rmtree(path)
    generate_dataset(path, preset, 2, seed=12, workers=0, progress=False)
    generate_dataset(tmp_path / "elsewhere", preset, 2, seed=12, workers=0, progress=False)
    again = DataStore.open(path).read_phantoms([0, 1])
    np.testing.assert_array_equal(again, DataStore.open(tmp_path / "elsewhere").read_phantoms([0, 1]))
    assert not np.array_equal(again, first)
    reconstruct_dataset(path, "fbp", workers=0, progress=False)
    assert DataStore.open(path).read_reconstruction("fbp", [0]).shape == first[:1].shape
