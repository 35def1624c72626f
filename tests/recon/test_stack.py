"""Motion-corrected FBP, Joseph reprojection and the coarse-to-fine stack motion."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.core.geometry import Geometry
from nanoct.core.operators import RayTransform
from nanoct.io.rawscan import axis_after
from nanoct.motion.stack import estimate_stack_motion
from nanoct.recon.fbp import fbp
from nanoct.recon.stack import (
    bin_geometry,
    bin_sinograms,
    corrected_fbp,
    reproject,
)
from nanoct.sim.analytic import ellipse_sinogram, rasterize_ellipses, stack_phantom

N, K, L = 96, 120, 137


def _gauge_free_rms(estimate, truth, angles):
    """RMS of the difference after removing what no method can tell: a constant and a translation."""
    basis = np.stack([np.ones_like(angles), np.cos(angles), np.sin(angles)], axis=1)
    diff = np.asarray(estimate) - np.asarray(truth)
    return float(np.sqrt(np.mean((diff - basis @ np.linalg.lstsq(basis, diff, rcond=None)[0]) ** 2)))


def test_corrected_fbp_without_shifts_is_fbp():
    geometry = Geometry("parallel", N, K, L, center_offset=1.5)
    sino = ellipse_sinogram(stack_phantom(N, 1)[0], geometry.angles, L, center_offset=1.5)
    reference = fbp(geometry, sino).image
    ours = corrected_fbp(geometry, sino)
    # equal up to float32 and the outermost detector pixel (read by fbp, skipped here)
    assert np.linalg.norm(ours - reference) / np.linalg.norm(reference) < 1e-3


def test_corrected_fbp_undoes_the_shifts_and_the_sign_matters():
    geometry = Geometry("parallel", N, K, L)
    phantom = stack_phantom(N, 1, seed=4)[0]
    d = np.random.default_rng(1).uniform(-5, 5, K)
    moved = ellipse_sinogram(phantom, geometry.angles, L, shifts=d, subsamples=4)
    still = corrected_fbp(geometry, ellipse_sinogram(phantom, geometry.angles, L, subsamples=4), filter="hann")

    def error(shifts):
        return np.linalg.norm(corrected_fbp(geometry, moved, shifts, "hann") - still) / np.linalg.norm(still)

    assert error(d) < 0.04  # up to the linear interpolation of the filtered views
    assert error(-d) > 10 * error(d) and error(np.zeros(K)) > 10 * error(d)


@pytest.mark.parametrize("offset", [0.0, -2.5])
def test_reproject_matches_astra_and_the_exact_projection(offset):
    geometry = Geometry("parallel", N, K, L, center_offset=offset)
    phantom = stack_phantom(N, 1, seed=2)[0]
    image = rasterize_ellipses(phantom, N, 4)
    d = np.random.default_rng(0).uniform(-3, 3, K)
    phi = geometry.angles
    motion = np.stack([d * np.cos(phi), d * np.sin(phi), np.zeros(K)], axis=1)
    astra = RayTransform(geometry, motion).forward(image)
    exact = ellipse_sinogram(phantom, phi, L, shifts=d, center_offset=offset, subsamples=4)
    ours = reproject(geometry, image, d)
    assert np.linalg.norm(ours - astra) / np.linalg.norm(astra) < 0.02
    assert np.linalg.norm(ours - exact) / np.linalg.norm(exact) < 0.02
    assert np.linalg.norm(reproject(geometry, image, -d) - exact) / np.linalg.norm(exact) > 0.2


def test_binning_keeps_the_axis_where_the_import_puts_it():
    geometry = Geometry("parallel", 256, 10, 256, center_offset=3.25)
    small = bin_geometry(geometry, 4)
    assert (small.n, small.n_det) == (64, 64)
    assert small.center_offset == pytest.approx(axis_after(3.25, 256, None, 4))
    assert bin_sinograms(np.arange(8.0)[None], 4).tolist() == [[1.5, 5.5]]


def test_fan_beam_is_refused():
    with pytest.raises(NanoctError, match="parallel-beam"):
        corrected_fbp(Geometry("fan", 16, 8, 31, source_radius=100.0, angle_range=2 * np.pi), np.zeros((8, 31)))


def _moving_scan(n_det=256, k=360, offset=2.7):
    phi = np.arange(k) * np.pi / k
    t = np.arange(k) / k
    d = 3 * t**2 - 2 * t + 1.2 * np.cos(2 * phi) + np.random.default_rng(0).uniform(-2, 2, k)
    sino = np.stack([ellipse_sinogram(e, phi, n_det, shifts=d, center_offset=offset, subsamples=2)
                     for e in stack_phantom(n_det, 2, seed=1)])  # fmt: skip
    basis = np.stack([np.ones(k), np.cos(phi), np.sin(phi)], axis=1)
    return Geometry.from_angles(phi, n_det, n_det), sino, d, offset - np.linalg.lstsq(basis, d, rcond=None)[0][0]


def test_stack_motion_and_axis_from_the_centroids():
    geometry, sino, d, axis = _moving_scan()
    result = estimate_stack_motion(geometry, sino)
    assert result.center_method == "centroid" and result.mass_spread < 1e-3 and result.steps == []
    assert result.center_offset == pytest.approx(axis, abs=0.02)
    assert _gauge_free_rms(result.shifts, d, geometry.angles) < 0.02
    assert _gauge_free_rms(np.zeros(geometry.n_angles), d, geometry.angles) > 1.0  # the motion is there to be found


def test_stack_motion_without_centroids():
    """Opposite views, binned Dremel and projection matching: what is used for objects that leave the detector."""
    geometry, sino, d, axis = _moving_scan()
    result = estimate_stack_motion(geometry, sino, binning=4, refine=(1,) * 6, centroid_tolerance=0.0)
    assert result.center_method == "opposite views" and len(result.steps) == 6
    assert result.center_offset == pytest.approx(axis, abs=0.5)
    assert _gauge_free_rms(result.shifts, d, geometry.angles) < 0.3
    assert _gauge_free_rms(result.coarse, d, geometry.angles) < 1.0


def test_stack_motion_with_a_given_axis_keeps_it():
    geometry, sino, d, axis = _moving_scan()
    result = estimate_stack_motion(geometry, sino, center=2.7, refine=())
    assert result.center_offset == 2.7 and result.center_method == "given"
    assert _gauge_free_rms(result.shifts, d, geometry.angles) < 0.02
