"""Gridrec against FBP, a direct Fourier sum, ASTRA's back projection and the motion convention."""

from __future__ import annotations

import sys
import types

import astra
import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.core.geometry import Geometry, get_preset
from nanoct.core.operators import RayTransform
from nanoct.evaluation.metrics import psnr
from nanoct.recon import gridrec as gridrec_module
from nanoct.recon.fbp import fbp, ramp_filter
from nanoct.recon.gridrec import GridrecPlan, gridrec, gridrec_slices, select_backend
from nanoct.recon.stack import reproject
from nanoct.sim.analytic import ellipse_sinogram, rasterize_ellipses, stack_phantom


def _scan(n=96, n_det=96, views=120, offset=0.0, shifts=None, spacing=1.0, slices=1, seed=1):
    """(geometry, sinograms (S, K, L), phantoms (S, N, N)) of analytic ellipse slices."""
    phi = np.arange(views) * np.pi / views
    phantoms = stack_phantom(n, slices, seed=seed)
    sino = np.stack(
        [ellipse_sinogram(e, phi, n_det, shifts=shifts, center_offset=offset, spacing=spacing) for e in phantoms]
    )
    truth = np.stack([rasterize_ellipses(e, n, 2) for e in phantoms])
    return Geometry.from_angles(phi, n, n_det, center_offset=offset, det_spacing=spacing), sino, truth


def _smooth_wave(views):
    phi = np.arange(views) * np.pi / views
    return 1.5 * np.sin(3 * phi) + 0.8 * np.cos(phi) + 0.4 * np.linspace(-1, 1, views)


def _direct(geometry, sino, shifts, interpolation, period):
    """The formula of the module docstring, summed directly: each filtered view's Fourier series at each pixel."""
    n, n_det = geometry.n, geometry.n_det
    filtered = ramp_filter(sino, geometry.det_spacing)
    m = np.fft.fftfreq(period) * period
    series = np.fft.fft(filtered, n=period, axis=1) / period
    if interpolation == "linear":
        series *= np.sinc(m / period) ** 2
    if period % 2 == 0:
        series[:, period // 2] = 0.0
    r1 = np.arange(n)[None, :] - (n - 1) / 2
    r2 = (n - 1) / 2 - np.arange(n)[:, None]
    centre = (n_det - 1) / 2 + geometry.center_offset
    image = np.zeros((n, n))
    for k, (phi, w) in enumerate(zip(geometry.angles, geometry.angle_weights)):
        pos = (r1 * np.cos(phi) + r2 * np.sin(phi)) / geometry.det_spacing + centre - shifts[k]
        image += w * np.real(np.exp(2j * np.pi * pos[..., None] * m / period) @ series[k])
    return image


@pytest.mark.parametrize("interpolation", ["linear", "sinc"])
@pytest.mark.parametrize(
    ("n", "n_det", "offset", "spacing"), [(24, 24, 1.3, 1.0), (23, 30, -2.2, 1.0), (20, 12, 0.4, 2.0)]
)
def test_equals_the_direct_fourier_sum(interpolation, n, n_det, offset, spacing):
    """Same sum as a dense evaluation at every pixel: orientation, half-pixel grid, axis and shift phases."""
    views = 14
    phi = np.arange(views) * np.pi / views + 0.1
    geometry = Geometry.from_angles(phi, n, n_det, center_offset=offset, det_spacing=spacing)
    sino = np.random.default_rng(0).uniform(0, 1, geometry.sino_shape)
    shifts = np.random.default_rng(1).uniform(-2, 2, views)
    plan = GridrecPlan(geometry, shifts, interpolation=interpolation, eps=1e-12)
    ours = plan(sino)
    ref = _direct(geometry, sino, shifts, interpolation, plan.period)
    assert np.abs(ours - ref).max() < 1e-5 * np.abs(ref).max()
    assert np.abs(ref - ref[::-1]).max() > 0.1 * np.abs(ref).max()  # no symmetry hides a flip


@pytest.mark.parametrize(("filter", "rel_diff", "psnr_gap"), [("ram-lak", 0.08, 0.3), ("hann", 0.02, 0.05)])
def test_matches_fbp_with_and_without_motion(filter, rel_diff, psnr_gap):
    """Against nanoct's FBP on analytic slices (N = L = 128, 180 views, axis offset 2.3 px).

    The linear interpolation of FBP's back projection also aliases the highest detector
    frequencies, which the sinc^2 weighting does not model: measured relative L2 difference
    0.065 (Ram-Lak) and 0.014 (Hann), PSNR 0.15-0.23 dB (Ram-Lak) and < 0.01 dB (Hann) below
    FBP's at this size (0.05 dB at 2048 columns, ``benchmarks/bench_gridrec.py``).
    """
    views = 180
    for shifts in (None, _smooth_wave(views)):
        geometry, sino, truth = _scan(n=128, n_det=128, views=views, offset=2.3, shifts=shifts)
        ref = fbp(geometry, sino[0], shifts=shifts, filter=filter).image
        ours = gridrec(geometry, sino[0], shifts=shifts, filter=filter).image
        assert np.linalg.norm(ours - ref) < rel_diff * np.linalg.norm(ref)
        assert abs(psnr(ours, truth[0]) - psnr(ref, truth[0])) < psnr_gap
        assert psnr(ours, truth[0]) > 32


def test_back_projection_is_the_projectors_adjoint():
    """ASTRA's back projection (its strip projector's transpose) and nanoct's ray transform: <A x, y> = <x, B y>.

    Measured at small-parallel: 0.65 % from ASTRA on random views, 4.8 % on Ram-Lak-filtered
    views (nanoct's FBP: 0.8 %; the difference is the aliasing of linear interpolation at the
    highest frequencies); the inner products agree to 6e-5 (phantom) and 0.16 % of
    ``|A x| |y|`` (zero-mean noise).
    """
    g = get_preset("small-parallel")
    x = rasterize_ellipses(stack_phantom(g.n, 1, seed=3)[0], g.n, 2)
    sino = np.asarray(RayTransform(g)(x), dtype=np.float64)
    y = np.random.default_rng(2).uniform(0, 1, g.sino_shape)
    filtered = ramp_filter(sino, g.det_spacing)
    vol = astra.create_vol_geom(g.n, g.n)
    pid = astra.create_projector("strip", astra.create_proj_geom("parallel", 1.0, g.n_det, g.angles), vol)
    try:
        refs = []
        for views in (y, filtered):
            data_id, image = astra.creators.create_backprojection(views, pid)
            astra.data2d.delete(data_id)
            refs.append(image * g.angle_weights[0])
    finally:
        astra.projector.delete(pid)
    plan = GridrecPlan(g)
    for views, ref, tol in ((y, refs[0], 0.01), (filtered, refs[1], 0.06)):
        assert np.linalg.norm(plan.backproject(views) - ref) < tol * np.linalg.norm(ref)
    noise = np.random.default_rng(3).uniform(-1, 1, g.image_shape)
    for image, views in ((x, y), (noise, y - y.mean())):
        lhs = float(np.sum(RayTransform(g)(image) * views))
        rhs = float(np.sum(image * plan.backproject(views))) / g.angle_weights[0]
        assert abs(lhs - rhs) < 0.01 * np.linalg.norm(RayTransform(g)(image)) * np.linalg.norm(views)
    assert abs(float(np.sum(RayTransform(g)(x) * y)) - float(np.sum(x * plan.backproject(y))) / g.angle_weights[0]) < (
        1e-3 * float(np.sum(RayTransform(g)(x) * y))
    )


def test_shift_sign_follows_the_motion_convention():
    """A sinogram of a moved object (p_k(u) = P_k(u + d_k)), corrected with d, gives the unmoved image; -d does not.

    Measured (96^2, 150 views, shifts up to 6.8 px): PSNR 35.0 unmoved, 34.4 / 33.8 corrected
    (analytic / nanoct's projector), 22.7 / 23.1 with the opposite sign, 23.1 / 23.6 uncorrected.
    """
    views = 150
    d = 2.5 * _smooth_wave(views)
    geometry, still, truth = _scan(n=96, n_det=96, views=views)
    moved_analytic = _scan(n=96, n_det=96, views=views, shifts=d)[1][0]
    moved_reproject = reproject(geometry, truth[0], d)  # nanoct's projector with the same convention
    best = psnr(gridrec(geometry, still[0]).image, truth[0])
    for moved in (moved_analytic, moved_reproject):
        assert psnr(gridrec(geometry, moved, shifts=d).image, truth[0]) > best - 1.5
        assert psnr(gridrec(geometry, moved, shifts=-d).image, truth[0]) < best - 8
        assert psnr(gridrec(geometry, moved).image, truth[0]) < best - 8
    corrected = gridrec(geometry, moved_analytic, shifts=d).image
    ref = fbp(geometry, moved_analytic, shifts=d).image
    assert np.linalg.norm(corrected - ref) < 0.1 * np.linalg.norm(ref)  # measured 0.081


def test_axis_offset_is_a_constant_shift():
    """A rotation axis off the detector centre: reconstructed in place, and equal to shifting every view by -offset."""
    offset = 3.4
    geometry, sino, truth = _scan(n=96, n_det=104, views=150, offset=offset)
    ours = gridrec(geometry, sino[0]).image
    assert psnr(ours, truth[0]) > 28
    assert psnr(gridrec(Geometry.from_angles(geometry.angles, 96, 104), sino[0]).image, truth[0]) < 25
    as_shift = GridrecPlan(Geometry.from_angles(geometry.angles, 96, 104), np.full(150, -offset))(sino[0])
    np.testing.assert_allclose(as_shift, ours, atol=1e-4 * float(np.abs(ours).max()))


def test_two_slices_per_transform_equal_one_at_a_time():
    d = _smooth_wave(120)
    geometry, sino, _ = _scan(n=64, n_det=64, views=120, offset=1.1, shifts=d, slices=5)
    plan = GridrecPlan(geometry, d, threads=2)
    stacked = plan(sino)
    alone = np.stack([plan(s) for s in sino])
    scale = float(np.abs(alone).max())
    np.testing.assert_allclose(stacked, alone, atol=1e-5 * scale)
    np.testing.assert_allclose(gridrec_slices(geometry, sino[:2], d), stacked[:2], atol=1e-5 * scale)
    # bit for bit the same on a second run and with another number of threads (one plan per thread)
    assert np.array_equal(plan(sino), stacked)
    assert np.array_equal(GridrecPlan(geometry, d, threads=1)(sino), stacked)
    assert np.array_equal(GridrecPlan(geometry, d, threads=3)(sino), stacked)
    # the default (eps 1e-5, upsampling 1.25) against a 1e-10 transform (upsampling 2)
    exact = GridrecPlan(geometry, d, eps=1e-10)(sino)
    assert np.abs(exact - stacked).max() < 1e-5 * scale


def test_bad_input():
    geometry, sino, _ = _scan(n=32, n_det=32, views=20)
    with pytest.raises(ValueError, match="parallel beam only"):
        gridrec(get_preset("tiny-fan"), np.zeros(get_preset("tiny-fan").sino_shape))
    with pytest.raises(ValueError, match="shifts"):
        gridrec(geometry, sino[0], shifts=np.zeros(3))
    with pytest.raises(ValueError, match="sinogram"):
        gridrec(geometry, sino[0, :, :-1])
    with pytest.raises(ValueError, match="sinograms"):
        GridrecPlan(geometry)(sino[:, :, :-1])
    with pytest.raises(ValueError, match="eps"):
        gridrec(geometry, sino[0], eps=0.0)


def test_backend_selection(monkeypatch):
    monkeypatch.setattr(gridrec_module, "gpu_available", lambda: True)
    assert select_backend("auto") == "cufinufft" and select_backend("finufft") == "finufft"
    monkeypatch.setattr(gridrec_module, "gpu_available", lambda: False)
    assert select_backend("auto") == "finufft"
    with pytest.raises(NanoctError, match="cufinufft"):
        select_backend("cufinufft")
    monkeypatch.setattr(gridrec_module, "gridrec_available", lambda: False)
    with pytest.raises(NanoctError, match="pip install finufft"):
        select_backend("auto")


def test_gpu_path_with_a_stand_in_library(monkeypatch):
    """The cufinufft engine (torch FFTs, cufinufft plans) on the CPU: torch on 'cpu', finufft behind cufinufft's API."""
    import finufft
    import torch

    class Plan:
        def __init__(self, kind, modes, n_trans, eps, isign, dtype):
            self.plan = finufft.Plan(kind, modes, n_trans=n_trans, eps=eps, isign=isign, dtype=dtype)

        def setpts(self, x, y):
            assert isinstance(x, torch.Tensor)
            self.plan.setpts(x.numpy(), y.numpy())

        def execute(self, c):
            assert isinstance(c, torch.Tensor)
            return torch.as_tensor(self.plan.execute(c.numpy()))

    monkeypatch.setitem(sys.modules, "cufinufft", types.SimpleNamespace(Plan=Plan, __version__="stand-in"))
    monkeypatch.setattr(gridrec_module, "gpu_available", lambda: True)
    monkeypatch.setattr(gridrec_module, "GPU_DEVICE", "cpu")
    d = _smooth_wave(90)
    geometry, sino, _ = _scan(n=48, n_det=48, views=90, offset=0.7, shifts=d, slices=3)
    gpu = GridrecPlan(geometry, d)
    assert gpu.backend == "cufinufft"
    cpu = GridrecPlan(geometry, d, backend="finufft")
    ref = cpu(sino)
    np.testing.assert_allclose(gpu(sino), ref, atol=1e-5 * float(np.abs(ref).max()))
    tilted = GridrecPlan(geometry, d, axis_range=1.0, backend="finufft")(sino, axis=[0.5, -0.5, 1.0])
    on_gpu = GridrecPlan(geometry, d, axis_range=1.0)(sino, axis=[0.5, -0.5, 1.0])
    np.testing.assert_allclose(on_gpu, tilted, atol=1e-5 * float(np.abs(ref).max()))
    result = gridrec(geometry, sino[0], shifts=d)
    assert result.params["engine"] == "gridrec/cufinufft stand-in"


def test_single_slice_calls_reuse_the_last_plan(monkeypatch):
    geometry, sino, _ = _scan(n=32, n_det=32, views=30, slices=2)
    built = []
    monkeypatch.setattr(gridrec_module, "GridrecPlan", lambda *a, **k: built.append(1) or GridrecPlan(*a, **k))
    gridrec_module._CACHE.clear()
    first = gridrec(geometry, sino[0]).image
    np.testing.assert_array_equal(gridrec(geometry, sino[0]).image, first)
    gridrec(geometry, sino[1])
    assert len(built) == 1  # same geometry, shifts and parameters: one plan
    gridrec(geometry, sino[0], shifts=np.ones(30))
    gridrec(geometry, sino[0], filter="hann")
    assert len(built) == 3


def test_per_slice_axis_equals_a_geometry_per_slice():
    """A tilted axis: each slice's own offset as a phase ramp before two slices share a transform."""
    geometry, sino, _ = _scan(n=48, n_det=48, views=60, offset=1.0, slices=3)
    axis = np.array([-0.7, 0.2, 1.3])
    d = _smooth_wave(60)
    plan = GridrecPlan(geometry, d, axis_range=1.5)
    ours, flipped = plan(sino, axis=axis), plan(sino, axis=-axis)
    for s in range(3):
        own = Geometry.from_angles(geometry.angles, 48, 48, center_offset=1.0 + axis[s])
        ref = GridrecPlan(own, d)(sino[s])  # another period M: the series differ a little
        assert np.abs(ours[s] - ref).max() < 2e-3 * np.abs(ref).max() < 0.1 * np.abs(flipped[s] - ref).max()
    with pytest.raises(ValueError, match="axis_range"):
        GridrecPlan(geometry, d, axis_range=0.5)(sino, axis=axis)
