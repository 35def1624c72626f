"""Rays traced on the fly: the parallel-beam ``line`` model without a stored matrix.

The cached system matrix (:func:`nanoct.core.operators.system_matrix`) holds every ray of every
view and grows as N³ (8 bytes per non-zero, about 1.3 K N² non-zeros for K views: 0.5 GB at
the paper-parallel preset, 3 GB at N = 511, 190 GB at N = 2048). The row-action methods use
one ray (Kaczmarz, RESESOP) or one view (Dremel) at a time, so above a size they trace each
ray when they need it (:func:`ray_dot`, :func:`ray_add`) and store nothing but the image.
Kaczmarz and RESESOP trace each ray once into a buffer of at most ``3 N`` pixels
(:func:`ray_trace`) and use it for the ray's dot product and its update; Dremel traces a
whole view's rays once into a per-view buffer (:func:`trace_view`, at most
:data:`VIEW_BUFFER_BYTES`) and uses it for the view's projection and back projection
(:func:`backproject_traced`).

The line model is ASTRA's parallel-beam ``line`` kernel: a ray that is mainly vertical
(``|ray_x| < |ray_y|``) crosses the centre line of every image row at a fractional column
``c``; with ``m`` the nearest column and ``o = c - m``, the ray's length per row
``h = sqrt(rx² + ry²) / |ry|`` goes to column ``m`` alone when ``|o| <= S`` and is shared
linearly with the neighbour towards ``o`` otherwise (``S = (1 - |rx / ry|) / 2``,
``T = (1 + |rx / ry|) / 2``: the neighbour gets ``h (|o| - S) / (T - S)``). Mainly horizontal
rays are handled the same way with rows and columns exchanged. Here the arithmetic is float64
and the crossings are computed directly (ASTRA accumulates them in float32), so a ray's weights
agree with the cached CSR row to about 1e-3 of a pixel length (tested row by row).

A view's rays can be split over threads (:func:`project_view`, :func:`backproject_view` and
the buffered :func:`trace_view`, :func:`backproject_traced`):
projections are independent; back projections go in blocks of rays, the even blocks in
parallel and then the odd ones, so that concurrent blocks touch disjoint pixels and the
result does not depend on the number of threads.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .geometry import Geometry
from .operators import astra_vectors

__all__ = [
    "NNZ_PER_VIEW_PIXEL",
    "PARALLEL_MIN_WORK",
    "ParallelRays",
    "VIEW_BUFFER_BYTES",
    "backproject_traced",
    "backproject_traced_serial",
    "backproject_view",
    "backproject_view_serial",
    "column_sums",
    "matrix_bytes",
    "project_view",
    "project_view_serial",
    "ray_add",
    "ray_block",
    "ray_dot",
    "ray_set",
    "ray_setup",
    "ray_trace",
    "residual_norm_free",
    "trace_view",
    "trace_view_serial",
    "use_threads",
    "view_buffer",
]

#: Non-zeros of the parallel ``line`` matrix per view and image pixel (measured: 47.0 M for the
#: paper-parallel preset, K = 567, N = 255, gives 1.27; rounded up).
NNZ_PER_VIEW_PIXEL = 1.3


def matrix_bytes(geometry: Geometry) -> int:
    """Estimated bytes of the cached CSR system matrix of ``geometry`` (float32 values, int32 indices).

    ``8 * NNZ_PER_VIEW_PIXEL * K * N²`` for parallel beam; for fan beam the same order (the
    estimate is used only to choose a projector).
    """
    return int(8 * NNZ_PER_VIEW_PIXEL * geometry.n_angles * geometry.n * geometry.n)


class ParallelRays:
    """The per-view ray parameters of a parallel-beam geometry, as ASTRA stores them (float32).

    Parameters
    ----------
    geometry : Geometry
        A parallel-beam geometry (its rotation-axis offset included).

    Attributes
    ----------
    params : ndarray of shape (K, 6), float32
        Per view ``(ray_x, ray_y, start_x, start_y, u_x, u_y)``: ray direction, the detector's
        edge ``d - L/2 u`` and its pixel vector.
    """

    def __init__(self, geometry: Geometry) -> None:
        if geometry.kind != "parallel":
            raise ValueError(
                f"the matrix-free projector covers parallel beam only, got a {geometry.kind}-beam "
                "geometry; use projector='matrix'"
            )
        self.geometry = geometry
        vec = astra_vectors(geometry)
        start = vec[:, 2:4] - 0.5 * geometry.n_det * vec[:, 4:6]
        self.params = np.ascontiguousarray(np.concatenate([vec[:, 0:2], start, vec[:, 4:6]], axis=1), np.float32)


# ------------------------------------------------------------------ fused kernels (no rows stored)
@numba.njit(cache=True, nogil=True)
def ray_setup(par, n):  # pragma: no cover - compiled
    """Per-view constants of the fused kernels.

    Returns ``(major, minor, delta, s, invw, length, c_first, c_step)``: the ray crosses the
    centre line ``i`` of the major axis (rows for mainly vertical rays, columns otherwise;
    pixel stride ``major``) at the fractional minor coordinate (stride ``minor``)
    ``c = c_first + det * c_step + i * delta``.
    """
    rx, ry = np.float64(par[0]), np.float64(par[1])
    sx, sy, ux, uy = np.float64(par[2]), np.float64(par[3]), np.float64(par[4]), np.float64(par[5])
    ex = -n / 2.0 + 0.5
    ey = n / 2.0 - 0.5
    norm = math.sqrt(rx * rx + ry * ry)
    if abs(rx) < abs(ry):
        ratio = rx / ry
        c_first = sx + 0.5 * ux + (ey - sy - 0.5 * uy) * ratio - ex
        c_step = ux - uy * ratio
        major, minor, length = n, 1, norm / abs(ry)
    else:
        ratio = ry / rx
        c_first = -(sy + 0.5 * uy + (ex - sx - 0.5 * ux) * ratio - ey)
        c_step = -(uy - ux * ratio)
        major, minor, length = 1, n, norm / abs(rx)
    s = 0.5 - 0.5 * abs(ratio)
    width = abs(ratio)  # T - S
    invw = 1.0 / width if width > 1e-12 else 1e30  # axis-parallel rays: no sharing
    return major, minor, -ratio, s, invw, length, c_first, c_step


@numba.njit(cache=True, nogil=True, inline="always")
def _minor(c):  # pragma: no cover - compiled
    return int(math.floor(c + 0.5))


@numba.njit(cache=True, nogil=True, fastmath={"reassoc", "nsz", "contract"})
def ray_dot(x, n, setup, c0):  # pragma: no cover - compiled
    """``(<a, x>, sum(a), sum(a²))`` for the ray whose first crossing is ``c0`` (flat image ``x``)."""
    major, minor, delta, s, invw, length = setup[0], setup[1], setup[2], setup[3], setup[4], setup[5]
    dot = 0.0
    tot = 0.0
    sq = 0.0
    for i in range(n):
        c = c0 + i * delta
        m = _minor(c)
        off = c - m
        wl = length * min(max((-s - off) * invw, 0.0), 1.0)
        wr = length * min(max((off - s) * invw, 0.0), 1.0)
        wc = length - wl - wr
        base = i * major + m * minor
        if 1 <= m <= n - 2:  # all three neighbours inside: no bounds tests
            dot += wl * x[base - minor] + wc * x[base] + wr * x[base + minor]
            tot += length
            sq += wl * wl + wc * wc + wr * wr
            continue
        if m < -1 or m > n:
            continue
        if m >= 1:
            dot += wl * x[base - minor]
            tot += wl
            sq += wl * wl
        if 0 <= m < n:
            dot += wc * x[base]
            tot += wc
            sq += wc * wc
        if m + 1 < n:
            dot += wr * x[base + minor]
            tot += wr
            sq += wr * wr
    return dot, tot, sq


@numba.njit(cache=True, nogil=True, inline="always")
def _put(x, j, v, scale, scaled, nonneg):  # pragma: no cover - compiled
    if scaled:
        v *= scale[j]
    v += x[j]
    x[j] = v if (v > 0.0 or not nonneg) else 0.0


@numba.njit(cache=True, nogil=True)
def ray_add(x, n, setup, c0, coef, scale, scaled, nonneg):  # pragma: no cover - compiled
    """``x[j] += coef * a_j (* scale[j] if scaled)`` along one ray, clipped at 0 if ``nonneg``."""
    major, minor, delta, s, invw, length = setup[0], setup[1], setup[2], setup[3], setup[4], setup[5]
    for i in range(n):
        c = c0 + i * delta
        m = _minor(c)
        off = c - m
        wl = length * min(max((-s - off) * invw, 0.0), 1.0)
        wr = length * min(max((off - s) * invw, 0.0), 1.0)
        wc = length - wl - wr
        base = i * major + m * minor
        if 1 <= m <= n - 2:
            _put(x, base - minor, coef * wl, scale, scaled, nonneg)
            _put(x, base, coef * wc, scale, scaled, nonneg)
            _put(x, base + minor, coef * wr, scale, scaled, nonneg)
            continue
        if m < -1 or m > n:
            continue
        if m >= 1:
            _put(x, base - minor, coef * wl, scale, scaled, nonneg)
        if 0 <= m < n:
            _put(x, base, coef * wc, scale, scaled, nonneg)
        if m + 1 < n:
            _put(x, base + minor, coef * wr, scale, scaled, nonneg)


@numba.njit(cache=True, nogil=True)
def ray_set(x, n, setup, c0, coef):  # pragma: no cover - compiled
    """``x[j] = coef * a_j`` for the pixels of one ray (``coef = 0`` clears them)."""
    major, minor, delta, s, invw, length = setup[0], setup[1], setup[2], setup[3], setup[4], setup[5]
    for i in range(n):
        c = c0 + i * delta
        m = _minor(c)
        if m < -1 or m > n:
            continue
        off = c - m
        wl = length * min(max((-s - off) * invw, 0.0), 1.0)
        wr = length * min(max((off - s) * invw, 0.0), 1.0)
        base = i * major + m * minor
        if m >= 1:
            x[base - minor] = coef * wl
        if 0 <= m < n:
            x[base] = coef * (length - wl - wr)
        if m + 1 < n:
            x[base + minor] = coef * wr


@numba.njit(cache=True, nogil=True)
def _trace_into(n, setup, c0, idx, wts):  # pragma: no cover - compiled
    """Store the pixels of one ray in ``idx[:cnt]`` and their weights in ``wts[:cnt]``.

    The pixels of :func:`ray_dot`, :func:`ray_add` and :func:`ray_set` in their order (zero
    weights of in-bounds neighbours included), with a branch-free interior. Returns
    ``(cnt, sum of the weights)``.
    """
    major, minor, delta, s, invw, length = setup[0], setup[1], setup[2], setup[3], setup[4], setup[5]
    q = 0
    tot = 0.0
    for i in range(n):
        c = c0 + i * delta
        m = _minor(c)
        if m < -1 or m > n:
            continue
        off = c - m
        wl = length * min(max((-s - off) * invw, 0.0), 1.0)
        wr = length * min(max((off - s) * invw, 0.0), 1.0)
        wc = length - wl - wr
        base = i * major + m * minor
        if 1 <= m <= n - 2:
            idx[q] = base - minor
            wts[q] = wl
            idx[q + 1] = base
            wts[q + 1] = wc
            idx[q + 2] = base + minor
            wts[q + 2] = wr
            q += 3
            tot += length
            continue
        if m >= 1:
            idx[q] = base - minor
            wts[q] = wl
            q += 1
            tot += wl
        if 0 <= m < n:
            idx[q] = base
            wts[q] = wc
            q += 1
            tot += wc
        if m + 1 < n:
            idx[q] = base + minor
            wts[q] = wr
            q += 1
            tot += wr
    return q, tot


@numba.njit(cache=True, nogil=True)
def ray_trace(x, n, setup, c0, idx, wts):  # pragma: no cover - compiled
    """Store the pixels of one ray: ``idx[:cnt]`` flat pixel indices, ``wts[:cnt]`` their weights.

    The same pixels and weights as :func:`ray_dot`, :func:`ray_add` and :func:`ray_set` (zero
    weights of in-bounds neighbours included); ``idx`` and ``wts`` need ``3 N`` entries.
    Returns ``(cnt, <a, x>, sum(a²))`` (flat image ``x``). A method that uses a ray several
    times traces it once into these buffers.
    """
    cnt = _trace_into(n, setup, c0, idx, wts)[0]
    dot = 0.0
    sq = 0.0
    for q in range(cnt):
        w = wts[q]
        dot += w * x[idx[q]]
        sq += w * w
    return cnt, dot, sq


@numba.njit(cache=True, nogil=True)
def column_sums(params, n, n_det):  # pragma: no cover - compiled
    """``A^T 1``: the column sums of all views' rows, (N*N,) float64 (``params``: (K, 6))."""
    cols = np.zeros(n * n)
    for k in range(params.shape[0]):
        setup = ray_setup(params[k], n)
        for l in range(n_det):
            ray_add(cols, n, setup, setup[6] + l * setup[7], 1.0, cols, False, False)
    return cols


@numba.njit(cache=True, nogil=True)
def residual_norm_free(params, n, n_det, y, x):  # pragma: no cover - compiled
    """``||A x - y||_2`` with the rays traced on the fly (``y`` flat, view-major)."""
    tot = 0.0
    for k in range(params.shape[0]):
        setup = ray_setup(params[k], n)
        for l in range(n_det):
            e = ray_dot(x, n, setup, setup[6] + l * setup[7])[0] - y[k * n_det + l]
            tot += e * e
    return math.sqrt(tot)


def ray_block(geometry: Geometry) -> int:
    """Rays per block of the parallel kernels: blocks two apart touch disjoint pixels.

    A ray touches pixels within 1.5 pixels of its crossings, and neighbouring rays cross a
    row (or column) at least ``det_spacing`` apart, so a gap of ``4 / det_spacing`` rays
    (at least 8) separates the pixels of two blocks of one phase.
    """
    return max(8, math.ceil(4.0 / geometry.det_spacing))


@numba.njit(cache=True, nogil=True)
def _project_rays(par, n, x, p, rowsum, lo, hi):  # pragma: no cover - compiled
    setup = ray_setup(par, n)
    for l in range(lo, hi):
        dot, tot, _ = ray_dot(x, n, setup, setup[6] + l * setup[7])
        p[l] = dot
        rowsum[l] = tot


@numba.njit(cache=True, nogil=True)
def _backproject_rays(par, n, coef, x, scale, scaled, nonneg, lo, hi):  # pragma: no cover - compiled
    setup = ray_setup(par, n)
    for l in range(lo, hi):
        if coef[l] != 0.0:
            ray_add(x, n, setup, setup[6] + l * setup[7], coef[l], scale, scaled, nonneg)


@numba.njit(cache=True, parallel=True)
def project_view(par, n, n_det, x, p, rowsum, block):  # pragma: no cover - compiled
    """``p[l] = <a_l, x>`` and ``rowsum[l] = sum(a_l)`` for the rays of one view, blocks in parallel."""
    for b in numba.prange((n_det + block - 1) // block):
        _project_rays(par, n, x, p, rowsum, b * block, min((b + 1) * block, n_det))


@numba.njit(cache=True, nogil=True)
def project_view_serial(par, n, n_det, x, p, rowsum, block):  # pragma: no cover - compiled
    """:func:`project_view` on one thread."""
    _project_rays(par, n, x, p, rowsum, 0, n_det)


@numba.njit(cache=True, parallel=True)
def backproject_view(par, n, n_det, coef, x, scale, scaled, nonneg, block):  # pragma: no cover - compiled
    """``x += sum_l coef[l] a_l`` (times ``scale`` if ``scaled``, clipped at 0 if ``nonneg``) for one view.

    Rays go in blocks of ``block`` (:func:`ray_block`): first the even blocks in parallel,
    then the odd ones; blocks of one phase touch disjoint pixels, so the result does not
    depend on the number of threads. Within a block the rays go in detector order.
    """
    n_blocks = (n_det + block - 1) // block
    for phase in range(2):
        for b in numba.prange((n_blocks + 1 - phase) // 2):
            start = (2 * b + phase) * block
            _backproject_rays(par, n, coef, x, scale, scaled, nonneg, start, min(start + block, n_det))


@numba.njit(cache=True, nogil=True)
def backproject_view_serial(par, n, n_det, coef, x, scale, scaled, nonneg, block):  # pragma: no cover - compiled
    """:func:`backproject_view` on one thread, blocks in the same order (the same result)."""
    n_blocks = (n_det + block - 1) // block
    for phase in range(2):
        for b in range((n_blocks + 1 - phase) // 2):
            start = (2 * b + phase) * block
            _backproject_rays(par, n, coef, x, scale, scaled, nonneg, start, min(start + block, n_det))


#: Views with at least this many ray-crossings (``N * L``) are projected and back-projected
#: with all threads (:func:`project_view`, :func:`backproject_view`); smaller ones on one
#: thread. Threads meet twice per view; on the shared 2-core machine of the benchmarks that
#: made a Dremel sweep at N = 511 several times slower than one thread
#: (``benchmarks/README.md``), so only views of 2048-column scans (N L >= 2^22) use them.
PARALLEL_MIN_WORK = 1 << 22


def use_threads(geometry: Geometry) -> bool:
    """Whether one view's rays are split over threads: ``N * L >= PARALLEL_MIN_WORK``."""
    return geometry.n * geometry.n_det >= PARALLEL_MIN_WORK


# ------------------------------------------------------------------ views traced once into a buffer
#: Largest per-view buffer of traced rays (bytes): ``12 * 3 N * L`` (int32 pixel index and
#: float64 weight for at most ``3 N`` pixels per ray). Views whose buffer would be larger are
#: traced twice per step (:func:`project_view`, :func:`backproject_view`).
VIEW_BUFFER_BYTES = 256 * 2**20


def view_buffer(geometry: Geometry) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """A buffer for one view's traced rays, or None when it would exceed :data:`VIEW_BUFFER_BYTES`.

    Parameters
    ----------
    geometry : Geometry
        A parallel-beam geometry.

    Returns
    -------
    tuple of ndarray or None
        ``(idx, wts, cnt)``: (L, 3 N) int32 flat pixel indices, (L, 3 N) float64 weights and
        (L,) int64 pixel counts, for :func:`trace_view` and :func:`backproject_traced`.
    """
    n, n_det = geometry.n, geometry.n_det
    if 12 * 3 * n * n_det > VIEW_BUFFER_BYTES:
        return None
    return np.empty((n_det, 3 * n), np.int32), np.empty((n_det, 3 * n)), np.empty(n_det, np.int64)


@numba.njit(cache=True, nogil=True)
def _trace_rays(par, n, x, p, rowsum, idx, wts, cnt, lo, hi):  # pragma: no cover - compiled
    """Rays ``lo:hi`` of a view traced into rows of the buffer (:func:`_trace_into`), with their
    projections ``p`` and weight sums ``rowsum``."""
    setup = ray_setup(par, n)
    for l in range(lo, hi):
        q, tot = _trace_into(n, setup, setup[6] + l * setup[7], idx[l], wts[l])
        cnt[l] = q
        rowsum[l] = tot
        p[l] = _gather_dot(idx[l], wts[l], x, q)


@numba.njit(cache=True, nogil=True, fastmath={"reassoc", "nsz", "contract"})
def _gather_dot(idx, wts, x, cnt):  # pragma: no cover - compiled
    """``sum(wts[q] * x[idx[q]] for q < cnt)`` (vectorised float64)."""
    dot = 0.0
    for q in range(cnt):
        dot += wts[q] * x[idx[q]]
    return dot


@numba.njit(cache=True, nogil=True)
def _backproject_traced_rays(coef, x, scale, scaled, nonneg, idx, wts, cnt, lo, hi):  # pragma: no cover
    for l in range(lo, hi):
        cl = coef[l]
        if cl != 0.0:
            for q in range(cnt[l]):
                _put(x, idx[l, q], cl * wts[l, q], scale, scaled, nonneg)


@numba.njit(cache=True, parallel=True)
def trace_view(par, n, n_det, x, p, rowsum, idx, wts, cnt, block):  # pragma: no cover - compiled
    """Trace the rays of one view into ``(idx, wts, cnt)`` (:func:`view_buffer`), blocks in parallel.

    Ray ``l`` stores its pixels in ``idx[l, :cnt[l]]`` and weights in ``wts[l, :cnt[l]]``
    (:func:`ray_trace`); also ``p[l] = <a_l, x>`` and ``rowsum[l] = sum(a_l)``.
    """
    for b in numba.prange((n_det + block - 1) // block):
        _trace_rays(par, n, x, p, rowsum, idx, wts, cnt, b * block, min((b + 1) * block, n_det))


@numba.njit(cache=True, nogil=True)
def trace_view_serial(par, n, n_det, x, p, rowsum, idx, wts, cnt, block):  # pragma: no cover - compiled
    """:func:`trace_view` on one thread."""
    _trace_rays(par, n, x, p, rowsum, idx, wts, cnt, 0, n_det)


@numba.njit(cache=True, parallel=True)
def backproject_traced(n_det, coef, x, scale, scaled, nonneg, block, idx, wts, cnt):  # pragma: no cover
    """:func:`backproject_view` with the view's rays read from the buffer of :func:`trace_view`.

    The same pixels, increments and block order as :func:`backproject_view`, so the same result.
    """
    n_blocks = (n_det + block - 1) // block
    for phase in range(2):
        for b in numba.prange((n_blocks + 1 - phase) // 2):
            start = (2 * b + phase) * block
            _backproject_traced_rays(coef, x, scale, scaled, nonneg, idx, wts, cnt, start, min(start + block, n_det))


@numba.njit(cache=True, nogil=True)
def backproject_traced_serial(n_det, coef, x, scale, scaled, nonneg, block, idx, wts, cnt):  # pragma: no cover
    """:func:`backproject_traced` on one thread, blocks in the same order (the same result)."""
    n_blocks = (n_det + block - 1) // block
    for phase in range(2):
        for b in range((n_blocks + 1 - phase) // 2):
            start = (2 * b + phase) * block
            _backproject_traced_rays(coef, x, scale, scaled, nonneg, idx, wts, cnt, start, min(start + block, n_det))
