"""Tests for nanoct.core.fanout: the local cluster shares the CPUs out among its workers."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from nanoct.core.fanout import run_tasks, worker_threads


def test_worker_threads_share_the_usable_cpus(monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3, 4}, raising=False)
    assert [worker_threads(w) for w in (1, 2, 3, 5, 8)] == [5, 2, 1, 1, 1]
    assert worker_threads(0) == 5


def _record(i: int, folder: str) -> None:
    import numba

    Path(folder, str(i)).write_text(f"{os.environ.get('NUMBA_NUM_THREADS')} {numba.get_num_threads()}")


@pytest.mark.slow
def test_worker_processes_get_their_share_of_numba_threads(tmp_path):
    from functools import partial

    assert run_tasks(partial(_record, folder=str(tmp_path)), [0, 1], workers=2, progress=False) == 2
    expected = worker_threads(2)
    for i in (0, 1):
        assert (tmp_path / str(i)).read_text() == f"{expected} {expected}"


def test_on_result_gets_every_return_value_in_this_process():
    got: list[int] = []
    assert run_tasks(lambda i: i * i, [3, 1, 2], workers=0, progress=False, on_result=got.append) == 3
    assert got == [9, 1, 4]
    assert run_tasks(lambda i: i, [], workers=0, progress=False, on_result=got.append) == 0 and got == [9, 1, 4]


@pytest.mark.slow
def test_on_result_gets_the_dask_workers_return_values():
    got: list[int] = []
    assert run_tasks(abs, [-3, 1, -2], workers=2, progress=False, on_result=got.append) == 3
    assert sorted(got) == [1, 2, 3]


def test_a_resumed_jobs_bar_counts_the_tasks_done_before(capsys):
    """``done``: the bar of a resumed job starts at the tasks finished by the earlier run, out of all of them."""
    run_tasks(lambda i: i, [5, 6], workers=0, progress=True, desc="generate", done=3)
    err = capsys.readouterr().err
    assert "3/5" in err and "5/5" in err and "0/2" not in err
