"""The array API at the top level: nanoct.fbp / kaczmarz / dremel / resesop on plain arrays."""

from __future__ import annotations

import numpy as np
import pytest

import nanoct
from nanoct.core.geometry import Geometry, get_preset
from nanoct.core.operators import RayTransform
from nanoct.recon.dremel import dremel as dremel_solver
from nanoct.recon.fbp import fbp as fbp_solver


@pytest.fixture(scope="module")
def data():
    g = get_preset("tiny-parallel")
    x = np.zeros(g.image_shape, np.float32)
    x[20:40, 25:45] = 1.0
    return g, x, RayTransform(g).forward(x)


def test_angles_give_the_same_result_as_the_geometry(data):
    g, _, y = data
    by_angles = nanoct.fbp(y, angles=g.angles, size=g.n)
    np.testing.assert_array_equal(by_angles.image, fbp_solver(g, y).image)
    by_degrees = nanoct.dremel(y, angles=np.rad2deg(g.angles), degrees=True, size=g.n, n_iter=3)
    np.testing.assert_array_equal(by_degrees.image, dremel_solver(g, y, n_iter=3).image)
    assert by_degrees.motion.shape == (g.n_angles,)


def test_every_method_is_there_and_takes_its_parameters(data):
    g, x, y = data
    assert nanoct.kaczmarz(y, g, n_iter=2).params["n_iter"] == 2
    res = nanoct.resesop(y, g, eta=np.zeros(g.n_angles), n_iter=3)
    assert res.image.shape == g.image_shape and np.isfinite(res.image).all()
    assert nanoct.fbp(y, g, filter="hann").params["filter"] == "hann"
    assert isinstance(nanoct.make_geometry(y, angles=g.angles, center_offset=1.0), Geometry)


def test_the_solvers_other_arguments_pass_through(data):
    g, x, y = data
    shifts = np.linspace(-1.0, 1.0, g.n_angles)
    np.testing.assert_array_equal(nanoct.fbp(y, g, shifts=shifts).image, fbp_solver(g, y, shifts=shifts).image)
    fixed = nanoct.dremel(y, g, n_iter=2, shifts0=shifts, fix_shifts=True)
    np.testing.assert_array_equal(fixed.motion, shifts.astype(np.float32))
    seen = []
    nanoct.kaczmarz(y, g, n_iter=2, x0=x, callback=lambda it, image, extra: seen.append(it))
    assert seen == [0, 1]
    moved = nanoct.resesop(y, g, eta=np.zeros(g.n_angles), n_iter=2, shifts=shifts)
    assert np.isfinite(moved.image).all()
    with pytest.raises(nanoct.api.NanoctError, match="shifts_from: parameters of 'nanoct reconstruct'.*shifts0="):
        nanoct.dremel(y, g, shifts_from="shifts.txt")


def test_bad_calls(data):
    g, _, y = data
    with pytest.raises(ValueError, match="either geometry= or angles="):
        nanoct.fbp(y)
    with pytest.raises(ValueError, match="either geometry= or angles="):
        nanoct.fbp(y, g, angles=g.angles)
    with pytest.raises(ValueError, match="shape"):
        nanoct.fbp(y[:, :-1], g)
    with pytest.raises(ValueError, match="angle"):
        nanoct.fbp(y, angles=g.angles[:-1])
    with pytest.raises(nanoct.api.NanoctError, match="not a parameter"):
        nanoct.kaczmarz(y, g, sweeps=3)
    with pytest.raises(AttributeError):
        nanoct.sirt  # noqa: B018


def test_the_examples_in_the_array_api_docstring_run():
    import doctest

    import nanoct.api

    result = doctest.testmod(nanoct.api, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted >= 8 and result.failed == 0
