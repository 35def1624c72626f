"""The measured-data choices of Dremel and RESESOP checked on simulated samples (truth known).

Usage::

    PYTHONPATH=src python benchmarks/rowaction_simulated.py [--presets tiny-parallel,small-parallel] [--samples 6]

For each preset and noise level (0 and 0.5, in sinogram units) and each sample (seed 7,
indices 0..S-1, the paper's motion), mean PSNR after the best sub-pixel translation
(:func:`nanoct.evaluation.metrics.register`) against the phantom of:

* Dremel (32 iterations, the simulations' defaults) and with ``subpixel=True`` (the parabolic
  correlation peak, the measured-data default);
* Dremel restarted from its own motion (a second run with a fresh image);
* Dremel started from the views' centroid motion (:func:`nanoct.motion.center.centroid_motion`,
  where the views' total line integral varies by at most 1 %, the tolerance of
  :func:`nanoct.motion.stack.estimate_stack_motion`; else from zero), and RESESOP after it;
* RESESOP with the unperturbed model and eta from Dremel's residual (scale 1), and RESESOP
  after Dremel: Dremel's motion in the model (``shifts=``) and eta the residual after it.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from nanoct.core.geometry import get_preset
from nanoct.evaluation.metrics import register
from nanoct.motion.center import centroid_motion
from nanoct.recon.dremel import dremel
from nanoct.recon.eta import eta_from_residual
from nanoct.recon.resesop import resesop
from nanoct.sim.simulate import SimulationConfig, simulate_sample

ROWS = (
    "dremel", "dremel_subpixel", "dremel_restart", "resesop_unmoved_model", "resesop_after_dremel",
    "dremel_centroid", "resesop_after_dremel_centroid",
)  # fmt: skip


def psnr(image: np.ndarray, truth: np.ndarray) -> float:
    """PSNR (data range of the truth) after the best sub-pixel translation onto it."""
    moved = register(image, truth)[0]
    return float(10 * np.log10((truth.max() - truth.min()) ** 2 / np.mean((moved - truth) ** 2)))


def sample_scores(g, sample) -> dict[str, float]:
    """Every row's PSNR on one simulated sample."""
    y, truth = sample.sinogram, sample.phantom
    d = dremel(g, y)
    images = {
        "dremel": d.image,
        "dremel_subpixel": dremel(g, y, subpixel=True).image,
        "dremel_restart": dremel(g, y, shifts0=d.motion).image,
        "resesop_unmoved_model": resesop(g, y, eta_from_residual(g, y, d.image)).image,
        "resesop_after_dremel": resesop(g, y, eta_from_residual(g, y, d.image, shifts=d.motion), shifts=d.motion).image,
    }
    _, start, spread = centroid_motion(y, g.angles)
    c = dremel(g, y, shifts0=start * g.det_spacing / g.magnification) if spread <= 0.01 else d
    images["dremel_centroid"] = c.image
    eta = eta_from_residual(g, y, c.image, shifts=c.motion)
    images["resesop_after_dremel_centroid"] = resesop(g, y, eta, shifts=c.motion).image
    return {row: psnr(images[row], truth) for row in ROWS}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--presets", default="tiny-parallel,small-parallel")
    parser.add_argument("--samples", type=int, default=6)
    args = parser.parse_args()
    start = time.perf_counter()
    print("preset | noise | " + " | ".join(ROWS))
    for preset in args.presets.split(","):
        g = get_preset(preset)
        for noise in (0.0, 0.5):
            rows = [sample_scores(g, simulate_sample(g, SimulationConfig(noise_std=noise), 7, i))
                    for i in range(args.samples)]  # fmt: skip
            means = " | ".join(f"{np.mean([r[k] for r in rows]):.2f}" for k in ROWS)
            print(f"{preset} | {noise} | {means}", flush=True)
    print(f"total {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
