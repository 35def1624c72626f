"""Tests for nanoct.sim.motion."""

from __future__ import annotations

import json

import matplotlib
import numpy as np
import pytest

from nanoct.sim.motion import (
    MotionParams,
    no_motion,
    plot_motion,
    rotation_matrix,
    sample_motion,
    sample_motion_components,
)

matplotlib.use("Agg")


def rng(seed: int, index: int = 0) -> np.random.Generator:
    return np.random.default_rng((seed, index))


@pytest.mark.parametrize("kind, n_angles", [("parallel", 567), ("fan", 133), ("parallel", 1)])
def test_shape_dtype(kind: str, n_angles: int) -> None:
    motion = sample_motion(rng(0), n_angles, MotionParams.for_kind(kind))
    assert motion.shape == (n_angles, 3)
    assert motion.dtype == np.float32
    assert np.isfinite(motion).all()


def test_for_kind() -> None:
    assert MotionParams.for_kind("parallel").n_sinusoids == 38
    assert MotionParams.for_kind("fan").n_sinusoids == 9
    assert MotionParams.for_kind("fan", max_shift=1.5).max_shift == 1.5
    with pytest.raises(ValueError, match="kind="):
        MotionParams.for_kind("cone")
    with pytest.raises(ValueError, match="unknown"):
        MotionParams.for_kind("fan", max_shfit=1.5)


def test_deterministic_and_seed_dependent() -> None:
    params = MotionParams()
    a = sample_motion(rng(3, 1), 200, params)
    b = sample_motion(rng(3, 1), 200, params)
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != sample_motion(rng(3, 2), 200, params).tobytes()


def test_motion_is_sum_of_components() -> None:
    params = MotionParams.for_kind("fan")
    eps, jitter = sample_motion_components(rng(4), 133, params)
    assert eps.shape == (133, 2) and jitter.shape == (133, 3)
    assert eps.dtype == jitter.dtype == np.float32
    motion = sample_motion(rng(4), 133, params)
    np.testing.assert_array_equal(motion[:, :2], eps + jitter[:, :2])
    np.testing.assert_array_equal(motion[:, 2], jitter[:, 2])


def test_switches_keep_random_streams_aligned() -> None:
    eps, jitter = sample_motion_components(rng(9), 300, MotionParams())
    eps_only, no_jitter = sample_motion_components(rng(9), 300, MotionParams(jitter=False))
    no_eps, jitter_only = sample_motion_components(rng(9), 300, MotionParams(sinusoids=False))
    np.testing.assert_array_equal(eps_only, eps)
    np.testing.assert_array_equal(jitter_only, jitter)
    assert not no_jitter.any() and not no_eps.any()


@pytest.mark.parametrize("max_shift", [0.0, 0.5, 1.3, 2.0, 50.0])
def test_eps_bound(max_shift: float) -> None:
    params = MotionParams(max_shift=max_shift)
    for i in range(100):
        eps, _ = sample_motion_components(rng(11, i), 567, params)
        assert np.abs(eps).max() <= max_shift * (1 + 1e-6)


def test_eps_is_only_scaled_down() -> None:
    loose = MotionParams(max_shift=1e6)
    tight = MotionParams(max_shift=1.0)
    for i in range(20):
        raw, _ = sample_motion_components(rng(12, i), 400, loose)
        eps, _ = sample_motion_components(rng(12, i), 400, tight)
        for c in range(2):
            peak = np.abs(raw[:, c]).max()
            expected = raw[:, c] if peak <= 1.0 else raw[:, c] / peak
            np.testing.assert_allclose(eps[:, c], expected, rtol=1e-5, atol=1e-6)


def test_sinusoids_start_at_onset_and_damp() -> None:
    # One undamped sinusoid: zero before the onset, non-zero after it.
    params = MotionParams(
        n_sinusoids=1,
        jitter=False,
        damping_range=(0.0, 0.0),
        amplitude_range=(1.0, 1.0),
        max_shift=10.0,
    )
    eps, _ = sample_motion_components(rng(2), 1000, params)
    magnitude = np.hypot(eps[:, 0], eps[:, 1])
    started = np.flatnonzero(magnitude > 0)
    assert started.size > 0
    assert not magnitude[: started[0]].any()
    assert magnitude.max() == pytest.approx(1.0, abs=1e-3)


def test_jitter_std_fixed() -> None:
    params = MotionParams(sinusoids=False, jitter_std_std=0.0)
    motion = sample_motion(rng(21), 100_000, params)
    np.testing.assert_allclose(motion.mean(axis=0), 0.0, atol=0.005)
    np.testing.assert_allclose(motion.std(axis=0), 0.127, rtol=0.03)


def test_jitter_std_distribution() -> None:
    params = MotionParams(sinusoids=False)
    stds = np.array([sample_motion(rng(22, i), 4000, params).std(axis=0) for i in range(300)])
    # 900 per-sample, per-component standard deviations ~ |N(0.127, 0.0254^2)|.
    assert stds.mean() == pytest.approx(0.127, rel=0.05)
    assert stds.std() == pytest.approx(0.0254, rel=0.15)


def test_no_motion_and_switches_off() -> None:
    assert not no_motion(50).any() and no_motion(50).shape == (50, 3)
    assert no_motion(50).dtype == np.float32
    motion = sample_motion(rng(0), 50, MotionParams(jitter=False, sinusoids=False))
    assert motion.shape == (50, 3) and not motion.any()
    motion = sample_motion(rng(0), 50, MotionParams(n_sinusoids=0, jitter=False))
    assert not motion.any()


def test_rotation_matrix() -> None:
    angles = np.array([0.0, 17.0, 90.0, -123.4, 270.0])
    mats = rotation_matrix(angles)
    assert mats.shape == (5, 2, 2)
    identity = np.broadcast_to(np.eye(2), mats.shape)
    np.testing.assert_allclose(mats @ np.swapaxes(mats, -1, -2), identity, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(mats), 1.0)
    np.testing.assert_allclose(rotation_matrix(90.0) @ [1.0, 0.0], [0.0, 1.0], atol=1e-12)
    composed = rotation_matrix(30.0) @ rotation_matrix(60.0)
    np.testing.assert_allclose(composed, rotation_matrix(90.0), atol=1e-12)


def test_params_round_trip() -> None:
    params = MotionParams.for_kind("fan", max_shift=1.25, frequency_range=(1.0, 5.0), jitter=False)
    data = json.loads(json.dumps(params.to_dict()))
    assert MotionParams.from_dict(data) == params
    assert MotionParams.from_dict({}) == MotionParams()


def test_plot_motion(tmp_path) -> None:
    from matplotlib.figure import Figure

    motion = sample_motion(rng(1), 133, MotionParams.for_kind("fan"))
    fig = plot_motion(motion)
    assert isinstance(fig, Figure)
    fig.savefig(tmp_path / "motion.png")
    assert (tmp_path / "motion.png").stat().st_size > 0
    angles = np.arange(133) * (2 * np.pi / 133)
    fig2 = plot_motion(motion, angles=angles)
    assert fig2.axes[0].get_lines()[0].get_xdata()[-1] == pytest.approx(np.rad2deg(angles[-1]))
    import matplotlib.pyplot as plt

    fig3, ax = plt.subplots()
    assert plot_motion(motion, ax=ax) is fig3
    plt.close(fig3)
    with pytest.raises(ValueError, match="angles"):
        plot_motion(motion, angles=angles[:-1])
    with pytest.raises(ValueError, match="motion"):
        plot_motion(motion[:, :2])


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"max_shift": -1.0}, "max_shift="),
        ({"max_shift": float("nan")}, "max_shift="),
        ({"n_sinusoids": -1}, "n_sinusoids="),
        ({"n_sinusoids": 2.5}, "n_sinusoids="),
        ({"jitter_std_mean": -0.1}, "jitter_std_mean="),
        ({"frequency_range": (5.0, 1.0)}, "frequency_range="),
        ({"damping_range": (-1.0, 1.0)}, "damping_range="),
        ({"amplitude_range": 3.0}, "amplitude_range="),
        ({"jitter": "yes"}, "jitter="),
    ],
)
def test_bad_params(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        MotionParams(**kwargs)


@pytest.mark.parametrize("n_angles", [0, -5, 10.0, True])
def test_bad_n_angles(n_angles: object) -> None:
    with pytest.raises(ValueError, match="n_angles="):
        sample_motion(rng(0), n_angles, MotionParams())  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="n_angles="):
        no_motion(n_angles)  # type: ignore[arg-type]


def test_bad_rng() -> None:
    with pytest.raises(TypeError, match="Generator"):
        sample_motion(np.random.RandomState(0), 10, MotionParams())  # type: ignore[arg-type]
