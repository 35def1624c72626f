"""Reconstruction on plain arrays, for notebooks: ``nanoct.fbp(sinogram, angles=...)``.

Each function takes a sinogram ``(K views, L detector pixels)`` and either a
:class:`~nanoct.core.geometry.Geometry` or the scan's ``angles`` (radians unless ``degrees``) with an
optional rotation-axis ``center_offset`` (detector pixels from the detector centre) and image
``size``, builds the parallel-beam geometry, and calls the registered method with the given
keyword parameters (see :mod:`nanoct.recon` for the contract and each method's parameters).
They return the method's :class:`~nanoct.recon.result.ReconResult` (``image``, ``motion`` for
Dremel, ``residuals``, ``params``).

Examples
--------
A disk of radius 20 and density 1, centred on the axis, seen by 90 parallel views:

>>> import numpy as np
>>> import nanoct
>>> angles = np.linspace(0, np.pi, 90, endpoint=False)
>>> s = np.arange(64) - 31.5
>>> sinogram = np.tile(2 * np.sqrt(np.clip(20**2 - s**2, 0, None)), (90, 1)).astype(np.float32)
>>> image = nanoct.fbp(sinogram, angles=angles).image
>>> image.shape, round(float(image[32, 32]), 2)
((64, 64), 1.0)
>>> round(float(nanoct.gridrec(sinogram, angles=angles).image[32, 32]), 2)  # the same FBP, in Fourier space
1.0
>>> result = nanoct.dremel(sinogram, angles=angles, n_iter=4)
>>> result.motion.shape, result.stop_reason
((90,), 'max_iter')
>>> bool(np.abs(result.motion).max() < 0.5)  # the disk does not move
True
>>> nanoct.resesop(sinogram, angles=angles, eta=np.full(90, 0.5), n_iter=5).image.shape
(64, 64)
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from functools import cache
from typing import Any

import numpy as np

from .core.errors import NanoctError
from .core.geometry import Geometry
from .recon.registry import method_spec
from .recon.result import ReconResult

__all__ = ["NanoctError", "dremel", "fbp", "gridrec", "kaczmarz", "make_geometry", "resesop"]


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
            angles, shape[1] if size is None else size, shape[1], degrees=degrees, center_offset=center_offset
        )
    if shape != geometry.sino_shape:
        raise ValueError(f"sinogram has shape {shape}, the geometry expects {geometry.sino_shape}")
    return geometry


_COMMON = """

Parameters
----------
sinogram : array_like of shape (K, L)
    Line integrals, one row per view.
geometry : Geometry, optional
    The scan geometry; or give ``angles`` instead.
angles : array_like of shape (K,), optional
    View angles (radians unless ``degrees``), for parallel beam.
center_offset : float
    Rotation axis relative to the detector centre, in detector pixels (with ``angles``).
size : int, optional
    Image size N (with ``angles``; default L).
degrees : bool
    ``angles`` are in degrees.
**params
    The method's parameters (see its solver), and its other keyword arguments: ``x0``,
    ``callback``, ``matrix``, ``stop_residual`` (iterative methods), ``shifts0`` (Dremel's
    start), ``shifts`` (a known motion for FBP, gridrec and RESESOP).

Returns
-------
ReconResult
"""


@cache
def _solver_arguments(method: str) -> frozenset[str]:
    """The keyword arguments of a method's solver that are not method parameters (``x0``, ``shifts0``, ...)."""
    spec = method_spec(method)
    named = inspect.signature(spec.solver()).parameters.values()
    keywords = {p.name for p in named if p.kind is inspect.Parameter.KEYWORD_ONLY}
    return frozenset(keywords - set(spec.solver_parameter_names()))


def _array_method(method: str, summary: str) -> Callable[..., ReconResult]:
    """The array-API function of a registered method (``eta=`` for methods that need it)."""
    spec = method_spec(method)

    def run(
        sinogram: Any,
        geometry: Geometry | None = None,
        *,
        angles: Any = None,
        center_offset: float = 0.0,
        size: int | None = None,
        degrees: bool = False,
        eta: Any = None,
        **params: Any,
    ) -> ReconResult:
        spec.check_eta(eta)
        batch = sorted(set(params) & set(spec.batch_parameter_names()))
        if batch:
            raise NanoctError(
                f"{', '.join(batch)}: parameters of 'nanoct reconstruct' on a data set; on arrays pass a motion as "
                "shifts0= (Dremel's start; fix_shifts=True holds it) or shifts= (FBP, gridrec, RESESOP)"
            )
        g = make_geometry(sinogram, geometry, angles=angles, center_offset=center_offset, size=size, degrees=degrees)
        extras = _solver_arguments(method)
        spec.check({k: v for k, v in params.items() if k not in extras}, g)
        return spec.run(g, sinogram, eta, **params)

    run.__name__ = run.__qualname__ = method
    run.__doc__ = summary + _COMMON
    return run


fbp = _array_method("fbp", "Filtered back projection (:func:`nanoct.recon.fbp.fbp`; ``filter=``).")
gridrec = _array_method(
    "gridrec",
    "FBP computed in Fourier space with a non-uniform FFT, parallel beam (:func:`nanoct.recon.gridrec.gridrec`; "
    "``filter=``, ``interpolation=``); for many slices with one geometry use "
    ":func:`nanoct.recon.gridrec.gridrec_slices`.",
)
kaczmarz = _array_method("kaczmarz", "Kaczmarz sweeps (:func:`nanoct.recon.kaczmarz.kaczmarz`; ``n_iter=``, ...).")
dremel = _array_method(
    "dremel",
    "Dremel: Kaczmarz with per-view shift estimation (:func:`nanoct.recon.dremel.dremel`); "
    "the estimated object shift per view (detector pixels) is ``result.motion``.",
)
resesop = _array_method(
    "resesop",
    "RESESOP-Kaczmarz with the per-view model error ``eta=`` (:func:`nanoct.recon.resesop.resesop`); "
    "without ground truth estimate it with :mod:`nanoct.recon.eta`, e.g. "
    "``eta_from_residual(geometry, sinogram, dremel(...).image)``.",
)
