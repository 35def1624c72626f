"""Estimates of RESESOP's per-view model error eta when the ground truth is unknown.

The paper's eta is ``eta_k = max_l |y_kl - y^eta_kl|``: the distance between the measured
sinogram and the sinogram the unperturbed model would give, which only a simulation knows.
On a measured scan it has to be estimated. Two estimators:

``residual``
    From a first reconstruction ``x0`` that already corrects most of the motion (Dremel):
    ``eta_k = scale * max_l |y_kl - (A x0)_kl|``, or with the motion ``x0`` came with
    (``shifts``: Dremel's estimate) against the data with that motion undone, the model error
    RESESOP meets when it is given the same ``shifts``. ``A x0`` stands in for ``y^eta``; the
    residual also holds the model's discretisation error and what ``x0`` got wrong, and
    ``scale`` (1 by default, or fitted on a simulated reference set with
    :func:`fit_scale`) corrects its average bias. On measured data (an open beam not at zero,
    :func:`~nanoct.recon.measured.looks_measured`) the air level is removed first and the
    default scale is :data:`MEASURED_SCALE` = 0.5, the level ``nanoct stack`` uses for RESESOP
    (chosen on simulated stacks, ``benchmarks/stack_eta.py``: half the largest residual per
    view beat the whole on every stack).
``reference``
    From a simulated reference data set of the same geometry whose eta is known: a per-view
    statistic of its eta over samples (median by default). It assumes the scan's motion is
    as strong as the simulation's, view by view, and ignores the scan's own data.

Measured quality against the true eta and RESESOP with each estimate: docs/measured_data.md.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.errors import NanoctError
from ..core.geometry import Geometry
from ..core.operators import RayTransform, system_matrix
from ..core.validation import check_array, check_choice, check_float
from .measured import MEASURED_MODES, air_level, looks_measured, read_moved
from .rowaction import resolve_projector

__all__ = ["MEASURED_SCALE", "eta_from_reference", "eta_from_residual", "fit_scale"]

#: Default ``scale`` of :func:`eta_from_residual` on measured data.
MEASURED_SCALE = 0.5

_STATISTICS = ("median", "mean", "max")


def eta_from_residual(
    geometry: Geometry,
    sinogram: Any,
    image: Any,
    *,
    scale: float | None = None,
    projector: str | None = None,
    measured: str = "auto",
    shifts: Any = None,
) -> np.ndarray:
    """``scale * max_l |y - A x0|`` per view, from a first reconstruction ``x0``.

    For measured data the per-view air level (:func:`~nanoct.recon.measured.air_level`) is
    removed from ``y`` first, as the reconstruction methods do, so that the open beam is not
    counted as model error.

    Parameters
    ----------
    geometry : Geometry
        Scan geometry of the (unperturbed) model ``A``.
    sinogram : array_like of shape (K, L)
        Measured sinogram ``y``.
    image : array_like of shape (N, N)
        First reconstruction ``x0`` (Dremel's is the intended one: it has the motion mostly
        corrected, so ``A x0`` is close to the unperturbed data).
    scale : float, optional
        Factor on the residual's per-view maximum (>= 0); default 1, or
        :data:`MEASURED_SCALE` on measured data.
    projector : str, optional
        ASTRA projector of ``A`` (default: the one reconstructions use; where they trace their
        rays instead of holding the matrix, a parallel beam whose matrix would exceed
        :data:`~nanoct.recon.rowaction.AUTO_MATRIX_BYTES`, ASTRA projects without it).
    measured : {"auto", "on", "extend", "off"}
        Measured data (as the methods' parameter): ``"on"`` removes the air level; ``"auto"``
        is ``"on"`` where :func:`~nanoct.recon.measured.looks_measured`, else ``"off"``;
        ``"extend"`` keeps the air level but takes the measured default scale.
    shifts : array_like of shape (K,), optional
        The motion the model carries (object pixels along ``e_u``, as Dremel's ``motion`` and
        :func:`~nanoct.recon.resesop.resesop`'s ``shifts``): the residual is taken against the
        views read at ``u - d_k`` (:func:`~nanoct.recon.measured.read_moved`), so that eta is
        the model error left after this motion. Give Dremel's own motion with its image.

    Returns
    -------
    ndarray of shape (K,), float32
    """
    y = check_array(sinogram, "sinogram", shape=geometry.sino_shape).astype(np.float64)
    x = check_array(image, "image", shape=geometry.image_shape)
    measured = check_choice(measured, "measured", MEASURED_MODES)
    if measured == "auto":
        measured = "on" if looks_measured(y) else "off"
    if shifts is not None:
        d = check_array(shifts, "shifts", shape=(geometry.n_angles,), dtype=np.float64)
        y = read_moved(y, d * geometry.magnification / geometry.det_spacing)
    if measured == "on":
        y = y - air_level(y)[:, None]
    if scale is None:
        scale = 1.0 if measured == "off" else MEASURED_SCALE
    try:
        scale = check_float(scale, "eta scale", low=0.0)
    except ValueError as exc:
        raise NanoctError(str(exc)) from exc
    if projector is None and resolve_projector("auto", geometry) == "matrixfree":
        model = RayTransform(geometry)(x)
    else:
        model = (system_matrix(geometry, projector) @ x.ravel()).reshape(geometry.sino_shape)
    return (scale * np.abs(y - model).max(axis=1)).astype(np.float32)


def eta_from_reference(etas: Any, *, statistic: str = "median") -> np.ndarray:
    """Per-view statistic of a reference data set's true eta.

    Parameters
    ----------
    etas : array_like of shape (S, K)
        eta of S simulated samples of the same geometry.
    statistic : {"median", "mean", "max"}
        How the S values of a view are combined.

    Returns
    -------
    ndarray of shape (K,), float32
    """
    arr = check_array(etas, "reference eta", ndim=2, dtype=np.float64)
    if arr.shape[0] == 0:
        raise NanoctError("the reference data set has no samples with eta")
    if statistic not in _STATISTICS:
        raise NanoctError(f"statistic {statistic!r} is unknown; use one of {', '.join(_STATISTICS)}")
    return getattr(np, statistic)(arr, axis=0).astype(np.float32)


def fit_scale(true_eta: Any, estimated_eta: Any) -> float:
    """Least-squares factor ``s`` minimising ``||true - s * estimated||`` over a reference set.

    Parameters
    ----------
    true_eta, estimated_eta : array_like of the same shape
        The true eta of simulated samples and an unscaled estimate of it (e.g. the residual
        estimate with ``scale=1``).

    Returns
    -------
    float
        The factor (>= 0).
    """
    t = check_array(true_eta, "true eta", dtype=np.float64).ravel()
    e = check_array(estimated_eta, "estimated eta", shape=np.shape(true_eta), dtype=np.float64).ravel()
    denom = float(e @ e)
    if denom == 0:
        raise NanoctError("the estimated eta is zero everywhere; no scale can be fitted")
    return max(float(t @ e) / denom, 0.0)
