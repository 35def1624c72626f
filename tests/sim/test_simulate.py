import numpy as np
import pytest

from nanoct.core.geometry import get_preset
from nanoct.core.operators import RayTransform
from nanoct.sim.motion import MotionParams
from nanoct.sim.phantoms import downsample, random_ellipse_phantom, random_phantom
from nanoct.sim.simulate import SimulationConfig, model_error, sample_rngs, simulate_sample


@pytest.mark.parametrize("preset", ["tiny-parallel", "tiny-fan"])
def test_sample_shapes_and_consistency(preset):
    g = get_preset(preset)
    cfg = SimulationConfig.for_geometry(g)
    assert cfg.motion.n_sinusoids == (38 if g.kind == "parallel" else 9)
    s = simulate_sample(g, cfg, seed=5, index=2)
    assert s.phantom.shape == g.image_shape and s.phantom.dtype == np.float32
    assert s.sinogram.shape == s.sinogram_eta.shape == g.sino_shape
    assert s.motion.shape == (g.n_angles, 3) and s.eta.shape == (g.n_angles,)
    np.testing.assert_array_equal(
        s.eta, np.abs(s.sinogram.astype(np.float64) - s.sinogram_eta).max(axis=1).astype(np.float32)
    )
    assert (s.eta > 0).all()  # every view moved
    # y_eta is the unperturbed projection of the same (fine) phantom; y uses the stored motion
    fine = random_phantom(sample_rngs(5, 2)[0], g.n, oversample=2)
    np.testing.assert_array_equal(downsample(fine, 2), s.phantom)
    np.testing.assert_allclose(RayTransform(g, oversample=2).forward(fine), s.sinogram_eta, rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(RayTransform(g, s.motion, oversample=2).forward(fine), s.sinogram, rtol=1e-5, atol=1e-4)


def test_sample_depends_only_on_seed_and_index():
    g = get_preset("tiny-parallel")
    cfg = SimulationConfig.for_geometry(g)
    a = simulate_sample(g, cfg, 7, 4)
    simulate_sample(g, cfg, 7, 3)  # other work in between changes nothing
    b = simulate_sample(g, cfg, 7, 4)
    for field in ("phantom", "sinogram", "sinogram_eta", "motion", "eta"):
        assert getattr(a, field).tobytes() == getattr(b, field).tobytes()
    c = simulate_sample(g, cfg, 7, 5)
    d = simulate_sample(g, cfg, 8, 4)
    assert not np.array_equal(a.phantom, c.phantom) and not np.array_equal(a.phantom, d.phantom)


def test_unperturbed_and_inverse_crime_options():
    g = get_preset("tiny-parallel")
    s = simulate_sample(g, SimulationConfig.for_geometry(g, perturbed=False), 0, 0)
    np.testing.assert_array_equal(s.sinogram, s.sinogram_eta)
    assert not s.eta.any() and not s.motion.any()
    crime = simulate_sample(g, SimulationConfig.for_geometry(g, perturbed=False, oversample=1), 0, 0)
    np.testing.assert_allclose(RayTransform(g).forward(crime.phantom), crime.sinogram_eta, rtol=1e-6, atol=1e-5)
    # the default (finer grid) data are not exactly the reconstruction model's projection
    assert np.abs(RayTransform(g).forward(s.phantom) - s.sinogram_eta).max() > 1e-3


def test_noise_is_added_to_y_only_and_eta_is_the_model_error():
    g = get_preset("tiny-parallel")
    clean = simulate_sample(g, SimulationConfig.for_geometry(g), 1, 1)
    noisy = simulate_sample(g, SimulationConfig.for_geometry(g, noise_std=0.5), 1, 1)
    np.testing.assert_array_equal(clean.sinogram_eta, noisy.sinogram_eta)
    np.testing.assert_array_equal(clean.eta, noisy.eta)
    assert np.std(noisy.sinogram - clean.sinogram) == pytest.approx(0.5, rel=0.05)


def test_max_shift_bounds_the_sinusoids():
    g = get_preset("tiny-parallel")
    cfg = SimulationConfig.for_geometry(g, motion=MotionParams.for_kind("parallel", max_shift=0.5, jitter=False))
    for i in range(5):
        assert np.abs(simulate_sample(g, cfg, 0, i).motion[:, :2]).max() <= 0.5 + 1e-6


def test_config_round_trip_and_validation():
    cfg = SimulationConfig.for_geometry(get_preset("tiny-fan"), noise_std=0.1)
    assert SimulationConfig.from_dict(cfg.to_dict()) == cfg
    assert "phantoms" not in cfg.to_dict()  # the paper's family keeps the stored description of its data sets
    other = SimulationConfig(phantoms="ellipses")
    assert SimulationConfig.from_dict(other.to_dict()) == other and other.to_dict()["phantoms"] == "ellipses"
    with pytest.raises(ValueError, match="phantoms"):
        SimulationConfig(phantoms="disks")
    with pytest.raises(ValueError, match="oversample"):
        SimulationConfig(oversample=0)
    with pytest.raises(ValueError, match="noise_std"):
        SimulationConfig(noise_std=-1.0)
    with pytest.raises(ValueError, match="seed"):
        sample_rngs(-1, 0)
    with pytest.raises(ValueError):
        model_error(np.zeros((3, 4)), np.zeros((3, 5)))


def test_the_ellipse_family_changes_only_the_phantom():
    """``phantoms="ellipses"``: the phantom of random_ellipse_phantom from the sample's generator, the same motion."""
    g = get_preset("tiny-parallel")
    paper = simulate_sample(g, SimulationConfig.for_geometry(g), 3, 1)
    other = simulate_sample(g, SimulationConfig.for_geometry(g, phantoms="ellipses"), 3, 1)
    expected = downsample(random_ellipse_phantom(sample_rngs(3, 1)[0], g.n, oversample=2), 2)
    np.testing.assert_array_equal(other.phantom, expected)
    np.testing.assert_array_equal(other.motion, paper.motion)
    assert not np.array_equal(other.phantom, paper.phantom) and not np.array_equal(other.sinogram, paper.sinogram)
