"""Benchmarks of the foundation: projections, FBP and data-set generation.

Each measurement is printed next to its baseline from the same run, with the ratio.

    python benchmarks/bench_operators.py [--presets paper-parallel paper-fan] [--samples 24]
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import astra
import numpy as np
from scipy.ndimage import map_coordinates

from nanoct.core.fanout import dask_client
from nanoct.core.geometry import get_preset
from nanoct.core.operators import RayTransform, astra_vectors, system_matrix
from nanoct.recon.fbp import fbp, ramp_filter
from nanoct.sim.generate import generate_dataset
from nanoct.sim.motion import sample_motion
from nanoct.sim.phantoms import downsample, random_phantom
from nanoct.sim.simulate import SimulationConfig, sample_rngs


def best_of(fn, repeat: int = 5) -> float:
    fn()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def report(label: str, ours: float, base: float, base_label: str) -> None:
    print(
        f"  {label:<38s} {ours * 1e3:9.1f} ms   {base_label:<34s} {base * 1e3:9.1f} ms   speed-up x{base / ours:6.2f}"
    )


def warp_then_project(geometry, fine: np.ndarray, motion: np.ndarray, oversample: int) -> np.ndarray:
    """Baseline: per view, move the image by interpolation, then project that view alone."""
    m = fine.shape[0]
    c = (np.arange(m) + 0.5) / oversample - geometry.n / 2
    r1, r2 = np.meshgrid(c, -c)
    out = np.empty(geometry.sino_shape, np.float32)
    vectors = astra_vectors(geometry)
    for k in range(geometry.n_angles):
        th = np.deg2rad(motion[k, 2])
        q1 = np.cos(th) * r1 - np.sin(th) * r2 + motion[k, 0]
        q2 = np.sin(th) * r1 + np.cos(th) * r2 + motion[k, 1]
        cols = (q1 + geometry.n / 2) * oversample - 0.5
        rows = (geometry.n / 2 - q2) * oversample - 0.5
        warped = map_coordinates(fine, [rows, cols], order=1, mode="constant").astype(np.float32)
        vol = astra.create_vol_geom(m, m, -geometry.n / 2, geometry.n / 2, -geometry.n / 2, geometry.n / 2)
        vec = vectors[k : k + 1]
        kind = "parallel_vec" if geometry.kind == "parallel" else "fanflat_vec"
        proj = astra.create_proj_geom(kind, geometry.n_det, vec)
        pid = astra.create_projector("line" if geometry.kind == "parallel" else "line_fanflat", proj, vol)
        sid, view = astra.create_sino(warped, pid)
        astra.data2d.delete(sid)
        astra.projector.delete(pid)
        out[k] = view[0]
    return out


def astra_fbp(geometry, sino: np.ndarray) -> np.ndarray:
    vol = astra.create_vol_geom(geometry.n, geometry.n)
    proj = astra.create_proj_geom("parallel", geometry.det_spacing, geometry.n_det, geometry.angles)
    pid = astra.create_projector("line", proj, vol)
    sid = astra.data2d.create("-sino", proj, sino)
    rid = astra.data2d.create("-vol", vol)
    cfg = astra.astra_dict("FBP")
    cfg.update(ProjectorId=pid, ProjectionDataId=sid, ReconstructionDataId=rid, FilterType="ram-lak")
    aid = astra.algorithm.create(cfg)
    astra.algorithm.run(aid)
    out = astra.data2d.get(rid)
    astra.algorithm.delete(aid)
    astra.data2d.delete([sid, rid])
    astra.projector.delete(pid)
    return out


def bench_preset(name: str, samples: int, workers: int) -> None:
    g = get_preset(name)
    print(f"\n== {name}: N={g.n}, K={g.n_angles}, L={g.n_det}")
    rng_p, rng_m, _ = sample_rngs(0, 0)
    fine = random_phantom(rng_p, g.n, oversample=2)
    x = downsample(fine, 2)
    motion = sample_motion(rng_m, g.n_angles, SimulationConfig.for_geometry(g).motion)
    op = RayTransform(g)
    t = time.perf_counter()
    mat = system_matrix(g)
    print(
        f"  system matrix: {mat.nnz / 1e6:.1f} M nnz, "
        f"{(mat.data.nbytes + mat.indices.nbytes + mat.indptr.nbytes) / 2**20:.0f} MiB, "
        f"load/build {time.perf_counter() - t:.1f} s"
    )
    y = op.forward(x)
    xv = x.ravel()
    report(
        "forward, cached CSR (A @ x)",
        best_of(lambda: mat @ xv),
        best_of(lambda: op.forward(x)),
        "forward, ASTRA on the fly",
    )
    report(
        "adjoint, cached CSR (A.T @ y)",
        best_of(lambda: mat.T @ y.ravel()),
        best_of(lambda: op.adjoint(y)),
        "adjoint, ASTRA on the fly",
    )
    moved = RayTransform(g, motion, oversample=2)
    report(
        "forward with motion, exact rays (2x grid)",
        best_of(lambda: moved.forward(fine), 3),
        best_of(lambda: warp_then_project(g, fine, motion, 2), 1),
        "warp per view, then project",
    )
    if g.kind == "fan":
        print(
            "  FBP (nanoct, fan weights + numba back projection) "
            f"{best_of(lambda: fbp(g, y)) * 1e3:9.1f} ms   (ASTRA has no CPU fan FBP)"
        )
    if g.kind == "parallel":
        filt = lambda: (mat.T @ (ramp_filter(y, 1.0).ravel().astype(np.float32))) * (np.pi / g.n_angles)  # noqa: E731
        report(
            "FBP, filter + cached CSR back projection", best_of(filt), best_of(lambda: astra_fbp(g, y)), "ASTRA CPU FBP"
        )
        report("FBP (nanoct)", best_of(lambda: fbp(g, y)), best_of(lambda: astra_fbp(g, y)), "ASTRA CPU FBP")
    # generation throughput, both sinograms included, against warp-then-project per sample
    tmp = Path(tempfile.mkdtemp())
    try:
        with dask_client(workers) as client:  # one cluster: its start-up is not timed
            address = client.scheduler.address
            generate_dataset(tmp / "warm", g, 2 * workers, workers=workers, scheduler=address, progress=False)
            t = time.perf_counter()
            generate_dataset(tmp / "d", g, samples, seed=1, workers=workers, scheduler=address, progress=False)
            ours = (time.perf_counter() - t) / samples
        t = time.perf_counter()
        warp_then_project(g, fine, motion, 2)
        RayTransform(g, oversample=2).forward(fine)
        base = time.perf_counter() - t
        print(
            f"  generation: {1 / ours:.2f} samples/s on {workers} workers ({samples} samples, warm cluster); "
            f"warp-then-project baseline {1 / base:.2f} samples/s on 1 core -> x{base / ours:.1f}"
        )
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--presets", nargs="+", default=["paper-parallel", "paper-fan"])
    parser.add_argument("--samples", type=int, default=24)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    for name in args.presets:
        bench_preset(name, args.samples, args.workers)


if __name__ == "__main__":
    main()
