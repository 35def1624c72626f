"""Benchmark of the conditional invertible networks at the tiny study's size: old vs new configuration.

For each invertible network (cinn, cinn-res, ciunet, ciunet-res) one run measures, with the same
threads and inputs:

* training steps per second (forward NLL + backward + gradient clipping + Adam step, batch 16,
  63 x 63, the trainer's memory format: channels_last on CPU), and
* seconds per image to draw the study's latent samples for the mean and std (``reconstruct``),

for the "old" configuration (additive couplings everywhere, the paper's
conditioner widths) and the "new" one (the tiny study's ``model_kwargs`` in
:data:`nanoct.study.config.STUDIES`), and prints the ratio new/old of the step rate.

    PYTHONPATH=src .venv/bin/python benchmarks/bench_flows.py --threads 1 --repeat 5
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from typing import Any

import torch

from nanoct.learn.models import build_model
from nanoct.study.config import STUDIES

NETWORKS = ("cinn", "cinn-res", "ciunet", "ciunet-res")
#: The earlier tiny-study architecture (additive couplings everywhere), the baseline of the comparison.
OLD = {"cinn": {"blocks_per_scale": 2}, "ciunet": {"blocks_per_scale": 1}}


def _old(name: str) -> dict[str, Any]:
    return dict(OLD[name.removesuffix("-res")])


def bench_train(
    name: str, kwargs: dict[str, Any], size: int, batch: int, repeat: int, bf16: bool = False, compile: bool = False
) -> float:
    """Median seconds of one training step (``bf16``: the forward pass under bfloat16 autocast; ``compile``: the
    loss through ``torch.compile``, compiled in the warm-up step)."""
    torch.manual_seed(0)
    model = build_model(name, **kwargs).to(memory_format=torch.channels_last)
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    g = torch.Generator().manual_seed(0)
    x = torch.rand(batch, 1, size, size, generator=g).contiguous(memory_format=torch.channels_last)
    x_tilde = (x + 0.05 * torch.randn(x.shape, generator=g)).contiguous(memory_format=torch.channels_last)
    model.train()
    if hasattr(model, "data_init"):  # the flows' data-dependent ActNorm start
        model.data_init(x_tilde, x)
    loss_fn = torch.compile(model.loss) if compile else model.loss

    def step() -> None:
        opt.zero_grad(set_to_none=True)
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            loss, _ = loss_fn(x_tilde, x)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()

    step()  # warm-up
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        step()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_sample(name: str, kwargs: dict[str, Any], size: int, n_samples: int) -> float:
    """Seconds for the mean and std of one image from ``n_samples`` latent samples."""
    torch.manual_seed(0)
    model = build_model(name, **kwargs).to(memory_format=torch.channels_last).eval()
    x_tilde = torch.rand(1, 1, size, size).contiguous(memory_format=torch.channels_last)
    model.reconstruct(x_tilde, n_samples=2, seed=0)  # warm-up
    t0 = time.perf_counter()
    model.reconstruct(x_tilde, n_samples=n_samples, seed=0)
    return time.perf_counter() - t0


def step_args(description: str, repeat: int, networks: tuple[str, ...] = NETWORKS) -> argparse.Namespace:
    """The command line of the training-step benchmarks (size, batch, repeat, threads, networks);
    sets torch's thread count."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--size", type=int, default=63)
    p.add_argument("--batch", type=int, default=16)
    p.add_argument("--repeat", type=int, default=repeat)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--networks", nargs="+", default=list(networks))
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    return a


def main() -> None:
    a = step_args(__doc__.splitlines()[0], repeat=5)
    study = STUDIES["tiny"]
    print(f"# {platform.processor() or platform.machine()}, torch {torch.__version__}, {a.threads} thread(s)")
    print(f"# {a.size} x {a.size}, batch {a.batch}, median of {a.repeat} steps; sampling {study.n_samples} samples")
    print("network     | old steps/s | new steps/s | new/old | old s/img | new s/img")
    for name in a.networks:
        old, new = _old(name), dict(study.model_kwargs.get(name, {}))
        t_old, t_new = (bench_train(name, kw, a.size, a.batch, a.repeat) for kw in (old, new))
        s_old, s_new = (bench_sample(name, kw, a.size, study.n_samples) for kw in (old, new))
        print(
            f"{name:11s} | {1 / t_old:11.2f} | {1 / t_new:11.2f} | {t_old / t_new:7.2f} | {s_old:9.2f} | {s_new:9.2f}"
        )


if __name__ == "__main__":
    main()
