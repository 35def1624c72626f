"""Stripe removal: the same arrays through algotom's own functions, and rings on a constructed slice."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.core.geometry import Geometry
from nanoct.preprocess.rings import ring_metric
from nanoct.preprocess.stripes import STRIPE_METHODS, remove_stripes, stripe_function
from nanoct.recon.fbp import fbp

removal = pytest.importorskip("algotom.prep.removal")


def _disc_sinogram(n_views=120, n_det=95, stripes=True, seed=0):
    """Line integrals of an off-centre Gaussian blob (width 10 px, 180 degrees), with detector-pixel offsets."""
    t = np.arange(n_det) - (n_det - 1) / 2
    phi = np.arange(n_views) * np.pi / n_views
    centre = 15 * np.cos(phi) + 8 * np.sin(phi)  # the blob at (15, 8) pixels from the axis
    sino = 0.5 * np.exp(-((t[None, :] - centre[:, None]) ** 2) / (2 * 10.0**2))
    sino += 0.002 * np.random.default_rng(seed).standard_normal((n_views, n_det))
    if stripes:
        sino[:, [20, 41, 60, 71]] += [0.05, -0.04, 0.06, 0.03]  # pixels off by a constant: rings
    return sino.astype(np.float32)


@pytest.mark.parametrize("method", sorted(STRIPE_METHODS))
def test_same_as_algotom_on_each_row(method):
    stack = np.stack([_disc_sinogram(seed=0), _disc_sinogram(seed=1)], axis=1)  # (K, 2 rows, L)
    func = getattr(removal, STRIPE_METHODS[method][0])
    params = {"size": 15} if method in ("sorting", "filtering") else {}
    ours = remove_stripes(stack, method, params)
    for r in range(2):
        expected = func(stack[:, r, :], **stripe_function(method, params)[1])
        np.testing.assert_allclose(ours[:, r, :], expected, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(remove_stripes(stack[:, 0], method, params), ours[:, 0], rtol=1e-6)


def test_default_removes_the_rings_of_a_constructed_slice():
    geometry = Geometry.from_angles(np.arange(120) * np.pi / 120, 95, 95)
    clean = ring_metric(fbp(geometry, _disc_sinogram(stripes=False)).image)
    striped = ring_metric(fbp(geometry, _disc_sinogram()).image)
    removed = ring_metric(fbp(geometry, remove_stripes(_disc_sinogram())).image)
    assert striped > 50 * clean
    assert removed < striped / 10


def test_bad_method_parameter_and_values():
    data = _disc_sinogram()
    with pytest.raises(NanoctError, match="--stripes 'wavelet'"):
        remove_stripes(data, "wavelet")
    with pytest.raises(NanoctError, match="'snr' is not one of method 'sorting'"):
        remove_stripes(data, "sorting", {"snr": 3})
    with pytest.raises(NanoctError, match="must not exceed"):
        remove_stripes(data, "sorting", {"size": 200})
    data[3, 3] = np.inf
    with pytest.raises(NanoctError, match="infinite"):
        remove_stripes(data)
