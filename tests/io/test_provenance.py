"""Environment information for report headers."""

from __future__ import annotations

import json
import platform

import numpy as np
import pytest
import scipy
import torch

from nanoct.io.provenance import PACKAGES, THREAD_VARIABLES, environment_info, format_environment


def test_versions_match_the_imported_libraries(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    monkeypatch.delenv("MKL_NUM_THREADS", raising=False)
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        info = environment_info()
    finally:
        torch.set_num_threads(old)
    assert info["python"] == platform.python_version()
    assert set(info["packages"]) == set(PACKAGES)
    assert info["packages"]["numpy"] == np.__version__
    assert info["packages"]["scipy"] == scipy.__version__
    assert info["packages"]["torch"] == torch.__version__
    assert info["packages"]["astra-toolbox"] and info["packages"]["FrEIA"] and info["packages"]["scikit-image"]
    assert info["torch"]["num_threads"] == 1
    assert info["thread_variables"]["OMP_NUM_THREADS"] == "3" and info["thread_variables"]["MKL_NUM_THREADS"] is None
    assert set(info["thread_variables"]) == set(THREAD_VARIABLES)
    assert isinstance(info["numba_threads"], int) and info["numba_threads"] >= 1
    json.dumps(info, allow_nan=False)
    text = format_environment(info)
    assert f"numpy {np.__version__}" in text and "torch threads 1" in text and "OMP_NUM_THREADS=3" in text


def test_missing_package_and_no_threads():
    info = environment_info(packages=("numpy", "surely-not-a-package-nanoct"), threads=False)
    assert info["packages"] == {"numpy": np.__version__, "surely-not-a-package-nanoct": None}
    assert "torch" not in info and "numba_threads" not in info
    assert "surely-not-a-package-nanoct not installed" in format_environment(info)


@pytest.mark.parametrize("cuda", [None, "12.4"])
def test_format_cuda(cuda):
    info = environment_info(packages=("numpy",), threads=False)
    info["torch"] = {
        "num_threads": 2,
        "num_interop_threads": 2,
        "deterministic_algorithms": True,
        "cuda": cuda,
        "cuda_available": False,
    }
    text = format_environment(info)
    assert ("CUDA 12.4 (no GPU visible)" in text) == (cuda is not None) and "deterministic algorithms on" in text
