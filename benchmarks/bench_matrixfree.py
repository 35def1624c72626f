"""Matrix-free vs cached-matrix reconstruction, and nanoct's FBP vs algotom's, at growing sizes.

Usage::

    NANOCT_CACHE=/tmp/nanoct-cache python benchmarks/bench_matrixfree.py
        [--sizes 255 511 1024] [--fbp-sizes 255 511 1024 2048] [--matrix-sizes 255] [--sweeps 3]

Every case runs in its own subprocess, so its peak memory (``ru_maxrss`` of that process:
Python, numba, the data, the matrix if any) is its own. Geometries follow the paper-parallel
ratios: ``K = round(567 N / 255)`` views, ``L = round(363 N / 255)`` detector pixels.

* Dremel and RESESOP: seconds per sweep (compiled beforehand on a small geometry; the
  matrix's load or build time and each path's one-time sums, which are cached with the
  geometry or the matrix, are measured by a first call and reported separately) with the
  cached matrix
  (``--matrix-sizes``) and with the traced rays, and their ratio at the sizes where both ran;
  also the cost per ray crossing (K L N crossings per sweep). ``dremel:matrixfree+threads``
  splits every view over the threads (``--thread-sizes``), whatever its size.
* FBP: ``nanoct.fbp`` vs ``algotom.rec.reconstruction.fbp_reconstruction`` (CPU, its
  default Hann-windowed ramp, no log, 2 cores) on the same sinogram of ``round(1800 N / 2048)``
  views and N columns (the measured-scan shape: 1800 x 2048 at N = 2048), and their ratio.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import numpy as np


def geometry(n: int):  # noqa: ANN201 - Geometry, imported in the worker
    """The paper-parallel geometry scaled to N."""
    from nanoct.core.geometry import Geometry

    return Geometry(kind="parallel", n=n, n_angles=round(567 * n / 255), n_det=round(363 * n / 255))


def fbp_geometry(n: int):  # noqa: ANN201
    """The measured-scan shape of the FBP comparison: ``round(1800 N / 2048)`` views, N columns."""
    from nanoct.core.geometry import Geometry

    return Geometry(kind="parallel", n=n, n_angles=round(1800 * n / 2048), n_det=n)


def sinogram(g) -> np.ndarray:  # noqa: ANN001
    """A random phantom projected with ASTRA (no matrix), shifted by a smooth per-view motion;
    cached in the temporary directory (the FBP and algotom cases share it)."""
    import tempfile
    from pathlib import Path

    path = Path(tempfile.gettempdir()) / f"bench_matrixfree_{g.n}_{g.n_angles}_{g.n_det}.npy"
    if path.exists():
        return np.load(path)
    from nanoct.core.operators import RayTransform
    from nanoct.sim.phantoms import random_phantom

    x = random_phantom(np.random.default_rng(0), g.n)
    motion = np.zeros((g.n_angles, 3))
    t = np.linspace(0, 1, g.n_angles)
    motion[:, 0] = 0.01 * g.n * np.sin(2 * np.pi * t)
    motion[:, 1] = 0.01 * g.n * np.cos(3 * np.pi * t)
    y = RayTransform(g, motion=motion)(x)
    np.save(path, y)
    return y


def peak_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def worker(case: str, n: int, sweeps: int) -> dict:
    """Run one case in this process; return its measurements."""
    from nanoct.core.operators import system_matrix
    from nanoct.recon.dremel import dremel
    from nanoct.recon.fbp import fbp
    from nanoct.recon.resesop import resesop

    g = fbp_geometry(n) if case in ("fbp", "algotom") else geometry(n)
    y = sinogram(g)
    out: dict = {"case": case, "n": n, "views": g.n_angles, "det": g.n_det}
    if case == "fbp":
        fbp(geometry(16), np.zeros(geometry(16).sino_shape))  # compile
        t = time.perf_counter()
        fbp(g, y)
        out["seconds"] = time.perf_counter() - t
    elif case == "algotom":
        from algotom.rec.reconstruction import fbp_reconstruction

        t = time.perf_counter()
        fbp_reconstruction(y, (g.n_det - 1) / 2, angles=g.angles, apply_log=False, gpu=False, ncore=2)
        out["seconds"] = time.perf_counter() - t
    else:
        method, projector = case.split(":")
        if projector == "matrixfree+threads":  # split every view over the threads
            import nanoct.core.matrixfree

            nanoct.core.matrixfree.PARALLEL_MIN_WORK = 0
            projector = "matrixfree"
        kw = {"matrix": None, "projector": projector}
        if projector == "matrix":
            t = time.perf_counter()
            kw["matrix"] = system_matrix(g)
            out["matrix_seconds"] = time.perf_counter() - t
            kw["projector"] = "auto"
        if method == "dremel":
            run = lambda n_iter: dremel(g, y, n_iter=n_iter, **kw)  # noqa: E731
        else:
            eta = np.full(g.n_angles, 0.02 * float(np.abs(y).max()))
            run = lambda n_iter: resesop(g, y, eta, n_iter=n_iter, tau=1.01, **kw)  # noqa: E731
        small = geometry(32)
        if method == "dremel":
            dremel(small, np.zeros(small.sino_shape), n_iter=1, projector=projector)  # compile
        else:
            resesop(small, np.ones(small.sino_shape), np.zeros(small.n_angles), n_iter=1, projector=projector)
        t = time.perf_counter()
        run(1)  # the one-time sums (cached with the geometry or the matrix) and one sweep
        first = time.perf_counter() - t
        t = time.perf_counter()
        run(sweeps)
        out["seconds"] = (time.perf_counter() - t) / sweeps
        out["setup_seconds"] = max(first - out["seconds"], 0.0)
        out["crossings"] = g.n_angles * g.n_det * g.n  # ray-row (or ray-column) crossings per sweep
    out["peak_gb"] = peak_gb()
    return out


def run_case(case: str, n: int, sweeps: int) -> dict:
    cmd = [sys.executable, __file__, "--worker", case, str(n), "--sweeps", str(sweeps)]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        return {"case": case, "n": n, "error": proc.stderr.strip().splitlines()[-1:]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="*", default=[255, 511, 1024])
    ap.add_argument("--matrix-sizes", type=int, nargs="*", default=[255])
    ap.add_argument("--thread-sizes", type=int, nargs="*", default=[255, 511], help="Dremel with threads per view")
    ap.add_argument("--fbp-sizes", type=int, nargs="*", default=[255, 511, 1024, 2048])
    ap.add_argument("--sweeps", type=int, default=3)
    ap.add_argument("--worker", nargs=2, metavar=("CASE", "N"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(worker(args.worker[0], int(args.worker[1]), args.sweeps)))
        return
    rows = []
    for method in ("dremel", "resesop"):
        for n in args.sizes:
            cases = [f"{method}:matrixfree"] + ([f"{method}:matrix"] if n in args.matrix_sizes else [])
            if method == "dremel" and n in args.thread_sizes:
                cases.append("dremel:matrixfree+threads")
            res = {c: run_case(c, n, args.sweeps) for c in cases}
            for c, r in res.items():
                rows.append(r)
                if "error" in r:
                    print(f"{c:20s} N={n:5d} failed: {r['error']}", flush=True)
                    continue
                extra = f", set-up {r['setup_seconds']:.2f} s"
                extra += f", matrix load/build {r['matrix_seconds']:.1f} s" if "matrix_seconds" in r else ""
                ns = r["seconds"] / r["crossings"] * 1e9
                print(
                    f"{c:20s} N={n:5d} K={r['views']} L={r['det']}: {r['seconds']:.2f} s/sweep "
                    f"({ns:.2f} ns per ray crossing), peak {r['peak_gb']:.2f} GB{extra}",
                    flush=True,
                )
            free, mat = res.get(f"{method}:matrixfree", {}), res.get(f"{method}:matrix", {})
            if "seconds" in free and "seconds" in mat:
                print(f"{'':20s} matrix-free / matrix time ratio: {free['seconds'] / mat['seconds']:.2f}", flush=True)
    for n in args.fbp_sizes:
        a, b = run_case("fbp", n, 1), run_case("algotom", n, 1)
        rows += [a, b]
        if "seconds" in a and "seconds" in b:
            print(
                f"fbp N={n:5d}: nanoct {a['seconds']:.2f} s ({a['peak_gb']:.2f} GB), algotom {b['seconds']:.2f} s "
                f"({b['peak_gb']:.2f} GB), ratio nanoct/algotom {a['seconds'] / b['seconds']:.2f}",
                flush=True,
            )
        else:
            print(f"fbp N={n}: {a.get('error')} {b.get('error')}", flush=True)


if __name__ == "__main__":
    main()
