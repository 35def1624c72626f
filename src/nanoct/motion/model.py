"""A smooth model of per-view shifts: polynomial drift in time plus harmonics of the rotation.

Beamline tools describe a sample's horizontal motion with few parameters: a slow drift (a
low-order polynomial in acquisition time, as nabu's motion estimation fits) and an axis
run-out that repeats every turn (a few harmonics ``cos(h phi), sin(h phi)``, as ESRF ID16A's
correction files hold). :func:`fit_motion_model` fits such a model to per-view estimates by
least squares and reports the RMS of what it leaves out; replacing noisy per-view estimates by
the model averages their noise over all views, at the price of any real motion the model
cannot follow (jitter).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.validation import check_array, check_int

__all__ = ["MotionModel", "fit_motion_model", "motion_basis"]


def motion_basis(angles: Any, degree: int = 3, harmonics: int = 3, times: Any = None) -> np.ndarray:
    """Columns ``1, t, ..., t^degree, cos(h phi), sin(h phi)`` (h = 1..harmonics), ``t`` in [-1, 1].

    Parameters
    ----------
    angles : array_like of shape (K,)
        View angles in radians (in acquisition order).
    degree : int
        Polynomial degree of the drift in time (Legendre polynomials, for a well-conditioned fit).
    harmonics : int
        Number of rotation harmonics.
    times : array_like of shape (K,), optional
        Acquisition times (any unit); default the view index.

    Returns
    -------
    ndarray of shape (K, degree + 1 + 2 * harmonics)
    """
    phi = np.asarray(angles, dtype=np.float64).ravel()
    t = (
        np.arange(phi.size, dtype=np.float64)
        if times is None
        else check_array(times, "times", shape=(phi.size,), dtype=np.float64)
    )
    span = np.ptp(t)
    t = 2 * (t - t.min()) / span - 1 if span > 0 else np.zeros_like(t)
    drift = np.polynomial.legendre.legvander(t, check_int(degree, "degree", 0))
    h = np.arange(1, check_int(harmonics, "harmonics", 0) + 1)
    return np.concatenate([drift, np.cos(phi[:, None] * h), np.sin(phi[:, None] * h)], axis=1)


@dataclass(frozen=True)
class MotionModel:
    """A fitted smooth motion.

    Attributes
    ----------
    shifts : ndarray of shape (K,)
        The model's value at every view.
    coefficients : ndarray
        Least-squares coefficients of :func:`motion_basis`'s columns.
    residual_rms : float
        RMS of the estimates minus the model (pixels): the part the model leaves out.
    degree, harmonics : int
        The model's size.
    """

    shifts: np.ndarray
    coefficients: np.ndarray
    residual_rms: float
    degree: int
    harmonics: int


def fit_motion_model(shifts: Any, angles: Any, degree: int = 3, harmonics: int = 3, times: Any = None) -> MotionModel:
    """Least-squares fit of :func:`motion_basis` to per-view shift estimates.

    Parameters
    ----------
    shifts : array_like of shape (K,)
        Per-view estimates (pixels).
    angles, degree, harmonics, times
        See :func:`motion_basis`.

    Returns
    -------
    MotionModel

    Raises
    ------
    ValueError
        If the model has at least as many parameters as there are views.
    """
    d = check_array(shifts, "shifts", dtype=np.float64).ravel()
    basis = motion_basis(angles, degree, harmonics, times)
    if basis.shape[0] != d.size:
        raise ValueError(f"shifts has {d.size} values but angles has {basis.shape[0]}; give one per view")
    if basis.shape[1] >= d.size:
        raise ValueError(
            f"a model with {basis.shape[1]} parameters (degree={degree}, harmonics={harmonics}) needs more than "
            f"{d.size} views; lower degree or harmonics"
        )
    coef, *_ = np.linalg.lstsq(basis, d, rcond=None)
    fitted = basis @ coef
    return MotionModel(fitted, coef, float(np.sqrt(np.mean((d - fitted) ** 2))), degree, harmonics)
