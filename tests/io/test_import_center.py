"""`nanoct import --center-offset auto`: the axis found from opposite views, in raw pixels."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.cli import run
from nanoct.io.rawscan import axis_after
from nanoct.io.store import DataStore
from nanoct.sim.analytic import ellipse_sinogram, stack_phantom

L, K, OFFSET = 180, 200, 3.4


@pytest.mark.parametrize("crop", [None, (6, 178)])
def test_import_finds_the_axis(tmp_path, crop):
    phi = np.arange(K) * np.pi / K
    rows = [ellipse_sinogram(e, phi, L, center_offset=OFFSET, subsamples=2) for e in stack_phantom(150, 2, seed=7)]
    np.save(tmp_path / "scan.npy", np.stack(rows, axis=1))  # (K, R, L) line integrals
    np.savetxt(tmp_path / "angles.txt", np.rad2deg(phi))
    args = ["import", str(tmp_path / "scan.npy"), "--out", str(tmp_path / "store"), "--angles",
            str(tmp_path / "angles.txt"), "--line-integrals", "--center-offset", "auto", "--binning", "2"]  # fmt: skip
    if crop is not None:
        args += ["--crop", f"{crop[0]},{crop[1]}"]
    assert run(args) == 0
    store = DataStore.open(tmp_path / "store")
    assert store.meta["scan"]["center_offset_raw"] == pytest.approx(OFFSET, abs=0.05)
    assert store.geometry.center_offset == pytest.approx(axis_after(OFFSET, L, crop, 2), abs=0.03)


def test_import_refuses_a_bad_center_offset(tmp_path, capsys):
    np.save(tmp_path / "scan.npy", np.zeros((4, 1, 8), dtype=np.float32))
    assert run(["import", str(tmp_path / "scan.npy"), "--out", str(tmp_path / "s"), "--center-offset", "middle"]) == 2
    assert "auto" in capsys.readouterr().err


def test_import_auto_axis_is_not_fooled_by_motion(tmp_path):
    phi = np.arange(K) * np.pi / K
    d = np.random.default_rng(3).uniform(-3, 3, K)
    d -= np.linalg.lstsq(np.stack([np.ones(K), np.cos(phi), np.sin(phi)], 1), d, rcond=None)[0][0]
    rows = [ellipse_sinogram(e, phi, L, shifts=d, center_offset=OFFSET) for e in stack_phantom(150, 2, seed=7)]
    np.save(tmp_path / "scan.npy", np.stack(rows, axis=1))
    np.savetxt(tmp_path / "angles.txt", np.rad2deg(phi))
    assert run(["import", str(tmp_path / "scan.npy"), "--out", str(tmp_path / "store"), "--angles",
                str(tmp_path / "angles.txt"), "--line-integrals", "--center-offset", "auto"]) == 0  # fmt: skip
    assert DataStore.open(tmp_path / "store").geometry.center_offset == pytest.approx(OFFSET, abs=0.05)
