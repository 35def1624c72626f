"""RESESOP uncertainty level in ``nanoct stack --method resesop``: candidate rules for eta.

Usage::

    PYTHONPATH=src python benchmarks/stack_eta.py [--slices 2] [--extra]

For analytic moving stacks (``nanoct.sim.analytic``: sizes, motion amplitudes and noise levels
below) each slice is reconstructed with the motion given (``true``) and with the motion from
:func:`nanoct.motion.stack.estimate_stack_motion` (``est``, axis given, its object translation
aligned to the truth): motion-corrected FBP, Dremel with
the shifts fixed, and RESESOP on the shift-corrected sinogram with these per-view levels
(``r = |y_c - A x_0|``, ``x_0`` the corrected FBP of ``y_c``; ``r_c`` the same residual of the
FBP of the consistent data ``A x_0``, the FBP's own error):

- ``max``: ``max_l r``, ``max*0.5`` (the ``auto`` default), ``max*0.2``;
- ``rms``: the root mean square of ``r`` per view; ``p90``: its 90th percentile;
- ``model``: ``max_l |r - r_c|``, the residual with the FBP's own error removed.

Prints the mean PSNR over slices against the phantoms, and for RESESOP the mean sweeps used and
the time per slice.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from nanoct.core.geometry import Geometry
from nanoct.evaluation.metrics import psnr
from nanoct.motion.stack import estimate_stack_motion
from nanoct.recon.dremel import dremel
from nanoct.recon.resesop import resesop
from nanoct.recon.stack import corrected_fbp, reproject
from nanoct.sim.analytic import ellipse_sinogram, rasterize_ellipses, stack_phantom
from nanoct.workflows.stack import shift_corrected

#: (columns, views, drift amplitude in px, relative noise)
STACKS = ((160, 240, 1.0, 0.0), (160, 240, 2.0, 0.005), (256, 384, 1.5, 0.02))
#: Two more stacks (``--extra``): a larger one and the small one at 2 % noise.
EXTRA_STACKS = ((384, 576, 2.0, 0.005), (160, 240, 1.0, 0.02))
RULES = ("max", "max*0.5", "max*0.2", "rms", "p90", "model")


def levels(geometry: Geometry, corrected: np.ndarray, rule: str) -> np.ndarray:
    """Per-view level of ``rule`` for the shift-corrected sinogram ``corrected``."""
    start = corrected_fbp(geometry, corrected)
    consistent = reproject(geometry, start)
    r = corrected - consistent
    if rule.startswith("max"):
        scale = float(rule[4:]) if "*" in rule else 1.0
        return scale * np.abs(r).max(axis=1)
    if rule == "rms":
        return np.sqrt(np.mean(r**2, axis=1))
    if rule == "p90":
        return np.quantile(np.abs(r), 0.9, axis=1)
    own = consistent - reproject(geometry, corrected_fbp(geometry, consistent))
    return np.abs(r - own).max(axis=1)


def stack(n: int, k: int, amp: float, noise: float, n_slices: int):
    """Sinograms, phantoms, geometry and true shifts of one moving analytic stack."""
    phi = np.arange(k) * np.pi / k
    rng = np.random.default_rng(5)
    d = amp * (1.2 * np.cos(2 * phi) + np.linspace(-1, 1, k) + rng.uniform(-1.5, 1.5, k))
    d -= np.linalg.lstsq(np.stack([np.ones(k), np.cos(phi), np.sin(phi)], axis=1), d, rcond=None)[0][0]
    phantoms = stack_phantom(n, n_slices, seed=2)
    sino = np.stack([ellipse_sinogram(e, phi, n, shifts=d, subsamples=2) for e in phantoms])
    sino += noise * sino.max() * rng.standard_normal(sino.shape)
    truth = [rasterize_ellipses(e, n, 4) for e in phantoms]
    return sino, truth, Geometry.from_angles(phi, n, n), d


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--slices", type=int, default=2)
    parser.add_argument("--extra", action="store_true", help="run EXTRA_STACKS instead of STACKS")
    args = parser.parse_args()
    print("| stack | motion | FBP | Dremel | " + " | ".join(RULES) + " |")
    print("|---" * (4 + len(RULES)) + "|")
    for n, k, amp, noise in EXTRA_STACKS if args.extra else STACKS:
        sino, truth, geometry, d = stack(n, k, amp, noise, args.slices)
        est = estimate_stack_motion(geometry, sino, center=0.0).shifts
        # an object translation (shifts a cos + b sin) is what no method can tell: align it to the truth
        basis = np.stack([np.ones(k), np.cos(np.arange(k) * np.pi / k), np.sin(np.arange(k) * np.pi / k)], axis=1)
        est = est + basis @ np.linalg.lstsq(basis, d - est, rcond=None)[0]
        for label, shifts in (("true", d), ("est", est)):
            scores = {m: [] for m in ("FBP", "Dremel", *RULES)}
            sweeps = {r: [] for r in RULES}
            secs = {r: 0.0 for r in RULES}
            for i in range(args.slices):
                scores["FBP"].append(psnr(corrected_fbp(geometry, sino[i], shifts), truth[i]))
                obj = shifts * geometry.det_spacing / geometry.magnification
                scores["Dremel"].append(psnr(dremel(geometry, sino[i], shifts0=obj, fix_shifts=True).image, truth[i]))
                corrected = shift_corrected(sino[i], shifts)
                for rule in RULES:
                    t0 = time.perf_counter()
                    res = resesop(geometry, corrected, levels(geometry, corrected, rule), projector="auto")
                    secs[rule] += time.perf_counter() - t0
                    sweeps[rule].append(len(res.residuals))
                    scores[rule].append(psnr(res.image, truth[i]))
            cells = [f"{np.mean(scores[m]):.1f}" for m in ("FBP", "Dremel")]
            cells += [
                f"{np.mean(scores[r]):.1f} ({np.mean(sweeps[r]):.0f}, {secs[r] / args.slices:.1f} s)" for r in RULES
            ]
            print(f"| {n} px, {k} views, x{amp}, {noise:.1%} | {label} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
