"""The stages of a setting: data, first reconstructions, training, prediction.

Every stage is cached in the setting's directory: the data set, each reconstruction, each
training run and each prediction resume where they stopped and are skipped when complete.
Training runs and predictions are independent jobs: on a local machine they run one after
another in this process with all its cores as torch threads; with a Dask scheduler (a cluster)
they go to its workers, one torch thread each.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

from ..core.fanout import run_tasks, usable_cpus
from ..core.geometry import get_preset
from ..core.names import prediction_name, seed_name
from ..io.store import DataStore
from ..learn.models import model_class
from ..recon.batch import reconstruct_dataset
from ..sim.generate import generate_dataset
from ..sim.simulate import SimulationConfig
from .config import Jobs, Setting, Study, calibration_seed

__all__ = ["data_stage", "prediction_stage", "reconstruction_stage", "training_stage"]


def _run_dir(runs: str, model: str, input_name: str, seed: int) -> Path:
    return Path(runs) / (f"{model}-{input_name}" + (f"-seed{seed}" if seed else ""))


def _with_threads(threads: int, job: Callable[[], object]) -> None:
    """Run ``job()`` with ``threads`` torch threads, restoring the previous count after; the freed
    memory of its steps kept for the next (:func:`nanoct.learn.train.keep_freed_memory`)."""
    import torch

    from ..learn.train import keep_freed_memory

    keep_freed_memory()

    old = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        job()
    finally:
        torch.set_num_threads(old)


def _train_job(data: str, runs: str, study: Study, jobs: list[tuple[str, str, int]], threads: int, index: int) -> int:
    from ..learn.train import TrainConfig, train

    model, input_name, seed = jobs[index]
    config = TrainConfig(
        model,
        input_name,
        epochs=study.epochs[model],
        lr=study.lr.get(model),
        scheduler=study.scheduler.get(model),
        model_kwargs=study.model_kwargs.get(model),
        seed=seed,
        precision=study.precision,
    )
    run = partial(train, data, _run_dir(runs, model, input_name, seed), config, progress=False)
    _with_threads(threads, run)
    return index


def _predict_job(
    data: str,
    runs: str,
    study: Study,
    jobs: list[tuple[str, str, str, int]],
    threads: int,
    index: int,
    *,
    calibration: str | None,
) -> int:
    """Predict job ``index`` of ``jobs``; the sampling networks' intervals fitted on ``calibration``
    (a calibration set) where given, else on the data set's validation split."""
    from ..learn.predict import predict

    model, train_input, input_name, seed = jobs[index]
    sampling = model_class(model).has_uncertainty
    name = seed_name(prediction_name(input_name, model, train_input), seed) if seed else None
    run = partial(
        predict,
        data,
        _run_dir(runs, model, train_input, seed),
        input_name,
        split="test",
        progress=False,
        name=name,
        reconstruct_kwargs=study.sampling if sampling else None,
        calibrate_on=calibration if sampling else None,
    )
    _with_threads(threads, run)
    return index


def data_stage(setting: Setting, study: Study, jobs: Jobs, seed: int, fan: dict[str, Any]) -> DataStore:
    """Simulate the setting's data set and, where it has one, its calibration set (resumable); return the data set."""
    geometry = get_preset(setting.preset)
    config = SimulationConfig.for_geometry(geometry, perturbed=setting.perturbed)
    if jobs.calibration:
        generate_dataset(
            setting.calibration,
            geometry,
            jobs.calibration,
            seed=calibration_seed(seed),
            config=config,
            split_fractions=(0.0, 1.0, 0.0),
            **fan,
        )
    return generate_dataset(
        setting.out / "data",
        geometry,
        jobs.samples,
        seed=seed,
        config=config,
        split_fractions=study.split_fractions,
        **fan,
    )


def reconstruction_stage(setting: Setting, jobs: Jobs, fan: dict[str, Any]) -> None:
    """Every first reconstruction of the setting over every sample, and over the calibration set those the
    networks are trained on (resumable)."""
    for name, (method, params) in setting.recons.items():
        reconstruct_dataset(setting.out / "data", method, params=params, name=name, **fan)
        if jobs.calibration and name in setting.train_inputs:
            reconstruct_dataset(setting.calibration, method, params=params, name=name, **fan)


def _torch_fan(fan: dict[str, Any]) -> tuple[dict[str, Any], int]:
    """Fan-out arguments and torch threads per job for training and prediction jobs.

    With a scheduler (a cluster) the jobs go to its workers, one torch thread each. On the local
    machine they run one after another in this process with all its cores as torch threads:
    two torch jobs side by side in separate processes were 2.1x slower than one after another on
    the 2-core AVX512-BF16 machine (``benchmarks/bench_concurrency.py``); on a 2-core AVX2-only
    machine two float32 training jobs side by side, one thread each, were 1.06-1.81x faster
    (``benchmarks/bench_cpu_training.py``), but a run's bits depend on its thread count, so the
    study keeps one order everywhere (benchmarks/README.md).
    """
    if fan.get("scheduler") is not None:
        return fan, 1
    return fan | {"workers": 0}, usable_cpus()


def _torch_stage(job: Callable[..., int], jobs: list, desc: str, setting: Setting, study: Study, fan: dict) -> None:
    """Run ``job`` for every entry of ``jobs`` where :func:`_torch_fan` puts torch jobs."""
    if jobs:
        torch_fan, threads = _torch_fan(fan)
        run_tasks(
            partial(job, str(setting.out / "data"), str(setting.out / "runs"), study, jobs, threads),
            range(len(jobs)),
            desc=desc,
            unit="run",
            **torch_fan,
        )


def training_stage(setting: Setting, study: Study, jobs: Jobs, fan: dict[str, Any]) -> None:
    """One network per (model, input, seed); finished runs are skipped, killed ones resume.

    Torch threads are set explicitly per job (torch may have been imported under
    ``OMP_NUM_THREADS=1``); where the jobs run: :func:`_torch_fan`.
    """
    _torch_stage(_train_job, jobs.train, "train", setting, study, fan)


def prediction_stage(setting: Setting, study: Study, jobs: Jobs, fan: dict[str, Any]) -> None:
    """Every prediction on the test split (done ones are skipped by :func:`nanoct.learn.predict.predict`)."""
    calibration = str(setting.calibration) if jobs.calibration else None
    _torch_stage(partial(_predict_job, calibration=calibration), jobs.predict, "predict", setting, study, fan)
