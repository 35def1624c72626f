"""Sampling cost of the conditional invertible networks: ms per sample per image.

Usage::

    python benchmarks/bench_sampling.py [--models cinn ciunet] [--sizes 63 255] [--samples 16]
        [--chunks 1 8 0] [--threads 1] [--repeat 2]

For every model (paper-default architecture, untrained: the cost does not depend on the weights)
and image size it times, on CPU:

* one density-direction pass (``model(x, x_tilde)``: conditioner + flow, one image) -- the
  baseline one sample is compared with;
* ``reconstruct(x_tilde, n_samples=M, chunk=c)`` for each chunk size c (0 = one single chunk of
  all M samples), reported as ms per sample per image, and as a ratio to the single-chunk run
  and to the forward pass.

The conditioner runs once per image; each chunk runs the inverse flow on ``chunk`` latent samples
with the condition features repeated, so memory is bounded by the chunk size.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from nanoct.learn.cinn import CiNN, CiNNRes
from nanoct.learn.ciunet import CiUNet, CiUNetRes

MODELS = {"cinn": CiNN, "cinn-res": CiNNRes, "ciunet": CiUNet, "ciunet-res": CiUNetRes}


def _time(fn, repeat: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--models", nargs="+", default=["cinn", "ciunet"], choices=sorted(MODELS))
    ap.add_argument("--sizes", nargs="+", type=int, default=[63, 255])
    ap.add_argument("--samples", type=int, default=16, help="M latent samples per image")
    ap.add_argument("--chunks", nargs="+", type=int, default=[1, 8, 0], help="0 = all M in one chunk")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    print(f"torch {torch.__version__}, {args.threads} thread(s), M = {args.samples}, median of {args.repeat}")
    print(f"{'model':<11}{'N':>5}{'chunk':>7}{'ms/sample/img':>15}{'vs 1 chunk':>12}{'vs fwd pass':>13}")
    for name in args.models:
        for n in args.sizes:
            model = MODELS[name]().eval()
            x = torch.rand(1, 1, n, n)
            x_tilde = x + 0.05 * torch.randn_like(x)
            with torch.no_grad():
                model(x, x_tilde)  # ActNorm initialisation
                fwd = _time(lambda: model(x, x_tilde), args.repeat)
            print(f"{name:<11}{n:>5}{'fwd':>7}{1e3 * fwd:>15.1f}{'':>12}{1.0:>13.2f}")
            results = {}
            for c in args.chunks:
                chunk = args.samples if c == 0 else c
                t = _time(lambda: model.reconstruct(x_tilde, n_samples=args.samples, chunk=chunk), args.repeat)
                results[c] = t / args.samples
            single = results.get(0, min(results.values()))
            for c, per in results.items():
                label = f"{args.samples}" if c == 0 else str(c)
                print(f"{name:<11}{n:>5}{label:>7}{1e3 * per:>15.1f}{per / single:>12.2f}{per / fwd:>13.2f}")


if __name__ == "__main__":
    main()
