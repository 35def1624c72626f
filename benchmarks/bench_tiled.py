"""Tiled prediction of a large slice: time and peak memory, against the untiled cost of the same tiles.

The tiny study's CiUNetRes (its architecture arguments, trained weights with --checkpoint, else a
freshly built network: the cost does not depend on the weights) predicts an N x N slice (default
2048) in tiles of the size it was trained on (63) with M latent samples in antithetic pairs
(default 16), as ``nanoct predict --tile 0`` does. Baseline in the same run: the untiled network on
a batch of single 63 x 63 images, its time per image times the number of tiles (the cost of the
tiles alone, without overlap bookkeeping and blending). Prints the wall time, the ratio to the
baseline and the process's peak resident memory.

    PYTHONPATH=src python benchmarks/bench_tiled.py [--size 2048] [--samples 16] [--checkpoint RUN/best.pt]
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np
import torch

from nanoct.learn.calibration import Inference
from nanoct.learn.checkpoint import load_checkpoint, model_from_checkpoint
from nanoct.learn.models import build_model
from nanoct.learn.tiling import DEFAULT_MARGIN, predict_tiled, tile_starts
from nanoct.study.config import STUDIES


def _peak_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=2048)
    parser.add_argument("--samples", type=int, default=16)
    parser.add_argument("--tile", type=int, default=63)
    parser.add_argument("--overlap", type=int, default=16)
    parser.add_argument("--batch", type=int, default=16, help="tiles per network call")
    parser.add_argument("--checkpoint", default=None)
    parser.add_argument(
        "--stitch-only",
        action="store_true",
        help="a pointwise stand-in for the network: the time and memory of the tiling and blending alone",
    )
    args = parser.parse_args()
    if args.stitch_only:
        slice_ = np.random.default_rng(0).uniform(0, 1, (args.size, args.size)).astype(np.float32)
        t0 = time.perf_counter()
        mean, std = predict_tiled(slice_, lambda x, s: (x, 0.1 * x), args.tile, overlap=args.overlap, batch=args.batch)
        wall = time.perf_counter() - t0
        np.testing.assert_allclose(mean, slice_, rtol=1e-5)
        print(f"stitching alone, {args.size}^2: {wall:.1f} s, peak resident memory {_peak_gb():.2f} GB")
        return
    if args.checkpoint:
        model = model_from_checkpoint(load_checkpoint(args.checkpoint), args.checkpoint)
    else:
        torch.manual_seed(0)
        model = build_model("ciunet-res", **STUDIES["tiny"].model_kwargs["ciunet-res"])
    infer = Inference(model, {"n_samples": args.samples, "antithetic": True}, True, "cpu")
    rng = np.random.default_rng(0)
    n_tiles = len(tile_starts(args.size, args.tile, args.overlap)) ** 2
    print(
        f"torch threads {torch.get_num_threads()}, {args.size}^2 slice, {n_tiles} tiles of {args.tile}^2, "
        f"M = {args.samples}, peak before {_peak_gb():.2f} GB"
    )
    # baseline: untiled batches of single training-size images
    images = rng.uniform(0, 1, (args.batch, args.tile, args.tile)).astype(np.float32)
    infer(images[:2], 0)  # warm-up
    t0 = time.perf_counter()
    reps = 3
    for k in range(reps):
        infer(images, k)
    per_image = (time.perf_counter() - t0) / (reps * args.batch)
    baseline = per_image * n_tiles
    print(f"baseline: {per_image * 1e3:.1f} ms per {args.tile}^2 image -> {baseline:.1f} s for {n_tiles} tiles")
    slice_ = rng.uniform(0, 1, (args.size, args.size)).astype(np.float32)
    t0 = time.perf_counter()
    mean, std = predict_tiled(
        slice_, infer, args.tile, overlap=args.overlap, margin=DEFAULT_MARGIN, batch=args.batch, seed=1, progress=True
    )
    wall = time.perf_counter() - t0
    assert mean.shape == (args.size, args.size) and std is not None and np.isfinite(std).all()
    print(f"tiled: {wall:.1f} s ({wall / baseline:.2f} x baseline), peak resident memory {_peak_gb():.2f} GB")


if __name__ == "__main__":
    main()
