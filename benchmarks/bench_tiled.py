"""Tiled prediction of a large slice: time and peak memory, parallel tile workers against torch's own threads.

The tiny study's CiUNetRes (its architecture arguments, trained weights with --checkpoint, else a
freshly built network: the cost does not depend on the weights) predicts an N x N slice (default
2048) in tiles of the size it was trained on (63) with M latent samples in antithetic pairs
(default 16), as ``nanoct predict --tile 0`` does.

Old and new in the same run, on a smaller slice first (``--compare-size``, default 256), alternated
``--repeats`` times: the old path calls the network on one batch of tiles at a time with torch's
intra-op threads; the new path (:func:`nanoct.learn.tiling.parallel_tiles`) runs as many
single-threaded calls at once as torch has threads. The two outputs must agree to 1e-5 (float32
rounding: the thread count changes the convolutions' summation order).
Then the new path on the full slice (``--full-old``: the old path too), with the wall time, the
time per tile, the ratio to the old path's time per tile and the process's peak resident memory.
The load average is printed with every timing (a shared machine inflates all of them).

    PYTHONPATH=src python benchmarks/bench_tiled.py [--size 2048] [--samples 16] [--checkpoint RUN/best.pt]
"""

from __future__ import annotations

import argparse
import os
import resource
import time
from collections.abc import Callable

import numpy as np
import torch

from nanoct.learn.calibration import Inference
from nanoct.learn.checkpoint import load_checkpoint, model_from_checkpoint
from nanoct.learn.models import build_model
from nanoct.learn.tiling import DEFAULT_MARGIN, parallel_tiles, predict_tiled, tile_starts
from nanoct.study.config import STUDIES


def _peak_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def _load() -> str:
    return "load average " + " / ".join(f"{v:.1f}" for v in os.getloadavg())


def _tiled(slice_: np.ndarray, infer: Callable, args: argparse.Namespace, parallel: bool, progress: bool = False):
    """(mean, std, wall seconds, CPU seconds) of one tiled prediction by the old or the new path."""
    t0, c0 = time.perf_counter(), time.process_time()
    kwargs = dict(overlap=args.overlap, margin=DEFAULT_MARGIN, batch=args.batch, seed=1, progress=progress)
    if parallel:
        with parallel_tiles("cpu") as workers:
            mean, std = predict_tiled(slice_, infer, args.tile, workers=workers, **kwargs)
    else:
        mean, std = predict_tiled(slice_, infer, args.tile, **kwargs)
    return mean, std, time.perf_counter() - t0, time.process_time() - c0


def _stitch_only(args: argparse.Namespace) -> None:
    slice_ = np.random.default_rng(0).uniform(0, 1, (args.size, args.size)).astype(np.float32)
    t0 = time.perf_counter()
    mean, std = predict_tiled(slice_, lambda x, s: (x, 0.1 * x), args.tile, overlap=args.overlap, batch=args.batch)
    wall = time.perf_counter() - t0
    np.testing.assert_allclose(mean, slice_, rtol=1e-5)
    print(f"stitching alone, {args.size}^2: {wall:.1f} s, peak resident memory {_peak_gb():.2f} GB")


def _compare(infer: Callable, args: argparse.Namespace, rng: np.random.Generator) -> float:
    """Old and new path alternated on a ``--compare-size`` slice; returns the old path's seconds per tile."""
    small = rng.uniform(0, 1, (args.compare_size, args.compare_size)).astype(np.float32)
    n_small = len(tile_starts(args.compare_size, args.tile, args.overlap)) ** 2
    infer(small[None, : args.tile, : args.tile], 0)  # warm-up: the first call at each shape and thread count
    with parallel_tiles("cpu"):
        infer(small[None, : args.tile, : args.tile], 0)
    walls: dict[str, list[float]] = {"old": [], "new": []}
    for rep in range(args.repeats):
        outputs = {}
        for name in ("old", "new"):
            mean, std, wall, cpu = _tiled(small, infer, args, parallel=name == "new")
            outputs[name] = (mean, std)
            walls[name].append(wall)
            print(
                f"{args.compare_size}^2 ({n_small} tiles), {name}: {wall:.1f} s wall "
                f"({wall / n_small * 1e3:.0f} ms per tile), {cpu:.1f} s CPU, {_load()}",
                flush=True,
            )
        diff = max(float(np.abs(a - b).max()) for a, b in zip(outputs["old"], outputs["new"]))
        assert diff <= 1e-5, f"the parallel tiles changed the output by {diff:.2g}"
        ratio = walls["old"][-1] / walls["new"][-1]
        print(f"  repeat {rep + 1}: old / new = {ratio:.2f}, outputs differ <= {diff:.1g}")
    old, new = sum(walls["old"]), sum(walls["new"])
    print(f"{args.compare_size}^2, {args.repeats} repeats: old {old:.1f} s, new {new:.1f} s, old / new {old / new:.2f}")
    return old / (args.repeats * n_small)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=2048)
    parser.add_argument("--samples", type=int, default=16)
    parser.add_argument("--tile", type=int, default=63)
    parser.add_argument("--overlap", type=int, default=16)
    parser.add_argument("--batch", type=int, default=16, help="tiles per network call")
    parser.add_argument("--checkpoint", default=None)
    parser.add_argument("--compare-size", type=int, default=256, help="slice for old vs new (0: none)")
    parser.add_argument("--repeats", type=int, default=2, help="old/new alternations on the compare slice")
    parser.add_argument("--full-old", action="store_true", help="also the old path on the full slice")
    parser.add_argument(
        "--stitch-only",
        action="store_true",
        help="a pointwise stand-in for the network: the time and memory of the tiling and blending alone",
    )
    args = parser.parse_args()
    if args.stitch_only:
        _stitch_only(args)
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
        f"overlap {args.overlap}, M = {args.samples}, {_load()}"
    )
    old_per_tile = _compare(infer, args, rng) if args.compare_size else None
    slice_ = rng.uniform(0, 1, (args.size, args.size)).astype(np.float32)
    for name in ("new", "old") if args.full_old else ("new",):
        mean, std, wall, cpu = _tiled(slice_, infer, args, parallel=name == "new", progress=True)
        assert mean.shape == (args.size, args.size) and std is not None and np.isfinite(std).all()
        note = ""
        if old_per_tile and name == "new":
            note = f", old path's time per tile on the compare slice / new here: {old_per_tile * n_tiles / wall:.2f}"
        print(
            f"{args.size}^2, {name}: {wall:.1f} s wall ({wall / n_tiles * 1e3:.0f} ms per tile), {cpu:.1f} s CPU"
            f"{note}; "
            f"peak resident memory {_peak_gb():.2f} GB; {_load()}",
            flush=True,
        )


if __name__ == "__main__":
    main()
