"""Analytic ellipse sinograms against ASTRA's projection of the rasterised phantom."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.geometry import Geometry
from nanoct.core.operators import RayTransform
from nanoct.sim.analytic import Ellipse, ellipse_sinogram, rasterize_ellipses, stack_phantom

N, K, L = 64, 60, 91


def _phantom() -> list[Ellipse]:
    return [Ellipse(3.0, -2.0, 22.0, 14.0, 0.4, 1.0), Ellipse(-6.0, 5.0, 6.0, 3.0, -0.7, 0.5)]


@pytest.mark.parametrize("offset", [0.0, 2.5])
def test_matches_astra_with_shifts_and_axis_offset(offset):
    geometry = Geometry("parallel", N, K, L, center_offset=offset)
    d = np.random.default_rng(0).uniform(-4, 4, K)
    phi = geometry.angles
    motion = np.stack([d * np.cos(phi), d * np.sin(phi), np.zeros(K)], axis=1)
    fine = 8
    image = rasterize_ellipses(_phantom(), N, fine)
    reference = RayTransform(geometry, motion, oversample=fine).forward(np.kron(image, np.ones((fine, fine))))
    exact = ellipse_sinogram(_phantom(), phi, L, shifts=d, center_offset=offset)
    assert np.linalg.norm(exact - reference) / np.linalg.norm(reference) < 0.02
    # a wrong sign of the shift or of the offset is far off
    flipped = ellipse_sinogram(_phantom(), phi, L, shifts=-d, center_offset=-offset - 1)
    assert np.linalg.norm(flipped - reference) / np.linalg.norm(reference) > 0.2


def test_line_integral_of_a_disc_and_mass():
    disc = [Ellipse(0.0, 0.0, 10.0, 10.0, 0.0, 2.0)]
    sino = ellipse_sinogram(disc, [0.0, 1.0], 41, subsamples=4)
    assert sino[0, 20] == pytest.approx(2 * 2.0 * 10.0, rel=1e-3)  # chord through the centre
    assert sino.sum(axis=1) == pytest.approx([2.0 * np.pi * 100] * 2, rel=1e-3)  # mass of every view


def test_stack_phantom_is_inside_the_field_of_view_and_seeded():
    slices = stack_phantom(128, 3, seed=1)
    assert len(slices) == 3 and slices != stack_phantom(128, 3, seed=2)
    image = rasterize_ellipses(slices[0], 128)
    yy, xx = np.mgrid[:128, :128] - 63.5
    assert np.all(image[np.hypot(xx, yy) > 0.46 * 128] == 0)
