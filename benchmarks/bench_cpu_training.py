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

With ``--settings`` it measures instead what the process settings do to the same 2-thread step,
settings that leave the weights' bits alone: glibc's malloc as it is against
:func:`nanoct.learn.train.keep_freed_memory`, and libgomp's default wait policy (spinning) against
``OMP_WAIT_POLICY=PASSIVE``; each variant in a fresh process, the variants interleaved over
``--rounds`` rounds (on a shared machine the load changes from minute to minute), with the wall
and CPU seconds, the system seconds and page faults per step, the machine's 1-minute load and a
checksum of the weights after the steps (equal checksums: the same bits).

    PYTHONPATH=src:benchmarks .venv/bin/python benchmarks/bench_cpu_training.py --settings --repeat 20 \
        --rounds 2 --networks unet ciunet-res
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import platform
import resource
import statistics
import subprocess
import sys
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


#: ``--settings`` variants: name -> (environment added, keep_freed_memory called).
SETTINGS = {
    "default": ({}, False),
    "keep_freed_memory": ({}, True),
    "OMP_WAIT_POLICY=PASSIVE": ({"OMP_WAIT_POLICY": "PASSIVE"}, False),
    "both": ({"OMP_WAIT_POLICY": "PASSIVE"}, True),
}


def settings_child(name: str, repeat: int, keep: bool) -> dict[str, float | str]:
    """In this (fresh) process: ``repeat`` 2-thread float32 steps of ``name`` after 3 warm-up steps, as the
    tiny study trains (bench_flows.bench_train's step); wall, CPU and faults of the steps only."""
    from nanoct.learn.models import build_model
    from nanoct.learn.train import keep_freed_memory

    if keep:
        assert keep_freed_memory()
    torch.set_num_threads(2)
    torch.manual_seed(0)
    model = build_model(name, **STUDIES["tiny"].model_kwargs.get(name, {})).to(memory_format=torch.channels_last)
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    g = torch.Generator().manual_seed(0)
    x = torch.rand(16, 1, 63, 63, generator=g).contiguous(memory_format=torch.channels_last)
    x_tilde = (x + 0.05 * torch.randn(x.shape, generator=g)).contiguous(memory_format=torch.channels_last)
    model.train()
    if hasattr(model, "data_init"):
        model.data_init(x_tilde, x)

    def step() -> None:
        opt.zero_grad(set_to_none=True)
        loss, _ = model.loss(x_tilde, x)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()

    for _ in range(3):
        step()
    r0, times = resource.getrusage(resource.RUSAGE_SELF), []
    for _ in range(repeat):
        t0 = time.perf_counter()
        step()
        times.append(time.perf_counter() - t0)
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    cpu = r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime
    return {
        "wall": statistics.median(times),
        "cpu": cpu / repeat,
        "sys": (r1.ru_stime - r0.ru_stime) / repeat,
        "faults": (r1.ru_minflt - r0.ru_minflt) / repeat,
        "load": float(os.getloadavg()[0]),
        "weights": repr(sum(float(p.detach().double().sum()) for p in model.parameters())),
    }


def settings_main(networks: list[str], repeat: int, rounds: int) -> None:
    """The ``--settings`` table: every variant of :data:`SETTINGS` per network, interleaved over ``rounds``."""
    print(f"# 2 threads, float32, 63 x 63, batch 16, median of {repeat} steps after 3; fresh process per cell")
    print("round | network | setting | s/step | CPU s/step | sys s/step | faults/step | load | weights")
    # libgomp's default, whatever this process was given (importing nanoct.study sets PASSIVE where it is unset)
    base = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    for r in range(1, rounds + 1):
        for name in networks:
            for label, (env, keep) in SETTINGS.items():
                out = subprocess.run(
                    [sys.executable, __file__, "--settings-child", name, str(repeat), str(int(keep))],
                    env=base | env,
                    capture_output=True,
                    text=True,
                    check=True,
                ).stdout
                m = json.loads(out.strip().splitlines()[-1])
                print(f"{r} | {name} | {label} | {m['wall']:.3f} | {m['cpu']:.3f} | {m['sys']:.4f} | "
                      f"{m['faults']:,.0f} | {m['load']:.2f} | {m['weights']}", flush=True)  # fmt: skip


def main() -> None:
    if len(sys.argv) == 5 and sys.argv[1] == "--settings-child":
        print(json.dumps(settings_child(sys.argv[2], int(sys.argv[3]), bool(int(sys.argv[4])))))
        return
    settings = "--settings" in sys.argv
    rounds = 2
    if settings:
        sys.argv.remove("--settings")
        if "--rounds" in sys.argv:
            i = sys.argv.index("--rounds")
            rounds = int(sys.argv[i + 1])
            del sys.argv[i : i + 2]
    a = step_args(__doc__.splitlines()[0], repeat=8, networks=table_order())
    if settings:
        settings_main(a.networks, a.repeat, rounds)
        return
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
