"""Plan a study run without running it: stages, jobs, disk and a time estimate per stage.

The job lists come from :func:`nanoct.study.config.setting_jobs`, the function the runner uses,
so the counts are the ones a run does. Times are estimates from the measured figures in
``benchmarks/README.md`` and ``docs/results.md`` (2-core CPU sandbox), expressed as
core-seconds per unit of work and divided by the cores (or GPUs) given; see
:data:`COST_SOURCES` for where each figure comes from. They are a guide for choosing a
machine, not a promise: the measurements vary by up to 2x with the machine's load.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..core.errors import NanoctError
from ..core.geometry import get_preset
from ..io.store import split_assignment
from ..learn.models import model_class
from .config import (
    Setting,
    Study,
    check_models,
    preset_models,
    preset_setting,
    preset_study,
    scale_settings,
    scale_study,
    setting_jobs,
)

__all__ = ["COST_SOURCES", "STAGES", "StagePlan", "format_plan", "plan_study"]

STAGES = ("data", "reconstructions", "training", "prediction", "report")

#: Paper-parallel (N=255, K=567, L=363) core-seconds per sample, and where they were measured.
_PAPER_PARALLEL = {"generate": 2 / 7.82, "fbp": 0.151, "dremel": 3.42, "resesop": 1.68}
#: Paper-fan (N=255, K=133, L=723) core-seconds per sample.
_PAPER_FAN = {"generate": 2 / 7.82 * 146.1 / 306.4, "fbp": 0.0496, "dremel": 1.98, "resesop": 1.68 * 24.5 / 51.9}
#: Per-sample, per-job overhead (core-s) not scaling with the geometry: fitted so that the tiny
#: study's generation + 5 reconstructions of 200 samples take the measured ~60 s on 2 cores.
_OVERHEAD = 0.077
#: Core-seconds per training image (one image of one epoch) at N = 63 and N = 255. N = 63: the tiny
#: study of docs/results.md on 2 cores (bfloat16 training steps, one run at a time with 2 threads;
#: the 1,081 s training stage split by the runs' epoch seconds): 5 UNet runs (32,000 images) 314 s,
#: 20 invertible runs (70,400 images) 767 s.
_TRAIN = {
    63: {"unet": 2 * 314 / 32000, "inn": 2 * 767 / 70400},
    255: {"unet": 2 / 5.5, "cinn": 3 * 0.0901, "ciunet": 3 * 0.3162},
}
#: The precision each :data:`_TRAIN` size was measured in (sizes scaled from 255: float32).
_TRAIN_PRECISION = {63: "bf16", 255: "fp32"}
#: Float32 over bfloat16 seconds per training step on a CPU with native bfloat16 (docs/learn.md: UNet
#: 0.253 / 0.127 s at 2 threads; CiNNRes 0.202 / 0.147 and CiUNetRes 0.309 / 0.217 s at 1 thread).
_FP32_OVER_BF16 = {"unet": 0.253 / 0.127, "inn": (0.202 / 0.147 + 0.309 / 0.217) / 2}
#: Core-seconds per test image: UNet inference; invertible networks per latent sample (at N = 63
#: the tiny run: 45 predictions in 83 s on 2 cores, 20 of them invertible on 20 test + 20
#: validation (calibration) images x 32 antithetic samples; the UNet's share is negligible).
_PREDICT = {
    63: {"unet": 2 * 0.0018, "inn": 2 * 83 / 25600},
    255: {"unet": 2 * 0.0529, "cinn": 0.0691, "ciunet": 0.2667},
}

#: Where the cost figures come from.
COST_SOURCES = (
    "generation, FBP, Dremel, RESESOP: benchmarks/README.md (paper-parallel measured; paper-fan generation and "
    "RESESOP scaled from the parallel figures by the measured forward-with-motion and Kaczmarz-sweep ratios); "
    "other sizes scaled by N*K*L, plus a per-sample overhead fitted to the tiny study's measured ~1 min",
    "UNet training: docs/results.md tiny run (5 runs of 40 epochs in 5 min 14 s, bfloat16, 2 threads) at N=63, "
    "benchmarks/README.md (5.5 images/s on 2 cores, float32) at N=255; invertible networks at N=63: the tiny run "
    "(20 runs of 12-32 epochs, 70,400 images, in 12 min 47 s, one at a time, bfloat16, the tiny study's light "
    "stacks); at N=255: 3 x the measured forward pass "
    "(benchmarks/README.md sampling table; backward assumed 2 forward), the paper's architectures; training in "
    "the other precision than the figure's (the tiny study's 'auto' takes fp32 on a CPU without native bfloat16): "
    "scaled by the fp32/bf16 step-time ratio measured on a CPU with it (docs/learn.md: UNet 2.0, invertible 1.4)",
    "prediction: UNet inference (channels_last, batch 16, benchmarks/README.md) and the per-latent-sample cost of "
    "the invertible networks (N=63: the tiny run's 45 predictions in 83 s; N=255: benchmarks/README.md), "
    "times the study's latent samples, over the test split and the calibration images (the calibration set, "
    "else the validation split); sizes between 63 and 255 scaled by pixel count from 255",
    "no GPU figure was measured: with --gpus, training and prediction use --gpu-speedup (one GPU relative to "
    "one CPU core) and stay unestimated without it",
)


@dataclass(frozen=True)
class StagePlan:
    """One stage of one setting in a plan.

    Attributes
    ----------
    setting, stage : str
        Output directory name of the setting and the stage (:data:`STAGES`).
    jobs : int
        Jobs of the stage (samples, reconstructions x samples, training runs, predictions).
    disk_bytes : int
        Disk the stage writes (float32 arrays; checkpoints and the report not counted).
    seconds : float or None
        Estimated wall time, None where no figure exists (GPU without a speed-up).
    precision : str or None
        Of the training stage: the precision its runs take on this machine
        (:func:`nanoct.learn.train.resolve_precision`).
    """

    setting: str
    stage: str
    jobs: int
    disk_bytes: int
    seconds: float | None
    precision: str | None = None


def _family(model: str) -> str:
    return "ciunet" if model.startswith("ciunet") else "cinn" if model.startswith("cinn") else "unet"


def _per_size(table: dict[int, dict[str, float]], n: int, model: str) -> float:
    """A per-image cost at size ``n``: measured at 63 or 255, else scaled by pixels from 255."""
    if n == 63:
        row = table[63]
        return row.get(model, row.get(_family(model), row.get("inn", 0.0)))
    return table[255][_family(model)] * (n / 255) ** 2


def _recon_costs(preset: str) -> dict[str, float]:
    g = get_preset(preset)
    base, ref = (_PAPER_FAN, (255, 133, 723)) if g.kind == "fan" else (_PAPER_PARALLEL, (255, 567, 363))
    ratio = g.n * g.n_angles * g.n_det / float(np.prod(ref))
    return {k: v * ratio + (_OVERHEAD if g.n < 255 else 0.0) for k, v in base.items()}


def _train_cost(n: int, model: str, precision: str) -> float:
    """Core-seconds per training image at size ``n`` in ``precision`` (the measured figure, scaled by
    :data:`_FP32_OVER_BF16` where it was measured in the other precision)."""
    ratio = _FP32_OVER_BF16["unet" if model == "unet" else "inn"]
    measured = _TRAIN_PRECISION.get(n, "fp32")
    factor = 1.0 if measured == precision else ratio if precision == "fp32" else 1 / ratio
    return _per_size(_TRAIN, n, model) * factor


def _setting_plan(
    setting: Setting,
    study: Study,
    models: tuple[str, ...],
    n: int | None,
    seeds: int,
    speed: dict[str, float | None],
    precision: str,
) -> list[StagePlan]:
    jobs = setting_jobs(setting, study, models, n, seeds)
    g = get_preset(setting.preset)
    labels = split_assignment(jobs.samples, 0, study.split_fractions)
    n_train, n_val, n_test = (int((labels == k).sum()) for k in (0, 1, 2))
    image, costs = 4 * g.n * g.n, _recon_costs(setting.preset)
    name = setting.out.name
    samples = jobs.samples + jobs.calibration  # the calibration set is simulated alike
    core_s = samples * costs["generate"]
    out = [StagePlan(name, "data", samples, samples * 4 * (g.n**2 + 2 * g.n_angles * g.n_det), core_s)]
    per_recon = {k: jobs.samples + (jobs.calibration if k in setting.train_inputs else 0) for k in setting.recons}
    core_s = sum(per_recon[k] * costs[method] for k, (method, _) in setting.recons.items())
    out.append(StagePlan(name, "reconstructions", sum(per_recon.values()), sum(per_recon.values()) * image, core_s))
    core_s = sum(study.epochs[m] * n_train * _train_cost(g.n, m, precision) for m, _, _ in jobs.train)
    out.append(StagePlan(name, "training", len(jobs.train), 0, core_s, precision))
    core_s = disk = 0.0
    for m, train_input, input_name, _ in jobs.predict:
        inn = model_class(m).has_uncertainty
        per_image = _per_size(_PREDICT, g.n, m) * (study.n_samples if inn else 1)
        calibrates = inn and input_name == train_input  # once per run; mixing predictions reuse the fit
        core_s += per_image * (n_test + ((jobs.calibration or n_val) if calibrates else 0))
        disk += n_test * image * (2 if inn else 1)
    out.append(StagePlan(name, "prediction", len(jobs.predict), int(disk), core_s))
    out.append(StagePlan(name, "report", 1, 0, 0.0))
    return [replace(p, seconds=None if speed[p.stage] is None else p.seconds / speed[p.stage]) for p in out]


def plan_study(
    scale: str | None,
    *,
    preset: str = "tiny-parallel",
    perturbed: bool = True,
    n: int | None = None,
    models: tuple[str, ...] | None = None,
    study: Study | None = None,
    seeds: int = 1,
    cores: int = 2,
    gpus: int = 0,
    gpu_speedup: float | None = None,
) -> list[StagePlan]:
    """The stages of ``nanoct reproduce --scale scale`` (or ``--preset preset`` when scale is None).

    Parameters
    ----------
    scale : str or None
        A key of :data:`nanoct.study.config.STUDIES` (its study: :func:`nanoct.study.config.scale_study`),
        or None for one preset.
    preset, perturbed, n
        The single setting when ``scale`` is None (``n`` only applies there).
    models, study, seeds
        As :func:`nanoct.study.runner.reproduce_scale`.
    cores : int
        CPU cores for every stage (and training/prediction without GPUs).
    gpus : int
        GPUs for training and prediction.
    gpu_speedup : float, optional
        One GPU's throughput relative to one CPU core; without it GPU stages have no estimate.

    Raises
    ------
    NanoctError
        If ``cores`` < 1, ``gpus`` < 0 or ``gpu_speedup`` <= 0, or the scale/preset is unknown.
    """
    if cores < 1 or gpus < 0 or (gpu_speedup is not None and not gpu_speedup > 0):
        raise NanoctError(f"--cores {cores} must be >= 1, --gpus {gpus} >= 0 and --gpu-speedup {gpu_speedup} > 0")
    if scale is None:
        models = check_models(models, preset_models(preset))
        study = study or preset_study(preset)
        settings = [preset_setting(preset, perturbed, None, study.mixing)]
    else:
        models = check_models(models)
        settings = scale_settings(scale)
        study = study or scale_study(scale)
    learn = float(cores) if gpus == 0 else (None if gpu_speedup is None else gpus * gpu_speedup)
    speed = {
        "data": float(cores),
        "reconstructions": float(cores),
        "training": learn,
        "prediction": learn,
        "report": 1.0,
    }
    precision = _planned_precision(study.precision, gpus)
    return [
        p
        for s in settings
        for p in _setting_plan(s, study, models, n if scale is None else None, seeds, speed, precision)
    ]


def _planned_precision(precision: str, gpus: int) -> str:
    """The precision the training runs take: on this machine's CPU, or on a GPU (``"auto"``: bf16)."""
    if gpus:
        return "bf16" if precision == "auto" else precision
    from ..learn.train import resolve_precision  # imports torch

    return resolve_precision(precision, "cpu")


def _duration(seconds: float | None) -> str:
    if seconds is None:
        return "? (no figure)"
    return f"{seconds:,.0f} s" + (f" ({seconds / 3600:.1f} h)" if seconds >= 3600 else "")


def format_plan(plan: list[StagePlan]) -> str:
    """The plan as a text table with totals, in seconds, and the sources of the figures."""
    lines = [f"{'setting':<14} {'stage':<16} {'jobs':>8} {'disk':>10}  estimated time", "-" * 72]
    for p in plan:
        stage = p.stage if p.precision is None else f"{p.stage} ({p.precision})"
        lines.append(f"{p.setting:<14} {stage:<16} {p.jobs:>8,} {p.disk_bytes / 1e9:>8.2f} GB  {_duration(p.seconds)}")
    known = [p.seconds for p in plan if p.seconds is not None]
    total = None if len(known) < len(plan) else sum(known)
    disk = sum(p.disk_bytes for p in plan)
    lines += ["-" * 72, f"{'total':<31} {'':>8} {disk / 1e9:>8.2f} GB  {_duration(total)}", "", "Figures:"]
    lines += [f"- {s}" for s in COST_SOURCES]
    return "\n".join(lines) + "\n"
