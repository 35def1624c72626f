"""The per-slice Dremel and RESESOP of ``nanoct stack``: the stack's motion as the start on measured data."""

from __future__ import annotations

import numpy as np

from nanoct.core.geometry import Geometry
from nanoct.core.operators import system_matrix
from nanoct.io.store import DataStore, create_scan
from nanoct.workflows.stack import _dremel_slice, _reconstruct_slice, _resesop_slice

N = 40
ANGLES = np.linspace(0, np.pi, 48, endpoint=False)


def _scan() -> tuple[Geometry, np.ndarray, np.ndarray, np.ndarray]:
    g = Geometry.from_angles(ANGLES, N, N)
    yy, xx = np.mgrid[:N, :N] - (N - 1) / 2
    x = (np.hypot(yy, xx) <= 10).astype(np.float32) * 0.05
    x[np.hypot(yy - 3, xx + 2) <= 4] = 0.1
    clean = (system_matrix(g) @ x.ravel()).reshape(g.sino_shape).astype(np.float32)
    d = np.round(2 * np.sin(np.linspace(0, 2 * np.pi, ANGLES.size))).astype(int)
    moved = np.stack([np.roll(view, -dk) for view, dk in zip(clean, d)])
    return g, x, moved, d.astype(np.float64)


def _psnr(a: np.ndarray, gt: np.ndarray) -> float:
    return float(10 * np.log10((gt.max() - gt.min()) ** 2 / np.mean((a - gt) ** 2)))


def test_dremel_slice_holds_the_motion_of_a_simulation_and_refines_a_measured_one() -> None:
    g, x, moved, d = _scan()
    start = 0.5 * d  # a rough stack estimate
    held = _dremel_slice(g, moved, start)
    np.testing.assert_array_equal(held.motion, start.astype(np.float32))
    refined = _dremel_slice(g, moved + np.float32(0.3), start)  # the open beam of a measured scan
    assert refined.params["measured_data"]["air_level_mean"] > 0.29
    assert not np.array_equal(refined.motion, start.astype(np.float32))
    err = lambda m: np.abs(m - d - np.mean(m - d)).mean()  # noqa: E731 - translation-free error
    assert err(refined.motion) < err(start)


def test_resesop_slice_carries_the_motion_on_measured_data() -> None:
    g, x, moved, d = _scan()
    measured = moved + np.float32(0.3)
    auto, auto_motion, auto_check = _resesop_slice(g, measured, d, "auto")
    level, level_motion, level_check = _resesop_slice(g, measured, d, 0.01)
    sim, sim_motion, sim_check = _resesop_slice(g, moved, d, 0.01)
    assert auto_check is None and level_check is None and sim_check is None  # nothing ran away here
    for image in (auto, level, sim):
        assert image.shape == (N, N) and np.isfinite(image).all()
    assert min(_psnr(level, x), _psnr(auto, x), _psnr(sim, x)) > 30.0  # about 35 dB; 18-20 dB without the motion
    assert _psnr(_resesop_slice(g, measured, -d, 0.01)[0], x) < 20.0  # the sign of the motion matters
    # the motion each used: Dremel's refinement with "auto" eta on measured data, else the stack's
    np.testing.assert_allclose(auto_motion, _dremel_slice(g, measured, d).motion, atol=1e-6)
    assert level_motion is d and sim_motion is d


def test_reconstruct_slice_stores_the_motion_it_used(tmp_path) -> None:
    g, _, moved, d = _scan()
    sinos = np.stack([moved + np.float32(0.3), moved])  # a measured slice (open beam at 0.3), a simulated one
    path = str(create_scan(tmp_path / "scan", g, sinos, {"source": "test"}).path)
    start, vertical = 0.5 * d, np.zeros(ANGLES.size)
    refined = _dremel_slice(g, sinos[0], start).motion
    assert np.abs(refined - start).max() > 0.1
    for method in ("dremel", "resesop"):
        DataStore.open(path, mode="r+").prepare_reconstruction(method, {"method": method}, shifts=True)
        for index in (0, 1):
            _reconstruct_slice(path, method, method, {"center_offset": 0.0}, "auto", start, vertical, index)
        rows = DataStore.open(path).read_shifts(method)
        np.testing.assert_allclose(rows[0], refined, atol=1e-6)  # measured: Dremel's refinement (detector px)
        np.testing.assert_array_equal(rows[1], start.astype(np.float32))  # a simulation: the stack's motion
