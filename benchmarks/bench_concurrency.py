"""Benchmark: two training runs side by side in separate processes vs one after another.

``nanoct reproduce`` runs training and prediction jobs one after another in its own process on a
local machine (all cores as torch threads) and fans them out over Dask workers only on a cluster.
This script measures why, on the machine it runs on: it builds a small tiny-parallel data set
with FBP inputs in a temporary folder, then times ``epochs`` epochs of one network

* alone, with all cores as torch threads (the study's local mode), twice one after another, and
* two runs at the same time in two processes with one torch thread each (the worker mode),

and prints the wall time of both ways of doing the same two runs and their ratio.

    PYTHONPATH=src .venv/bin/python benchmarks/bench_concurrency.py --model cinn-res --epochs 3
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import platform
import tempfile
import time
from pathlib import Path

import torch

from nanoct.core.geometry import get_preset
from nanoct.recon.batch import reconstruct_dataset
from nanoct.sim.generate import generate_dataset
from nanoct.study.config import STUDIES


def _train(store: str, model: str, out: str, epochs: int, threads: int) -> None:
    from nanoct.learn.train import TrainConfig, train

    torch.set_num_threads(threads)
    study = STUDIES["tiny"]
    train(
        store,
        out,
        TrainConfig(
            model,
            "fbp",
            epochs=epochs,
            lr=study.lr.get(model),
            model_kwargs=study.model_kwargs.get(model),
            precision=study.precision,
        ),
        progress=False,
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default="cinn-res")
    p.add_argument("--epochs", type=int, default=3)
    p.add_argument("--n", type=int, default=200, help="samples (80 %% train, as the tiny study)")
    a = p.parse_args()
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    with tempfile.TemporaryDirectory() as tmp:
        store = str(Path(tmp) / "data")
        generate_dataset(store, get_preset("tiny-parallel"), a.n, seed=0, workers=0, progress=False)
        reconstruct_dataset(store, "fbp", workers=0, progress=False)
        ctx = mp.get_context("spawn")

        def run(name: str, threads: int) -> mp.Process:
            proc = ctx.Process(target=_train, args=(store, a.model, str(Path(tmp) / name), a.epochs, threads))
            proc.start()
            return proc

        def wait(proc: mp.Process) -> None:
            proc.join()
            if proc.exitcode:
                raise SystemExit(f"a training process failed (exit code {proc.exitcode}); no timing")

        t0 = time.perf_counter()
        for name in ("serial-a", "serial-b"):
            wait(run(name, cores))
        serial = time.perf_counter() - t0
        t0 = time.perf_counter()
        procs = [run(name, 1) for name in ("side-a", "side-b")]
        for proc in procs:
            wait(proc)
        side = time.perf_counter() - t0
    print(f"# {platform.processor() or platform.machine()}, {cores} cores, torch {torch.__version__}")
    print(f"# {a.model}, {a.epochs} epochs on {a.n} tiny-parallel samples, the tiny study's settings")
    print("# (each run in its own process; process start and data loading included)")
    print(f"two runs one after another, {cores} threads each: {serial:7.1f} s")
    print(f"two runs side by side, 1 thread each:           {side:7.1f} s")
    print(f"side by side / one after another: {side / serial:.2f}")


if __name__ == "__main__":
    main()
