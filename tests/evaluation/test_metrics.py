import numpy as np
import pytest
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from nanoct.evaluation.metrics import (
    GAUSSIAN_COVERAGE,
    coverage,
    edge_std,
    interval_scores,
    partial_correlation,
    psnr,
    register,
    reliability,
    sparsification,
    ssim,
    summarize,
    support_mask,
    truth_support,
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


def _blobs(n: int = 48) -> np.ndarray:
    from scipy import ndimage

    img = np.zeros((n, n))
    img[14:30, 10:34] = 1.0
    img[20:26, 18:24] = 2.0
    img[34:40, 30:36] = 0.5
    return ndimage.gaussian_filter(img, 1.2)


@pytest.mark.parametrize("shift", [(0.3, -0.45), (-1.7, 0.8), (0.0, 0.25)])
def test_register_recovers_a_known_subpixel_translation(shift):
    """The image moved by a known sub-pixel translation (scipy's spline shift, not the Fourier shift used inside)."""
    from scipy import ndimage

    gt = _blobs()
    moved = ndimage.shift(gt, shift, order=3, mode="constant")
    back, found = register(moved, gt)
    np.testing.assert_allclose(found, -np.asarray(shift), atol=0.06)
    assert psnr(back, gt) > psnr(moved, gt) + 10
    assert ssim(back, gt) > ssim(moved, gt)


def test_registered_scores_are_never_below_the_plain_ones(rng):
    """Noise with no translation: the registration keeps the image; a moved noisy image gains."""
    from scipy import ndimage

    gts = np.stack([_blobs()] * 4)
    recos = gts + rng.normal(0, 0.05, gts.shape)
    recos[2] = ndimage.shift(recos[2], (0.6, -0.4), order=3, mode="constant")
    s = summarize(recos, gts)
    assert all(r >= p for r, p in zip(s["psnr_registered_values"], s["psnr_values"]))
    assert s["psnr_registered_values"][2] > s["psnr_values"][2] + 1.0
    assert s["psnr_registered_mean"] > s["psnr_mean"] and s["ssim_registered_mean"] >= s["ssim_mean"] - 1e-9
    assert np.hypot(*s["shift_values"][2]) == pytest.approx(np.hypot(0.6, 0.4), abs=0.1)
    same, t = register(gts[0], gts[0])
    assert np.array_equal(same, gts[0]) and not np.any(t)


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
    u = uncertainty_summary(std, recos, gts, half_widths={"0.9": 1.6449 * std})
    assert u["intervals"]["0.9"]["coverage"] == pytest.approx(0.9, abs=0.02) and u["n_pixels"] == std.size
    assert u["std_error_corr"] > 0.4 and u["std_error_spearman"] > 0.4  # larger std, larger errors
    assert u["ause_ratio"] < 0.8  # ordering by std beats random order
    assert u["partial_corr_given_baseline"] is None
    over = uncertainty_summary(std * 3, recos, gts, half_widths={"0.9": 1.6449 * std})  # the same intervals
    assert over["intervals"]["0.9"] == u["intervals"]["0.9"]
    assert over["ause"] == pytest.approx(u["ause"]) and over["std_error_spearman"] == pytest.approx(
        u["std_error_spearman"]
    )
    assert over["ause"] == pytest.approx(u["ause"])  # the ordering does not depend on the scale
    assert over["std_error_corr"] == pytest.approx(u["std_error_corr"])
    unrelated = uncertainty_summary(rng.permutation(std.ravel()).reshape(std.shape), recos, gts)
    assert abs(unrelated["std_error_corr"]) < 0.1 and unrelated["intervals"] == {}
    with pytest.raises(ValueError, match="negative"):
        uncertainty_summary(-std, recos, gts)


def test_partial_correlation_against_residuals(rng):
    z = rng.normal(size=5000)
    x = z + 0.5 * rng.normal(size=z.size)
    y = z + 0.5 * rng.normal(size=z.size)  # x and y are related only through z
    assert abs(partial_correlation(x, y, z)) < 0.05 and np.corrcoef(x, y)[0, 1] > 0.7
    y2 = y + x
    res = [v - np.polyval(np.polyfit(z, v, 1), z) for v in (x, y2)]
    assert partial_correlation(x, y2, z) == pytest.approx(np.corrcoef(*res)[0, 1], abs=1e-9)
    assert np.isnan(partial_correlation(x, y, np.ones_like(z)))


def test_interval_scores_are_size_stratified(rng):
    """Intervals that cover on average but not where they are narrow show it in the width quintiles."""
    std = rng.uniform(0.1, 1.0, (10, 20, 20))
    err = rng.normal(size=std.shape) * 0.5  # the errors do not follow the std
    s = interval_scores(err, std)
    assert s["coverage"] == pytest.approx(np.mean(np.abs(err) <= std))
    assert s["width_error_corr"] == pytest.approx(np.corrcoef(std.ravel(), np.abs(err).ravel())[0, 1])
    assert s["coverage_by_width"][0] < 0.4 < 0.9 < s["coverage_by_width"][-1]
    assert s["mean_half_width"] == pytest.approx(std.mean())
    mask = np.zeros(std.shape, bool)
    mask[:5] = True  # the first five images only
    m = interval_scores(err, std, mask)
    per_image = [np.mean(np.abs(err[i]) <= std[i]) for i in range(5)]
    expected = {"min": min(per_image), "max": max(per_image), "std": np.std(per_image)}
    assert m["image_coverage"] == pytest.approx(expected)


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
    u_in = uncertainty_summary(std, recos, gts, mask=mask, half_widths={"0.68": std})
    assert u_in["n_pixels"] == 13 and u_all["n_pixels"] == gts.size
    assert u_in["mean_abs_error"] == pytest.approx(0.2 / 13)
    assert u_in["intervals"]["0.68"]["coverage"] == 1.0 and u_in["ause"] == pytest.approx(0, abs=1e-12)
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


def test_the_support_of_a_reconstructed_reference_is_thresholded_not_positive():
    """A phantom keeps ``gt > 0`` dilated; a reference with noise (negative values) is positive over half its
    background, so there the object is the smoothed reference above 30 % of its 99th percentile, dilated."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[:40, :40] - 20
    disc = np.hypot(yy, xx) < 8
    phantom = np.where(disc, 0.5, 0.0)
    reference = phantom + rng.normal(0, 0.01, phantom.shape)
    both = truth_support(np.stack([phantom, reference]))
    np.testing.assert_array_equal(both[0], support_mask(phantom))
    assert (reference[~disc] > 0).mean() > 0.4  # "> 0" would take half the background
    for found, true in ((both[1], support_mask(disc)), (truth_support(reference, radius=0), disc)):
        assert (found & true).sum() / (found | true).sum() > 0.9  # the smoothed edge, within a pixel
        assert not found[np.hypot(yy, xx) > 13].any()
    # a reference known only in a field of view: the percentile is that of the known pixels, so values
    # outside it (here a bright ring) do not move the threshold
    view = np.hypot(yy, xx) < 15
    ringed = np.where(view, reference, 5.0)
    assert not truth_support(ringed, 0)[disc].any()
    found = truth_support(ringed, 0, known=view)
    inner = np.hypot(yy, xx) < 12  # away from the ring, which the smoothing spreads over the view's edge
    np.testing.assert_array_equal(found[inner], truth_support(np.where(view, reference, -1.0), 0, known=view)[inner])
    assert ((found & inner) & disc).sum() / ((found & inner) | disc).sum() > 0.9
