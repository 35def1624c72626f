"""The ring metric against a direct loop, and its response to a ring."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import savgol_filter

from nanoct.preprocess.rings import radial_profile, ring_metric


def test_profile_matches_a_direct_loop(rng):
    image = rng.standard_normal((41, 41))
    profile = radial_profile(image)
    assert profile.shape == (20,)
    for r in (0, 3, 19):
        pixels = [image[i, j] for i in range(41) for j in range(41) if round(np.hypot(i - 20, j - 20)) == r]
        assert profile[r] == pytest.approx(np.mean(pixels), rel=1e-12)
    high = profile - savgol_filter(profile, 11, 2, mode="interp")
    assert ring_metric(image) == pytest.approx(np.sum(high[3:] ** 2), rel=1e-12)


def test_a_ring_raises_it_and_a_smooth_object_does_not():
    n = 101
    y, x = np.indices((n, n)) - (n - 1) / 2
    r = np.hypot(x, y)
    disc = np.exp(-(r**2) / (2 * 15**2))  # smooth and centred: its profile has no high-pass part
    ring = disc + 0.05 * (np.abs(r - 20) < 0.7)
    assert ring_metric(ring) > 20 * ring_metric(disc)  # measured 58x
    shifted = np.exp(-((x - 15) ** 2 + (y - 8) ** 2) / (2 * 10**2))  # off-centre: its profile is smooth too
    assert ring_metric(shifted + 0.05 * (np.abs(r - 20) < 0.7)) > 20 * ring_metric(shifted)
