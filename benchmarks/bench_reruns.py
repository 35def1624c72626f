"""How long planning and cached reruns take, each against a baseline measured in the same run.

The tests check what a rerun does (nothing retrained: the checkpoints' modification times stay)
and what a plan contains; how long they take is measured here, where a loaded machine makes a
number noisy but never a failure:

* ``plan_study`` at each scale (tiny, small, paper) against the tiny plan: planning reads
  benchmark figures and counts jobs, so the paper's plan should cost about what the tiny one does
  (ratio near 1, whatever the study's size);
* the toy study of ``tests/study/test_reproduce.py`` (``reproduce_study``, UNet and cINN-res, one
  epoch each): the cached rerun and the rerun of the folder moved elsewhere against the first run
  (ratio well below 1: only the report is written again);
* the toy data-scaling study of ``tests/study/test_scaling.py`` (``run_scaling``): its rerun
  against the first run.

The tests asserted ``plan < 10 s`` and ``rerun < 30 s`` before; those limits are printed in the last
column for reference, not checked. Usage::

    PYTHONPATH=src .venv/bin/python benchmarks/bench_reruns.py            # all three
    PYTHONPATH=src .venv/bin/python benchmarks/bench_reruns.py --only plan
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
import warnings
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

#: The toy study of tests/study/test_reproduce.py (a copy: benchmarks do not import the tests).
TOY_MODELS = {
    "unet": {"channels": (4, 4, 4, 4, 4)},
    "cinn-res": dict(
        n_scales=3,
        blocks_per_scale=1,
        fc_dim=8,
        fc_blocks=1,
        cond_channels=4,
        cond_width=4,
        fc_cond_dim=8,
        hidden_ratio=1.0,
    ),
}


def _timed(fn: Callable[[], object]) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def _duration(seconds: float) -> str:
    return f"{seconds:8.2f} s " if seconds >= 1 else f"{seconds * 1e3:8.2f} ms"


def _row(what: str, seconds: float, baseline: float, limit: float | None = None) -> None:
    ratio = seconds / baseline if baseline > 0 else float("nan")
    old = f"{limit:.0f} s" if limit else ""
    print(f"{what:48s} | {_duration(seconds)} | {_duration(baseline)} | {ratio:7.3f} | {old}")


def bench_plan(repeat: int) -> None:
    from nanoct.study.plan import plan_study

    best = {
        s: min(_timed(lambda s=s: plan_study(s, cores=16)) for _ in range(repeat)) for s in ("tiny", "small", "paper")
    }
    for scale, seconds in best.items():
        _row(f"plan_study({scale!r}) vs the tiny plan", seconds, best["tiny"], 10)


def bench_reproduce(tmp: Path) -> None:
    from nanoct.study.config import Study
    from nanoct.study.runner import reproduce_study

    toy = Study(
        n=12,
        split_fractions=(0.5, 0.25, 0.25),
        epochs={"unet": 1, "cinn-res": 1},
        model_kwargs=TOY_MODELS,
        n_samples=3,
        mixing=("unet",),
        antithetic=True,
        scheduler={"cinn-res": "cosine"},
        precision="auto",
        n_calibration=4,
    )
    out, moved = tmp / "study", tmp / "moved"

    def run(folder: Path) -> None:
        reproduce_study("tiny-parallel", out=folder, models=("unet", "cinn-res"), study=toy, workers=0, progress=False)

    first = _timed(lambda: run(out))
    again = _timed(lambda: run(out))
    out.rename(moved)
    after_move = _timed(lambda: run(moved))
    _row("toy study: first run (the baseline)", first, first)
    _row("toy study: cached rerun vs the first run", again, first, 30)
    _row("toy study: rerun of the moved folder vs first", after_move, first)


def bench_scaling(tmp: Path) -> None:
    from nanoct.study.config import STUDIES
    from nanoct.study.scaling import ScalingStudy, run_scaling

    models = {
        "unet": {"channels": (4, 4, 4, 4, 4), "skip_channels": 4, "out_bias": -7.0},
        "ciunet-res": {"n_scales": 3, "blocks_per_scale": 1, "cond_channels": [4, 4, 4]},
    }
    toy = ScalingStudy(
        sizes=(4, 8),
        seeds=(2, 1),
        steps=2,
        long_factor=2,
        n_val=2,
        n_test=3,
        inputs=("fbp", "dremel"),
        base=replace(STUDIES["tiny"], model_kwargs=models, n_samples=2),
    )
    out = tmp / "scaling"
    first = _timed(lambda: run_scaling(out, toy, workers=0, progress=False))
    again = _timed(lambda: run_scaling(out, toy, workers=0, progress=False))
    _row("toy scaling study: first run (the baseline)", first, first)
    _row("toy scaling study: rerun vs the first run", again, first, 30)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", choices=("plan", "reproduce", "scaling"), action="append")
    p.add_argument("--repeat", type=int, default=3, help="best of this many plans per scale")
    a = p.parse_args()
    only = a.only or ["plan", "reproduce", "scaling"]
    warnings.filterwarnings("ignore", category=UserWarning)  # the toy sets are too small for the OOD checks
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} cores, 1-minute load {load:.2f}")
    print(f"{'measurement':48s} | {'time':>11s} | {'baseline':>11s} | {'ratio':>7s} | old test limit")
    with tempfile.TemporaryDirectory() as tmp:
        if "plan" in only:
            bench_plan(a.repeat)
        if "reproduce" in only:
            bench_reproduce(Path(tmp))
        if "scaling" in only:
            bench_scaling(Path(tmp))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"# 1-minute load after the run {load:.2f}")


if __name__ == "__main__":
    main()
