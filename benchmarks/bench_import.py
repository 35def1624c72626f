"""Peak memory and time of importing a few slices of a large NXtomo scan.

Writes a synthetic NXtomo file with ESRF's ``nxtomo`` library (uint16 frames: 2 darks, 2 flats,
K projections of R x L pixels), then runs, each in a fresh process (so the peak resident memory
is its own):

* baseline: reading the whole detector (``read_scan(path)``: what an import of any rows costs
  when the reader loads every pixel and cuts afterwards);
* nanoct: ``nanoct.workflows.importscan.import_scan(path, out, rows=slice(r, r + S))``, which reads only
  the selected rows from disk (an HDF5 hyperslab);
* the same process with the same imports and no work (the libraries' own memory);

and prints peak RSS, wall time and the ratios (of the whole processes and of the memory above
the libraries'). Usage::

    python benchmarks/bench_import.py --views 720 --rows 128 --cols 1024 --slices 2
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

_CHILD = """
import json, resource, sys, time
from pathlib import Path
mode, path, out, first, stop = sys.argv[1:]
from nanoct.core.geometry import Geometry
from nanoct.io.scanio import read_scan
from nanoct.workflows.importscan import import_scan
from nanoct.io.store import create_scan
start = time.perf_counter()
if mode == "full":
    read_scan(path)
elif mode == "rows":
    import_scan(path, out, rows=slice(int(first), int(stop)))
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps({"seconds": time.perf_counter() - start, "peak_mib": peak}))
"""


def write_scan(path: Path, views: int, rows: int, cols: int) -> None:
    """A synthetic NXtomo file (uint16, smooth object, flats and darks) written by ``nxtomo``."""
    import pint
    from nxtomo import NXtomo

    units = pint.get_application_registry()
    rng = np.random.default_rng(0)
    u = np.linspace(-1, 1, cols)
    profile = np.clip(1 - u**2, 0, None)  # a cylinder's line integrals, the same on every row
    frames = np.empty((4 + views, rows, cols), np.uint16)
    frames[:2] = 100
    frames[2:4] = 60000
    for k in range(views):
        shift = int(10 * np.sin(2 * np.pi * k / views))
        line = np.roll(profile, shift)
        frames[4 + k] = (100 + 59900 * np.exp(-line))[None, :] + rng.integers(0, 50, (rows, 1))
    nx = NXtomo()
    nx.instrument.detector.data = frames
    nx.instrument.detector.image_key_control = np.r_[2, 2, 1, 1, np.zeros(views, int)]
    nx.sample.rotation_angle = np.r_[0, 0, 0, 0, np.arange(views) * 180 / views] * units.degree
    nx.sample.x_pixel_size = 50e-9 * units.meter
    nx.save(str(path), data_path="entry0000")


def run(mode: str, path: Path, out: Path, first: int, stop: int) -> dict[str, float]:
    """One measurement in a fresh Python process."""
    result = subprocess.run(
        [sys.executable, "-c", _CHILD, mode, str(path), str(out), str(first), str(stop)],
        check=True,
        capture_output=True,
        text=True,
    )
    return json.loads(result.stdout.strip().splitlines()[-1])


def main() -> None:
    """Parse the sizes, write the scan, measure both paths and print a table."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--views", type=int, default=720)
    parser.add_argument("--rows", type=int, default=128)
    parser.add_argument("--cols", type=int, default=1024)
    parser.add_argument("--slices", type=int, default=2)
    parser.add_argument("--write", type=Path, help=argparse.SUPPRESS)  # the child that writes the scan
    args = parser.parse_args()
    if args.write is not None:
        write_scan(args.write, args.views, args.rows, args.cols)
        return
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scan.nx"
        # written by another process: Linux keeps a process's peak RSS across fork and exec, so the
        # measuring children must start from a parent that never held the frames
        sizes = ["--views", str(args.views), "--rows", str(args.rows), "--cols", str(args.cols)]
        subprocess.run([sys.executable, __file__, "--write", str(path), *sizes], check=True)
        size = path.stat().st_size / 2**20
        first = args.rows // 2
        libs = run("none", path, Path(tmp) / "unused", 0, 0)
        full = run("full", path, Path(tmp) / "unused", 0, 0)
        part = run("rows", path, Path(tmp) / "data", first, first + args.slices)
    print(f"scan: {args.views} views x {args.rows} rows x {args.cols} columns, uint16, file {size:.0f} MiB")
    print("| step | peak RSS (MiB) | wall (s) |")
    print("|---|---|---|")
    print(f"| baseline: read the whole detector (float32) | {full['peak_mib']:.0f} | {full['seconds']:.2f} |")
    print(f"| nanoct import --rows {first}:{first + args.slices} | {part['peak_mib']:.0f} | {part['seconds']:.2f} |")
    print(f"| the same imports, no work | {libs['peak_mib']:.0f} | |")
    print(
        f"ratio (baseline / import): memory {full['peak_mib'] / part['peak_mib']:.1f}x, "
        f"time {full['seconds'] / part['seconds']:.1f}x; memory above the libraries': baseline "
        f"{full['peak_mib'] - libs['peak_mib']:.0f} MiB, import {part['peak_mib'] - libs['peak_mib']:.0f} MiB"
    )


if __name__ == "__main__":
    main()
