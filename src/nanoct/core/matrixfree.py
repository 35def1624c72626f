"""Rays traced on the fly: the parallel-beam ``line`` model without a stored matrix.

The cached system matrix (:func:`nanoct.core.operators.system_matrix`) holds every ray of every
view and grows as N³ (8 bytes per non-zero, about 1.3 K N² non-zeros for K views: 0.5 GB at
the paper-parallel preset, 3 GB at N = 511, 190 GB at N = 2048). The row-action methods use
one ray (Kaczmarz, RESESOP) or one view (Dremel) at a time, so above a size they trace each
ray when they need it (:func:`ray_dot`, :func:`ray_add`) and store nothing but the image.
Kaczmarz and RESESOP trace each ray once into a buffer of at most ``2 N`` pixels
(:func:`ray_trace`) and use it for the ray's dot product and its update; Dremel traces a
whole view's rays once into a per-view buffer (:func:`trace_view`, 8 bytes per ray and image
line, at most :data:`VIEW_BUFFER_BYTES`) and uses it for the view's projection and back
projection (:func:`backproject_traced`).

Every kernel splits a ray into its interior lines, where all three candidate pixels lie in the
image (:func:`ray_rows`, found from the line's equation), and the few edge lines. The interior
runs without branches, so the compiler vectorises the weights and the projection, and a ray's
lines outside the image are never visited. Pixel updates are written out in the loops: a
compiled call per pixel (with the image as an argument) costs several times the update.

The line model is ASTRA's parallel-beam ``line`` kernel: a ray that is mainly vertical
(``|ray_x| < |ray_y|``) crosses the centre line of every image row at a fractional column
``c``; with ``m`` the nearest column and ``o = c - m``, the ray's length per row
``h = sqrt(rx² + ry²) / |ry|`` goes to column ``m`` alone when ``|o| <= S`` and is shared
linearly with the neighbour towards ``o`` otherwise (``S = (1 - |rx / ry|) / 2``,
``T = (1 + |rx / ry|) / 2``: the neighbour gets ``h (|o| - S) / (T - S)``). Mainly horizontal
rays are handled the same way with rows and columns exchanged. Here the crossings are computed
directly in float64 (ASTRA accumulates them in float32) and the shared weight is rounded to
float32, as the cached matrix stores its weights (the nearest pixel gets ``h`` minus it), so a
ray's weights agree with the cached CSR row (tested row by row: 99.9 % within 1e-3 of a pixel
length, all within 1e-2, the largest for nearly axis-parallel rays).

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
    "RAY_ENTRIES_PER_N",
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
    "ray_rows",
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


@numba.njit(cache=True, nogil=True)
def _rows_between(n, delta, c0, m_lo, m_hi, i_lo, i_hi):  # pragma: no cover - compiled
    """The major lines ``i`` in ``[i_lo, i_hi)`` whose nearest minor index
    ``m = floor(c0 + i delta + 1/2)`` lies in ``[m_lo, m_hi]``, as ``(a, b)``.

    ``c0 + i delta`` is monotone in ``i`` (rounding is monotone), so these lines form one range;
    an estimate from the line's equation is widened and then trimmed by testing its ends.
    """
    if i_lo >= i_hi:
        return i_lo, i_lo
    if delta == 0.0:
        m = _minor(c0)
        return (i_lo, i_hi) if m_lo <= m <= m_hi else (i_lo, i_lo)
    t1 = (m_lo - 0.5 - c0) / delta
    t2 = (m_hi + 0.5 - c0) / delta
    lo = max(int(math.floor(min(max(min(t1, t2), -1.0), n + 1.0))) - 1, i_lo)  # clamped before int()
    hi = min(int(math.ceil(min(max(max(t1, t2), -1.0), n + 1.0))) + 2, i_hi)
    while lo < hi and not (m_lo <= _minor(c0 + lo * delta) <= m_hi):
        lo += 1
    while hi > lo and not (m_lo <= _minor(c0 + (hi - 1) * delta) <= m_hi):
        hi -= 1
    if lo >= hi:
        return i_lo, i_lo
    return lo, hi


@numba.njit(cache=True, nogil=True)
def ray_rows(n, setup, c0):  # pragma: no cover - compiled
    """``(r0, a, b, r1)``: the ray touches pixels on major lines ``[r0, r1)``, with all three
    neighbours ``m - 1, m, m + 1`` inside the image on ``[a, b)`` (the interior)."""
    r0, r1 = _rows_between(n, setup[2], c0, -1, n, 0, n)
    a, b = _rows_between(n, setup[2], c0, 1, n - 2, r0, r1)
    if a == b:
        a = b = r1
    return r0, a, b, r1


@numba.njit(cache=True, nogil=True)
def _edge_line(r0, a, b, e):  # pragma: no cover - compiled
    """The ``e``-th edge line of a ray (:func:`ray_rows`): ``[r0, a)`` first, then ``[b, r1)``."""
    return r0 + e if r0 + e < a else b + e - (a - r0)


@numba.njit(cache=True, nogil=True)
def _interior_cross(setup, c0, i):  # pragma: no cover - compiled
    """``(j, up, ws)`` on an interior line: the nearest pixel ``j``, whether the ray's crossing
    lies towards the next pixel (``j + minor``, else ``j - minor``), and the weight shared with
    that neighbour, rounded to float32 as the cached matrix stores its weights.

    The ``line`` model gives the neighbour ``h clip((|o| - S) / (T - S), 0, 1)`` and the
    nearest pixel the rest of ``h`` (the other neighbour 0). ``c + 1/2 >= 1`` on an interior
    line, so truncation is the floor.
    """
    major, minor, delta, s, invw, length = setup[0], setup[1], setup[2], setup[3], setup[4], setup[5]
    c = c0 + i * delta
    m = int(c + 0.5)
    off = c - m
    ws = np.float32(length * min(max((abs(off) - s) * invw, 0.0), 1.0))
    return i * major + m * minor, off > 0.0, ws


@numba.njit(cache=True, nogil=True)
def _interior_row(setup, c0, i):  # pragma: no cover - compiled
    """``(j1, j2, w1, w2)`` on an interior line (:func:`_interior_cross`): the nearest pixel and
    its weight, the neighbour towards the crossing and the shared weight (0 when the ray stays
    in the pixel)."""
    j, up, ws = _interior_cross(setup, c0, i)
    minor = setup[1]
    w2 = np.float64(ws)
    return j, j + (2 * up - 1) * minor, setup[5] - w2, w2


@numba.njit(cache=True, nogil=True)
def _edge_row(n, setup, c0, i):  # pragma: no cover - compiled
    """:func:`_interior_row` on a line where a neighbour lies outside the image: the (at most
    two) pixels inside, with their weights (zero weights of inside neighbours included); a
    single pixel is returned twice, the second time with weight 0."""
    major, minor, delta, s, invw, length = setup[0], setup[1], setup[2], setup[3], setup[4], setup[5]
    c = c0 + i * delta
    m = _minor(c)
    off = c - m
    wl = np.float64(np.float32(length * min(max((-s - off) * invw, 0.0), 1.0)))
    wr = np.float64(np.float32(length * min(max((off - s) * invw, 0.0), 1.0)))
    base = i * major + m * minor
    j1 = -1
    w1 = 0.0
    j2 = -1
    w2 = 0.0
    if m >= 1:
        j1 = base - minor
        w1 = wl
    if 0 <= m < n:
        if j1 < 0:
            j1 = base
            w1 = length - wl - wr
        else:
            j2 = base
            w2 = length - wl - wr
    if m + 1 < n:
        if j1 < 0:
            j1 = base + minor
            w1 = wr
        else:
            j2 = base + minor
            w2 = wr
    if j2 < 0:
        j2 = j1
        w2 = 0.0
    return j1, j2, w1, w2


@numba.njit(cache=True, nogil=True, fastmath={"reassoc", "nsz", "contract"})
def ray_dot(x, n, setup, c0):  # pragma: no cover - compiled
    """``(<a, x>, sum(a), sum(a²))`` for the ray whose first crossing is ``c0`` (flat image ``x``).

    The interior lines (:func:`ray_rows`) run without branches, so they vectorise.
    """
    r0, a, b, r1 = ray_rows(n, setup, c0)
    dot = 0.0
    tot = 0.0
    sq = 0.0
    for i in range(a, b):
        j1, j2, w1, w2 = _interior_row(setup, c0, i)
        dot += w1 * x[j1] + w2 * x[j2]
        sq += w1 * w1 + w2 * w2
    tot += (b - a) * setup[5]
    for e in range((a - r0) + (r1 - b)):  # the edge lines: before and after the interior
        i = _edge_line(r0, a, b, e)
        j1, j2, w1, w2 = _edge_row(n, setup, c0, i)
        dot += w1 * x[j1] + w2 * x[j2]
        tot += w1 + w2
        sq += w1 * w1 + w2 * w2
    return dot, tot, sq


@numba.njit(cache=True, nogil=True)
def ray_add(x, n, setup, c0, coef, scale, scaled, nonneg):  # pragma: no cover - compiled
    """``x[j] += coef * a_j (* scale[j] if scaled)`` along one ray, clipped at 0 if ``nonneg``.

    The ray's entries with weight 0 (the other neighbour on a line the ray crosses inside one
    pixel) are updated too: with ``nonneg`` a negative value there is clipped, as it would be by
    any later update; a non-negative image is unchanged by them.
    """
    r0, a, b, r1 = ray_rows(n, setup, c0)
    for i in range(a, b):
        j1, j2, w1, w2 = _interior_row(setup, c0, i)
        for t in range(2):  # the pixel update written out once: a call per pixel is slow
            j = j1 if t == 0 else j2
            v = coef * (w1 if t == 0 else w2)
            if scaled:
                v *= scale[j]
            v += x[j]
            x[j] = v if (v > 0.0 or not nonneg) else 0.0
    _add_edge_lines(x, n, setup, c0, (r0, a, b, r1), coef, scale, scaled, nonneg)


@numba.njit(cache=True, nogil=True)
def _add_edge_lines(x, n, setup, c0, lines, coef, scale, scaled, nonneg):  # pragma: no cover - compiled
    """:func:`ray_add` on the edge lines of a ray (``lines``: its :func:`ray_rows`)."""
    r0, a, b, r1 = lines
    for e in range((a - r0) + (r1 - b)):
        j1, j2, w1, w2 = _edge_row(n, setup, c0, _edge_line(r0, a, b, e))
        for t in range(2):
            j = j1 if t == 0 else j2
            v = coef * (w1 if t == 0 else w2)
            if scaled:
                v *= scale[j]
            v += x[j]
            x[j] = v if (v > 0.0 or not nonneg) else 0.0


@numba.njit(cache=True, nogil=True)
def ray_set(x, n, setup, c0, coef):  # pragma: no cover - compiled
    """``x[j] = coef * a_j`` for the pixels of one ray (``coef = 0`` clears them).

    Written directly from the line model (left, nearest and right pixel of every line, bounds
    tested per pixel), independently of :func:`ray_rows`: the tests use it as the reference.
    """
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


#: Entries of a traced ray's buffer per image size ``N``: two pixels per major line.
RAY_ENTRIES_PER_N = 2


@numba.njit(cache=True, nogil=True)
def _trace_into(n, setup, c0, idx, wts):  # pragma: no cover - compiled
    """Store the pixels of one ray in ``idx[:cnt]`` and their weights in ``wts[:cnt]``.

    Two entries per major line the ray touches (:func:`_interior_row`, :func:`_edge_row`): the
    first entries of all lines, then the second ones (zero weights included; a pixel appears at
    most once with a non-zero weight). The interior lines are stored without branches.
    Returns ``cnt``.
    """
    r0, a, b, r1 = ray_rows(n, setup, c0)
    rows = r1 - r0
    # views indexed from 0 by the loop: indices the compiler knows to be >= 0 let it vectorise
    idx1, wts1, idx2, wts2 = idx[a - r0 :], wts[a - r0 :], idx[rows + a - r0 :], wts[rows + a - r0 :]
    for q in range(b - a):
        j1, j2, w1, w2 = _interior_row(setup, c0, a + q)
        idx1[q] = j1
        wts1[q] = w1
        idx2[q] = j2
        wts2[q] = w2
    for e in range((a - r0) + (r1 - b)):  # the edge lines: before and after the interior
        i = _edge_line(r0, a, b, e)
        j1, j2, w1, w2 = _edge_row(n, setup, c0, i)
        idx[i - r0] = j1
        wts[i - r0] = w1
        idx[rows + i - r0] = j2
        wts[rows + i - r0] = w2
    return 2 * rows


@numba.njit(cache=True, nogil=True, fastmath={"reassoc", "nsz", "contract"})
def ray_trace(x, n, setup, c0, idx, wts):  # pragma: no cover - compiled
    """Store the pixels of one ray: ``idx[:cnt]`` flat pixel indices, ``wts[:cnt]`` their weights.

    The ray of :func:`ray_dot` and :func:`ray_add` (two entries per major line: zero weights
    included, a pixel at most once with a non-zero weight); ``idx`` and ``wts`` need
    ``RAY_ENTRIES_PER_N * N`` entries. Returns ``(cnt, <a, x>, sum(a²))`` (flat image ``x``).
    A method that uses a ray several times traces it once into these buffers.
    """
    cnt = _trace_into(n, setup, c0, idx, wts)
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
#: with all threads (:func:`project_view`, :func:`backproject_view`, :func:`trace_view`,
#: :func:`backproject_traced`); smaller ones on one thread. Threads meet twice per view: on an
#: idle 2-core machine two threads made a Dremel sweep 1.5x faster at N = 255, 1.3x at N = 511
#: and 2.0x at N = 1024, but on a machine loaded by other jobs the waits made it several times
#: slower (``benchmarks/README.md``). So views of 1024-column scans and larger (N L >= 2^20) use
#: them, where the gain is largest; the local Dask workers share the CPUs out
#: (:func:`nanoct.core.fanout.worker_threads`).
PARALLEL_MIN_WORK = 1 << 20


def use_threads(geometry: Geometry) -> bool:
    """Whether one view's rays are split over threads: ``N * L >= PARALLEL_MIN_WORK``."""
    return geometry.n * geometry.n_det >= PARALLEL_MIN_WORK


# ------------------------------------------------------------------ views traced once into a buffer
#: Largest per-view buffer of traced rays (bytes): ``8 N L`` (per ray and interior line an
#: int32 pixel code and a float32 shared weight). Views whose buffer would be larger are
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
        ``(code, shared, rows)`` for :func:`trace_view` and :func:`backproject_traced`: per ray
        ``l`` and interior line (:func:`ray_rows`), ``code[l, i - a] = 2 j + up`` (the nearest
        pixel and the side of its neighbour, (L, N) int32) and ``shared[l, i - a]`` (the
        neighbour's weight, (L, N) float32); ``rows[l] = (r0, a, b, r1)``, (L, 4) int32. The
        edge lines are traced again in the back projection. Only the interior is stored, in 8
        bytes per line, so that a view of the paper-parallel preset (0.7 MB) stays in a core's
        cache.
    """
    n, n_det = geometry.n, geometry.n_det
    if 8 * n * n_det > VIEW_BUFFER_BYTES or n * n >= 2**30:
        return None
    return np.empty((n_det, n), np.int32), np.empty((n_det, n), np.float32), np.empty((n_det, 4), np.int32)


@numba.njit(cache=True, nogil=True, fastmath={"reassoc", "nsz", "contract"})
def _trace_rays(par, n, x, p, rowsum, code, shared, rows, lo, hi):  # pragma: no cover - compiled
    """Rays ``lo:hi`` of a view traced into rows of the buffer (:func:`view_buffer`), with their
    projections ``p`` and weight sums ``rowsum``."""
    setup = ray_setup(par, n)
    minor, length = setup[1], setup[5]
    for l in range(lo, hi):
        c0 = setup[6] + l * setup[7]
        r0, a, b, r1 = ray_rows(n, setup, c0)
        rows[l, 0], rows[l, 1], rows[l, 2], rows[l, 3] = r0, a, b, r1
        cl = code[l]
        sl = shared[l]
        for i in range(a, b):
            j, up, ws = _interior_cross(setup, c0, i)
            cl[i - a] = 2 * j + up
            sl[i - a] = ws
        dot = 0.0
        for r in range(b - a):  # a second pass over the stored line (in cache) vectorises better
            cd = cl[r]
            j = cd >> 1
            w2 = np.float64(sl[r])
            dot += (length - w2) * x[j] + w2 * x[j + (2 * (cd & 1) - 1) * minor]
        tot = (b - a) * length
        for e in range((a - r0) + (r1 - b)):
            i = _edge_line(r0, a, b, e)
            j1, j2, w1, w2 = _edge_row(n, setup, c0, i)
            dot += w1 * x[j1] + w2 * x[j2]
            tot += w1 + w2
        p[l] = dot
        rowsum[l] = tot


@numba.njit(cache=True, nogil=True)
def _backproject_traced_rays(par, n, coef, x, scale, scaled, nonneg, code, shared, rows, lo, hi):  # pragma: no cover
    setup = ray_setup(par, n)
    minor, length = setup[1], setup[5]
    for l in range(lo, hi):
        cl = coef[l]
        if cl == 0.0:
            continue
        r0, a, b, r1 = rows[l, 0], rows[l, 1], rows[l, 2], rows[l, 3]
        for r in range(b - a):  # the interior, from the buffer
            cd = code[l, r]
            w2 = np.float64(shared[l, r])
            j = cd >> 1
            side = (2 * (cd & 1) - 1) * minor  # arithmetic, not a branch: the side is random
            for t in range(2):  # the pixel update written out once: a call per pixel is slow
                v = cl * (length - w2) if t == 0 else cl * w2
                if scaled:
                    v *= scale[j]
                v += x[j]
                x[j] = v if (v > 0.0 or not nonneg) else 0.0
                j += side
        # the edge lines, traced again
        _add_edge_lines(x, n, setup, setup[6] + l * setup[7], (r0, a, b, r1), cl, scale, scaled, nonneg)


@numba.njit(cache=True, parallel=True)
def trace_view(par, n, n_det, x, p, rowsum, code, shared, rows, block):  # pragma: no cover - compiled
    """Trace the rays of one view into ``(code, shared, rows)`` (:func:`view_buffer`), blocks in parallel.

    Also ``p[l] = <a_l, x>`` and ``rowsum[l] = sum(a_l)`` (the rays of :func:`ray_dot`).
    """
    for b in numba.prange((n_det + block - 1) // block):
        _trace_rays(par, n, x, p, rowsum, code, shared, rows, b * block, min((b + 1) * block, n_det))


@numba.njit(cache=True, nogil=True)
def trace_view_serial(par, n, n_det, x, p, rowsum, code, shared, rows, block):  # pragma: no cover - compiled
    """:func:`trace_view` on one thread."""
    _trace_rays(par, n, x, p, rowsum, code, shared, rows, 0, n_det)


@numba.njit(cache=True, parallel=True)
def backproject_traced(
    par, n, n_det, coef, x, scale, scaled, nonneg, block, code, shared, rows
):  # pragma: no cover - compiled
    """:func:`backproject_view` with the view's interior lines read from the buffer of :func:`trace_view`.

    The same pixels, increments and block order as :func:`backproject_view`, so the same result.
    ``par`` must be the view last traced into the buffer: its edge lines are traced again from
    ``par`` and its interior is decoded with ``par``'s orientation (no bounds are checked).
    """
    n_blocks = (n_det + block - 1) // block
    for phase in range(2):
        for b in numba.prange((n_blocks + 1 - phase) // 2):
            start = (2 * b + phase) * block
            _backproject_traced_rays(
                par, n, coef, x, scale, scaled, nonneg, code, shared, rows, start, min(start + block, n_det)
            )


@numba.njit(cache=True, nogil=True)
def backproject_traced_serial(
    par, n, n_det, coef, x, scale, scaled, nonneg, block, code, shared, rows
):  # pragma: no cover - compiled
    """:func:`backproject_traced` on one thread, blocks in the same order (the same result)."""
    n_blocks = (n_det + block - 1) // block
    for phase in range(2):
        for b in range((n_blocks + 1 - phase) // 2):
            start = (2 * b + phase) * block
            _backproject_traced_rays(
                par, n, coef, x, scale, scaled, nonneg, code, shared, rows, start, min(start + block, n_det)
            )
