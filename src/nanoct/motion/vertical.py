"""Vertical shift per view from the projections' row profiles (no reconstruction needed).

In parallel beam the rotation axis runs along the detector columns, so the sum of a projection
over a detector row is the mass of the slice that row sees, whatever the angle:
``M_k(z) = sum_x m_k(z, x) = M(z + v_k)`` for a view moved vertically by ``v_k`` (detector rows;
``m_k(z, x) = Q_k(z + v_k, x)``, the sign of :mod:`nanoct.motion.matching`). Every view's
profile is the same curve moved by its own shift: :func:`vertical_shifts` registers each profile
to the median of the aligned profiles by sub-pixel cross-correlation of their derivatives (a
constant open-beam level adds a constant per row and drops out), and repeats with the new
reference. The mean shift is not determined (a vertical translation of the object) and is set
to zero.

For an object wider than the field of view the mass seen by a row changes with the angle, but
smoothly; its edges in ``z`` (top and bottom of features) still carry the shift.

The same fact gives the in-plane tilt of the axis on the detector without opposite views (a
limited-angle tilt series): only when the projections are summed perpendicular to the axis do
all views share one profile. :func:`tilt_from_profiles` rotates every projection back by a
candidate tilt, aligns the profiles vertically, and takes the tilt that leaves them most alike
(a common-line criterion: every parallel projection holds the object's projection onto the axis).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.errors import NanoctError
from ..core.validation import check_int
from .center import fourier_shift, xcorr_shifts
from .matching import apply_vertical

__all__ = ["row_profiles", "tilt_from_profiles", "vertical_shifts"]


def row_profiles(projections: Any) -> np.ndarray:
    """``(K, R)`` row sums of ``(K, R, L)`` projections (line integrals)."""
    proj = np.asarray(projections, dtype=np.float64)
    if proj.ndim != 3:
        raise NanoctError(f"projections have shape {proj.shape}; expected (views, rows, columns)")
    return proj.sum(axis=2)


def vertical_shifts(profiles: Any, *, max_shift: float | None = None, rounds: int = 3) -> np.ndarray:
    """Vertical shift ``v_k`` per view from its row profile (see the module docstring).

    Parameters
    ----------
    profiles : array_like of shape (K, R)
        Row sums of each view (:func:`row_profiles`); a stack's store gives them slice by slice.
    max_shift : float, optional
        Largest ``|v_k|`` searched (default a quarter of the rows).
    rounds : int
        Rounds of register-to-reference.

    Returns
    -------
    ndarray of shape (K,)
        ``v_k`` in detector rows, mean zero.
    """
    prof = np.asarray(profiles, dtype=np.float64)
    if prof.ndim != 2 or prof.shape[1] < 4:
        raise NanoctError(f"row profiles of shape {prof.shape}: need (views, rows) with at least 4 rows")
    if not np.isfinite(prof).all():
        raise NanoctError("the row profiles hold NaN or infinite values")
    check_int(rounds, "rounds", 1)
    limit = prof.shape[1] / 4 if max_shift is None else float(max_shift)
    taper = np.hanning(prof.shape[1] + 2)[1:-1]
    slopes = np.gradient(prof, axis=1)
    v = np.zeros(prof.shape[0])
    for _ in range(rounds):
        reference = np.median(fourier_shift(slopes, v), axis=0)
        lag = xcorr_shifts(np.broadcast_to(reference * taper, prof.shape), slopes * taper, max_shift=limit)
        v = lag - lag.mean()
    return v


def tilt_from_profiles(
    projections: Any, *, max_tilt_deg: float = 6.0, step_deg: float = 0.5, margin: int = 8
) -> tuple[float, np.ndarray, np.ndarray]:
    """In-plane tilt of the rotation axis on the detector from the views' row profiles.

    For each candidate ``theta`` on a grid, every projection is rotated by ``-theta`` about the
    detector centre, its row profile taken (``margin`` rows left out at the top and bottom, where
    the rotation brings in repeated edge rows), the profiles aligned by :func:`vertical_shifts`,
    and scored by the spread of their aligned derivatives about their mean, relative to the mean's
    energy. The tilt is the grid minimum refined by a parabola through it and its neighbours.
    Needs no angles and no opposite views; the open beam should be removed first (its level is
    constant along a row and drops out of the derivatives, but not its gradients).

    Parameters
    ----------
    projections : array_like of shape (K, R, L)
        Line integrals.
    max_tilt_deg, step_deg : float
        Grid ``-max_tilt_deg .. max_tilt_deg`` in steps of ``step_deg`` (degrees).
    margin : int
        Rows left out at each end of the profiles.

    Returns
    -------
    tilt_deg : float
        Positive: the axis moves right going down the rows (as
        :class:`~nanoct.motion.axis.AxisTilt`; undone by
        :func:`~nanoct.motion.matching.apply_vertical` with ``tilt_deg``).
    grid, scores : ndarray
        The candidates and their scores.
    """
    proj = np.asarray(projections, dtype=np.float32)
    if proj.ndim != 3 or proj.shape[1] < 2 * margin + 8:
        raise NanoctError(f"projections of shape {proj.shape}: need (views, rows, columns) with {2 * margin + 8} rows")
    grid = np.arange(-max_tilt_deg, max_tilt_deg + 1e-9, step_deg)
    scores = np.empty(grid.size)
    still = np.zeros(proj.shape[0])
    for i, theta in enumerate(grid):
        profiles = row_profiles(apply_vertical(proj, still, float(theta))[:, margin:-margin])
        aligned = np.gradient(fourier_shift(profiles, vertical_shifts(profiles)), axis=1)
        mean = aligned.mean(axis=0)
        scores[i] = np.mean((aligned - mean) ** 2) / max(float(np.mean(mean**2)), 1e-30)
    best = int(np.argmin(scores))
    tilt = float(grid[best])
    if 0 < best < grid.size - 1:
        low, mid, high = scores[best - 1 : best + 2]
        curvature = low - 2 * mid + high
        if curvature > 0:
            tilt += 0.5 * step_deg * (low - high) / curvature
    return tilt, grid, scores
