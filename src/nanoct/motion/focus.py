"""The slow part of the horizontal motion by autofocus: the sharpest reconstruction over a smooth model.

Projection matching compares each view with the reprojection of a reconstruction from the other
views. Motion that changes slowly from view to view escapes it: the sinogram trace of every
edge is moved alike in neighbouring views, the reconstruction bends the edge to follow, and its
reprojection then agrees with the moved view (measured on the real I13 crop wider than the field
of view: of a smooth motion of 0.97 px RMS, matching left 0.98 px). Where the whole object is seen
the views' centroids fix such motion; where it is wider than the field of view they do not.

What slow motion does change is the sharpness of the slice: a point whose trace is bent becomes a
small curve, an edge a double edge. :func:`focus_smooth` therefore writes the horizontal shifts as
``d = d0 + sum_j c_j cos(pi j (k + 1/2) / K)`` (the first ``modes`` cosines over the view index
``k``, with ``j = 0``, the axis, optionally) and minimises the total variation of filtered back
projections of a few slices over ``c`` by L-BFGS, with its exact gradient. The filtered sinograms
are computed once, from the rows extended smoothly beyond the detector edges
(:func:`~nanoct.motion.matching.extend_edges`); only the back projection depends on ``d``, and only
the disc inside the field of view is scored, so mass outside the field of view costs nothing.
Fast, view-to-view motion is left to projection matching, which sees it well: per-view
autofocus follows the noise instead (1.5-1.8 px RMS on the same crop).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
from scipy.optimize import minimize

from ..core.validation import check_int
from ..recon.fbp import ramp_filter
from .matching import extend_edges, views_and_angles

__all__ = ["FocusResult", "focus_smooth", "smooth_basis", "tv_score"]


@dataclass(frozen=True)
class FocusResult:
    """Shifts found by :func:`focus_smooth`.

    Attributes
    ----------
    horizontal : ndarray of shape (K,)
        ``d_k`` (detector pixels, the sign of :func:`~nanoct.recon.stack.corrected_fbp`).
    score_start, score : float
        Total variation of the scored slices at the start and at the end.
    iterations : int
        L-BFGS iterations.
    accepted : bool
        False when a cosine ended at its bound: the search ran to the degenerate minimum far
        from ``d0`` (flat slices from views read beyond the detector; seen on a 22 x 26 crop of
        a flat interior), and ``horizontal`` is ``d0`` unchanged.
    """

    horizontal: np.ndarray
    score_start: float
    score: float
    iterations: int
    accepted: bool = True


def smooth_basis(n_views: int, modes: int, constant: bool = False) -> np.ndarray:
    """Columns ``cos(pi j (k + 1/2) / K)`` for ``j = 1 .. modes`` (and ``j = 0`` when ``constant``)."""
    k = np.arange(n_views) + 0.5
    j = np.arange(0 if constant else 1, modes + 1)
    return np.cos(np.pi * np.outer(k, j) / n_views)


@numba.njit(parallel=True, fastmath=True, cache=True)
def _back_project(filtered, cos, sin, shifts, centre, n):  # pragma: no cover - jit
    """Slices ``(R, n, n)``: view ``k`` read at ``centre + x cos + y sin - d_k`` (linear interpolation)."""
    n_rows, n_views, width = filtered.shape
    half = (n - 1) / 2.0
    out = np.zeros((n_rows, n, n))
    for index in numba.prange(n_rows * n):
        r, i = index // n, index % n
        y = i - half
        for j in range(n):
            x = j - half
            total = 0.0
            for k in range(n_views):
                pos = min(max(centre + x * cos[k] + y * sin[k] - shifts[k], 0.0), width - 1.000001)
                lo = int(pos)
                frac = pos - lo
                total += filtered[r, k, lo] + frac * (filtered[r, k, lo + 1] - filtered[r, k, lo])
            out[r, i, j] = total
    return out


@numba.njit(parallel=True, fastmath=True, cache=True)
def _shift_gradient(filtered, cos, sin, shifts, centre, weight):  # pragma: no cover - jit
    """``d/d d_k`` of ``sum weight * slices``: minus the slope of view ``k`` where each pixel reads it."""
    n_rows, n_views, width = filtered.shape
    n = weight.shape[1]
    half = (n - 1) / 2.0
    grad = np.zeros(n_views)
    for k in numba.prange(n_views):
        total = 0.0
        for r in range(n_rows):
            for i in range(n):
                y = i - half
                for j in range(n):
                    w = weight[r, i, j]
                    if w != 0.0:
                        pos = centre + (j - half) * cos[k] + y * sin[k] - shifts[k]
                        if 0.0 <= pos <= width - 1.000001:
                            lo = int(pos)
                            total += w * (filtered[r, k, lo + 1] - filtered[r, k, lo])
        grad[k] = -total
    return grad


def tv_score(images: np.ndarray, mask: np.ndarray, eps: float) -> tuple[float, np.ndarray]:
    """Smoothed total variation ``sum sqrt(gx^2 + gy^2 + eps^2)`` over ``mask`` and its gradient.

    Parameters
    ----------
    images : ndarray of shape (R, n, n)
    mask : ndarray of bool, shape (n - 1, n - 1)
        Where the forward differences are scored.
    eps : float
        Smoothing of the absolute value (same unit as the differences).

    Returns
    -------
    score : float
    gradient : ndarray of shape (R, n, n)
    """
    gx = np.diff(images, axis=1)[:, :, :-1]
    gy = np.diff(images, axis=2)[:, :-1, :]
    magnitude = np.sqrt(gx**2 + gy**2 + eps**2)
    ux, uy = np.where(mask, gx / magnitude, 0.0), np.where(mask, gy / magnitude, 0.0)
    grad = np.zeros_like(images)
    grad[:, 1:, :-1] += ux
    grad[:, :-1, :-1] -= ux + uy
    grad[:, :-1, 1:] += uy
    return float(magnitude[:, mask].sum()), grad


def focus_smooth(
    projections: Any,
    angles: Any,
    center_offset: float,
    horizontal: Any = None,
    *,
    modes: int = 12,
    axis: bool = False,
    max_rows: int = 16,
    max_columns: int = 160,
    max_shift: float | None = None,
    filter: str = "hann",
) -> FocusResult:
    """Smooth horizontal motion that makes the sharpest slices (see the module docstring).

    Parameters
    ----------
    projections : array_like of shape (K, R, L)
        Line integrals, vertical motion already removed; views in acquisition order.
    angles : array_like of shape (K,)
        View angles in radians.
    center_offset : float
        Rotation axis minus the detector centre (detector pixels).
    horizontal : array_like of shape (K,), optional
        Starting shifts ``d0`` (default zero); the found smooth part is added to them.
    modes : int
        Number of cosines over the view index (motion slower than ``K / modes`` views).
    axis : bool
        Also fit the constant (a correction of the axis, returned in the shifts' constant).
    max_rows : int
        Slices scored (spread over the rows).
    max_columns : int
        Wider detectors are binned to at most this many columns (rows alike) for the search.
    max_shift : float, optional
        Bound on each cosine's amplitude (detector pixels; default ``max(2, L / 16)``). The total
        variation has a degenerate minimum far away, where every view reads the flat extension
        beyond the detector; the bound keeps the search near ``d0``.
    filter : {"hann", "ram-lak"}
        Reconstruction filter of the scored slices.

    Returns
    -------
    FocusResult
    """
    proj, phi = views_and_angles(projections, angles, np.float64)
    modes = check_int(modes, "modes", 1)
    n_views, n_rows, n_det = proj.shape
    start = np.zeros(n_views) if horizontal is None else np.asarray(horizontal, dtype=np.float64).copy()
    factor = max(1, int(np.ceil(n_det / check_int(max_columns, "max_columns", 8))))
    rows = np.unique(np.linspace(0, n_rows - factor, min(max_rows, max(n_rows // factor, 1))).round().astype(int))
    sinos = np.stack([proj[:, r : r + factor].mean(axis=1) for r in rows])  # (S, K, L)
    n = n_det // factor
    sinos = sinos[:, :, : n * factor].reshape(len(rows), n_views, n, factor).mean(axis=3)
    pad = n // 2
    filtered = np.stack([ramp_filter(s, 1.0, filter) for s in extend_edges(sinos, pad)]) * (np.pi / n_views)
    centre = (n + 2 * pad - 1) / 2 + ((n_det - 1) / 2 + center_offset + 0.5) / factor - 0.5 - (n - 1) / 2
    cos, sin = np.cos(phi), np.sin(phi)
    grid = np.arange(n - 1) - (n - 2) / 2
    mask = np.hypot(*np.meshgrid(grid, grid, indexing="ij")) < 0.45 * n
    basis = smooth_basis(n_views, modes, constant=axis)
    first = _back_project(filtered, cos, sin, start / factor, centre, n)
    eps = 1e-3 * float(np.sqrt(np.mean(np.diff(first, axis=2) ** 2)) + 1e-30)
    scale = tv_score(first, mask, eps)[0]

    def objective(coef: np.ndarray, columns: int) -> tuple[float, np.ndarray]:
        shifts = (start + basis[:, :columns] @ coef) / factor
        value, weight = tv_score(_back_project(filtered, cos, sin, shifts, centre, n), mask, eps)
        grad = _shift_gradient(filtered, cos, sin, shifts, centre, weight) / factor
        return value / scale, basis[:, :columns].T @ grad / scale

    bound = max(2.0, n_det / 16) if max_shift is None else float(max_shift)
    coef, iterations, value = np.zeros(0), 0, 1.0
    for columns in _continuation(basis.shape[1], int(axis)):  # slow cosines first: stay in the basin of d0
        coef = np.concatenate([coef, np.zeros(columns - coef.size)])
        limits = [(-bound, bound)] * columns
        result = minimize(objective, coef, args=(columns,), jac=True, method="L-BFGS-B", bounds=limits)
        coef, iterations, value = result.x, iterations + int(result.nit), float(result.fun)
    if np.any(np.abs(coef) >= 0.99 * bound):
        return FocusResult(start, scale, value * scale, iterations, accepted=False)
    return FocusResult(start + basis @ coef, scale, value * scale, iterations)


def _continuation(columns: int, extra: int) -> list[int]:
    """Numbers of leading basis columns to fit in turn: 2, 4, 8, ... cosines, then all."""
    counts = [extra + m for m in (2, 4, 8) if extra + m < columns]
    return [*counts, columns]
