"""``nanoct import --center-offset auto`` and ``nanoct stack`` on a full-size NXtomo scan, as a user runs them.

Writes, once (cached in ``--work``), an NXtomo file with ESRF's ``nxtomo`` library: R detector
rows x L columns x K views over 180 degrees (default 4 x 2048 x 1800), 2 darks and 2 flats,
float32 intensities of exact ellipse line integrals (:mod:`nanoct.sim.analytic`), the rotation
axis ``--offset`` px right of the detector centre and a known horizontal motion per view (a cubic
drift, rotation harmonics 2 and 3 and jitter, scaled to ``--motion`` px at most; its constant
and ``a cos + b sin`` part, which no data determine, left out, so the axis is defined), 0.5 %
Gaussian noise on the line integrals. Then, each in its own process, timed with its peak
resident memory (``wait4``: the process and the workers it waited for):

1. ``nanoct import SCAN --out DIR --center-offset auto``
2. ``nanoct stack DIR``

and prints, per command, wall seconds and peak GiB, the axis error and the gauge-free RMS of
the shifts (estimate minus truth less its least-squares 1, cos, sin part). With ``--baseline
REF`` the same two commands run again from a ``git worktree`` of commit REF in the same run
(its own virtual environment's Python, ``PYTHONPATH`` pointing at the worktree's ``src``), and the
time ratios are printed. With ``--profile`` each command also runs under ``cProfile`` and the
20 functions of largest cumulative time are printed (stage by stage: reading, corrections, axis,
motion, slices). Usage::

    python benchmarks/bench_commands.py [--rows 4 --cols 2048 --views 1800] [--baseline COMMIT] [--profile]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def truth(views: int, largest: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """View angles (radians) and a horizontal motion of at most ``largest`` px, without its gauge."""
    phi = np.arange(views) * np.pi / views
    t = np.linspace(-1, 1, views)
    d = 4.0 * t + 3.0 * t**3 - 2.0 * t**2 + 2.5 * np.cos(2 * phi) + 1.5 * np.sin(3 * phi)
    d += rng.uniform(-1.5, 1.5, views)
    d -= gauge(d, phi)
    return phi, d * (largest / np.abs(d).max())


def gauge(diff: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """The least-squares part of ``diff`` in (1, cos, sin): what no estimate can identify."""
    basis = np.stack([np.ones_like(phi), np.cos(phi), np.sin(phi)], axis=1)
    return basis @ np.linalg.lstsq(basis, diff, rcond=None)[0]


def write_scan(path: Path, rows: int, cols: int, views: int, offset: float, largest: float) -> np.ndarray:
    """The NXtomo file; returns the true shifts (detector pixels, the sign of ``dremel``'s motion)."""
    import pint
    from nxtomo import NXtomo

    from nanoct.sim.analytic import ellipse_sinogram, stack_phantom

    phi, d = truth(views, largest, np.random.default_rng(0))
    if path.is_file():
        return d
    phantoms = stack_phantom(cols, rows, seed=1)
    lines = np.stack([ellipse_sinogram(e, phi, cols, shifts=d, center_offset=offset, subsamples=2) for e in phantoms])
    lines += np.random.default_rng(1).normal(0, 0.005 * lines.max(), lines.shape)
    flat = 50000.0
    frames = np.empty((4 + views, rows, cols), np.float32)
    frames[:2], frames[2:4] = 100.0, flat + 100.0
    frames[4:] = 100.0 + flat * np.exp(-lines.transpose(1, 0, 2))
    units = pint.get_application_registry()
    nx = NXtomo()
    nx.instrument.detector.data = frames
    nx.instrument.detector.image_key_control = np.r_[2, 2, 1, 1, np.zeros(views, int)]
    nx.sample.rotation_angle = np.r_[0, 0, 0, 0, np.rad2deg(phi)] * units.degree
    nx.sample.x_pixel_size = 50e-9 * units.meter
    nx.sample.y_pixel_size = 50e-9 * units.meter
    partial = path.with_suffix(".partial.nx")
    nx.save(str(partial), data_path="entry0000", overwrite=True)
    partial.rename(path)
    return d


_PROFILED = """
import cProfile, pstats, sys
from nanoct.cli import run
profile = cProfile.Profile()
code = profile.runcall(run, sys.argv[1:])
pstats.Stats(profile).sort_stats("cumulative").print_stats(r"nanoct|algotom|finufft|scipy", 25)
sys.exit(code)
"""


def timed(python: str, args: list[str], env: dict[str, str], profile: bool) -> tuple[float, float, str]:
    """Run ``nanoct ARGS`` with ``python`` in a new process: (wall seconds, peak GiB, its output)."""
    cmd = [python, "-c", _PROFILED, *args] if profile else [python, "-m", "nanoct", *args]
    start = time.perf_counter()
    with tempfile.TemporaryFile("w+") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        seconds = time.perf_counter() - start
        log.seek(0)
        output = log.read()
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(args)} failed:\n{output[-3000:]}")
    return seconds, usage.ru_maxrss / 2**20, output


def measure(python: str, src: Path, scan: Path, work: Path, d: np.ndarray, offset: float, profile: bool) -> dict:
    """Import and stack once with the code under ``src``: times, memory, axis and shift errors."""
    env = {**os.environ, "PYTHONPATH": str(src)}
    store = work / f"store-{abs(hash(str(src))) % 10**6}"
    shutil.rmtree(store, ignore_errors=True)
    result = {}
    for stage, args in (
        ("import", ["import", str(scan), "--out", str(store), "--center-offset", "auto"]),
        ("stack", ["stack", str(store), "-q"]),
    ):
        seconds, gib, output = timed(python, args, env, profile)
        result[stage] = (seconds, gib)
        if profile:
            print(f"--- profile of {stage} ({src}) ---\n{output[-6000:]}", flush=True)
    probe = subprocess.run(
        [python, "-c", _PROBE, str(store)], env=env, capture_output=True, text=True, check=True
    ).stdout.split()
    imported, stacked = float(probe[0]), float(probe[1])
    shifts = np.array(probe[2:], dtype=float)
    phi = np.arange(d.size) * np.pi / d.size
    err = shifts - d
    result["axis_import"] = imported - offset
    result["axis_stack"] = stacked - offset
    result["shift_rms"] = float(np.sqrt(np.mean((err - gauge(err, phi)) ** 2)))
    shutil.rmtree(store, ignore_errors=True)
    return result


_PROBE = """
import sys
from nanoct.io.store import DataStore
data = DataStore.open(sys.argv[1])
info = data.recons.motion_info("fbp_stack")
shifts = data.recons.shared_shifts("fbp_stack")
print(data.geometry.center_offset, info["center_offset"], *shifts.tolist())
"""


def worktree(ref: str, work: Path) -> Path:
    """A checkout of ``ref``'s sources (``git worktree``), reused when it exists."""
    tree = work / f"tree-{ref[:12]}"
    if not tree.is_dir():
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree), ref], check=True)
    return tree / "src"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rows", type=int, default=4)
    parser.add_argument("--cols", type=int, default=2048)
    parser.add_argument("--views", type=int, default=1800)
    parser.add_argument("--offset", type=float, default=16.6, help="Axis minus the detector centre, px")
    parser.add_argument("--motion", type=float, default=9.0, help="Largest horizontal shift, px")
    parser.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "nanoct-bench-commands")
    parser.add_argument("--baseline", default=None, help="A commit to run the same commands from, for the ratio")
    parser.add_argument("--profile", action="store_true", help="Also print each command's cProfile")
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    scan = args.work / f"scan_{args.rows}x{args.cols}x{args.views}_{args.offset:g}_{args.motion:g}.nx"
    t0 = time.perf_counter()
    d = write_scan(scan, args.rows, args.cols, args.views, args.offset, args.motion)
    size = f"{args.rows} rows x {args.cols} columns x {args.views} views"
    print(f"scan {scan.name}: {size}, axis {args.offset:+.2f} px, shifts {d.min():+.2f}..{d.max():+.2f} px "
          f"({time.perf_counter() - t0:.0f} s to write or find)", flush=True)  # fmt: skip
    runs = {"current": ROOT / "src"}
    if args.baseline is not None:
        runs[f"baseline {args.baseline}"] = worktree(args.baseline, args.work)
    results = {}
    for label, src in runs.items():
        r = measure(sys.executable, src, scan, args.work, d, args.offset, args.profile)
        results[label] = r
        total = r["import"][0] + r["stack"][0]
        print(f"{label}: import {r['import'][0]:.1f} s ({r['import'][1]:.2f} GiB), stack {r['stack'][0]:.1f} s "
              f"({r['stack'][1]:.2f} GiB), total {total:.1f} s; axis error at import {r['axis_import']:+.3f} px, "
              f"after stack {r['axis_stack']:+.3f} px; shifts {r['shift_rms']:.3f} px RMS (gauge-free)",
              flush=True)  # fmt: skip
    if args.baseline is not None:
        cur, base = results["current"], results[f"baseline {args.baseline}"]
        for stage in ("import", "stack"):
            print(f"{stage}: current / baseline = {cur[stage][0] / base[stage][0]:.2f}")
        total = (cur["import"][0] + cur["stack"][0]) / (base["import"][0] + base["stack"][0])
        print(f"total: current / baseline = {total:.2f}")


if __name__ == "__main__":
    main()
