"""The row-action core shared by Kaczmarz, Dremel and RESESOP-Kaczmarz.

The unperturbed ray transform is the float32 CSR matrix of :func:`nanoct.core.operators.system_matrix`
(row ``k*L + l`` is ray ``(k, l)``); a *sweep* visits every view once in a chosen *view order*
and, within a view, the rays in detector order ``l = 0 .. L-1``. This module holds what the
three methods share: problem setup (:func:`prepare_problem`), view orders, the row product
:func:`row_dot`, residuals, the projection onto ``x >= 0``, one per-matrix cache of derived
arrays, and the checks of the common parameters (:func:`check_row_action`).

View orders (:func:`view_order`)
--------------------------------
``"sequential"``
    ``0, 1, ..., K-1`` every sweep, as in the paper's pseudo-code. Consecutive views are
    nearly parallel, so their hyperplanes are nearly parallel and a sweep makes little
    progress (see ``docs/choices.md``).
``"random"``
    A fresh random permutation of the views every sweep, drawn from ``seed``.
``"golden"``
    A fixed low-discrepancy order: position ``i`` visits view ``~ K * frac(i * g)`` with
    ``g = (sqrt(5) - 1) / 2``, so consecutive views are far apart in angle (deterministic).

Projectors
----------
``projector="matrix"`` uses the cached CSR matrix; ``"matrixfree"`` builds the rows of one view
at a time (:class:`nanoct.core.matrixfree.ParallelRays`, parallel beam only) and keeps only
that view's block in memory; ``"auto"`` (default) takes the matrix while its estimated size
(:func:`nanoct.core.matrixfree.matrix_bytes`) is at most :data:`AUTO_MATRIX_BYTES` or the beam
is fan-shaped, and the matrix-free rows above. Both give the same iterates up to float32
rounding of the weights and of the summation order within a row (``docs/reconstruction.md``).

Non-negativity
--------------
Densities are non-negative, so every iterative method can project onto ``{x >= 0}``.
Kaczmarz and RESESOP apply the projection after each sweep (an alternating projection
between "one sweep" and the closed convex orthant); Dremel applies it within each view step.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numba
import numpy as np
import scipy.sparse as sp

from ..core.geometry import Geometry
from ..core.matrixfree import ParallelRays, matrix_bytes
from ..core.operators import RayTransform, system_matrix
from ..core.validation import check_array, check_bool, check_choice, check_float, check_int
from .params import MethodParams, resolve_geometry

__all__ = [
    "AUTO_MATRIX_BYTES",
    "AUTO_RELAXATION",
    "ORDERS",
    "PROJECTORS",
    "RESIDUALS",
    "auto_relaxation",
    "check_projector",
    "check_row_action",
    "clip_nonneg",
    "matrix_cache",
    "prepare_problem",
    "residual_norm",
    "resolve_projector",
    "resolve_relaxation",
    "row_dot",
    "row_dot_f64",
    "row_norms_squared",
    "unsigned_indices",
    "view_order",
]

#: Names of the view orders understood by :func:`view_order`.
ORDERS = ("sequential", "random", "golden")

#: How a method records its residual history: ``"exact"`` ``||A x - y||`` after each sweep
#: (one more pass over the matrix) or ``"running"`` (free: from the residuals met during it).
RESIDUALS = ("exact", "running")

#: Projectors of the row-action methods (see the module docstring).
PROJECTORS = ("auto", "matrix", "matrixfree")

#: ``projector="auto"`` switches to the matrix-free rows when the cached matrix would be larger.
AUTO_MATRIX_BYTES = 1_000_000_000

#: The default relaxation of Kaczmarz and Dremel is ``min(1, AUTO_RELAXATION / K)`` for K views
#: (the best relaxation on motion-perturbed data scales like ``1 / K``; see ``docs/choices.md``).
AUTO_RELAXATION = 8.0

_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


def auto_relaxation(n_views: int) -> float:
    """``min(1, AUTO_RELAXATION / n_views)``: the default relaxation for ``n_views`` views."""
    return min(1.0, AUTO_RELAXATION / n_views)


def view_order(n_views: int, order: str, rng: np.random.Generator | None = None) -> np.ndarray:
    """The order in which one sweep visits the views.

    Parameters
    ----------
    n_views : int
        Number of views K.
    order : {"sequential", "random", "golden"}
        See the module docstring.
    rng : numpy.random.Generator, optional
        Source of the permutation for ``"random"`` (required there).

    Returns
    -------
    ndarray of shape (K,), int64
        A permutation of ``0 .. K-1``.
    """
    order = check_choice(order, "order", ORDERS)
    if order == "sequential":
        return np.arange(n_views, dtype=np.int64)
    if order == "random":
        if rng is None:
            raise ValueError("order='random' needs a random generator")
        return rng.permutation(n_views).astype(np.int64)
    keys = np.mod(np.arange(n_views) * _GOLDEN, 1.0)
    # rank of key i = view visited at position i: a permutation close to K * frac(i g)
    return np.argsort(np.argsort(keys, kind="stable"), kind="stable").astype(np.int64)


def check_row_action(p: MethodParams) -> None:
    """Check and normalise, in place, the parameters every row-action method declares.

    ``n_iter``, ``order``, ``nonneg``, ``seed``, ``residual`` and, where the method has one,
    ``relaxation`` (``None`` stays None until :func:`resolve_relaxation`).

    Raises
    ------
    ValueError
        Naming the first bad parameter and its accepted values.
    """
    p._set("n_iter", check_int(p.n_iter, "n_iter", 1))
    if getattr(p, "relaxation", None) is not None:
        p._set("relaxation", _check_relaxation(p.relaxation))
    p._set("order", check_choice(p.order, "order", ORDERS))
    p._set("nonneg", check_bool(p.nonneg, "nonneg"))
    p._set("seed", check_int(p.seed, "seed", 0))
    p._set("residual", check_choice(p.residual, "residual", RESIDUALS))
    p._set("projector", check_choice(p.projector, "projector", PROJECTORS))


def check_projector(values: dict[str, Any], geometry: Geometry) -> dict[str, Any]:
    """``values`` unchanged; raises ``ValueError`` if its ``projector`` cannot serve ``geometry``."""
    resolve_projector(values["projector"], geometry)
    return values


def resolve_projector(projector: str, geometry: Geometry, matrix: Any = None) -> str:
    """``"matrix"`` or ``"matrixfree"`` for a method's ``projector`` parameter.

    A given ``matrix`` is always used; ``"auto"`` picks the matrix-free rows for a parallel
    beam whose matrix would exceed :data:`AUTO_MATRIX_BYTES`.

    Raises
    ------
    ValueError
        For ``"matrixfree"`` with a fan-beam geometry or together with a ``matrix``.
    """
    if projector == "matrixfree":
        if matrix is not None:
            raise ValueError("projector='matrixfree' does not use a matrix; pass matrix=None or projector='matrix'")
        if geometry.kind != "parallel":
            raise ValueError("projector='matrixfree' covers parallel beam only; use 'matrix' or 'auto' for fan beam")
        return "matrixfree"
    if projector == "matrix" or matrix is not None or geometry.kind != "parallel":
        return "matrix"
    return "matrixfree" if matrix_bytes(geometry) > AUTO_MATRIX_BYTES else "matrix"


def _check_relaxation(value: Any) -> float:
    # Kaczmarz / SART converge for 0 < omega < 2
    return check_float(value, "relaxation", low=0.0, high=2.0, low_open=True, high_open=True)


def resolve_relaxation(values: dict[str, Any], geometry: Geometry) -> dict[str, Any]:
    """``values`` with ``relaxation=None`` replaced by :func:`auto_relaxation` of the geometry's views
    (and ``projector`` checked against the geometry, :func:`check_projector`)."""
    check_projector(values, geometry)
    if values["relaxation"] is None:
        values["relaxation"] = _check_relaxation(auto_relaxation(geometry.n_angles))
    return values


def _check_matrix(matrix: Any, shape: tuple[int, int]) -> sp.csr_matrix:
    if not sp.issparse(matrix) or matrix.format != "csr":
        raise ValueError("matrix must be a scipy CSR matrix (see nanoct.core.operators.system_matrix)")
    if matrix.shape != shape:
        raise ValueError(f"matrix has shape {matrix.shape}, expected {shape} for this geometry")
    if matrix.dtype != np.float32:
        matrix = matrix.astype(np.float32)
    if not matrix.has_sorted_indices:
        matrix = matrix.sorted_indices()
    return matrix


def prepare_problem(
    op: Geometry | RayTransform,
    sino: Any,
    matrix: sp.csr_matrix | None,
    x0: Any,
    projector: str = "matrix",
) -> tuple[Geometry, np.ndarray, sp.csr_matrix | ParallelRays, np.ndarray]:
    """Validate inputs; return geometry, flat float32 sinogram, the rays and float32 start image.

    The rays are the CSR matrix, or :class:`~nanoct.core.matrixfree.ParallelRays` where
    :func:`resolve_projector` chooses the matrix-free rows.
    """
    geometry = resolve_geometry(op)
    y = check_array(sino, "sinogram", shape=geometry.sino_shape).ravel()
    shape = (geometry.n_angles * geometry.n_det, geometry.n * geometry.n)
    if resolve_projector(projector, geometry, matrix) == "matrixfree":
        matrix = ParallelRays(geometry)
    elif matrix is None:
        matrix = system_matrix(geometry)
    else:
        matrix = _check_matrix(matrix, shape)
    if x0 is None:
        x = np.zeros(shape[1], dtype=np.float32)
    else:
        x = check_array(x0, "x0", shape=geometry.image_shape).ravel().copy()
    return geometry, y, matrix, x


# ------------------------------------------------------------------ one cache per matrix
_CACHE: dict[int, tuple[sp.csr_matrix, dict[Any, Any]]] = {}
_CACHE_SIZE = 4


def matrix_cache(matrix: sp.csr_matrix, key: Any, compute: Callable[[sp.csr_matrix], Any]) -> Any:
    """``compute(matrix)``, computed once per matrix object and ``key`` (the last few matrices kept).

    Entries hold a reference to the matrix, so an ``id`` is never reused while its entry lives.
    """
    entry = _CACHE.get(id(matrix))
    if entry is None or entry[0] is not matrix:
        if len(_CACHE) >= _CACHE_SIZE:
            _CACHE.pop(next(iter(_CACHE)))
        entry = (matrix, {})
        _CACHE[id(matrix)] = entry
    if key not in entry[1]:
        entry[1][key] = compute(matrix)
    return entry[1][key]


@numba.njit(cache=True, nogil=True)
def _row_norms2(indptr, data):  # pragma: no cover - compiled
    m = indptr.shape[0] - 1
    out = np.zeros(m, dtype=np.float64)
    for r in range(m):
        s = 0.0
        for p in range(indptr[r], indptr[r + 1]):
            d = data[p]
            s += d * d
        out[r] = s
    return out


def row_norms_squared(matrix: sp.csr_matrix) -> np.ndarray:
    """Squared Euclidean norms of the rows of a CSR matrix (float64, cached per matrix)."""
    return matrix_cache(matrix, "row_norms2", lambda m: _row_norms2(m.indptr, m.data))


def unsigned_indices(matrix: sp.csr_matrix) -> np.ndarray:
    """The column indices of a CSR matrix viewed as unsigned integers (no copy).

    CSR column indices are non-negative, so the view is exact; numba then omits the
    wrap-around handling of negative indices in the kernels' gathers and scatters.
    """
    ind = matrix.indices
    return ind.view(np.uint32 if ind.dtype.itemsize == 4 else np.uint64)


# ------------------------------------------------------------------ kernels
#: LLVM flags of :func:`row_dot`: reassociation lets the reduction vectorise (AVX2/AVX-512
#: gathers); no ``nnan``/``ninf`` assumptions.
_DOT_FASTMATH = {"reassoc", "nsz", "contract"}


def _make_row_dot(acc: type, fastmath: Any) -> Callable[..., float]:
    """Compile the row product with accumulator type ``acc`` (one source, one kernel per dtype)."""

    def row_dot(indices, data, x, p0, p1):  # pragma: no cover - compiled
        idx = indices[p0:p1]
        a = data[p0:p1]
        s = acc(0.0)
        for q in range(p1 - p0):
            s += a[q] * x[idx[q]]
        return np.float64(s)

    return numba.njit(cache=True, nogil=True, fastmath=fastmath)(row_dot)


#: ``sum(data[p] * x[indices[p]] for p in range(p0, p1))`` with float32 products and partial
#: sums; the summation order is left to the compiler (vectorised gathers, faster than a
#: sequential float64 sum: ``benchmarks/README.md``); the relative rounding error is a few float32 ulps, the order of
#: storing ``x`` in float32. Pass ``indices`` unsigned (:func:`unsigned_indices`) to spare the
#: negative-index checks. Used by Kaczmarz, Dremel and :func:`residual_norm`.
row_dot = _make_row_dot(np.float32, _DOT_FASTMATH)

#: The same row product with float32 products summed in float64 in sequential order (RESESOP,
#: whose stripe tests compare residuals with small widths).
row_dot_f64 = _make_row_dot(np.float64, False)


@numba.njit(cache=True, nogil=True)
def residual_norm(indptr, indices, data, y, x):  # pragma: no cover - compiled
    """``||A x - y||_2`` for a CSR matrix given by its arrays (numba).

    Row products ``<a, x>`` as in :func:`row_dot` (float32 accumulation), the sum of squares
    in float64.
    """
    m = indptr.shape[0] - 1
    tot = 0.0
    for r in range(m):
        d = row_dot(indices, data, x, indptr[r], indptr[r + 1]) - y[r]
        tot += d * d
    return math.sqrt(tot)


@numba.njit(cache=True, nogil=True)
def clip_nonneg(x):  # pragma: no cover - compiled
    """In-place projection onto ``{x >= 0}``."""
    for j in range(x.shape[0]):
        if x[j] < 0.0:
            x[j] = 0.0
