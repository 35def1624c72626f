"""The software environment a result was obtained in: versions, threads, platform.

Training and reconstruction results depend on library versions and on thread counts (the
order of floating-point sums changes with them), so a report states them in its header and
its JSON.
"""

from __future__ import annotations

import os
import platform
from importlib import metadata
from typing import Any

__all__ = ["PACKAGES", "THREAD_VARIABLES", "environment_info", "format_environment"]

#: Distributions whose versions a report states, by the name pip knows them under.
PACKAGES = (
    "nanoct",
    "numpy",
    "scipy",
    "torch",
    "astra-toolbox",
    "numba",
    "zarr",
    "FrEIA",
    "scikit-image",
    "dask",
)
#: Environment variables that set thread counts of the numerical libraries.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS")


def _version(distribution: str) -> str | None:
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return None


def _numpy_blas() -> str | None:
    try:
        import numpy as np

        blas = np.show_config(mode="dicts")["Build Dependencies"]["blas"]
        return f"{blas.get('name', '?')} {blas.get('version', '?')}".strip()
    except Exception:  # older numpy or an unusual build: the BLAS name is a nicety
        return None


def _torch_info() -> dict[str, Any] | None:
    try:
        import torch
    except ImportError:
        return None
    return {
        "num_threads": torch.get_num_threads(),
        "num_interop_threads": torch.get_num_interop_threads(),
        "deterministic_algorithms": torch.are_deterministic_algorithms_enabled(),
        # the CPU kernels' instruction set (oneDNN/ATen): another one sums in another order
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "cuda": torch.version.cuda,
        "cuda_available": torch.cuda.is_available(),
    }


def _numba_threads() -> int | None:
    try:
        import numba
    except ImportError:
        return None
    return int(numba.get_num_threads())


def environment_info(packages: tuple[str, ...] = PACKAGES, threads: bool = True) -> dict[str, Any]:
    """Versions of Python and the numerical libraries, thread settings and the platform.

    Parameters
    ----------
    packages : tuple of str
        Distributions to report (default :data:`PACKAGES`); one not installed gives None.
    threads : bool
        Also import torch and numba for their thread counts (torch takes a second or two to
        import the first time).

    Returns
    -------
    dict
        JSON-serialisable: ``python``, ``implementation``, ``platform``, ``machine``,
        ``cpu_count``, ``cpu_affinity`` (CPUs this process may use), ``packages``
        (``{name: version or None}``), ``numpy_blas``, ``thread_variables`` (values of
        :data:`THREAD_VARIABLES`, None when unset) and, with ``threads``, ``torch``
        (``num_threads``, ``num_interop_threads``, ``deterministic_algorithms``, ``cpu_capability``, ``cuda``,
        ``cuda_available``; None without torch) and ``numba_threads``.
    """
    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    info: dict[str, Any] = {
        "python": platform.python_version(),
        "implementation": platform.python_implementation(),
        "platform": platform.platform(),
        "machine": platform.machine(),
        "cpu_count": os.cpu_count(),
        "cpu_affinity": affinity,
        "packages": {name: _version(name) for name in packages},
        "numpy_blas": _numpy_blas(),
        "thread_variables": {var: os.environ.get(var) for var in THREAD_VARIABLES},
    }
    if threads:
        info["torch"] = _torch_info()
        info["numba_threads"] = _numba_threads()
    return info


def format_environment(info: dict[str, Any]) -> str:
    """One Markdown paragraph for a report header from :func:`environment_info`'s result."""
    packages = ", ".join(f"{name} {version or 'not installed'}" for name, version in info["packages"].items())
    parts = [f"Python {info['python']} ({info['implementation']}) on {info['platform']}"]
    parts.append(f"{info['cpu_affinity'] or info['cpu_count']} usable CPU(s)")
    parts.append(packages)
    if info.get("numpy_blas"):
        parts.append(f"numpy BLAS {info['numpy_blas']}")
    torch = info.get("torch")
    if torch:
        cuda = (
            f"CUDA {torch['cuda']}" + ("" if torch["cuda_available"] else " (no GPU visible)")
            if torch["cuda"]
            else "CPU"
        )
        parts.append(
            f"torch threads {torch['num_threads']} (inter-op {torch['num_interop_threads']}), {cuda}, "
            f"deterministic algorithms {'on' if torch['deterministic_algorithms'] else 'off'}"
        )
    if info.get("numba_threads") is not None:
        parts.append(f"numba threads {info['numba_threads']}")
    set_vars = [f"{k}={v}" for k, v in info["thread_variables"].items() if v is not None]
    parts.append("thread variables: " + (", ".join(set_vars) if set_vars else "none set"))
    return "Environment: " + "; ".join(parts) + ".\n"
