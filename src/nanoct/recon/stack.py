"""Slices of a measured stack with a per-view shift: motion-corrected FBP, reprojection, detector binning.

The motion itself is estimated in :mod:`nanoct.motion`; these are the tools it and ``nanoct stack``
reconstruct and reproject with.

:func:`corrected_fbp` (:func:`nanoct.recon.fbp.fbp` with its per-view shift: each view read at
``u - d_k`` in the back projection) and :func:`reproject` (Joseph's ray-driven projection,
compiled with numba, one view per core at a time) build no matrix, so a 2048^2 slice needs a
few image-sized arrays.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

from ..core.errors import NanoctError
from ..core.geometry import Geometry
from ..core.validation import check_array, check_int
from .fbp import fbp

__all__ = [
    "bin_geometry",
    "bin_sinograms",
    "corrected_fbp",
    "reproject",
    "with_center",
]


@numba.njit(parallel=True, fastmath=True, cache=True)
def _project_shifted(image, image_t, cos, sin, shifts, n_det, centre, spacing):  # pragma: no cover - jit
    n = image.shape[0]
    n_views = cos.shape[0]
    half = (n - 1) / 2.0
    sino = np.zeros((n_views, n_det), dtype=np.float32)
    for k in numba.prange(n_views):
        c, s = cos[k], sin[k]
        u0 = (shifts[k] - centre) * spacing  # detector position of pixel 0 on the static object
        steep = abs(c) >= abs(s)  # the ray (s, -c) crosses every row once: walk the rows, else the columns
        lead, other = (c, s) if steep else (s, c)
        grid = image if steep else image_t
        out = sino[k]
        for line in range(n):
            t = (half - line) if steep else (line - half)  # r2 of the row / r1 of the column
            # along the row (column) the ray is at r = (u - t * other) / lead: index r + half (half - r)
            r0 = (u0 - t * other) / lead
            first, step = (r0 + half, spacing / lead) if steep else (half - r0, -spacing / lead)
            for l in range(n_det):
                pos = first + l * step
                lo = int(np.floor(pos))
                if 0 <= lo < n - 1:
                    frac = pos - lo
                    out[l] += grid[line, lo] + frac * (grid[line, lo + 1] - grid[line, lo])
        inv = 1.0 / abs(lead)
        for l in range(n_det):
            out[l] *= inv
    return sino


def _kernel_args(geometry: Geometry, shifts: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    if geometry.kind != "parallel":
        raise NanoctError("the stack path handles parallel-beam scans only; this geometry is fan beam")
    phi = geometry.angles
    d = np.zeros(phi.size) if shifts is None else check_array(shifts, "shifts", shape=(phi.size,), dtype=np.float64)
    centre = (geometry.n_det - 1) / 2.0 + geometry.center_offset
    return np.cos(phi), np.sin(phi), d.astype(np.float64), float(centre), 1.0 / geometry.det_spacing


def corrected_fbp(geometry: Geometry, sinogram: Any, shifts: Any = None, filter: str = "ram-lak") -> np.ndarray:
    """Filtered back projection of one slice with a per-view detector shift.

    Parameters
    ----------
    geometry : Geometry
        Parallel-beam geometry (angles with their quadrature weights, axis offset).
    sinogram : array_like of shape (K, L)
        Line integrals.
    shifts : array_like of shape (K,), optional
        Per-view shifts ``d_k`` in detector pixels; view ``k`` is read at ``u - d_k``.
    filter : {"ram-lak", "hann"}
        Reconstruction filter (:func:`~nanoct.recon.fbp.ramp_filter`).

    Returns
    -------
    ndarray of shape (N, N), float32
        :func:`nanoct.recon.fbp.fbp` with ``shifts`` converted to its object pixels.
    """
    _, _, d, _, _ = _kernel_args(geometry, shifts)
    return fbp(geometry, sinogram, shifts=d * geometry.det_spacing / geometry.magnification, filter=filter).image


def reproject(geometry: Geometry, image: Any, shifts: Any = None) -> np.ndarray:
    """Forward projection of an image with a per-view detector shift (Joseph's method, no matrix).

    Parameters
    ----------
    geometry : Geometry
        Parallel-beam geometry.
    image : array_like of shape (N, N)
        The slice.
    shifts : array_like of shape (K,), optional
        Per-view shifts ``d_k`` in detector pixels: the views of the object moved as the
        measured ones are (``p_k(x) = P_k(x + d_k)``).

    Returns
    -------
    ndarray of shape (K, L), float32
        Line integrals: along each ray, the image interpolated linearly within every row (or
        column, for rays closer to the rows) it crosses, times the path length per row.
    """
    x = check_array(image, "image", shape=geometry.image_shape).astype(np.float32)
    cos, sin, d, centre, inv = _kernel_args(geometry, shifts)
    return _project_shifted(x, np.ascontiguousarray(x.T), cos, sin, d, geometry.n_det, centre, 1.0 / inv)


def bin_geometry(geometry: Geometry, binning: int) -> Geometry:
    """The geometry of the detector binned ``binning`` times (image size and axis offset scaled alike)."""
    binning = check_int(binning, "binning", 1)
    n_det = geometry.n_det // binning
    axis = (geometry.n_det - 1) / 2 + geometry.center_offset
    offset = (axis + 0.5) / binning - 0.5 - (n_det - 1) / 2
    n = max(geometry.n // binning, 1)
    return Geometry.from_angles(geometry.angles, n, n_det, center_offset=offset, det_spacing=geometry.det_spacing)


def bin_sinograms(sinograms: Any, binning: int) -> np.ndarray:
    """Average ``binning`` neighbouring detector pixels of ``(..., K, L)`` sinograms (remainder dropped)."""
    sino = np.asarray(sinograms, dtype=np.float32)
    cols = sino.shape[-1] // binning * binning
    return sino[..., :cols].reshape(*sino.shape[:-1], cols // binning, binning).mean(axis=-1)


def with_center(geometry: Geometry, center: float) -> Geometry:
    """``geometry`` with its rotation-axis offset set to ``center`` (detector pixels)."""
    data = geometry.to_dict()
    data["center_offset"] = float(center)
    return Geometry.from_dict(data)
