"""Open-beam normalisation from air regions, one fit per view (beam decay, flat-field mismatch).

After flat/dark correction the open beam is rarely at transmission 1: the beam decays during a
scan, the flat field was taken at another time or position, and the detector response drifts.
Each view's open-beam level is estimated from the pixels that see only air and the view is
divided by it (equivalently, its ``-log`` is subtracted from the line integrals).

Automatic air detection (``columns=None``), per view:

1. ``s`` = the view after a 3 x 3 median filter (classification only; zingers and noise do not
   decide which pixels are air), ``sigma`` = ``1.4826 * median |v[i, j+1] - v[i, j]| / sqrt(2)``,
   a robust estimate of the pixel noise (:func:`robust_noise`).
2. The upper mode: starting from the 99th percentile of ``s``, repeat ``level = median(s[|s -
   level| <= band * sigma])`` until it stops moving (a flat-kernel mean shift, which climbs to
   the nearest mode of the histogram from above: the brightest mode, which is the open beam
   wherever some air is seen). The half-width is at least ``0.005 * level`` so that noise-free
   data have a band.
3. Air = the pixels within that band, less connected regions of fewer than 9 pixels (3 in a
   single row: hot pixels, bright fringes).
4. Refused when the air found is less than ``min_fraction`` of the view's pixels, or is not
   flat: the median of ``s``'s local gradient (central differences, the larger of the row and
   column ones) over its inside (the air eroded by one pixel) exceeds half the band's half-width
   (measured: at most 0.09 on Diamond I13-2, 0.15 on a neutron sinogram, 0.4 on single-row
   simulations with 2 % noise and 10 air pixels a side; 0.7-1.6 where the edge of an object wider
   than the detector is the brightest region at noise up to 0.4 %). Then no air is visible and
   the columns must be given.
   An object wider than the detector that is nearly flat at the edges within the noise cannot
   be told from air by intensity: give the columns, or leave the normalisation off.

Given columns (``columns=[(first, stop), ...]``): air = those columns, all rows.

The fit over the air pixels of each view: ``degree=0``, their median (one level per view); or a
least-squares polynomial surface of total degree 1 (a plane) or 2 in the centred column and row
coordinates, for a beam profile that differs from the flat's (on Diamond I13-2 the open beam
falls off towards both sides by about 5 % and moves sideways during the scan). A surface is
refitted three times to the pixels within the band around it (air at the sides is darker than
the brightest mode). A plane needs air spanning at least half the detector width; a quadratic
also needs air in the middle third of the columns (above or below the object), since air at
the two sides alone cannot tell the constant from the curvature. The default,
``degree="auto"``, fits each view the highest degree its air determines.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..core.errors import NanoctError

__all__ = ["OpenBeam", "estimate_open_beam", "normalize_open_beam", "poly_terms", "robust_noise"]

_REL_BAND = 0.005  # the band's half-width is at least this fraction of the level
_MIN_REGION = 9  # connected air regions of fewer pixels are specks (hot pixels, fringes), not air
_MAX_SLOPE = 0.5  # air is flat: its median local gradient is below this fraction of the band's half-width
_REFITS = 3  # a surface (degree > 0) is refitted to the pixels within the band around it


@dataclass(frozen=True)
class OpenBeam:
    """The open beam fitted to each view's air pixels.

    Attributes
    ----------
    coefficients : ndarray of shape (K, T)
        Per view, the coefficients of the polynomial terms ``u**i * w**j`` with ``i + j <=
        degree`` in the order of :func:`poly_terms`, where ``u = j / (L - 1) - 1/2`` and ``w = i /
        (R - 1) - 1/2`` are the centred column and row coordinates (0 for a single column or row).
    degree : int
        Total degree of the polynomial (0: one level per view).
    air_fraction : ndarray of shape (K,)
        Fraction of each view's pixels used as air.
    shape : (int, int)
        ``(R, L)``, the detector shape.
    """

    coefficients: np.ndarray
    degree: int
    air_fraction: np.ndarray
    shape: tuple[int, int]

    @property
    def levels(self) -> np.ndarray:
        """The mean open beam of each view over the detector, shape (K,)."""
        return np.array([self.field(k).mean() for k in range(self.coefficients.shape[0])])

    def field(self, view: int) -> np.ndarray:
        """The open beam of one view over the detector, shape (R, L), float64."""
        terms = _detector_terms(tuple(self.shape), self.degree)
        return sum(c * t for c, t in zip(self.coefficients[view], terms)) + np.zeros(self.shape)


@functools.lru_cache(maxsize=8)
def _detector_factors(shape: tuple[int, int], degree: int) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """The factors ``u**i`` (1, L) and ``w**j`` (R, 1) of :func:`poly_terms` over a detector of ``shape``, made
    once per shape and degree (read-only; a row and a column each, so the cache stays small)."""
    w, u = _coordinates(shape)
    u, w = u[None, :], w[:, None]
    factors = tuple((u ** (d - j), w**j) for d in range(degree + 1) for j in range(d + 1))
    for pair in factors:
        for f in pair:
            f.flags.writeable = False
    return factors


def _detector_terms(shape: tuple[int, int], degree: int) -> list[np.ndarray]:
    """:func:`poly_terms` over a detector of ``shape``: the same products of the same powers, from the cached
    factors (:func:`_detector_factors`)."""
    return [a * b for a, b in _detector_factors(shape, degree)]


def poly_terms(u: np.ndarray, w: np.ndarray, degree: int) -> list[np.ndarray]:
    """The terms ``u**i * w**j`` with ``i + j <= degree``, ordered by total degree, then by ``j``."""
    return [u ** (d - j) * w**j for d in range(degree + 1) for j in range(d + 1)]


def _coordinates(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = shape
    w = np.arange(rows) / (rows - 1) - 0.5 if rows > 1 else np.zeros(1)
    u = np.arange(cols) / (cols - 1) - 0.5 if cols > 1 else np.zeros(1)
    return w, u


def _robust_noise(view: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """``(finite mask, 3 x 3 median of the view, robust pixel noise)``: see :func:`robust_noise`."""
    finite = np.isfinite(view)
    filled = np.where(finite, view, np.median(view[finite]) if finite.any() else 0.0)
    smooth = ndimage.median_filter(filled, size=(min(3, view.shape[0]), 3), mode="nearest")
    return finite, smooth, robust_noise(filled)


def robust_noise(image: np.ndarray) -> float:
    """The pixel noise of an image: ``1.4826 * median |x[i, j+1] - x[i, j]| / sqrt(2)``.

    The median absolute difference of neighbouring pixels along the rows, scaled to a Gaussian
    standard deviation; edges and zingers, a small fraction of the pairs, barely move it.
    Non-finite pairs are ignored; 0 for fewer than two columns.
    """
    diff = np.diff(np.asarray(image, np.float64), axis=-1)
    diff = np.abs(diff[np.isfinite(diff)])
    return float(1.4826 * np.median(diff) / np.sqrt(2)) if diff.size else 0.0


def _upper_mode(values: np.ndarray, band: float, sigma: float) -> tuple[float, float]:
    """``(level, half-width)``: the flat-kernel mean shift from the 99th percentile down to a mode."""
    level = float(np.quantile(values, 0.99))
    for _ in range(100):
        half = max(band * sigma, _REL_BAND * abs(level))
        inside = values[np.abs(values - level) <= half]
        new = float(np.median(inside)) if inside.size else level
        if abs(new - level) <= 1e-3 * half:
            break
        level = new
    return level, max(band * sigma, _REL_BAND * abs(level))


#: 4-connected neighbours (:func:`scipy.ndimage.label`'s default), made once
_CROSS = ndimage.generate_binary_structure(2, 1)


def _without_specks(mask: np.ndarray) -> np.ndarray:
    labels, count = ndimage.label(mask, _CROSS)
    sizes = np.bincount(labels.ravel(), minlength=count + 1)
    kept = sizes >= min(_MIN_REGION, 3 * mask.shape[0])  # 3 pixels in a single row
    kept[0] = False  # the background
    return kept[labels]


def _slope(smooth: np.ndarray, air: np.ndarray, half: float) -> float:
    """The median local gradient of the smoothed view inside the air (its border left out), in band half-widths."""
    inner = ndimage.binary_erosion(air, np.ones((min(3, air.shape[0]), 3), bool))
    air = inner if inner.any() else air
    grad = np.abs(np.gradient(smooth, axis=1))
    if smooth.shape[0] > 1:
        grad = np.maximum(grad, np.abs(np.gradient(smooth, axis=0)))
    return float(np.median(grad[air]) / half) if half > 0 else 0.0


def _spans_half(air: np.ndarray) -> bool:
    """Whether the air's columns span at least half the detector width (a plane can be fitted)."""
    cols = np.nonzero(air.any(axis=0))[0]
    return cols.size > 0 and cols[-1] - cols[0] >= air.shape[1] / 2


def _fits_degree(air: np.ndarray) -> int:
    """The highest degree the air determines: 2 with air in the middle third of the columns too
    (air at the two sides only cannot tell the constant from the curvature), 1 if it spans half
    the detector width, else 0."""
    if not _spans_half(air):
        return 0
    third = air.shape[1] // 3
    return 2 if air[:, third : air.shape[1] - third].any() else 1


def _auto_fit(view: np.ndarray, band: float, degree: int | str, k: int) -> tuple[np.ndarray, np.ndarray]:
    """``(coefficients, air mask)`` of view ``k``: the brightest mode's pixels, then refits of the surface."""
    finite, smooth, sigma = _robust_noise(view)
    if not finite.any():
        return np.zeros(1), finite
    level, half = _upper_mode(smooth[finite], band, sigma)
    air = _without_specks(finite & (np.abs(smooth - level) <= half))
    if air.any() and _slope(smooth, air, half) > _MAX_SLOPE:
        raise NanoctError(
            f"no flat air region found in view {k}: its brightest pixels change by {_slope(smooth, air, half):.2f} "
            f"band widths per pixel (air: < {_MAX_SLOPE}), so the object fills the detector; give the detector "
            "columns that see only air (--air-columns FIRST:STOP[,FIRST:STOP])"
        )
    if degree == "auto":
        degree = _fits_degree(air)
    coef = _fit(view, air, degree)
    for _ in range(_REFITS if degree > 0 and air.any() else 0):  # air darker or brighter by the beam profile
        field = OpenBeam(coef[None], degree, np.zeros(1), view.shape).field(0)
        air = _without_specks(finite & (np.abs(smooth - field) <= half))
        if not air.any():
            break
        coef = _fit(view, air, degree)
    return coef, air


def _fit(view: np.ndarray, air: np.ndarray, degree: int) -> np.ndarray:
    """The polynomial's coefficients from the air pixels of one view (degree 0: their median)."""
    values = view[air].astype(np.float64)
    if values.size == 0:  # no air: a zero level, which the caller refuses by its air fraction
        return np.zeros(1)
    if degree == 0:
        return np.array([np.median(values)])
    design = np.stack([t[air] for t in _detector_terms(view.shape, degree)], axis=1)
    # normal equations (T x T; a minimum-norm solution where rows or columns are constant)
    coef, *_ = np.linalg.lstsq(design.T @ design, design.T @ values, rcond=None)
    return coef


def _columns_mask(shape: tuple[int, int], columns: list[tuple[int, int]]) -> np.ndarray:
    mask = np.zeros(shape, bool)
    for first, stop in columns:
        if not 0 <= first < stop <= shape[1]:
            raise NanoctError(
                f"air columns {first}:{stop} must satisfy 0 <= FIRST < STOP <= {shape[1]} detector columns"
            )
        mask[:, first:stop] = True
    return mask


def estimate_open_beam(
    transmission: np.ndarray,
    *,
    columns: list[tuple[int, int]] | None = None,
    degree: int | str = "auto",
    band: float = 3.0,
    min_fraction: float = 0.01,
) -> OpenBeam:
    """Fit each view's open beam to its air pixels (see the module docstring for the estimator).

    Parameters
    ----------
    transmission : ndarray of shape (K, R, L)
        Flat/dark-normalised projections (or raw counts: the fit is in the data's units).
    columns : list of (int, int), optional
        Detector column ranges ``[first, stop)`` known to see only air in every view. Default:
        found automatically per view.
    degree : {"auto", 0, 1, 2}
        Total degree of the polynomial surface fitted per view: 0, one level (the median of the
        air); 1, a plane; 2, a quadratic surface (a beam profile that falls off to the sides);
        ``"auto"``, per view the highest degree its air determines: 2 with air spanning half the
        detector width and reaching its middle third, 1 with air spanning half the width, else 0.
    band : float
        Half-width of the air band around the brightest mode (and around the fitted surface),
        in units of the robust pixel noise (automatic detection only).
    min_fraction : float
        Least fraction of a view's pixels that must be air.

    Returns
    -------
    OpenBeam

    Raises
    ------
    NanoctError
        For a bad option, a view without (enough) air, a surface (degree > 0) whose air does not
        span half the detector width, or an open beam that is not positive.
    """
    data = np.asarray(transmission)
    if data.ndim != 3 or 0 in data.shape:
        raise NanoctError(f"projections of shape {data.shape} must be (views, rows, columns), none empty")
    if degree not in (0, 1, 2, "auto"):
        raise NanoctError(f"--open-beam-degree {degree!r} must be 0, 1, 2 or auto")
    if not (band > 0 and 0 < min_fraction < 1):
        raise NanoctError(f"air band {band} must be > 0 and the least air fraction {min_fraction} in (0, 1)")
    shape = data.shape[1:]
    given = None if columns is None else _columns_mask(shape, columns)
    n_terms = len(poly_terms(np.zeros(1), np.zeros(1), 2 if degree == "auto" else degree))
    coefficients = np.zeros((data.shape[0], n_terms))
    fraction = np.zeros(data.shape[0])
    for k, view in enumerate(data):
        if given is None:
            coef, air = _auto_fit(view, band, degree, k)
        else:
            air = given & np.isfinite(view)
            coef = _fit(view, air, _fits_degree(air) if degree == "auto" else degree)
        fraction[k] = air.mean()
        if fraction[k] < min_fraction:
            raise NanoctError(
                f"no air found in view {k}: {fraction[k]:.1%} of its pixels (need {min_fraction:.0%}); "
                "give the detector columns that see only air (--air-columns FIRST:STOP[,FIRST:STOP])"
            )
        if degree in (1, 2) and _fits_degree(air) < degree:
            cols = np.nonzero(air.any(axis=0))[0]
            raise NanoctError(
                f"the air of view {k} (columns {cols[0]}..{cols[-1]}) does not determine a surface of degree "
                f"{degree} (1: air spanning half the detector width; 2: also air in its middle third); "
                "use --open-beam-degree auto"
            )
        coefficients[k, : coef.size] = coef  # a degree-0 view of an auto fit: the other terms stay 0
    beam = OpenBeam(coefficients, 2 if degree == "auto" else degree, fraction, shape)
    lows = [float(beam.field(k).min()) for k in range(data.shape[0])]
    if min(lows) <= 0:
        bad = int(np.argmin(lows))
        raise NanoctError(f"the open beam fitted to view {bad} falls to {lows[bad]:.3g}, not positive; check the data")
    return beam


def normalize_open_beam(transmission: np.ndarray, open_beam: OpenBeam) -> np.ndarray:
    """Divide each view by its fitted open beam: air then reads transmission 1.

    Parameters
    ----------
    transmission : ndarray of shape (K, R, L)
    open_beam : OpenBeam
        From :func:`estimate_open_beam` on the same projections.

    Returns
    -------
    ndarray of shape (K, R, L), float32
    """
    data = np.asarray(transmission)
    out = np.empty(data.shape, np.float32)
    for k in range(data.shape[0]):
        out[k] = data[k] / np.maximum(open_beam.field(k), 1e-12)
    return out
