"""The whole study from one call: generate, reconstruct, train, predict, evaluate, report.

Every stage is cached in the output directory: the data set, each reconstruction, each
training run and each prediction resume where they stopped and are skipped when complete;
tables and figures are cheap and redone. Training runs and predictions are independent jobs
fanned out over the same Dask workers as the per-sample work (one torch thread each), except
the UNet runs on a local machine: they run one after another in this process with all its
torch threads (the UNet's convolutions scale with threads, the invertible networks' less).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

from .errors import NanoctError
from .evaluate import evaluate_store, format_mixing, format_table, mixing_matrices, write_report_tables
from .fanout import run_tasks
from .figures import compare_reconstructions, show_sample, uncertainty_report
from .fileio import atomic_write_text, remove_stale_temporaries
from .generate import generate_dataset
from .geometry import get_preset, preset_names
from .learn.models import model_class, table_order
from .recon.batch import reconstruct_dataset
from .recon.registry import method_spec, output_name
from .simulate import SimulationConfig

__all__ = ["STUDIES", "Study", "reproduce_study"]


@dataclass(frozen=True)
class Study:
    """Scale of a reproduction.

    Attributes
    ----------
    n, split_fractions
        Number of samples and train/val/test proportions.
    epochs : dict
        Training epochs per model.
    lr : dict
        Learning rates that differ from the paper's (model registry) defaults.
    model_kwargs : dict
        Architecture arguments that differ from the paper's defaults, per model.
    n_samples : int
        Latent samples per image for the invertible networks (paper: 100).
    mixing : tuple of str
        Models also applied to every input they were not trained on (input-mixing tables).
    """

    n: int
    split_fractions: tuple[float, float, float]
    epochs: dict[str, int] = field(default_factory=lambda: dict.fromkeys(table_order(), 500))
    lr: dict[str, float] = field(default_factory=dict)
    model_kwargs: dict[str, dict[str, Any]] = field(default_factory=dict)
    n_samples: int = 100
    mixing: tuple[str, ...] = table_order()


# tiny: a 2-core laptop in under 25 minutes (measured in the README); the invertible networks
# get a 100x larger learning rate than the paper's 1e-5 because they train for tens of epochs
# instead of 500, lighter coupling stacks (same architecture family) at 63 x 63, a narrower
# conditioning UNet for CiUNet (16-64 channels: half the step time) and the pixel-wise
# conditional scale (additive couplings for the mean, a conditional ActNorm for the spread),
# chosen on the validation split: docs/learn.md has the measurements.
# The UNet (cosine learning rate, 70 epochs = 700 steps) is set for this budget on the
# validation split, Dremel input (the hardest to improve; val MSE of the input 4.93e-4;
# numbers below with 32-channel skips, 60 epochs unless said):
# - output bias -7 (sigmoid 0.0009, near the zero background): with PyTorch's default start the
#   background stayed at 0.024 and SSIM halved; the sigmoid's floor costs SSIM in the 82 % of
#   zero pixels (bias -6: val 4.73e-4 / SSIM 0.936; -7: 4.66e-4 / 0.963; -8: 5.19e-4 / 0.964);
# - 32-channel skip branches instead of dival's 4 (the paper's figure is not available): the
#   4-channel skips could not carry Dremel's fine detail (val MSE 5.33e-4 > input, 60 epochs).
STUDIES: dict[str, Study] = {
    "tiny": Study(
        n=200,
        split_fractions=(0.8, 0.1, 0.1),
        epochs={"unet": 70, "cinn": 24, "cinn-res": 24, "ciunet": 18, "ciunet-res": 18},
        lr={"cinn": 1e-3, "cinn-res": 1e-3, "ciunet": 1e-3, "ciunet-res": 1e-3},
        model_kwargs={"unet": {"out_bias": -7.0, "skip_channels": 32}}
        | {m: {"blocks_per_scale": 2, "conditional_scale": True} for m in ("cinn", "cinn-res")}
        | {
            m: {"blocks_per_scale": 1, "conditional_scale": True, "cond_channels": [16, 16, 32, 32, 64]}
            for m in ("ciunet", "ciunet-res")
        },
        n_samples=100,
        mixing=("unet",),
    ),
    "small": Study(n=2000, split_fractions=(0.9, 0.05, 0.05), epochs=dict.fromkeys(table_order(), 100)),
    "paper": Study(n=32095, split_fractions=(0.95, 0.04, 0.01)),
}


#: The paper's reconstructions (method, parameters), in its table order.
_PAPER_RECONS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("fbp", {}),
    ("dremel", {}),
    ("resesop", {"eta_scale": 1.0}),
    ("resesop", {"eta_scale": 0.8}),
    ("resesop", {"eta_scale": 1.2}),
)


def _recons(perturbed: bool = True) -> dict[str, tuple[str, dict[str, Any]]]:
    """Output name -> (method, parameters) of the study's reconstructions."""
    if not perturbed:  # the paper's unperturbed table: each method once, eta = 0 where a method uses eta
        methods = dict.fromkeys(m for m, _ in _PAPER_RECONS)
        return {m: (m, {"eta_scale": 0.0} if method_spec(m).needs_eta else {}) for m in methods}
    return {output_name(m, p): (m, p) for m, p in _PAPER_RECONS}


def _with_threads(threads: int, job: Callable[[], object]) -> None:
    """Run ``job()`` with ``threads`` torch threads, restoring the previous count after."""
    import torch

    old = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        job()
    finally:
        torch.set_num_threads(old)


def _train_job(data: str, runs: str, study: Study, jobs: list[tuple[str, str]], threads: int, index: int) -> int:
    from .learn.train import train

    model, input_name = jobs[index]
    _with_threads(
        threads,
        partial(
            train,
            data,
            model,
            input_name,
            Path(runs) / f"{model}-{input_name}",
            epochs=study.epochs[model],
            lr=study.lr.get(model),
            model_kwargs=study.model_kwargs.get(model),
            progress=False,
        ),
    )
    return index


def _predict_job(data: str, runs: str, study: Study, jobs: list[tuple[str, str, str]], threads: int, index: int) -> int:
    from .learn.predict import predict

    model, train_input, input_name = jobs[index]
    kwargs = {"n_samples": study.n_samples} if model_class(model).has_uncertainty else None
    _with_threads(
        threads,
        partial(
            predict,
            data,
            Path(runs) / f"{model}-{train_input}",
            input_name,
            split="test",
            progress=False,
            reconstruct_kwargs=kwargs,
        ),
    )
    return index


def reproduce_study(
    preset: str,
    *,
    out: str | os.PathLike[str] | None = None,
    n: int | None = None,
    perturbed: bool = True,
    models: tuple[str, ...] | None = None,
    study: Study | None = None,
    workers: int = 2,
    scheduler: str | None = None,
    progress: bool = True,
) -> Path:
    """Run the study for a geometry preset and return the path of its Markdown report.

    Parameters
    ----------
    preset : str
        Geometry preset (``tiny-parallel``, ``paper-fan``, ...); its size prefix picks the
        scale in :data:`STUDIES`.
    out : path, optional
        Output directory (default ``runs/<preset>`` or ``runs/<preset>-nomotion``): the data set
        is ``<out>/data``, training runs ``<out>/runs/<model>-<input>``, the report ``<out>/report``.
    n : int, optional
        Number of samples instead of the scale's default.
    perturbed : bool
        False gives the unperturbed sanity case.
    models : tuple of str, optional
        Post-processing networks to train (default all of :data:`nanoct.learn.models.MODELS`;
        ``()`` for none).
    study : Study, optional
        Scale settings instead of the preset's entry in :data:`STUDIES`.
    workers, scheduler, progress
        See :func:`nanoct.fanout.run_tasks`.
    """
    if preset not in preset_names():
        raise NanoctError(f"unknown preset {preset!r}; choose one of: {', '.join(preset_names())}")
    models = table_order() if models is None else tuple(models)
    unknown = [m for m in models if m not in table_order()]
    if unknown:
        raise NanoctError(f"unknown model(s) {unknown}; choose from {', '.join(table_order())}")
    geometry = get_preset(preset)
    study = study or STUDIES[preset.split("-")[0]]
    out = Path(out or Path("runs") / (preset if perturbed else f"{preset}-nomotion"))
    data, runs, report_dir = out / "data", out / "runs", out / "report"
    fan = {"workers": workers, "scheduler": scheduler, "progress": progress}

    # 1. data and first reconstructions
    config = SimulationConfig.for_geometry(geometry, perturbed=perturbed)
    store = generate_dataset(
        data, geometry, study.n if n is None else n, seed=0, config=config, split_fractions=study.split_fractions, **fan
    )
    recons = _recons(perturbed)
    for name, (method, params) in recons.items():
        reconstruct_dataset(data, method, params=params, name=name, **fan)
    inputs = list(recons)

    # 2. one network per (model, input); then predictions on the test split, with input mixing.
    # Jobs fanned out over local workers get one torch thread each; the UNet runs go one after
    # another in this process with all threads instead (tiny preset, 2 cores: 0.29 s per step
    # with 1 thread, 0.16 s with 2, and two 1-thread runs side by side slow each other by 25 %).
    # Counts are set explicitly per job (torch may have been imported under OMP_NUM_THREADS=1).
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    job_threads = cores if scheduler is None and workers == 0 else 1
    train_jobs = [(m, i) for m in models for i in inputs]
    for in_process in (True, False):
        jobs = [(m, i) for m, i in train_jobs if (m == "unet" and scheduler is None) == in_process]
        if jobs:
            run_tasks(
                partial(_train_job, str(data), str(runs), study, jobs, cores if in_process else job_threads),
                range(len(jobs)),
                desc="train",
                unit="run",
                **(fan | {"workers": 0} if in_process else fan),
            )
    predict_jobs = [(m, t, i) for m in models for t in inputs for i in inputs if i == t or m in study.mixing]
    run_tasks(
        partial(_predict_job, str(data), str(runs), study, predict_jobs, job_threads),
        range(len(predict_jobs)),
        desc="predict",
        unit="run",
        **fan,
    )

    # 3. tables and figures
    names = inputs + [f"{i}+{m}" for m in models for i in inputs]
    names += [f"{i}+{m}@{t}" for m, t, i in predict_jobs if i != t]
    results = evaluate_store(store, "test", names=names)
    remove_stale_temporaries(report_dir)  # left by a kill during an earlier report
    write_report_tables(store, results, report_dir, "test")
    test = [int(i) for i in store.indices("test")[:3]]
    figures = [("reconstructions.png", "First reconstructions")]
    compare_reconstructions(store, inputs, test, report_dir / "reconstructions.png")
    for m in models:
        compare_reconstructions(store, [f"{i}+{m}" for i in inputs], test, report_dir / f"reconstructions_{m}.png")
        figures.append((f"reconstructions_{m}.png", f"Post-processed by {m}"))
    show_sample(store, test[0], report_dir / "sample.png")
    figures.append(("sample.png", "A test sample: motion, sinograms, FBP"))
    mixing = mixing_matrices(results)
    text = [
        f"# nanoct study: {preset}{'' if perturbed else ' (no motion)'}",
        "",
        f"{store.n} samples (train/val/test {store.info()['splits']}), seed {store.seed}; "
        f"networks: {', '.join(models) or 'none'}; epochs {', '.join(f'{m} {study.epochs[m]}' for m in models)}.",
        "",
        format_table(results, "Test split"),
        format_mixing(mixing) if mixing else "",
        uncertainty_report(store, results, list(models), inputs, runs, report_dir),
    ]
    text += [f"## {title}\n\n![{title}]({png})\n" for png, title in figures]
    return atomic_write_text(report_dir / "report.md", "\n".join(text))
