"""Streaming slabs: a raw scan read a block of rows at a time, flat/dark corrected, motion undone, resumable."""

from __future__ import annotations

import os
import sys
from functools import partial

import numpy as np
import pytest
import zarr

from nanoct.core.errors import NanoctError
from nanoct.core.geometry import Geometry
from nanoct.recon import slab
from nanoct.recon.gridrec import GridrecPlan
from nanoct.recon.slab import read_block, reconstruct_slabs, slab_blocks
from scan_cases import SLAB_K, SLAB_L, SLAB_OFFSET, SLAB_R, slab_line_integrals, write_raw_scan

K, R, L, OFFSET = SLAB_K, SLAB_R, SLAB_L, SLAB_OFFSET
_line_integrals, _write_scan = slab_line_integrals, write_raw_scan


def test_blocks_equal_the_whole_scan_reconstructed_at_once(tmp_path):
    d = 1.5 * np.sin(np.arange(K) * np.pi / K * 3)
    phi, data = _line_integrals(d=d)
    scan, read = _write_scan(tmp_path, data, phi)
    assert slab_blocks(1, 7, 4) == [(1, 5), (5, 7)]
    out = reconstruct_slabs(scan, tmp_path / "out", shifts=d, center_offset=OFFSET, rows=(1, 7), block=4,
                            read=read, progress=False)  # fmt: skip
    images = zarr.open_group(str(out), mode="r")["slices"][:]
    geometry = Geometry.from_angles(phi, L, L, center_offset=OFFSET)
    ref = GridrecPlan(geometry, d)(data[:, 1:7].transpose(1, 0, 2))
    np.testing.assert_allclose(images, ref, atol=1e-4 * float(np.abs(ref).max()))
    assert zarr.open_group(str(out), mode="r")["done"][:].all()


def test_vertical_shift_is_undone_with_the_motion_sign(tmp_path):
    """Whole-row shifts are undone exactly (up to float32 rounding of the intensities), sub-pixel ones closely."""
    phi, still = _line_integrals()
    interior = still[:, 2:5].transpose(1, 0, 2)
    scale = float(np.abs(interior).max())
    for v, tol in (
        (np.round(2 * np.cos(np.arange(K) * np.pi / K * 2)), 1e-4),
        (1.3 * np.sin(np.arange(K) * 0.1), 0.05),
    ):
        _, moved = _line_integrals(v=v)
        scan, read = _write_scan(tmp_path, moved, phi)
        source = {"path": str(scan), "n_rows": R, **read}
        right = np.abs(read_block(source, (2, 5), v) - interior).max()
        wrong = np.abs(read_block(source, (2, 5), -v) - interior).max()
        uncorrected = np.abs(read_block(source, (2, 5)) - interior).max()
        assert right < tol * scale and wrong > 0.1 * scale and uncorrected > 0.05 * scale, (right, wrong, uncorrected)


def test_a_stopped_run_resumes_with_identical_bytes(tmp_path, monkeypatch):
    phi, data = _line_integrals()
    scan, read = _write_scan(tmp_path, data, phi)
    kwargs = {"center_offset": OFFSET, "block": 2, "read": read, "progress": False}
    whole = reconstruct_slabs(scan, tmp_path / "whole", **kwargs)
    task = slab._block_task

    def stop_at_block_2(out, source, setup, blocks, index):
        if index == 2:
            raise KeyboardInterrupt
        return task(out, source, setup, blocks, index)

    monkeypatch.setattr(slab, "_block_task", stop_at_block_2)
    with pytest.raises(KeyboardInterrupt):
        reconstruct_slabs(scan, tmp_path / "stopped", **kwargs)
    assert zarr.open_group(str(tmp_path / "stopped"), mode="r")["done"][:].tolist() == [True, True, False, False]
    monkeypatch.setattr(slab, "_block_task", task)
    calls = []
    monkeypatch.setattr(slab, "_block_task", lambda *a: calls.append(a[-1]) or task(*a))
    reconstruct_slabs(scan, tmp_path / "stopped", **kwargs)
    assert calls == [2, 3]  # only the blocks not written
    chunks = sorted(p.relative_to(whole) for p in (whole / "slices").rglob("*") if p.is_file())
    assert chunks and all(
        (whole / c).read_bytes() == (tmp_path / "stopped" / c).read_bytes() for c in chunks
    )  # the same bytes as the undisturbed run


def test_bad_input_and_other_parameters(tmp_path):
    phi, data = _line_integrals()
    scan, read = _write_scan(tmp_path, data, phi)
    with pytest.raises(NanoctError, match="rows"):
        reconstruct_slabs(scan, tmp_path / "a", rows=(3, 99), read=read, progress=False)
    with pytest.raises(NanoctError, match="shifts"):
        reconstruct_slabs(scan, tmp_path / "a", shifts=np.zeros(3), read=read, progress=False)
    with pytest.raises(NanoctError, match="block"):
        reconstruct_slabs(scan, tmp_path / "a", block=0, read=read, progress=False)
    assert not (tmp_path / "a").exists()
    reconstruct_slabs(scan, tmp_path / "a", rows=(0, 2), read=read, progress=False)
    with pytest.raises(NanoctError, match="other rows, block"):
        reconstruct_slabs(scan, tmp_path / "a", rows=(0, 2), center_offset=2.0, read=read, progress=False)


def _die_in_block_1(marker, out, source, setup, blocks, index):
    """The task of a worker killed in the middle of block 1 (once): half its chunk written, no flag."""
    if index == 1 and not os.path.exists(marker):
        open(marker, "w").close()
        r0, r1 = blocks[1]
        zarr.open_group(out, mode="r+")["slices"][r0 - blocks[0][0] : r1 - blocks[0][0]] = 7.0
        os._exit(1)
    return slab._write_block(out, source, setup, blocks, index)


@pytest.mark.slow
def test_a_worker_killed_in_a_block_costs_that_block_only(tmp_path, monkeypatch):
    """Local Dask cluster of 2 workers; one dies in block 1: every slice present, bytes of an undisturbed run."""
    import cloudpickle

    phi, data = _line_integrals()
    scan, read = _write_scan(tmp_path, data, phi)
    kwargs = {"center_offset": OFFSET, "block": 2, "read": read, "progress": False}
    whole = reconstruct_slabs(scan, tmp_path / "whole", **kwargs)
    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the workers cannot import this test module
    try:
        monkeypatch.setattr(slab, "_block_task", partial(_die_in_block_1, str(tmp_path / "died")))
        killed = reconstruct_slabs(scan, tmp_path / "killed", workers=2, **kwargs)
    finally:
        cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
    assert (tmp_path / "died").exists()  # a worker did die
    group = zarr.open_group(str(killed), mode="r")
    assert group["done"][:].all() and np.isfinite(group["slices"][:]).all()
    chunks = sorted(p.relative_to(whole) for p in (whole / "slices").rglob("*") if p.is_file())
    assert len(chunks) == 5  # 4 chunks and the metadata
    assert all((whole / c).read_bytes() == (killed / c).read_bytes() for c in chunks)
