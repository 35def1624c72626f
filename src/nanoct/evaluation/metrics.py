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
from scipy.special import erf, erfinv
from skimage.metrics import structural_similarity

from ..core.validation import check_array

__all__ = [
    "EDGE_SIGMA",
    "GAUSSIAN_COVERAGE",
    "SPARSIFICATION_FRACTIONS",
    "STD_MAP_BINS",
    "STD_MAP_MIN_SLOPE",
    "STD_MAP_VALUE_BINS",
    "SUPPORT_RADIUS",
    "apply_std_map",
    "calibrated_std",
    "coverage",
    "edge_std",
    "fit_std_map",
    "fit_std_scale",
    "fit_value_std_map",
    "invert_std_map",
    "raw_std",
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
#: Number of equal-count bins of the raw std in each of which :func:`fit_std_map` fits one value.
STD_MAP_BINS = 16
#: Smallest slope of the calibration map in log(raw std) -> log(calibrated std); it keeps the map invertible.
STD_MAP_MIN_SLOPE = 0.05
#: Number of equal-count bins of the predicted value in each of which :func:`fit_value_std_map`
#: fits its own std map (quartiles of the validation means).
STD_MAP_VALUE_BINS = 4


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
        paired comparisons of :mod:`nanoct.evaluation.conclusions` use them).
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


def _bin_value(err: np.ndarray, ks: tuple[float, ...]) -> float:
    """The std c > 0 whose coverages within k c are closest to the Gaussian's (least squares over ``ks``).

    The coverage within k c only changes at c = |err_i| / k, so these values are the
    candidates; the smallest minimiser is taken. NaN when every error is zero.
    """
    positive = np.sort(err[err > 0])
    if positive.size == 0:
        return float("nan")
    n_zero = err.size - positive.size
    ratios = {k: positive / k for k in ks}
    candidates = np.unique(np.concatenate(list(ratios.values())))
    loss = np.zeros(candidates.size)
    for k, r in ratios.items():
        covered = (n_zero + np.searchsorted(r, candidates, side="right")) / err.size
        loss += (covered - erf(k / np.sqrt(2))) ** 2
    return float(candidates[int(np.argmin(loss))])


def fit_std_map(
    err: np.ndarray, std: np.ndarray, n_bins: int = STD_MAP_BINS, ks: tuple[float, ...] = (1, 2, 3)
) -> dict[str, list[float]]:
    """A strictly increasing map from raw std to calibrated std, fitted bin by bin.

    The pixels with a positive std are sorted by std and split into ``n_bins`` bins of equal
    count (bins whose median std is equal are merged). In each bin one calibrated std c is fitted
    so that the coverages within k c for k in ``ks`` are as close as possible to the Gaussian
    levels (:data:`GAUSSIAN_COVERAGE`), in least squares; its knot is (median raw std of the
    bin, c). The knots' values are then made increasing with at least the slope
    :data:`STD_MAP_MIN_SLOPE` in log-log from each knot to the next (a running maximum with a
    floor on the slope), so the map keeps the order of the std and can be inverted
    (:func:`invert_std_map`). Unlike one factor (:func:`fit_std_scale`) the map can widen the
    large std more than the small ones, where the error grows faster than linearly with the std.

    Parameters
    ----------
    err, std : array
        Errors (their absolute value is used) and raw std, any equal shapes.
    n_bins : int
        Number of bins (knots before merging).
    ks : tuple of float
        Multiples of the std whose coverage is fitted.

    Returns
    -------
    dict
        ``std``: the knots' raw std, ``calibrated``: their calibrated std (lists of floats,
        both strictly increasing); :func:`apply_std_map` interpolates between them.

    Raises
    ------
    ValueError
        Fewer pixels with a positive std than bins, bad ``n_bins`` or ``ks``, or no bin with a
        non-zero error.
    """
    err, std = _err_std(err, std)
    if n_bins < 1 or not ks or min(ks) <= 0:
        raise ValueError(f"need n_bins >= 1 and positive multiples ks, got n_bins={n_bins}, ks={ks}")
    keep = std > 0
    order = np.argsort(std[keep], kind="stable")
    s_sorted, e_sorted = std[keep][order], err[keep][order]
    if s_sorted.size < n_bins:
        raise ValueError(f"{s_sorted.size} pixels with a positive std cannot fill {n_bins} bins")
    groups: list[tuple[float, list[np.ndarray]]] = []
    for s_bin, e_bin in zip(np.array_split(s_sorted, n_bins), np.array_split(e_sorted, n_bins)):
        median = float(np.median(s_bin))
        if groups and median <= groups[-1][0]:
            groups[-1][1].append(e_bin)  # the same median std as the bin before: one knot
        else:
            groups.append((median, [e_bin]))
    knots = [(x, _bin_value(np.concatenate(e), ks)) for x, e in groups]
    knots = [(x, y) for x, y in knots if np.isfinite(y)]
    if not knots:
        raise ValueError("every error is zero; there is no std to calibrate")
    lx, ly = np.log([x for x, _ in knots]), np.log([y for _, y in knots])
    for i in range(1, ly.size):
        ly[i] = max(ly[i], ly[i - 1] + STD_MAP_MIN_SLOPE * (lx[i] - lx[i - 1]))
    return {"std": np.exp(lx).tolist(), "calibrated": np.exp(ly).tolist()}


def _map_knots(std_map: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """The log knots (x, y) of a map, checked: positive, finite, strictly increasing, of equal length."""
    try:
        x, y = (np.asarray(std_map[key], dtype=np.float64) for key in ("std", "calibrated"))
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"a std map needs lists 'std' and 'calibrated' of numbers, got {std_map!r}") from exc
    ok = x.ndim == 1 and x.shape == y.shape and x.size >= 1
    ok = ok and bool(np.isfinite(x).all() and np.isfinite(y).all() and (x > 0).all() and (y > 0).all())
    if not ok or (np.diff(x) <= 0).any() or (np.diff(y) <= 0).any():
        raise ValueError(f"a std map needs strictly increasing positive knots of equal length, got {std_map!r}")
    return np.log(x), np.log(y)


def _loglog(values: np.ndarray, lx: np.ndarray, ly: np.ndarray) -> np.ndarray:
    """Piecewise-linear interpolation in log-log through (lx, ly), extended by the end segments; 0 maps to 0."""
    v = np.asarray(values, dtype=np.float64)
    if not np.isfinite(v).all() or (v < 0).any():
        raise ValueError("the std to map contains negative, NaN or infinite values")
    out = np.zeros_like(v)
    pos = v > 0
    lv = np.log(v[pos])
    if lx.size == 1:  # one knot: proportional
        lo = hi = 1.0
    else:
        lo, hi = (ly[1] - ly[0]) / (lx[1] - lx[0]), (ly[-1] - ly[-2]) / (lx[-1] - lx[-2])
    mapped = np.interp(lv, lx, ly)
    mapped = np.where(lv < lx[0], ly[0] + lo * (lv - lx[0]), mapped)
    mapped = np.where(lv > lx[-1], ly[-1] + hi * (lv - lx[-1]), mapped)
    out[pos] = np.exp(mapped)
    return out


def fit_value_std_map(
    err: np.ndarray,
    std: np.ndarray,
    values: np.ndarray,
    n_value_bins: int = STD_MAP_VALUE_BINS,
    n_bins: int = STD_MAP_BINS,
    ks: tuple[float, ...] = (1, 2, 3),
) -> dict[str, Any]:
    """A calibration map of the std conditioned on the predicted value: one :func:`fit_std_map` per value bin.

    The pixels are split into ``n_value_bins`` equal-count bins of ``values`` (the network's
    mean at each pixel) and a map from raw to calibrated std is fitted in each. The error of
    a pixel depends on what the network predicts there, not only on its std: on the empty
    background most errors are tiny but a few are not, which makes the errors of one std bin a
    mixture with heavier tails than a Gaussian; conditioning on the value separates the parts
    of the mixture (``docs/uncertainty.md``). A bin with too few pixels, or without a non-zero
    error, is merged with the next one (the last with the one before).

    Parameters
    ----------
    err, std, values : array
        Errors (their absolute value is used), raw std and predicted values, equal shapes.
    n_value_bins : int
        Number of value bins (before merging); 1 gives one map for all pixels.
    n_bins, ks
        As for :func:`fit_std_map`, in each value bin.

    Returns
    -------
    dict
        ``value_edges``: the inner bin edges of the value (increasing list of floats; a value
        ``v`` lies in bin ``searchsorted(value_edges, v, side="right")``), ``maps``: one
        :func:`fit_std_map` result per bin. :func:`apply_std_map` with ``values`` applies it.

    Raises
    ------
    ValueError
        Bad ``n_value_bins``, unequal shapes, or no bin that can be fitted at all.
    """
    err, std = _err_std(err, std)
    values = np.asarray(values, dtype=np.float64).ravel()
    if values.shape != err.shape or not np.isfinite(values).all():
        raise ValueError(f"need {err.size} finite predicted values, got {values.size} (or NaN/inf among them)")
    if n_value_bins < 1:
        raise ValueError(f"need n_value_bins >= 1, got {n_value_bins}")
    edges = np.unique(np.quantile(values, np.arange(1, n_value_bins) / n_value_bins))
    which = np.searchsorted(edges, values, side="right")
    kept: list[float] = []  # upper edges of the fitted bins but the last
    maps: list[dict[str, list[float]]] = []
    group = np.zeros(values.size, dtype=bool)  # this bin plus those merged into it
    previous = group
    for j in range(edges.size + 1):
        group = group | (which == j)
        try:
            maps.append(fit_std_map(err[group], std[group], n_bins=n_bins, ks=ks))
        except ValueError:
            if j < edges.size:
                continue  # merged with the next bin
            if not maps:
                raise
            group = previous | group  # the last bin: merged with the one before
            maps[-1] = fit_std_map(err[group], std[group], n_bins=n_bins, ks=ks)
            kept.pop()
            break
        if j < edges.size:
            kept.append(float(edges[j]))
        previous, group = group, np.zeros(values.size, dtype=bool)
    return {"value_edges": kept, "maps": maps}


def _value_bins(std: np.ndarray, std_map: dict[str, Any], values: np.ndarray | None) -> tuple[np.ndarray, list]:
    """Bin index per pixel and the maps of a value-binned map (checked)."""
    try:
        edges = np.asarray(std_map["value_edges"], dtype=np.float64)
        maps = list(std_map["maps"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"a value-binned std map needs 'value_edges' and 'maps', got {std_map!r}") from exc
    if edges.ndim != 1 or len(maps) != edges.size + 1 or (np.diff(edges) <= 0).any():
        raise ValueError(f"a value-binned std map needs increasing edges and one map more than edges, got {std_map!r}")
    if values is None:
        raise ValueError("this std map is conditioned on the predicted value: pass the reconstruction as values")
    values = np.asarray(values, dtype=np.float64)
    if values.shape != np.shape(std):
        raise ValueError(f"predicted values of shape {values.shape} for a std of shape {np.shape(std)}")
    return np.searchsorted(edges, values, side="right"), maps


def _map_each(std: np.ndarray, std_map: dict[str, Any], values: np.ndarray | None, inverse: bool) -> np.ndarray:
    """Apply (or invert) a plain or value-binned std map."""
    if "maps" not in std_map:
        lx, ly = _map_knots(std_map)
        return _loglog(std, ly, lx) if inverse else _loglog(std, lx, ly)
    which, maps = _value_bins(std, std_map, values)
    std = np.asarray(std, dtype=np.float64)
    out = np.zeros_like(std)
    for j, one in enumerate(maps):
        sel = which == j
        out[sel] = _map_each(std[sel], one, None, inverse)
    return out


def apply_std_map(std: np.ndarray, std_map: dict[str, Any], values: np.ndarray | None = None) -> np.ndarray:
    """Calibrated std of a raw std under a :func:`fit_std_map` or :func:`fit_value_std_map` map (float64).

    Piecewise linear in log(raw std) - log(calibrated std) between the knots, continued
    linearly (in log-log) beyond the end knots with the slopes of the end segments (a single
    knot: proportional); a zero std stays zero. Strictly increasing. A value-binned map applies
    the map of each pixel's bin of ``values`` (the predicted values, same shape as ``std``).

    Raises
    ------
    ValueError
        A malformed map, a negative or non-finite std, or a value-binned map without ``values``.
    """
    return _map_each(std, std_map, values, inverse=False)


def invert_std_map(calibrated: np.ndarray, std_map: dict[str, Any], values: np.ndarray | None = None) -> np.ndarray:
    """Raw std of a calibrated std: the inverse of :func:`apply_std_map` (float64, same shape).

    Raises
    ------
    ValueError
        A malformed map, a negative or non-finite std, or a value-binned map without ``values``.
    """
    return _map_each(calibrated, std_map, values, inverse=True)


def calibrated_std(raw: np.ndarray, calibration: dict[str, Any], values: np.ndarray | None = None) -> np.ndarray | None:
    """The calibrated std of a raw std under a stored calibration (:mod:`nanoct.learn.calibration`).

    Its ``std_map`` if it has one (:func:`apply_std_map`; ``values``, the reconstruction, for a
    value-binned map), else its one factor ``scale`` (a result calibrated by one factor); None for a
    calibration with neither (an empty dict: not calibrated).
    """
    if calibration.get("std_map"):
        return apply_std_map(raw, calibration["std_map"], values)
    if calibration.get("scale"):
        return np.asarray(raw, dtype=np.float64) * calibration["scale"]
    return None


def raw_std(stored: np.ndarray, calibration: dict[str, Any], values: np.ndarray | None = None) -> np.ndarray:
    """The raw std behind a stored one: the inverse of :func:`calibrated_std` (unchanged if not calibrated)."""
    if calibration.get("std_map"):
        return invert_std_map(stored, calibration["std_map"], values).astype(np.float32)
    return stored / calibration["scale"] if calibration.get("scale") else stored


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
    std_map: dict[str, Any] | None = None,
    mask: np.ndarray | None = None,
) -> dict[str, object]:
    """How well a pixel-wise std predicts the actual error, over all (or the masked) pixels.

    Parameters
    ----------
    stds, recos, gts : array (n, H, W)
        Raw (uncalibrated) std, reconstructions and ground truths.
    scale : float, optional
        One-factor calibration (:func:`fit_std_scale`): the scaled std is ``scale * stds``.
    std_map : dict, optional
        Calibration map (:func:`fit_std_map` or :func:`fit_value_std_map`): the calibrated std is
        ``apply_std_map(stds, std_map, recos)``.
    mask : bool array (n, H, W), optional
        Pixels to score (e.g. :func:`support_mask`); default all.

    Returns
    -------
    dict
        ``std_error_corr``: Pearson correlation between std and absolute error (NaN when
        either is constant); ``coverage``: fractions of pixels within k = 1, 2, 3 std of the
        ``raw``, the ``scaled`` (``scale * stds``; None without ``scale``) and the ``calibrated``
        std (the map's, else the scaled std's; None without either), next to the Gaussian
        ``expected``; ``calibration``: what ``calibrated`` used (``"map"``, ``"scale"`` or None);
        ``scale``; ``ause``, ``ause_random``, ``ause_ratio`` (:func:`sparsification`);
        ``mean_std`` (raw), ``mean_abs_error`` and ``n_pixels``.
    """
    stds = check_array(stds, "std", ndim=3, dtype=np.float64)
    recos = check_array(recos, "reconstructions", shape=stds.shape, dtype=np.float64)
    gts = check_array(gts, "ground truths", shape=stds.shape, dtype=np.float64)
    if scale is not None and not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"calibration scale {scale} must be a positive number")
    err, std, values = np.abs(recos - gts), stds, recos
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != stds.shape:
            raise ValueError(f"mask of shape {mask.shape} for images of shape {stds.shape}")
        err, std, values = err[mask], std[mask], values[mask]
    err, std = _err_std(err, std)
    values = values.ravel()
    corr = float(np.corrcoef(std, err)[0, 1]) if std.std() > 0 and err.std() > 0 else float("nan")
    sp = sparsification(err, std)
    scaled = None if scale is None else coverage(err, scale * std)
    calibrated = scaled if std_map is None else coverage(err, apply_std_map(std, std_map, values))
    return {
        "std_error_corr": corr,
        "coverage": {
            "expected": dict(GAUSSIAN_COVERAGE),
            "raw": coverage(err, std),
            "scaled": scaled,
            "calibrated": calibrated,
        },
        "calibration": "map" if std_map is not None else None if scale is None else "scale",
        "scale": scale,
        "ause": sp["ause"],
        "ause_random": sp["ause_random"],
        "ause_ratio": sp["ause_ratio"],
        "mean_std": float(std.mean()),
        "mean_abs_error": float(err.mean()),
        "n_pixels": int(err.size),
    }
