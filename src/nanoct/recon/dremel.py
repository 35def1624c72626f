"""Dremel: Kaczmarz view steps interleaved with per-view shift correction (the paper's Algorithm 1).

For each view ``k`` (in the chosen view order) one iteration does

1. ``z = A_k(s_k) x``: forward projection of the current image with the view's current
   model, i.e. the unperturbed rows of view ``k`` followed by a sub-pixel shift on the
   detector (see "Shifted model" below);
2. a relaxed, SART-normalised Kaczmarz block step
   ``x <- x - omega * C^-1 A_k(s_k)^T R_k^-1 (z - y_k)`` with ``R_k`` the row sums (ray
   lengths) of the shifted view and ``C`` the view-averaged column sums ``A^T 1 / K``;
   optionally with the projection onto ``x >= 0`` applied to every pixel as each ray's
   contribution to the step is added (one pass; a pixel is clipped when a partial sum of the
   view step makes it negative, rather than only after the whole view step);
3. the shift update ``s_k <- s_k + lambda * (Delta_d / m) * shift_cross_corr(z, y_k)``
   (:func:`shift_cross_corr`: cross-correlation of the 2x upsampled, mean-subtracted,
   zero-padded projections, cropped and weighted against the zero-padding bias).

A whole iteration runs in one compiled (numba) call: the view step over the cached float32
CSR matrix (row products accumulated in float32, see
:func:`~nanoct.recon.rowaction.row_dot`) and the shift estimate, whose correlation is computed
directly for every lag of the cropped window (``n_SR`` lags, ``O(n_SR^2)`` multiply-adds,
vectorised) instead of by the FFT of :func:`shift_cross_corr`; both give the same arg-max up
to rounding (checked on random signals in the tests).

Sign convention of the shifts
-----------------------------
The returned ``motion[k]`` estimates the object shift ``t_k . e_u`` along the detector axis
``e_u = (cos phi_k, sin phi_k)`` of the true motion ``x_k(r) = x(r + t_k)`` (same sign).
For such a motion the parallel-beam projection obeys ``p_k^moved(s) = p_k(s + t_k . e_u)``.
The paper's ``s`` has the opposite sign (``s_paper = -motion``): it subtracts the
cross-correlation shift where this module adds it.

Shifted model
-------------
``A_k(s) x`` is realised as ``W(d) A_k x`` where ``A_k`` are the CSR rows of view ``k`` and
``W(d)`` is linear interpolation on the detector at positions ``l + d``,
``d = s * m / Delta_d`` (``m`` = :attr:`Geometry.magnification`, ``Delta_d`` = detector pixel
size); the adjoint is ``A_k^T W(d)^T``. For parallel beam this is exact in the continuum
(a shifted object shifts its projection rigidly), up to the smoothing of linear
interpolation. For fan beam it is the usual approximation of the paper and of Dremel et
al. 2018: the shift component along ``e_u`` is magnified by ``m`` at the rotation axis
(the magnification varies by ``~ r / R_source``, < 2.5 % over the paper's object) and the
component along the central ray, which changes the magnification only slightly, is ignored.

Defaults
--------
The defaults were chosen on validation phantoms (own seeds, not a test split); the paper's
ambiguities, what was chosen and the measurements are in ``docs/choices.md`` (Dremel), the
speed in ``benchmarks/README.md``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Any

import numba
import numpy as np
import scipy.fft as sfft
import scipy.sparse as sp

from ..core.geometry import Geometry
from ..core.matrixfree import (
    ParallelRays,
    backproject_traced,
    backproject_traced_serial,
    backproject_view,
    backproject_view_serial,
    column_sums,
    project_view,
    project_view_serial,
    ray_block,
    ray_dot,
    ray_setup,
    trace_view,
    trace_view_serial,
    use_threads,
    view_buffer,
)
from ..core.operators import RayTransform
from ..core.validation import check_array, check_bool, check_choice, check_float, check_int
from .measured import check_measured, solve_measured
from .params import MethodParams, resolve_geometry
from .result import ReconResult
from .rowaction import (
    check_row_action,
    matrix_cache,
    prepare_problem,
    resolve_relaxation,
    row_dot,
    unsigned_indices,
    view_order,
)

__all__ = ["MAX_SHIFT_FRACTION", "DremelParams", "WEIGHTINGS", "dremel", "runaway_shifts", "shift_cross_corr"]


# ------------------------------------------------------------------ cross-correlation
WEIGHTINGS = ("additive", "overlap", "none")


class _XCorr:
    """Pre-computed pieces of :func:`shift_cross_corr` for signals of length ``n``."""

    def __init__(self, n: int, f_sr: int, weighting: str = "additive") -> None:
        check_choice(weighting, "weighting", WEIGHTINGS)
        self.n = n
        self.f = f_sr
        self.mode = weighting
        self.n_sr = n_sr = f_sr * n
        self.pos = np.arange(n_sr) / f_sr  # up-sampling positions (in input samples)
        self.grid = np.arange(n, dtype=np.float64)
        self.nfft = sfft.next_fast_len(2 * n_sr)  # zero padding: linear, not circular
        half = n_sr // 2
        lags = np.arange(-half, n_sr - half)  # cropped to the original size n_sr
        self.lags = lags
        self.index = np.mod(lags, self.nfft)  # where lag l lies in the circular result
        self.abs_lags = np.abs(lags).astype(np.float64)
        # "overlap": inverse overlap fraction n / (n - |l|) (the literal multiplicative reading)
        self.weight = n_sr / (n_sr - self.abs_lags)

    def spectrum(self, signal: np.ndarray) -> tuple[np.ndarray, float]:
        up = np.interp(self.pos, self.grid, signal)
        mean = float(up.mean())
        up -= mean
        return sfft.rfft(up, self.nfft), mean

    def shift(self, z: tuple[np.ndarray, float], y_conj: tuple[np.ndarray, float], subpixel: bool = False) -> float:
        corr = sfft.irfft(z[0] * y_conj[0], self.nfft)
        c = corr[self.index]
        if self.mode == "additive":
            # zero padding after mean subtraction lowers lag l by |l| * mean(z) * mean(y)
            c = c + self.abs_lags * (z[1] * y_conj[1])
        elif self.mode == "overlap":
            c = c * self.weight
        i = int(np.argmax(c))
        zero = int(np.flatnonzero(self.lags == 0)[0])
        if c[i] <= c[zero]:  # ties (e.g. an all-zero model projection) mean no evidence of a shift
            i = zero
        lag = float(self.lags[i])
        if subpixel and 0 < i < c.size - 1:
            # parabola through the peak and its neighbours (not in the paper)
            den = c[i - 1] - 2.0 * c[i] + c[i + 1]
            if den < 0.0:
                lag += float(np.clip(0.5 * (c[i - 1] - c[i + 1]) / den, -0.5, 0.5))
        return lag / self.f


def shift_cross_corr(z: Any, y: Any, f_sr: int = 2, *, weighting: str = "additive", subpixel: bool = False) -> float:
    """Detector shift between two projections by up-sampled cross-correlation.

    Implements the paper's ``shift_cross_corr``: both signals are up-sampled by ``f_sr``
    (linear interpolation; ``n_SR = f_sr * n`` samples), mean-subtracted and zero-padded; the
    cross-correlation ``c_l = sum_n y_n z_{n+l}`` is cropped to the lags
    ``-floor(n_SR/2) <= l < n_SR - floor(n_SR/2)``, corrected for the bias of zero padding
    towards small lags, and the arg-max lag divided by ``f_sr`` is returned.

    The bias correction ("a weighting that boosts the correlation values for higher shifts")
    is not spelled out in the paper. After mean subtraction and zero padding, a lag ``l``
    loses the overlap of the two (negative) baselines over ``|l|`` samples, which lowers
    ``c_l`` by exactly ``|l| mean(z) mean(y)`` when both projections vanish at the detector
    ends (the object stays in the field of view). ``weighting="additive"`` (default) adds
    this back, which makes the estimator unbiased. ``"overlap"`` multiplies by the inverse
    overlap fraction ``n_SR / (n_SR - |l|)``, the textbook "unbiased correlation" weight,
    which over-compensates on projections of phantoms; ``"none"`` keeps the bias towards 0.
    The measured biases are in ``docs/choices.md``.

    Parameters
    ----------
    z : array_like of shape (n,)
        Model (forward) projection.
    y : array_like of shape (n,)
        Measured projection.
    f_sr : int, default 2
        Up-sampling (super-resolution) factor; the paper uses 2. The result is a multiple
        of ``1 / f_sr``.
    weighting : {"additive", "overlap", "none"}, default "additive"
        Zero-padding bias compensation, see above.
    subpixel : bool, default False
        Refine the arg-max by a parabola through the peak and its two neighbours (not in the
        paper); the result is then no longer quantised to ``1 / f_sr``.

    Returns
    -------
    float
        The shift ``sigma`` in detector pixels with ``y[n] ~ z[n + sigma]`` (``y`` is ``z``
        moved by ``-sigma``).
    """
    z = check_array(z, "z", ndim=1, dtype=np.float64)
    y = check_array(y, "y", ndim=1, dtype=np.float64)
    if z.shape != y.shape:
        raise ValueError(f"z and y must have the same length, got {z.shape} and {y.shape}")
    f_sr = check_int(f_sr, "f_sr", 1)
    if z.size < 2:
        raise ValueError("z and y need at least 2 samples")
    xc = _XCorr(z.size, int(f_sr), weighting)
    ys, ym = xc.spectrum(y)
    return xc.shift(xc.spectrum(z), (np.conj(ys), ym), bool(subpixel))


# ------------------------------------------------------------------ numba kernels
@numba.njit(cache=True, nogil=True)
def _interp_weights(pos):  # pragma: no cover - compiled
    i0 = int(math.floor(pos))
    f = pos - i0
    return i0, 1.0 - f, f


@numba.njit(cache=True, nogil=True)
def _project_view(indptr, indices, data, x, base, n_det, p):  # pragma: no cover - compiled
    """Unshifted model projection of one view into ``p``: ``p[l] = <a_(base + l), x>``."""
    for l in range(n_det):
        r = base + l
        p[l] = row_dot(indices, data, x, indptr[r], indptr[r + 1])


@numba.njit(cache=True, nogil=True, inline="always")
def _shifted_step(p, y, ybase, rowsum, rbase, n_det, d, z, g):  # pragma: no cover - compiled
    """Shift the view's projection ``p`` by ``d`` detector pixels into ``z`` and form the Kaczmarz
    update of each detector bin in ``g`` (residual over the shifted row sums, pulled back through
    the interpolation; ``y``/``rowsum`` read from ``ybase``/``rbase``); returns ``||z - y_k||^2``."""
    res2 = 0.0
    for l in range(n_det):
        g[l] = 0.0
    for l in range(n_det):
        i0, w0, w1 = _interp_weights(l + d)
        zz = 0.0
        rs = 0.0
        if 0 <= i0 < n_det:
            zz += w0 * p[i0]
            rs += w0 * rowsum[rbase + i0]
        if 0 <= i0 + 1 < n_det:
            zz += w1 * p[i0 + 1]
            rs += w1 * rowsum[rbase + i0 + 1]
        z[l] = zz
        e = zz - y[ybase + l]
        res2 += e * e
        if rs > 1e-6:
            e = e / rs
            if 0 <= i0 < n_det:
                g[i0] += w0 * e
            if 0 <= i0 + 1 < n_det:
                g[i0 + 1] += w1 * e
    return res2


@numba.njit(cache=True, nogil=True, inline="always")
def _shifted_sq(p, y, ybase, n_det, d):  # pragma: no cover - compiled
    """``||S_d p - y_k||^2``: the view's projection ``p`` shifted by ``d`` detector pixels against ``y``."""
    tot = 0.0
    for l in range(n_det):
        i0, w0, w1 = _interp_weights(l + d)
        zz = 0.0
        if 0 <= i0 < n_det:
            zz += w0 * p[i0]
        if 0 <= i0 + 1 < n_det:
            zz += w1 * p[i0 + 1]
        e = zz - y[ybase + l]
        tot += e * e
    return tot


@numba.njit(cache=True, nogil=True)
def _view_step(
    indptr, indices, data, rowsum, inv_col, y, x, k, n_det, d, omega, nonneg, p, z, g
):  # pragma: no cover - compiled
    """One Dremel view step in place; fills ``z`` (model projection) and returns ``||z - y_k||^2``.

    Pass ``indices`` as unsigned integers (:func:`~nanoct.recon.rowaction.unsigned_indices`).
    The forward projection accumulates in float32 (:func:`~nanoct.recon.rowaction.row_dot`)
    and each pixel's increment ``c * a_rj / C_j`` is formed in float32.
    """
    base = k * n_det
    _project_view(indptr, indices, data, x, base, n_det, p)
    res2 = _shifted_step(p, y, base, rowsum, base, n_det, d, z, g)
    for l in range(n_det):
        if g[l] == 0.0:
            continue
        c = np.float32(-omega * g[l])
        r = base + l
        idx = indices[indptr[r] : indptr[r + 1]]
        a = data[indptr[r] : indptr[r + 1]]
        if nonneg:
            for q in range(idx.shape[0]):
                j = idx[q]
                v = x[j] + c * a[q] * inv_col[j]
                x[j] = v if v > np.float32(0.0) else np.float32(0.0)
        else:
            for q in range(idx.shape[0]):
                j = idx[q]
                x[j] += c * a[q] * inv_col[j]
    return res2


@numba.njit(cache=True, nogil=True, fastmath={"reassoc", "nsz", "contract"})
def _lag_dot(a, b, n):  # pragma: no cover - compiled
    """``sum(a[m] * b[m] for m in range(n))`` (vectorised float64; contiguous slices)."""
    s = 0.0
    for m in range(n):
        s += a[m] * b[m]
    return s


@numba.njit(cache=True, nogil=True)
def _upsample_centre(signal, f_sr, out):  # pragma: no cover - compiled
    """``np.interp(arange(n * f_sr) / f_sr, arange(n), signal)`` minus its mean, into ``out``."""
    n = signal.shape[0]
    tot = 0.0
    for m in range(out.shape[0]):
        pos = m / f_sr
        j = int(math.floor(pos))
        if j >= n - 1:
            v = signal[n - 1]
        else:
            v = (signal[j + 1] - signal[j]) * (pos - j) + signal[j]
        out[m] = v
        tot += v
    mean = tot / out.shape[0]
    for m in range(out.shape[0]):
        out[m] -= mean
    return mean


@numba.njit(cache=True, nogil=True)
def _xcorr_shift(zc, zmean, yc, ymean, f_sr, mode, subpixel, c):  # pragma: no cover - compiled
    """Arg-max lag / ``f_sr`` of the cropped, bias-corrected correlation (as :meth:`_XCorr.shift`).

    ``zc``, ``yc``: up-sampled, mean-subtracted signals (:func:`_upsample_centre`) of length
    ``n_SR``; ``mode`` 0 = "additive", 1 = "overlap", 2 = "none"; ``c``: work array (n_SR,).
    The correlation ``c_l = sum_m yc[m] zc[m + l]`` over the overlap of the zero-padded
    signals is computed directly for every lag ``-floor(n_SR/2) <= l < n_SR - floor(n_SR/2)``
    (the same values as the zero-padded FFT correlation, up to rounding).
    """
    n_sr = zc.shape[0]
    half = n_sr // 2
    mm = zmean * ymean
    best = 0
    for i in range(n_sr):
        lag = i - half
        if lag >= 0:
            v = _lag_dot(yc, zc[lag:], n_sr - lag)
        else:
            v = _lag_dot(yc[-lag:], zc, n_sr + lag)
        a = abs(lag)
        if mode == 0:
            v = v + a * mm
        elif mode == 1:
            v = v * (n_sr / (n_sr - a))
        c[i] = v
        if v > c[best]:
            best = i
    if c[best] <= c[half]:  # ties (e.g. an all-zero model projection): no evidence of a shift
        best = half
    lag = float(best - half)
    if subpixel and 0 < best < n_sr - 1:
        den = c[best - 1] - 2.0 * c[best] + c[best + 1]
        if den < 0.0:
            lag += min(max(0.5 * (c[best - 1] - c[best + 1]) / den, -0.5), 0.5)
    return lag / f_sr


@numba.njit(cache=True, nogil=True)
def _dremel_sweep(
    indptr,
    indices,
    data,
    rowsum,
    inv_col,
    y,
    x,
    views,
    n_det,
    shifts,
    det_per_obj,
    omega,
    nonneg,
    correct,
    lam,
    f_sr,
    mode,
    subpixel,
    ycorr,
    ymean,
    p,
    z,
    g,
    zc,
    c,
):  # pragma: no cover - compiled
    """One Dremel iteration (view steps and shift updates) in place; returns the summed ``||z - y_k||^2``."""
    run = 0.0
    for i in range(views.shape[0]):
        k = views[i]
        d = shifts[k] * det_per_obj
        run += _view_step(indptr, indices, data, rowsum, inv_col, y, x, k, n_det, d, omega, nonneg, p, z, g)
        if correct:
            zmean = _upsample_centre(z, f_sr, zc)
            sigma = _xcorr_shift(zc, zmean, ycorr[k], ymean[k], f_sr, mode, subpixel, c)
            shifts[k] += lam * sigma / det_per_obj
    return run


@numba.njit(cache=True, nogil=True)
def _shifted_residual(indptr, indices, data, y, x, n_det, dshift, p):  # pragma: no cover
    """``||A(s) x - y||_2`` with every view's detector shift ``dshift[k]``."""
    n_views = dshift.shape[0]
    tot = 0.0
    for k in range(n_views):
        base = k * n_det
        _project_view(indptr, indices, data, x, base, n_det, p)
        tot += _shifted_sq(p, y, base, n_det, dshift[k])
    return math.sqrt(tot)


@numba.njit(cache=True, nogil=True)
def _sums(indptr, indices, data, n_cols):  # pragma: no cover - compiled
    m = indptr.shape[0] - 1
    rows = np.zeros(m, dtype=np.float64)
    cols = np.zeros(n_cols, dtype=np.float64)
    for r in range(m):
        s = 0.0
        for q in range(indptr[r], indptr[r + 1]):
            s += data[q]
            cols[indices[q]] += data[q]
        rows[r] = s
    return rows, cols


def _row_col_sums(mat: sp.csr_matrix, n_views: int) -> tuple[np.ndarray, np.ndarray]:
    """Row sums (float64) and inverse view-averaged column sums (float32, 0 where empty), cached."""

    def compute(m: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray]:
        rows, cols = _sums(m.indptr, m.indices, m.data, m.shape[1])
        cols /= n_views
        inv_col = np.zeros(m.shape[1], dtype=np.float32)
        ok = cols > 1e-6
        inv_col[ok] = (1.0 / cols[ok]).astype(np.float32)
        return rows, inv_col

    return matrix_cache(mat, ("dremel_sums", n_views), compute)


@lru_cache(maxsize=2)
def _inverse_column_sums_of(geometry: Geometry) -> np.ndarray:
    cols = column_sums(ParallelRays(geometry).params, geometry.n, geometry.n_det) / geometry.n_angles
    inv_col = np.zeros(cols.shape, dtype=np.float32)
    ok = cols > 1e-6
    inv_col[ok] = (1.0 / cols[ok]).astype(np.float32)
    return inv_col


def _inverse_column_sums(rays: ParallelRays) -> np.ndarray:
    """Inverse view-averaged column sums of the matrix-free rows (float32, 0 where empty), cached."""
    return _inverse_column_sums_of(rays.geometry)


@numba.njit(cache=True, nogil=True)
def _view_step_free(
    par, n, n_det, inv_col, y, x, d, omega, nonneg, p, z, g, rowsum, block, threads, buffered, code, shared, rows
):  # pragma: no cover - compiled
    """:func:`_view_step` with the rays of one view traced on the fly (``par``: its ray parameters).

    ``buffered``: each ray is traced once into ``(code, shared, rows)``
    (:func:`~nanoct.core.matrixfree.trace_view`) for the projection and the back projection;
    otherwise twice (:func:`~nanoct.core.matrixfree.project_view`,
    :func:`~nanoct.core.matrixfree.backproject_view`). ``threads``: the view's rays are split
    over all threads.
    """
    if buffered:
        if threads:
            trace_view(par, n, n_det, x, p, rowsum, code, shared, rows, block)
        else:
            trace_view_serial(par, n, n_det, x, p, rowsum, code, shared, rows, block)
    elif threads:
        project_view(par, n, n_det, x, p, rowsum, block)
    else:
        project_view_serial(par, n, n_det, x, p, rowsum, block)
    res2 = _shifted_step(p, y, 0, rowsum, 0, n_det, d, z, g)
    for l in range(n_det):
        g[l] *= -omega
    if buffered:
        if threads:
            backproject_traced(par, n, n_det, g, x, inv_col, True, nonneg, block, code, shared, rows)
        else:
            backproject_traced_serial(par, n, n_det, g, x, inv_col, True, nonneg, block, code, shared, rows)
    elif threads:
        backproject_view(par, n, n_det, g, x, inv_col, True, nonneg, block)
    else:
        backproject_view_serial(par, n, n_det, g, x, inv_col, True, nonneg, block)
    return res2


@numba.njit(cache=True, nogil=True)
def _dremel_sweep_free(
    params,
    n,
    inv_col,
    y,
    x,
    views,
    n_det,
    shifts,
    det_per_obj,
    omega,
    nonneg,
    correct,
    lam,
    f_sr,
    mode,
    subpixel,
    ycorr,
    ymean,
    p,
    z,
    g,
    zc,
    c,
    rowsum,
    block,
    threads,
    buffered,
    code,
    shared,
    rows,
):  # pragma: no cover - compiled
    """:func:`_dremel_sweep` with the rays traced on the fly (``params``: (K, 6) ray parameters)."""
    run = 0.0
    for i in range(views.shape[0]):
        k = views[i]
        d = shifts[k] * det_per_obj
        yk = y[k * n_det : (k + 1) * n_det]
        step = (omega, nonneg, p, z, g, rowsum, block, threads, buffered, code, shared, rows)
        run += _view_step_free(params[k], n, n_det, inv_col, yk, x, d, *step)
        if correct:
            zmean = _upsample_centre(z, f_sr, zc)
            sigma = _xcorr_shift(zc, zmean, ycorr[k], ymean[k], f_sr, mode, subpixel, c)
            shifts[k] += lam * sigma / det_per_obj
    return run  # fmt: skip


@numba.njit(cache=True, nogil=True)
def _shifted_residual_free(params, n, y, x, n_det, dshift, p):  # pragma: no cover - compiled
    """:func:`_shifted_residual` with the rays traced on the fly."""
    tot = 0.0
    for k in range(dshift.shape[0]):
        setup = ray_setup(params[k], n)
        for l in range(n_det):
            p[l] = ray_dot(x, n, setup, setup[6] + l * setup[7])[0]
        tot += _shifted_sq(p, y, k * n_det, n_det, dshift[k])
    return math.sqrt(tot)


def _measured_correlation(y: np.ndarray, n_views: int, n_det: int, f_sr: int) -> tuple[np.ndarray, np.ndarray]:
    """Up-sampled, mean-subtracted measured projections (K, f_sr L) and their means (K,)."""
    y2 = y.reshape(n_views, n_det)
    ycorr = np.empty((n_views, f_sr * n_det))
    ymean = np.empty(n_views)
    for k in range(n_views):
        ymean[k] = _upsample_centre(y2[k].astype(np.float64), f_sr, ycorr[k])
    return ycorr, ymean


# ------------------------------------------------------------------ public
@dataclass(frozen=True)
class DremelParams(MethodParams):
    """The parameters of :func:`dremel`.

    Parameters
    ----------
    n_iter : int, default 32
        Number of iterations (sweeps over all views); the paper: 32.
    relaxation : float, optional
        ``omega`` of the SART-normalised view step; SART converges for ``0 < omega < 2``.
        Default ``min(1, 8 / K)`` (K views,
        :func:`~nanoct.recon.rowaction.auto_relaxation`): one sweep then moves the image by
        about the same amount whatever the number of views. The paper's ``omega = 1`` is in
        its own operator scaling; ``docs/choices.md`` has the measurements behind the choice.
    order : {"random", "sequential", "golden"}, default "random"
        View order. The paper's pseudo-code is sequential, which converges very slowly with
        view-block steps.
    nonneg : bool, default True
        Keep ``x >= 0``: each pixel is clipped at 0 as each ray's share of the view step is
        added (see the module docstring).
    seed : int, default 0
        Seed of the random view order.
    residual : {"running", "exact"}, default "running"
        ``"running"``: root of the summed squared view residuals ``||A_k(s_k) x - y_k||^2``
        met during the iteration, before each view's step (free). ``"exact"``:
        ``||A(s) x - y||`` with the current image and shifts after each iteration (one more
        pass over the matrix).
    shift_relaxation : float, default 1.0
        ``lambda`` in ``(0, 1]`` (the paper: 1, no relaxation).
    correction_start : int, default 0
        First iteration (0-based) in which shifts are corrected; the paper found 0 best.
    f_sr : int, default 2
        Up-sampling factor of the cross-correlation (the paper: 2).
    weighting : {"additive", "overlap", "none"}, default "additive"
        Zero-padding bias compensation of the cross-correlation (:func:`shift_cross_corr`).
    subpixel : bool, optional
        Parabolic refinement of the correlation peak (:func:`shift_cross_corr`; not in the
        paper). Default False, and True for measured data (``measured``): a real motion is
        not a multiple of ``1 / f_sr`` pixels (on the I13 scan with an added motion the
        refinement gained 0.3 dB, ``docs/reconstruction.md``).
    fix_shifts : bool, default False
        Keep the shifts at ``shifts0`` (no shift correction): SART with a known motion, e.g.
        one estimated jointly from several slices or read from another tool's file.
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

    n_iter: int = 32
    relaxation: float | None = None
    order: str = "random"
    nonneg: bool = True
    seed: int = 0
    residual: str = "running"
    shift_relaxation: float = 1.0
    correction_start: int = 0
    f_sr: int = 2
    weighting: str = "additive"
    subpixel: bool = False
    fix_shifts: bool = False
    projector: str = "auto"
    measured: str = "auto"
    pad: int | None = None

    def __post_init__(self) -> None:
        check_row_action(self)
        measured, pad = check_measured(self.measured, self.pad)
        self._set("measured", measured)
        self._set("pad", pad)
        self._set(
            "shift_relaxation",
            check_float(self.shift_relaxation, "shift_relaxation", low=0.0, high=1.0, low_open=True),
        )
        self._set("correction_start", check_int(self.correction_start, "correction_start", 0))
        self._set("f_sr", check_int(self.f_sr, "f_sr", 1))
        self._set("weighting", check_choice(self.weighting, "weighting", WEIGHTINGS))
        self._set("subpixel", check_bool(self.subpixel, "subpixel"))
        self._set("fix_shifts", check_bool(self.fix_shifts, "fix_shifts"))

    def resolve(self, geometry: Geometry) -> dict[str, Any]:
        """The values for ``geometry`` (default relaxation from its number of views)."""
        return resolve_relaxation(super().resolve(geometry), geometry)


#: Measured data: an estimated shift that moved more than this fraction of the detector width from
#: its start is a runaway estimate, not a motion (views with too little structure to correlate: on
#: the noise-dominated 26-column Diamond K11 crop the shifts reached 45 px); the slice is then
#: reconstructed with the shifts kept at their start (:func:`runaway_shifts`).
MAX_SHIFT_FRACTION = 0.25


def runaway_shifts(change: np.ndarray, geometry: Geometry) -> str | None:
    """Why a shift estimate is rejected as a runaway (None: it is kept).

    Parameters
    ----------
    change : ndarray of shape (K,)
        The estimated object shifts less their start (object pixels).
    geometry : Geometry
        The scan geometry (its detector width sets the bound).

    Returns
    -------
    str or None
        The reason, where a shift moved more than :data:`MAX_SHIFT_FRACTION` of the detector width.
    """
    limit = MAX_SHIFT_FRACTION * geometry.n_det * geometry.det_spacing / geometry.magnification
    largest = float(np.abs(change).max()) if change.size else 0.0
    if largest <= limit:
        return None
    return (
        f"Dremel's shift estimate rejected: it moved up to {largest:.1f} px, more than a quarter of the "
        f"{geometry.n_det}-pixel detector ({limit:.1f} px), which means too little structure to correlate; "
        "the shifts were kept at their start"
    )


def _start(shifts0: Any, n_views: int) -> np.ndarray:
    """The start shifts as a float64 copy: ``shifts0`` checked against ``n_views`` views, or zeros."""
    if shifts0 is None:
        return np.zeros(n_views, dtype=np.float64)
    return check_array(shifts0, "shifts0", shape=(n_views,), dtype=np.float64).copy()


def _dremel_measured(
    op: Geometry | RayTransform, sino: Any, p: dict[str, Any], params: dict[str, Any], args: dict[str, Any]
) -> ReconResult | None:
    """:func:`dremel` on the measured-data treatment (None where it does not apply), the shifts kept at their
    start where the estimate runs away (:func:`runaway_shifts`; ``args``: dremel's other arguments)."""
    inner = {"subpixel": True, **params, "measured": "off", "pad": None}  # measured data: the refined peak
    stop = args["stop_residual"]
    measured = solve_measured(
        lambda d, x, cb: dremel(
            d.geometry, d.sinogram, **inner,
            **{**args, "x0": x, "callback": cb, "stop_residual": d.discrepancy() if stop is None else stop},
        ),
        resolve_geometry(op), sino, p, x0=args["x0"], callback=args["callback"], matrix=args["matrix"],
    )  # fmt: skip
    if measured is None or p["fix_shifts"]:
        return measured
    reason = runaway_shifts(measured.motion - _start(args["shifts0"], measured.motion.size), resolve_geometry(op))
    if reason is None:
        return measured
    kept = dremel(op, sino, **args, **{**params, "fix_shifts": True})
    return replace(kept, params={**kept.params, "shift_check": reason})


def dremel(
    op: Geometry | RayTransform,
    sino: Any,
    *,
    x0: Any = None,
    shifts0: Any = None,
    callback: Callable[[int, np.ndarray, np.ndarray], Any] | None = None,
    matrix: sp.csr_matrix | None = None,
    stop_residual: float | None = None,
    **params: Any,
) -> ReconResult:
    """Dremel reconstruction with per-view object-shift estimation (the paper's Algorithm 1).

    Parameters
    ----------
    op : Geometry or RayTransform
        Scan geometry of the unperturbed model.
    sino : array_like of shape (K, L)
        Measured (perturbed) sinogram; must be finite.
    x0 : array_like of shape (N, N), optional
        Start image (default zeros, "empty phantom").
    shifts0 : array_like of shape (K,), optional
        Initial object shifts (default zeros).
    callback : callable, optional
        ``callback(iteration, x, shifts)`` after each iteration (``shifts`` a float32 copy);
        True stops ("callback").
    matrix : scipy.sparse.csr_matrix, optional
        The system matrix (default :func:`nanoct.core.operators.system_matrix`).
    stop_residual : float, optional
        Stop (reason ``"discrepancy"``) after the first iteration whose recorded residual is
        at most this value (the discrepancy principle). Default: none, or for measured data
        (``measured``) the bound from the estimated noise
        (:meth:`~nanoct.recon.measured.MeasuredData.discrepancy`).
    **params
        The method's parameters: :class:`DremelParams`.

    Returns
    -------
    ReconResult
        ``image``; ``residuals`` per iteration; ``stop_reason`` ``"max_iter"``,
        ``"discrepancy"`` or ``"callback"``; for measured data ``params["measured_data"]``, and
        ``params["shift_check"]`` where the shift estimate ran away (:func:`runaway_shifts`: the
        slice is then reconstructed with the shifts kept at ``shifts0``);
        ``motion``: the estimated object shift per view, shape (K,), float32, in pixels
        along ``e_u = (cos phi_k, sin phi_k)``, same sign as ``t_k . e_u`` of the true motion
        (see the module docstring).

    Notes
    -----
    Convergence: for fixed shifts the iteration is SART over view blocks, convergent for
    ``0 < omega < 2``; the shift updates make the model change, so there is no general
    convergence guarantee (as in the paper). A translation common to all views
    (``a cos phi_k + b sin phi_k``) is not determined by the data (the image can absorb it),
    so estimated shifts may differ from the true ones by such a term.
    """
    p = DremelParams.check(op, **params)
    args = {"x0": x0, "shifts0": shifts0, "callback": callback, "matrix": matrix, "stop_residual": stop_residual}
    measured = _dremel_measured(op, sino, p, params, args)
    if measured is not None:
        return measured
    geometry, y, mat, x = prepare_problem(op, sino, matrix, x0, p["projector"])
    shifts = _start(shifts0, geometry.n_angles)
    n_views, n_det = geometry.sino_shape
    det_per_obj = geometry.magnification / geometry.det_spacing  # detector px per object px
    f_sr = p["f_sr"]
    ycorr, ymean = _measured_correlation(y, n_views, n_det, f_sr)
    rng = np.random.default_rng(p["seed"])
    work = (np.zeros(n_det), np.zeros(n_det), np.zeros(n_det), np.zeros(f_sr * n_det), np.zeros(f_sr * n_det))
    shift_args = (p["shift_relaxation"], f_sr, WEIGHTINGS.index(p["weighting"]), p["subpixel"])
    residuals: list[float] = []
    stop = "max_iter"
    start = p["n_iter"] if p["fix_shifts"] else p["correction_start"]  # first iteration with shift correction
    free = isinstance(mat, ParallelRays)
    if free:
        inv_col = _inverse_column_sums(mat)
        rowsum = np.zeros(n_det)
        buffer = view_buffer(geometry)
        buffered = buffer is not None
        if buffer is None:  # typed placeholders: each ray is traced twice per view step
            buffer = (np.empty((1, 1), np.int32), np.empty((1, 1), np.float32), np.empty((1, 4), np.int32))
    else:
        rowsum, inv_col = _row_col_sums(mat, n_views)
        indices = unsigned_indices(mat)
    for it in range(p["n_iter"]):
        views = view_order(n_views, p["order"], rng)
        step = (det_per_obj, p["relaxation"], p["nonneg"], it >= start)
        if free:
            run = _dremel_sweep_free(
                mat.params, geometry.n, inv_col, y, x, views, n_det, shifts, *step, *shift_args, ycorr, ymean,
                *work, rowsum, ray_block(geometry), use_threads(geometry), buffered, *buffer,
            )  # fmt: skip
        else:
            step_args = (views, n_det, shifts, *step)
            run = _dremel_sweep(
                mat.indptr, indices, mat.data, rowsum, inv_col, y, x, *step_args, *shift_args, ycorr, ymean, *work
            )
        if p["residual"] == "exact":
            dshift = shifts * det_per_obj
            if free:
                residuals.append(float(_shifted_residual_free(mat.params, geometry.n, y, x, n_det, dshift, work[0])))
            else:
                residuals.append(float(_shifted_residual(mat.indptr, indices, mat.data, y, x, n_det, dshift, work[0])))
        else:
            residuals.append(math.sqrt(run))
        if stop_residual is not None and residuals[-1] <= stop_residual:
            stop = "discrepancy"
            break
        if callback is not None and callback(it, x.reshape(geometry.image_shape), shifts.astype(np.float32)):
            stop = "callback"
            break
    image = x.reshape(geometry.image_shape)
    return ReconResult(image, residuals, stop, shifts.astype(np.float32), {"method": "dremel", **p})
