"""Reconstruction on plain arrays, for notebooks: ``nanoct.fbp(sinogram, angles=...)``.

Each function takes a sinogram ``(K views, L detector pixels)`` and either a
:class:`~nanoct.geometry.Geometry` or the scan's ``angles`` (radians unless ``degrees``) with an
optional rotation-axis ``center_offset`` (detector pixels from the detector centre) and image
``size``, builds the parallel-beam geometry, and calls the registered method with the given
keyword parameters (see :mod:`nanoct.recon` for the contract and each method's parameters).
They return the method's :class:`~nanoct.recon.result.ReconResult` (``image``, ``motion`` for
Dremel, ``residuals``, ``params``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .errors import NanoctError
from .geometry import Geometry
from .recon.registry import check_method_params, method_spec
from .recon.result import ReconResult

__all__ = ["NanoctError", "dremel", "fbp", "kaczmarz", "make_geometry", "resesop"]


def make_geometry(
    sinogram: Any,
    geometry: Geometry | None = None,
    *,
    angles: Any = None,
    center_offset: float = 0.0,
    size: int | None = None,
    degrees: bool = False,
) -> Geometry:
    """The geometry of a sinogram: ``geometry`` if given, else parallel beam from ``angles``.

    Raises
    ------
    ValueError
        If neither or both of ``geometry`` and ``angles`` are given, or the sinogram's shape
        does not match them.
    """
    shape = np.shape(sinogram)
    if (geometry is None) == (angles is None):
        raise ValueError("give either geometry= or angles= (one angle per sinogram row)")
    if geometry is None:
        if len(shape) != 2:
            raise ValueError(f"sinogram has shape {shape}; expected (views, detector pixels)")
        if np.size(angles) != shape[0]:
            raise ValueError(f"{np.size(angles)} angles for a sinogram of {shape[0]} views; give one angle per row")
        geometry = Geometry.from_angles(
            angles, size or shape[1], shape[1], degrees=degrees, center_offset=center_offset
        )
    if shape != geometry.sino_shape:
        raise ValueError(f"sinogram has shape {shape}, the geometry expects {geometry.sino_shape}")
    return geometry


def _run(method: str, sinogram: Any, geometry: Geometry, eta: Any, params: dict[str, Any]) -> ReconResult:
    spec = method_spec(method)
    check_method_params(method, params, geometry)
    data = (sinogram, eta) if spec.needs_eta else (sinogram,)
    return spec.solver()(geometry, *data, **params)


def fbp(
    sinogram: Any,
    geometry: Geometry | None = None,
    *,
    angles: Any = None,
    center_offset: float = 0.0,
    size: int | None = None,
    degrees: bool = False,
    **params: Any,
) -> ReconResult:
    """Filtered back projection of a sinogram (:func:`nanoct.recon.fbp.fbp`; ``filter=``)."""
    g = make_geometry(sinogram, geometry, angles=angles, center_offset=center_offset, size=size, degrees=degrees)
    return _run("fbp", sinogram, g, None, params)


def kaczmarz(
    sinogram: Any,
    geometry: Geometry | None = None,
    *,
    angles: Any = None,
    center_offset: float = 0.0,
    size: int | None = None,
    degrees: bool = False,
    **params: Any,
) -> ReconResult:
    """Kaczmarz sweeps (:func:`nanoct.recon.kaczmarz.kaczmarz`; ``n_iter=``, ``relaxation=``, ...)."""
    g = make_geometry(sinogram, geometry, angles=angles, center_offset=center_offset, size=size, degrees=degrees)
    return _run("kaczmarz", sinogram, g, None, params)


def dremel(
    sinogram: Any,
    geometry: Geometry | None = None,
    *,
    angles: Any = None,
    center_offset: float = 0.0,
    size: int | None = None,
    degrees: bool = False,
    **params: Any,
) -> ReconResult:
    """Dremel: Kaczmarz with per-view shift estimation (:func:`nanoct.recon.dremel.dremel`).

    The estimated object shift per view (detector pixels) is ``result.motion``.
    """
    g = make_geometry(sinogram, geometry, angles=angles, center_offset=center_offset, size=size, degrees=degrees)
    return _run("dremel", sinogram, g, None, params)


def resesop(
    sinogram: Any,
    geometry: Geometry | None = None,
    *,
    eta: Any,
    angles: Any = None,
    center_offset: float = 0.0,
    size: int | None = None,
    degrees: bool = False,
    **params: Any,
) -> ReconResult:
    """RESESOP-Kaczmarz with the per-view model error ``eta`` (:func:`nanoct.recon.resesop.resesop`).

    Without ground truth, estimate ``eta`` with :mod:`nanoct.eta` (e.g.
    ``eta_from_residual(geometry, sinogram, dremel(...).image)``).
    """
    g = make_geometry(sinogram, geometry, angles=angles, center_offset=center_offset, size=size, degrees=degrees)
    return _run("resesop", sinogram, g, eta, params)
