"""Benchmark of two ways to train faster on a CPU in float32: ``torch.compile`` and two runs side by side.

For the UNet and each invertible network (the tiny study's ``model_kwargs``) one run measures the
float32 training step of :func:`bench_flows.bench_train` (batch 16, 63 x 63, channels_last) as the
tiny study trains, one run after another with 2 threads (the baseline), against

* the same step with the model's loss through ``torch.compile`` (inductor; compiled in a warm-up
  step whose seconds are printed), 2 threads, and
* two processes side by side, 1 thread each, the same step in both (the steps per second of both
  together),

and prints each as a ratio of the baseline's steps per second (above 1: faster).

    PYTHONPATH=src:benchmarks .venv/bin/python benchmarks/bench_cpu_training.py --repeat 8
"""

from __future__ import annotations

import multiprocessing as mp
import platform
import time

import torch

from bench_flows import bench_train, step_args
from nanoct.learn.models import table_order
from nanoct.study.config import STUDIES


def _step_seconds(name: str, size: int, batch: int, repeat: int, threads: int, compile: bool) -> tuple[float, float]:
    """In a fresh process: median seconds of one step, and the seconds of the warm-up (compile) step and the steps."""
    torch.set_num_threads(threads)
    t0 = time.perf_counter()
    t = bench_train(name, dict(STUDIES["tiny"].model_kwargs.get(name, {})), size, batch, repeat, compile=compile)
    return t, time.perf_counter() - t0


def rates(name: str, size: int, batch: int, repeat: int) -> tuple[float, float, float, float]:
    """Steps per second: 2 threads, 2 threads compiled (and its warm-up seconds), and two 1-thread processes side by
    side, together; each in fresh processes, one after another."""
    ctx = mp.get_context("spawn")
    with ctx.Pool(1) as pool:
        base, _ = pool.apply(_step_seconds, (name, size, batch, repeat, 2, False))
    with ctx.Pool(1) as pool:
        compiled, total = pool.apply(_step_seconds, (name, size, batch, repeat, 2, True))
    with ctx.Pool(2) as pool:
        both = pool.starmap(_step_seconds, [(name, size, batch, repeat, 1, False)] * 2)
    return 1 / base, 1 / compiled, total - (repeat + 1) * compiled, sum(1 / t for t, _ in both)


def main() -> None:
    a = step_args(__doc__.splitlines()[0], repeat=8, networks=table_order())
    print(f"# {platform.processor() or platform.machine()}, torch {torch.__version__}, "
          f"CPU capability {torch.backends.cpu.get_cpu_capability()}")  # fmt: skip
    print(f"# float32, {a.size} x {a.size}, batch {a.batch}, median of {a.repeat} steps; ratios to the baseline")
    print("network     | 2 threads steps/s | torch.compile steps/s (ratio, compile s) | 2 x 1 thread together (ratio)")
    for name in a.networks:
        base, compiled, warm, both = rates(name, a.size, a.batch, a.repeat)
        print(f"{name:11s} | {base:17.2f} | {compiled:6.2f} ({compiled / base:.2f}, {warm:.0f} s) | "
              f"{both:6.2f} ({both / base:.2f})")  # fmt: skip


if __name__ == "__main__":
    main()
