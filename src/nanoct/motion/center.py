"""Rotation-axis position from opposite views, kept apart from the per-view motion.

Model of a measured parallel-beam view (detector coordinate ``x = l - (L-1)/2``, pixels)::

    p_k(x) = P(phi_k, x - c + d_k)

with ``P`` the projection of the static object about the rotation axis, ``c`` the axis offset
(:attr:`~nanoct.core.geometry.Geometry.center_offset`) and ``d_k`` the view's shift (the sign of
:func:`~nanoct.recon.dremel.dremel`'s motion). Opposite views see the mirrored projection,
``P(phi + pi, t) = P(phi, -t)``, so the view at ``phi_k`` equals the mirrored view at
``phi_k + pi`` moved by ``2c - d_k - d_j``: :func:`fit_center` measures that lag by sub-pixel
cross-correlation (:func:`xcorr_shifts`) and returns ``c`` given the shifts (zero when unknown).

When the whole object stays inside the field of view, the centroid of each view gives both at
once (:func:`centroid_motion`): the first moment of ``p_k`` over its mass is
``c - d_k + x_c . e_u(phi_k)`` (``x_c`` the object's centre of mass), so the centroids, fitted by
least squares on ``(1, cos phi, sin phi)``, give the axis as the constant and the shifts as
what is left. No reconstruction is needed, and every view counts (opposite views only tie the
first and the last view of a 180-degree scan together).

A constant added to every ``d_k`` and to ``c`` changes no view, and a translation of the object
adds ``a cos(phi_k) + b sin(phi_k)`` to the shifts: neither is determined by the data.
:func:`separate_center` fixes the split: the constant term of the least-squares fit of the
shifts on ``(1, cos phi, sin phi)`` goes into the axis, so that the reported motion has none.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.fft as sfft

from ..core.errors import NanoctError
from ..core.validation import check_array

__all__ = [
    "centroid_motion",
    "fit_center",
    "fourier_shift",
    "opposite_pairs",
    "separate_center",
    "xcorr_shifts",
]


def xcorr_shifts(a: Any, b: Any, max_shift: float | None = None, newton_steps: int = 6) -> np.ndarray:
    """Sub-pixel lag ``tau`` per row such that ``a(x) ~ b(x - tau)`` (``a`` is ``b`` moved right).

    The cross-correlation is computed with zero padding (no wrap-around); its integer peak is
    refined by Newton steps on the band-limited (trigonometric) interpolation of the
    correlation, which is exact for shifted band-limited signals.

    Parameters
    ----------
    a, b : array_like of shape (..., R, L)
        Rows to compare; leading axes are summed (e.g. several slices sharing one shift).
    max_shift : float, optional
        Largest lag searched, in pixels (default: any).
    newton_steps : int
        Refinement steps.

    Returns
    -------
    ndarray of shape (R,), float64
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape or a.ndim < 2:
        raise ValueError(f"xcorr_shifts needs two arrays of the same shape (..., R, L); got {a.shape} and {b.shape}")
    n_det = a.shape[-1]
    size = sfft.next_fast_len(2 * n_det)
    spec = sfft.rfft(a, size, axis=-1, workers=-1) * np.conj(sfft.rfft(b, size, axis=-1, workers=-1))
    spec = spec.reshape(-1, *spec.shape[-2:]).sum(axis=0)  # (R, F)
    corr = sfft.irfft(spec, size, axis=-1, workers=-1)
    lags = np.fft.fftfreq(size, 1.0 / size)
    if max_shift is not None:
        corr = np.where(np.abs(lags) <= max_shift, corr, -np.inf)
    tau = lags[np.argmax(corr, axis=1)].astype(np.float64)
    start = tau.copy()
    omega = 2 * np.pi * np.arange(spec.shape[1]) / size
    weight = np.full(spec.shape[1], 2.0)
    weight[0] = 1.0
    if size % 2 == 0:
        weight[-1] = 1.0
    for _ in range(newton_steps):
        phase = spec * np.exp(1j * omega[None, :] * tau[:, None]) * weight
        first = -(phase.imag * omega).sum(axis=1)
        second = -(phase.real * omega**2).sum(axis=1)
        step = np.where(second < 0, -first / np.where(second < 0, second, -1.0), 0.0)
        tau = np.clip(tau + step, start - 1.0, start + 1.0)
    return tau


def fourier_shift(rows: Any, shifts: Any) -> np.ndarray:
    """Move row ``k`` right by ``shifts[k]`` pixels: ``out(x) = row(x - s)`` (band-limited, zero-padded)."""
    rows = np.asarray(rows, dtype=np.float64)
    n_det = rows.shape[-1]
    size = sfft.next_fast_len(2 * n_det)
    omega = 2 * np.pi * np.arange(size // 2 + 1) / size
    phase = np.exp(-1j * omega * np.asarray(shifts, dtype=np.float64)[:, None])
    spec = sfft.rfft(rows, size, axis=-1, workers=-1) * phase
    return sfft.irfft(spec, size, axis=-1, workers=-1)[..., :n_det]


def opposite_pairs(angles: Any, tolerance: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs of views about ``pi`` apart.

    Parameters
    ----------
    angles : array_like of shape (K,)
        View angles in radians.
    tolerance : float, optional
        Largest accepted ``|phi_j - phi_k - pi|`` (mod ``2 pi``); default 1.01 median view step
        (a 180-degree scan ``k pi / K`` then has its first and last view as the one pair).

    Returns
    -------
    k, j : ndarray of int
        The pairs (each view at most once as ``k``).
    mismatch : ndarray
        ``pi - (phi_j - phi_k)`` mod ``2 pi`` per pair, in radians.
    """
    phi = np.mod(np.asarray(angles, dtype=np.float64), 2 * np.pi)
    if tolerance is None:
        tolerance = 1.01 * float(np.median(np.diff(np.sort(phi)))) if phi.size > 1 else 0.0
    diff = np.mod(phi[None, :] - phi[:, None] - np.pi + np.pi, 2 * np.pi) - np.pi  # phi_j - phi_k - pi, wrapped
    j = np.argmin(np.abs(diff), axis=1)
    mismatch = -diff[np.arange(phi.size), j]
    keep = np.abs(mismatch) <= tolerance
    return np.flatnonzero(keep), j[keep], mismatch[keep]


def fit_center(sinogram: Any, angles: Any, shifts: Any = None, *, max_offset: float | None = None) -> float:
    """Rotation-axis offset ``c`` (detector pixels from the centre) from opposite views.

    Parameters
    ----------
    sinogram : array_like of shape (K, L) or (S, K, L)
        Line integrals; several slices are used together.
    angles : array_like of shape (K,)
        View angles in radians.
    shifts : array_like of shape (K,), optional
        Per-view shifts ``d_k`` (detector pixels) known so far (default none); the views are
        first moved back by them. The opposite view is interpolated linearly in angle to
        exactly ``phi_k + pi`` from its two nearest views (for a 180-degree scan: extrapolated
        from the last two).
    max_offset : float, optional
        Largest ``|c|`` searched (default: any).

    Returns
    -------
    float
        Mean over the opposite pairs of ``c``.

    Raises
    ------
    NanoctError
        If no two views are about 180 degrees apart.
    """
    sino = np.asarray(sinogram, dtype=np.float64)
    sino = sino[None] if sino.ndim == 2 else sino
    phi = np.asarray(angles, dtype=np.float64)
    k, j, mismatch = opposite_pairs(phi)
    if k.size == 0:
        raise NanoctError(
            "no two views are 180 degrees apart (the scan covers less than 180 degrees): give the axis with "
            "--center-offset PIXELS"
        )
    d = np.zeros(phi.size) if shifts is None else check_array(shifts, "shifts", shape=(phi.size,), dtype=np.float64)
    first = fourier_shift(sino[:, k].reshape(-1, sino.shape[2]), np.tile(d[k], sino.shape[0]))
    first = first.reshape(sino.shape[0], k.size, -1)
    second = _opposite_in_angle(sino, phi, d, j, mismatch)
    lag = xcorr_shifts(first, second[..., ::-1], None if max_offset is None else 2 * max_offset)
    return float(np.mean(lag) / 2)


def _opposite_in_angle(
    sino: np.ndarray, phi: np.ndarray, d: np.ndarray, j: np.ndarray, mismatch: np.ndarray
) -> np.ndarray:
    """Views ``j`` moved back by their shifts and interpolated linearly in angle by ``mismatch``."""
    order = np.argsort(phi)
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    direction = np.where(mismatch >= 0, 1, -1)  # towards the exact opposite angle
    neighbour = order[np.clip(rank[j] + direction, 0, order.size - 1)]
    neighbour = np.where(neighbour == j, order[np.clip(rank[j] - direction, 0, order.size - 1)], neighbour)
    step = phi[neighbour] - phi[j]
    weight = np.where(np.abs(step) > 0, mismatch / np.where(step == 0, 1.0, step), 0.0)
    n_s, n_det = sino.shape[0], sino.shape[2]
    here = fourier_shift(sino[:, j].reshape(-1, n_det), np.tile(d[j], n_s)).reshape(n_s, j.size, n_det)
    there = fourier_shift(sino[:, neighbour].reshape(-1, n_det), np.tile(d[neighbour], n_s)).reshape(n_s, j.size, n_det)
    return here + weight[None, :, None] * (there - here)


def separate_center(center: float, shifts: Any, angles: Any) -> tuple[float, np.ndarray]:
    """Move the constant part of the shifts into the axis offset.

    Parameters
    ----------
    center : float
        Axis offset ``c`` (detector pixels) that goes with ``shifts``.
    shifts : array_like of shape (K,)
        Per-view shifts ``d_k``.
    angles : array_like of shape (K,)
        View angles in radians.

    Returns
    -------
    center : float
        ``c - a0``, with ``a0`` the constant of the least-squares fit of the shifts on
        ``(1, cos phi, sin phi)``.
    shifts : ndarray of shape (K,)
        ``d - a0``: the same views (``-c + d_k`` unchanged), with no constant term.
    """
    phi = np.asarray(angles, dtype=np.float64)
    d = np.asarray(shifts, dtype=np.float64)
    basis = np.stack([np.ones_like(phi), np.cos(phi), np.sin(phi)], axis=1)
    coef, *_ = np.linalg.lstsq(basis, d, rcond=None)
    return float(center - coef[0]), d - coef[0]


def centroid_motion(sinogram: Any, angles: Any) -> tuple[float, np.ndarray, float]:
    """Axis offset and per-view shifts from the centroid of every view.

    Parameters
    ----------
    sinogram : array_like of shape (K, L) or (S, K, L)
        Line integrals; several slices are averaged.
    angles : array_like of shape (K,)
        View angles in radians.

    Returns
    -------
    center : float
        Axis offset (detector pixels): the constant of the least-squares fit of the centroids on
        ``(1, cos phi, sin phi)``.
    shifts : ndarray of shape (K,)
        ``d_k`` with no constant and no translation term.
    mass_spread : float
        Largest relative spread (std / mean) over views of a slice's total line integral; the
        centroid is only right when it is small (the object never leaves the detector and the
        flat-field correction holds): :func:`nanoct.motion.stack.estimate_stack_motion` uses it up to 1 %.
    """
    sino = np.asarray(sinogram, dtype=np.float64)
    sino = sino[None] if sino.ndim == 2 else sino
    phi = np.asarray(angles, dtype=np.float64)
    x = np.arange(sino.shape[2]) - (sino.shape[2] - 1) / 2
    mass = sino.sum(axis=2)
    if np.any(mass <= 0):
        return 0.0, np.zeros(phi.size), float("inf")
    spread = float(np.max(mass.std(axis=1) / mass.mean(axis=1)))
    offsets = ((sino * x).sum(axis=2) / mass).mean(axis=0)  # c - d_k + x_c . e_u
    basis = np.stack([np.ones_like(phi), np.cos(phi), np.sin(phi)], axis=1)
    coef, *_ = np.linalg.lstsq(basis, offsets, rcond=None)
    return float(coef[0]), basis @ coef - offsets, spread
