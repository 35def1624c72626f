"""Run one ``nanoct`` command in the benchmark's process, as the shell would, and time it.

Imported by the benchmarks that drive the command line (``semireal_networks.py``, ``bench_cuda.py``,
``coverage_seeds.py``); run as scripts, they find it beside them.
"""

from __future__ import annotations

import time

from nanoct.cli import run


def cli(*args: object) -> float:
    """Run ``nanoct ARGS`` (each argument as ``str``) in this process; its seconds, to 0.01 s.

    Raises
    ------
    SystemExit
        If the command fails: the command line and its status (a failure stops the benchmark).
    """
    start = time.perf_counter()
    code = run([str(a) for a in args])
    if code != 0:
        raise SystemExit(f"nanoct {' '.join(map(str, args))} failed with status {code}")
    return round(time.perf_counter() - start, 2)
