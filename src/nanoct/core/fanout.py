"""Fan-out of per-sample work over Dask distributed, with a progress bar.

Every task writes its own result into the store (one chunk per sample, completion flag last),
so the driver only counts finished tasks; an interrupted run is resumed by running the same
command again, which submits only the samples that are not flagged done.
"""

from __future__ import annotations

import logging
import os
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

from tqdm.auto import tqdm

__all__ = ["dask_client", "run_tasks", "usable_cpus", "worker_threads"]


@contextmanager
def dask_client(workers: int = 2, scheduler: str | None = None) -> Iterator[object]:
    """A Dask client: connected to ``scheduler`` if given, else on a local process cluster.

    Dask writes its worker settings (``OMP_NUM_THREADS=1``, ``MALLOC_TRIM_THRESHOLD_``, ...)
    into this process's environment; they are undone on exit, so work that runs here later
    (in-process training, say) is not pinned to one thread.

    Parameters
    ----------
    workers : int
        Worker processes of the local cluster (one task at a time each; the compiled kernels
        of each get :func:`worker_threads` threads).
    scheduler : str, optional
        Address of a running scheduler, e.g. ``tcp://10.0.0.1:8786``.
    """
    env = dict(os.environ)
    try:
        with _client(workers, scheduler) as client:
            yield client
    finally:
        os.environ.clear()
        os.environ.update(env)


def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity where the platform has one), at least 1."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def worker_threads(workers: int) -> int:
    """Compiled-kernel threads of each local worker process: the usable CPUs shared out, at least 1.

    The matrix-free kernels split a large view over threads (:func:`nanoct.core.matrixfree.use_threads`);
    with every worker process on all CPUs they would wait for each other's cores at every view.

    Parameters
    ----------
    workers : int
        Worker processes of the local cluster.

    Returns
    -------
    int
        ``max(1, usable CPUs // workers)``.
    """
    return max(1, usable_cpus() // max(workers, 1))


@contextmanager
def _client(workers: int, scheduler: str | None) -> Iterator[object]:
    from dask.distributed import Client, LocalCluster

    if scheduler:
        client = Client(scheduler)
        try:
            yield client
        finally:
            client.close()
        return
    with _sigint_ignored():  # inherited by the worker processes: Ctrl-C stops only this one, which cleans up
        cluster = LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            scheduler_kwargs={"dashboard_address": ":0"},  # its HTTP server on a free port: runs side by side
            silence_logs=logging.CRITICAL,
            env={"NUMBA_NUM_THREADS": str(worker_threads(workers))},
        )
    client = Client(cluster)
    try:
        yield client
    finally:
        client.close()
        cluster.close()


@contextmanager
def _sigint_ignored() -> Iterator[None]:
    """Ignore SIGINT while worker processes are started (they inherit it), in the main thread only."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def run_tasks(
    task: Callable[[int], object],
    indices: Sequence[int],
    *,
    workers: int = 2,
    scheduler: str | None = None,
    desc: str = "samples",
    progress: bool = True,
    unit: str = "sample",
    on_result: Callable[[Any], None] | None = None,
    done: int = 0,
) -> int:
    """Run ``task(i)`` for every index, on Dask or (``workers == 0``) in this process.

    Parameters
    ----------
    task : callable
        Picklable function of one sample index that writes its own result.
    indices : sequence of int
        Samples to process.
    workers : int
        Local worker processes; 0 runs serially in the calling process (no Dask).
    scheduler : str, optional
        Address of an existing Dask scheduler (overrides ``workers``).
    desc : str
        Progress-bar label.
    progress : bool
        Show a progress bar.
    unit : str
        What one task is, for the progress bar.
    on_result : callable, optional
        Called in this process with each task's return value, as the tasks finish.
    done : int
        Tasks of the same job finished before (a resumed run): the bar counts from there, out of
        ``done + len(indices)``.

    Returns
    -------
    int
        Number of tasks run.

    Raises
    ------
    Exception
        The first exception raised by a task; tasks not yet started are cancelled, and what
        finished stays written.
    """
    indices = [int(i) for i in indices]
    if workers < 0:
        raise ValueError(f"--workers {workers} must be >= 0")
    if not indices:
        return 0
    bar = tqdm(total=done + len(indices), initial=done, desc=desc, unit=unit, disable=not progress)
    try:
        if workers == 0 and not scheduler:
            for i in indices:
                result = task(i)
                if on_result is not None:
                    on_result(result)
                bar.update()
            return len(indices)
        from dask.distributed import as_completed

        with dask_client(workers, scheduler) as client:
            futures = client.map(task, indices, pure=False)
            try:
                for future in as_completed(futures):
                    result = future.result()
                    if on_result is not None:
                        on_result(result)
                    bar.update()
            except BaseException:
                client.cancel(futures)
                raise
        return len(indices)
    finally:
        bar.close()
