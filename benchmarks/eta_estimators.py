"""RESESOP's eta without ground truth: the estimators against the true eta, and RESESOP with each.

Makes a test store (``--n`` samples, all in the test split) and a reference store of the same
geometry with another seed, reconstructs the test samples with FBP, Dremel, RESESOP with the
true eta and with each estimate, fits the residual estimator's scale on the reference store
(never on the test samples) and prints the tables of docs/measured_data.md. The CLI commands
doing the same are listed there. Resumable: existing stores and reconstructions are reused.

    python benchmarks/eta_estimators.py --preset tiny-parallel --n 24 --n-ref 24 --out /tmp/eta/tiny
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from nanoct.core.geometry import get_preset
from nanoct.evaluation.metrics import summarize
from nanoct.io.store import DataStore
from nanoct.recon.batch import reconstruct_dataset
from nanoct.recon.eta import eta_from_reference, eta_from_residual, fit_scale
from nanoct.sim.generate import generate_dataset


def _residual_etas(store: DataStore, indices: np.ndarray) -> np.ndarray:
    firsts = store.read_reconstruction("dremel", indices)
    return np.stack(
        [eta_from_residual(store.geometry, store.read_sample(int(i)).sinogram, x) for i, x in zip(indices, firsts)]
    )


def _quality(true: np.ndarray, est: np.ndarray) -> dict[str, float]:
    corr = np.array([np.corrcoef(t, e)[0, 1] for t, e in zip(true, est)])
    ratio = est.mean(axis=1) / true.mean(axis=1)
    return {"corr_mean": corr.mean(), "corr_std": corr.std(), "ratio_mean": ratio.mean(), "ratio_std": ratio.std()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="tiny-parallel")
    parser.add_argument("--n", type=int, default=24)
    parser.add_argument("--n-ref", type=int, default=24)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    g = get_preset(args.preset)
    common = dict(workers=args.workers, progress=False, split_fractions=(0.0, 0.0, 1.0))
    test = generate_dataset(args.out / "test", g, args.n, seed=1, **common)
    ref = generate_dataset(args.out / "ref", g, args.n_ref, seed=2, **common)
    run = dict(split="test", workers=args.workers, progress=False)
    for method in ("fbp", "dremel", "resesop"):
        reconstruct_dataset(test.path, method, params={"eta_scale": 1.0} if method == "resesop" else {}, **run)
    reconstruct_dataset(ref.path, "dremel", **run)
    # the residual estimator's scale, fitted on the reference store
    ref_idx, idx = ref.indices("test"), test.indices("test")
    ref_true = np.stack([ref.read_sample(int(i)).eta for i in ref_idx])
    ref_median = eta_from_reference(ref_true)
    scale = round(fit_scale(ref_true, _residual_etas(ref, ref_idx)), 2)
    ref_scale = round(fit_scale(ref_true, np.tile(ref_median, (len(ref_idx), 1))), 2)
    sources = {
        "resesop_est-residual": ("estimate:residual", 1.0),
        f"resesop_est-residual_eta{scale:g}": ("estimate:residual", scale),
        "resesop_est-reference": (f"estimate:reference={ref.path}", 1.0),
        f"resesop_est-reference_eta{ref_scale:g}": (f"estimate:reference={ref.path}", ref_scale),
    }
    for name, (eta, s) in sources.items():
        assert reconstruct_dataset(test.path, "resesop", params={"eta": eta, "eta_scale": s}, **run) == name
    true = np.stack([test.read_sample(int(i)).eta for i in idx])
    residual = _residual_etas(test, idx)
    reference = np.tile(ref_median, (len(idx), 1))
    quality = {
        "residual (scale 1)": _quality(true, residual),
        f"residual (scale {scale:g}, fitted on the reference store)": _quality(true, scale * residual),
        "reference (per-view median)": _quality(true, reference),
        f"reference (scale {ref_scale:g}, fitted on the reference store)": _quality(true, ref_scale * reference),
    }
    gts = test.read_phantoms(idx)
    names = ["fbp", "dremel", "resesop", *sources]
    images = {n: summarize(test.read_reconstruction(n, idx), gts) for n in names}
    print(f"## {args.preset}: {len(idx)} test samples, reference store {len(ref_idx)} samples")
    print("\n| estimator | corr with true eta (mean ± std) | mean(est) / mean(true) (mean ± std) |\n|---|---|---|")
    for label, q in quality.items():
        corr, ratio = f"{q['corr_mean']:.3f} ± {q['corr_std']:.3f}", f"{q['ratio_mean']:.2f} ± {q['ratio_std']:.2f}"
        print(f"| {label} | {corr} | {ratio} |")
    print("\n| reconstruction | PSNR (dB) | SSIM |\n|---|---|---|")
    for n, m in images.items():
        print(f"| {n} | {m['psnr_mean']:.2f} ± {m['psnr_std']:.2f} | {m['ssim_mean']:.3f} ± {m['ssim_std']:.3f} |")
    scales = {"residual": scale, "reference": ref_scale}
    report = {"preset": args.preset, "scales": scales, "quality": quality, "images": images}
    (args.out / "eta_estimators.json").write_text(json.dumps(report, indent=1, default=float))


if __name__ == "__main__":
    main()
