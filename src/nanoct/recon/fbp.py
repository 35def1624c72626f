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

__all__ = ["FILTERS", "FbpParams", "fbp", "ramp_filter"]

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
    check_choice(filter, "filter", FILTERS)
    n_det = sino.shape[1]
    size = int(2 ** np.ceil(np.log2(2 * n_det)))
    n = np.concatenate([np.arange(0, size // 2 + 1), np.arange(-(size // 2) + 1, 0)])
    kernel = np.zeros(size)
    kernel[0] = 1.0 / (4 * spacing**2)
    odd = n % 2 == 1
    kernel[odd] = -1.0 / (np.pi * n[odd] * spacing) ** 2
    response = np.real(np.fft.fft(kernel))
    if filter == "hann":
        freq = np.abs(np.fft.fftfreq(size))  # cycles per sample, Nyquist at 0.5
        response *= 0.5 + 0.5 * np.cos(2 * np.pi * freq)
    spectrum = np.fft.rfft(sino, n=size, axis=1) * response[: size // 2 + 1]
    return spacing * np.fft.irfft(spectrum, n=size, axis=1)[:, :n_det]


@numba.njit(cache=True, fastmath=False)
def _backproject_kernel(filtered, phis, n, kind_fan, source_radius, spacing, offset):  # pragma: no cover - jit
    n_det = filtered.shape[1]
    centre = (n_det - 1) / 2.0 + offset  # where the rotation axis is seen
    half = (n - 1) / 2.0
    image = np.zeros((n, n))
    for k in range(phis.shape[0]):
        c, s = np.cos(phis[k]), np.sin(phis[k])
        for row in range(n):
            r2 = half - row
            for col in range(n):
                r1 = col - half
                u = r1 * c + r2 * s
                weight = 1.0
                if kind_fan:
                    ratio = source_radius / (source_radius - r1 * s + r2 * c)
                    u *= ratio
                    weight = ratio * ratio
                pos = u / spacing + centre
                lo = int(np.floor(pos))
                frac = pos - lo
                val = 0.0
                if 0 <= lo < n_det:
                    val += (1.0 - frac) * filtered[k, lo]
                if 0 <= lo + 1 < n_det:
                    val += frac * filtered[k, lo + 1]
                image[row, col] += weight * val
    return image


def _backproject(geometry: Geometry, filtered: np.ndarray, spacing: float) -> np.ndarray:
    """Pixel-driven back projection with linear interpolation, weighted for fan beam."""
    return _backproject_kernel(
        np.ascontiguousarray(filtered, dtype=np.float64),
        geometry.angles,
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


def fbp(op: Geometry | RayTransform, sino: Any, **params: Any) -> ReconResult:
    """Filtered back projection of an (unperturbed-model) sinogram.

    Parameters
    ----------
    op : Geometry or RayTransform
        Scan geometry (parallel over [0, pi) or fan over [0, 2 pi); explicit view angles are
        weighted by :attr:`~nanoct.core.geometry.Geometry.angle_weights`, the rotation-axis offset
        moves the back projection), or an unperturbed ray transform with ``oversample=1``, as
        for the iterative methods.
    sino : array_like of shape (K, L)
        Sinogram of line integrals in pixel units; must be finite.
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
    image = _backproject(geometry, filtered, spacing) * scale
    return ReconResult(image=image.astype(np.float32), params={"method": "fbp", **params})
