"""Fourier ring correlation (FRC): a resolution measure that needs no ground truth.

Two images of the same object with independent noise (for tomography: the slices reconstructed
from the even and from the odd views) are compared ring by ring in Fourier space::

    FRC(r) = Re sum_{|f| in ring r} F1(f) conj(F2(f)) / sqrt(sum |F1(f)|^2 * sum |F2(f)|^2)

The rings are one frequency step wide (``1 / min(N, M)`` cycles per pixel for ``N x M`` images)
and run from 0 to the Nyquist frequency 0.5 cycles/pixel. Stacks ``(..., N, M)`` are compared
slice by slice with the ring sums added over the slices (one curve for a slab).

The resolution is the first frequency (after the zero ring) at which the curve falls below a
threshold (linear interpolation between the two rings around the crossing); reported as that
frequency in cycles/pixel and as its inverse, a period in pixels:

``"1/7"``
    The fixed threshold 1/7 = 0.1429 (Rosenthal & Henderson, J. Mol. Biol. 333, 721, 2003).
``"half-bit"``
    The information threshold of van Heel & Schatz (J. Struct. Biol. 151, 250, 2005) for two
    half data sets, ``T(n) = (S + (2 sqrt(S) + 1) / sqrt(n)) / (S + 1 + 2 sqrt(S) / sqrt(n))``
    with ``S = (sqrt(2) - 1) / 2`` the signal-to-noise ratio of each half that gives the whole
    data set half a bit per sample, and ``n`` the number of Fourier samples in the ring; with
    the numbers written out, ``(0.2071 + 1.9102 / sqrt(n)) / (1.2071 + 0.9102 / sqrt(n))``.
    It falls towards ``S / (1 + S) = 0.1716`` for rings of many samples, so it always lies above
    1/7 and gives the more cautious (lower) crossing frequency.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.errors import NanoctError

__all__ = ["FRC_THRESHOLDS", "frc", "frc_resolution", "half_bit_threshold", "ring_counts"]

#: The thresholds :func:`frc_resolution` knows.
FRC_THRESHOLDS = ("1/7", "half-bit")


def _ring_index(shape: tuple[int, int]) -> tuple[np.ndarray, int, float]:
    """Ring number of every Fourier sample of an ``shape`` image, the number of rings and their width."""
    n, m = shape
    step = 1.0 / min(n, m)
    radius = np.hypot(*np.meshgrid(np.fft.fftfreq(n), np.fft.fftfreq(m), indexing="ij"))
    rings = int(np.floor(0.5 / step + 0.5)) + 1
    return np.floor(radius / step + 0.5).astype(np.int64), rings, step


def ring_counts(shape: tuple[int, int]) -> np.ndarray:
    """Number of Fourier samples in each ring of :func:`frc` for images of ``shape`` ``(N, M)``.

    Parameters
    ----------
    shape : tuple of int
        Image shape (rows, columns).

    Returns
    -------
    ndarray of int, shape (R,)
        Samples per ring, ring 0 (zero frequency) first; multiply by the number of slices for a stack.
    """
    index, rings, _ = _ring_index((int(shape[0]), int(shape[1])))
    return np.bincount(index.ravel(), minlength=rings)[:rings]


def frc(a: Any, b: Any, *, mask: Any = None) -> tuple[np.ndarray, np.ndarray]:
    """Fourier ring correlation of two images (or two stacks of images, rings summed over slices).

    Parameters
    ----------
    a, b : array_like of shape (..., N, M)
        Real images of the same shape, e.g. slices reconstructed from the even and the odd views.
    mask : array_like of shape (N, M), optional
        Real-space weight applied to both before the transform (e.g. a soft disc on the field of
        view, to keep the corners of a reconstruction out).

    Returns
    -------
    frequencies : ndarray of shape (R,)
        Ring centres in cycles per pixel, ``0, 1/min(N, M), ...`` up to 0.5.
    curve : ndarray of shape (R,)
        FRC per ring, in [-1, 1] (0 where a ring holds no power).

    Raises
    ------
    NanoctError
        For shapes that differ, images smaller than 2 x 2 or values that are not finite.
    """
    x, y = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if x.shape != y.shape or x.ndim < 2 or min(x.shape[-2:]) < 2:
        raise NanoctError(f"frc: images of shapes {x.shape} and {y.shape}; give two images (..., N, M) of one shape")
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise NanoctError("frc: the images hold NaN or infinite values")
    if mask is not None:
        weight = np.asarray(mask, dtype=np.float64)
        if weight.shape != x.shape[-2:]:
            raise NanoctError(f"frc: mask of shape {weight.shape} for images of shape {x.shape[-2:]}")
        x, y = x * weight, y * weight
    fx, fy = np.fft.fft2(x), np.fft.fft2(y)
    index, rings, step = _ring_index(x.shape[-2:])
    keep = index.ravel() < rings

    def ring_sum(values: np.ndarray) -> np.ndarray:
        flat = values.reshape(-1, index.size).sum(axis=0)
        return np.bincount(index.ravel()[keep], weights=flat[keep], minlength=rings)[:rings]

    cross = ring_sum(np.real(fx * np.conj(fy)))
    power = np.sqrt(ring_sum(np.abs(fx) ** 2) * ring_sum(np.abs(fy) ** 2))
    curve = np.divide(cross, power, out=np.zeros(rings), where=power > 0)
    return np.arange(rings) * step, np.clip(curve, -1.0, 1.0)


def half_bit_threshold(counts: Any) -> np.ndarray:
    """The half-bit threshold for rings of ``counts`` Fourier samples (see the module docstring).

    Parameters
    ----------
    counts : array_like of int
        Samples per ring (:func:`ring_counts`, times the slices of a stack).

    Returns
    -------
    ndarray
        Threshold per ring (1 where a ring is empty).
    """
    n = np.asarray(counts, dtype=np.float64)
    snr = (np.sqrt(2.0) - 1.0) / 2.0
    root = np.sqrt(np.maximum(n, 1.0))
    out = (snr + (2.0 * np.sqrt(snr) + 1.0) / root) / (snr + 1.0 + 2.0 * np.sqrt(snr) / root)
    return np.where(n > 0, out, 1.0)


def frc_resolution(
    freq: Any, curve: Any, threshold: str = "1/7", *, counts: Any = None
) -> tuple[float | None, float | None]:
    """First crossing of an FRC curve below a threshold.

    Parameters
    ----------
    freq, curve : array_like of shape (R,)
        From :func:`frc`.
    threshold : {"1/7", "half-bit"}
        Fixed 1/7, or the half-bit curve (module docstring).
    counts : array_like of shape (R,), optional
        Fourier samples per ring for ``"half-bit"`` (default :func:`ring_counts` of a square
        image of side ``1 / freq[1]``; pass it for other shapes or for stacks).

    Returns
    -------
    frequency : float or None
        Crossing in cycles per pixel (linear interpolation between rings); ``None`` when the
        curve stays above the threshold up to the last ring.
    resolution : float or None
        ``1 / frequency``: the finest period resolved, in pixels.

    Raises
    ------
    NanoctError
        For an unknown threshold or curves of different lengths.
    """
    f, c = np.asarray(freq, dtype=np.float64), np.asarray(curve, dtype=np.float64)
    if f.shape != c.shape or f.ndim != 1 or f.size < 2:
        raise NanoctError(f"frc_resolution: frequencies {f.shape} and curve {c.shape} must be 1-D of one length >= 2")
    if threshold == "1/7":
        level = np.full(f.size, 1.0 / 7.0)
    elif threshold == "half-bit":
        if counts is None:
            side = int(round(1.0 / (f[1] - f[0])))
            counts = ring_counts((side, side))[: f.size]
        level = half_bit_threshold(counts)
        if level.shape != f.shape:
            raise NanoctError(f"frc_resolution: {level.size} ring counts for {f.size} rings")
    else:
        raise NanoctError(f"frc_resolution: threshold {threshold!r}; choose one of {', '.join(FRC_THRESHOLDS)}")
    below = np.flatnonzero(c[1:] < level[1:]) + 1
    if below.size == 0:
        return None, None
    i = int(below[0])
    gap_before, gap_after = c[i - 1] - level[i - 1], c[i] - level[i]
    t = gap_before / (gap_before - gap_after) if gap_before > gap_after else 0.0
    crossing = float(f[i - 1] + t * (f[i] - f[i - 1]))
    return crossing, (1.0 / crossing if crossing > 0 else None)
