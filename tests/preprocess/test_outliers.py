"""Outlier removal against a direct numpy median filter and algotom's zinger removal."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

from nanoct.core.errors import NanoctError
from nanoct.preprocess.outliers import remove_outliers


def _smooth_scan(rng, views=3, rows=32, cols=40, noise=0.01):
    y, x = np.mgrid[0:rows, 0:cols]
    base = 0.5 + 0.3 * np.sin(x / 7.0) * np.cos(y / 9.0)
    return (base[None] * (1 + noise * rng.standard_normal((views, rows, cols)))).astype(np.float32)


def _median3(image):
    padded = np.pad(image, 1, mode="edge")
    return np.median(sliding_window_view(padded, (3, 3)), axis=(-2, -1))


def test_matches_a_direct_median_and_threshold(rng):
    clean = _smooth_scan(rng)
    data = clean.copy()
    hits = [(0, 5, 7), (1, 20, 30), (2, 31, 0), (2, 10, 10)]
    for k, i, j in hits:
        data[k, i, j] *= 3.0  # zingers
    data[1, 3, 4] = 0.0  # a dead pixel
    out, count = remove_outliers(data, threshold=5.0)
    for k in range(data.shape[0]):
        med = _median3(data[k].astype(np.float64))
        diff = np.abs(data[k].astype(np.float64) - med)
        sigma = 1.4826 * np.median(np.abs(np.diff(data[k].astype(np.float64), axis=1))) / np.sqrt(2)
        expected = np.where(diff > 5.0 * sigma, med, data[k])
        np.testing.assert_allclose(out[k], expected, rtol=1e-6)
    assert count == len(hits) + 1
    assert np.abs(out - clean).max() < 0.05  # every planted outlier replaced, nothing else moved much


def test_bright_only_keeps_dead_pixels(rng):
    data = _smooth_scan(rng)
    data[0, 5, 5] *= 4
    data[0, 9, 9] = 0
    out, count = remove_outliers(data, kind="bright")
    assert count == 1 and out[0, 9, 9] == 0 and out[0, 5, 5] < 1


def test_agrees_with_algotom_on_isolated_zingers(rng):
    removal = pytest.importorskip("algotom.prep.removal")
    clean = _smooth_scan(rng, views=1, rows=48, cols=48, noise=0.002)
    data = clean.copy()
    idx = rng.choice(44 * 44, 12, replace=False)
    data[0, 2:-2, 2:-2].flat[idx] *= 2.0  # away from the border, where algotom's neighbours wrap around
    ours, _ = remove_outliers(data, threshold=5.0, kind="bright")
    theirs = removal.remove_zinger(data[0], 0.08, size=1)
    inner = (slice(2, -2), slice(2, -2))
    # the same pixels replaced, by their neighbourhood's median (ours) or mean (algotom's)
    np.testing.assert_array_equal((ours[0] != data[0])[inner], (theirs != data[0])[inner])
    assert (ours[0] != data[0]).sum() == 12
    np.testing.assert_allclose(ours[0][inner], theirs[inner], atol=0.02)


def test_bad_options():
    data = np.ones((1, 4, 4), np.float32)
    with pytest.raises(NanoctError, match="threshold"):
        remove_outliers(data, threshold=0)
    with pytest.raises(NanoctError, match="outlier-size"):
        remove_outliers(data, size=4)
    with pytest.raises(NanoctError, match="kind"):
        remove_outliers(data, kind="hot")
