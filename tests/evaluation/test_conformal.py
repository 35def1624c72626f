"""Split-conformal multipliers and the risk-controlling (Hoeffding-Bentkus) guarantee on constructed data."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nanoct.evaluation.conformal import (
    apply_width_map,
    conformal_multiplier,
    fit_width_map,
    guaranteed_coverage,
    half_width_of,
    hb_upper_bound,
    image_miscoverage,
    level_key,
    rcps_multiplier,
    scores,
)


def test_conformal_multiplier_is_the_order_statistic(rng):
    err, std = rng.normal(size=99), rng.uniform(0.5, 2, 99)
    s = np.sort(np.abs(err) / std)
    assert conformal_multiplier(err, std, 0.9) == s[math.ceil(100 * 0.9) - 1]
    assert scores(np.array([0.0, 1.0]), np.array([0.0, 0.0])).tolist() == [0.0, math.inf]
    with pytest.raises(ValueError, match="too few"):
        conformal_multiplier(err[:5], std[:5], 0.9)
    with pytest.raises(ValueError, match="no finite positive"):
        conformal_multiplier(err, np.zeros_like(std), 0.5)
    with pytest.raises(ValueError, match="strictly between"):
        level_key(1.0)
    assert level_key(0.9) == "0.9" and level_key(0.68) == "0.68"


@pytest.mark.parametrize("level", [0.68, 0.9, 0.95])
def test_conformal_coverage_is_nominal_on_exchangeable_data(rng, level):
    """Over many calibration sets of n exchangeable scores, a fresh one is covered with probability in
    [level, level + 1 / (n + 1)] (heteroscedastic errors: the std carries the scale)."""
    n, trials = 50, 20_000
    std = rng.lognormal(0, 1, (trials, n + 1))
    err = rng.standard_t(3, (trials, n + 1)) * std  # heavy-tailed, but exchangeable scores
    covered = [abs(e[-1]) <= conformal_multiplier(e[:-1], s[:-1], level) * s[-1] for e, s in zip(err, std)]
    se = math.sqrt(level * (1 - level) / trials)
    assert level - 3 * se <= np.mean(covered) <= level + 1 / (n + 1) + 3 * se


def test_hb_bound_known_values_and_validity(rng):
    # with no observed loss the Hoeffding part gives 1 - delta^(1/n)
    assert hb_upper_bound(0.0, 20, 0.1) == pytest.approx(1 - 0.1 ** (1 / 20), rel=1e-6)
    assert hb_upper_bound(0.0, 20, 0.1) > 0.1  # 20 images cannot guarantee 90 % coverage at delta = 0.1
    assert hb_upper_bound(0.05, 10_000, 0.1) == pytest.approx(0.05, abs=0.005)
    assert hb_upper_bound(1.0, 5, 0.1) == 1.0
    ucb = [hb_upper_bound(r, 30, 0.1) for r in (0.0, 0.1, 0.2, 0.5)]
    assert ucb == sorted(ucb) and all(u >= r for u, r in zip(ucb, (0.0, 0.1, 0.2, 0.5)))
    # validity: Bernoulli(mu) losses, the bound falls below mu in at most delta of the draws
    mu, n, delta = 0.1, 40, 0.1
    below = [hb_upper_bound(float(rng.binomial(1, mu, n).mean()), n, delta) < mu for _ in range(2000)]
    assert np.mean(below) <= delta
    with pytest.raises(ValueError, match="delta"):
        hb_upper_bound(0.1, 10, 1.0)


def test_rcps_guarantee_holds_over_calibration_sets(rng):
    """Images of exchangeable pixels: with probability >= 1 - delta over calibration sets, a new image's
    expected miscoverage is at most alpha; the guaranteed coverage of the chosen multiplier is >= 1 - alpha."""
    n_images, pixels, level, delta = 200, 64, 0.9, 0.1
    violations, margins = 0, []
    for _ in range(40):
        scale = rng.lognormal(0, 0.5, (n_images, 1))  # image-level variation: pixels of one image are dependent
        std = rng.uniform(0.5, 2, (n_images, pixels))
        err = rng.normal(size=(n_images, pixels)) * std * scale
        lam = rcps_multiplier(err, std, level, delta)
        assert guaranteed_coverage(err, std, lam, delta) >= level
        # the true risk of lam: a large fresh set of images
        scale2 = rng.lognormal(0, 0.5, (4000, 1))
        std2 = rng.uniform(0.5, 2, (4000, pixels))
        risk = image_miscoverage(rng.normal(size=std2.shape) * std2 * scale2, std2, [lam]).mean()
        violations += risk > 1 - level
        margins.append(risk)
    assert violations / 40 <= delta
    assert np.mean(margins) < 1 - level  # conservative, as the bound is
    with pytest.raises(ValueError, match="too few"):
        rcps_multiplier(err[:20], std[:20], 0.9, delta)


def test_image_miscoverage_counts_per_image(rng):
    err, std = rng.normal(size=(3, 4, 5)), np.ones((3, 4, 5))
    got = image_miscoverage(err, std, [0.5, 1.0])
    for i in range(3):
        assert got[i].tolist() == pytest.approx([np.mean(np.abs(err[i]) > m) for m in (0.5, 1.0)])


def test_width_map_evens_out_coverage_and_keeps_the_ranking(rng):
    """Errors with spread std**2: one multiplier of the std under-covers large std and over-covers small;
    the width map (the 90 % quantile of |err| given the std) covers each std quintile within 2 points,
    and it is strictly increasing (the same ranking as the std)."""
    std = rng.uniform(0.1, 1.0, 100_000)
    err = rng.normal(size=std.size) * std**2
    m = fit_width_map(err, std, 0.9)
    assert np.all(np.diff(m["std"]) > 0) and np.all(np.diff(m["width"]) > 0)
    grid = np.linspace(0.05, 1.5, 1000)
    assert np.all(np.diff(apply_width_map(grid, m)) > 0)
    # the knots follow the true quantile 1.645 * s**2 within 5 %
    np.testing.assert_allclose(m["width"], 1.6449 * np.asarray(m["std"]) ** 2, rtol=0.05)
    order = np.argsort(std)
    fresh = rng.normal(size=std.size) * std**2
    for entry, worst in (({"multiplier": conformal_multiplier(err, std, 0.9)}, 0.05), ({"map": m}, 0.02)):
        if "map" in entry:
            entry["multiplier"] = conformal_multiplier(err, half_width_of(std, {"map": m, "multiplier": 1.0}), 0.9)
        inside = np.abs(fresh) <= half_width_of(std, entry)
        fifths = [b.mean() for b in np.array_split(inside[order], 5)]
        assert (max(abs(f - 0.9) for f in fifths) > worst) == ("map" not in entry)
        assert inside.mean() == pytest.approx(0.9, abs=0.005)
    assert apply_width_map(np.array([0.0]), m)[0] == 0.0
    with pytest.raises(ValueError, match="fewer than two distinct"):
        fit_width_map(err, np.full(std.size, 0.5), 0.9)
