"""Per-view motion in 3-D by projection matching: reconstruct, reproject, register, coarse to fine.

Model of a measured parallel-beam projection (detector column ``x``, row ``z``, pixels)::

    m_k(z, x) = Q_k(z + v_k, x + d_k)

with ``Q_k`` the projection of the static object about the rotation axis (offset ``c`` from the
detector centre), ``d_k`` the horizontal shift (the sign of :func:`nanoct.dremel`'s motion and of
:func:`nanoct.recon.stack.corrected_fbp`) and ``v_k`` the vertical shift of view ``k``. An
in-plane tilt ``theta`` of the rotation axis on the detector rotates every projection about the
detector centre by ``theta`` (degrees, counter-clockwise in the (column, row) image).

:func:`match_projections` alternates, at each detector binning of its schedule (coarse to fine):

1. every projection moved back vertically by ``v_k`` (and rotated by ``-theta``);
2. every slice of the slab reconstructed by motion-corrected FBP with ``d_k``, on a grid wider
   than the detector, from sinograms extended smoothly beyond their edges (an object wider than
   the field of view and a non-zero open beam then leave no edge artefact);
3. the reconstruction reprojected (no motion): the static projections ``Q_k``;
4. each measured projection registered to its reprojection by sub-pixel 2-D cross-correlation of
   high-pass filtered, tapered images (:func:`~nanoct.motion.registration.register_shifts`), which gives ``(v_k, d_k)``
   directly.

No centroid is used, so the estimate holds for objects wider than the field of view and for a
non-zero open beam. The data cannot fix a translation of the object: the vertical shifts are
returned with zero mean and the horizontal ones without the term ``a cos(phi) + b sin(phi)``;
their constant stays (it is the correction of the given axis).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np
import scipy.ndimage as ndi

from ..core.errors import NanoctError
from ..core.geometry import Geometry, remove_translation
from ..core.validation import check_int
from ..recon.fbp import ramp_filter
from ..recon.stack import corrected_fbp, reproject
from .registration import register_shifts

__all__ = ["MatchedMotion", "apply_vertical", "extend_edges", "match_projections", "register_views", "views_and_angles"]


@dataclass
class MatchedMotion:
    """Motion found by :func:`match_projections`.

    Attributes
    ----------
    horizontal, vertical : ndarray of shape (K,)
        ``d_k`` and ``v_k`` in full-size detector pixels.
    center_offset : float
        The axis offset the shifts go with (detector pixels).
    tilt_deg : float
        In-plane tilt of the rotation axis on the detector (degrees; 0 when not estimated).
    steps : list of (int, float, float)
        Per round: binning, RMS change of ``d`` and of ``v`` (full-size pixels).
    """

    horizontal: np.ndarray
    vertical: np.ndarray
    center_offset: float
    tilt_deg: float = 0.0
    steps: list[tuple[int, float, float]] = field(default_factory=list)


def views_and_angles(projections: Any, angles: Any, dtype: Any = np.float32) -> tuple[np.ndarray, np.ndarray]:
    """``(K, R, L)`` projections as ``dtype`` and their ``K`` angles as float64, checked against each other.

    Raises
    ------
    NanoctError
        The projections are not 3-D or their number differs from the angles'.
    """
    proj = np.asarray(projections, dtype=dtype)
    phi = np.asarray(angles, dtype=np.float64)
    if proj.ndim != 3 or phi.shape != (proj.shape[0],):
        raise NanoctError(f"projections of shape {proj.shape} do not match {phi.size} angles (views, rows, columns)")
    return proj, phi


def extend_edges(sinograms: np.ndarray, pad: int) -> np.ndarray:
    """Sinograms ``(..., K, L)`` extended by ``pad`` columns each side: edge value times a cosine taper to 0."""
    if pad <= 0:
        return sinograms
    ramp = 0.5 + 0.5 * np.cos(np.pi * (np.arange(1, pad + 1) / (pad + 1)))  # 1 -> 0 away from the edge
    left = sinograms[..., :1] * ramp[::-1]
    right = sinograms[..., -1:] * ramp
    return np.concatenate([left, sinograms, right], axis=-1)


def apply_vertical(projections: np.ndarray, vertical: np.ndarray, tilt_deg: float = 0.0) -> np.ndarray:
    """Projections ``(K, R, L)`` moved back by their vertical shifts (and rotated by ``-tilt_deg``).

    ``out_k(z, x) = m_k(z - v_k, x)``: undoes ``m_k(z, x) = Q_k(z + v_k, x)``; rows from outside
    the detector repeat the nearest row.
    """
    out = np.empty_like(projections, dtype=np.float32)
    for k, image in enumerate(projections):
        moved = ndi.shift(image, (vertical[k], 0.0), order=3, mode="nearest")
        if tilt_deg:
            moved = ndi.rotate(moved, -tilt_deg, reshape=False, order=3, mode="nearest")
        out[k] = moved
    return out


def register_views(
    measured: np.ndarray, model: np.ndarray, factor: int, margin: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """``(v_k, d_k)`` per view with ``measured_k(z, x) = model_k(z + v_k, x + d_k)`` (:func:`register_shifts`).

    Both images are high-pass filtered before they are tapered: the vertical shift is registered
    on the derivative along the rows, the horizontal one on the images less their Gaussian blur
    of 8 full-size pixels (edges repeated), low-passed at 4 full-size pixels (a view's own
    direction holds no information in a reconstruction without it, Fourier slice theorem, so the
    fine detail of its model along the detector is interpolated from its neighbours' and not to
    be trusted). Filtering first matters where the object is wider than the field of view: a
    taper applied to the raw views turns their high edges into a step at the same place in both
    images, which pins the correlation peak at zero. The outer 15 % of the columns, where the
    reconstruction from truncated views is least right, are tapered away. Views of a single row
    (four slices binned four times) give a vertical shift of zero.
    """
    margin = (margin[0], max(margin[1], int(0.15 * measured.shape[2])))
    if measured.shape[1] < 2:  # one row (a few slices binned): no vertical shift to see
        vertical = np.zeros(measured.shape[0])
    else:
        rows_model, rows_measured = np.gradient(model, axis=1), np.gradient(measured, axis=1)
        vertical = register_shifts(rows_model, rows_measured, sigma=0.0, margin=margin)[:, 0]
    sigma = max(8.0 / factor, 2.0)
    high_model = model - ndi.gaussian_filter(model, (0, sigma, sigma), mode="nearest")
    high_measured = measured - ndi.gaussian_filter(measured, (0, sigma, sigma), mode="nearest")
    horizontal = register_shifts(high_model, high_measured, sigma=0.0, smooth=4.0 / factor, margin=margin)
    return vertical, horizontal[:, 1]


def _bin2(projections: np.ndarray, factor: int) -> np.ndarray:
    """Average ``factor x factor`` blocks of ``(K, R, L)`` projections (remainders dropped)."""
    if factor == 1:
        return projections
    k, r, l = projections.shape
    r2, l2 = r // factor, l // factor
    cut = projections[:, : r2 * factor, : l2 * factor]
    return cut.reshape(k, r2, factor, l2, factor).mean(axis=(2, 4))


def _binned_geometry(angles: np.ndarray, n_det: int, center: float, factor: int, pad: int) -> Geometry:
    """Geometry of a detector binned ``factor`` times and extended by ``pad`` columns each side."""
    axis = (n_det - 1) / 2 + center
    binned = n_det // factor
    offset = (axis + 0.5) / factor - 0.5 - (binned - 1) / 2
    width = binned + 2 * pad
    return Geometry.from_angles(angles, width, width, center_offset=offset)


@numba.njit(fastmath=True, cache=True, inline="always")
def _bp_value(f, row, col, c, s, half, centre, shift, n_det, spacing):  # pragma: no cover - jit
    """One view's filtered projection back projected to pixel (row, col), as :func:`nanoct.recon.fbp.fbp` does."""
    pos = ((col - half) * c + (half - row) * s) / spacing + centre - shift + 1.0
    pos = min(max(pos, 0.0), n_det + 1.0)
    lo = int(pos)
    frac = pos - lo
    return (1.0 - frac) * f[lo] + frac * f[lo + 1]


@numba.njit(parallel=True, fastmath=True, cache=True)
def _own_views(filtered, cos, sin, shifts, n, centre, spacing):  # pragma: no cover - jit
    """Each filtered view back projected alone and reprojected along its own direction.

    The back projection is that of :func:`nanoct.recon.fbp.fbp` (``filtered`` padded as its
    kernel expects, weights applied), the projection that of :func:`nanoct.recon.stack.reproject`
    without shifts: the view's own term in its reprojected reconstruction.
    """
    n_views = cos.shape[0]
    n_det = filtered.shape[1] - 3
    half = (n - 1) / 2.0
    out = np.zeros((n_views, n_det))
    for k in numba.prange(n_views):
        c, s = cos[k], sin[k]
        f = filtered[k]
        u0 = -centre * spacing
        steep = abs(c) >= abs(s)
        lead, other = (c, s) if steep else (s, c)
        for line in range(n):
            t = (half - line) if steep else (line - half)
            r0 = (u0 - t * other) / lead
            first, step = (r0 + half, spacing / lead) if steep else (half - r0, -spacing / lead)
            for l in range(n_det):
                pos = first + l * step
                lo = int(np.floor(pos))
                if 0 <= lo < n - 1:
                    frac = pos - lo
                    if steep:
                        a = _bp_value(f, line, lo, c, s, half, centre, shifts[k], n_det, spacing)
                        b = _bp_value(f, line, lo + 1, c, s, half, centre, shifts[k], n_det, spacing)
                    else:
                        a = _bp_value(f, lo, line, c, s, half, centre, shifts[k], n_det, spacing)
                        b = _bp_value(f, lo + 1, line, c, s, half, centre, shifts[k], n_det, spacing)
                    out[k, l] += a + frac * (b - a)
        for l in range(n_det):
            out[k, l] /= abs(lead)
    return out


def _static_projections(
    proj: np.ndarray, geometry: Geometry, horizontal: np.ndarray, pad: int, filter: str
) -> np.ndarray:
    """Each view's static projection, reprojected from a reconstruction without that view.

    Every slice is reconstructed from all views (motion-corrected by ``horizontal``) and
    reprojected; the view's own term (:func:`_own_views`: its filtered projection back projected
    alone and reprojected along its own direction) is then subtracted. Left in, it pulls the
    model towards the view as corrected so far, and the matching would recover only a fraction
    of the motion; leaving out whole groups of views instead undersamples the angles and rings.
    """
    sinos = extend_edges(proj.transpose(1, 0, 2), pad)  # (R, K, L + 2 pad)
    out = np.empty_like(proj, dtype=np.float32)
    n_det = proj.shape[2]
    cos, sin = np.cos(geometry.angles), np.sin(geometry.angles)
    centre = (geometry.n_det - 1) / 2.0 + geometry.center_offset
    shifts = np.ascontiguousarray(horizontal, dtype=np.float64)
    for r, sino in enumerate(sinos):
        image = corrected_fbp(geometry, sino, horizontal, filter=filter)
        filtered = np.zeros((sino.shape[0], sino.shape[1] + 3))
        filtered[:, 1:-2] = ramp_filter(sino.astype(np.float64), geometry.det_spacing, filter)
        filtered *= geometry.angle_weights[:, None]
        own = _own_views(filtered, cos, sin, shifts, geometry.n, centre, geometry.det_spacing)
        out[:, r, :] = (reproject(geometry, image) - own)[:, pad : pad + n_det]
    return out


def match_projections(
    projections: Any,
    angles: Any,
    center_offset: float,
    *,
    schedule: tuple[int, ...] = (4, 2, 1),
    rounds: int = 2,
    horizontal: Any = None,
    vertical: Any = None,
    tilt_deg: float = 0.0,
    max_rows: int = 256,
    relaxation: float = 1.0,
    filter: str = "hann",
    progress: Callable[[str], Any] | None = None,
) -> MatchedMotion:
    """Horizontal and vertical shift per view by projection matching (see the module docstring).

    Parameters
    ----------
    projections : array_like of shape (K, R, L)
        Line integrals, one 2-D projection per view (rows = slices).
    angles : array_like of shape (K,)
        View angles in radians.
    center_offset : float
        Rotation axis minus the detector centre (detector pixels), held fixed.
    schedule : tuple of int
        Detector binning of each level (rows and columns alike), coarse to fine; ends with 1
        for full-size precision.
    rounds : int
        Rounds of reconstruct / reproject / register per level.
    horizontal, vertical : array_like of shape (K,), optional
        Starting shifts (default zero).
    tilt_deg : float
        In-plane axis tilt to undo before matching (degrees).
    max_rows : int
        At most this many rows (the central block) are reconstructed per level; more rows
        average the registration over more structure.
    relaxation : float
        Each round moves the shifts by this multiple of the measured correction.
    filter : {"ram-lak", "hann"}
        FBP filter of the reconstructions that are reprojected (Hann damps the noise the
        registration would otherwise follow).
    progress : callable, optional
        Called with ``"match"`` after each round.

    Returns
    -------
    MatchedMotion
    """
    proj, phi = views_and_angles(projections, angles)
    check_int(rounds, "rounds", 1)
    n_views, n_rows, n_det = proj.shape
    d = np.zeros(n_views) if horizontal is None else np.asarray(horizontal, dtype=np.float64).copy()
    v = np.zeros(n_views) if vertical is None else np.asarray(vertical, dtype=np.float64).copy()
    tick = progress or (lambda stage: None)
    steps: list[tuple[int, float, float]] = []
    for factor in schedule:
        factor = check_int(factor, "binning", 1)
        pad = max(n_det // factor // 4, 4)
        geometry = _binned_geometry(phi, n_det, center_offset, factor, pad)
        for _ in range(rounds):
            straight = _bin2(apply_vertical(proj, v, tilt_deg), factor)
            moved = _bin2(proj, factor)
            rows = _pick_rows(straight.shape[1], max_rows)
            model = _static_projections(straight[:, rows], geometry, d / factor, pad, filter)
            margin = (max(2, int(np.ceil(np.max(np.abs(v), initial=0.0) / factor)) + 2), 2)
            new_v, new_d = register_views(moved[:, rows], model, factor, margin)
            new_v, new_d = new_v * factor, new_d * factor
            new_v -= new_v.mean()
            new_d = remove_translation(new_d, phi)
            steps.append((factor, float(np.sqrt(np.mean((new_d - d) ** 2))), float(np.sqrt(np.mean((new_v - v) ** 2)))))
            d, v = d + relaxation * (new_d - d), v + relaxation * (new_v - v)
            tick("match")
    return MatchedMotion(d, v, float(center_offset), float(tilt_deg), steps)


def _pick_rows(n_rows: int, max_rows: int) -> np.ndarray:
    """All rows when they fit in ``max_rows``, else the central contiguous block of ``max_rows`` rows."""
    first = max((n_rows - max_rows) // 2, 0)
    return np.arange(first, min(first + max_rows, n_rows))
