"""The streaming stack end to end: ``nanoct stack SCAN.nx --out OUT.zarr`` on a synthetic NXtomo scan.

Usage::

    python benchmarks/bench_slabs.py [--rows 32] [--cols 2048] [--views 1800] [--block 16] [--workers 0]
        [--check-slices 3] [--resume-check] [--cache /tmp/nanoct-bench-slabs]

The scan (intensities, 2 darks and 2 flats in one NXtomo file, HDF5 chunks of 16 rows) is
written once and cached under ``--cache`` (its generation time is reported separately): ``rows``
detector rows whose line integrals blend linearly between two analytic ellipse slices
(:func:`nanoct.sim.analytic.stack_phantom`) times a vertical ripple of period 24 rows (the image
of row ``r`` is the same combination of the two phantoms; the ripple gives the row profiles the
vertical structure a sample has), rotation axis 7.3 px off centre, a per-view horizontal shift (drift, rotation
harmonics, jitter; up to about 8 px, with no constant, ``cos`` or ``sin`` part: those are a
translation of the object that no data determine, so the phantom is the reference as it is).

Then, in one run:

* the pipeline through the command line in a child process (``python -m nanoct stack SCAN --out
  OUT.zarr --block B -w W -q``): reading, flat/dark correction, the vertical motion from the row
  profiles (one pass over the rows), the horizontal motion and axis from 4 rows, every slice with
  gridrec into Zarr. Wall time, per slice, and the child's peak resident memory
  (``getrusage(RUSAGE_CHILDREN).ru_maxrss``; with ``-w 0`` one process, two threads);
* ``--check-slices`` slices (first, middle, last): nanoct's per-slice FBP
  (:func:`~nanoct.recon.stack.corrected_fbp`, numba back projection on all cores) with the motion
  and axis the pipeline recorded, timed on the in-memory sinogram (the baseline), and the PSNR of
  both against the phantom (rasterised at 2x2 sub-pixels, ``data_range`` of the phantom);
* ``--resume-check``: the last block's flag cleared, the same command run again: its time (one
  block, the motion not estimated again) and whether every chunk is byte for byte the same.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

OFFSET = 7.3


def _motion(views: int) -> np.ndarray:
    """Drift, rotation harmonics and jitter, less the translation part (constant, cos, sin) no data determine."""
    phi = np.arange(views) * np.pi / views
    t = np.linspace(-1, 1, views)
    d = 4.0 * t + 3.0 * t**3 - 2.0 * t**2 + 2.5 * np.cos(2 * phi) + 1.5 * np.sin(3 * phi)
    d = d + np.random.default_rng(0).uniform(-1.5, 1.5, views)
    basis = np.stack([np.ones(views), np.cos(phi), np.sin(phi)], axis=1)
    return d - basis @ np.linalg.lstsq(basis, d, rcond=None)[0]


def _phantoms(cols: int) -> list:
    from nanoct.sim.analytic import stack_phantom

    return stack_phantom(cols, 2, seed=5)


def _row_weights(row: int, rows: int) -> tuple[float, float]:
    """Row ``row``'s image is ``a * phantom_0 + b * phantom_1``: a linear blend times a vertical ripple (24 rows)."""
    w = row / max(rows - 1, 1)
    ripple = 0.75 + 0.25 * np.sin(2 * np.pi * row / 24)
    return ripple * (1 - w), ripple * w


def write_scan(path: Path, rows: int, cols: int, views: int) -> float:
    """The NXtomo scan of the module docstring; returns the seconds it took."""
    import h5py

    from nanoct.sim.analytic import ellipse_sinogram

    t0 = time.perf_counter()
    phi = np.arange(views) * np.pi / views
    d = _motion(views)
    ends = [ellipse_sinogram(e, phi, cols, shifts=d, center_offset=OFFSET, subsamples=2) for e in _phantoms(cols)]
    tmp = path.with_suffix(".writing")
    with h5py.File(tmp, "w") as f:
        data = f.create_dataset(
            "entry/instrument/detector/data", (views + 4, rows, cols), "float32", chunks=(1, min(rows, 16), cols)
        )
        data[:2] = 10.0  # darks
        data[2:4] = 1000.0  # flats
        for r0 in range(0, rows, 16):
            a, b = np.array([_row_weights(r, rows) for r in range(r0, min(r0 + 16, rows))]).T[:, :, None, None]
            lines = a * ends[0][None] + b * ends[1][None]
            data[4:, r0 : r0 + lines.shape[0]] = (10.0 + 990.0 * np.exp(-lines)).transpose(1, 0, 2)
        f["entry/instrument/detector/image_key"] = np.r_[2, 2, 1, 1, np.zeros(views, int)]
        f["entry/sample/rotation_angle"] = np.r_[0, 0, 0, 0, np.rad2deg(phi)]
    os.replace(tmp, path)
    return time.perf_counter() - t0


def run_cli(scan: Path, out: Path, block: int, workers: int) -> tuple[float, float]:
    """Wall seconds of ``nanoct stack SCAN --out OUT`` in a child process and the children's peak RSS (GiB)."""
    cmd = [sys.executable, "-m", "nanoct", "stack", str(scan), "--out", str(out), "--block", str(block)]
    cmd += ["-w", str(workers), "-q"]
    print("command:", " ".join(cmd[1:]))
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    took = time.perf_counter() - t0
    if done.returncode:
        sys.exit(f"the pipeline failed ({done.returncode}):\n{done.stderr[-3000:]}")
    print(done.stdout.strip())
    return took, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 2**20


def check_slices(scan: Path, out: Path, count: int) -> float:
    """nanoct's per-slice FBP with the recorded motion (timed) and PSNR of both against the phantom."""
    import zarr

    from nanoct.core.geometry import Geometry
    from nanoct.evaluation.metrics import psnr
    from nanoct.io.scanio import read_scan
    from nanoct.recon.slab import read_block
    from nanoct.recon.stack import corrected_fbp
    from nanoct.sim.analytic import rasterize_ellipses

    group = zarr.open_group(str(out), mode="r")
    info = dict(group.attrs["info"])
    head = read_scan(scan, rows=slice(0, 1))
    n_rows, cols = head.source["detector_shape"]
    geometry = Geometry.from_angles(head.angles, cols, cols, center_offset=info["center_offset"])
    shifts, vertical = np.asarray(info["shifts"]), np.asarray(info["vertical"])
    print(f"recorded: axis {info['center_offset']:+.3f} px (true {OFFSET:+.3f}), shift error RMS "
          f"{np.sqrt(np.mean((shifts - _motion(shifts.size)) ** 2)):.3f} px, vertical "
          f"{vertical.min():+.3f} to {vertical.max():+.3f} px ({info['vertical_method']})")  # fmt: skip
    truths = [rasterize_ellipses(e, cols, 2) for e in _phantoms(cols)]
    source = {"path": str(scan), "n_rows": n_rows}
    small = Geometry.from_angles(head.angles[:8], 64, 64)
    corrected_fbp(small, np.ones((8, 64), np.float32), np.zeros(8))  # compile the kernels (not timed)
    times = []
    for r in sorted({int(v) for v in np.linspace(0, n_rows - 1, count).round()}):
        a, b = _row_weights(r, n_rows)
        truth = (a * truths[0] + b * truths[1]).astype(np.float32)
        sino = read_block(source, (r, r + 1), vertical if vertical.any() else None)[0]
        t0 = time.perf_counter()
        fbp = corrected_fbp(geometry, sino, shifts)
        times.append(time.perf_counter() - t0)
        ours = group["slices"][r]
        print(f"slice {r}: PSNR gridrec (pipeline) {psnr(ours, truth):.3f} dB, nanoct FBP {psnr(fbp, truth):.3f} dB "
              f"(difference {psnr(ours, truth) - psnr(fbp, truth):+.3f} dB); FBP {times[-1]:.2f} s")  # fmt: skip
    return float(np.median(times)) if times else float("nan")


def resume_check(scan: Path, out: Path, block: int, workers: int) -> None:
    """Clear the last block's flag, rerun the same command: its time and whether the bytes are the same."""
    import zarr

    chunks = {p: p.read_bytes() for p in sorted((out / "slices").rglob("*")) if p.is_file()}
    group = zarr.open_group(str(out), mode="r+")
    group["done"][-1] = False
    took, _ = run_cli(scan, out, block, workers)
    same = all(p.read_bytes() == b for p, b in chunks.items())
    print(f"resume: the last block again in {took:.1f} s (process start and reading included); "
          f"every chunk byte for byte the same: {same}")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rows", type=int, default=32)
    parser.add_argument("--cols", type=int, default=2048)
    parser.add_argument("--views", type=int, default=1800)
    parser.add_argument("--block", type=int, default=16)
    parser.add_argument("--workers", type=int, default=0)
    parser.add_argument("--check-slices", type=int, default=3)
    parser.add_argument("--resume-check", action="store_true")
    parser.add_argument("--cache", type=Path, default=Path("/tmp/nanoct-bench-slabs"))
    args = parser.parse_args()
    import finufft

    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, finufft "
          f"{finufft.__version__}, load {os.getloadavg()[0]:.1f}")  # fmt: skip
    args.cache.mkdir(parents=True, exist_ok=True)
    scan = args.cache / f"scan_{args.views}x{args.rows}x{args.cols}.nx"
    if scan.exists():
        print(f"scan: {scan} (cached)")
    else:
        print(f"scan: {scan} written in {write_scan(scan, args.rows, args.cols, args.views):.1f} s (not timed below)")
    print(f"  {args.views} views x {args.rows} rows x {args.cols} columns, {scan.stat().st_size / 2**30:.2f} GiB")
    out = args.cache / f"out_{args.views}x{args.rows}x{args.cols}_b{args.block}.zarr"
    shutil.rmtree(out, ignore_errors=True)
    wall, peak = run_cli(scan, out, args.block, args.workers)
    per_slice = wall / args.rows
    print(f"pipeline: {wall:.1f} s wall for {args.rows} slices ({per_slice:.2f} s per slice, everything included), "
          f"peak memory {peak:.2f} GiB; load now {os.getloadavg()[0]:.1f}")  # fmt: skip
    fbp = check_slices(scan, out, args.check_slices)
    print(f"ratio nanoct FBP per slice / pipeline per slice: {fbp / per_slice:.1f}x (FBP {fbp:.2f} s, median)")
    if args.resume_check:
        resume_check(scan, out, args.block, args.workers)
    print(json.dumps({"rows": args.rows, "wall_s": wall, "per_slice_s": per_slice, "peak_gib": peak, "fbp_s": fbp}))


if __name__ == "__main__":
    main()
