"""Split-conformal multipliers and the risk-controlling (Hoeffding-Bentkus) guarantee on constructed data."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nanoct.evaluation.conformal import (
    apply_width_map,
    conformal_multiplier,
    decode_mask,
    encode_mask,
    fit_footprint,
    fit_group_cuts,
    fit_group_intervals,
    fit_support_threshold,
    fit_width_map,
    footprint_outside,
    group_guaranteed_coverage,
    group_labels,
    guaranteed_coverage,
    half_width_of,
    hb_upper_bound,
    image_miscoverage,
    level_key,
    rcps_multiplier,
    scores,
    support_image,
    support_of,
)
from nanoct.evaluation.metrics import support_mask


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


def test_width_map_grows_no_faster_than_the_std_past_its_knots(rng):
    """A top bin whose quantile jumps (a few pixels of large error among the largest std, as on the
    background next to an object) gives a steep last segment; past the last knot the map continues
    with slope 1 in log-log (width proportional to the std), not with that segment's slope, and below
    the first knot it shrinks at most in proportion to the std. The multiplier fitted on the map still
    covers fresh pixels of the same law at the level."""
    std = rng.uniform(0.1, 1.0, 40_000)
    top = std > np.quantile(std, 0.97)

    def errors():
        e = rng.normal(size=std.size) * 0.01 * std
        return np.where(top & (rng.uniform(size=std.size) < 0.2), rng.normal(size=std.size), e)

    err = errors()
    m = fit_width_map(err, std, 0.95)
    x, w = np.asarray(m["std"]), np.asarray(m["width"])
    assert np.log(w[-1] / w[-2]) / np.log(x[-1] / x[-2]) > 5  # the steep last segment
    np.testing.assert_allclose(apply_width_map(2 * x[-1:], m), 2 * w[-1], rtol=1e-12)
    grid = np.linspace(x[-1], 3 * x[-1], 50)
    assert np.all(np.diff(apply_width_map(grid, m)) > 0)
    # steep first segment: clipped to slope 1 below it as well
    steep_first = {"std": [1.0, 2.0, 4.0], "width": [1.0, 8.0, 9.0]}
    assert apply_width_map(np.array([0.5]), steep_first)[0] == pytest.approx(0.5)
    q = conformal_multiplier(err, apply_width_map(std, m), 0.95)
    fresh = errors()
    assert np.mean(np.abs(fresh) <= q * apply_width_map(std, m)) == pytest.approx(0.95, abs=0.006)


def _object_data(n, rng, size=24):
    """Images with a disk object: on the background |err| follows the std, on the object the error has a
    floor (0.02 + std), so one pooled calibration leaves the object's narrowest std fifth under-covered."""
    yy, xx = np.mgrid[:size, :size] - size / 2
    support = np.broadcast_to(xx**2 + yy**2 <= 8**2, (n, size, size))
    std = np.where(support, rng.uniform(0.01, 0.1, support.shape), rng.uniform(0.005, 0.03, support.shape))
    err = rng.normal(size=std.shape) * np.where(support, 0.02 + std, std)
    return err, std, support


def _labels(std, support, cuts):
    return np.where(support, 1 + np.searchsorted(cuts, std, side="right"), 0)


def test_group_conditional_intervals_cover_every_group_where_one_multiplier_does_not(rng):
    err, std, support = _object_data(200, rng)
    cuts = fit_group_cuts(std, support)
    assert len(cuts) == 4 and np.all(np.diff(cuts) > 0)
    labels = _labels(std, support, cuts)
    assert np.bincount(labels[support])[1:] == pytest.approx([support.sum() / 5] * 5, rel=0.01)
    fit = fit_group_intervals(err, std, labels, 0.9)
    entry = {"groups": {"support": {"source": "std", "threshold": 0.0, "radius": 0}, "cuts": cuts} | fit}
    fresh_err, fresh_std, fresh_support = _object_data(400, rng)
    fresh_labels = _labels(fresh_std, fresh_support, cuts)
    # the half-width by hand: the group's multiplier times its region's width map
    base = np.where(
        fresh_labels > 0, apply_width_map(fresh_std, fit["maps"][1]), apply_width_map(fresh_std, fit["maps"][0])
    )
    expected = np.asarray(fit["multipliers"])[fresh_labels] * base
    entry["groups"]["support"] = {"source": "mean", "threshold": 0.5, "radius": 0}  # the true support, given
    half = half_width_of(fresh_std, entry, image=fresh_support.astype(float))
    np.testing.assert_allclose(half, expected)
    with pytest.raises(ValueError, match="pass the mean"):
        half_width_of(fresh_std, entry)
    # within each group the half-width increases with the std
    for g in range(6):
        order = np.argsort(fresh_std[fresh_labels == g])
        assert np.all(np.diff(half[fresh_labels == g][order]) > 0)
    pooled_map = fit_width_map(err, std, 0.9)
    q = conformal_multiplier(err, apply_width_map(std, pooled_map), 0.9)
    pooled = q * apply_width_map(fresh_std, pooled_map)
    inside, inside_pooled = np.abs(fresh_err) <= half, np.abs(fresh_err) <= pooled
    per_group = [inside[fresh_labels == g].mean() for g in range(6)]
    per_group_pooled = [inside_pooled[fresh_labels == g].mean() for g in range(6)]
    assert min(per_group_pooled) < 0.8  # the object's narrowest fifth
    assert per_group == pytest.approx([0.9] * 6, abs=0.015)
    assert all(0.8 < c < 0.9 for c in fit["guaranteed_coverage"])  # the per-image bound, below the level
    assert fit["val_coverage"] == pytest.approx([0.9] * 6, abs=0.005) and not any(fit["pooled"])
    # a group without validation pixels takes the multiplier of all pixels
    few = fit_group_intervals(err, std, np.where(labels == 5, 4, labels), 0.9)
    assert few["pooled"] == [False] * 5 + [True] and few["n_pixels"][5] == 0 and few["val_coverage"][5] is None
    both = np.where(labels > 0, apply_width_map(std, few["maps"][1]), apply_width_map(std, few["maps"][0]))
    assert few["multipliers"][5] == conformal_multiplier(err, both, 0.9)


def test_group_conditional_coverage_is_within_the_finite_sample_bound(rng):
    """Over many calibration sets, each group's expected coverage of fresh pixels lies in
    [level, level + 1 / (n_g + 1)] (up to the width maps being fitted on the same pixels)."""
    level, trials, covered, sizes = 0.9, 300, [], []
    cuts = None
    for _ in range(trials):
        err, std, support = _object_data(6, rng)
        cuts = fit_group_cuts(std, support) if cuts is None else cuts  # fixed groups across trials
        labels = _labels(std, support, cuts)
        fit = fit_group_intervals(err, std, labels, level)
        fe, fs, fsup = _object_data(4, rng)
        fl = _labels(fs, fsup, cuts)
        base = np.where(fl > 0, apply_width_map(fs, fit["maps"][1]), apply_width_map(fs, fit["maps"][0]))
        inside = np.abs(fe) <= np.asarray(fit["multipliers"])[fl] * base
        covered.append([inside[fl == g].mean() for g in range(6)])
        sizes.append(fit["n_pixels"])
    mean, n_g = np.mean(covered, axis=0), np.min(sizes, axis=0)
    assert np.all(mean >= level - 0.01), mean
    assert np.all(mean <= level + 1 / (n_g + 1) + 0.01), (mean, n_g)


def _missed_rim_data(n, rng, size=24):
    """A disk object (radius 8) of which the prediction-time support sees only the core (radius 5): the rim's
    pixels fall in the background group, with errors of the object's size (0.05 + std) but a background std."""
    yy, xx = np.mgrid[:size, :size] - size / 2
    r = np.hypot(xx, yy)
    truth, seen = np.broadcast_to(r <= 8, (n, size, size)), np.broadcast_to(r <= 5, (n, size, size))
    std = np.where(seen, rng.uniform(0.01, 0.1, truth.shape), rng.uniform(0.005, 0.03, truth.shape))
    err = rng.normal(size=std.shape) * np.where(truth, 0.05 + std, std)
    return err, std, seen, truth


def test_object_conditional_intervals_cover_the_object_the_support_misses(rng):
    """Where the support misses part of the object, the group multipliers leave those object pixels uncovered;
    object-conditional multipliers (the larger of the object's and the rest's) cover both classes of every
    group at the level, and the background of the group holding missed object pixels more than that."""
    err, std, seen, truth = _missed_rim_data(150, rng)
    cuts = fit_group_cuts(std, seen)
    labels = _labels(std, seen, cuts)
    plain = fit_group_intervals(err, std, labels, 0.9)
    fit = fit_group_intervals(err, std, labels, 0.9, truth=truth)
    assert "class_multipliers" not in plain and len(fit["class_multipliers"]) == 6
    q_obj, q_rest = fit["class_multipliers"][0]
    assert fit["multipliers"][0] == max(q_obj, q_rest) and q_obj > q_rest
    for g in range(1, 6):  # the core is all object: its groups keep their multipliers
        assert fit["class_multipliers"][g][1] is None and fit["multipliers"][g] == plain["multipliers"][g]
    assert min(fit["object_val_coverage"]) >= 0.9
    assert fit["multipliers"][0] > 1.5 * plain["multipliers"][0]  # the rim's errors set the background group's
    fresh_err, fresh_std, fresh_seen, fresh_truth = _missed_rim_data(300, rng)
    fresh_labels = _labels(fresh_std, fresh_seen, cuts)
    base = np.where(
        fresh_labels > 0, apply_width_map(fresh_std, fit["maps"][1]), apply_width_map(fresh_std, fit["maps"][0])
    )
    for entry, floor in ((plain, None), (fit, 0.9)):
        inside = np.abs(fresh_err) <= np.asarray(entry["multipliers"])[fresh_labels] * base
        on_object = [inside[(fresh_labels == g) & fresh_truth].mean() for g in range(6)]
        rest = [inside[(fresh_labels == g) & ~fresh_truth].mean() for g in range(6) if g == 0]
        if floor is None:
            assert on_object[0] < 0.6  # the missed rim, with the background's multiplier
        else:
            assert min(on_object) > floor - 0.015 and rest[0] > 0.97
    with pytest.raises(ValueError, match="object has shape"):
        fit_group_intervals(err, std, labels, 0.9, truth=truth[:2])


def _footprint_data(n, rng, size=24):
    """Slices of one sample on one grid: a disk object (radius 8); the prediction (``mean``) sees all of it and a
    pixel beyond (radius 9) in the even slices, only its core (radius 5) in the odd ones, whose rim then has
    errors of the object's size (0.05 + std) but a background std."""
    yy, xx = np.mgrid[:size, :size] - size / 2
    r = np.hypot(xx, yy)
    truth = np.broadcast_to(r <= 8, (n, size, size))
    mean = np.stack([r <= (9 if i % 2 == 0 else 5) for i in range(n)]).astype(float)
    std = np.where(mean > 0, rng.uniform(0.01, 0.1, truth.shape), rng.uniform(0.005, 0.03, truth.shape))
    err = rng.normal(size=std.shape) * np.where(truth, 0.05 + std, std)
    return err, std, mean, truth


def test_a_footprint_keeps_the_background_outside_the_sample_narrow(rng):
    """With the sample's footprint (the union of the slices' supports) the missed rim lies in the background
    group inside it, so the background outside it is covered at the level with its own, narrow multiplier;
    without it, object-conditional multipliers widen all the background for the rim's sake."""
    mask = rng.random((5, 7)) > 0.5
    np.testing.assert_array_equal(decode_mask(encode_mask(mask)), mask)
    err, std, mean, truth = _footprint_data(120, rng)
    rule = {"source": "mean", "threshold": 0.5, "radius": 0}
    support = support_of(mean, 0.5, 0)
    footprint = fit_footprint(support)
    np.testing.assert_array_equal(footprint, support[0])  # the even slices' support holds the odd ones'
    groups = {"support": rule, "cuts": fit_group_cuts(std, support)}
    with_footprint = groups | {"footprint": encode_mask(footprint)}
    labels, split = group_labels(std, groups, mean), group_labels(std, with_footprint, mean)
    np.testing.assert_array_equal(split, np.where((labels == 0) & footprint, 6, labels))
    assert (split[1::2][truth[1::2] & ~support[1::2]] == 6).all()  # the missed rim
    fit = with_footprint | fit_group_intervals(err, std, split, 0.9, truth=truth, footprint=True)
    plain = groups | fit_group_intervals(err, std, labels, 0.9, truth=truth)
    assert len(fit["multipliers"]) == 7 and fit["class_multipliers"][0][0] is None  # no object outside it
    # the rim's errors set the group inside the footprint as they set the whole background without it
    assert fit["multipliers"][6] == pytest.approx(plain["multipliers"][0]) and fit["maps"] == plain["maps"]
    assert fit["multipliers"][0] < plain["multipliers"][0] / 1.5
    fresh_err, fresh_std, fresh_mean, fresh_truth = _footprint_data(300, rng)
    fresh = group_labels(fresh_std, with_footprint, fresh_mean)
    outside = fresh == 0
    for entry, band in ((fit, (0.885, 0.915)), (plain, (0.97, 1.001))):
        inside = np.abs(fresh_err) <= half_width_of(fresh_std, {"groups": entry}, image=fresh_mean)
        assert band[0] < inside[outside].mean() < band[1]
        assert min(inside[(fresh == g) & fresh_truth].mean() for g in range(1, 7)) > 0.885
    # the background groups (0 and 6) take the background's width map, the object's groups the object's
    half = half_width_of(fresh_std, {"groups": fit}, image=fresh_mean)
    for g, region in ((0, 0), (6, 0), (3, 1)):
        where = fresh == g
        expected = fit["multipliers"][g] * apply_width_map(fresh_std[where], fit["maps"][region])
        np.testing.assert_allclose(half[where], expected, rtol=1e-12)
    # an image of another shape: all its background in the group inside the footprint, with the larger of the two
    # background multipliers
    crop_std, crop_mean = fresh_std[:2, :20, :20], fresh_mean[:2, :20, :20]
    crop = group_labels(crop_std, with_footprint, crop_mean)
    assert not (crop == 0).any() and (crop == 6).any()
    swapped = fit | {"multipliers": [fit["multipliers"][6], *fit["multipliers"][1:6], fit["multipliers"][0]]}
    crop_half = half_width_of(crop_std, {"groups": swapped}, image=crop_mean)
    background = crop == 6
    expected = max(fit["multipliers"][0], fit["multipliers"][6]) * apply_width_map(crop_std, fit["maps"][0])
    np.testing.assert_allclose(crop_half[background], expected[background], rtol=1e-12)
    with pytest.raises(ValueError, match="labels 0..6 outside -1..5"):
        fit_group_intervals(err, std, split, 0.9)  # a footprint's labels fitted as if there were none


def test_footprint_outside_counts_the_support_that_leaves_the_footprint(rng):
    """The slices of the calibrating sample lie inside its footprint (0); the same sample moved 4 px has the support
    pixels beyond the footprint's edge outside it, as counted by hand; ``known`` leaves out the pixels it excludes."""
    _, std, mean, _ = _footprint_data(6, rng, size=32)
    rule = {"source": "mean", "threshold": 0.5, "radius": 0}
    support = support_of(mean, 0.5, 0)
    groups = {"support": rule, "cuts": fit_group_cuts(std, support), "footprint": encode_mask(fit_footprint(support))}
    np.testing.assert_array_equal(footprint_outside(std, groups, mean), np.zeros(6))
    moved_mean, moved_std = np.roll(mean, 4, axis=2), np.roll(std, 4, axis=2)
    moved = support_of(moved_mean, 0.5, 0)
    by_hand = (moved & ~support[0]).sum(axis=(1, 2)) / moved.sum(axis=(1, 2))
    found = footprint_outside(moved_std, groups, moved_mean)
    np.testing.assert_allclose(found, by_hand)
    assert (found[::2] > 0.2).all() and (found[1::2] == 0).all()  # the odd slices' core (radius 5) stays inside
    left = np.zeros(mean.shape[1:], bool)
    left[:, :16] = True  # the moved disc's left half stays inside the footprint
    np.testing.assert_array_equal(footprint_outside(moved_std, groups, moved_mean, known=left), 0)
    np.testing.assert_array_equal(footprint_outside(std[0], groups, mean[0]), [0.0])  # one image
    with pytest.raises(ValueError, match="no footprint"):
        footprint_outside(std, {k: v for k, v in groups.items() if k != "footprint"}, mean)
    with pytest.raises(ValueError, match=r"the footprint is \(32, 32\), the images \(28, 28\)"):
        footprint_outside(std[:, :28, :28], groups, mean[:, :28, :28])


def test_object_conditional_multiplier_falls_back_for_a_class_too_small(rng):
    """A class with too few pixels of a group for the level gets no multiplier of its own there (None); the other
    class's sets the group's, and a group with neither class large enough keeps the group's own."""
    err, std, seen, truth = _missed_rim_data(20, rng)
    labels = _labels(std, seen, fit_group_cuts(std, seen))
    truth = truth.copy()
    truth[labels == 0] = False
    truth[0, 0, 0] = labels[0, 0, 0] == 0  # one object pixel in the background group
    fit = fit_group_intervals(err, std, labels, 0.9, truth=truth)
    assert fit["class_multipliers"][0][0] is None and fit["multipliers"][0] == fit["class_multipliers"][0][1]
    assert all(q_rest is None for _, q_rest in fit["class_multipliers"][1:])  # the core is all object
    small = np.where(labels == 5, -1, labels)
    small[0, 12, 12] = 5  # one pixel: pooled, as without truth
    fit = fit_group_intervals(err, std, small, 0.9, truth=truth)
    assert fit["pooled"][5] and fit["class_multipliers"][5] == [None, None]


def test_support_threshold_recovers_the_object(rng):
    yy, xx = np.mgrid[:32, :32] - 16
    truth = np.broadcast_to((np.abs(xx) < 9) & (np.abs(yy) < 6), (5, 32, 32))
    image = np.where(truth, rng.uniform(0.3, 1.0, truth.shape), rng.uniform(0.0, 0.1, truth.shape))
    t = fit_support_threshold(image, support_mask(truth, 2), 2)
    assert 0.1 <= t < 0.4  # between the background's values and most of the object's
    found, true = support_of(image, t, 2), support_mask(truth, 2)
    assert (found & true).sum() / (found | true).sum() > 0.98
    with pytest.raises(ValueError, match="no support"):
        fit_support_threshold(image, np.zeros_like(truth), 2)
    # an object seen only at its rim (a std that is large at edges): filling the holes recovers its inside
    rim_image = np.where(truth & ~_interior(truth, 2), 1.0, 0.0)
    assert support_of(rim_image, 0.5, 2).sum() < support_mask(truth, 2).sum()
    np.testing.assert_array_equal(support_of(rim_image, 0.5, 2, fill=True), support_mask(truth, 2))
    np.testing.assert_array_equal(support_of(rim_image[0], 0.5, 2, fill=True), support_mask(truth[0], 2))


def _interior(mask, r):
    """Pixels farther than ``r`` from the mask's edge (erosion by a square)."""
    from scipy import ndimage

    return np.stack([ndimage.binary_erosion(m, structure=np.ones((2 * r + 1, 2 * r + 1))) for m in mask])


def test_masked_image_miscoverage_and_risk_control(rng):
    err, std = rng.normal(size=(4, 5, 6)), np.ones((4, 5, 6))
    mask = np.zeros(err.shape, bool)
    mask[:3, :2] = True  # the last image has no masked pixel: left out
    got = image_miscoverage(err, std, [1.0], mask)
    assert got.shape == (3, 1)
    assert got[:, 0].tolist() == pytest.approx([np.mean(np.abs(err[i, :2]) > 1.0) for i in range(3)])
    assert group_guaranteed_coverage(err, std, mask.astype(int), 2, 0.1)[1] == pytest.approx(
        1 - hb_upper_bound(float(got.mean()), 3, 0.1)
    )


def test_a_relative_support_finds_a_faint_object_as_a_bright_one(rng):
    """``support_image("relative")``: the mean over each image's own 99th percentile, so an object 100 times
    fainter lands in the object's groups, where an absolute threshold leaves it in the background."""
    yy, xx = np.mgrid[:32, :32] - 16
    truth = (np.abs(xx) < 9) & (np.abs(yy) < 6)
    bright = np.where(truth, 0.2, 0.0) + rng.normal(0, 0.002, (32, 32))
    mean = np.stack([bright, bright / 100])
    std = np.full_like(mean, 0.01)
    relative = support_image("relative", std, mean)
    np.testing.assert_allclose(relative[0], relative[1], rtol=1e-12)  # scale-free
    groups = {"support": {"source": "relative", "threshold": 0.5, "radius": 0}, "cuts": [1.0, 2.0, 3.0, 4.0]}
    labels = group_labels(std, groups, mean)
    assert (labels[:, truth] > 0).all() and (labels[:, ~truth] == 0).all()
    absolute = group_labels(std, {**groups, "support": {"source": "mean", "threshold": 0.1, "radius": 0}}, mean)
    assert (absolute[0][truth] > 0).all() and (absolute[1] == 0).all()  # the faint one: all background
    with pytest.raises(ValueError, match="pass the mean"):
        group_labels(std, groups)
    with pytest.raises(ValueError, match="std, mean or relative"):
        support_image("edges", std, mean)


def test_pixels_left_out_do_not_move_the_group_fit(rng):
    """Labels -1 (e.g. outside the field of view) are in no group, region map or pooled multiplier."""
    err, std, support = _object_data(40, rng)
    labels = _labels(std, support, fit_group_cuts(std, support))
    wrecked, out = err.copy(), np.zeros(err.shape, bool)
    out[:, :2] = True  # two rows of every image left out, their errors wrecked
    wrecked[out] = 1e3
    left = fit_group_intervals(wrecked, std, np.where(out, -1, labels), 0.9)
    kept = fit_group_intervals(err[:, 2:], std[:, 2:], labels[:, 2:], 0.9)
    for key in ("multipliers", "maps", "n_pixels", "val_coverage"):
        assert left[key] == kept[key]


def test_mean_noise_ratio_against_a_direct_computation(rng):
    """The median std over sqrt(M) on the known pixels, over the 99th percentile of |mean| there; inf for a zero
    image; and it matches the spread of means of M independent draws."""
    from nanoct.evaluation.conformal import mean_noise_ratio

    std = rng.uniform(0.01, 0.03, (2, 16, 16))
    image = rng.normal(0, 1, (2, 16, 16))
    known = np.zeros((16, 16), bool)
    known[2:12, 3:] = True
    got = mean_noise_ratio(std, image, 9, known)
    want = [np.median(s[known]) / 3 / np.percentile(np.abs(m[known]), 99) for s, m in zip(std, image)]
    assert got == pytest.approx(want, rel=1e-12)
    assert mean_noise_ratio(std[0], np.zeros((16, 16)), 4).tolist() == [np.inf]
    assert np.isnan(mean_noise_ratio(std, image, 9, np.zeros((16, 16), bool))).all()  # no pixel known
    holed = std.copy()
    holed[:, 5, 5] = np.nan  # a NaN pixel is left out, not spread
    assert mean_noise_ratio(holed, image, 9, known) == pytest.approx(
        [np.nanmedian(s[known]) / 3 / np.percentile(np.abs(m[known]), 99) for s, m in zip(holed, image)], rel=1e-12
    )
    draws = rng.normal(1.0, 0.2, (400, 16, 16, 25))  # the std of a 25-draw mean: 0.2 / 5
    means = draws.mean(axis=-1)
    assert means.std() == pytest.approx(mean_noise_ratio(np.full((16, 16), 0.2), np.ones((16, 16)), 25)[0], rel=0.02)
