"""Benchmark of training-step speed in float32 vs bfloat16 autocast, the tiny study's networks.

For the UNet and each invertible network (the tiny study's ``model_kwargs`` in
:data:`nanoct.study.config.STUDIES`) one run measures, with the same threads and inputs, the median
seconds of one training step (the model's loss, backward, gradient clipping, Adam; batch 16,
63 x 63, channels_last as the trainer uses on CPU) with ``precision="fp32"`` and with the forward
pass under ``torch.autocast(dtype=torch.bfloat16)`` as :func:`nanoct.learn.train.train` runs it
for ``precision="bf16"``, and prints the ratio of the step rates.

    PYTHONPATH=src .venv/bin/python benchmarks/bench_precision.py --threads 2 --repeat 10
"""

from __future__ import annotations

import platform

import torch

from bench_flows import bench_train, step_args  # the same step, timed the same way
from nanoct.learn.models import table_order
from nanoct.study.config import STUDIES


def main() -> None:
    a = step_args(__doc__.splitlines()[0], repeat=10, networks=table_order())
    study = STUDIES["tiny"]
    bf16_native = torch.ops.mkldnn._is_mkldnn_bf16_supported()
    print(f"# {platform.processor() or platform.machine()}, torch {torch.__version__}, {a.threads} thread(s)")
    print(f"# oneDNN native bfloat16: {bf16_native}; {a.size} x {a.size}, batch {a.batch}, median of {a.repeat} steps")
    print("network     | fp32 steps/s | bf16 steps/s | bf16/fp32")
    for name in a.networks:
        kwargs = dict(study.model_kwargs.get(name, {}))
        t32, t16 = (bench_train(name, kwargs, a.size, a.batch, a.repeat, bf16=bf16) for bf16 in (False, True))
        print(f"{name:11s} | {1 / t32:12.2f} | {1 / t16:12.2f} | {t32 / t16:9.2f}")


if __name__ == "__main__":
    main()
