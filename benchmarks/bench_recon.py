"""Benchmarks of the row-action reconstructions, each with its baselines in the same run.

Usage::

    NANOCT_CACHE=/tmp/nanoct-cache python benchmarks/bench_recon.py [--presets paper-parallel paper-fan]
        [--repeat 3] [--numpy-rows 300] [--skip-astra]

Measures, on one core (threads pinned to 1):

* one Kaczmarz sweep (numba) vs ASTRA's CPU ``ART`` over the same rays, vs reading the CSR
  arrays once (``max``: the memory-bandwidth floor) and streaming the CSR matrix once (numba
  ``||A x - y||`` pass and scipy ``A @ x``), vs a straightforward numpy row loop (a few hundred
  rows timed, extrapolated to all rows);
* full RESESOP (20 sweeps) and Dremel (32 iterations) per sample, with peak memory
  (tracemalloc peak of Python/numpy allocations during the call, and the process max RSS),
  vs a straightforward numpy implementation of the same algorithm (a few hundred rays /
  a few views timed and extrapolated).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402

import numpy as np  # noqa: E402

from nanoct.core.geometry import get_preset  # noqa: E402
from nanoct.core.operators import RayTransform, astra_vectors, system_matrix  # noqa: E402
from nanoct.recon.dremel import _XCorr, dremel  # noqa: E402
from nanoct.recon.kaczmarz import _kaczmarz_sweep, kaczmarz_reference  # noqa: E402
from nanoct.recon.resesop import resesop, resesop_reference  # noqa: E402
from nanoct.recon.rowaction import residual_norm, row_norms_squared, unsigned_indices, view_order  # noqa: E402
from nanoct.sim.phantoms import downsample, random_phantom  # noqa: E402


def timeit(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def make_sample(geometry, seed=4242):
    """A validation-style sample: phantom on a 2x grid, smooth motion + jitter (translation)."""
    rng = np.random.default_rng(seed)
    fine = random_phantom(rng, geometry.n, oversample=2)
    k = geometry.n_angles
    tt = np.arange(k) / k
    motion = np.zeros((k, 3))
    motion[:, 0] = 1.5 * np.sin(2 * np.pi * 3 * tt) + rng.normal(0, 0.127, k)
    motion[:, 1] = 1.5 * np.cos(2 * np.pi * 5 * tt + 1) * np.exp(-tt) + rng.normal(0, 0.127, k)
    y = RayTransform(geometry, motion, oversample=2).forward(fine)
    y_eta = RayTransform(geometry, oversample=2).forward(fine)
    eta = np.abs(y - y_eta).max(axis=1)
    return downsample(fine, 2).astype(np.float32), y, eta


def astra_art_sweep(geometry, y, n_rays):
    import astra

    n = geometry.n
    vol = astra.create_vol_geom(n, n, -n / 2, n / 2, -n / 2, n / 2)
    kind = "parallel_vec" if geometry.kind == "parallel" else "fanflat_vec"
    proj = astra.create_proj_geom(kind, geometry.n_det, astra_vectors(geometry))
    pid = astra.create_projector("line" if geometry.kind == "parallel" else "line_fanflat", proj, vol)
    sid = astra.data2d.create("-sino", proj, y)
    rid = astra.data2d.create("-vol", vol, 0.0)
    cfg = astra.astra_dict("ART")
    cfg["ProjectorId"] = pid
    cfg["ProjectionDataId"] = sid
    cfg["ReconstructionDataId"] = rid
    cfg["option"] = {"RayOrder": "sequential"}
    aid = astra.algorithm.create(cfg)
    t = time.perf_counter()
    astra.algorithm.run(aid, n_rays)  # one ART iteration = one ray
    dt = time.perf_counter() - t
    for f, i in (
        (astra.algorithm.delete, aid),
        (astra.data2d.delete, sid),
        (astra.data2d.delete, rid),
        (astra.projector.delete, pid),
    ):
        f(i)
    return dt


def with_memory(fn):
    tracemalloc.start()
    t = time.perf_counter()
    out = fn()
    dt = time.perf_counter() - t
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return out, dt, peak / 2**20


def dremel_numpy_views(geometry, mat, y, n_views, omega=0.05):
    """Straightforward numpy/scipy Dremel view steps (per view: slice rows, project, step, xcorr)."""
    k_all, l_all = geometry.sino_shape
    x = np.zeros(mat.shape[1])
    rows_sum = np.asarray(mat.sum(axis=1)).ravel()
    col = np.asarray(mat.sum(axis=0)).ravel() / k_all
    inv_col = np.where(col > 1e-6, 1 / np.maximum(col, 1e-6), 0)
    xc = _XCorr(l_all, 2)
    shifts = np.zeros(k_all)
    grid = np.arange(l_all, dtype=float)
    t = time.perf_counter()
    for k in range(n_views):
        ak = mat[k * l_all : (k + 1) * l_all]
        p = ak @ x
        d = shifts[k] * geometry.magnification
        z = np.interp(grid + d, grid, p, left=0, right=0)
        rs = np.interp(grid + d, grid, rows_sum[k * l_all : (k + 1) * l_all], left=0, right=0)
        e = np.where(rs > 1e-6, (z - y[k]) / np.maximum(rs, 1e-6), 0)
        # adjoint of linear interpolation
        i0 = np.floor(grid + d).astype(int)
        f = grid + d - i0
        g = np.zeros(l_all)
        for idx, w in ((i0, 1 - f), (i0 + 1, f)):
            ok = (idx >= 0) & (idx < l_all)
            np.add.at(g, idx[ok], w[ok] * e[ok])
        x -= omega * inv_col * (ak.T @ g)
        np.maximum(x, 0, out=x)
        ys, ym = xc.spectrum(y[k].astype(float))
        shifts[k] += xc.shift(xc.spectrum(z), (np.conj(ys), ym)) / geometry.magnification
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--presets", nargs="+", default=["paper-parallel", "paper-fan"])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--numpy-rows", type=int, default=300, help="rows timed for the numpy baselines")
    ap.add_argument("--skip-astra", action="store_true")
    args = ap.parse_args()

    for name in args.presets:
        g = get_preset(name)
        t = time.perf_counter()
        mat = system_matrix(g)
        t_mat = time.perf_counter() - t
        norms = row_norms_squared(mat)
        gt, y, eta = make_sample(g)
        yf = y.ravel()
        k_all, l_all = g.sino_shape
        n_rays = k_all * l_all
        print(
            f"\n=== {name}: N={g.n}, K={k_all}, L={l_all}, rays={n_rays}, nnz={mat.nnz / 1e6:.1f} M, "
            f"matrix load/build {t_mat:.2f} s"
        )

        # ---- one Kaczmarz sweep (unsigned column indices, as kaczmarz() passes them)
        ind = unsigned_indices(mat)
        x = np.zeros(mat.shape[1], np.float32)
        views = view_order(k_all, "random", np.random.default_rng(0))
        _kaczmarz_sweep(mat.indptr, ind, mat.data, norms, yf, x, views, l_all, 1.0)  # warm up / compile

        def sweep():
            _kaczmarz_sweep(mat.indptr, ind, mat.data, norms, yf, x, views, l_all, 1.0)

        t_sweep = timeit(sweep, args.repeat)
        t_bw = timeit(lambda: (mat.data.max(), ind.max()), args.repeat)
        t_stream = timeit(lambda: residual_norm(mat.indptr, ind, mat.data, yf, x), args.repeat)
        t_spmv = timeit(lambda: mat @ x, args.repeat)
        gb = (mat.data.nbytes + ind.nbytes) / 1e9
        print(f"Kaczmarz sweep (numba):            {t_sweep * 1e3:8.1f} ms")
        print(
            f"read data + indices once (max):    {t_bw * 1e3:8.1f} ms  ({gb / t_bw:.1f} GB/s) -> "
            f"sweep / read = {t_sweep / t_bw:.2f}"
        )
        print(
            f"stream CSR once (numba A x - y):   {t_stream * 1e3:8.1f} ms  -> sweep / stream = {t_sweep / t_stream:.2f}"
        )
        print(f"scipy A @ x:                        {t_spmv * 1e3:8.1f} ms  -> sweep / spmv = {t_sweep / t_spmv:.2f}")
        if not args.skip_astra:
            t_art = astra_art_sweep(g, y, n_rays)
            print(f"ASTRA CPU ART, same {n_rays} rays: {t_art * 1e3:8.1f} ms  -> speed-up {t_art / t_sweep:.1f}x")
        # numpy row loop on the first views
        n_v = max(1, args.numpy_rows // l_all)
        xr = np.zeros(mat.shape[1])
        t = time.perf_counter()
        kaczmarz_reference(mat, yf.astype(np.float64), xr, np.arange(n_v), l_all, 1.0)
        t_np = (time.perf_counter() - t) * k_all / n_v
        print(
            f"numpy row loop (extrapolated from {n_v * l_all} rows): {t_np:8.2f} s  -> speed-up {t_np / t_sweep:.0f}x"
        )

        # ---- RESESOP 20 sweeps
        for residual in ("running", "exact"):
            resesop(g, y, eta, n_iter=1, matrix=mat)  # compile
            res, t_res, peak = with_memory(lambda: resesop(g, y, eta, n_iter=20, matrix=mat, residual=residual))
            print(
                f"RESESOP ({res.iterations} sweeps, residual={residual}, stop={res.stop_reason}): {t_res:6.2f} s, "
                f"tracemalloc peak {peak:6.1f} MiB, updates/sweep {res.params['n_updates'][0]} -> "
                f"{res.params['n_updates'][-1]}"
            )
        xr = np.zeros(mat.shape[1])
        width = np.repeat(eta.astype(np.float64), l_all)
        t = time.perf_counter()
        resesop_reference(mat, yf.astype(np.float64), xr, width, 1.01, np.arange(n_v), l_all, {})
        t_np1 = (time.perf_counter() - t) / (n_v * l_all)
        print(
            f"numpy RESESOP (literal, dense search directions): {t_np1 * 1e3:.3f} ms/ray -> one sweep "
            f"~{t_np1 * n_rays:.1f} s, 20 sweeps ~{20 * t_np1 * n_rays:.0f} s (extrapolated from {n_v * l_all} rays, "
            f"first sweep: all rays updated) -> {20 * t_np1 * n_rays / t_res:.0f}x"
        )

        # ---- Dremel 32 iterations
        dremel(g, y, n_iter=1, matrix=mat)  # compile
        for residual in ("running", "exact"):
            res, t_dr, peak = with_memory(lambda: dremel(g, y, n_iter=32, matrix=mat, residual=residual))
            print(f"Dremel (32 iterations, residual={residual}): {t_dr:6.2f} s, tracemalloc peak {peak:6.1f} MiB")
        n_dv = max(4, args.numpy_rows // 20)
        t_np_d = dremel_numpy_views(g, mat, y, n_dv) / n_dv * k_all * 32
        print(
            f"numpy/scipy Dremel (extrapolated from {n_dv} view steps): 32 iterations ~{t_np_d:.1f} s "
            f"-> {t_np_d / t_dr:.1f}x"
        )
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"\nprocess max RSS (whole run, includes matrices and ASTRA): {rss:.0f} MiB")


if __name__ == "__main__":
    main()
