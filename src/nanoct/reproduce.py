"""The whole study from one call: generate, reconstruct, train, predict, evaluate, report.

:func:`reproduce_study` runs one setting (a geometry preset, perturbed or not);
:func:`reproduce_scale` runs the paper's three settings with the paper's rows. Both go through
the same stage functions (:func:`data_stage`, :func:`reconstruction_stage`,
:func:`training_stage`, :func:`prediction_stage`, :func:`report_stage`), and their job lists
come from :func:`setting_jobs`, which :mod:`nanoct.plan` uses to plan a run without running it.

Every stage is cached in the output directory: the data set, each reconstruction, each
training run and each prediction resume where they stopped and are skipped when complete;
tables and figures are cheap and redone. Training runs and predictions are independent jobs: on
a local machine they run one after another in this process with all its cores as torch threads;
with a Dask scheduler (a cluster) they go to its workers, one torch thread each.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from .conclusions import check_conclusions, format_conclusions
from .errors import NanoctError
from .evaluate import (
    evaluate_store,
    format_mixing,
    format_table,
    mixing_matrices,
    parse_name,
    per_image_values,
    write_report_tables,
)
from .fanout import run_tasks
from .figures import compare_reconstructions, show_sample, uncertainty_report
from .fileio import atomic_write_text, remove_stale_temporaries
from .generate import generate_dataset
from .geometry import get_preset, preset_names
from .learn.models import model_class, prediction_name, table_order
from .paper import format_comparison, format_mixing_comparison
from .provenance import environment_info, format_environment
from .recon.batch import reconstruct_dataset
from .recon.registry import method_spec, output_name
from .report_html import write_html_report
from .simulate import SimulationConfig
from .store import SPLITS, DataStore

__all__ = [
    "CONCLUSION_K",
    "DEFAULT_SEED",
    "SCALE_SETTINGS",
    "SCALE_STUDIES",
    "STUDIES",
    "check_models",
    "Jobs",
    "Setting",
    "Study",
    "data_stage",
    "prediction_stage",
    "preset_setting",
    "preset_study",
    "reconstruction_stage",
    "report_stage",
    "reproduce_scale",
    "reproduce_study",
    "run_setting",
    "scale_settings",
    "scale_study",
    "seed_name",
    "setting_jobs",
    "setting_mixing",
    "training_stage",
]

#: Seed of the study's data sets unless ``--seed`` says otherwise.
DEFAULT_SEED = 0
#: Standard errors a paired difference must exceed for a conclusion check to hold.
CONCLUSION_K = 2.0


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
    scheduler : dict
        Learning-rate schedules (``"none"``, ``"plateau"``, ``"cosine"``) that differ from the
        model registry's, per model (:func:`nanoct.learn.train.train`'s ``scheduler``).
    model_kwargs : dict
        Architecture arguments that differ from the paper's defaults, per model.
    n_samples : int
        Latent samples per image for the invertible networks (paper: 100).
    mixing : tuple of str
        Models also applied to every input they were not trained on (input-mixing tables).
    precision : {"fp32", "bf16"}
        Arithmetic of the training steps (:func:`nanoct.learn.train.train`).
    antithetic : bool
        Draw the invertible networks' latent samples in antithetic pairs (z, -z) (the paper:
        independent draws; ``reconstruct``'s ``antithetic``).
    """

    n: int
    split_fractions: tuple[float, float, float]
    epochs: dict[str, int] = field(default_factory=lambda: dict.fromkeys(table_order(), 500))
    lr: dict[str, float] = field(default_factory=dict)
    scheduler: dict[str, str] = field(default_factory=dict)
    model_kwargs: dict[str, dict[str, Any]] = field(default_factory=dict)
    n_samples: int = 100
    mixing: tuple[str, ...] = table_order()
    precision: str = "fp32"
    antithetic: bool = False


def _flow_kwargs(model: str, form: str, location_weight: float = 0.0) -> dict[str, Any]:
    """The tiny study's architecture arguments of an invertible network with conditional-scale
    ``form`` and, if positive, the location term's weight (docs/learn.md)."""
    kwargs: dict[str, Any] = {"blocks_per_scale": 2, "conditional_scale": form}
    if not model.startswith("cinn"):
        kwargs = {"blocks_per_scale": 1, "conditional_scale": form, "cond_channels": [16, 16, 32, 32, 64]}
    return kwargs | ({"location_weight": location_weight} if location_weight else {})


# tiny: meant for the one-setting study in under 25 minutes and the three settings in under 45 on
# a 2-core machine (what the fresh runs took: docs/results.md); the invertible networks get a 100x larger learning rate
# than the paper's 1e-5 because they train for tens of epochs instead of 500, lighter coupling
# stacks (same architecture family) at 63 x 63, a narrower conditioning UNet for CiUNet (16-64
# channels: half the step time) and the pixel-wise conditional scale (additive couplings, and a
# conditional ActNorm whose head gives each pixel's spread and location, in the location form),
# chosen on the validation split: docs/learn.md. The non-residual CiNN and CiUNet add the location
# term (location_weight 1000): under the NLL alone they stayed 3.5-9.1 dB below their inputs; the
# CiUNet's lr decays on a cosine (1e-3 -> 1e-4; the plateau schedule never lowered it in 24 epochs,
# and its samples then came out biased by +0.11 on FBP).
# Training steps run under bfloat16 autocast (on an AVX512-BF16 CPU the UNet makes 2x, the
# invertible networks 0.9-1.4x the steps per second, with the same quality within run-to-run
# spread, docs/learn.md). The budget (40 UNet epochs, 32 for the residual invertible networks,
# which the paper recommends, 24 for the others, M = 32 latent samples in antithetic pairs) is
# what fits the one-setting study into 25 minutes on that machine (SCALE_STUDIES: the three
# settings' 45 runs and 152 sampling passes in 45 minutes, with the round-four settings of the
# non-residual networks: 12 epochs, no location term, the shift form for CiUNet, the plateau
# schedule); antithetic pairs remove the Monte-Carlo error of the mean that M = 50 independent
# draws left (docs/learn.md).
# The UNet's architecture arguments were set for the previous budget (70 epochs) on the
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
        epochs={"unet": 40, "cinn": 24, "cinn-res": 32, "ciunet": 24, "ciunet-res": 32},
        lr={"cinn": 1e-3, "cinn-res": 1e-3, "ciunet": 1e-3, "ciunet-res": 1e-3},
        scheduler={"ciunet": "cosine"},
        model_kwargs={"unet": {"out_bias": -7.0, "skip_channels": 32}}
        | {
            m: _flow_kwargs(m, "location", 0.0 if m.endswith("-res") else 1000.0)
            for m in ("cinn", "cinn-res", "ciunet", "ciunet-res")
        },
        n_samples=32,
        mixing=("unet",),
        precision="bf16",
        antithetic=True,
    ),
    "small": Study(n=2000, split_fractions=(0.9, 0.05, 0.05), epochs=dict.fromkeys(table_order(), 100)),
    "paper": Study(n=32095, split_fractions=(0.95, 0.04, 0.01)),
}

#: Studies of ``reproduce --scale`` where they differ from the one-setting study of the same size
#: (:data:`STUDIES`): at tiny scale the three settings share 45 minutes, so the residual invertible
#: networks train 24 epochs instead of 32, and the non-residual ones 12 instead of 24, without the
#: location term, CiUNet in the shift form and on the plateau schedule (docs/learn.md).
SCALE_STUDIES: dict[str, Study] = {
    "tiny": replace(
        STUDIES["tiny"],
        epochs={**STUDIES["tiny"].epochs, "cinn": 12, "cinn-res": 24, "ciunet": 12, "ciunet-res": 24},
        scheduler={},
        model_kwargs={
            **STUDIES["tiny"].model_kwargs,
            "cinn": _flow_kwargs("cinn", "location"),
            "ciunet": _flow_kwargs("ciunet", "shift"),
        },
    ),
}


def scale_study(scale: str) -> Study:
    """The :class:`Study` of ``reproduce --scale scale`` (:data:`SCALE_STUDIES`, else :data:`STUDIES`).

    Raises
    ------
    NanoctError
        If ``scale`` is not one of :data:`STUDIES`.
    """
    _check_scale(scale)
    return SCALE_STUDIES.get(scale) or STUDIES[scale]


def _check_scale(scale: str) -> None:
    if scale not in STUDIES:
        raise NanoctError(f"unknown scale {scale!r}; choose one of: {', '.join(STUDIES)}")


#: The paper's reconstructions (method, parameters), in its table order.
_PAPER_RECONS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("fbp", {}),
    ("dremel", {}),
    ("resesop", {"eta_scale": 1.0}),
    ("resesop", {"eta_scale": 0.8}),
    ("resesop", {"eta_scale": 1.2}),
)

#: The paper's three settings: (geometry kind, perturbed).
SCALE_SETTINGS: dict[str, tuple[str, bool]] = {
    "parallel": ("parallel", True),
    "fan": ("fan", True),
    "unperturbed": ("parallel", False),
}


def _recons(perturbed: bool = True) -> dict[str, tuple[str, dict[str, Any]]]:
    """Output name -> (method, parameters) of the study's reconstructions."""
    if not perturbed:  # the paper's unperturbed table: each method once, eta = 0 where a method uses eta
        methods = dict.fromkeys(m for m, _ in _PAPER_RECONS)
        return {m: (m, {"eta_scale": 0.0} if method_spec(m).needs_eta else {}) for m in methods}
    return {output_name(m, p): (m, p) for m, p in _PAPER_RECONS}


@dataclass(frozen=True)
class Setting:
    """One setting of a study: its geometry, data directory and the rows it has.

    Attributes
    ----------
    preset : str
        Geometry preset.
    perturbed : bool
        Motion in the data (False: the unperturbed case).
    out : Path
        Directory of the setting: ``data``, ``runs``, ``report`` below it.
    recons : dict
        Output name -> (method, parameters) of the first reconstructions.
    train_inputs : tuple of str
        Inputs the networks are trained on.
    mixing : tuple of str
        Networks also applied to every training input they were not trained on.
    paper : str or None
        Key of the paper's table this setting corresponds to (``parallel``, ``fan``,
        ``unperturbed``), None for a setting the paper does not have.
    """

    preset: str
    perturbed: bool
    out: Path
    recons: dict[str, tuple[str, dict[str, Any]]]
    train_inputs: tuple[str, ...]
    mixing: tuple[str, ...]
    paper: str | None


def _paper_key(preset: str, perturbed: bool) -> str | None:
    kind = get_preset(preset).kind
    return next((k for k, v in SCALE_SETTINGS.items() if v == (kind, perturbed)), None)


def preset_study(preset: str) -> Study:
    """The :data:`STUDIES` entry of a geometry preset (its size prefix).

    Raises
    ------
    NanoctError
        If ``preset`` is not a geometry preset.
    """
    if preset not in preset_names():
        raise NanoctError(f"unknown preset {preset!r}; choose one of: {', '.join(preset_names())}")
    return STUDIES[preset.split("-")[0]]


def preset_setting(
    preset: str, perturbed: bool, out: Path | None, mixing: tuple[str, ...], seed: int = DEFAULT_SEED
) -> Setting:
    """The setting of ``nanoct reproduce --preset``: every first reconstruction is an input of every network."""
    preset_study(preset)  # rejects an unknown preset
    suffix = ("" if perturbed else "-nomotion") + ("" if seed == DEFAULT_SEED else f"-seed{seed}")
    recons = _recons(perturbed)
    out = Path(out or Path("runs") / f"{preset}{suffix}")
    return Setting(preset, perturbed, out, recons, tuple(recons), mixing, _paper_key(preset, perturbed))


def scale_settings(scale: str, out: Path | None = None, seed: int = DEFAULT_SEED) -> list[Setting]:
    """The paper's three settings at a scale, with the paper's rows (see :func:`reproduce_scale`).

    Raises
    ------
    NanoctError
        If ``scale`` is not one of :data:`STUDIES`.
    """
    _check_scale(scale)
    root = Path(out or Path("runs") / (scale if seed == DEFAULT_SEED else f"{scale}-seed{seed}"))
    perturbed = _recons(True)
    fan = {k: v for k, v in perturbed.items() if k in ("fbp", "dremel", "resesop")}
    return [
        Setting(f"{scale}-parallel", True, root / "parallel", perturbed, tuple(perturbed), table_order(), "parallel"),
        Setting(f"{scale}-fan", True, root / "fan", fan, tuple(fan), (), "fan"),
        Setting(f"{scale}-parallel", False, root / "unperturbed", _recons(False), ("fbp",), (), "unperturbed"),
    ]


@dataclass(frozen=True)
class Jobs:
    """The jobs of one setting, per stage; the runner and :func:`nanoct.plan.plan_study` both use them.

    Attributes
    ----------
    samples : int
        Samples to simulate.
    recons : list of str
        First reconstructions (each over every sample).
    train : list of (model, input, seed)
        Training runs.
    predict : list of (model, train_input, input, seed)
        Predictions on the test split.
    """

    samples: int
    recons: list[str]
    train: list[tuple[str, str, int]]
    predict: list[tuple[str, str, str, int]]


def setting_jobs(setting: Setting, study: Study, models: tuple[str, ...], n: int | None, seeds: int = 1) -> Jobs:
    """Every job of a setting: samples, reconstructions, training runs and predictions.

    With ``seeds > 1`` each network is trained on each of its inputs with training seeds
    ``0 .. seeds - 1`` (the rows that decide the paper's conclusions); input mixing uses seed 0.
    """
    if seeds < 1:
        raise NanoctError(f"seeds = {seeds} must be >= 1 (training seeds per network row)")
    train = [(m, i, s) for m in models for i in setting.train_inputs for s in range(seeds)]
    predict = [(m, i, i, s) for m, i, s in train]
    mixed = [m for m in models if m in setting.mixing]
    predict += [(m, t, i, 0) for m in mixed for t in setting.train_inputs for i in setting.train_inputs if i != t]
    return Jobs(study.n if n is None else n, list(setting.recons), train, predict)


def _run_dir(runs: str, model: str, input_name: str, seed: int) -> Path:
    return Path(runs) / (f"{model}-{input_name}" + (f"-seed{seed}" if seed else ""))


def seed_name(name: str, seed: int) -> str:
    """Store name of a prediction of training seed ``seed`` (seed 0: the name itself)."""
    return name if seed == 0 else f"{name}%seed{seed}"


def _with_threads(threads: int, job: Callable[[], object]) -> None:
    """Run ``job()`` with ``threads`` torch threads, restoring the previous count after."""
    import torch

    old = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        job()
    finally:
        torch.set_num_threads(old)


def _train_job(data: str, runs: str, study: Study, jobs: list[tuple[str, str, int]], threads: int, index: int) -> int:
    from .learn.train import train

    model, input_name, seed = jobs[index]
    run = partial(
        train,
        data,
        model,
        input_name,
        _run_dir(runs, model, input_name, seed),
        epochs=study.epochs[model],
        lr=study.lr.get(model),
        scheduler=study.scheduler.get(model),
        model_kwargs=study.model_kwargs.get(model),
        seed=seed,
        progress=False,
        precision=study.precision,
    )
    _with_threads(threads, run)
    return index


def _sampling(study: Study) -> dict[str, Any]:
    """``reconstruct`` arguments of the invertible networks in ``study``."""
    return {"n_samples": study.n_samples} | ({"antithetic": True} if study.antithetic else {})


def _predict_job(
    data: str, runs: str, study: Study, jobs: list[tuple[str, str, str, int]], threads: int, index: int
) -> int:
    from .learn.predict import predict

    model, train_input, input_name, seed = jobs[index]
    kwargs = _sampling(study) if model_class(model).has_uncertainty else None
    name = seed_name(prediction_name(input_name, model, train_input), seed) if seed else None
    run = partial(
        predict,
        data,
        _run_dir(runs, model, train_input, seed),
        input_name,
        split="test",
        progress=False,
        name=name,
        reconstruct_kwargs=kwargs,
    )
    _with_threads(threads, run)
    return index


def _cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def data_stage(setting: Setting, study: Study, jobs: Jobs, seed: int, fan: dict[str, Any]) -> DataStore:
    """Simulate the setting's data set (resumable) and return its store."""
    geometry = get_preset(setting.preset)
    config = SimulationConfig.for_geometry(geometry, perturbed=setting.perturbed)
    return generate_dataset(
        setting.out / "data",
        geometry,
        jobs.samples,
        seed=seed,
        config=config,
        split_fractions=study.split_fractions,
        **fan,
    )


def reconstruction_stage(setting: Setting, fan: dict[str, Any]) -> None:
    """Every first reconstruction of the setting over every sample (resumable)."""
    for name, (method, params) in setting.recons.items():
        reconstruct_dataset(setting.out / "data", method, params=params, name=name, **fan)


def _torch_fan(fan: dict[str, Any]) -> tuple[dict[str, Any], int]:
    """Fan-out arguments and torch threads per job for training and prediction jobs.

    With a scheduler (a cluster) the jobs go to its workers, one torch thread each. On the local
    machine they run one after another in this process with all its cores as torch threads:
    two torch jobs side by side in separate processes were much slower than one after another
    on the 2-core machine the tiny study is timed on (``benchmarks/bench_concurrency.py``,
    benchmarks/README.md).
    """
    if fan.get("scheduler") is not None:
        return fan, 1
    return fan | {"workers": 0}, _cores()


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
    _torch_stage(_predict_job, jobs.predict, "predict", setting, study, fan)


def _result_names(setting: Setting, models: tuple[str, ...], jobs: Jobs) -> tuple[list[str], list[str]]:
    """(table rows in order, extra-seed rows) of the setting's report."""
    names = list(setting.recons) + [f"{i}+{m}" for m in models for i in setting.train_inputs]
    names += [prediction_name(i, m, t) for m, t, i, s in jobs.predict if i != t and s == 0]
    extra = [seed_name(prediction_name(i, m, t), s) for m, t, i, s in jobs.predict if s]
    return names, extra


def _conclusion_values(results: dict[str, Any], extra: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Per-image values of every row, stacked over training seeds where a row has several."""
    values = per_image_values(results)
    for name, scores in extra.items():
        base = name.split("%seed")[0]
        if base in values:
            for metric in ("psnr", "ssim"):
                values[base][metric] = np.vstack([values[base][metric], scores[f"{metric}_values"]])
    return values


def _figures(store: DataStore, setting: Setting, models: tuple[str, ...], report_dir: Path) -> list[str]:
    test = [int(i) for i in store.indices("test")[:3]]
    inputs = list(setting.train_inputs)
    compare_reconstructions(store, list(setting.recons), test, report_dir / "reconstructions.png")
    figures = [("reconstructions.png", "First reconstructions")]
    for m in models:
        compare_reconstructions(store, [f"{i}+{m}" for i in inputs], test, report_dir / f"reconstructions_{m}.png")
        figures.append((f"reconstructions_{m}.png", f"Post-processed by {m}"))
    show_sample(store, test[0], report_dir / "sample.png")
    figures.append(("sample.png", "A test sample: motion, sinograms, FBP"))
    return [f"## {title}\n\n![{title}]({png})\n" for png, title in figures]


def _paper_sections(setting: Setting, results: dict[str, Any], checks: list[dict[str, Any]]) -> list[str]:
    """Our rows next to the paper's, the mixing tables and the conclusion checks (Markdown)."""
    if setting.paper is None:
        return []
    title = f"Ours next to the paper ({setting.paper}; gain = row minus its input)"
    text = [format_comparison(results, setting.paper, title)]
    mixed = {m for m, *_ in setting_mixing(results)} if setting.paper == "parallel" else set()
    for model in [m for m in table_order() if m in mixed]:
        text.append(format_mixing_comparison(results, model))
    text += ["### The paper's conclusions", "", format_conclusions(checks, CONCLUSION_K)]
    return text


def setting_mixing(results: dict[str, Any]) -> list[tuple[str, str, str]]:
    """(model, train_input, input) of every input-mixing row in ``results``, in table order."""
    return [(m, t, i) for i, m, t in map(parse_name, results) if m is not None and i != t]


def report_stage(
    setting: Setting, study: Study, models: tuple[str, ...], jobs: Jobs, seconds: dict[str, float] | None = None
) -> tuple[Path, list[str]]:
    """Tables, comparison with the paper, conclusion checks, figures, Markdown + HTML report.

    ``seconds``: wall time of each earlier stage in this invocation (a stage finished by an
    earlier invocation takes about 0 s), shown under the setting's heading.

    Returns the Markdown report's path and its sections that a scale report repeats.
    """
    store = DataStore.open(setting.out / "data")
    report_dir = setting.out / "report"
    names, extra_names = _result_names(setting, models, jobs)
    scored = evaluate_store(store, "test", names=names + extra_names)  # one pass over the ground truth
    results = {n: scored[n] for n in names if n in scored}
    extra = {n: scored[n] for n in extra_names if n in scored}
    checks = []
    if setting.paper is not None:
        checks = check_conclusions(_conclusion_values(results, extra), setting.paper, k=CONCLUSION_K)
    remove_stale_temporaries(report_dir)  # left by a kill during an earlier report
    write_report_tables(store, results, report_dir, "test", conclusions=checks, setting=setting.paper)
    mixing = mixing_matrices(results)
    seeds = 1 + max((s for *_, s in jobs.train), default=0)
    schedules = ", ".join(f"{m} {study.scheduler[m]}" for m in models if m in study.scheduler)
    sections = [
        f"## {setting.preset}{'' if setting.perturbed else ' (no motion)'}",
        "",
        f"{store.n} samples (train/val/test { ({s: int(store.indices(s).size) for s in SPLITS}) }), seed {store.seed}; "
        f"networks: {', '.join(models) or 'none'}; epochs {', '.join(f'{m} {study.epochs[m]}' for m in models)}"
        + (f"; learning-rate schedule {schedules} (others: their model's default)" if schedules else "")
        + (f"; {seeds} training seeds per network row (tables: seed 0)" if seeds > 1 else "")
        + ".",
        "",
        _format_seconds(seconds or {}),
        *_paper_sections(setting, results, checks),
    ]
    text = [f"# nanoct study: {setting.preset}{'' if setting.perturbed else ' (no motion)'}", ""]
    text += [format_environment(environment_info()), *sections[2:5], format_table(results, "Test split")]
    text += [*sections[5:], format_mixing(mixing) if mixing else ""]
    runs = setting.out / "runs"
    text.append(uncertainty_report(store, results, list(models), list(setting.train_inputs), runs, report_dir))
    text += _figures(store, setting, models, report_dir)
    md = atomic_write_text(report_dir / "report.md", "\n".join(text))
    write_html_report(md)
    return md, sections


def check_models(models: tuple[str, ...] | None) -> tuple[str, ...]:
    """The networks of a study (default all, in the paper's order); NanoctError for unknown names."""
    models = table_order() if models is None else tuple(models)
    unknown = [m for m in models if m not in table_order()]
    if unknown:
        raise NanoctError(f"unknown model(s) {unknown}; choose from {', '.join(table_order())}")
    return models


def run_setting(
    setting: Setting,
    study: Study,
    models: tuple[str, ...],
    *,
    n: int | None = None,
    seed: int = DEFAULT_SEED,
    seeds: int = 1,
    fan: dict[str, Any],
) -> tuple[Path, list[str]]:
    """Every stage of one setting in order, timed; see :func:`report_stage` for what it returns."""
    jobs = setting_jobs(setting, study, models, n, seeds)
    seconds: dict[str, float] = {}
    stages: dict[str, Callable[[], object]] = {
        "data": partial(data_stage, setting, study, jobs, seed, fan),
        "reconstructions": partial(reconstruction_stage, setting, fan),
        "training": partial(training_stage, setting, study, jobs, fan),
        "prediction": partial(prediction_stage, setting, study, jobs, fan),
    }
    for stage, run in stages.items():
        t0 = time.perf_counter()
        run()
        seconds[stage] = time.perf_counter() - t0
    t0 = time.perf_counter()
    md, sections = report_stage(setting, study, models, jobs, seconds)
    seconds["report"] = time.perf_counter() - t0
    atomic_write_text(md.parent / "stage_seconds.json", json.dumps(seconds, indent=2))
    return md, sections


def _format_seconds(seconds: dict[str, float]) -> str:
    """One line: the wall time of each stage in this invocation."""
    if not seconds:
        return ""
    parts = [f"{stage} {_duration(s)}" for stage, s in seconds.items()]
    return f"Wall time of the stages in this run: {', '.join(parts)} (a stage completed by an earlier run: ~0 s).\n"


def _duration(s: float) -> str:
    m, sec = divmod(round(s), 60)
    return f"{m} min {sec:02d} s" if m else f"{sec} s"


def reproduce_study(
    preset: str,
    *,
    out: str | os.PathLike[str] | None = None,
    n: int | None = None,
    perturbed: bool = True,
    models: tuple[str, ...] | None = None,
    study: Study | None = None,
    seed: int = DEFAULT_SEED,
    seeds: int = 1,
    workers: int = 2,
    scheduler: str | None = None,
    progress: bool = True,
) -> Path:
    """Run the study for one geometry preset and return the path of its Markdown report.

    Parameters
    ----------
    preset : str
        Geometry preset (``tiny-parallel``, ``paper-fan``, ...); its size prefix picks the
        scale in :data:`STUDIES`.
    out : path, optional
        Output directory (default ``runs/<preset>``, ``-nomotion`` / ``-seed<S>`` appended where
        they apply): the data set is ``<out>/data``, training runs ``<out>/runs/<model>-<input>``,
        the report ``<out>/report`` (``report.md``, ``report.html``, ``evaluation.json``).
    n : int, optional
        Number of samples instead of the scale's default.
    perturbed : bool
        False gives the unperturbed sanity case.
    models : tuple of str, optional
        Post-processing networks to train (default all of :data:`nanoct.learn.models.MODELS`;
        ``()`` for none).
    study : Study, optional
        Scale settings instead of the preset's entry in :data:`STUDIES`.
    seed : int
        Seed of the data set.
    seeds : int
        Training seeds per network row (the conclusion checks add their spread).
    workers, scheduler, progress
        See :func:`nanoct.fanout.run_tasks`.
    """
    models = check_models(models)
    study = study or preset_study(preset)
    setting = preset_setting(preset, perturbed, None if out is None else Path(out), study.mixing, seed)
    fan = {"workers": workers, "scheduler": scheduler, "progress": progress}
    return run_setting(setting, study, models, n=n, seed=seed, seeds=seeds, fan=fan)[0]


def reproduce_scale(
    scale: str,
    *,
    out: str | os.PathLike[str] | None = None,
    models: tuple[str, ...] | None = None,
    study: Study | None = None,
    seed: int = DEFAULT_SEED,
    seeds: int = 1,
    workers: int = 2,
    scheduler: str | None = None,
    progress: bool = True,
) -> Path:
    """Run the paper's three settings at a scale and return the path of the combined report.

    The settings (:func:`scale_settings`): perturbed parallel beam (FBP, Dremel, RESESOP with
    eta, 0.8 eta and 1.2 eta, each raw and with every network, input mixing for every
    network), perturbed fan beam (FBP, Dremel, RESESOP, raw and with every network) and
    unperturbed parallel beam (FBP, Dremel, RESESOP with eta = 0, the networks on FBP). Each
    setting lives in ``<out>/<setting>`` (default ``out``: ``runs/<scale>``) with its own report;
    ``<out>/report.md`` / ``report.html`` gather the three settings' tables, the paper's numbers
    and the conclusion checks, ``<out>/report.json`` their results, mixing tables and checks
    per setting with the environment. Other arguments as :func:`reproduce_study`.
    """
    t0 = time.perf_counter()
    models = check_models(models)
    settings = scale_settings(scale, None if out is None else Path(out), seed)
    study = study or scale_study(scale)
    fan = {"workers": workers, "scheduler": scheduler, "progress": progress}
    root, env = settings[0].out.parent, environment_info()
    text = [f"# nanoct study: {scale} scale, the paper's three settings", "", format_environment(env)]
    summary: dict[str, Any] = {"scale": scale, "seed": seed, "seeds": seeds, "environment": env, "settings": {}}
    for setting in settings:
        md, sections = run_setting(setting, study, models, seed=seed, seeds=seeds, fan=fan)
        text += sections + [f"Full report of this setting: [{md.relative_to(root)}]({md.relative_to(root)})", ""]
        evaluation = json.loads((md.parent / "evaluation.json").read_text())
        summary["settings"][setting.paper] = {
            "report": str(md.relative_to(root)),
            "stage_seconds": json.loads((md.parent / "stage_seconds.json").read_text()),
        } | {k: evaluation[k] for k in ("results", "mixing", "conclusions")}
    summary["seconds"] = time.perf_counter() - t0
    text.insert(
        3, f"\nWall time of this run: {_duration(summary['seconds'])} (stages completed by an earlier run: ~0 s).\n"
    )
    atomic_write_text(root / "report.json", json.dumps(summary, indent=2))
    report = atomic_write_text(root / "report.md", "\n".join(text))
    write_html_report(report)
    return report
