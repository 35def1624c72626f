"""Image quality and uncertainty metrics.

PSNR and SSIM are computed per image with ``data_range = max(gt) - min(gt)`` of the ground
truth (the paper's and dival's convention); SSIM uses scikit-image's defaults (7x7 uniform
window). Tables report mean and standard deviation over the images, with their number.

Beside these (the paper's gauge: the image as reconstructed) each image is also scored after
the best sub-pixel translation onto its ground truth (:func:`register`, the *registered*
scores). A method that estimates motion fixes the object only up to a translation common to
all views, which no data determine; the registered scores take that gauge out.

Pixel-wise uncertainty (a std map next to each reconstruction) is scored over all pixels of
all images of a split pooled together: the correlation of std and absolute error, the coverage
of calibrated intervals (overall, per width quintile, spread over images), and the
sparsification curve with its area (AUSE, Ilg et al., ECCV 2018).
What each score means and its conventions: ``docs/uncertainty.md``.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
from scipy import ndimage
from scipy.special import erfinv
from scipy.stats import spearmanr
from skimage.metrics import structural_similarity
from skimage.registration import phase_cross_correlation

from ..core.validation import check_array

__all__ = [
    "EDGE_SIGMA",
    "GAUSSIAN_COVERAGE",
    "SPARSIFICATION_FRACTIONS",
    "SUPPORT_RADIUS",
    "REFERENCE_FRACTION",
    "REFERENCE_SMOOTH_PX",
    "REGISTER_UPSAMPLE",
    "WIDTH_BINS",
    "coverage",
    "edge_std",
    "interval_scores",
    "partial_correlation",
    "psnr",
    "register",
    "reliability",
    "sparsification",
    "ssim",
    "summarize",
    "support_mask",
    "truth_support",
    "uncertainty_summary",
]

#: Probability of |N(0, s^2)| <= k s for k = 1, 2, 3.
GAUSSIAN_COVERAGE = {"1": 0.6827, "2": 0.9545, "3": 0.9973}
#: Fractions of pixels removed along a sparsification curve (0 to 0.99 in steps of 0.01).
SPARSIFICATION_FRACTIONS = np.round(np.arange(100) / 100, 2)
#: Radius in pixels (Euclidean disk) by which ``gt > 0`` is dilated to give the object's support.
SUPPORT_RADIUS = 2
#: Gaussian sigma (px) and fraction of the 99th percentile above which a reconstructed reference is object.
REFERENCE_SMOOTH_PX = 1.0
REFERENCE_FRACTION = 0.3
#: Gaussian sigma in pixels of the edge baseline (smoothed Sobel gradient magnitude).
EDGE_SIGMA = 1.0
#: Up-sampling factor of the phase correlation in :func:`register` (shifts found to 1/20 pixel).
REGISTER_UPSAMPLE = 20
#: Number of equal-count bins of the interval width in which size-stratified coverage is scored (quintiles).
WIDTH_BINS = 5


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


def register(reco: np.ndarray, gt: np.ndarray, upsample: int = REGISTER_UPSAMPLE) -> tuple[np.ndarray, np.ndarray]:
    """The image moved by the best sub-pixel translation onto the ground truth.

    The translation is the peak of the cross-correlation up-sampled ``upsample`` times
    (``skimage.registration.phase_cross_correlation`` with ``normalization=None``: on smooth
    images the phase-normalised correlation was off by up to 0.1 px in the tests); the image is moved by it in Fourier
    space (``scipy.ndimage.fourier_shift``: periodic, no interpolation smoothing). If the moved
    image is farther from ``gt`` (mean squared error) than the image itself, the image is kept
    and the translation is zero, so a registered score is never below the plain one.

    Parameters
    ----------
    reco, gt : ndarray of shape (N, M)
    upsample : int

    Returns
    -------
    ndarray of shape (N, M), float64
        The registered image.
    ndarray of shape (2,)
        The translation (rows, columns) applied to ``reco``, in pixels.
    """
    gt = check_array(gt, "ground truth", ndim=2, dtype=np.float64)
    reco = check_array(reco, "reconstruction", shape=gt.shape, dtype=np.float64)
    zero = np.zeros(2)
    if not (np.ptp(reco) > 0 and np.ptp(gt) > 0):
        return reco, zero
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # an empty (zero) image only warns; its shift is 0
        found = phase_cross_correlation(gt, reco, upsample_factor=upsample, normalization=None)[0]
    shift = np.asarray(found, dtype=np.float64)
    if not np.any(shift):
        return reco, zero
    moved = np.real(np.fft.ifft2(ndimage.fourier_shift(np.fft.fft2(reco), shift)))
    if np.mean((moved - gt) ** 2) >= np.mean((reco - gt) ** 2):
        return reco, zero
    return moved, shift


def summarize(recos: np.ndarray, gts: np.ndarray) -> dict[str, Any]:
    """PSNR and SSIM of a stack of images, as reconstructed and registered: per image, mean and std.

    Returns
    -------
    dict
        ``psnr_mean``, ``psnr_std``, ``ssim_mean``, ``ssim_std`` (std with ddof 0), ``n``, and
        the per-image values ``psnr_values``, ``ssim_values`` (lists, in the given order; the
        paired comparisons of :mod:`nanoct.evaluation.conclusions` use them): the paper's
        scores of the images as reconstructed. The same with ``_registered`` after ``psnr`` /
        ``ssim`` (``psnr_registered_mean``, ..., ``ssim_registered_values``): the scores after
        the best sub-pixel translation of each image onto its ground truth (:func:`register`);
        ``shift_values``: that translation per image (rows, columns) in pixels, and
        ``shift_mean``: the mean of its length.
    """
    if len(recos) != len(gts):
        raise ValueError(f"{len(recos)} reconstructions for {len(gts)} ground truths")
    if len(gts) == 0:
        raise ValueError("no images to evaluate (is the test split empty?)")
    p = np.array([psnr(r, g) for r, g in zip(recos, gts)])
    s = np.array([ssim(r, g) for r, g in zip(recos, gts)])
    moved = [register(r, g) for r, g in zip(recos, gts)]
    pr = np.array([psnr(m, g) for (m, _), g in zip(moved, gts)])
    sr = np.array([ssim(m, g) for (m, _), g in zip(moved, gts)])
    shifts = np.array([t for _, t in moved])
    out: dict[str, Any] = {}
    for name, values in (("psnr", p), ("ssim", s)):
        out |= {f"{name}_mean": float(values.mean()), f"{name}_std": float(values.std())}
    out |= {"n": int(len(gts)), "psnr_values": p.tolist(), "ssim_values": s.tolist()}
    for name, values in (("psnr_registered", pr), ("ssim_registered", sr)):
        out |= {f"{name}_mean": float(values.mean()), f"{name}_std": float(values.std())}
    out |= {"psnr_registered_values": pr.tolist(), "ssim_registered_values": sr.tolist()}
    out |= {"shift_values": shifts.tolist(), "shift_mean": float(np.hypot(*shifts.T).mean())}
    return out


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


def truth_support(gts: np.ndarray, radius: int = SUPPORT_RADIUS, known: np.ndarray | None = None) -> np.ndarray:
    """The object's support in a ground truth that may be a reconstruction, per image.

    A phantom (no negative value) gets :func:`support_mask`. A reference reconstructed from measured
    data (negative values: its noise) is positive over much of its background, so there the object is
    the reference smoothed by a Gaussian of ``REFERENCE_SMOOTH_PX`` above ``REFERENCE_FRACTION`` of its
    own 99th percentile, dilated as :func:`support_mask` dilates (the object of the semi-real
    evaluation, ``docs/semireal_networks.md``). ``known`` (bool, (H, W) or the stack's shape): the
    pixels where the reference is known (e.g. the field of view); the percentile is taken over
    those, and the support is not limited to them.
    """
    gts = np.asarray(gts, np.float64)
    stack = gts.reshape(-1, *gts.shape[-2:])
    where = None if known is None else np.broadcast_to(np.asarray(known, bool), gts.shape).reshape(stack.shape)
    out = []
    for i, gt in enumerate(stack):
        if gt.min() >= 0:
            out.append(support_mask(gt, radius))
            continue
        smooth = ndimage.gaussian_filter(gt, REFERENCE_SMOOTH_PX)
        level = np.percentile(gt if where is None else gt[where[i]], 99)
        out.append(support_mask(smooth > REFERENCE_FRACTION * level, radius))
    return np.stack(out).reshape(gts.shape)


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


def partial_correlation(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> float:
    """Pearson correlation of x and y given z: what x says about y beyond what z says.

    ``(r_xy - r_xz r_yz) / sqrt((1 - r_xz^2)(1 - r_yz^2))``; NaN when a variable is constant or
    x or y is a linear function of z.
    """
    x, y, z = (np.asarray(v, dtype=np.float64).ravel() for v in (x, y, z))
    if min(x.std(), y.std(), z.std()) == 0:
        return float("nan")
    r = np.corrcoef(np.stack([x, y, z]))
    den = (1 - r[0, 2] ** 2) * (1 - r[1, 2] ** 2)
    return float((r[0, 1] - r[0, 2] * r[1, 2]) / np.sqrt(den)) if den > 0 else float("nan")


def interval_scores(
    err: np.ndarray, half: np.ndarray, mask: np.ndarray | None = None, n_bins: int = WIDTH_BINS
) -> dict[str, Any]:
    """Scores of the intervals ``|err| <= half`` of stacks (n, H, W), over all or the masked pixels.

    Returns
    -------
    dict
        ``coverage`` (pooled pixels); ``mean_half_width``; ``width_error_corr``: Pearson
        correlation of the half-width with |err| (NaN if either is constant);
        ``coverage_by_width``: coverage of ``n_bins`` equal-count bins of the pixels sorted by
        half-width (smallest first; size-stratified coverage); ``image_coverage``: the
        per-image coverages' ``min``, ``max`` and ``std`` (spread over images; images without
        a masked pixel are left out).
    """
    err = np.abs(np.asarray(err, dtype=np.float64))
    half = np.asarray(half, dtype=np.float64)
    keep = np.ones(err.shape, bool) if mask is None else np.asarray(mask, bool)
    inside = err <= half
    h, e = half[keep], err[keep]
    bins = np.array_split(inside[keep][np.argsort(h, kind="stable")], n_bins)
    per_image = np.array([inside[i][keep[i]].mean() for i in range(err.shape[0]) if keep[i].any()])
    corr = float(np.corrcoef(h, e)[0, 1]) if h.std() > 0 and e.std() > 0 else float("nan")
    return {
        "coverage": float(inside[keep].mean()),
        "mean_half_width": float(h.mean()),
        "width_error_corr": corr,
        "coverage_by_width": [float(b.mean()) for b in bins],
        "image_coverage": {
            "min": float(per_image.min()),
            "max": float(per_image.max()),
            "std": float(per_image.std()),
        },
    }


def uncertainty_summary(
    stds: np.ndarray,
    recos: np.ndarray,
    gts: np.ndarray,
    *,
    half_widths: dict[str, np.ndarray] | None = None,
    baseline: np.ndarray | None = None,
    mask: np.ndarray | None = None,
) -> dict[str, object]:
    """How well a pixel-wise std predicts the actual error, over all (or the masked) pixels.

    Every score is computed on ``stds`` as given (the stored std), and the intervals on the
    ``half_widths`` given (calibrated intervals are strictly increasing functions of the std,
    so the Spearman correlation and AUSE of the std are those of every interval's width; the
    Pearson correlation of the width is reported with each interval).

    Parameters
    ----------
    stds, recos, gts : array (n, H, W)
        Std, reconstructions (the network's mean) and ground truths.
    half_widths : dict, optional
        ``{level key: half-width array (n, H, W)}`` of calibrated intervals
        (:func:`nanoct.evaluation.conformal.half_width_of`).
    baseline : array (n, H, W), optional
        Another std (the edge baseline) for the partial correlation of the std with the error
        given it.
    mask : bool array (n, H, W), optional
        Pixels to score (e.g. :func:`support_mask`); default all.

    Returns
    -------
    dict
        ``std_error_corr`` (Pearson) and ``std_error_spearman`` between std and absolute error
        (NaN when either is constant); ``partial_corr_given_baseline`` (None without
        ``baseline``); ``intervals`` = {level key: :func:`interval_scores`} (empty without
        ``half_widths``); ``ause``, ``ause_random``, ``ause_ratio`` (:func:`sparsification`);
        ``mean_std``, ``mean_abs_error`` and ``n_pixels``.
    """
    stds = check_array(stds, "std", ndim=3, dtype=np.float64)
    recos = check_array(recos, "reconstructions", shape=stds.shape, dtype=np.float64)
    gts = check_array(gts, "ground truths", shape=stds.shape, dtype=np.float64)
    keep = np.ones(stds.shape, bool) if mask is None else np.asarray(mask, dtype=bool)
    if keep.shape != stds.shape:
        raise ValueError(f"mask of shape {keep.shape} for images of shape {stds.shape}")
    err3 = np.abs(recos - gts)
    err, std = _err_std(err3[keep], stds[keep])
    varies = std.std() > 0 and err.std() > 0
    corr = float(np.corrcoef(std, err)[0, 1]) if varies else float("nan")
    rank = float(spearmanr(std, err).statistic) if varies else float("nan")
    partial = None if baseline is None else partial_correlation(std, err, np.asarray(baseline, np.float64)[keep])
    sp = sparsification(err, std)
    intervals = {k: interval_scores(err3, h, keep) for k, h in (half_widths or {}).items()}
    return {
        "std_error_corr": corr,
        "std_error_spearman": rank,
        "partial_corr_given_baseline": partial,
        "intervals": intervals,
        "ause": sp["ause"],
        "ause_random": sp["ause_random"],
        "ause_ratio": sp["ause_ratio"],
        "mean_std": float(std.mean()),
        "mean_abs_error": float(err.mean()),
        "n_pixels": int(err.size),
    }
