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
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.errors import NanoctError
from ..core.validation import check_int
from .center import fourier_shift, xcorr_shifts

__all__ = ["row_profiles", "vertical_shifts"]


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
