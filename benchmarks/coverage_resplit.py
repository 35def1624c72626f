"""How much the object's width-fifth coverage of a finished study moves with the calibration/test split.

Usage::

    PYTHONPATH=src python benchmarks/coverage_resplit.py runs/tiny-parallel [--splits 200] [--level 0.9] [--names A,B]

For every calibrated prediction of the study's data set (Dremel/RESESOP + CiNNRes/CiUNetRes), the
network's mean and raw std of the validation and test images are made as ``predict`` makes them
(:func:`nanoct.learn.calibration.sample_outputs`: one image at a time, latent samples seeded with
the sample index, the prediction's sampling arguments); the stored test outputs are checked
against them. The validation and test images are exchangeable, so their pool is split at random
into a calibration half and a test half of the study's sizes, many times; each time the
group-conditional intervals are fitted on the calibration half
(:func:`nanoct.learn.calibration.fit_intervals`, as ``predict`` fits them) and scored on the other
half as ``nanoct evaluate`` scores them (coverage of the object's support in five equal-count
half-width bins, :func:`nanoct.evaluation.metrics.interval_scores`). Printed per row: the study's
own split (which must equal the evaluation's numbers), and over the random splits the 5th, 50th
and 95th percentile of each fifth's coverage and the fraction of splits with all five fifths in
87-93 %: what a split of this size can promise.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from nanoct.evaluation.conformal import half_width
from nanoct.evaluation.metrics import interval_scores, support_mask
from nanoct.io.store import DataStore
from nanoct.learn.calibration import fit_intervals, sample_outputs
from nanoct.learn.checkpoint import load_checkpoint, model_from_checkpoint

BAND = (0.87, 0.93)


def outputs(store: DataStore, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Indices (validation then test), means, raw stds and ground truths of one calibrated prediction."""
    params = store.reconstruction_params(name)
    ckpt_path = Path(params["run"]) / f"{params['checkpoint']}.pt"
    model = model_from_checkpoint(load_checkpoint(ckpt_path), ckpt_path)
    val, test = store.indices("val"), store.indices("test")
    means, stds = sample_outputs(model, store, params["input"], val, params["reconstruct"])
    stored = store.read_reconstruction(name, test), store.read_uncertainty(name, test)
    again = sample_outputs(model, store, params["input"], test, params["reconstruct"])
    for a, b in zip(stored, again):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)  # the outputs predict stored
    indices = np.concatenate([val, test])
    return (
        indices,
        np.concatenate([means, stored[0]]),
        np.concatenate([stds, stored[1]]),
        store.read_phantoms(indices),
    )


def fifths(means, stds, gts, fit, level: float) -> np.ndarray:
    """Coverage of the object's support in five half-width bins, as the evaluation scores it."""
    half = half_width({"calibration": fit}, stds, level, mean=means)
    return np.array(interval_scores(means - gts, half, support_mask(gts), 5)["coverage_by_width"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("study", type=Path)
    parser.add_argument("--splits", type=int, default=200)
    parser.add_argument("--level", type=float, default=0.9)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--names", default=None, help="comma-separated predictions (default: every calibrated one)")
    args = parser.parse_args()
    store = DataStore.open(args.study / "data")
    names = [n for n in store.reconstruction_names() if "calibration" in store.reconstruction_params(n)]
    names = names if args.names is None else [n for n in names if n in args.names.split(",")]
    rng = np.random.default_rng(args.seed)
    n_val = store.indices("val").size
    for name in sorted(names):
        start = time.perf_counter()
        indices, means, stds, gts = outputs(store, name)
        own = fifths(
            means[n_val:], stds[n_val:], gts[n_val:],
            store.reconstruction_params(name)["calibration"], args.level,
        )  # fmt: skip
        runs = []
        for _ in range(args.splits):
            order = rng.permutation(indices.size)
            cal, test = order[:n_val], order[n_val:]
            fit = fit_intervals(means[cal], stds[cal], gts[cal], levels=(args.level,))
            runs.append(fifths(means[test], stds[test], gts[test], fit, args.level))
        runs = np.array(runs)
        inside = np.all((runs >= BAND[0]) & (runs <= BAND[1]), axis=1).mean()
        p5, p50, p95 = np.percentile(runs, [5, 50, 95], axis=0)
        print(f"\n{name} ({n_val} calibration / {indices.size - n_val} test images, {args.splits} splits, "
              f"{time.perf_counter() - start:.0f} s)")  # fmt: skip
        print("  the study's split : " + " / ".join(f"{100 * v:.1f}" for v in own))
        for label, row in (("5th percentile", p5), ("median", p50), ("95th percentile", p95)):
            print(f"  {label:<17} : " + " / ".join(f"{100 * v:.1f}" for v in row))
        print(f"  splits with all five fifths in {100 * BAND[0]:.0f}-{100 * BAND[1]:.0f} %: {100 * inside:.0f} %")


if __name__ == "__main__":
    main()
