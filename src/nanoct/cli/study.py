"""Study commands: ``evaluate`` a data set's reconstructions, ``reproduce`` the paper's study, the
``shift-test`` of its invertible networks and the data-``scaling`` study."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from ..core.errors import NanoctError
from .options import QUIET, SCHEDULER, WORKERS
from .parsing import parse_models


def evaluate(
    directory: Path = typer.Argument(..., help="Data-set store."),
    split: str = typer.Option("test", "--split", help="Split to evaluate on."),
    out: Path | None = typer.Option(None, "--out", "-o", help="Directory for evaluation.md/json (default DIR/report)."),
    as_json: bool = typer.Option(False, "--json", help="Print evaluation.json instead of the Markdown tables."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Write the files, print nothing."),
) -> None:
    """PSNR/SSIM (mean ± std over a split, and per image) of every reconstruction in the store.

    Also the input-mixing tables (models applied to inputs they were not trained on), for
    sampling models the std/error correlation and calibration, and the paper's conclusions
    checked on the per-image values (paired differences) for the paper's setting of the store.
    """
    from ..evaluation.evaluate import store_setting, write_report_tables
    from ..io.store import DataStore
    from ..study.report import evaluate_rows

    store = DataStore.open(directory)
    scores = evaluate_rows(store, split, store_setting(store))
    if not scores.results:
        raise NanoctError(
            f"no reconstruction in {directory} covers the '{split}' split; run 'nanoct reconstruct' first"
        )
    md, js = write_report_tables(
        store,
        scores.results,
        out or Path(directory) / "report",
        split,
        conclusions=scores.checks,
        setting=scores.setting,
    )
    if not quiet:
        typer.echo(js.read_text() if as_json else md.read_text())
        typer.echo(f"wrote {md} and {js}", err=True)


def reproduce(
    preset: str = typer.Option(
        "tiny-parallel",
        "--preset",
        "-p",
        help="Study preset: a geometry preset name, or tiny-quick (a first result in minutes, docs/study.md).",
    ),
    scale: str | None = typer.Option(
        None, "--scale", help="Run the paper's three settings at a scale (tiny, small, paper) instead of one preset."
    ),
    out: Path | None = typer.Option(
        None, "--out", "-o", help="Output directory (default runs/<preset> or runs/<scale>)."
    ),
    n: int | None = typer.Option(None, "--n", help="Override the number of samples of the preset."),
    no_motion: bool = typer.Option(False, "--no-motion", help="The unperturbed sanity case."),
    models: str | None = typer.Option(
        None,
        "--models",
        help="Comma-separated post-processing networks, or 'none' (default: the preset's; tiny-quick: unet,ciunet-res; "
        "the others: unet,cinn,cinn-res,ciunet,ciunet-res).",
    ),
    seed: int = typer.Option(0, "--seed", help="Seed of the data set(s)."),
    seeds: int = typer.Option(1, "--seeds", help="Training seeds per network row (spread in the conclusion checks)."),
    precision: str | None = typer.Option(
        None,
        "--precision",
        help="Training precision fp32 | bf16 | auto (default: the study's; tiny: auto, i.e. bf16 where the CPU or "
        "GPU runs it natively, else fp32; small, paper: fp32).",
    ),
    plan: bool = typer.Option(False, "--plan", help="Print the stages, jobs, disk and time estimates; run nothing."),
    cores: int = typer.Option(2, "--cores", help="With --plan: CPU cores to plan for."),
    gpus: int = typer.Option(0, "--gpus", help="With --plan: GPUs for training and prediction."),
    gpu_speedup: float | None = typer.Option(
        None, "--gpu-speedup", help="With --plan and --gpus: one GPU's speed relative to one CPU core (not measured)."
    ),
    workers: int = WORKERS,
    scheduler: str | None = SCHEDULER,
    quiet: bool = QUIET,
) -> None:
    """Run the study end to end: generate, reconstruct, train, predict, evaluate, report.

    Every stage is cached in the output directory: a second run only redoes what is
    missing, and a killed run resumes. The report (Markdown and a self-contained HTML file)
    puts the paper's numbers next to ours and checks the paper's conclusions.
    """
    from ..study.runner import reproduce_scale, reproduce_study

    chosen = None if models is None else parse_models(models)
    if scale is not None and (n is not None or no_motion):
        raise NanoctError("--n and --no-motion apply to one --preset; --scale runs the study's three settings")
    study = _study_with_precision(scale, preset, precision)
    if plan:
        from ..study.plan import format_plan, plan_study

        typer.echo(
            format_plan(
                plan_study(
                    scale,
                    preset=preset,
                    perturbed=not no_motion,
                    n=n,
                    models=chosen,
                    study=study,
                    seeds=seeds,
                    cores=cores,
                    gpus=gpus,
                    gpu_speedup=gpu_speedup,
                )
            )
        )
        return
    run = dict(out=out, models=chosen, study=study, seed=seed, seeds=seeds, workers=workers, scheduler=scheduler)
    run["progress"] = not quiet
    precision_note(study.precision)
    if scale is not None:
        report = reproduce_scale(scale, **run)
    else:
        report = reproduce_study(preset, n=n, perturbed=not no_motion, **run)
    typer.echo(report.read_text())
    typer.echo(f"report: {report} (and {report.with_suffix('.html').name})", err=True)


def _study_with_precision(scale: str | None, preset: str, precision: str | None) -> Any:
    """The study of ``reproduce --scale``/``--preset``, with ``--precision`` where given."""
    from dataclasses import replace

    from ..study.config import preset_study, scale_study

    study = scale_study(scale) if scale is not None else preset_study(preset)
    if precision is None:
        return study
    from ..learn.train import check_precision

    return replace(study, precision=check_precision(precision, "--precision"))


def precision_note(precision: str) -> None:
    """Say which precision the training runs take here, and why where that is not bfloat16 natively."""
    from ..learn.train import native_bf16, resolve_device, resolve_precision

    device = resolve_device()
    taken, native = resolve_precision(precision, device), native_bf16(device)
    why = ""
    if taken == "bf16" and not native:
        why = f" (emulated on this {device.type.upper()}: 5-9x slower than fp32; --precision auto takes fp32 here)"
    elif precision == "auto" and taken == "fp32":
        why = (
            f" ({device.type.upper()} without native bfloat16, where bfloat16 steps are 5-9x slower); the tiny "
            "study's tables in docs/results.md were trained in bf16, so this run's networks and tables differ from "
            "them by training noise (docs/study.md)"
        )
    typer.echo(f"note: training precision {taken}{why}", err=True)


def shift_test(
    directory: Path = typer.Argument(..., help="Output directory of 'nanoct reproduce --preset ...'."),
    preset: str = typer.Option("tiny-parallel", "--preset", "-p", help="The study's preset."),
    n: int = typer.Option(20, "--n", help="Test images per shifted set."),
    workers: int = WORKERS,
    quiet: bool = QUIET,
) -> None:
    """Score a study's invertible networks on shifted test sets (motion x0.5 / x1.5, noise, none, other phantoms).

    Coverage of the 90 % intervals, correlation of the std with the error and the share of
    images predict flags as out of distribution, per shifted set next to the study's own test
    split; written to DIRECTORY/shift/shift.{md,json} (cached; a rerun only redoes what is missing).
    """
    from ..study.shift import format_shift_table, shift_study

    if n < 1:
        raise NanoctError(f"--n {n} must be a positive number of test images")
    results = shift_study(directory, preset, n=n, workers=workers, progress=not quiet)
    typer.echo(format_shift_table(results))


def scaling(
    out: Path = typer.Option(Path("runs/scaling"), "--out", "-o", help="Output directory of the study."),
    plan: bool = typer.Option(
        False,
        "--plan",
        help="Measure the per-sample and per-step costs here and print the cost of what is left; run nothing.",
    ),
    steps: int = typer.Option(640, "--steps", help="Optimiser steps of every run (the same at every size)."),
    sizes: str = typer.Option("160,640,2560", "--sizes", help="Comma-separated training-set sizes."),
    seeds: str = typer.Option("3,2,2", "--seeds", help="Training seeds at each size (comma-separated)."),
    only: str | None = typer.Option(
        None, "--only", help="Run only the units whose run name matches this shell pattern (e.g. 'unet-dremel-*')."
    ),
    workers: int = WORKERS,
    quiet: bool = QUIET,
) -> None:
    """Data-scaling study: UNet and CiUNetRes on FBP, Dremel and RESESOP (tiny-parallel) trained on
    growing nested training sets for a fixed number of steps, plus 4x the steps at the largest size.

    Resumable: every (network, input, size, seed) is a unit skipped once complete; a killed run
    continues with the same command. The report (report.md, report.json, scaling.png in --out)
    gives the gain over the input per size with the spread over seeds, the paper's gain and the
    paper's conclusion checks at each size.
    """
    from ..study.scaling import format_scaling_plan, plan_scaling, run_scaling
    from ..study.scaling_config import ScalingStudy

    try:
        study = ScalingStudy(
            sizes=tuple(int(v) for v in sizes.split(",")), seeds=tuple(int(v) for v in seeds.split(",")), steps=steps
        )
    except ValueError:
        raise NanoctError(f"--sizes {sizes!r} and --seeds {seeds!r} must be comma-separated integers") from None
    if plan:
        typer.echo(format_scaling_plan(plan_scaling(study, out), study))
        return
    report = run_scaling(out, study, only=only, workers=workers, progress=not quiet)
    typer.echo(report.read_text())
    typer.echo(f"report: {report}", err=True)
