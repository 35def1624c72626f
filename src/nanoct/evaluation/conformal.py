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

import numpy as np
from scipy.optimize import brentq
from scipy.stats import binom

__all__ = [
    "DEFAULT_DELTA",
    "DEFAULT_LEVELS",
    "EXPONENTS",
    "conformal_multiplier",
    "fit_exponent",
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
#: Candidate exponents p of the half-width ``multiplier * std**p`` (:func:`fit_exponent`).
EXPONENTS = tuple(np.round(np.arange(0.5, 3.001, 0.05), 2).tolist())


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


def fit_exponent(
    err: np.ndarray, std: np.ndarray, level: float, exponents: tuple[float, ...] = EXPONENTS, n_bins: int = 5
) -> float:
    """The exponent p for which the intervals ``q_p * std**p`` cover ``level`` most evenly across the std.

    For each candidate p, ``q_p`` is the :func:`conformal_multiplier` of ``std**p``; the pixels are
    split into ``n_bins`` equal-count bins by std (the same bins for every p: ``std**p`` is
    increasing in std) and p minimises the largest deviation of a bin's coverage from ``level``
    (ties: the p closest to 1). ``std**p`` ranks the pixels exactly as the std does, so the
    network's ranking is kept; p > 1 widens the intervals of large std relative to small ones
    (errors growing faster than the std).

    Raises
    ------
    ValueError
        As :func:`conformal_multiplier`, or if no candidate is given.
    """
    if not exponents:
        raise ValueError("no candidate exponent")
    err = np.abs(np.asarray(err, dtype=np.float64)).ravel()
    std = np.asarray(std, dtype=np.float64).ravel()
    order = np.argsort(std, kind="stable")
    best, best_key = 1.0, (math.inf, math.inf)
    for p in exponents:
        scaled = std**p
        q = conformal_multiplier(err, scaled, level)
        bins = np.array_split((err <= q * scaled)[order], n_bins)
        key = (max(abs(float(b.mean()) - level) for b in bins), abs(p - 1))
        if key < best_key:
            best, best_key = float(p), key
    return best


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
