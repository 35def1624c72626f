"""Gridrec (FBP in Fourier space) beside nanoct's FBP, algotom's CPU FBP and ASTRA's CPU FBP, in one run.

Usage::

    python benchmarks/bench_gridrec.py [--cols 1024 2048] [--views 1800] [--slices 4] [--repeat 3]
        [--paper-slices 8] [--skip-paper] [--times-only]

For each size: a few slices of an analytic ellipse phantom (:func:`nanoct.sim.analytic.stack_phantom`,
exact line integrals, 2 sub-samples per detector pixel) over 180 degrees, rotation axis 7.3 px
off centre, a per-view horizontal shift (drift, rotation harmonics, jitter; up to about 10 px).
Every time is the minimum of ``--repeat`` runs (the machine is shared):

* nanoct FBP with the motion (``corrected_fbp``, numba back projection on all cores), one slice;
* algotom's CPU FBP (``fbp_reconstruction``, ``gpu=False``, no smoothing window) of the same
  slice with the views moved back first (algotom takes no per-view shift; the move is not timed);
* gridrec with the motion: the plan (polar points, phase ramps, NUFFT plans) built once for the
  stack, then ``--slices`` slices, two per complex transform; per slice = that time / slices.
  Also one slice through ``nanoct.recon.gridrec.gridrec`` (plan included), as a single call costs.

PSNR against the phantom (rasterised at 2x2 sub-pixels; ``data_range`` of the phantom) of the
first two slices, with and without motion, for nanoct's FBP and gridrec (the difference is the
agreement target: within 0.1 dB), and algotom's (best of the 8 flips/rotations of its image: its
orientation convention differs). Paper-parallel (255^2, 567 views, 363 detector pixels): ASTRA's
CPU FBP (``line`` projector) against gridrec per slice in a stack of ``--paper-slices``.

The streaming pipeline end to end (``nanoct stack SCAN --out OUT.zarr``): ``bench_slabs.py``.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from collections.abc import Callable
from typing import Any

import numpy as np


def _best(fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    """(minimum seconds over ``repeat`` runs, the last result)."""
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def _motion(views: int) -> np.ndarray:
    phi = np.arange(views) * np.pi / views
    t = np.linspace(-1, 1, views)
    d = 4.0 * t + 3.0 * t**3 - 2.0 * t**2 + 2.5 * np.cos(2 * phi) + 1.5 * np.sin(3 * phi)
    return d + np.random.default_rng(0).uniform(-1.5, 1.5, views)


def _scan(cols: int, views: int, slices: int, offset: float, shifts: np.ndarray | None) -> tuple:
    from nanoct.sim.analytic import ellipse_sinogram, rasterize_ellipses, stack_phantom

    phi = np.arange(views) * np.pi / views
    phantoms = stack_phantom(cols, slices, seed=1)
    sino = np.stack(
        [ellipse_sinogram(e, phi, cols, shifts=shifts, center_offset=offset, subsamples=2) for e in phantoms]
    )
    truth = [rasterize_ellipses(e, cols, 2) for e in phantoms[:2]]
    return phi, sino, truth


def _one_call(geometry: Any, sino: np.ndarray, shifts: Any, repeat: int) -> tuple[float, float]:
    """Seconds of one ``gridrec()`` call: (plan built in the call, plan reused from the previous call)."""
    from nanoct.recon import gridrec as module

    def fresh() -> Any:
        module._CACHE.clear()
        return module.gridrec(geometry, sino, shifts=shifts)

    built, _ = _best(fresh, repeat)
    reused, _ = _best(lambda: module.gridrec(geometry, sino, shifts=shifts), repeat)
    return built, reused


def _psnr_any_orientation(image: np.ndarray, truth: np.ndarray) -> float:
    from nanoct.evaluation.metrics import psnr

    variants = [np.rot90(image, k) for k in range(4)] + [np.rot90(image.T, k) for k in range(4)]
    return max(psnr(v.astype(np.float32), truth) for v in variants)


def _algotom(sino: np.ndarray, phi: np.ndarray, centre: float) -> np.ndarray:
    import algotom.rec.reconstruction as rec

    return rec.fbp_reconstruction(sino, centre, angles=phi, apply_log=False, gpu=False, filter_name=None, ratio=None)


def _size(cols: int, views: int, slices: int, repeat: int, quality: bool = True, offset: float = 7.3) -> None:
    """Times (and with ``quality`` nanoct's FBP and the PSNR) at one size."""
    from nanoct.core.geometry import Geometry
    from nanoct.recon.gridrec import GridrecPlan
    from nanoct.recon.stack import corrected_fbp
    from nanoct.workflows.stack import shift_corrected

    d = _motion(views)
    geometry = Geometry.from_angles(np.arange(views) * np.pi / views, cols, cols, center_offset=offset)
    t0 = time.perf_counter()
    phi, sino, truth = _scan(cols, views, slices, offset, d)
    print(f"\n== {cols} columns, {views} views, {slices} slices (simulated in {time.perf_counter() - t0:.0f} s)")
    t_fbp, fbp0 = _best(lambda: corrected_fbp(geometry, sino[0], d), repeat) if quality else (float("nan"), None)
    corrected = shift_corrected(sino[0].astype(np.float64), d).astype(np.float32)
    t_alg, alg = _best(lambda: _algotom(corrected, phi, (cols - 1) / 2 + offset), repeat)
    t0 = time.perf_counter()
    plan = GridrecPlan(geometry, d)
    t_plan = time.perf_counter() - t0
    t_batch, images = _best(lambda: plan(sino), repeat)
    t_single, t_again = _one_call(geometry, sino[0], d, max(1, repeat - 1))
    per_slice = t_batch / slices
    print(f"time per slice: nanoct FBP {t_fbp:.2f} s | algotom FBP {t_alg:.2f} s | gridrec {per_slice:.3f} s "
          f"(plan {t_plan:.2f} s once; one gridrec() call: {t_single:.2f} s with its plan, {t_again:.2f} s "
          f"reusing the last call's)")  # fmt: skip
    print(f"ratio algotom / gridrec: {t_alg / per_slice:.1f}x (target >= 6); nanoct FBP / gridrec: "
          f"{t_fbp / per_slice:.1f}x; with the plan in one call: {t_alg / t_single:.1f}x")  # fmt: skip
    if quality:
        _quality(geometry, sino, images, fbp0, truth, d, offset)
        print(f"PSNR slice 0, motion: algotom FBP (views moved back, best orientation) "
              f"{_psnr_any_orientation(alg, truth[0]):.3f} dB")  # fmt: skip


def _quality(
    geometry: Any, sino: np.ndarray, images: np.ndarray, fbp0: np.ndarray, truth: list, d: Any, offset: float
) -> None:
    """PSNR of nanoct's FBP and gridrec on the first two slices, with the motion and without (simulated again)."""
    from nanoct.evaluation.metrics import psnr
    from nanoct.recon.gridrec import GridrecPlan
    from nanoct.recon.stack import corrected_fbp

    _, still, _ = _scan(geometry.n_det, geometry.n_angles, 2, offset, None)
    for label, data, shifts, gimages in (("motion", sino, d, images), ("no motion", still, None, None)):
        gimages = GridrecPlan(geometry, shifts)(data[:2]) if gimages is None else gimages
        for i in range(2):
            ref = fbp0 if (i == 0 and shifts is not None) else corrected_fbp(geometry, data[i], shifts)
            p_fbp, p_grid = psnr(ref, truth[i]), psnr(gimages[i], truth[i])
            print(f"PSNR slice {i}, {label}: nanoct FBP {p_fbp:.3f} dB, gridrec {p_grid:.3f} dB "
                  f"(difference {p_grid - p_fbp:+.3f} dB)")  # fmt: skip


def _astra_fbp(geometry: Any, sino: np.ndarray) -> np.ndarray:
    import astra

    vol = astra.create_vol_geom(geometry.n, geometry.n)
    proj = astra.create_proj_geom("parallel", geometry.det_spacing, geometry.n_det, geometry.angles)
    pid = astra.create_projector("line", proj, vol)
    sid = astra.data2d.create("-sino", proj, sino)
    rid = astra.data2d.create("-vol", vol)
    cfg = astra.astra_dict("FBP")
    cfg.update(ReconstructionDataId=rid, ProjectionDataId=sid, ProjectorId=pid, option={"FilterType": "ram-lak"})
    aid = astra.algorithm.create(cfg)
    try:
        astra.algorithm.run(aid)
        return astra.data2d.get(rid)
    finally:
        astra.algorithm.delete(aid)
        astra.data2d.delete([sid, rid])
        astra.projector.delete(pid)


def _paper(slices: int, repeat: int) -> None:
    from nanoct.core.geometry import get_preset
    from nanoct.evaluation.metrics import psnr
    from nanoct.recon.fbp import fbp
    from nanoct.recon.gridrec import GridrecPlan
    from nanoct.sim.analytic import ellipse_sinogram, rasterize_ellipses, stack_phantom

    g = get_preset("paper-parallel")
    phantoms = stack_phantom(g.n, slices, seed=2)
    sino = np.stack([ellipse_sinogram(e, g.angles, g.n_det, subsamples=2) for e in phantoms])
    truth = rasterize_ellipses(phantoms[0], g.n, 2)
    print(f"\n== paper-parallel: {g.n}^2, {g.n_angles} views, {g.n_det} detector pixels, {slices} slices")
    t_astra, ref = _best(lambda: _astra_fbp(g, sino[0]), 3 * repeat)
    t_fbp, ours_fbp = _best(lambda: fbp(g, sino[0]).image, 3 * repeat)
    plan = GridrecPlan(g)
    t_batch, images = _best(lambda: plan(sino), 3 * repeat)
    t_single, t_again = _one_call(g, sino[0], None, 3 * repeat)
    per_slice = t_batch / slices
    print(f"time per slice: ASTRA CPU FBP {1e3 * t_astra:.1f} ms | nanoct FBP {1e3 * t_fbp:.1f} ms | gridrec "
          f"{1e3 * per_slice:.1f} ms in a stack of {slices} (one gridrec() call: {1e3 * t_single:.1f} ms with its "
          f"plan, {1e3 * t_again:.1f} ms reusing the last call's)")  # fmt: skip
    print(f"ratio ASTRA / gridrec: {t_astra / per_slice:.1f}x in a stack (target >= 3); one call: "
          f"{t_astra / t_single:.1f}x with its plan, {t_astra / t_again:.1f}x reusing it")  # fmt: skip
    print(f"PSNR slice 0: ASTRA {psnr(ref.astype(np.float32), truth):.3f} dB, nanoct FBP {psnr(ours_fbp, truth):.3f} "
          f"dB, gridrec {psnr(images[0], truth):.3f} dB")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cols", type=int, nargs="+", default=[1024, 2048])
    parser.add_argument("--views", type=int, default=1800)
    parser.add_argument("--slices", type=int, default=4)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--paper-slices", type=int, default=8)
    parser.add_argument("--skip-paper", action="store_true")
    parser.add_argument("--times-only", action="store_true", help="Skip nanoct's FBP and the PSNR (gridrec vs algotom)")
    args = parser.parse_args()
    import finufft
    import numba

    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, numba threads "
          f"{numba.get_num_threads()}, finufft {finufft.__version__}, load {os.getloadavg()[0]:.1f}")  # fmt: skip
    if not args.skip_paper:
        _paper(args.paper_slices, args.repeat)
    for cols in args.cols:
        _size(cols, args.views, args.slices, args.repeat, quality=not args.times_only)


if __name__ == "__main__":
    main()
