"""Image quality and uncertainty metrics.

PSNR and SSIM are computed per image with ``data_range = max(gt) - min(gt)`` of the ground
truth (the paper's and dival's convention); SSIM uses scikit-image's defaults (7x7 uniform
window). Tables report mean and standard deviation over the images, with their number.

Pixel-wise uncertainty (a std map next to each reconstruction) is scored over all pixels of
all images of a split pooled together: the correlation of std and absolute error, the coverage
of k-std intervals, and the sparsification curve with its area (AUSE, Ilg et al., ECCV 2018).
What each score means and its conventions: ``docs/uncertainty.md``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import ndimage
from scipy.special import erfinv
from skimage.metrics import structural_similarity

from .validation import check_array

__all__ = [
    "EDGE_SIGMA",
    "GAUSSIAN_COVERAGE",
    "SPARSIFICATION_FRACTIONS",
    "SUPPORT_RADIUS",
    "coverage",
    "edge_std",
    "fit_std_scale",
    "psnr",
    "reliability",
    "sparsification",
    "ssim",
    "summarize",
    "support_mask",
    "uncertainty_summary",
]

#: Probability of |N(0, s^2)| <= k s for k = 1, 2, 3.
GAUSSIAN_COVERAGE = {"1": 0.6827, "2": 0.9545, "3": 0.9973}
#: Fractions of pixels removed along a sparsification curve (0 to 0.99 in steps of 0.01).
SPARSIFICATION_FRACTIONS = np.round(np.arange(100) / 100, 2)
#: Radius in pixels (Euclidean disk) by which ``gt > 0`` is dilated to give the object's support.
SUPPORT_RADIUS = 2
#: Gaussian sigma in pixels of the edge baseline (smoothed Sobel gradient magnitude).
EDGE_SIGMA = 1.0


def _data_range(gt: np.ndarray) -> float:
    rng = float(gt.max() - gt.min())
    if rng <= 0:
        raise ValueError(
            "the ground truth is constant (max == min); PSNR/SSIM with data_range = max - min are undefined"
        )
    return rng


def psnr(reco: np.ndarray, gt: np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB with data range ``max(gt) - min(gt)``."""
    gt = check_array(gt, "ground truth", ndim=2, dtype=np.float64)
    reco = check_array(reco, "reconstruction", shape=gt.shape, dtype=np.float64)
    mse = float(np.mean((reco - gt) ** 2))
    if mse == 0:
        return float("inf")
    return float(10 * np.log10(_data_range(gt) ** 2 / mse))


def ssim(reco: np.ndarray, gt: np.ndarray) -> float:
    """Structural similarity (scikit-image defaults) with data range ``max(gt) - min(gt)``."""
    gt = check_array(gt, "ground truth", ndim=2, dtype=np.float64)
    reco = check_array(reco, "reconstruction", shape=gt.shape, dtype=np.float64)
    return float(structural_similarity(reco, gt, data_range=_data_range(gt)))


def summarize(recos: np.ndarray, gts: np.ndarray) -> dict[str, Any]:
    """PSNR and SSIM of a stack of images: per image, and their mean and std.

    Returns
    -------
    dict
        ``psnr_mean``, ``psnr_std``, ``ssim_mean``, ``ssim_std`` (std with ddof 0), ``n``, and
        the per-image values ``psnr_values``, ``ssim_values`` (lists, in the given order; the
        paired comparisons of :mod:`nanoct.conclusions` use them).
    """
    if len(recos) != len(gts):
        raise ValueError(f"{len(recos)} reconstructions for {len(gts)} ground truths")
    if len(gts) == 0:
        raise ValueError("no images to evaluate (is the test split empty?)")
    p = np.array([psnr(r, g) for r, g in zip(recos, gts)])
    s = np.array([ssim(r, g) for r, g in zip(recos, gts)])
    return {
        "psnr_mean": float(p.mean()),
        "psnr_std": float(p.std()),
        "ssim_mean": float(s.mean()),
        "ssim_std": float(s.std()),
        "n": int(len(gts)),
        "psnr_values": p.tolist(),
        "ssim_values": s.tolist(),
    }


def _err_std(err: np.ndarray, std: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    err = np.asarray(err, dtype=np.float64).ravel()
    std = np.asarray(std, dtype=np.float64).ravel()
    if err.shape != std.shape:
        raise ValueError(f"{err.size} errors for {std.size} std values")
    if err.size == 0:
        raise ValueError("no pixels to score (empty images or an empty mask)")
    if not (np.isfinite(err).all() and np.isfinite(std).all()):
        raise ValueError("the errors or the std contain NaN or infinite values")
    if (std < 0).any():
        raise ValueError("std contains negative values")
    return np.abs(err), std


def coverage(err: np.ndarray, std: np.ndarray, ks: tuple[float, ...] = (1, 2, 3)) -> dict[str, float]:
    """Fraction of pixels with ``|err| <= k * std`` for each k (keys ``"1"``, ``"2"``, ...).

    For errors drawn from N(0, std^2) this is :data:`GAUSSIAN_COVERAGE`.
    """
    err, std = _err_std(err, std)
    return {f"{k:g}": float(np.mean(err <= k * std)) for k in ks}


def reliability(err: np.ndarray, std: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """Observed coverage of the central Gaussian intervals of nominal probability ``levels``.

    The interval of level p is ``|err| <= k_p std`` with ``k_p = sqrt(2) erfinv(p)``; a
    calibrated Gaussian std gives observed = p (the diagonal of a reliability diagram).
    """
    err, std = _err_std(err, std)
    levels = np.asarray(levels, dtype=np.float64)
    if ((levels <= 0) | (levels >= 1)).any():
        raise ValueError(f"nominal levels must lie strictly between 0 and 1, got {levels}")
    ratio = np.sort(_ratio(err, std))
    k = np.sqrt(2) * erfinv(levels)
    return np.searchsorted(ratio, k, side="right") / ratio.size


def _ratio(err: np.ndarray, std: np.ndarray) -> np.ndarray:
    """``|err| / std`` with 0/0 = 0 and x/0 = inf (a zero std covers only a zero error)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        r = err / std
    r[(std == 0) & (err == 0)] = 0.0
    return r


def fit_std_scale(err: np.ndarray, std: np.ndarray, level: float = GAUSSIAN_COVERAGE["1"]) -> float:
    """The smallest factor s with ``|err| <= s * std`` on at least ``level`` of the pixels.

    This is the ``level`` quantile of ``|err| / std`` (an observed value, so the fitted
    coverage is at least ``level`` and exceeds it by at most the share of tied ratios).

    Raises
    ------
    ValueError
        If no finite positive factor reaches ``level`` (the std is zero on too many pixels
        with non-zero error, or the error is zero on ``level`` of the pixels).
    """
    err, std = _err_std(err, std)
    if not 0 < level < 1:
        raise ValueError(f"level {level} must lie strictly between 0 and 1")
    s = float(np.quantile(_ratio(err, std), level, method="inverted_cdf"))
    if not np.isfinite(s) or s <= 0:
        raise ValueError(
            f"no finite positive std scale covers {level:.1%} of the pixels (quantile of |err|/std = {s}); "
            "the std is zero where the error is not, or the error is zero almost everywhere"
        )
    return s


def sparsification(err: np.ndarray, std: np.ndarray, fractions: np.ndarray | None = None) -> dict[str, object]:
    """Sparsification curves of a std map and their areas (Ilg et al., ECCV 2018).

    For each fraction f, the fraction f of pixels with the largest std is removed and the mean
    absolute error (MAE) of the remaining pixels is taken; the oracle removes the pixels with
    the largest error instead. Both curves are divided by the MAE of all pixels, so they start
    at 1 and areas are comparable between rows. Pixels with tied std are removed in random
    order, taken in expectation (their errors are replaced by the tie group's mean), so a
    constant std gives the random curve. Removing pixels in random order leaves an expected
    MAE equal to the MAE of all pixels: the random curve is the constant 1.

    Parameters
    ----------
    err, std : array
        Errors (their absolute value is used) and std, any equal shapes.
    fractions : array, optional
        Removed fractions in [0, 1), increasing (default :data:`SPARSIFICATION_FRACTIONS`).

    Returns
    -------
    dict
        ``fractions``, ``curve`` (by std), ``oracle`` (by error), ``ause`` = area between
        ``curve`` and ``oracle`` (trapezoid rule over ``fractions``; 0 is perfect),
        ``ause_random`` = area between the random curve and the oracle, and ``ause_ratio`` =
        ``ause / ause_random`` (1: no better than random order). All NaN when every error is 0.
    """
    err, std = _err_std(err, std)
    f = SPARSIFICATION_FRACTIONS if fractions is None else np.asarray(fractions, dtype=np.float64)
    if f.ndim != 1 or f.size < 2 or (np.diff(f) <= 0).any() or f[0] < 0 or f[-1] >= 1:
        raise ValueError("fractions must be an increasing 1-D grid of at least 2 values in [0, 1)")
    total = float(err.mean())
    if total == 0:
        nan = float("nan")
        return {"fractions": f, "curve": f * nan, "oracle": f * nan, "ause": nan, "ause_random": nan, "ause_ratio": nan}
    order = np.argsort(-std, kind="stable")
    std_sorted, err_by_std = std[order], err[order]
    starts = np.flatnonzero(np.r_[True, std_sorted[1:] != std_sorted[:-1]])
    counts = np.diff(np.r_[starts, err.size])
    err_by_std = np.repeat(np.add.reduceat(err_by_std, starts) / counts, counts)  # tie groups: their mean
    removed = np.floor(f * err.size + 1e-9).astype(np.int64)

    def remaining_mae(ordered: np.ndarray) -> np.ndarray:
        head = np.r_[0.0, np.cumsum(ordered)]
        return (head[-1] - head[removed]) / (err.size - removed) / total

    curve, oracle = remaining_mae(err_by_std), remaining_mae(-np.sort(-err))
    ause = float(np.trapezoid(curve - oracle, f))
    ause_random = float(np.trapezoid(1.0 - oracle, f))
    ratio = ause / ause_random if ause_random > 0 else float("nan")
    return {
        "fractions": f,
        "curve": curve,
        "oracle": oracle,
        "ause": ause,
        "ause_random": ause_random,
        "ause_ratio": ratio,
    }


def support_mask(gts: np.ndarray, radius: int = SUPPORT_RADIUS) -> np.ndarray:
    """The object's support: ``gt > 0`` dilated by a disk of ``radius`` pixels, per image.

    ``gts`` is one image (H, W) or a stack (n, H, W); stacks are dilated image by image.
    """
    gts = np.asarray(gts)
    if gts.ndim not in (2, 3):
        raise ValueError(f"expected an image (H, W) or a stack (n, H, W), got shape {gts.shape}")
    if radius < 0:
        raise ValueError(f"support radius {radius} must be non-negative")
    r = np.arange(-radius, radius + 1)
    disk = r[:, None] ** 2 + r[None, :] ** 2 <= radius**2
    structure = disk if gts.ndim == 2 else disk[None]
    return ndimage.binary_dilation(gts > 0, structure=structure) if radius > 0 else gts > 0


def edge_std(images: np.ndarray, sigma: float = EDGE_SIGMA) -> np.ndarray:
    """Heuristic std: Gaussian-smoothed Sobel gradient magnitude of each image.

    The Sobel derivatives are divided by 8, so the magnitude is a gradient in intensity per
    pixel; the smoothing (``sigma`` pixels) spreads it over the pixels beside an edge, where a
    mis-placed edge makes its error. The scale is arbitrary (fit it with :func:`fit_std_scale`).
    """
    images = np.asarray(images, dtype=np.float64)
    if images.ndim not in (2, 3):
        raise ValueError(f"expected an image (H, W) or a stack (n, H, W), got shape {images.shape}")
    if sigma < 0:
        raise ValueError(f"edge smoothing sigma {sigma} must be non-negative")
    stack = images[None] if images.ndim == 2 else images
    out = np.empty_like(stack)
    for i, img in enumerate(stack):
        mag = np.hypot(ndimage.sobel(img, axis=0), ndimage.sobel(img, axis=1)) / 8
        out[i] = ndimage.gaussian_filter(mag, sigma) if sigma > 0 else mag
    return out[0] if images.ndim == 2 else out


def uncertainty_summary(
    stds: np.ndarray,
    recos: np.ndarray,
    gts: np.ndarray,
    *,
    scale: float | None = None,
    mask: np.ndarray | None = None,
) -> dict[str, object]:
    """How well a pixel-wise std predicts the actual error, over all (or the masked) pixels.

    Parameters
    ----------
    stds, recos, gts : array (n, H, W)
        Raw (uncalibrated) std, reconstructions and ground truths.
    scale : float, optional
        Calibration factor: the calibrated std is ``scale * stds``.
    mask : bool array (n, H, W), optional
        Pixels to score (e.g. :func:`support_mask`); default all.

    Returns
    -------
    dict
        ``std_error_corr``: Pearson correlation between std and absolute error (NaN when
        either is constant); ``coverage``: ``raw`` and ``calibrated`` (None without ``scale``)
        fractions of pixels within k = 1, 2, 3 std, next to the Gaussian ``expected``;
        ``scale``; ``ause``, ``ause_random``, ``ause_ratio`` (:func:`sparsification`);
        ``mean_std`` (raw), ``mean_abs_error`` and ``n_pixels``.
    """
    stds = check_array(stds, "std", ndim=3, dtype=np.float64)
    recos = check_array(recos, "reconstructions", shape=stds.shape, dtype=np.float64)
    gts = check_array(gts, "ground truths", shape=stds.shape, dtype=np.float64)
    if scale is not None and not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"calibration scale {scale} must be a positive number")
    err, std = np.abs(recos - gts), stds
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != stds.shape:
            raise ValueError(f"mask of shape {mask.shape} for images of shape {stds.shape}")
        err, std = err[mask], std[mask]
    err, std = _err_std(err, std)
    corr = float(np.corrcoef(std, err)[0, 1]) if std.std() > 0 and err.std() > 0 else float("nan")
    sp = sparsification(err, std)
    return {
        "std_error_corr": corr,
        "coverage": {
            "expected": dict(GAUSSIAN_COVERAGE),
            "raw": coverage(err, std),
            "calibrated": None if scale is None else coverage(err, scale * std),
        },
        "scale": scale,
        "ause": sp["ause"],
        "ause_random": sp["ause_random"],
        "ause_ratio": sp["ause_ratio"],
        "mean_std": float(std.mean()),
        "mean_abs_error": float(err.mean()),
        "n_pixels": int(err.size),
    }
