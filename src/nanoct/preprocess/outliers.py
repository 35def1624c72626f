"""Outlier (zinger, dead-pixel) removal in projections: a median filter and a robust threshold.

Each projection ``v`` (rows x columns) is compared with its median-filtered copy ``m``
(``scipy.ndimage.median_filter``, ``size`` x ``size`` pixels, edges repeated; ``1 x size`` for a
single row). A pixel is an outlier where ``v - m > threshold * sigma`` (``"bright"``: zingers,
from X-rays or gamma rays hitting the detector), ``v - m < -threshold * sigma`` (``"dark"``: dead
pixels) or either (``"both"``), with ``sigma`` the robust pixel noise of the projection
(:func:`nanoct.preprocess.openbeam.robust_noise`: the median absolute difference of neighbouring
pixels, scaled to a Gaussian standard deviation). Outliers are replaced by ``m``; other pixels
are unchanged. The same rule as TomoPy's ``remove_outlier`` with the threshold in noise units
instead of data units.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from ..core.errors import NanoctError
from .openbeam import robust_noise

__all__ = ["OUTLIER_KINDS", "remove_outliers"]

#: Which side of the median an outlier lies on.
OUTLIER_KINDS = ("both", "bright", "dark")


def remove_outliers(
    projections: np.ndarray, *, threshold: float = 5.0, size: int = 3, kind: str = "both"
) -> tuple[np.ndarray, int]:
    """Replace outlying pixels of each projection by the median of their neighbourhood.

    Parameters
    ----------
    projections : ndarray of shape (K, R, L)
        Projections (transmission or raw counts), one per view; non-finite pixels are outliers too.
    threshold : float
        Distance from the local median, in units of the projection's robust noise, beyond which
        a pixel is an outlier.
    size : int
        Odd width of the median filter's window (3 or 5: zingers of 1 and 2 pixels).
    kind : {"both", "bright", "dark"}
        Which outliers to replace.

    Returns
    -------
    (ndarray of shape (K, R, L), float32; int)
        The corrected projections and the number of pixels replaced.

    Raises
    ------
    NanoctError
        For a bad threshold, size or kind, or projections that are not 3-D.
    """
    data = np.asarray(projections)
    if data.ndim != 3:
        raise NanoctError(f"projections of shape {data.shape} must be (views, rows, columns)")
    if not threshold > 0:
        raise NanoctError(f"--outlier-threshold {threshold} must be > 0 (robust noise units)")
    if not (isinstance(size, int | np.integer) and size >= 3 and size % 2 == 1):
        raise NanoctError(f"--outlier-size {size} must be an odd integer >= 3")
    if kind not in OUTLIER_KINDS:
        raise NanoctError(f"outlier kind {kind!r} must be one of {', '.join(OUTLIER_KINDS)}")
    out = np.empty(data.shape, np.float32)
    replaced = 0
    window = (min(size, data.shape[1]) | 1, size)
    for k, view in enumerate(data):
        view = view.astype(np.float32)
        finite = np.isfinite(view)
        filled = np.where(finite, view, np.median(view[finite]) if finite.any() else 0.0)
        med = ndimage.median_filter(filled, size=window, mode="nearest")
        diff = filled - med
        limit = threshold * robust_noise(filled)
        bad = {"both": np.abs(diff) > limit, "bright": diff > limit, "dark": diff < -limit}[kind] | ~finite
        out[k] = np.where(bad, med, view)
        replaced += int(bad.sum())
    return out, replaced
