import numpy as np
import pytest
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from nanoct.metrics import psnr, ssim, summarize


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
    from nanoct.metrics import uncertainty_summary

    std = rng.uniform(0.01, 0.2, (4, 32, 32))
    gts = rng.random((4, 32, 32))
    recos = gts + rng.normal(0, 1, std.shape) * std  # errors drawn with exactly that std
    u = uncertainty_summary(std, recos, gts)
    for k, expected in u["calibration"]["expected"].items():
        assert u["calibration"]["observed"][k] == pytest.approx(expected, abs=0.02)
    assert u["std_error_corr"] > 0.4  # larger std, larger errors
    over = uncertainty_summary(std * 3, recos, gts)  # over-dispersed: covers too much
    assert over["calibration"]["observed"]["1"] > 0.95
    unrelated = uncertainty_summary(rng.permutation(std.ravel()).reshape(std.shape), recos, gts)
    assert abs(unrelated["std_error_corr"]) < 0.1
    with pytest.raises(ValueError, match="negative"):
        uncertainty_summary(-std, recos, gts)
