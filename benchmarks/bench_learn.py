"""Benchmark of the post-processing UNet: training throughput and inference time per image.

Measures, for each image size, one training step (forward + MSE backward + Adam step) on a
batch of 16 and inference (eval mode, no_grad) per image, with the paper's UNet (5 scales,
32-128 channels). Baseline in the same run: contiguous (NCHW) memory format against the
channels_last format the trainer uses on CPU. On CUDA both formats are measured as well.

    .venv/bin/python benchmarks/bench_learn.py --sizes 63 255 --repeat 5
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

import torch

from nanoct.learn.unet import UNetPost


def _sync(dev: torch.device) -> None:
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)


def bench(size: int, batch: int, dev: torch.device, channels_last: bool, repeat: int, warmup: int) -> dict[str, float]:
    torch.manual_seed(0)
    fmt = torch.channels_last if channels_last else torch.contiguous_format
    model = UNetPost().to(dev, memory_format=fmt)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    x_tilde = torch.rand(batch, 1, size, size, device=dev).contiguous(memory_format=fmt)
    x = torch.rand(batch, 1, size, size, device=dev).contiguous(memory_format=fmt)

    def step() -> None:
        opt.zero_grad(set_to_none=True)
        loss, _ = model.loss(x_tilde, x)
        loss.backward()
        opt.step()

    model.eval()
    times = []
    with torch.no_grad():
        for i in range(warmup + 2 * repeat):
            _sync(dev)
            t = time.perf_counter()
            model.reconstruct(x_tilde)
            _sync(dev)
            if i >= warmup:
                times.append(time.perf_counter() - t)
    infer_s = statistics.median(times)

    model.train()
    times = []
    for i in range(warmup + repeat):
        _sync(dev)
        t = time.perf_counter()
        step()
        _sync(dev)
        if i >= warmup:
            times.append(time.perf_counter() - t)
    train_s = statistics.median(times)
    return {"train_img_s": batch / train_s, "step_s": train_s, "infer_ms_img": 1e3 * infer_s / batch}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[63, 255])
    p.add_argument("--batch", type=int, default=16)
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--warmup", type=int, default=2)
    p.add_argument("--device", default=None, help="cpu or cuda (default: both where available)")
    a = p.parse_args()
    devices = (
        [torch.device(a.device)]
        if a.device
        else [torch.device("cpu")] + ([torch.device("cuda")] if torch.cuda.is_available() else [])
    )
    print(
        f"torch {torch.__version__}, {platform.processor() or platform.machine()}, threads {torch.get_num_threads()}, "
        f"cuda {torch.cuda.get_device_name(0) if torch.cuda.is_available() else 'none'}"
    )
    print(
        f"UNetPost paper architecture: {sum(q.numel() for q in UNetPost().parameters()):,} "
        f"parameters, batch {a.batch}, "
        f"median of {a.repeat} training steps / {2 * a.repeat} inference batches after {a.warmup} "
        "warm-up; inference measured first on a fresh model"
    )
    print("| device | N | format | train step (s) | train images/s | inference ms/image |")
    print("|---|---|---|---|---|---|")
    for dev in devices:
        for n in a.sizes:
            res = {}
            for cl in (False, True):
                r = bench(n, a.batch, dev, cl, a.repeat, a.warmup)
                res[cl] = r
                name = "channels_last" if cl else "contiguous"
                print(
                    f"| {dev.type} | {n} | {name} | {r['step_s']:.3f} | {r['train_img_s']:.1f} | "
                    f"{r['infer_ms_img']:.2f} |",
                    flush=True,
                )
            print(
                f"| {dev.type} | {n} | ratio cl/contig | | "
                f"{res[True]['train_img_s'] / res[False]['train_img_s']:.2f}x | "
                f"{res[False]['infer_ms_img'] / res[True]['infer_ms_img']:.2f}x |",
                flush=True,
            )


if __name__ == "__main__":
    main()
