"""Image quality metrics with the paper's (dival's) conventions.

PSNR and SSIM are computed per image with ``data_range = max(gt) - min(gt)`` of the ground
truth; SSIM uses scikit-image's defaults (7x7 uniform window). Tables report mean and
standard deviation over the images, with their number.
"""

from __future__ import annotations

import numpy as np
from skimage.metrics import structural_similarity

from .validation import check_array

__all__ = ["GAUSSIAN_COVERAGE", "psnr", "ssim", "summarize", "uncertainty_summary"]

#: Probability of |N(0, s^2)| <= k s for k = 1, 2, 3.
GAUSSIAN_COVERAGE = {"1": 0.6827, "2": 0.9545, "3": 0.9973}


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


def summarize(recos: np.ndarray, gts: np.ndarray) -> dict[str, float | int]:
    """Mean and std of PSNR and SSIM over a stack of images.

    Returns
    -------
    dict
        ``psnr_mean``, ``psnr_std``, ``ssim_mean``, ``ssim_std`` and ``n``.
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
    }


def uncertainty_summary(stds: np.ndarray, recos: np.ndarray, gts: np.ndarray) -> dict[str, object]:
    """How well a pixel-wise std predicts the actual error, over all pixels of all images.

    Returns
    -------
    dict
        ``std_error_corr``: Pearson correlation between std and absolute error;
        ``calibration``: for k = 1, 2, 3 the fraction of pixels whose absolute error is at
        most k std, next to the Gaussian expectation (``expected``); ``mean_std`` and
        ``mean_abs_error``.
    """
    stds = check_array(stds, "std", ndim=3, dtype=np.float64)
    recos = check_array(recos, "reconstructions", shape=stds.shape, dtype=np.float64)
    gts = check_array(gts, "ground truths", shape=stds.shape, dtype=np.float64)
    if (stds < 0).any():
        raise ValueError("std contains negative values")
    err = np.abs(recos - gts).ravel()
    std = stds.ravel()
    corr = float(np.corrcoef(std, err)[0, 1]) if std.std() > 0 and err.std() > 0 else float("nan")
    coverage = {k: float(np.mean(err <= int(k) * std)) for k in GAUSSIAN_COVERAGE}
    return {
        "std_error_corr": corr,
        "calibration": {"observed": coverage, "expected": dict(GAUSSIAN_COVERAGE)},
        "mean_std": float(std.mean()),
        "mean_abs_error": float(err.mean()),
    }
