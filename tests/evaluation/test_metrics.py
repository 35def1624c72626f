import numpy as np
import pytest
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from nanoct.evaluation.metrics import (
    GAUSSIAN_COVERAGE,
    STD_MAP_MIN_SLOPE,
    apply_std_map,
    calibrated_std,
    coverage,
    edge_std,
    fit_std_map,
    fit_std_scale,
    fit_value_std_map,
    invert_std_map,
    psnr,
    raw_std,
    reliability,
    sparsification,
    ssim,
    summarize,
    support_mask,
    uncertainty_summary,
)


@pytest.mark.parametrize("offset", [0.0, 0.3])
def test_psnr_ssim_match_skimage_with_gt_range(rng, offset):
    gt = rng.random((40, 40)) * 0.7 + offset
    reco = gt + rng.normal(0, 0.05, gt.shape)
    dr = gt.max() - gt.min()
    assert psnr(reco, gt) == pytest.approx(peak_signal_noise_ratio(gt, reco, data_range=dr), rel=1e-12)
    assert ssim(reco, gt) == pytest.approx(structural_similarity(reco, gt, data_range=dr), rel=1e-12)
    # the data range is that of the ground truth, not the dtype's or the reconstruction's
    assert psnr(reco, gt) != pytest.approx(peak_signal_noise_ratio(gt, reco, data_range=1.0 + offset))


def test_psnr_is_symmetric_in_error_but_not_in_roles(rng):
    gt = rng.random((32, 32))
    assert psnr(gt, gt) == np.inf
    assert psnr(gt * 0.5, gt) != pytest.approx(psnr(gt, gt * 0.5))


def test_summarize(rng):
    gts = rng.random((5, 16, 16))
    recos = gts + rng.normal(0, 0.1, gts.shape)
    s = summarize(recos, gts)
    values = [psnr(r, g) for r, g in zip(recos, gts)]
    assert s["n"] == 5
    assert s["psnr_mean"] == pytest.approx(np.mean(values))
    assert s["psnr_std"] == pytest.approx(np.std(values))
    assert s["psnr_values"] == pytest.approx(values)
    assert s["ssim_values"] == pytest.approx([ssim(r, g) for r, g in zip(recos, gts)])


def test_bad_input(rng):
    with pytest.raises(ValueError, match="constant"):
        psnr(np.zeros((8, 8)), np.ones((8, 8)))
    with pytest.raises(ValueError, match="shape"):
        ssim(np.zeros((8, 9)), rng.random((8, 8)))
    with pytest.raises(ValueError, match="NaN"):
        psnr(np.full((8, 8), np.nan), rng.random((8, 8)))
    with pytest.raises(ValueError, match="no images"):
        summarize(np.zeros((0, 8, 8)), np.zeros((0, 8, 8)))


def test_uncertainty_summary_on_a_calibrated_gaussian(rng):
    std = rng.uniform(0.01, 0.2, (4, 32, 32))
    gts = rng.random((4, 32, 32))
    recos = gts + rng.normal(0, 1, std.shape) * std  # errors drawn with exactly that std
    u = uncertainty_summary(std, recos, gts)
    for k, expected in u["coverage"]["expected"].items():
        assert u["coverage"]["raw"][k] == pytest.approx(expected, abs=0.02)
    assert u["coverage"]["calibrated"] is None and u["n_pixels"] == std.size
    assert u["std_error_corr"] > 0.4  # larger std, larger errors
    assert u["ause_ratio"] < 0.8  # ordering by std beats random order
    over = uncertainty_summary(std * 3, recos, gts, scale=1 / 3)  # over-dispersed raw, calibrated by 1/3
    assert over["coverage"]["raw"]["1"] > 0.95
    assert over["coverage"]["calibrated"] == pytest.approx(u["coverage"]["raw"])
    assert over["ause"] == pytest.approx(u["ause"])  # the ordering does not depend on the scale
    assert over["coverage"]["scaled"] == over["coverage"]["calibrated"] and over["calibration"] == "scale"
    m = fit_std_map(recos - gts, std * 3)
    mapped = uncertainty_summary(std * 3, recos, gts, scale=1 / 3, std_map=m)
    assert mapped["calibration"] == "map" and mapped["coverage"]["scaled"] == over["coverage"]["scaled"]
    assert mapped["coverage"]["calibrated"] == coverage(recos - gts, apply_std_map(std * 3, m))
    assert mapped["coverage"]["calibrated"]["2"] == pytest.approx(GAUSSIAN_COVERAGE["2"], abs=0.01)
    unrelated = uncertainty_summary(rng.permutation(std.ravel()).reshape(std.shape), recos, gts)
    assert abs(unrelated["std_error_corr"]) < 0.1
    with pytest.raises(ValueError, match="negative"):
        uncertainty_summary(-std, recos, gts)
    with pytest.raises(ValueError, match="scale"):
        uncertainty_summary(std, recos, gts, scale=0.0)


def test_coverage_and_reliability_against_numpy(rng):
    err = rng.normal(0, 1, 5000) * rng.uniform(0.5, 2, 5000)
    std = rng.uniform(0.1, 2, 5000)
    std[:10] = 0.0
    err[:5] = 0.0  # 0 within 0 std counts as covered
    cov = coverage(err, std, ks=(1, 2, 3, 0.5))
    for k in (1, 2, 3, 0.5):
        assert cov[f"{k:g}"] == np.mean(np.abs(err) <= k * std)
    levels = np.array([0.1, 0.5, GAUSSIAN_COVERAGE["1"], 0.9, 0.99])
    from scipy.stats import norm

    ks = norm.ppf((1 + levels) / 2)
    expected = [np.mean(np.abs(err) <= k * std) for k in ks]
    np.testing.assert_allclose(reliability(err, std, levels), expected, atol=1e-12)
    # errors drawn from N(0, std^2): observed = nominal
    std = rng.uniform(0.1, 2, 200_000)
    np.testing.assert_allclose(reliability(rng.normal(0, 1, std.size) * std, std, levels), levels, atol=0.005)
    with pytest.raises(ValueError, match="strictly between"):
        reliability(err, std[:5000], np.array([0.5, 1.0]))


def test_fit_std_scale(rng):
    std = rng.uniform(0.01, 0.2, 100_000)
    err = rng.normal(0, 1, std.size) * std
    s = fit_std_scale(err, 4 * std)  # four times too wide: the fitted factor undoes it
    assert s == pytest.approx(0.25, rel=0.02)
    assert coverage(err, s * 4 * std)["1"] == pytest.approx(GAUSSIAN_COVERAGE["1"], abs=1e-4)
    assert coverage(err, s * 4 * std)["1"] >= GAUSSIAN_COVERAGE["1"]
    assert fit_std_scale(err, std, level=0.9545) == pytest.approx(2.0, rel=0.02)
    with pytest.raises(ValueError, match="no finite positive"):
        fit_std_scale(err, np.where(np.arange(std.size) < 50_000, 0.0, std))  # zero std on half the pixels


def _spread_case(rng, n=100_000):
    """Raw std log-uniform on [0.1, 1] and errors drawn from N(0, f(s)^2) with f(s) = s^2 (faster than linear)."""
    s = np.exp(rng.uniform(np.log(0.1), np.log(1.0), n))
    return rng.normal(0, 1, n) * s**2, s


def test_fit_std_map_recovers_a_known_spread(rng):
    err, s = _spread_case(rng)
    m = fit_std_map(err, s)
    x, y = np.array(m["std"]), np.array(m["calibrated"])
    assert x.size == 16 and (np.diff(x) > 0).all() and (np.diff(y) > 0).all()
    assert x[0] > 0.1 and x[-1] < 1.0  # the bins' median raw std
    np.testing.assert_allclose(y, x**2, rtol=0.05)  # the true spread f at the knots
    fresh_err, fresh_s = _spread_case(rng)  # calibrated on new draws: the Gaussian levels at 1, 2 and 3 std
    cov = coverage(fresh_err, apply_std_map(fresh_s, m))
    for k, tol in (("1", 0.01), ("2", 0.005), ("3", 0.002)):
        assert cov[k] == pytest.approx(GAUSSIAN_COVERAGE[k], abs=tol)
    scale = fit_std_scale(err, s)  # one factor: right at 1 std, far too narrow at 2 std
    one = coverage(fresh_err, scale * fresh_s)
    assert one["1"] == pytest.approx(GAUSSIAN_COVERAGE["1"], abs=0.01) and one["2"] < 0.92
    # a std proportional to the spread: the map is the factor (slope 1 in log-log)
    m1 = fit_std_map(err, 3 * s**2)
    np.testing.assert_allclose(np.array(m1["calibrated"]) / np.array(m1["std"]), 1 / 3, rtol=0.05)


def test_std_map_bin_value_is_the_least_squares_optimum(rng):
    """One bin: the fitted value beats every other candidate on the summed squared coverage error."""
    from scipy.special import erf

    err = np.abs(rng.standard_t(3, 400))
    m = fit_std_map(err, np.ones(err.size), n_bins=1)
    assert m["std"] == [1.0]

    def loss(c):
        return sum((np.mean(err <= k * c * (1 + 1e-12)) - erf(k / np.sqrt(2))) ** 2 for k in (1, 2, 3))

    best = m["calibrated"][0]
    grid = np.concatenate([err / k for k in (1, 2, 3)])
    assert loss(best) <= min(loss(c) for c in grid) + 1e-15
    assert apply_std_map(np.array([0.5, 2.0]), m) == pytest.approx([best / 2, best * 2])  # one knot: proportional


def test_std_map_is_strictly_increasing_and_inverts(rng):
    s = rng.uniform(0.1, 1.0, 50_000)
    err = rng.normal(0, 1, s.size) * (1.1 - s)  # errors that fall as the std rises: a flat map, still increasing
    m = fit_std_map(err, s)
    lx, ly = np.log(m["std"]), np.log(m["calibrated"])
    assert (np.diff(ly) / np.diff(lx) >= STD_MAP_MIN_SLOPE * (1 - 1e-9)).all()
    grid = np.concatenate([[0.0], np.geomspace(1e-4, 10, 2000)])  # beyond both end knots too
    out = apply_std_map(grid, m)
    assert out[0] == 0 and (np.diff(out) > 0).all()
    np.testing.assert_allclose(invert_std_map(out, m), grid, rtol=1e-9)
    stored = apply_std_map(grid, m).astype(np.float32)  # as predict stores it
    np.testing.assert_allclose(invert_std_map(stored, m), grid, rtol=1e-5)
    with pytest.raises(ValueError, match="strictly increasing"):
        apply_std_map(grid, {"std": [1.0, 2.0], "calibrated": [1.0, 1.0]})
    with pytest.raises(ValueError, match="lists"):
        invert_std_map(grid, {"std": [1.0]})
    with pytest.raises(ValueError, match="negative"):
        apply_std_map(-grid[1:], m)
    with pytest.raises(ValueError, match="cannot fill"):
        fit_std_map(err[:10], np.r_[np.zeros(5), s[:5]], n_bins=8)
    with pytest.raises(ValueError, match="every error is zero"):
        fit_std_map(np.zeros(100), s[:100])


def _mixture_case(rng, n=80_000):
    """Two kinds of pixel with the same raw std: value 0 with errors 0.1 s, value 1 with errors s."""
    s = np.exp(rng.uniform(np.log(0.1), np.log(1.0), n))
    values = (rng.random(n) < 0.5).astype(np.float64)
    return rng.normal(0, 1, n) * s * np.where(values > 0, 1.0, 0.1), s, values


@pytest.mark.slow
def test_value_std_map_separates_a_mixture_that_one_map_cannot(rng):
    err, s, values = _mixture_case(rng)
    m = fit_value_std_map(err, s, values)
    # quartile edges {0, 1}: bin (-inf, 0) is empty and merged with the next -> bins (-inf, 1), [1, inf)
    assert m["value_edges"] == [1.0] and len(m["maps"]) == 2
    for one, factor in zip(m["maps"], (0.1, 1.0)):  # each bin's map is its true spread
        np.testing.assert_allclose(np.array(one["calibrated"]) / np.array(one["std"]), factor, rtol=0.06)
        assert one == fit_std_map(err[values == (factor > 0.5)], s[values == (factor > 0.5)])
    fresh_err, fresh_s, fresh_values = _mixture_case(rng)
    cov = coverage(fresh_err, apply_std_map(fresh_s, m, fresh_values))
    for k, tol in (("1", 0.01), ("2", 0.005), ("3", 0.003)):
        assert cov[k] == pytest.approx(GAUSSIAN_COVERAGE[k], abs=tol)
    one = coverage(fresh_err, apply_std_map(fresh_s, fit_std_map(err, s)))  # one map: a heavy-tailed mixture
    assert abs(one["1"] - GAUSSIAN_COVERAGE["1"]) + abs(one["2"] - GAUSSIAN_COVERAGE["2"]) > 0.03
    # inverse, per bin; float32 as predict stores it
    calibrated = apply_std_map(fresh_s, m, fresh_values)
    np.testing.assert_allclose(invert_std_map(calibrated.astype(np.float32), m, fresh_values), fresh_s, rtol=1e-5)
    cal = {"std_map": m, "scale": 2.0}
    np.testing.assert_allclose(calibrated_std(fresh_s, cal, fresh_values), calibrated)
    np.testing.assert_allclose(raw_std(calibrated.astype(np.float32), cal, fresh_values), fresh_s, rtol=1e-5)
    # uncertainty_summary bins by the reconstructions (here 10 * value + error), over the mask's pixels only
    recos, gts = 10 * fresh_values + fresh_err, 10 * fresh_values
    m2 = fit_value_std_map(err, s, 10 * values + err)
    mask = rng.random(fresh_s.size) < 0.5
    stds, recos3, gts3, mask3 = (a.reshape(8, 100, 100) for a in (fresh_s, recos, gts, mask))
    summary = uncertainty_summary(stds, recos3, gts3, std_map=m2, mask=mask3)
    expected = coverage(fresh_err[mask], apply_std_map(fresh_s[mask], m2, recos[mask]))
    assert summary["coverage"]["calibrated"] == expected


def test_value_std_map_checks_its_input(rng):
    err, s, _ = _mixture_case(rng, 4000)
    constant = fit_value_std_map(err, s, np.full(err.size, 0.3))  # one value: one bin, the plain map
    assert constant == {"value_edges": [], "maps": [fit_std_map(err, s)]}
    values = np.linspace(0, 1, err.size)
    m = fit_value_std_map(err, s, values, n_value_bins=3)
    assert len(m["value_edges"]) == 2 and len(m["maps"]) == 3
    exact = np.where(values >= m["value_edges"][1], 0.0, err)  # the top bin has no error: merged with the one before
    merged = fit_value_std_map(exact, s, values, n_value_bins=3)
    assert merged["value_edges"] == m["value_edges"][:1] and merged["maps"][0] == m["maps"][0]
    upper = values >= m["value_edges"][0]
    assert merged["maps"][1] == fit_std_map(exact[upper], s[upper])
    with pytest.raises(ValueError, match="conditioned on the predicted value"):
        apply_std_map(s, m)
    with pytest.raises(ValueError, match="shape"):
        apply_std_map(s, m, s[:-1])
    with pytest.raises(ValueError, match="one map more than edges"):
        apply_std_map(s, {"value_edges": [0.5], "maps": m["maps"][:1]}, s)
    with pytest.raises(ValueError, match="finite predicted values"):
        fit_value_std_map(err, s, np.r_[s[:-1], np.nan])
    with pytest.raises(ValueError, match="n_value_bins"):
        fit_value_std_map(err, s, s, n_value_bins=0)
    with pytest.raises(ValueError, match="every error is zero"):
        fit_value_std_map(np.zeros(100), s[:100], s[:100])


def _brute_force_mae_curve(err, key, fractions):
    """Remove the pixels with the largest ``key`` one fraction at a time and average the rest."""
    out = []
    for f in fractions:
        keep = np.argsort(-key, kind="stable")[int(np.floor(f * err.size + 1e-9)) :]
        out.append(err[keep].mean() / err.mean())
    return np.array(out)


def test_sparsification(rng):
    err = np.abs(rng.normal(0, 1, 20_000))
    exact = sparsification(err, err)  # std = |error|: the oracle's order, AUSE 0
    assert exact["ause"] == pytest.approx(0, abs=1e-12) and exact["curve"][0] == pytest.approx(1)
    assert exact["ause_random"] > 0.3
    random = sparsification(err, rng.random(err.size))  # an unrelated std: random order
    assert random["ause"] == pytest.approx(random["ause_random"], rel=0.05)
    assert random["ause_ratio"] == pytest.approx(1, abs=0.05)
    flat = sparsification(err, np.full(err.size, 0.3))  # all tied: exactly the random curve
    np.testing.assert_allclose(flat["curve"], 1.0)
    assert flat["ause_ratio"] == pytest.approx(1, abs=1e-12)
    inverse = sparsification(err, 1 / (err + 1e-3))  # the worst order: far above random
    assert inverse["ause_ratio"] > 1.5
    # against a brute-force implementation on a small case without ties
    e, s = np.abs(rng.normal(0, 1, 300)), rng.random(300) + np.abs(rng.normal(0, 1, 300))
    f = np.linspace(0, 0.9, 10)
    sp = sparsification(e, s, f)
    np.testing.assert_allclose(sp["curve"], _brute_force_mae_curve(e, s, f), rtol=1e-12)
    np.testing.assert_allclose(sp["oracle"], _brute_force_mae_curve(e, e, f), rtol=1e-12)
    assert sp["ause"] == pytest.approx(np.trapezoid(sp["curve"] - sp["oracle"], f))
    assert np.isnan(sparsification(np.zeros(10), np.ones(10))["ause"])
    with pytest.raises(ValueError, match="increasing"):
        sparsification(e, s, np.array([0.0, 1.0]))


def test_support_mask_and_restriction():
    gts = np.zeros((2, 15, 15))
    gts[0, 7, 7] = 1.0  # one object pixel in the middle of image 0, none in image 1
    mask = support_mask(gts)
    assert mask[0].sum() == 13  # a disk of radius 2: 1 + 4 + 4 + 4 pixels
    assert mask[0, 7, 9] and mask[0, 8, 8] and not mask[0, 9, 9]
    assert not mask[1].any()  # the dilation stays within its image
    assert support_mask(gts[0], radius=0).sum() == 1
    # background pixels: huge errors and std; support: error = std. Restricted, the std is exact.
    std = np.full(gts.shape, 5.0)
    recos = gts + np.where(mask, 0.0, 3.0)
    recos[0, 7, 7] += 0.2
    std[mask] = np.abs(recos - gts)[mask] + 0.01
    u_all = uncertainty_summary(std, recos, gts)
    u_in = uncertainty_summary(std, recos, gts, mask=mask)
    assert u_in["n_pixels"] == 13 and u_all["n_pixels"] == gts.size
    assert u_in["mean_abs_error"] == pytest.approx(0.2 / 13)
    assert u_in["coverage"]["raw"]["1"] == 1.0 and u_in["ause"] == pytest.approx(0, abs=1e-12)
    assert u_all["mean_abs_error"] > 2


def test_edge_std():
    img = np.zeros((20, 20))
    img[:, 10:] = 1.0  # a vertical edge between columns 9 and 10
    e = edge_std(img, sigma=0)
    assert e[5, 9] == pytest.approx(0.5) and e[5, 10] == pytest.approx(0.5) and e[5, 3] == 0  # |grad| / px
    smooth = edge_std(img)
    assert smooth[5].argmax() in (9, 10) and smooth[5, 8] > 0 and smooth[5, 0] < 1e-6
    stack = np.stack([img, img.T])
    np.testing.assert_allclose(edge_std(stack), np.stack([smooth, edge_std(img.T)]))  # image by image
    assert not edge_std(np.ones((8, 8))).any()


def test_calibrated_and_raw_std_follow_the_stored_calibration():
    raw = np.linspace(0.01, 0.2, 50, dtype=np.float32)
    std_map = {"std": [0.02, 0.1], "calibrated": [0.01, 0.3]}
    cases = (({"std_map": std_map, "scale": 2.0}, apply_std_map(raw, std_map)), ({"scale": 2.0}, 2.0 * raw))
    for cal, expected in cases:
        stored = calibrated_std(raw, cal)
        np.testing.assert_allclose(stored, expected, rtol=1e-12)  # the map wins over the one factor
        np.testing.assert_allclose(raw_std(stored.astype(np.float32), cal), raw, rtol=1e-5)
    assert calibrated_std(raw, {}) is None and raw_std(raw, {}) is raw
