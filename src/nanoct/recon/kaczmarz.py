"""Kaczmarz' method (ART) as a numba row-action kernel over the cached CSR system matrix.

The shared row-action pieces (problem setup, view orders, :func:`~nanoct.recon.rowaction.row_dot`,
residuals) live in :mod:`nanoct.recon.rowaction`; this module holds only the Kaczmarz sweep.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import scipy.sparse as sp

from ..core.geometry import Geometry
from ..core.matrixfree import RAY_ENTRIES_PER_N, ParallelRays, ray_setup, ray_trace, residual_norm_free
from ..core.operators import RayTransform
from .measured import check_measured, solve_measured
from .params import MethodParams, resolve_geometry
from .result import ReconResult
from .rowaction import (
    check_row_action,
    clip_nonneg,
    prepare_problem,
    residual_norm,
    resolve_relaxation,
    row_dot,
    row_norms_squared,
    unsigned_indices,
    view_order,
)

__all__ = ["KaczmarzParams", "kaczmarz", "kaczmarz_reference"]


# ---------------------------------------------------------------------------------- kernel
@numba.njit(cache=True, nogil=True)
def _kaczmarz_sweep(indptr, indices, data, rownorm2, y, x, views, n_det, omega):  # pragma: no cover
    """One Kaczmarz sweep in place; returns the sum of squared pre-update residuals.

    Rows are visited view by view (``views``), within a view in detector order. A row whose
    squared norm is 0 (empty, or only explicit zeros) is skipped. ``<a, x>`` is accumulated
    in float32 (:func:`row_dot`), the step ``omega * res / ||a||^2`` in float64.
    """
    run = 0.0
    for i in range(views.shape[0]):
        base = views[i] * n_det
        for l in range(n_det):
            r = base + l
            nr = rownorm2[r]
            if nr <= 0.0:
                continue
            p0 = indptr[r]
            p1 = indptr[r + 1]
            res = y[r] - row_dot(indices, data, x, p0, p1)
            run += res * res
            c = np.float32(omega * res / nr)
            idx = indices[p0:p1]  # slices: a zero-based loop compiles to a faster scatter
            a = data[p0:p1]
            for q in range(p1 - p0):
                x[idx[q]] += c * a[q]
    return run


def kaczmarz_reference(
    matrix: sp.csr_matrix, y: np.ndarray, x: np.ndarray, views: np.ndarray, n_det: int, omega: float
) -> np.ndarray:
    """Straightforward numpy version of one Kaczmarz sweep (test oracle and benchmark baseline).

    Same visiting order and arithmetic as the numba kernel, one row at a time with numpy
    slicing of the CSR arrays; ``x`` (float64 recommended) is updated in place and returned.
    """
    indptr, indices, data = matrix.indptr, matrix.indices, matrix.data
    for k in views:
        for r in range(int(k) * n_det, (int(k) + 1) * n_det):
            a = data[indptr[r] : indptr[r + 1]].astype(np.float64)
            nr = float(a @ a)
            if nr <= 0.0:
                continue
            idx = indices[indptr[r] : indptr[r + 1]]
            x[idx] += omega * (y[r] - a @ x[idx]) / nr * a
    return x


# ---------------------------------------------------------------------------------- public
@dataclass(frozen=True)
class KaczmarzParams(MethodParams):
    """The parameters of :func:`kaczmarz`.

    Parameters
    ----------
    n_iter : int, default 10
        Number of sweeps over all rays.
    relaxation : float, optional
        Relaxation ``omega``. Kaczmarz converges for ``0 < omega < 2`` (to a solution of
        consistent systems; for inconsistent data the iterates approach a limit cycle whose
        size shrinks with ``omega``), so other values are rejected. Default
        ``min(1, 8 / K)`` (:func:`~nanoct.recon.rowaction.auto_relaxation`): on
        motion-perturbed data small relaxation acts as regularisation; use 1 for consistent
        data. The measurements behind the default are in ``docs/choices.md``.
    order : {"random", "sequential", "golden"}, default "random"
        View order of every sweep (:func:`~nanoct.recon.rowaction.view_order`). Random order
        is the default because sequential order (the paper's) converges far more slowly.
    nonneg : bool, default True
        Project onto ``x >= 0`` after each sweep.
    seed : int, default 0
        Seed of the random view permutations.
    residual : {"exact", "running"}, default "exact"
        ``"exact"`` records ``||A x - y||`` after each sweep (one extra pass over the matrix);
        ``"running"`` records the root of the sum of squared residuals seen *before* each row
        update during the sweep (free, an upper-bound-like proxy).
    projector : {"auto", "matrix", "matrixfree"}, default "auto"
        Rays from the cached system matrix or computed per view (parallel beam); ``"auto"``
        computes them per view when the matrix would exceed 1 GB
        (:func:`~nanoct.recon.rowaction.resolve_projector`).
    measured : {"auto", "on", "extend", "off"}, default "auto"
        Measured-data treatment (:mod:`~nanoct.recon.measured`): per-view air level removed,
        sinogram extended at the detector edges onto a larger grid, stop by the discrepancy
        principle with the estimated noise. ``"auto"`` applies it when the detector edges are
        not at zero (a measured scan); a simulation is reconstructed as given.
        ``"extend"``: the same without removing an air level (an object wider than the
        detector, open beam at zero).
    pad : int, optional
        Detector pixels added on each side for measured data (default a quarter of the
        detector width; 0: no extension).
    """

    n_iter: int = 10
    relaxation: float | None = None
    order: str = "random"
    nonneg: bool = True
    seed: int = 0
    residual: str = "exact"
    projector: str = "auto"
    measured: str = "auto"
    pad: int | None = None

    def __post_init__(self) -> None:
        check_row_action(self)
        measured, pad = check_measured(self.measured, self.pad)
        self._set("measured", measured)
        self._set("pad", pad)

    def resolve(self, geometry: Geometry) -> dict[str, Any]:
        """The values for ``geometry`` (default relaxation from its number of views)."""
        return resolve_relaxation(super().resolve(geometry), geometry)


def kaczmarz(
    op: Geometry | RayTransform,
    sino: Any,
    *,
    x0: Any = None,
    callback: Callable[[int, np.ndarray, None], Any] | None = None,
    matrix: sp.csr_matrix | None = None,
    stop_residual: float | None = None,
    **params: Any,
) -> ReconResult:
    """Kaczmarz' method (ART) with the unperturbed system matrix.

    For each ray ``(k, l)`` with row ``a`` of the system matrix
    ``x <- x + relaxation * (y_kl - <a, x>) / ||a||^2 * a``; rows of zero norm are skipped.

    Parameters
    ----------
    op : Geometry or RayTransform
        Scan geometry (or an unperturbed ray transform with ``oversample=1``).
    sino : array_like of shape (K, L)
        Measured sinogram; must be finite.
    x0 : array_like of shape (N, N), optional
        Start image (default zeros).
    callback : callable, optional
        ``callback(iteration, x, None)`` after each sweep with ``x`` the current (N, N) image
        (a view; do not modify). If it returns True the iteration stops with reason
        ``"callback"``.
    matrix : scipy.sparse.csr_matrix, optional
        The system matrix (default :func:`nanoct.core.operators.system_matrix`), e.g. to reuse it.
    stop_residual : float, optional
        Stop (reason ``"discrepancy"``) after the first sweep whose recorded residual is at
        most this value (the discrepancy principle). Default: none, or for measured data
        (``measured``) the bound from the estimated noise
        (:meth:`~nanoct.recon.measured.MeasuredData.discrepancy`).
    **params
        The method's parameters: :class:`KaczmarzParams`.

    Returns
    -------
    ReconResult
        ``image`` (N, N) float32, ``residuals`` per sweep, ``stop_reason`` ``"max_iter"``,
        ``"discrepancy"`` or ``"callback"``, ``motion`` None; for measured data
        ``params["measured_data"]`` says what was done.
    """
    p = KaczmarzParams.check(op, **params)
    inner = {**params, "measured": "off", "pad": None}
    measured = solve_measured(
        lambda d, x, cb: kaczmarz(
            d.geometry, d.sinogram, x0=x, callback=cb, matrix=matrix,
            stop_residual=d.discrepancy() if stop_residual is None else stop_residual, **inner,
        ),
        resolve_geometry(op), sino, p, x0=x0, callback=callback, matrix=matrix,
    )  # fmt: skip
    if measured is not None:
        return measured
    geometry, y, mat, x = prepare_problem(op, sino, matrix, x0, p["projector"])
    n_det, omega = geometry.n_det, p["relaxation"]
    if isinstance(mat, ParallelRays):  # rays traced on the fly

        def sweep(views: np.ndarray) -> float:
            return _kaczmarz_sweep_free(mat.params, geometry.n, y, x, views, n_det, omega)

        def exact_residual() -> float:
            return residual_norm_free(mat.params, geometry.n, n_det, y, x)

    else:
        norms = row_norms_squared(mat)
        indices = unsigned_indices(mat)

        def sweep(views: np.ndarray) -> float:
            return _kaczmarz_sweep(mat.indptr, indices, mat.data, norms, y, x, views, n_det, omega)

        def exact_residual() -> float:
            return residual_norm(mat.indptr, indices, mat.data, y, x)

    rng = np.random.default_rng(p["seed"])
    residuals: list[float] = []
    stop = "max_iter"
    for it in range(p["n_iter"]):
        run = sweep(view_order(geometry.n_angles, p["order"], rng))
        if p["nonneg"]:
            clip_nonneg(x)
        residuals.append(float(exact_residual()) if p["residual"] == "exact" else math.sqrt(run))
        if stop_residual is not None and residuals[-1] <= stop_residual:
            stop = "discrepancy"
            break
        if callback is not None and callback(it, x.reshape(geometry.image_shape), None):
            stop = "callback"
            break
    return ReconResult(x.reshape(geometry.image_shape), residuals, stop, None, {"method": "kaczmarz", **p})


@numba.njit(cache=True, nogil=True)
def _kaczmarz_sweep_free(params, n, y, x, views, n_det, omega):  # pragma: no cover - compiled
    """:func:`_kaczmarz_sweep` with the rays traced on the fly (``params``: (K, 6) ray parameters)."""
    run = 0.0
    idx = np.empty(RAY_ENTRIES_PER_N * n, np.int64)  # each ray is traced once, for its dot and its update
    wts = np.empty(RAY_ENTRIES_PER_N * n)
    for i in range(views.shape[0]):
        k = views[i]
        setup = ray_setup(params[k], n)
        for l in range(n_det):
            cnt, dot, nr = ray_trace(x, n, setup, setup[6] + l * setup[7], idx, wts)
            if nr <= 0.0:
                continue
            res = y[k * n_det + l] - dot
            run += res * res
            coef = omega * res / nr
            for j in range(cnt):
                x[idx[j]] += coef * wts[j]
    return run
