"""Lock files: a second writer is refused while the first lives; stale locks are broken.

The concurrency tests run real ``nanoct`` processes: one holding a lock while another is
refused, and two identical commands started together on one store or run, which must both end
correctly or one must be refused, and leave the same result as a single run.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from nanoct.core.errors import BusyError
from nanoct.io.lock import exclusive, lock_path
from nanoct.io.store import DataStore
from nanoct.recon.batch import reconstruct_dataset

SRC = str(Path(__file__).resolve().parents[2] / "src")
SMALL = '{"channels": [4, 4, 8, 8, 16]}'


def _env() -> dict[str, str]:
    return os.environ | {"PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}


def _record(**change) -> str:
    record = {"pid": os.getpid(), "started": 0.0, "host": socket.gethostname(), "since": "", "command": "x"}
    return json.dumps(record | change)


def test_lock_is_released_and_leaves_nothing(tmp_path, monkeypatch):
    target = tmp_path / "run" / "deeper"
    with exclusive(target, "train", "the run") as lock:
        assert lock == lock_path(target, "train") and lock.is_file()
        assert json.loads(lock.read_text())["pid"] == os.getpid()
        with pytest.raises(BusyError, match=f"pid {os.getpid()} on {socket.gethostname()}"):
            with exclusive(target, "train", "the run"):
                pass
        with exclusive(target, "other", "another name"):  # other names are independent
            pass
    assert list(tmp_path.iterdir()) == []  # the lock and the directories it made are gone
    with monkeypatch.context() as m:  # a block of this process whose clean-up failed (a simulated kill)
        m.setattr(Path, "unlink", lambda self, missing_ok=False: None)
        with exclusive(tmp_path, "fbp", "fbp"):
            pass
    assert lock_path(tmp_path, "fbp").exists()
    with exclusive(tmp_path, "fbp", "fbp"):  # its lock is stale
        pass
    assert not lock_path(tmp_path, "fbp").exists()
    with exclusive(tmp_path, "train", "the run"):
        (tmp_path / "result").write_text("x")
    assert [p.name for p in tmp_path.iterdir()] == ["result"]


def test_stale_locks_are_broken(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    lock = lock_path(tmp_path, "fbp")
    for stale in (_record(pid=dead.pid), _record()):  # a dead process; a live pid started at another time
        lock.write_text(stale)
        with exclusive(tmp_path, "fbp", "fbp"):
            assert json.loads(lock.read_text())["started"] > 0
        assert not lock.exists()
    for garbled in ("", "{}", "[1]"):  # a writer killed between creating and filling its lock
        lock.write_text(garbled)
        with pytest.raises(BusyError, match="writing the lock file now"):
            with exclusive(tmp_path, "fbp", "fbp"):
                pass
        os.utime(lock, (time.time() - 60, time.time() - 60))
        with exclusive(tmp_path, "fbp", "fbp"):
            pass
        assert not lock.exists()


class _Clock:
    """The lock module's ``time`` on a clock of its own: ``sleep`` advances it without waiting."""

    def __init__(self):
        self.now, self.slept = 1000.0, 0.0

    def monotonic(self):
        return self.now

    def sleep(self, seconds):
        self.now += seconds
        self.slept += seconds

    def __getattr__(self, name):
        return getattr(time, name)


def test_a_waiting_writer_gets_the_lock_once_it_is_released(tmp_path, monkeypatch):
    """``wait``: a block of milliseconds (a small file's update) waits for the holder instead of failing; past
    the wait, or with none, it is refused as before."""
    import threading

    import nanoct.io.lock as lock_module

    held, release = threading.Event(), threading.Event()

    def holder():
        with exclusive(tmp_path, "calibration.json", "the file"):
            held.set()
            release.wait(10)

    thread = threading.Thread(target=holder)
    thread.start()
    held.wait(10)
    try:
        for wait in (0.0, 0.2):  # refused once the wait is spent, on the lock's clock (none spent for no wait)
            clock = _Clock()
            monkeypatch.setattr(lock_module, "time", clock)
            with pytest.raises(BusyError, match="the file is being written"):
                with exclusive(tmp_path, "calibration.json", "the file", wait=wait):
                    pass
            assert clock.slept >= wait and (clock.slept == 0) == (wait == 0)
        monkeypatch.undo()
        threading.Timer(0.3, release.set).start()
        with exclusive(tmp_path, "calibration.json", "the file", wait=10.0) as lock:
            assert release.is_set() and json.loads(lock.read_text())["pid"] == os.getpid()
    finally:
        release.set()
        thread.join()
    assert list(tmp_path.iterdir()) == []


def test_lock_of_another_host_is_kept(tmp_path):
    lock = lock_path(tmp_path, "fbp")
    lock.write_text(_record(host="elsewhere", pid=1))
    with pytest.raises(BusyError, match=f"pid 1 on elsewhere.*delete {lock}"):
        with exclusive(tmp_path, "fbp", "reconstructions/fbp"):
            pass
    assert json.loads(lock.read_text())["host"] == "elsewhere"


def _cli(*args, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "nanoct", *map(str, args)], capture_output=True, text=True, env=_env(), **kw
    )


def _check_refused(proc: subprocess.CompletedProcess) -> None:
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert lines[0].startswith("error:") and "being written by another nanoct process" in lines[0], proc.stderr


def test_second_writer_is_refused_until_the_first_dies(tiny_store, tmp_path):
    store = tmp_path / "store"
    shutil.copytree(tiny_store.path, store)
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\nfrom nanoct.io.lock import exclusive\n"
         f"with exclusive({str(store)!r}, 'fbp', 'fbp'):\n    print('held', flush=True)\n    time.sleep(120)"],
        stdout=subprocess.PIPE, text=True, env=_env(),
    )  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "held"
        refused = _cli("reconstruct", store, "-m", "fbp", "-w", 0, "-q")
        _check_refused(refused)
        assert f"pid {holder.pid}" in refused.stderr
        assert "fbp" not in DataStore.open(store).reconstruction_names()  # nothing written
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert lock_path(store, "fbp").exists()  # a killed owner leaves its lock behind ...
    done = _cli("reconstruct", store, "-m", "fbp", "-w", 0, "-q")  # ... which the next run breaks
    assert done.returncode == 0, done.stderr
    assert DataStore.open(store).reconstruction_done("fbp").all() and not lock_path(store, "fbp").exists()


def _race(args: list, n: int = 2) -> list[subprocess.CompletedProcess]:
    """Start ``n`` identical commands at once; return them finished."""
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "nanoct", *map(str, args)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=_env(),
        )
        for _ in range(n)
    ]
    results = []
    for p in procs:
        out, err = p.communicate(timeout=600)
        results.append(subprocess.CompletedProcess(p.args, p.returncode, out, err))
    return results


def _check_race(results: list[subprocess.CompletedProcess]) -> None:
    assert any(r.returncode == 0 for r in results), [r.stderr for r in results]
    for r in results:
        if r.returncode:
            _check_refused(r)


@pytest.mark.slow
def test_concurrent_reconstructions(tiny_store, tmp_path):
    reference = tmp_path / "reference"
    shutil.copytree(tiny_store.path, reference)
    # a name of its own: the session's tiny_store may already hold a "dremel" of other parameters
    reconstruct_dataset(reference, "dremel", workers=0, progress=False, params={"n_iter": 4}, name="dremel_race")
    store = tmp_path / "store"
    shutil.copytree(tiny_store.path, store)
    args = ["reconstruct", store, "-m", "dremel", "--param", "n_iter=4", "--name", "dremel_race", "-w", 0, "-q"]
    _check_race(_race(args))
    s, ref = DataStore.open(store), DataStore.open(reference)
    np.testing.assert_array_equal(s.read_reconstruction("dremel_race"), ref.read_reconstruction("dremel_race"))
    assert not lock_path(store, "dremel_race").exists()


@pytest.mark.slow
def test_concurrent_training_and_prediction(tiny_store, tmp_path):
    store = tmp_path / "store"
    shutil.copytree(tiny_store.path, store)
    reconstruct_dataset(store, "fbp", workers=0, progress=False)
    reference = tmp_path / "reference-run"
    run = tmp_path / "run"
    args = ["train", store, "-i", "fbp", "--epochs", 2, "--batch-size", 2, "--seed", 1]
    args += ["--param", f"channels={json.loads(SMALL)['channels']}", "--device", "cpu", "-q"]
    # the reference: the same command run alone in a process of its own (the tests' own process trains with one
    # torch thread, tests/conftest.py, which changes the last digits of the losses)
    (alone,) = _race([*args, "--out", reference], n=1)
    assert alone.returncode == 0, alone.stderr
    _check_race(_race([*args, "--out", run]))
    np.testing.assert_array_equal(
        *(np.loadtxt(d / "log.csv", delimiter=",", skiprows=1, usecols=(0, 1, 2)) for d in (run, reference))
    )
    _check_race(_race(["predict", store, "--run", run, "--device", "cpu", "--split", "all", "-q"]))
    predicted = DataStore.open(store).read_reconstruction("fbp+unet")
    assert np.isfinite(predicted).all() and not lock_path(store, "fbp+unet").exists()
    assert not lock_path(run, "train").exists()
