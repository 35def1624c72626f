"""A measured-size moving scan: axis, coarse-to-fine motion and motion-corrected FBP, with baselines.

Usage::

    python benchmarks/bench_large.py [--cols 2048] [--views 1800] [--slices 4] [--motion-slices 2]
        [--store DIR]   # also time the CLI: nanoct stack on a store of the same scan

The scan is made without any system matrix: exact line integrals of ellipse phantoms
(:mod:`nanoct.sim.analytic`), 180 degrees, a known axis offset and a known shift per view (a
cubic drift in time, rotation harmonics 2 and 3, uniform jitter; the constant and the
translation of the object, ``a cos + b sin``, which no data determine, are left out of the
truth), Gaussian noise of 0.5 % of the largest line integral. Reported:

* axis offset: nanoct (opposite views, then with the motion) vs algotom's ``find_center_vo``;
* motion, twice: the default (centroids), and the path for objects that leave the detector
  (axis from opposite views, binned Dremel, projection matching); time per stage and the
  shift RMSE at full resolution (estimate minus truth, after removing the constant and the
  translation from the difference);
* one slice: motion-corrected FBP time vs algotom's CPU FBP of the same sinogram in the
  same run; PSNR against the phantom with the estimated motion vs with the true motion (the
  estimated shifts' translation aligned to the truth first, as the image cannot know it);
* peak memory of the process (``VmHWM``) after each stage.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def _peak_gib() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 2**20
    return float("nan")


def _gauge(diff: np.ndarray, phi: np.ndarray, constant: bool = True) -> np.ndarray:
    """The least-squares part of ``diff`` in (1,) cos, sin: what no method can identify."""
    cols = ([np.ones_like(phi)] if constant else []) + [np.cos(phi), np.sin(phi)]
    basis = np.stack(cols, axis=1)
    return basis @ np.linalg.lstsq(basis, diff, rcond=None)[0]


def _truth(views: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    phi = np.arange(views) * np.pi / views
    t = np.linspace(-1, 1, views)
    d = 4.0 * t + 3.0 * t**3 - 2.0 * t**2 + 2.5 * np.cos(2 * phi) + 1.5 * np.sin(3 * phi)
    d += rng.uniform(-1.5, 1.5, views)
    return phi, d - _gauge(d, phi)


def main() -> None:  # noqa: PLR0915 - one linear script
    from nanoct.core.geometry import Geometry
    from nanoct.evaluation.metrics import psnr
    from nanoct.motion.center import fit_center
    from nanoct.motion.stack import estimate_stack_motion
    from nanoct.recon.stack import corrected_fbp
    from nanoct.sim.analytic import ellipse_sinogram, rasterize_ellipses, stack_phantom

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cols", type=int, default=2048)
    parser.add_argument("--views", type=int, default=1800)
    parser.add_argument("--slices", type=int, default=4)
    parser.add_argument("--motion-slices", type=int, default=2)
    parser.add_argument("--offset", type=float, default=7.3)
    parser.add_argument("--noise", type=float, default=0.005, help="Gaussian noise, fraction of the largest value")
    parser.add_argument("--store", type=Path, default=None)
    parser.add_argument("--model-only", action="store_true", help="Only: when the smooth motion model helps")
    args = parser.parse_args()
    if args.model_only:
        _model_benefit(args.cols, args.views)
        return
    cols, views, offset = args.cols, args.views, args.offset
    phi, d = _truth(views, np.random.default_rng(0))
    print(f"scan: {cols} columns, {views} views over 180 deg, {args.slices} slices, axis {offset:+.3f} px, "
          f"shifts {d.min():+.2f}..{d.max():+.2f} px (RMS {np.sqrt(np.mean(d**2)):.2f})", flush=True)  # fmt: skip
    phantoms = stack_phantom(cols, args.slices, seed=1)
    t0 = time.perf_counter()
    sino = np.stack([ellipse_sinogram(e, phi, cols, shifts=d, center_offset=offset, subsamples=2) for e in phantoms])
    sino += np.random.default_rng(1).normal(0, args.noise * sino.max(), sino.shape).astype(np.float32)
    print(f"simulate (analytic): {time.perf_counter() - t0:.1f} s, peak {_peak_gib():.2f} GiB", flush=True)

    import algotom.prep.calculation as calc
    import algotom.rec.reconstruction as rec

    t0 = time.perf_counter()
    vo = calc.find_center_vo(sino[0]) - (cols - 1) / 2
    t_vo = time.perf_counter() - t0
    raw = fit_center(sino, phi)
    print(f"axis: algotom find_center_vo {vo:+.3f} px (error {vo - offset:+.3f}, {t_vo:.1f} s); "
          f"nanoct opposite views, no motion {raw:+.3f} px (error {raw - offset:+.3f})", flush=True)  # fmt: skip

    geometry = Geometry.from_angles(phi, cols, cols)
    chosen = np.linspace(0, args.slices - 1, args.motion_slices).round().astype(int)
    truth_image = rasterize_ellipses(phantoms[0], cols, 2)
    true_geometry = Geometry.from_angles(phi, cols, cols, center_offset=offset)
    p_true = psnr(corrected_fbp(true_geometry, sino[0], d), truth_image)
    p_still = psnr(corrected_fbp(Geometry.from_angles(phi, cols, cols, center_offset=raw), sino[0]), truth_image)
    print(f"PSNR of slice 0: FBP with the true motion {p_true:.2f} dB, without motion correction {p_still:.2f} dB")
    for label, options in (("centroids", {}), ("opposite views + binned Dremel + refine", {"centroid_tolerance": 0.0})):
        marks = {"start": time.perf_counter()}
        motion = estimate_stack_motion(
            geometry, sino[chosen], progress=lambda stage: marks.__setitem__(stage, time.perf_counter()), **options
        )
        err, coarse_err = motion.shifts - d, motion.coarse - d
        rmse = float(np.sqrt(np.mean((err - _gauge(err, phi)) ** 2)))
        coarse_rmse = float(np.sqrt(np.mean((coarse_err - _gauge(coarse_err, phi)) ** 2)))
        aligned = motion.shifts + _gauge(d - motion.shifts, phi, constant=False)
        est = Geometry.from_angles(phi, cols, cols, center_offset=motion.center_offset)
        p_est = psnr(corrected_fbp(est, sino[0], aligned), truth_image)
        print(f"motion, {label} ({len(chosen)} slices): coarse {marks['coarse'] - marks['start']:.1f} s "
              f"(RMSE {coarse_rmse:.3f} px), total {marks['axis'] - marks['start']:.1f} s; shift RMSE {rmse:.3f} px; "
              f"refine steps {np.round(motion.steps, 3).tolist()}; axis {motion.center_offset:+.3f} px "
              f"(error {motion.center_offset - offset:+.3f}); PSNR {p_est:.2f} dB ({p_est - p_true:+.2f} dB vs true "
              f"motion); peak {_peak_gib():.2f} GiB", flush=True)  # fmt: skip

    t0 = time.perf_counter()
    corrected_fbp(est, sino[0], aligned)
    t_ours = time.perf_counter() - t0
    t0 = time.perf_counter()
    rec.fbp_reconstruction(sino[0], (cols - 1) / 2 + offset, angles=phi, apply_log=False, gpu=False)
    t_algotom = time.perf_counter() - t0
    print(f"slice {cols}^2: motion-corrected FBP {t_ours:.1f} s vs algotom CPU FBP {t_algotom:.1f} s "
          f"(ratio {t_ours / t_algotom:.2f}); peak {_peak_gib():.2f} GiB", flush=True)  # fmt: skip
    if args.store is not None:
        _time_cli(args.store, geometry, sino)


def _model_benefit(cols: int, views: int) -> None:
    """Shift RMSE of the centroid estimate from one noisy slice, per view and with the smooth model (3, 3)."""
    from nanoct.motion.center import centroid_motion
    from nanoct.motion.model import fit_motion_model
    from nanoct.sim.analytic import ellipse_sinogram, stack_phantom

    phi, d = _truth(views, np.random.default_rng(0))
    jitter = np.random.default_rng(0).uniform(-1.5, 1.5, views)  # the jitter _truth draws first
    smooth = d - jitter + _gauge(jitter, phi)
    phantom = stack_phantom(cols, 1, seed=1)[0]
    for label, truth in (("smooth motion", smooth), ("smooth motion + jitter", d)):
        sino = ellipse_sinogram(phantom, phi, cols, shifts=truth, center_offset=7.3, subsamples=2)
        for noise in (0.005, 0.05):
            noisy = sino + np.random.default_rng(2).normal(0, noise * sino.max(), sino.shape).astype(np.float32)
            _, est, _ = centroid_motion(noisy, phi)
            model = fit_motion_model(est, phi, 3, 3)
            rms = [float(np.sqrt(np.mean((e - truth - _gauge(e - truth, phi)) ** 2))) for e in (est, model.shifts)]
            print(f"model, {label}, noise {noise:.1%}, 1 slice: shift RMSE per view {rms[0]:.3f} px, "
                  f"model (3, 3) {rms[1]:.3f} px (residual {model.residual_rms:.3f} px)", flush=True)  # fmt: skip


def _time_cli(store: Path, geometry, sino: np.ndarray) -> None:
    """Time ``nanoct stack`` on a store of the same scan (a separate process, 2 Dask workers)."""
    from nanoct.io.store import create_scan

    if not (store / "zarr.json").is_file():
        create_scan(store, geometry, sino, {"source": "bench_large"})
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "nanoct", "stack", str(store), "--overwrite", "-q"]
    out = subprocess.run(cmd, capture_output=True, text=True, check=False)
    print(f"CLI {' '.join(cmd[2:])}: {time.perf_counter() - t0:.1f} s, exit {out.returncode}: "
          f"{(out.stdout + out.stderr).strip()[-300:]}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
