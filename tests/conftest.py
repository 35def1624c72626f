"""Shared fixtures: operator cache in a temporary directory, a tiny data set; ``scan_cases`` importable."""

from __future__ import annotations

import os

# torch's OpenMP threads wait passively (as under ``nanoct.study``), set before torch is first imported: with
# libgomp's spinning default, the training tests' tiny steps ran several times slower on a shared 2-core machine.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import sys
from pathlib import Path

import numpy as np
import pytest

from nanoct.core.geometry import get_preset
from nanoct.sim.generate import generate_dataset

sys.path.insert(0, str(Path(__file__).resolve().parent))  # shared test helpers: scan_cases


def pytest_runtest_call(item):
    """One torch thread as every test starts (after its fixtures), once torch is imported: the tests' networks
    and images are tiny, and a second intra-op thread made their steps 5-15 times slower where another job shared
    the cores (a UNet step on 4 x 31 x 31 images: 0.14 s with two threads, 0.01 s with one). Set for each test,
    since numba's OpenMP kernels set the shared OpenMP thread count back to all cores; tests about threads set
    their own.
    """
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)


@pytest.fixture(autouse=True, scope="session")
def _operator_cache(tmp_path_factory):
    """Keep the on-disk system-matrix cache out of the home directory."""
    mp = pytest.MonkeyPatch()
    mp.setenv("NANOCT_CACHE", str(tmp_path_factory.mktemp("nanoct-cache")))
    yield
    mp.undo()


@pytest.fixture(scope="session")
def tiny_store(tmp_path_factory):
    """A complete tiny-parallel data set of 12 samples (made in-process)."""
    path = tmp_path_factory.mktemp("data") / "tiny"
    return generate_dataset(
        path, get_preset("tiny-parallel"), 12, seed=3, workers=0, progress=False, split_fractions=(0.5, 0.25, 0.25)
    )


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
