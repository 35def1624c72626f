"""What a training set matched to a measured scan takes from the scan: binning, noise, motion, axis.

Stated estimators (used by :mod:`nanoct.sim.matched`):

* **Binning** (:func:`bin_sinograms`): ``b`` neighbouring detector columns are averaged, and
  ``b`` neighbouring slices (detector rows) where the store has at least ``b`` of them, as
  ``nanoct import --binning`` does; the axis offset moves to the binned detector
  (:func:`binned_offset`).
* **Noise** (:func:`air_noise`): in every view of every slice, the air bands are the
  :func:`~nanoct.recon.measured.edge_width` outermost detector pixels on each side (the pixels
  whose median :func:`~nanoct.recon.measured.air_level` takes as the open-beam level). Within
  each band the smooth level (open beam, beam decay, flat-field mismatch) is removed by second
  differences along the detector, ``d = y[l+1] - 2 y[l] + y[l-1]``; the noise standard deviation
  per ray is ``1.4826 MAD(d) / sqrt(6)`` over all bands, views and slices (exact for white
  Gaussian noise on a locally linear level). Measured on the binned sinograms, so it is the noise
  of the data the network will see.
* **Open beam** (:func:`open_beam_level`): per view, the median of the air bands (the level the
  row-action methods remove from a measured view), median over slices: a flat/dark-corrected scan
  rarely reads zero in air, and its level drifts with the beam.
* **Motion** (:func:`motion_stats`): the stack's estimated per-view shift along the detector
  (``nanoct stack``, in acquisition order), mean removed, is split into a smooth part (a Gaussian
  filter over the views, ``MOTION_SMOOTH_VIEWS`` views std) and jitter (the rest). The smooth
  amplitude is the largest ``|smooth part|``; the jitter std is the rest's std divided by the
  factor the filter leaves of white noise, ``sqrt(1 - 2 w_0 + sum w^2)`` (``w`` its weights).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import ndimage

from ..core.errors import NanoctError
from ..core.geometry import Geometry
from ..recon.measured import air_level, edge_width

__all__ = [
    "MOTION_SMOOTH_VIEWS",
    "air_noise",
    "bin_sinograms",
    "binned_geometry",
    "binned_offset",
    "motion_stats",
    "open_beam_level",
]

#: Standard deviation, in views, of the Gaussian filter that gives the smooth part of a motion.
MOTION_SMOOTH_VIEWS = 2.0


def bin_sinograms(sinograms: np.ndarray, binning: int) -> np.ndarray:
    """Average ``binning`` detector columns, and ``binning`` slices where there are at least that many.

    Parameters
    ----------
    sinograms : ndarray of shape (S, K, L)
        One sinogram per slice; ``L`` must be a multiple of ``binning``.
    binning : int
        Pixels averaged (1: unchanged).

    Returns
    -------
    ndarray of shape (S // b or S, K, L // b), float32
        Trailing slices that do not fill a group are left out.
    """
    stack = np.asarray(sinograms, dtype=np.float64)
    s, k, det = stack.shape
    if binning == 1:
        return stack.astype(np.float32)
    stack = stack.reshape(s, k, det // binning, binning).mean(axis=3)
    if s >= binning:
        kept = s // binning * binning
        stack = stack[:kept].reshape(kept // binning, binning, k, det // binning).mean(axis=1)
    return stack.astype(np.float32)


def binned_offset(offset: float, n_det: int, binning: int) -> float:
    """The rotation-axis offset from the detector centre after binning ``n_det`` pixels by ``binning``.

    The axis is seen at raw column ``c = (L - 1) / 2 + offset``; binned pixel ``j`` is centred
    at raw column ``b j + (b - 1) / 2``, so the axis is at binned column ``(c + 0.5) / b - 0.5``.
    """
    column = (n_det - 1) / 2 + offset
    return (column + 0.5) / binning - 0.5 - (n_det // binning - 1) / 2


def binned_geometry(geometry: Geometry, binning: int, center_offset: float) -> Geometry:
    """The scan's geometry on the binned detector: same views, ``L / b`` pixels, image ``N / b``, axis moved.

    Raises
    ------
    NanoctError
        If ``binning`` is not a whole number >= 1 dividing the detector width and the image size.
    """
    if isinstance(binning, bool) or not isinstance(binning, int) or binning < 1:
        raise NanoctError(f"--bin {binning!r} must be a whole number >= 1")
    for what, size in (("detector width", geometry.n_det), ("image size", geometry.n)):
        if size % binning:
            divisors = [d for d in range(1, min(size, 16) + 1) if size % d == 0]
            again = (
                f"--binning {binning} (which drops the columns left over) or --crop to a width that {binning} divides"
                if what == "detector width"
                else f"--size set to a multiple of {binning}"
            )
            raise NanoctError(
                f"--bin {binning} does not divide the scan's {what} {size}; use one of {divisors}, or import the "
                f"scan again with {again}, and make the set like that import"
            )
    data = geometry.to_dict()
    data.update(
        n=geometry.n // binning,
        n_det=geometry.n_det // binning,
        center_offset=binned_offset(center_offset, geometry.n_det, binning),
    )
    return Geometry.from_dict(data)


def air_noise(sinograms: np.ndarray) -> dict[str, Any]:
    """Noise std per ray measured in the air bands of every view (see the module docstring).

    Parameters
    ----------
    sinograms : ndarray of shape (S, K, L)

    Returns
    -------
    dict
        ``sigma`` (the estimate), ``band_px`` (pixels per band), ``air_level`` (the median
        open-beam level over the bands, in the data's units), ``values`` (second differences
        pooled) and ``estimator`` (a one-line description).
    """
    y = np.asarray(sinograms, dtype=np.float64)
    w = min(edge_width(y.shape[2]), y.shape[2] // 2)
    if w < 3:
        raise NanoctError(
            f"the scan's detector ({y.shape[2]} pixels after binning) is too narrow to measure the noise in its air "
            "bands (3 pixels a side needed); use a smaller --bin"
        )
    bands = [y[..., :w], y[..., -w:]]
    d = np.concatenate([(b[..., 2:] - 2 * b[..., 1:-1] + b[..., :-2]).ravel() for b in bands])
    sigma = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / math.sqrt(6.0)
    return {
        "sigma": sigma,
        "band_px": int(w),
        "air_level": float(np.median(np.concatenate([b.ravel() for b in bands]))),
        "values": int(d.size),
        "estimator": f"1.4826 MAD / sqrt(6) of the second differences along the detector in the {w} outermost "
        "pixels on each side of every view (air bands)",
    }


def open_beam_level(sinograms: np.ndarray) -> np.ndarray:
    """The scan's open-beam level per view: :func:`~nanoct.recon.measured.air_level` of every slice, median over slices.

    Parameters
    ----------
    sinograms : ndarray of shape (S, K, L)

    Returns
    -------
    ndarray of shape (K,), float64
        In the data's units (absorbance): the level a flat/dark-corrected scan reads in air when
        the flat is brighter than the projections' open beam, and its drift over the views.
    """
    y = np.asarray(sinograms, dtype=np.float64)
    return np.median(np.stack([air_level(s) for s in y]), axis=0)


def _white_factor(sigma: float, size: int) -> float:
    """Std left of unit white noise by subtracting its Gaussian-filtered copy (``mode="nearest"``, mid-signal)."""
    impulse = np.zeros(2 * size + 1)
    impulse[size] = 1.0
    weights = ndimage.gaussian_filter1d(impulse, sigma, mode="constant")
    return float(math.sqrt(max(1.0 - 2.0 * weights[size] + float((weights**2).sum()), 1e-12)))


def motion_stats(shifts: np.ndarray, smooth_views: float = MOTION_SMOOTH_VIEWS) -> dict[str, float]:
    """Smooth amplitude and jitter std of a per-view shift (see the module docstring).

    Parameters
    ----------
    shifts : ndarray of shape (K,)
        Shift along the detector per view, in acquisition order (pixels).
    smooth_views : float
        Std of the Gaussian filter, in views.

    Returns
    -------
    dict
        ``amplitude`` (px), ``jitter`` (px), ``rms`` (px, the shift's std) and ``smooth_views``.
    """
    x = np.asarray(shifts, dtype=np.float64).ravel()
    if x.size < 3 or not np.isfinite(x).all():
        raise NanoctError(f"the estimated motion has {x.size} value(s) or non-finite ones; cannot take its statistics")
    x = x - x.mean()
    smooth = ndimage.gaussian_filter1d(x, smooth_views, mode="nearest")
    rest = x - smooth
    return {
        "amplitude": float(np.abs(smooth).max()),
        "jitter": float(rest.std() / _white_factor(smooth_views, x.size)),
        "rms": float(x.std()),
        "smooth_views": float(smooth_views),
    }
