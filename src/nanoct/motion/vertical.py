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

:func:`vertical_shifts` always returns a shift per view, also where the profiles hold no
structure to register: on a phantom stack whose slices differ by less than the views' own mass
variation it returned -21.9 to +6.1 px where nothing moved. :func:`vertical_motion` keeps the
shifts only when they are significant (:class:`VerticalEstimate`): the aligned profiles must be
clearly more alike than the unaligned ones (their misfit at most :data:`MAX_MISFIT_RATIO` of it),
and their common derivative must stand above the spread of the views about it
(:data:`MIN_PROFILE_SNR`); otherwise it returns zeros and says which test failed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from ..core.validation import check_int
from .center import fourier_shift, xcorr_shifts
from .matching import apply_vertical

__all__ = [
    "MAX_MISFIT_RATIO",
    "MIN_PROFILE_SNR",
    "VerticalEstimate",
    "row_profiles",
    "tilt_from_profiles",
    "vertical_motion",
    "vertical_shifts",
]

#: The aligned profiles' misfit (spread of the tapered derivatives about their mean) may be at
#: most this fraction of the unaligned profiles' for the shifts to count. Measured on the real
#: I13 scan: 0.006-0.04 with a known vertical motion of 0.3-1.4 px RMS, 0.11 and 0.70 on its crop
#: wider than the field of view (1.4 and 0.3 px RMS), 0.93-0.94 on the still scan and crop (whose
#: raw shifts, 0.01 and 0.11 px RMS, are then set to zero); 0.74-0.82 on flat profiles with noise,
#: on a still phantom stack of four slices and on the K11 interior crop (no known motion).
MAX_MISFIT_RATIO = 0.9

#: The aligned profiles' mean derivative energy must be at least this multiple of their spread
#: about it (the structure the registration follows, against the noise). Measured: 86-466 on the
#: I13 scan and its crop, 0.3-3.3 on the flat, phantom and K11 profiles above.
MIN_PROFILE_SNR = 10.0


@dataclass(frozen=True)
class VerticalEstimate:
    """Vertical shifts and whether they are significant (:func:`vertical_motion`).

    Attributes
    ----------
    shifts : ndarray of shape (K,)
        ``v_k`` in detector rows (mean zero); zeros when not ``significant``.
    significant : bool
        Both tests passed.
    misfit_ratio : float
        Misfit of the aligned profiles over that of the unaligned ones (small: the shifts explain
        the differences between views).
    profile_snr : float
        Energy of the aligned profiles' mean derivative over their spread about it.
    raw_rms : float
        RMS of the shifts :func:`vertical_shifts` found (before the guard).
    note : str
        Why the shifts were kept or set to zero, with the thresholds.
    """

    shifts: np.ndarray
    significant: bool
    misfit_ratio: float
    profile_snr: float
    raw_rms: float
    note: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record (without the shifts)."""
        return {
            "significant": self.significant,
            "misfit_ratio": self.misfit_ratio,
            "profile_snr": self.profile_snr,
            "raw_rms": self.raw_rms,
            "note": self.note,
        }


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


def _misfit(slopes: np.ndarray, taper: np.ndarray, shifts: np.ndarray) -> tuple[float, float]:
    """Spread of the tapered derivatives moved back by ``shifts`` about their mean, and the mean's energy."""
    aligned = fourier_shift(slopes, shifts) * taper
    mean = aligned.mean(axis=0)
    return float(np.mean((aligned - mean) ** 2)), float(np.mean(mean**2))


def vertical_motion(
    profiles: Any,
    *,
    max_misfit_ratio: float = MAX_MISFIT_RATIO,
    min_snr: float = MIN_PROFILE_SNR,
    **options: Any,
) -> VerticalEstimate:
    """:func:`vertical_shifts` kept only where the profiles show them (see the module docstring).

    Parameters
    ----------
    profiles : array_like of shape (K, R)
        Row sums of each view (:func:`row_profiles`).
    max_misfit_ratio : float
        Largest misfit of the aligned profiles relative to the unaligned ones.
    min_snr : float
        Smallest energy of the aligned mean derivative relative to the spread about it.
    **options
        ``max_shift`` and ``rounds`` of :func:`vertical_shifts`.

    Returns
    -------
    VerticalEstimate
    """
    v = vertical_shifts(profiles, **options)
    prof = np.asarray(profiles, dtype=np.float64)
    taper = np.hanning(prof.shape[1] + 2)[1:-1]
    slopes = np.gradient(prof, axis=1)
    before, _ = _misfit(slopes, taper, np.zeros_like(v))
    after, energy = _misfit(slopes, taper, v)
    ratio = after / before if before > 0 else 1.0
    snr = energy / after if after > 0 else float("inf")
    raw = float(np.sqrt(np.mean(v**2)))
    tests = f"misfit ratio {ratio:.3f} (at most {max_misfit_ratio}), profile SNR {snr:.3g} (at least {min_snr})"
    if ratio <= max_misfit_ratio and snr >= min_snr:
        return VerticalEstimate(v, True, ratio, snr, raw, f"vertical shifts kept: {tests}")
    why = "the aligned row profiles are not clearly more alike than the unaligned ones"
    if snr < min_snr:
        why = "the row profiles hold too little structure above their noise"
    note = f"no vertical motion estimated ({raw:.2f} px RMS found and set to zero): {why}; {tests}"
    return VerticalEstimate(np.zeros_like(v), False, ratio, snr, raw, note)


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
