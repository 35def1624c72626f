"""Generate a whole data set into a store, resumably, over Dask."""

from __future__ import annotations

import os
from collections.abc import Callable
from functools import partial
from pathlib import Path

from ..core.errors import NanoctError
from ..core.fanout import run_tasks
from ..core.geometry import Geometry
from ..io.fileio import disk_space_needed
from ..io.store import DataStore, Sample, open_cached
from .simulate import SimulationConfig, simulate_sample

__all__ = ["Simulator", "check_run", "fill_dataset", "generate_dataset"]


#: How one sample of a data set is made: ``simulate(store, index) -> Sample``.
Simulator = Callable[[DataStore, int], Sample]


def _simulate_into(path: str, index: int, simulate: Simulator | None = None) -> int:
    store = open_cached(path)
    if simulate is None:
        config = SimulationConfig.from_dict(store.meta["simulation"])
        sample = simulate_sample(store.geometry, config, store.seed, index)
    else:
        sample = simulate(store, index)
    store.write_sample(index, sample)
    return index


def fill_dataset(
    store: DataStore,
    *,
    simulate: Simulator | None = None,
    workers: int = 2,
    scheduler: str | None = None,
    progress: bool = True,
) -> None:
    """Simulate the samples of ``store`` not flagged done (over Dask; see :func:`nanoct.core.fanout.run_tasks`).

    Each sample is ``simulate(store, index)``, a module-level function (the workers import it), e.g.
    :func:`nanoct.sim.matched.simulate_matched_sample` for a set matched to a measured scan; by default
    :func:`~nanoct.sim.simulate.simulate_sample` with the store's simulation settings, which a matched set
    does not have (refused).
    """
    if simulate is None and "like" in store.meta["simulation"]:
        raise NanoctError(
            f"{store.path} is a set matched to a measured scan: 'nanoct generate --like' makes its samples"
        )
    pending = [int(i) for i in (~store.done).nonzero()[0]]
    with disk_space_needed(store.path, store.sample_nbytes * len(pending)):
        run_tasks(
            partial(_simulate_into, str(store.path), simulate=simulate),
            pending,
            workers=workers,
            scheduler=scheduler,
            desc="generate",
            progress=progress,
            done=store.n - len(pending),
        )


def check_run(n: int, seed: int, workers: int) -> None:
    """Refuse a bad sample count, seed or worker count of a simulation run (:class:`NanoctError`)."""
    if isinstance(n, bool) or not isinstance(n, int) or n <= 0:
        raise NanoctError(f"--n {n} must be a positive number of samples")
    if seed < 0:
        raise NanoctError(f"--seed {seed} must be >= 0")
    if workers < 0:
        raise NanoctError(f"--workers {workers} must be >= 0 (0: run in this process)")


def generate_dataset(
    out: str | os.PathLike[str],
    geometry: Geometry,
    n: int,
    *,
    seed: int = 0,
    config: SimulationConfig | None = None,
    split_fractions: tuple[float, float, float] = (0.95, 0.04, 0.01),
    workers: int = 2,
    scheduler: str | None = None,
    progress: bool = True,
) -> DataStore:
    """Simulate ``n`` samples into the store at ``out`` (resuming if it is partly there).

    Parameters
    ----------
    out : path
        Store directory. If it holds the same data set (same geometry, n, seed, simulation
        parameters and split), only missing samples are made; if it holds another one, an
        error is raised and nothing is changed.
    geometry : Geometry
        Scan geometry.
    n : int
        Number of samples (> 0).
    seed : int
        Data-set seed; sample i depends only on (seed, i).
    config : SimulationConfig, optional
        Simulation settings (default: the paper's for the geometry kind).
    split_fractions : tuple of float
        Train/val/test proportions (paper: 0.95/0.04/0.01).
    workers, scheduler, progress
        See :func:`nanoct.core.fanout.run_tasks`.

    Returns
    -------
    DataStore
        The complete data set.
    """
    check_run(n, seed, workers)
    config = config or SimulationConfig.for_geometry(geometry)
    store = DataStore.create(Path(out), geometry, n, seed, config.to_dict(), split_fractions)
    fill_dataset(store, workers=workers, scheduler=scheduler, progress=progress)
    return DataStore.open(store.path, mode="r+")
