"""RESESOP-Kaczmarz (the paper's Algorithm 2) as a numba row-action kernel.

For every ray ``(k, l)`` with system-matrix row ``a`` (the unperturbed, inexact model
``A^eta``), residual ``w = <a, x> - y_kl`` and stripe half-width ``c_kl = delta + eta_kl``:

1. if ``|w| <= tau * c_kl`` the discrepancy principle holds for this ray: no update;
2. otherwise ``x~ = x - sign(w) (|w| - c_kl) / ||a||^2 a`` is the metric projection onto the
   stripe ``{ |<a, x> - y_kl| <= c_kl }`` (search direction ``u_new = A_kl^* w``);
3. if ``x~`` lies outside the stripe of the previous update (search direction ``u_old``), ``x`` is
   projected onto the intersection of the two bounding hyperplanes (two search directions),
   exactly the paper's update ``x = x~ + <u_new,u_old> t u_new - ||u_new||^2 t u_old``.

Ambiguities of the paper's pseudo-code and what this implementation does
--------------------------------------------------------------------------
* **rho**: the paper's stripe width is ``(delta + eta rho) ||w||`` with ``rho`` bounding the
  solution norm (as in Blanke et al. 2020), but Algorithm 2 uses ``delta + eta_kl``. Here
  ``eta_kl`` is already a data-space error (the per-view maximum of ``|y - y^eta|``), so
  ``rho = 1``; any other ``rho`` is the same as ``eta_scale``.
* **Norm scaling**: Algorithm 2 measures ``X`` with the discretised ``L^2([-1, 1]^2)`` inner
  product ``<u, v>_X = h^2 sum u_i v_i``. The projections onto stripes and onto intersections
  of two hyperplanes are metric projections; if ``A^*`` is the adjoint in the same inner
  product (``A^* w = h^-2 a w``) the factor ``h^2`` cancels exactly, so plain Euclidean
  arithmetic on pixel values gives the same iterates. (Mixing the L^2 norm with the Euclidean
  transpose would merely rescale the step by ``h^2``; we do not do that.)
* **Stopping flags**: the pseudo-code sets ``stoppingCondition_kl`` when the ray meets the
  discrepancy and stops when all flags are set; it never clears a flag, although later updates
  can break the discrepancy of an earlier ray. ``stop_rule="sticky"`` is this literal reading;
  ``stop_rule="sweep"`` (default) stops only after a full sweep in which *every* ray met the
  discrepancy (so no update was made and the discrepancy principle truly holds for the
  returned image, as in the reference implementation ``kenaj123/RESESOP``). Both re-check every
  ray in every sweep: a ray that met the discrepancy once is *not* skipped for good.
* **"is first iteration"**: read as "no previous search direction exists yet" (the very first
  update); ``u_old`` carries over from one sweep to the next.
* **Degenerate second direction**: when ``u_new`` and ``u_old`` are (numerically) parallel
  the Gram determinant vanishes and the second direction is dropped (``t = 0``).
* **Non-negativity** (not in the paper): optional projection onto ``x >= 0`` after each sweep.

Row products are accumulated in float64 (:func:`~nanoct.recon.rowaction.row_dot_f64`): the
stripe tests compare residuals with widths that can be small.

Defaults
--------
Chosen on validation phantoms (own seeds, not a test split); the measurements are in
``docs/choices.md`` (RESESOP), the speed in ``benchmarks/README.md``.
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
from ..core.matrixfree import RAY_ENTRIES_PER_N, ParallelRays, ray_dot, ray_setup, ray_trace, residual_norm_free
from ..core.operators import RayTransform
from ..core.validation import check_array, check_choice, check_float
from .measured import check_measured, read_moved, solve_measured
from .params import MethodParams, resolve_geometry
from .result import ReconResult
from .rowaction import (
    check_projector,
    check_row_action,
    clip_nonneg,
    prepare_problem,
    residual_norm,
    row_dot_f64,
    row_norms_squared,
    view_order,
)

__all__ = ["ResesopParams", "STOP_RULES", "expand_eta", "resesop", "resesop_reference"]

#: Stop rules of :func:`resesop` (see the module docstring, "Stopping flags").
STOP_RULES = ("sweep", "sticky")


def expand_eta(eta: Any, geometry: Geometry, name: str = "eta") -> np.ndarray:
    """Validate ``eta`` of shape (K,) (per view) or (K, L) (per ray); return it as (K, L) float64."""
    arr = np.asarray(eta)
    k, l = geometry.sino_shape
    if arr.ndim == 0:
        raise ValueError(f"{name} must have shape ({k},) or ({k}, {l}), got a scalar")
    if arr.shape == (k,):
        arr = check_array(arr, name, shape=(k,), dtype=np.float64)
        arr = np.repeat(arr[:, None], l, axis=1)
    elif arr.shape == (k, l):
        arr = check_array(arr, name, shape=(k, l), dtype=np.float64)
    else:
        raise ValueError(f"{name} has shape {arr.shape}, expected ({k},) per view or ({k}, {l}) per ray")
    if (arr < 0).any():
        raise ValueError(f"{name} has {int((arr < 0).sum())} negative value(s); model errors must be >= 0")
    return arr


@numba.njit(cache=True, nogil=True)
def _resesop_sweep(
    indptr, indices, data, rownorm2, y, x, width, tau, views, n_det, wo, state, flags, sticky
):  # pragma: no cover - compiled
    """One RESESOP-Kaczmarz sweep in place.

    ``state`` (float64, length 3) carries the previous search direction between calls:
    ``state[0]`` its row (-1: none), ``state[1]`` the value ``<a_old, x>`` (kept analytically),
    ``state[2]`` unused. ``wo`` is a dense copy of row ``a_old`` (zeros elsewhere).
    Returns ``(n_updates, sum of squared residuals seen, n_rays_flagged)``.
    """
    old = int(state[0])
    old_val = state[1]
    n_upd = 0
    run = 0.0
    for i in range(views.shape[0]):
        base = views[i] * n_det
        for l in range(n_det):
            r = base + l
            nn = rownorm2[r]
            if nn <= 0.0:
                flags[r] = True
                continue
            p0 = indptr[r]
            p1 = indptr[r + 1]
            w = row_dot_f64(indices, data, x, p0, p1) - y[r]
            run += w * w
            c = width[r]
            aw = abs(w)
            if aw <= tau * c:
                flags[r] = True
                continue
            if not sticky:
                flags[r] = False
            sg = 1.0 if w > 0.0 else -1.0
            b_new = y[r] + sg * c  # <a, x> on the violated boundary of the new stripe
            step = sg * (aw - c) / nn  # x~ = x - step * a
            coef_new = -step
            coef_old = 0.0
            if old >= 0:
                g = row_dot_f64(indices, data, wo, p0, p1)
                c_old = old_val - step * g  # <a_old, x~>
                y_old = y[old]
                w_old = width[old]
                if c_old > y_old + w_old:
                    b_old = y_old + w_old
                elif c_old < y_old - w_old:
                    b_old = y_old - w_old
                else:
                    b_old = c_old
                if b_old != c_old:
                    no = rownorm2[old]
                    det = nn * no - g * g
                    if det > 1e-9 * nn * no:
                        tt = (c_old - b_old) / det
                        coef_new += tt * g
                        coef_old = -tt * nn
                # clear the old row from the work vector, moving x along it if needed
                q0 = indptr[old]
                q1 = indptr[old + 1]
                if coef_old != 0.0:
                    cf = np.float32(coef_old)
                    for q in range(q0, q1):
                        j = indices[q]
                        x[j] += cf * data[q]
                        wo[j] = 0.0
                else:
                    for q in range(q0, q1):
                        wo[indices[q]] = 0.0
            cn = np.float32(coef_new)
            for p in range(p0, p1):
                j = indices[p]
                x[j] += cn * data[p]
                wo[j] = data[p]
            old = r
            old_val = b_new
            n_upd += 1
    state[0] = old
    state[1] = old_val
    n_flag = 0
    for r in range(flags.shape[0]):
        if flags[r]:
            n_flag += 1
    return n_upd, run, n_flag


@numba.njit(cache=True, nogil=True)
def _resesop_sweep_free(
    params, n, y, x, width, tau, views, n_det, wo, state, flags, sticky
):  # pragma: no cover - compiled
    """:func:`_resesop_sweep` with the rays traced on the fly (``params``: (K, 6) ray parameters).

    ``state[2]`` carries the squared norm of the previous search direction's ray.
    """
    old = int(state[0])
    old_val = state[1]
    old_norm = state[2]
    n_upd = 0
    run = 0.0
    # each ray is traced once into (idx, wts); the previous search direction's ray stays in
    # (idx_old, wts_old) for its update, so no ray is traced twice
    idx = np.empty(RAY_ENTRIES_PER_N * n, np.int64)
    wts = np.empty(RAY_ENTRIES_PER_N * n)
    idx_old = np.empty(RAY_ENTRIES_PER_N * n, np.int64)
    wts_old = np.empty(RAY_ENTRIES_PER_N * n)
    cnt_old = 0
    if old >= 0:
        old_setup = ray_setup(params[old // n_det], n)
        cnt_old = ray_trace(x, n, old_setup, old_setup[6] + (old % n_det) * old_setup[7], idx_old, wts_old)[0]
    for i in range(views.shape[0]):
        k = views[i]
        setup = ray_setup(params[k], n)
        for l in range(n_det):
            r = k * n_det + l
            cnt, dot, nn = ray_trace(x, n, setup, setup[6] + l * setup[7], idx, wts)
            if nn <= 0.0:
                flags[r] = True
                continue
            w = dot - y[r]
            run += w * w
            c = width[r]
            aw = abs(w)
            if aw <= tau * c:
                flags[r] = True
                continue
            if not sticky:
                flags[r] = False
            sg = 1.0 if w > 0.0 else -1.0
            b_new = y[r] + sg * c
            step = sg * (aw - c) / nn
            coef_new = -step
            coef_old = 0.0
            if old >= 0:
                g = 0.0
                for j in range(cnt):
                    g += wts[j] * wo[idx[j]]
                c_old = old_val - step * g
                y_old = y[old]
                w_old = width[old]
                if c_old > y_old + w_old:
                    b_old = y_old + w_old
                elif c_old < y_old - w_old:
                    b_old = y_old - w_old
                else:
                    b_old = c_old
                if b_old != c_old:
                    det = nn * old_norm - g * g
                    if det > 1e-9 * nn * old_norm:
                        tt = (c_old - b_old) / det
                        coef_new += tt * g
                        coef_old = -tt * nn
                for j in range(cnt_old):
                    if coef_old != 0.0:
                        x[idx_old[j]] += coef_old * wts_old[j]
                    wo[idx_old[j]] = 0.0
            for j in range(cnt):  # wo is zero here; += as a line may list its pixel twice (once with 0)
                x[idx[j]] += coef_new * wts[j]
                wo[idx[j]] += wts[j]
            idx, idx_old = idx_old, idx
            wts, wts_old = wts_old, wts
            cnt_old = cnt
            old = r
            old_val = b_new
            old_norm = nn
            n_upd += 1
    state[0] = old
    state[1] = old_val
    state[2] = old_norm
    n_flag = 0
    for r in range(flags.shape[0]):
        if flags[r]:
            n_flag += 1
    return n_upd, run, n_flag


def resesop_reference(
    matrix: sp.csr_matrix,
    y: np.ndarray,
    x: np.ndarray,
    width: np.ndarray,
    tau: float,
    views: np.ndarray,
    n_det: int,
    state: dict,
) -> int:
    """Straightforward numpy version of one sweep of Algorithm 2 (test oracle, benchmark baseline).

    Written literally in terms of the search directions ``u = A_kl^* w`` (dense vectors),
    ``alpha``, ``xi`` of the pseudo-code; ``state`` carries ``u_old``, ``alpha_old``,
    ``xi_old`` between sweeps. Updates ``x`` (float64) in place; returns the number of updates.
    """
    n_upd = 0
    for k in views:
        for r in range(int(k) * n_det, (int(k) + 1) * n_det):
            a_idx = matrix.indices[matrix.indptr[r] : matrix.indptr[r + 1]]
            a_val = matrix.data[matrix.indptr[r] : matrix.indptr[r + 1]].astype(np.float64)
            if float(a_val @ a_val) <= 0.0:
                continue
            w = float(a_val @ x[a_idx]) - y[r]
            c = width[r]
            if abs(w) <= tau * c:
                continue
            alpha = w * y[r]
            xi = c * abs(w)
            u_new = np.zeros_like(x)
            u_new[a_idx] = a_val * w
            nu2 = float(u_new @ u_new)
            x_new = x - abs(w) * (abs(w) - c) / nu2 * u_new
            if state.get("u_old") is not None:
                u_old, a_o, xi_o = state["u_old"], state["alpha_old"], state["xi_old"]
                uf = float(u_old @ x_new)
                uu = float(u_new @ u_old)
                det = nu2 * float(u_old @ u_old) - uu * uu
                t = 0.0
                if det > 1e-9 * nu2 * float(u_old @ u_old):
                    if uf > a_o + xi_o:
                        t = (uf - (a_o + xi_o)) / det
                    elif uf < a_o - xi_o:
                        t = (uf - (a_o - xi_o)) / det
                x_new = x_new + uu * t * u_new - nu2 * t * u_old
            x[:] = x_new
            state["u_old"], state["alpha_old"], state["xi_old"] = u_new, alpha, xi
            n_upd += 1
    return n_upd


@dataclass(frozen=True)
class ResesopParams(MethodParams):
    """The parameters of :func:`resesop`.

    Parameters
    ----------
    n_iter : int, default 20
        Sweep limit (the paper: 20); the discrepancy principle may stop earlier.
    order : {"sequential", "random", "golden"}, default "sequential"
        View order (:func:`~nanoct.recon.rowaction.view_order`); sequential as the paper's
        pseudo-code, and measured best here (``docs/choices.md``).
    nonneg : bool, default True
        Project onto ``x >= 0`` after each sweep (not in the paper; see ``docs/choices.md``).
    seed : int, default 0
        Seed of the random view order.
    residual : {"running", "exact"}, default "running"
        ``"running"``: the root of the sum of squared residuals ``w`` met during the sweep,
        before each ray's update (free). ``"exact"``: ``||A x - y||`` after each sweep (one
        more pass over the matrix per sweep).
    eta_scale : float, default 1.0
        Factor on ``eta`` (the paper's 0.8 / 1.0 / 1.2 under-/over-estimation; also plays the
        role of the paper's ``rho``). Must be >= 0.
    delta : float, optional
        Noise level per ray, >= 0. Default 0 (the paper's data are noise-free), or for
        measured data (``measured``) the estimated noise standard deviation
        (:func:`~nanoct.recon.measured.noise_level`).
    tau : float, default 1.01
        Discrepancy factor, ``tau > 1`` (theory needs it; the paper does not give its value).
    stop_rule : {"sweep", "sticky"}, default "sweep"
        ``"sweep"``: stop after a sweep in which every ray met the discrepancy principle (no
        update). ``"sticky"``: the paper's literal flags, set once a ray meets the
        discrepancy and never cleared; stop when all are set.
    projector : {"auto", "matrix", "matrixfree"}, default "auto"
        Rays from the cached system matrix or computed per view (parallel beam); ``"auto"``
        computes them per view when the matrix would exceed 1 GB
        (:func:`~nanoct.recon.rowaction.resolve_projector`).
    measured : {"auto", "on", "extend", "off"}, default "auto"
        Measured-data treatment (:mod:`~nanoct.recon.measured`): per-view air level removed,
        sinogram extended at the detector edges onto a larger grid, ``delta`` from the
        estimated noise. ``"auto"`` applies it when the detector edges are not at zero (a
        measured scan); a simulation is reconstructed as given.
        ``"extend"``: the same without removing an air level (an object wider than the
        detector, open beam at zero).
    pad : int, optional
        Detector pixels added on each side for measured data (default a quarter of the
        detector width; 0: no extension).
    """

    n_iter: int = 20
    order: str = "sequential"
    nonneg: bool = True
    seed: int = 0
    residual: str = "running"
    eta_scale: float = 1.0
    delta: float | None = None
    tau: float = 1.01
    stop_rule: str = "sweep"
    projector: str = "auto"
    measured: str = "auto"
    pad: int | None = None

    def __post_init__(self) -> None:
        check_row_action(self)
        self._set("eta_scale", check_float(self.eta_scale, "eta_scale", low=0.0))
        if self.delta is not None:
            self._set("delta", check_float(self.delta, "delta", low=0.0))
        measured, pad = check_measured(self.measured, self.pad)
        self._set("measured", measured)
        self._set("pad", pad)
        # the discrepancy principle needs tau > 1
        self._set("tau", check_float(self.tau, "tau", low=1.0, low_open=True))
        self._set("stop_rule", check_choice(self.stop_rule, "stop_rule", STOP_RULES))

    def resolve(self, geometry: Geometry) -> dict[str, Any]:
        """The values for ``geometry`` (the projector checked against it)."""
        return check_projector(super().resolve(geometry), geometry)


def resesop(
    op: Geometry | RayTransform,
    sino: Any,
    eta: Any,
    *,
    x0: Any = None,
    shifts: Any = None,
    callback: Callable[[int, np.ndarray, None], Any] | None = None,
    matrix: sp.csr_matrix | None = None,
    **params: Any,
) -> ReconResult:
    """RESESOP-Kaczmarz with two search directions (the paper's Algorithm 2).

    Parameters
    ----------
    op : Geometry or RayTransform
        Scan geometry of the (inexact, unperturbed) model ``A^eta``.
    sino : array_like of shape (K, L)
        Measured (perturbed, possibly noisy) sinogram ``y^delta``; must be finite.
    eta : array_like of shape (K,) or (K, L)
        Model inexactness per view (``eta_kl = eta_k``) or per ray, >= 0. The paper uses
        ``eta_k = max_l |y_kl - y^eta_kl|``. ``eta = 0`` (with ``delta = 0``) is plain
        SESOP-Kaczmarz, which never meets the discrepancy and runs ``n_iter`` sweeps.
    x0 : array_like of shape (N, N), optional
        Start image (default zeros, as the paper).
    shifts : array_like of shape (K,), optional
        An estimated object shift per view (object pixels along ``e_u``, as Dremel's
        ``motion``): the model ``A^eta`` is then the operator of the object moved by them,
        realised by reading view ``k`` at ``u - d_k``, ``d_k = shifts_k m / Delta_d``
        (:func:`~nanoct.recon.measured.read_moved`; the same shifted model as Dremel's).
        ``eta`` is then the model error left after this motion
        (:func:`~nanoct.recon.eta.eta_from_residual` with the same ``shifts``). Default: the
        unperturbed model, as the paper.
    callback : callable, optional
        ``callback(iteration, x, None)`` after each sweep that did not meet the discrepancy
        principle; returning True stops (reason ``"callback"``).
    matrix : scipy.sparse.csr_matrix, optional
        The system matrix (default :func:`nanoct.core.operators.system_matrix`).
    **params
        The method's parameters: :class:`ResesopParams`.

    Returns
    -------
    ReconResult
        ``stop_reason`` is ``"discrepancy"``, ``"max_iter"`` or ``"callback"``;
        ``params`` includes ``n_updates`` per sweep, and for measured data ``measured_data``.

    Notes
    -----
    Convergence: each update is a metric projection onto a closed convex stripe (or onto the
    intersection of two hyperplanes bounding the current and the previous stripe), so the
    iterates are Fejer monotone with respect to every point of the intersection of all stripes
    (where that is non-empty); with ``tau > 1`` the method stops after finitely many updates
    (Blanke et al. 2020). The ``x >= 0`` projection is one more convex set and keeps this.
    """
    p = ResesopParams.check(op, **params)
    geometry = resolve_geometry(op)
    if shifts is not None:
        sino = check_array(sino, "sinogram", shape=geometry.sino_shape)
        d = check_array(shifts, "shifts", shape=(geometry.n_angles,), dtype=np.float64)
        sino = read_moved(sino, d * geometry.magnification / geometry.det_spacing).astype(np.float32)
    inner = {**params, "measured": "off", "pad": None}
    measured = solve_measured(
        lambda d, x, cb: resesop(
            d.geometry, d.sinogram, d.pad_eta(expand_eta(eta, geometry)), x0=x, callback=cb, matrix=matrix,
            **{**inner, "delta": d.noise if p["delta"] is None else p["delta"]},
        ),
        geometry, sino, p, x0=x0, callback=callback, matrix=matrix,
    )  # fmt: skip
    if measured is not None:
        return measured
    geometry, y, mat, x = prepare_problem(op, sino, matrix, x0, p["projector"])
    width = ((p["delta"] or 0.0) + p["eta_scale"] * expand_eta(eta, geometry)).ravel()
    free = isinstance(mat, ParallelRays)
    norms = None if free else row_norms_squared(mat)
    rng = np.random.default_rng(p["seed"])
    wo = np.zeros_like(x)
    state = np.array([-1.0, 0.0, 0.0])
    flags = np.zeros(y.shape[0], dtype=np.bool_)
    sticky = p["stop_rule"] == "sticky"
    residuals: list[float] = []
    updates: list[int] = []
    stop = "max_iter"
    for it in range(p["n_iter"]):
        views = view_order(geometry.n_angles, p["order"], rng)
        sweep_args = (y, x, width, p["tau"], views, geometry.n_det, wo, state, flags, sticky)
        if free:
            n_upd, run, n_flag = _resesop_sweep_free(mat.params, geometry.n, *sweep_args)
        else:
            n_upd, run, n_flag = _resesop_sweep(mat.indptr, mat.indices, mat.data, norms, *sweep_args)
        updates.append(int(n_upd))
        if p["nonneg"] and n_upd:
            clip_nonneg(x)
            if state[0] >= 0:  # x moved: <a_old, x> must be recomputed
                r = int(state[0])
                state[1] = _old_dot(mat, x, r)
        if p["residual"] == "exact":
            residuals.append(_residual(mat, y, x))
        else:
            residuals.append(math.sqrt(run))
        if (n_upd == 0) if not sticky else (n_flag == y.shape[0]):
            stop = "discrepancy"
            break
        if callback is not None and callback(it, x.reshape(geometry.image_shape), None):
            stop = "callback"
            break
    params = {"method": "resesop", **p, "n_updates": updates}
    return ReconResult(x.reshape(geometry.image_shape), residuals, stop, None, params)


def _old_dot(rays: sp.csr_matrix | ParallelRays, x: np.ndarray, r: int) -> float:
    """``<a_r, x>`` for ray ``r`` (float64 sum)."""
    if isinstance(rays, ParallelRays):
        n_det = rays.geometry.n_det
        setup = ray_setup(rays.params[r // n_det], rays.geometry.n)
        return float(ray_dot(x, rays.geometry.n, setup, setup[6] + (r % n_det) * setup[7])[0])
    return float(row_dot_f64(rays.indices, rays.data, x, rays.indptr[r], rays.indptr[r + 1]))


def _residual(rays: sp.csr_matrix | ParallelRays, y: np.ndarray, x: np.ndarray) -> float:
    """``||A x - y||_2``."""
    if isinstance(rays, ParallelRays):
        g = rays.geometry
        return float(residual_norm_free(rays.params, g.n, g.n_det, y, x))
    return float(residual_norm(rays.indptr, rays.indices, rays.data, y, x))
