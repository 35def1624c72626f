"""Intervals ``mean +- multiplier * std`` calibrated by split conformal prediction and risk control.

A sampling network's std ranks the pixels by how uncertain they are; its scale is rarely right.
The interval of level ``1 - alpha`` keeps that ranking: its half-width is one multiplier times
the std, fitted on validation outputs in two ways.

* **Split conformal** (:func:`conformal_multiplier`): the ``ceil((n + 1)(1 - alpha))``-th
  smallest score ``|error| / std`` of the n validation pixels. On exchangeable pixels a new
  pixel is covered with probability at least ``1 - alpha`` (and less than
  ``1 - alpha + 1 / (n + 1)`` without ties).
* **Risk control** (Angelopoulos et al., "Image-to-image regression with distribution-free
  uncertainty quantification", ICML 2022; :func:`rcps_multiplier`): the loss of an image is the
  fraction of its pixels outside the interval; with probability at least ``1 - delta`` over the
  validation images, the expected loss of a new image is at most ``alpha``, by the
  Hoeffding-Bentkus upper confidence bound (:func:`hb_upper_bound`) of the mean loss of the n
  validation images. Images, not pixels, are the exchangeable units here, so the guarantee holds
  although the pixels of one image are dependent.

:func:`guaranteed_coverage` states the guarantee a given multiplier comes with: the coverage
that holds with probability ``1 - delta`` (one minus the bound on its loss); :func:`half_width` the
half-width of a stored prediction's interval from the calibration recorded with it.
"""

from __future__ import annotations

import base64
import math
from typing import Any

import numpy as np
from scipy import ndimage
from scipy.optimize import brentq
from scipy.stats import binom

from ..core.errors import NanoctError
from .metrics import support_mask

__all__ = [
    "DEFAULT_DELTA",
    "DEFAULT_LEVELS",
    "OBJECT_WIDTH_BINS",
    "decode_mask",
    "encode_mask",
    "fit_footprint",
    "fit_group_cuts",
    "fit_group_intervals",
    "footprint_fits",
    "footprint_outside",
    "mean_noise_ratio",
    "FOOTPRINT_NOISY_MEAN",
    "FOOTPRINT_TOLERANCE",
    "object_region",
    "fit_support_threshold",
    "group_guaranteed_coverage",
    "group_labels",
    "support_image",
    "support_of",
    "WIDTH_MAP_BINS",
    "WIDTH_MAP_MAX_END_SLOPE",
    "WIDTH_MAP_MIN_SLOPE",
    "apply_width_map",
    "conformal_multiplier",
    "fit_width_map",
    "half_width",
    "half_width_of",
    "guaranteed_coverage",
    "hb_upper_bound",
    "image_miscoverage",
    "level_key",
    "rcps_multiplier",
    "scores",
]

#: Interval levels (nominal coverage) fitted by default.
DEFAULT_LEVELS = (0.68, 0.90, 0.95)
#: Probability that the risk-control guarantee fails (the paper's default).
DEFAULT_DELTA = 0.1
#: Equal-count bins of the std in which :func:`fit_width_map` takes the quantile of |err|.
WIDTH_MAP_BINS = 20
#: Equal-count std bins of the object's support in the group-conditional calibration (its fifths).
OBJECT_WIDTH_BINS = 5
#: Smallest slope of a width map in log(std) -> log(width); it keeps the map strictly increasing.
WIDTH_MAP_MIN_SLOPE = 0.05
#: Largest slope of a width map beyond its end knots (log-log): past the largest bin median the width
#: grows at most in proportion to the std. The top bin's quantile can jump (on the tiny study's Dremel +
#: CiUNetRes the background map's last segment has slope 16.5), and continuing that slope gave pixels of
#: twice the last knot's std intervals 10^5 times wider (a mean 95 % half-width of 228 on a 0..1 image).
WIDTH_MAP_MAX_END_SLOPE = 1.0
#: Fraction of an image's prediction-time support (on its known pixels) that may lie outside the
#: calibration's footprint before the image is flagged as not of the calibrating scan
#: (:func:`footprint_outside`). On the I13 scan's 67 slices (``benchmarks/semireal_networks.py``) 66 have
#: 0 % (slice 0, nearly empty and no pair's source, 18-21 %); moved by 3 px, 22 slices exceed it.
FOOTPRINT_TOLERANCE = 0.02
#: Ratio of a mean's sampling noise to its level (:func:`mean_noise_ratio`) above which the footprint check is
#: not made on an image: its support, relative to that level, is then speckle of the noise. On the I13 scan's
#: binned slices with a CiUNetRes predicting in tiles: 4 independent draws 0.23-0.30 (7 of 10 slices flagged,
#: none with 4 antithetic or 100 independent draws), its faint measured pairs 0.23-0.34, its bright ones at
#: most 0.05, 100 independent draws 0.07-0.12.
FOOTPRINT_NOISY_MEAN = 0.15


def level_key(level: float) -> str:
    """The key of a level in stored calibrations: ``0.9`` -> ``"0.9"``.

    Raises
    ------
    ValueError
        If ``level`` is not strictly between 0 and 1.
    """
    if not 0 < float(level) < 1:
        raise ValueError(f"interval level {level} must lie strictly between 0 and 1 (e.g. 0.9 for 90 %)")
    return f"{float(level):g}"


def scores(err: np.ndarray, std: np.ndarray) -> np.ndarray:
    """Conformity scores ``|err| / std`` (float64, same shape) with 0/0 = 0 and x/0 = inf.

    Raises
    ------
    ValueError
        Different shapes, non-finite values or a negative std.
    """
    err = np.abs(np.asarray(err, dtype=np.float64))
    std = np.asarray(std, dtype=np.float64)
    if err.shape != std.shape:
        raise ValueError(f"errors of shape {err.shape} for a std of shape {std.shape}")
    if not (np.isfinite(err).all() and np.isfinite(std).all()):
        raise ValueError("the errors or the std contain NaN or infinite values")
    if (std < 0).any():
        raise ValueError("the std contains negative values")
    with np.errstate(divide="ignore", invalid="ignore"):
        s = err / std
    s[(std == 0) & (err == 0)] = 0.0
    return s


def conformal_multiplier(err: np.ndarray, std: np.ndarray, level: float) -> float:
    """Split-conformal multiplier: the ``ceil((n + 1) level)``-th smallest of the n scores ``|err| / std``.

    Raises
    ------
    ValueError
        If ``level`` is outside (0, 1), there are too few pixels for it (``(n + 1) level > n``),
        or the quantile is infinite (the std is zero where the error is not) or zero.
    """
    level_key(level)
    s = scores(err, std).ravel()
    k = math.ceil((s.size + 1) * level)
    if k > s.size:
        raise ValueError(f"{s.size} calibration pixels are too few for a {level:.1%} interval")
    q = float(np.partition(s, k - 1)[k - 1])
    if not np.isfinite(q) or q <= 0:
        raise ValueError(
            f"no finite positive multiplier of the std covers {level:.1%} of the pixels (quantile {q}); "
            "the std is zero where the error is not, or the error is zero almost everywhere"
        )
    return q


def fit_width_map(
    err: np.ndarray, std: np.ndarray, level: float, n_bins: int = WIDTH_MAP_BINS, min_slope: float = WIDTH_MAP_MIN_SLOPE
) -> dict[str, list[float]]:
    """A strictly increasing map from std to the ``level`` quantile of |err| (monotone quantile regression on the std).

    The pixels are sorted by std and split into ``n_bins`` equal-count bins; the knot of a bin is
    (median std, ``level`` quantile of its |err|). The knots' widths are made increasing: each is
    at least the previous one times ``(x_b / x_{b-1})**min_slope`` (a slope of at least
    ``min_slope`` in log-log), so the map is strictly increasing and ranks the pixels exactly as
    the std does. Applied by :func:`apply_width_map`.

    Raises
    ------
    ValueError
        If the std has fewer than two distinct positive bin medians, or every error is zero.
    """
    err = np.abs(np.asarray(err, dtype=np.float64)).ravel()
    std = np.asarray(std, dtype=np.float64).ravel()
    scores(err, std)  # checks shapes and values
    pos = std > 0
    e, s_ = err[pos], std[pos]
    if s_.size < 2:
        raise ValueError(f"{s_.size} pixels with a positive std are too few for a width map")
    bins = np.array_split(np.argsort(s_, kind="stable"), min(n_bins, max(s_.size // 50, 1)))
    x = np.array([np.median(s_[b]) for b in bins if b.size])
    y = np.array([np.quantile(e[b], level) for b in bins if b.size])
    keep = np.r_[True, np.diff(x) > 0]  # equal medians (ties): keep the first
    x, y = x[keep], np.maximum.accumulate(y)[keep]
    if x.size < 2 or y[-1] <= 0:
        raise ValueError("the std takes fewer than two distinct values, or every error is zero: no width map")
    y = np.maximum(y, y[y > 0].min())
    for j in range(1, x.size):
        y[j] = max(y[j], y[j - 1] * (x[j] / x[j - 1]) ** min_slope)
    return {"std": x.tolist(), "width": y.tolist()}


def apply_width_map(std: np.ndarray, width_map: dict[str, list[float]]) -> np.ndarray:
    """The width map of :func:`fit_width_map` at ``std`` (float64): piecewise linear in log-log between
    the knots, continued beyond them with the end segments' slopes clipped to
    [:data:`WIDTH_MAP_MIN_SLOPE`, :data:`WIDTH_MAP_MAX_END_SLOPE`] (so it stays strictly increasing and
    grows no faster than the std past the knots); a zero std gives zero."""
    lx, ly = np.log(width_map["std"]), np.log(width_map["width"])
    std = np.asarray(std, dtype=np.float64)
    pos = std > 0
    ls = np.log(np.where(pos, std, 1.0))
    out = np.interp(ls, lx, ly)
    first, last = (ly[1] - ly[0]) / (lx[1] - lx[0]), (ly[-1] - ly[-2]) / (lx[-1] - lx[-2])
    first, last = np.clip([first, last], WIDTH_MAP_MIN_SLOPE, WIDTH_MAP_MAX_END_SLOPE)
    out = np.where(ls < lx[0], ly[0] + first * (ls - lx[0]), out)
    out = np.where(ls > lx[-1], ly[-1] + last * (ls - lx[-1]), out)
    return np.where(pos, np.exp(out), 0.0)


def half_width_of(
    std: np.ndarray, entry: dict[str, Any], multiplier: str = "multiplier", image: np.ndarray | None = None
) -> np.ndarray:
    """Half-width of a calibrated interval at ``std`` (float64, the shape of ``std``).

    With ``entry["groups"]`` (a group-conditional calibration, :func:`fit_group_intervals`): each
    pixel's group (:func:`group_labels`, from the std, or from ``image`` = the prediction's mean
    where the support is defined on the mean), and the group's multiplier (``multiplier`` =
    ``"multiplier"``: split conformal; ``"rcps_multiplier"``: risk control) times its region's
    (object or background) width map. An image of another shape than the calibration's footprint has
    all its background in the group inside it, with the larger of the two background groups'
    multipliers. Otherwise ``entry[multiplier] * g(std)``, g = ``entry["map"]``
    (:func:`apply_width_map`) where the entry has one, else the identity.
    """
    groups = entry.get("groups")
    if groups:
        labels = group_labels(std, groups, image)
        multipliers = np.asarray(groups[f"{multiplier}s"], dtype=np.float64)
        n_bins = len(groups["cuts"]) + 1
        if groups.get("footprint") and not footprint_fits(groups, np.shape(std)):
            # all the background is in the group inside the footprint: take the wider of the two
            multipliers[n_bins + 1] = max(multipliers[0], multipliers[n_bins + 1])
        q = multipliers[labels]
        maps = groups["maps"]
        on_object = object_region(labels, n_bins)
        return q * np.where(on_object, apply_width_map(std, maps[1]), apply_width_map(std, maps[0]))
    base = apply_width_map(std, entry["map"]) if entry.get("map") else np.asarray(std, dtype=np.float64)
    return float(entry[multiplier]) * base


def half_width(
    params: dict[str, Any], std: np.ndarray, level: float, guaranteed: bool = False, mean: np.ndarray | None = None
) -> np.ndarray:
    """The half-width of the interval of ``level`` of a prediction (float64, the shape of ``std``).

    ``params``: the prediction's stored parameters (with its ``calibration``); ``std``: its stored
    std, one image (H, W) or a stack (n, H, W) (the support of a group-conditional calibration is
    found per image); ``mean``: its stored mean, needed only where the calibration's support is
    defined on the mean. ``guaranteed`` takes the risk-controlling multipliers (coverage
    guaranteed with probability ``1 - delta``) instead of the split-conformal ones
    (:func:`nanoct.evaluation.conformal.half_width_of`).

    Raises
    ------
    NanoctError
        If the prediction has no calibration, was not calibrated at ``level``, (``guaranteed``) the
        validation split was too small for a guarantee at that level, or the support needs the mean.
    """
    cal = params.get("calibration") or {}
    levels = cal.get("levels")
    if not levels:
        raise NanoctError("this prediction has no interval calibration; predict it again without --no-calibrate")
    key = level_key(level)
    if key not in levels:
        raise NanoctError(
            f"no interval of level {key} was calibrated (levels: {', '.join(levels)}); predict again with "
            f"--levels including {key}"
        )
    which = "rcps_multiplier" if guaranteed else "multiplier"
    entry = levels[key]
    missing = None in entry["groups"]["rcps_multipliers"] if guaranteed and "groups" in entry else entry[which] is None
    if missing:
        raise NanoctError(
            f"the validation split ({cal.get('n_images')} images) is too small to guarantee "
            f"{float(key):.0%} coverage with probability {1 - cal['delta']:.0%}; "
            "leave out --guaranteed or choose a lower level"
        )
    try:
        return half_width_of(std, entry, which, image=mean)
    except ValueError as exc:
        raise NanoctError(f"cannot compute the interval: {exc}") from exc


def image_miscoverage(
    err: np.ndarray, std: np.ndarray, multipliers: np.ndarray, mask: np.ndarray | None = None
) -> np.ndarray:
    """Fraction of each image's pixels with ``|err| > multiplier * std``: shape (n_images, n_multipliers).

    ``err`` and ``std`` are stacks (n, H, W) (or (n, P) pixels per image). With ``mask`` (same
    shape) only the masked pixels count, and images without a masked pixel are left out.
    """
    s = scores(err, std)
    s = s.reshape(s.shape[0], -1)
    keep = np.ones(s.shape, bool) if mask is None else np.asarray(mask, bool).reshape(s.shape)
    rows = [np.sort(row[k]) for row, k in zip(s, keep) if k.any()]
    lam = np.asarray(multipliers, dtype=np.float64).ravel()
    if not rows:
        return np.empty((0, lam.size))
    return np.stack([1.0 - np.searchsorted(row, lam, side="right") / row.size for row in rows])


def hb_upper_bound(risk: float, n: int, delta: float) -> float:
    """Hoeffding-Bentkus upper confidence bound of the mean of losses in [0, 1].

    With probability at least ``1 - delta`` the expected loss is at most the returned value,
    given the empirical mean ``risk`` of ``n`` i.i.d. losses (Bates et al., "Distribution-free,
    risk-controlling prediction sets", JACM 2021, the HB bound; the code of ``im2im-uq``).
    """
    if n < 1:
        raise ValueError(f"{n} calibration images: at least one is needed")
    if not 0 < delta < 1:
        raise ValueError(f"delta {delta} must lie strictly between 0 and 1")
    risk = float(np.clip(risk, 0.0, 1.0))

    def log_tail(mu: float) -> float:
        y = min(risk, mu)
        kl = (y * math.log(y / mu) if y > 0 else 0.0) + ((1 - y) * math.log((1 - y) / (1 - mu)) if y < 1 else 0.0)
        hoeffding = -n * kl
        bentkus = math.log(max(float(binom.cdf(math.floor(n * risk), n, mu)), 1e-300)) + 1
        return min(hoeffding, bentkus) - math.log(delta)

    top = 1 - 1e-10
    if log_tail(top) > 0:
        return 1.0
    low = max(risk, 1e-12)
    if log_tail(low) <= 0:
        return low
    return float(brentq(log_tail, low, top, maxiter=200))


def guaranteed_coverage(
    err: np.ndarray, std: np.ndarray, multiplier: float, delta: float = DEFAULT_DELTA, mask: np.ndarray | None = None
) -> float:
    """Per-image pixel coverage that ``multiplier * std`` keeps with probability ``1 - delta``.

    One minus :func:`hb_upper_bound` of the mean :func:`image_miscoverage` of the images of
    ``err`` / ``std`` (stacks (n, H, W)); with ``mask``, of their masked pixels.
    """
    losses = image_miscoverage(err, std, [multiplier], mask)[:, 0]
    return 1.0 - hb_upper_bound(float(losses.mean()), losses.size, delta)


def rcps_multiplier(
    err: np.ndarray,
    std: np.ndarray,
    level: float,
    delta: float = DEFAULT_DELTA,
    n_grid: int = 2000,
    mask: np.ndarray | None = None,
) -> float:
    """Smallest multiplier whose intervals cover ``level`` of a new image's pixels with probability ``1 - delta``.

    The candidates are ``n_grid`` quantiles of the pooled scores ``|err| / std`` above the
    ``level`` quantile, and their maximum; the loss of an image (:func:`image_miscoverage`) does not
    increase with the multiplier, so the smallest candidate whose Hoeffding-Bentkus bound is at
    most ``1 - level`` is the RCPS choice (Angelopoulos et al. 2022). With ``mask`` the loss of an
    image is that of its masked pixels (a group's guarantee), over the images that have some.

    Raises
    ------
    ValueError
        If even the largest finite score gives no guarantee (too few images for ``level`` and
        ``delta``), or the scores are not finite.
    """
    level_key(level)
    s = scores(err, std)
    s = s if mask is None else s[np.asarray(mask, bool)]
    finite = s[np.isfinite(s)]
    if finite.size == 0:
        raise ValueError("the std is zero on every pixel with an error: no multiplier covers anything")
    grid = np.unique(np.quantile(finite, np.linspace(level, 1.0, n_grid), method="inverted_cdf"))
    losses = image_miscoverage(err, std, grid, mask)
    n, risk = losses.shape[0], losses.mean(axis=0)

    def ok(j: int) -> bool:
        return hb_upper_bound(float(risk[j]), n, delta) <= 1 - level

    if not ok(grid.size - 1):
        raise ValueError(
            f"{n} calibration images are too few to guarantee {level:.1%} coverage with probability "
            f"{1 - delta:.0%} (the Hoeffding-Bentkus bound is above {1 - level:.3f} for every multiplier)"
        )
    lo, hi = -1, grid.size - 1  # ok(hi) holds; the risk does not increase along the grid: bisect
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if ok(mid) else (mid, hi)
    return float(grid[hi])


def support_of(image: np.ndarray, threshold: float, radius: int, fill: bool = False) -> np.ndarray:
    """The object's support as seen at prediction time: ``image > threshold`` (with ``fill``, its holes
    filled, :func:`scipy.ndimage.binary_fill_holes`, per image) dilated by a disk of ``radius`` px.

    ``image`` is one image (H, W) or a stack (n, H, W) of what the prediction delivers (its std or
    its mean); no ground truth is involved.
    """
    above = np.asarray(image) > threshold
    if fill:
        above = np.stack([ndimage.binary_fill_holes(a) for a in above.reshape(-1, *above.shape[-2:])])
        above = above.reshape(np.shape(image))
    return support_mask(above, radius)


def fit_support_threshold(
    image: np.ndarray,
    truth_support: np.ndarray,
    radius: int,
    n_candidates: int = 64,
    fill: bool = False,
    mask: np.ndarray | None = None,
) -> float:
    """The threshold of :func:`support_of` whose support best matches ``truth_support`` (largest IoU).

    Candidates: ``n_candidates`` quantiles of ``image`` between its 50th and 99.5th percentiles.
    ``mask`` (bool, broadcast to ``image``): the pixels where the truth is known (e.g. the field of view
    of a measured reference); the quantiles and the IoU are taken over those only. Default: all.

    Raises
    ------
    ValueError
        If ``truth_support`` is empty or ``image`` is constant (on ``mask``).
    """
    image = np.asarray(image, np.float64)
    where = np.broadcast_to(np.asarray(True if mask is None else mask, bool), image.shape)
    truth = np.asarray(truth_support, bool) & where
    if not truth.any() or image[where].min() == image[where].max():
        raise ValueError("no support to match: the truth's support is empty or the image is constant")
    best, best_iou = float("nan"), -1.0
    for t in np.unique(np.quantile(image[where], np.linspace(0.5, 0.995, n_candidates))):
        s = support_of(image, float(t), radius, fill) & where
        iou = float((s & truth).sum() / (s | truth).sum())
        if iou > best_iou:
            best, best_iou = float(t), iou
    return best


def support_image(source: str, std: np.ndarray, mean: np.ndarray | None) -> np.ndarray:
    """What a support rule thresholds (:func:`support_of`): the std, the mean, or (``"relative"``) the mean
    divided by each image's own 99th percentile of ``|mean|``, so that the rule finds a faint object as
    it finds a bright one (slices of a measured sample differ in content by orders of magnitude).

    Raises
    ------
    ValueError
        For another source, or a source on the mean without ``mean``.
    """
    if source == "std":
        return np.asarray(std, np.float64)
    if source not in ("mean", "relative"):
        raise ValueError(f"support source {source!r} must be std, mean or relative")
    if mean is None:
        raise ValueError("this calibration's support is defined on the prediction's mean: pass the mean")
    mean = np.asarray(mean, np.float64)
    if source == "mean":
        return mean
    scale = np.percentile(np.abs(mean).reshape(-1, *mean.shape[-2:]), 99, axis=(1, 2)).reshape(mean.shape[:-2])
    return mean / np.maximum(scale, np.finfo(np.float64).tiny)[..., None, None]


def encode_mask(mask: np.ndarray) -> dict[str, Any]:
    """A boolean image as JSON-friendly data: its shape and its bits (:func:`numpy.packbits`, base64)."""
    mask = np.asarray(mask, bool)
    return {"shape": list(mask.shape), "bits": base64.b64encode(np.packbits(mask).tobytes()).decode("ascii")}


def decode_mask(data: dict[str, Any]) -> np.ndarray:
    """The boolean image of :func:`encode_mask`."""
    shape = tuple(int(v) for v in data["shape"])
    bits = np.frombuffer(base64.b64decode(data["bits"]), np.uint8)
    return np.unpackbits(bits, count=int(np.prod(shape))).astype(bool).reshape(shape)


def fit_footprint(support: np.ndarray) -> np.ndarray:
    """The sample's footprint: the pixels in the prediction-time support of at least one of the images (n, H, W).

    For images of one scan (its slices, or its measured pairs, on one grid) it marks where the sample
    is in some slice: a pixel of it outside its own slice's support may be object that the network
    missed there (a faint slice flattened, an edge fringe smoothed); a pixel outside it is background
    in every slice seen.
    """
    return np.asarray(support, bool).reshape(-1, *np.shape(support)[-2:]).any(axis=0)


def footprint_fits(groups: dict[str, Any], shape: tuple[int, ...]) -> bool:
    """Whether the footprint of ``groups`` (:func:`encode_mask`) has the image shape of ``shape`` (its last two)."""
    return tuple(int(v) for v in groups["footprint"]["shape"]) == tuple(shape[-2:])


def footprint_outside(
    std: np.ndarray, groups: dict[str, Any], image: np.ndarray | None = None, known: np.ndarray | None = None
) -> np.ndarray:
    """Per image, the fraction of its prediction-time support that lies outside the footprint of ``groups``.

    The footprint (:func:`fit_footprint`) is where the calibrating scan's sample is in some slice; the
    background inside it gets the wider intervals that pay for the object pixels a network misses.
    An image whose own support leaves it (another sample, the same one moved or mirrored, or a
    slice with nothing in it, whose support relative to its own level is its noise) is unlike
    every calibrating image there, and may have missed object pixels outside the footprint, where
    the background's narrow intervals do not cover them.

    Parameters
    ----------
    std : array (H, W) or (n, H, W)
        The prediction's stored std.
    groups : dict
        The groups of a calibration level with a footprint (:func:`group_labels`).
    image : array of the shape of ``std``, optional
        The prediction's mean, where the support is defined on it.
    known : bool array (H, W), optional
        The pixels that count (e.g. the field of view the footprint was fitted on); default all.

    Returns
    -------
    numpy.ndarray
        (n,) fractions in [0, 1]; an image without support on ``known`` gives 0.

    Raises
    ------
    ValueError
        If ``groups`` has no footprint, or one of another image shape.
    """
    if not groups.get("footprint"):
        raise ValueError("these groups have no footprint (a calibration on one scan's measured pairs has one)")
    if not footprint_fits(groups, np.shape(std)):
        raise ValueError(
            f"the footprint is {tuple(groups['footprint']['shape'])}, the images {tuple(np.shape(std)[-2:])}"
        )
    std = np.asarray(std).reshape(-1, *np.shape(std)[-2:])
    image = None if image is None else np.asarray(image).reshape(std.shape)
    support = object_region(group_labels(std, groups, image), len(groups["cuts"]) + 1)
    if known is not None:
        support &= np.asarray(known, bool)
    outside = (support & ~decode_mask(groups["footprint"])).sum(axis=(1, 2))
    return outside / np.maximum(support.sum(axis=(1, 2)), 1)


def mean_noise_ratio(std: np.ndarray, image: np.ndarray, n_samples: int, known: np.ndarray | None = None) -> np.ndarray:
    """Per image, the sampling noise of a mean of ``n_samples`` independent draws relative to the image's level.

    The noise is the median of ``std / sqrt(n_samples)`` and the level the 99th percentile of ``|image|``, both
    on the ``known`` pixels (default all). A faint slice (nearly empty, or of low contrast) predicted with a few
    draws has a ratio of a few tenths: its support relative to its own level (:func:`support_of` with
    ``source="relative"``) then follows the noise, and :func:`footprint_outside` measures the noise, not the
    object (:data:`FOOTPRINT_NOISY_MEAN`).

    Parameters
    ----------
    std, image : array (H, W) or (n, H, W)
        The prediction's per-pixel std of the draws and its mean.
    n_samples : int
        Independent draws the mean was taken over (antithetic pairs are not independent).
    known : bool array (H, W), optional
        The pixels that count.

    Returns
    -------
    numpy.ndarray
        (n,) ratios (NaN values ignored); ``inf`` for an image that is zero on every known pixel, NaN where no
        pixel is known.
    """
    std = np.asarray(std, np.float64).reshape(-1, *np.shape(std)[-2:])
    image = np.abs(np.asarray(image, np.float64)).reshape(std.shape)
    mask = np.ones(std.shape[1:], bool) if known is None else np.asarray(known, bool)
    if not mask.any():
        return np.full(len(std), np.nan)
    noise = np.nanmedian(std[:, mask], axis=1) / np.sqrt(n_samples)
    level = np.nanpercentile(image[:, mask], 99, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(level > 0, noise / np.where(level > 0, level, 1.0), np.inf)


def object_region(labels: np.ndarray, n_bins: int) -> np.ndarray:
    """Where :func:`group_labels` puts a pixel on the object's support (groups 1..``n_bins``)."""
    labels = np.asarray(labels)
    return (labels > 0) & (labels <= n_bins)


def group_labels(std: np.ndarray, groups: dict[str, Any], image: np.ndarray | None = None) -> np.ndarray:
    """Group of each pixel under a group-conditional calibration: 0 = background, k = 1..K the object's k-th
    std bin, and with a footprint K + 1 = background inside the sample's footprint.

    ``groups["support"]`` = {``source``: "std", "mean" or "relative", ``threshold``, ``radius``, ``fill``}
    defines the support (:func:`support_of` of :func:`support_image`: the std, or ``image`` = the
    prediction's mean, absolute or relative to the image's own level); ``groups["cuts"]`` are the
    K - 1 std cut points on the support (:func:`fit_group_cuts`). ``groups["footprint"]``
    (optional, :func:`encode_mask` of :func:`fit_footprint`) splits the background: its pixels inside
    the footprint form group K + 1. An image of another shape than the footprint has all its
    background in group K + 1 (:func:`half_width_of` then gives it the larger of the two background
    multipliers).

    Raises
    ------
    ValueError
        If the support is defined on the mean and ``image`` is not given.
    """
    rule = groups["support"]
    src = support_image(rule["source"], std, image)
    support = support_of(src, float(rule["threshold"]), int(rule["radius"]), rule.get("fill", False))
    bins = 1 + np.searchsorted(np.asarray(groups["cuts"], np.float64), np.asarray(std, np.float64), side="right")
    background = np.zeros(np.shape(std), np.int64)
    if groups.get("footprint"):
        inside = decode_mask(groups["footprint"]) if footprint_fits(groups, np.shape(std)) else True
        background = np.where(inside, len(groups["cuts"]) + 2, 0)  # K + 1, K = len(cuts) + 1 object bins
    return np.where(support, bins, background).astype(np.int64)


def fit_group_cuts(std: np.ndarray, support: np.ndarray, n_bins: int = OBJECT_WIDTH_BINS) -> list[float]:
    """The ``n_bins - 1`` std quantiles of the support's pixels that split it into equal-count bins."""
    s = np.asarray(std, np.float64)[np.asarray(support, bool)]
    if s.size < n_bins:
        raise ValueError(f"{s.size} support pixels are too few for {n_bins} width bins")
    return np.quantile(s, np.arange(1, n_bins) / n_bins).tolist()


def group_guaranteed_coverage(
    err: np.ndarray, half: np.ndarray, labels: np.ndarray, n_groups: int, delta: float = DEFAULT_DELTA
) -> list[float | None]:
    """Per group, the per-image coverage of ``|err| <= half`` that holds with probability ``1 - delta``.

    The loss of an image is the fraction of its pixels of the group outside the interval; one minus
    :func:`hb_upper_bound` of the mean loss over the images that have pixels of the group (None for
    a group no image has). Stacks (n, H, W).
    """
    out: list[float | None] = []
    outside = np.abs(err) > half
    for g in range(n_groups):
        m = labels == g
        losses = [outside[i][m[i]].mean() for i in range(len(m)) if m[i].any()]
        out.append(None if not losses else 1.0 - hb_upper_bound(float(np.mean(losses)), len(losses), delta))
    return out


def _region_maps(
    err: np.ndarray, std: np.ndarray, labels: np.ndarray, level: float, n_bins: int
) -> list[dict[str, list[float]]]:
    """Width maps (:func:`fit_width_map`) of the background (groups 0 and ``n_bins + 1``) and of the object
    (groups 1..``n_bins``); a region too small or too uniform for a map of its own gets the map of all
    pixels (labels -1, left out, in neither)."""
    maps = []
    on_object = object_region(labels, n_bins)
    for region in ((labels >= 0) & ~on_object, on_object):
        try:
            maps.append(fit_width_map(err[region], std[region], level))
        except ValueError:
            maps.append(fit_width_map(err[labels >= 0], std[labels >= 0], level))
    return maps


def _multipliers(
    err: np.ndarray, base: np.ndarray, fit_on: np.ndarray, mask: np.ndarray, level: float, delta: float
) -> tuple[float, float | None]:
    """The split-conformal multiplier of the pixels ``fit_on`` and the risk-controlling one of the pixels
    ``mask`` (None where the images are too few for it)."""
    q = conformal_multiplier(err[fit_on], base[fit_on], level)
    try:
        return q, rcps_multiplier(err, base, level, delta, mask=mask)
    except ValueError:
        return q, None


def _class_multipliers(
    err: np.ndarray, base: np.ndarray, m: np.ndarray, truth: np.ndarray, level: float, delta: float
) -> tuple[list[float | None], list[float | None]]:
    """Split-conformal and risk-controlling multipliers of group ``m``'s pixels on the reference's object and
    of its other pixels ([object, other] each; None for a class too small for the level or the guarantee)."""
    q: list[float | None] = []
    rcps: list[float | None] = []
    for part in (m & truth, m & ~truth):
        n = int(part.sum())
        if math.ceil((n + 1) * level) > n:
            q.append(None)
            rcps.append(None)
            continue
        q_part, rcps_part = _multipliers(err, base, part, part, level, delta)
        q.append(q_part)
        rcps.append(rcps_part)
    return q, rcps


def fit_group_intervals(
    err: np.ndarray,
    std: np.ndarray,
    labels: np.ndarray,
    level: float,
    delta: float = DEFAULT_DELTA,
    n_bins: int = OBJECT_WIDTH_BINS,
    truth: np.ndarray | None = None,
    footprint: bool = False,
) -> dict[str, Any]:
    """Group-conditional (Mondrian) split-conformal intervals of one level on validation outputs (n, H, W).

    ``labels`` (:func:`group_labels`): 0 = background, 1..K = the object's std bins (K = ``n_bins``),
    with ``footprint`` K + 1 = background inside the sample's footprint, -1 = left out (e.g. outside
    the field of view, where a measured reference is not known). A width map
    (:func:`fit_width_map`) is fitted per region (background, object) and a split-conformal
    multiplier of it per group: the ``ceil((n_g + 1) level)``-th smallest score of the group's
    n_g pixels. Within each group the half-width is strictly increasing in the std; across the
    object's bins it steps by the ratio of their multipliers (no running maximum: it would widen the
    wider bins beyond their level).

    Guarantee, per group g: a new pixel of group g exchangeable with the group's validation pixels
    is covered with probability in ``[level, level + 1 / (n_g + 1))`` (the width maps are fitted on
    the same pixels, a data-dependent choice of score of 20 knots per region). Over images (the pixels of one image are
    dependent): ``guaranteed_coverage``, the per-image coverage of the group's pixels that holds
    with probability ``1 - delta`` (:func:`group_guaranteed_coverage`), and the group's
    risk-controlling multiplier (:func:`rcps_multiplier` with the group's mask; None where the
    images are too few).

    ``truth`` (bool, the shape of ``err``): the object as the validation references show it
    (:func:`nanoct.evaluation.metrics.truth_support`). With it the calibration is object-conditional
    (label-conditional Mondrian): each group's multiplier is the larger of the split-conformal
    multipliers of its pixels on the reference's object and of its other pixels, so a new pixel of
    group g is covered with probability at least ``level`` both where the reference is object and
    where it is not, whatever part of the object the prediction-time support misses (at the price of
    wider intervals on the background of a group that holds missed object pixels). A class with too
    few pixels of a group for the level has no multiplier of its own there (``class_multipliers``:
    None in its place), and its pixels of that group are covered only through the other class's
    multiplier (the group's own where neither class has enough).

    A group with too few validation pixels for the level (``(n_g + 1) level > n_g``, e.g. none)
    gets the multiplier of all pixels (``pooled`` True for it): its guarantee is then only the
    marginal one over all pixels.

    Returns
    -------
    dict
        ``maps`` (background, object), ``multipliers``, ``rcps_multipliers``,
        ``guaranteed_coverage``, ``val_coverage``, ``n_pixels`` and ``pooled``, lists over the groups;
        with ``truth`` also ``class_multipliers`` ([object, other] per group) and
        ``object_val_coverage`` (per group, on the reference's object; None where it has no pixel).

    Raises
    ------
    ValueError
        If there is no positive finite multiplier, labels outside -1..n_groups - 1, or ``truth`` has
        another shape than ``err``.
    """
    err, std = np.abs(np.asarray(err, np.float64)), np.asarray(std, np.float64)
    labels = np.asarray(labels)
    n_groups = n_bins + 1 + int(footprint)
    if labels.size and not -1 <= int(labels.min()) <= int(labels.max()) < n_groups:
        raise ValueError(
            f"group labels {int(labels.min())}..{int(labels.max())} outside -1..{n_groups - 1} "
            f"({n_bins} object bins{', a footprint' if footprint else ''})"
        )
    if truth is not None:
        if np.shape(truth) != err.shape:
            raise ValueError(f"the reference's object has shape {np.shape(truth)}, the errors {err.shape}")
        truth = np.asarray(truth, bool)
    maps = _region_maps(err, std, labels, level, n_bins)
    base = np.where(object_region(labels, n_bins), apply_width_map(std, maps[1]), apply_width_map(std, maps[0]))
    known = labels >= 0
    q, rcps, pooled, by_class = [], [], [], []
    for g in range(n_groups):
        m = labels == g
        pooled.append(math.ceil((int(m.sum()) + 1) * level) > int(m.sum()))
        fit_on = known if pooled[-1] else m
        per_class, class_rcps = [None, None], [None, None]
        if truth is not None and not pooled[-1]:
            per_class, class_rcps = _class_multipliers(err, base, m, truth, level, delta)
        by_class.append(per_class)
        if any(v is not None for v in per_class):
            q.append(max(v for v in per_class if v is not None))
            fitted = [r for r, v in zip(class_rcps, per_class) if v is not None]
            rcps.append(None if None in fitted else max(fitted))
            continue
        q_group, rcps_group = _multipliers(err, base, fit_on, m, level, delta)
        q.append(q_group)
        rcps.append(rcps_group)
    half = np.asarray(q)[labels] * base
    sizes = [int((labels == g).sum()) for g in range(n_groups)]
    out = {
        "maps": maps,
        "multipliers": q,
        "rcps_multipliers": rcps,
        "guaranteed_coverage": group_guaranteed_coverage(err, half, labels, n_groups, delta),
        "val_coverage": [float(np.mean((err <= half)[labels == g])) if n else None for g, n in enumerate(sizes)],
        "n_pixels": sizes,
        "pooled": pooled,
    }
    if truth is not None:
        on = [(labels == g) & truth for g in range(n_groups)]
        out["class_multipliers"] = by_class
        out["object_val_coverage"] = [float(np.mean((err <= half)[o])) if o.any() else None for o in on]
    return out
