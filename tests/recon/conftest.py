"""Shared helpers of the reconstruction tests: consistent (noise-free) data and the PSNR used in the checks."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.geometry import get_preset
from nanoct.core.operators import system_matrix
from nanoct.sim.phantoms import random_phantom


def _consistent(name: str, seed: int = 5):
    g = get_preset(name)
    x = random_phantom(np.random.default_rng(seed), g.n).astype(np.float32)
    y = (system_matrix(g) @ x.ravel()).reshape(g.sino_shape)
    return g, x, y


def _psnr(x, gt):
    return 10 * np.log10((gt.max() - gt.min()) ** 2 / np.mean((x - gt) ** 2))


@pytest.fixture
def consistent():
    """``consistent(name, seed=5) -> (geometry, phantom, sinogram)``: a preset with exact, noise-free data."""
    return _consistent


@pytest.fixture
def psnr():
    """``psnr(x, gt)`` in dB with data range ``max(gt) - min(gt)`` (no input checks, unlike evaluation.metrics)."""
    return _psnr
