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
that holds with probability ``1 - delta`` (one minus the bound on its loss).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.optimize import brentq
from scipy.stats import binom

__all__ = [
    "DEFAULT_DELTA",
    "DEFAULT_LEVELS",
    "WIDTH_MAP_BINS",
    "WIDTH_MAP_MIN_SLOPE",
    "apply_width_map",
    "conformal_multiplier",
    "fit_width_map",
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
#: Smallest slope of a width map in log(std) -> log(width); it keeps the map strictly increasing.
WIDTH_MAP_MIN_SLOPE = 0.05


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
    the knots, continued with the end segments' slopes; a zero std gives zero."""
    lx, ly = np.log(width_map["std"]), np.log(width_map["width"])
    std = np.asarray(std, dtype=np.float64)
    pos = std > 0
    ls = np.log(np.where(pos, std, 1.0))
    out = np.interp(ls, lx, ly)
    first, last = (ly[1] - ly[0]) / (lx[1] - lx[0]), (ly[-1] - ly[-2]) / (lx[-1] - lx[-2])
    out = np.where(ls < lx[0], ly[0] + first * (ls - lx[0]), out)
    out = np.where(ls > lx[-1], ly[-1] + last * (ls - lx[-1]), out)
    return np.where(pos, np.exp(out), 0.0)


def half_width_of(std: np.ndarray, entry: dict[str, Any], multiplier: str = "multiplier") -> np.ndarray:
    """Half-width ``entry[multiplier] * g(std)`` of a calibrated interval; g = ``entry["map"]``
    (:func:`apply_width_map`) where the entry has one, else the identity."""
    base = apply_width_map(std, entry["map"]) if entry.get("map") else np.asarray(std, dtype=np.float64)
    return float(entry[multiplier]) * base


def image_miscoverage(err: np.ndarray, std: np.ndarray, multipliers: np.ndarray) -> np.ndarray:
    """Fraction of each image's pixels with ``|err| > multiplier * std``: shape (n_images, n_multipliers).

    ``err`` and ``std`` are stacks (n, H, W) (or (n, P) pixels per image).
    """
    s = scores(err, std)
    s = np.sort(s.reshape(s.shape[0], -1), axis=1)
    lam = np.asarray(multipliers, dtype=np.float64).ravel()
    inside = np.stack([np.searchsorted(row, lam, side="right") for row in s])
    return 1.0 - inside / s.shape[1]


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


def guaranteed_coverage(err: np.ndarray, std: np.ndarray, multiplier: float, delta: float = DEFAULT_DELTA) -> float:
    """Per-image pixel coverage that ``multiplier * std`` keeps with probability ``1 - delta``.

    One minus :func:`hb_upper_bound` of the mean :func:`image_miscoverage` of the images of
    ``err`` / ``std`` (stacks (n, H, W)).
    """
    losses = image_miscoverage(err, std, [multiplier])[:, 0]
    return 1.0 - hb_upper_bound(float(losses.mean()), losses.size, delta)


def rcps_multiplier(
    err: np.ndarray, std: np.ndarray, level: float, delta: float = DEFAULT_DELTA, n_grid: int = 2000
) -> float:
    """Smallest multiplier whose intervals cover ``level`` of a new image's pixels with probability ``1 - delta``.

    The candidates are ``n_grid`` quantiles of the pooled scores ``|err| / std`` above the
    ``level`` quantile, and their maximum; the loss of an image (:func:`image_miscoverage`) does not
    increase with the multiplier, so the smallest candidate whose Hoeffding-Bentkus bound is at
    most ``1 - level`` is the RCPS choice (Angelopoulos et al. 2022).

    Raises
    ------
    ValueError
        If even the largest finite score gives no guarantee (too few images for ``level`` and
        ``delta``), or the scores are not finite.
    """
    level_key(level)
    s = scores(err, std)
    finite = s[np.isfinite(s)]
    if finite.size == 0:
        raise ValueError("the std is zero on every pixel with an error: no multiplier covers anything")
    grid = np.unique(np.quantile(finite, np.linspace(level, 1.0, n_grid), method="inverted_cdf"))
    losses = image_miscoverage(err, std, grid)
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
