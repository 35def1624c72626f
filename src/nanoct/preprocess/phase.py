"""Single-distance phase retrieval (Paganin et al., J. Microsc. 206, 33, 2002).

For a homogeneous object (one ratio ``delta / beta`` of the refractive index decrement to the
absorption index) in the near field, the intensity at distance ``z`` behind it obeys the
transport-of-intensity equation ``I_z = (1 - z delta / mu * laplacian) exp(-mu T)`` with ``mu =
4 pi beta / lambda`` and ``T`` the projected thickness. Its inverse is a low-pass filter on the
open-beam-normalised projection, before ``-log``::

    exp(-mu T) = F^-1[ F[I_z / I_0] / (1 + pi * lambda * z * (delta / beta) * |f|^2) ]

with ``f`` the spatial frequency in cycles per metre (``|k|^2 = 4 pi^2 |f|^2``), ``lambda = h c /
E`` (``1.23984198e-9 m keV / E``). ``-log`` of the result is the attenuation line integral ``mu
T``. The projection is padded to a fast FFT length of at least twice its size by repeating its
edges (nabu's default), so that the filter's wrap-around does not mix the sides.
"""

from __future__ import annotations

import numpy as np
from scipy import fft

from ..core.errors import NanoctError

__all__ = ["HC_KEV_M", "paganin", "paganin_filter", "wavelength_m"]

#: Planck's constant times the speed of light, in keV metres (CODATA 2018).
HC_KEV_M = 1.239841984e-9


def wavelength_m(energy_kev: float) -> float:
    """The photon wavelength in metres at ``energy_kev``."""
    return HC_KEV_M / energy_kev


def _pixel_sizes(pixel_size_m: float | tuple[float, float]) -> tuple[float, float]:
    """``(horizontal, vertical)`` pixel sizes from a scalar or a pair."""
    sizes = np.broadcast_to(np.asarray(pixel_size_m, np.float64), (2,))
    return float(sizes[0]), float(sizes[1])


def paganin_filter(
    shape: tuple[int, int],
    *,
    delta_beta: float,
    energy_kev: float,
    distance_m: float,
    pixel_size_m: float | tuple[float, float],
) -> np.ndarray:
    """The filter ``1 / (1 + pi lambda z (delta/beta) |f|^2)`` on the grid of ``scipy.fft.rfft2``.

    Parameters
    ----------
    shape : (int, int)
        ``(rows, columns)`` of the (padded) image.
    delta_beta, energy_kev, distance_m : float
        ``delta / beta``, the photon energy in keV and the propagation distance in metres.
    pixel_size_m : float or (float, float)
        Detector pixel size in metres (horizontal, vertical).

    Returns
    -------
    ndarray of shape (rows, columns // 2 + 1), float64
    """
    px, py = _pixel_sizes(pixel_size_m)
    fy = np.fft.fftfreq(shape[0], d=py)
    fx = np.fft.rfftfreq(shape[1], d=px)
    f2 = fy[:, None] ** 2 + fx[None, :] ** 2
    return 1.0 / (1.0 + np.pi * wavelength_m(energy_kev) * distance_m * delta_beta * f2)


def _check(delta_beta: float, energy_kev: float, distance_m: float, pixel_size_m: float | tuple[float, float]) -> None:
    checks = {
        "--delta-beta": delta_beta,
        "--energy-kev": energy_kev,
        "--distance-m": distance_m,
        "--pixel-size-m": min(_pixel_sizes(pixel_size_m)),
    }
    for name, value in checks.items():
        if not (np.isfinite(value) and value > 0):
            raise NanoctError(f"{name} {value} must be a positive number (Paganin phase retrieval)")


def paganin(
    transmission: np.ndarray,
    *,
    delta_beta: float,
    energy_kev: float,
    distance_m: float,
    pixel_size_m: float | tuple[float, float],
) -> np.ndarray:
    """Paganin's single-distance phase retrieval of each projection (before ``-log``).

    Parameters
    ----------
    transmission : ndarray of shape (K, R, L)
        Open-beam-normalised projections ``I_z / I_0`` (air at 1), one per view.
    delta_beta : float
        Ratio of the refractive index decrement to the absorption index of the material.
    energy_kev : float
        Photon energy in keV.
    distance_m : float
        Sample-to-detector propagation distance in metres (the effective distance for a
        divergent beam).
    pixel_size_m : float or (float, float)
        Detector pixel size in metres, (horizontal, vertical) if they differ (after binning).

    Returns
    -------
    ndarray of shape (K, R, L), float32
        The filtered projections; their ``-log`` is the attenuation line integral ``mu T``.

    Raises
    ------
    NanoctError
        For a parameter that is not a positive number or projections that are not 3-D and finite.
    """
    _check(delta_beta, energy_kev, distance_m, pixel_size_m)
    data = np.asarray(transmission)
    if data.ndim != 3 or not np.all(np.isfinite(data)):
        raise NanoctError(f"projections of shape {data.shape} must be (views, rows, columns) and finite")
    rows, cols = data.shape[1:]
    padded = (fft.next_fast_len(2 * rows, real=True), fft.next_fast_len(2 * cols, real=True))
    top, left = (padded[0] - rows) // 2, (padded[1] - cols) // 2
    pad = ((top, padded[0] - rows - top), (left, padded[1] - cols - left))
    filt = paganin_filter(
        padded, delta_beta=delta_beta, energy_kev=energy_kev, distance_m=distance_m, pixel_size_m=pixel_size_m
    )
    out = np.empty(data.shape, np.float32)
    for k, view in enumerate(data):
        spectrum = fft.rfft2(np.pad(view.astype(np.float64), pad, mode="edge"))
        out[k] = fft.irfft2(spectrum * filt, s=padded)[top : top + rows, left : left + cols]
    return out
