"""Constructed 3-D scans and known motion for the motion tests (imported by them)."""

from __future__ import annotations

import numpy as np
import scipy.ndimage as ndi

from nanoct.sim.analytic import ellipse_sinogram, stack_phantom


def known_motion(angles: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal drift + rotation harmonics + jitter and vertical cubic + jitter (pixels)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(-1, 1, angles.size)
    horizontal = 1.5 * t + 1.0 * np.sin(angles) + 0.6 * np.cos(2 * angles) + 0.3 * rng.standard_normal(angles.size)
    vertical = 1.0 * t**3 - 0.8 * t + 0.25 * rng.standard_normal(angles.size)
    return horizontal, vertical


def moved(projections: np.ndarray, horizontal: np.ndarray, vertical: np.ndarray) -> np.ndarray:
    """``m_k(z, x) = Q_k(z + v_k, x + d_k)``: each projection moved up by ``v_k`` and left by ``d_k``."""
    return np.stack(
        [ndi.shift(p, (-v, -d), order=3, mode="nearest") for p, v, d in zip(projections, vertical, horizontal)]
    )


def gauge_free_rms(estimate: np.ndarray, truth: np.ndarray, angles: np.ndarray, *, vertical: bool = False) -> float:
    """RMS of ``estimate - truth`` less what the data cannot fix (a constant; horizontally also cos and sin)."""
    diff = np.asarray(estimate, dtype=np.float64) - truth
    columns = [np.ones_like(angles)] if vertical else [np.ones_like(angles), np.cos(angles), np.sin(angles)]
    basis = np.stack(columns, axis=1)
    diff = diff - basis @ np.linalg.lstsq(basis, diff, rcond=None)[0]
    return float(np.sqrt(np.mean(diff**2)))


def analytic_projections(angles: np.ndarray, n_det: int, n_rows: int, center: float, seed: int = 2) -> np.ndarray:
    """``(K, R, L)`` exact projections of a stack of ellipse slices about an axis at ``center``.

    The slices' density follows a smooth bump in ``z`` (an object with a top and a bottom inside
    the rows), so that the stack has vertical structure.
    """
    slices = stack_phantom(n_det, n_rows, seed=seed)
    z = np.linspace(-1, 1, n_rows)
    envelope = 0.5 + 0.5 * np.tanh((0.6 - np.abs(z)) * 8) + 0.3 * np.sin(5 * z)
    sinos = [w * ellipse_sinogram(e, angles, n_det, center_offset=center) for w, e in zip(envelope, slices)]
    return np.stack(sinos, axis=1)
