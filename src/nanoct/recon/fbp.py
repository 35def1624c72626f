"""Filtered back projection for parallel and flat-detector fan beam.

One implementation for both geometries: ramp filtering of each projection (the band-limited
Ram-Lak kernel, optionally apodised by a Hann window) followed by a pixel-driven back
projection with linear interpolation on the detector. For fan beam the projections are first
rescaled to a virtual detector through the rotation axis and cosine-weighted, and the back
projection carries the distance weight ``1/U^2`` (Kak & Slaney, ch. 3.4.2); ASTRA's CPU FBP
covers parallel beam only and is used in the tests as an independent reference.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from ..core.geometry import Geometry
from ..core.operators import RayTransform
from ..core.validation import check_array, check_choice
from .params import MethodParams, resolve_geometry
from .result import ReconResult

__all__ = ["FILTERS", "FbpParams", "fbp", "ramp_filter", "ramp_response"]

FILTERS = ("ram-lak", "hann")


def ramp_filter(sino: np.ndarray, spacing: float, filter: str = "ram-lak") -> np.ndarray:
    """Filter each row of a sinogram with the ramp filter.

    Parameters
    ----------
    sino : ndarray of shape (K, L)
        Projections, one per row.
    spacing : float
        Detector sample spacing (in image pixels, at the rotation axis).
    filter : {"ram-lak", "hann"}
        Ram-Lak (band-limited ramp, spatial-domain discretisation, which has no DC bias) or
        Ram-Lak times a Hann window.

    Returns
    -------
    ndarray of shape (K, L), float64
        ``spacing * (h * p)`` for each projection p: the discrete convolution approximating
        the ramp-filtered projection.
    """
    n_det = sino.shape[1]
    size = int(2 ** np.ceil(np.log2(2 * n_det)))
    spectrum = np.fft.rfft(sino, n=size, axis=1) * ramp_response(size, spacing, filter)[: size // 2 + 1]
    return spacing * np.fft.irfft(spectrum, n=size, axis=1)[:, :n_det]


def ramp_response(size: int, spacing: float, filter: str = "ram-lak") -> np.ndarray:
    """The DFT (length ``size``) of :func:`ramp_filter`'s spatial kernel (without its ``spacing`` factor).

    Parameters
    ----------
    size : int
        Transform length (the padded detector).
    spacing : float
        Detector sample spacing.
    filter : {"ram-lak", "hann"}
        Ram-Lak, or Ram-Lak times a Hann window.

    Returns
    -------
    ndarray of shape (size,), float64
    """
    check_choice(filter, "filter", FILTERS)
    n = np.concatenate([np.arange(0, size // 2 + 1), np.arange(-(size // 2) + 1, 0)])
    kernel = np.zeros(size)
    kernel[0] = 1.0 / (4 * spacing**2)
    odd = n % 2 == 1
    kernel[odd] = -1.0 / (np.pi * n[odd] * spacing) ** 2
    response = np.real(np.fft.fft(kernel))
    if filter == "hann":
        freq = np.abs(np.fft.fftfreq(size))  # cycles per sample, Nyquist at 0.5
        response *= 0.5 + 0.5 * np.cos(2 * np.pi * freq)
    return response


@numba.njit(cache=True, parallel=True, fastmath={"contract"})
def _backproject_kernel(filtered, phis, dshift, n, kind_fan, source_radius, spacing, offset):  # pragma: no cover - jit
    """Pixel-driven back projection, image rows split over threads; returns an (n, n) float64 image.

    ``filtered`` (K, L + 3) holds each filtered projection at columns ``1 .. L`` with zeros on
    both sides, so a detector position is clamped into ``[-1, L]`` instead of tested. View
    ``k`` is sampled at detector position ``pos - dshift[k]`` (the per-view shift correction).
    Every pixel sums its views in order ``k = 0 .. K-1``, whatever the number of threads.
    """
    n_views = phis.shape[0]
    n_det = filtered.shape[1] - 3
    centre = (n_det - 1) / 2.0 + offset  # where the rotation axis is seen
    half = (n - 1) / 2.0
    cs = np.cos(phis)
    sn = np.sin(phis)
    image = np.zeros((n, n))
    for row in numba.prange(n):
        r2 = half - row
        acc = np.zeros(n)
        for k in range(n_views):
            c, s = cs[k], sn[k]
            f = filtered[k]
            shift = centre - dshift[k] + 1.0  # + 1: column of detector pixel 0 in ``filtered``
            if kind_fan:
                for col in range(n):
                    r1 = col - half
                    ratio = source_radius / (source_radius - r1 * s + r2 * c)
                    pos = (r1 * c + r2 * s) * ratio / spacing + shift
                    pos = min(max(pos, 0.0), n_det + 1.0)
                    lo = int(pos)
                    frac = pos - lo
                    acc[col] += ratio * ratio * ((1.0 - frac) * f[lo] + frac * f[lo + 1])
            else:
                base = (r2 * s - half * c) / spacing + shift
                step = c / spacing
                for col in range(n):
                    pos = min(max(base + col * step, 0.0), n_det + 1.0)
                    lo = int(pos)
                    frac = pos - lo
                    acc[col] += (1.0 - frac) * f[lo] + frac * f[lo + 1]
        image[row] = acc
    return image


def _backproject(geometry: Geometry, filtered: np.ndarray, spacing: float, dshift: np.ndarray) -> np.ndarray:
    """Pixel-driven back projection with linear interpolation, weighted for fan beam."""
    padded = np.zeros((filtered.shape[0], filtered.shape[1] + 3))
    padded[:, 1:-2] = filtered
    return _backproject_kernel(
        padded,
        geometry.angles,
        np.ascontiguousarray(dshift, dtype=np.float64),
        geometry.n,
        geometry.kind == "fan",
        float(geometry.source_radius),
        float(spacing),
        float(geometry.center_offset),
    )


@dataclass(frozen=True)
class FbpParams(MethodParams):
    """The parameters of :func:`fbp`.

    Parameters
    ----------
    filter : {"ram-lak", "hann"}
        Reconstruction filter (default Ram-Lak).
    """

    filter: str = "ram-lak"

    def __post_init__(self) -> None:
        self._set("filter", check_choice(self.filter, "filter", FILTERS))

    def resolve(self, geometry: Geometry) -> dict[str, Any]:
        """The values for ``geometry``; a fan-beam scan must cover a full turn (no short-scan weighting)."""
        if geometry.kind == "fan" and not np.isclose(geometry.angle_range, 2 * np.pi):
            raise ValueError("fan-beam FBP needs a full 2 pi scan (no short-scan weighting)")
        return super().resolve(geometry)


def fbp(op: Geometry | RayTransform, sino: Any, *, shifts: Any = None, **params: Any) -> ReconResult:
    """Filtered back projection, optionally with a per-view detector-shift correction.

    Parameters
    ----------
    op : Geometry or RayTransform
        Scan geometry (parallel over [0, pi) or fan over [0, 2 pi); explicit view angles are
        weighted by :attr:`~nanoct.core.geometry.Geometry.angle_weights`, the rotation-axis offset
        moves the back projection), or an unperturbed ray transform with ``oversample=1``, as
        for the iterative methods.
    sino : array_like of shape (K, L)
        Sinogram of line integrals in pixel units; must be finite.
    shifts : array_like of shape (K,), optional
        Per-view object shift along the detector axis, in image pixels, with the sign and
        units of :func:`~nanoct.recon.dremel.dremel`'s ``motion`` (and its ``shifts0``): view
        ``k`` is back-projected as if its projection were moved by
        ``-shifts[k] * magnification / det_spacing`` detector pixels, so
        ``fbp(g, y, shifts=dremel(g, y).motion)`` is the motion-corrected FBP. For parallel
        beam with ``det_spacing = 1`` the shifts are detector pixels. Default: no correction.
    **params
        The method's parameters: :class:`FbpParams`.

    Returns
    -------
    ReconResult
        ``image`` is the (N, N) float32 reconstruction; ``stop_reason`` is ``"direct"``.
    """
    params = FbpParams.check(op, **params)
    geometry = resolve_geometry(op)
    sino = check_array(sino, "sinogram", shape=geometry.sino_shape).astype(np.float64)
    if shifts is None:
        dshift = np.zeros(geometry.n_angles)
    else:  # object pixels along e_u -> detector pixels
        shifts = check_array(shifts, "shifts", shape=(geometry.n_angles,), dtype=np.float64)
        dshift = shifts * (geometry.magnification / geometry.det_spacing)
    if geometry.kind == "parallel":
        spacing = geometry.det_spacing
        filtered = ramp_filter(sino, spacing, params["filter"])
        scale = 1.0
    else:
        # virtual detector through the rotation axis
        spacing = geometry.det_spacing / geometry.magnification
        u = (np.arange(geometry.n_det) - (geometry.n_det - 1) / 2 - geometry.center_offset) * spacing
        src = geometry.source_radius
        filtered = ramp_filter(sino * (src / np.sqrt(src**2 + u**2)), spacing, params["filter"])
        scale = 0.5  # every ray is measured twice over a full turn
    if geometry.view_angles is None:  # uniform views: one quadrature weight
        scale *= geometry.angle_weights[0]
    else:  # explicit angles: each view weighted by its share of the circle
        filtered *= geometry.angle_weights[:, None]
    image = _backproject(geometry, filtered, spacing, dshift) * scale
    return ReconResult(image=image.astype(np.float32), params={"method": "fbp", **params})
