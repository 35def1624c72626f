"""A scan's motion from a few rows, then every row streamed in blocks (reconstruct_scan)."""

from __future__ import annotations

import numpy as np
import pytest
import zarr

from nanoct.core.geometry import Geometry
from nanoct.recon import stack
from nanoct.recon.gridrec import GridrecPlan
from nanoct.workflows import slabs
from scan_cases import SLAB_K, SLAB_L, SLAB_OFFSET, SLAB_R, slab_line_integrals, write_raw_scan

K, R, L, OFFSET = SLAB_K, SLAB_R, SLAB_L, SLAB_OFFSET
_line_integrals, _write_scan = slab_line_integrals, write_raw_scan


def test_scan_motion_from_a_few_rows_then_every_block(tmp_path, monkeypatch):
    """reconstruct_scan: shifts and axis from 3 rows, every row reconstructed; the recorded motion is reused."""
    phi = np.arange(K) * np.pi / K
    d = 1.2 * np.sin(3 * phi) + np.random.default_rng(3).uniform(-1.2, 1.2, K)
    _, data = _line_integrals(d=d)
    scan, read = _write_scan(tmp_path, data, phi)
    out = slabs.reconstruct_scan(scan, tmp_path / "out", motion_rows=3, block=3, read=read, progress=False)
    group = zarr.open_group(str(out), mode="r")
    info = dict(group.attrs["info"])
    basis = np.stack([np.ones(K), np.cos(phi), np.sin(phi)], axis=1)  # what no data determine
    err = np.asarray(info["shifts"]) - d
    err -= basis @ np.linalg.lstsq(basis, err, rcond=None)[0]
    assert np.sqrt(np.mean(err**2)) < 0.15 and info["motion_rows"] == [0, 3, 6]  # measured 0.046 px
    shifts, estimated = np.asarray(info["shifts"]), Geometry.from_angles(phi, L, L, center_offset=info["center_offset"])
    images = group["slices"][:]
    assert group["done"][:].all() and images.shape == (R, L, L)
    sinos = data.transpose(1, 0, 2)
    np.testing.assert_allclose(images, GridrecPlan(estimated, shifts)(sinos), atol=1e-4 * float(np.abs(images).max()))
    # the images explain the data (up to the translation no method can tell): as well as with the true motion
    truth = Geometry.from_angles(phi, L, L, center_offset=OFFSET)
    for i in (0, R - 1):
        misfit = np.linalg.norm(stack.reproject(estimated, images[i], shifts) - sinos[i])
        best = np.linalg.norm(stack.reproject(truth, GridrecPlan(truth, d)(sinos[i]), d) - sinos[i])
        still = np.linalg.norm(stack.reproject(truth, GridrecPlan(truth)(sinos[i])) - sinos[i])
        assert misfit < 1.1 * best and still > 1.3 * best, (misfit, best, still)  # measured 0.98, 1.51-1.54
    # resume: one block lost its flag; the motion is not estimated again and the bytes come back the same
    before = (out / "slices" / "c" / "1" / "0" / "0").read_bytes()
    zarr.open_group(str(out), mode="r+")["done"][1] = False
    monkeypatch.setattr(slabs, "horizontal_motion", lambda *a, **k: pytest.fail("estimated again"))
    slabs.reconstruct_scan(scan, tmp_path / "out", motion_rows=3, block=3, read=read, progress=False)
    assert (out / "slices" / "c" / "1" / "0" / "0").read_bytes() == before


def test_a_second_writer_of_the_same_output_is_refused(tmp_path):
    """A slab output another process is writing (its lock held) is refused before anything is read or written."""
    from nanoct.core.errors import BusyError
    from nanoct.io.lock import exclusive

    phi = np.arange(K) * np.pi / K
    scan, read = _write_scan(tmp_path, _line_integrals(d=np.zeros(K))[1], phi)
    with exclusive(tmp_path, "out", "the slab output"):
        with pytest.raises(BusyError, match="being written by another nanoct process"):
            slabs.reconstruct_scan(scan, tmp_path / "out", motion_rows=3, block=3, read=read, progress=False)
    assert not (tmp_path / "out").exists()


def test_no_air_the_motion_slices_are_read_and_cleaned_once_on_one_bar(tmp_path, monkeypatch, capsys):
    """An object wider than the field of view: the streamed path hands its cleaned motion slices to the stack's
    estimate instead of reading them again (the open beam is removed once), and one bar shows the stages."""
    import nanoct.motion.axis as axis_mod
    from nanoct.workflows import stack as stack_wf

    phi = np.arange(K) * np.pi / K
    _, data = _line_integrals()
    scan, read = _write_scan(tmp_path, data, phi)
    calls = []
    real = axis_mod.remove_air

    def no_air(*a, **k):  # the same cleaning, reported as no air seen
        calls.append(1)
        return real(*a, **k)[0], False

    monkeypatch.setattr(axis_mod, "remove_air", no_air)
    monkeypatch.setattr(stack_wf, "remove_air", no_air)
    found = (np.zeros(K), {"center_offset": 0.0, "horizontal_method": "focus+matching"})
    monkeypatch.setattr(stack_wf, "_focus_matching", lambda *a: found)
    monkeypatch.setattr(slabs, "consistent_motion", lambda rows, params, vertical, shifts, info: shifts)  # own rows
    out = slabs.reconstruct_scan(scan, tmp_path / "out", motion_rows=3, block=3, read=read, vertical=False)
    assert len(calls) == 1 and dict(zarr.open_group(str(out), mode="r").attrs["info"])["center_offset"] == 0.0
    assert "motion:" in capsys.readouterr().err
