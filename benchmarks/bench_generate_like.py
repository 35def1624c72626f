"""Time ``nanoct generate --like`` on the Diamond I13-2 scan 24737 against the 15-minute target.

Usage::

    PYTHONPATH=src python benchmarks/bench_generate_like.py [--n 1000] [--bins 2,1] [--workers 2]

Steps, each one CLI command in a subprocess, timed by wall clock:

1. ``nanoct import`` of ``tests/data/realdata/i13-24737-tiff`` (91 views x 135 rows x 160 columns,
   axis ``--center-offset auto``);
2. ``nanoct stack`` on it (FBP per slice, the stack's motion and axis), so that the matched set
   takes the motion statistics of a measured motion;
3. ``nanoct generate --like STORE --bin B --n N`` for each binning: the timed command of the
   target (measuring the scan, its slices as phantoms, and N simulated pairs).

Prints the seconds of each step, the samples per second, the time extrapolated to 1,000 pairs
(linear in N beyond the measuring, which is timed separately with ``--plan``), and the ratio of
that time to the target's 900 s (below 1: the target holds).
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
I13 = ROOT / "tests" / "data" / "realdata" / "i13-24737-tiff"
TARGET_S = 900.0


def _nanoct(*args: str) -> float:
    """Run one nanoct command quietly; its wall-clock seconds."""
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "nanoct", *args], check=True, env=env, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def main() -> None:
    """Import, stack and generate --like; print the times and the ratio to the target."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=1000)
    parser.add_argument("--bins", default="2,1")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; workers {args.workers}")
    with tempfile.TemporaryDirectory() as tmp:
        scan = Path(tmp) / "i13"
        seconds = _nanoct(
            "import", str(I13 / "tiffs"), "--flats", str(I13 / "flat_00001.tiff"), "--darks",
            str(I13 / "dark_00001.tiff"), "--angles", str(I13 / "angles.txt"), "--angles-select", "10:101",
            "--center-offset", "auto", "--out", str(scan), "-q",
        )  # fmt: skip
        print(f"import               {seconds:7.1f} s")
        seconds = _nanoct("stack", str(scan), "-w", str(args.workers), "-q")
        print(f"stack (motion, axis) {seconds:7.1f} s")
        for b in (int(v) for v in args.bins.split(",")):
            out = Path(tmp) / f"matched-bin{b}"
            like = ["generate", "--like", str(scan), "--bin", str(b), "--n", str(args.n), "--out", str(out)]
            plan = _nanoct(*like, "--plan")
            seconds = _nanoct(*like, "-w", str(args.workers), "-q")
            per = (seconds - plan) / args.n
            at_1000 = plan + 1000 * per
            print(
                f"generate --like --bin {b} (image {160 // b}): {args.n} pairs in {seconds:.1f} s "
                f"(measuring {plan:.1f} s, {per * 1000:.1f} ms/pair); 1,000 pairs: {at_1000:.0f} s; "
                f"ratio to the {TARGET_S:.0f} s target {at_1000 / TARGET_S:.3f}"
            )


if __name__ == "__main__":
    main()
