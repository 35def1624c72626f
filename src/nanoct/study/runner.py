"""The whole study from one call: generate, reconstruct, train, predict, evaluate, report.

:func:`reproduce_study` runs one setting (a geometry preset, perturbed or not);
:func:`reproduce_scale` runs the paper's three settings with the paper's rows. Both run
:func:`run_setting`: the stages of :mod:`nanoct.study.stages` (data, reconstructions, training,
prediction) and the report of :mod:`nanoct.study.report`, over the jobs that
:func:`nanoct.study.config.setting_jobs` lists (which :mod:`nanoct.study.plan` prices without
running them). Every stage is cached in the output directory, so a second run only redoes what is
missing and a killed run resumes; tables and figures are cheap and redone.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

from ..io.fileio import atomic_write_text
from ..io.provenance import environment_info, format_environment
from .config import (
    DEFAULT_SEED,
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
from .report import SettingSections, format_duration, report_stage
from .report_html import write_html_report
from .stages import data_stage, prediction_stage, reconstruction_stage, training_stage

__all__ = ["reproduce_scale", "reproduce_study", "run_setting"]


def run_setting(
    setting: Setting,
    study: Study,
    models: tuple[str, ...],
    *,
    n: int | None = None,
    seed: int = DEFAULT_SEED,
    seeds: int = 1,
    fan: dict[str, Any],
) -> tuple[Path, SettingSections]:
    """Every stage of one setting in order, timed; see :func:`report_stage` for what it returns."""
    jobs = setting_jobs(setting, study, models, n, seeds)
    seconds: dict[str, float] = {}
    stages: dict[str, Callable[[], object]] = {
        "data": partial(data_stage, setting, study, jobs, seed, fan),
        "reconstructions": partial(reconstruction_stage, setting, jobs, fan),
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
        Geometry preset (``tiny-parallel``, ``paper-fan``, ...), whose size prefix picks the
        scale in :data:`STUDIES`, or a study preset of :data:`STUDY_PRESETS` (``tiny-quick``).
    out : path, optional
        Output directory (default ``runs/<preset>``, ``-nomotion`` / ``-seed<S>`` appended where
        they apply): the data set is ``<out>/data``, training runs ``<out>/runs/<model>-<input>``,
        the report ``<out>/report`` (``report.md``, ``report.html``, ``evaluation.json``).
    n : int, optional
        Number of samples instead of the scale's default.
    perturbed : bool
        False gives the unperturbed sanity case.
    models : tuple of str, optional
        Post-processing networks to train (default: a study preset's, else all of
        :data:`nanoct.learn.models.MODELS`; ``()`` for none).
    study : Study, optional
        Scale settings instead of the preset's entry in :data:`STUDIES`.
    seed : int
        Seed of the data set.
    seeds : int
        Training seeds per network row (the conclusion checks add their spread).
    workers, scheduler, progress
        See :func:`nanoct.core.fanout.run_tasks`.
    """
    models = check_models(models, preset_models(preset))
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
        text += sections.for_scale_report() + [
            f"Full report of this setting: [{md.relative_to(root)}]({md.relative_to(root)})",
            "",
        ]
        evaluation = json.loads((md.parent / "evaluation.json").read_text())
        summary["settings"][setting.paper] = {
            "report": str(md.relative_to(root)),
            "stage_seconds": json.loads((md.parent / "stage_seconds.json").read_text()),
        } | {k: evaluation[k] for k in ("results", "mixing", "conclusions")}
    summary["seconds"] = time.perf_counter() - t0
    text.insert(
        3,
        f"\nWall time of this run: {format_duration(summary['seconds'])} (stages completed by an earlier run: ~0 s).\n",
    )
    atomic_write_text(root / "report.json", json.dumps(summary, indent=2))
    report = atomic_write_text(root / "report.md", "\n".join(text))
    write_html_report(report)
    return report
