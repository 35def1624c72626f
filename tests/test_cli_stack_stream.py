"""`nanoct stack SCAN --out OUT.zarr`: a scan file streamed block by block, the stack's motion, resume, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import zarr

from nanoct.cli import run
from nanoct.io.store import DataStore
from nanoct.recon import slab
from scan_cases import analytic_projections, gauge_free_rms, known_motion, moved

K, R, L = 60, 20, 48


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    """Raw intensities (.npy, flats and darks) of a stack moved vertically and horizontally; angles; the motion."""
    folder = tmp_path_factory.mktemp("scan")
    phi = np.arange(K) * np.pi / K
    d, v = known_motion(phi, seed=1)
    lines = moved(analytic_projections(phi, L, R, center=1.2, seed=3), d, v)
    np.save(folder / "scan.npy", (20 + 980 * np.exp(-lines)).astype(np.float32))
    np.save(folder / "flats.npy", np.full((2, R, L), 1000, np.float32))
    np.save(folder / "darks.npy", np.full((2, R, L), 20, np.float32))
    read = ["--angles", "0:180", "--flats", str(folder / "flats.npy"), "--darks", str(folder / "darks.npy")]
    return folder / "scan.npy", read, phi, d, v


def _chunks(out):
    return {p.relative_to(out): p.read_bytes() for p in sorted((out / "slices").rglob("*")) if p.is_file()}


@pytest.mark.slow
def test_streamed_stack_finds_the_stacks_motion_and_matches_the_store_path(scan, tmp_path, capsys):
    """The same vertical motion as `stack --store` (and the true one), the same shifts, the same images."""
    path, read, phi, d, v = scan
    common = ["--center-offset", "1.2", "-w", "0", "-q", *read]
    assert run(["stack", str(path), "--out", str(tmp_path / "s.zarr"), "--block", "6", *common]) == 0
    summary = capsys.readouterr().out
    assert "rows 0:20 in blocks of 6" in summary and "vertical" in summary and "4 of 4 blocks" in summary, summary
    assert run(["stack", str(path), "--store", str(tmp_path / "store"), *common]) == 0
    group = zarr.open_group(str(tmp_path / "s.zarr"), mode="r")
    info = dict(group.attrs["info"])
    store = DataStore.open(tmp_path / "store")
    ref = store.recons.motion_info("fbp_stack")
    assert info["vertical_method"] == "row profiles" and ref["vertical_method"] == "row profiles"
    np.testing.assert_allclose(info["vertical"], ref["vertical"], atol=1e-3)
    assert gauge_free_rms(np.asarray(info["vertical"]), v, phi, vertical=True) < 0.25  # and the truth, roughly
    assert gauge_free_rms(-np.asarray(info["vertical"]), v, phi, vertical=True) > 0.5  # not with the other sign
    np.testing.assert_allclose(info["shifts"], store.recons.shared_shifts("fbp_stack"), atol=1e-3)
    images, stored = group["slices"][:], store.read_reconstruction("fbp_stack")
    assert images.shape == (R, L, L) and group["done"][:].all()
    np.testing.assert_allclose(images, stored, atol=2e-3 * float(np.abs(stored).max()))


def test_an_interrupted_stream_resumes_with_the_same_command_and_bytes(scan, tmp_path, monkeypatch, capsys):
    path, read, *_ = scan
    argv = ["--rows", "2:9", "--block", "3", "--center-offset", "1.2", "-w", "0", "-q", *read]
    assert run(["stack", str(path), "--out", str(tmp_path / "whole.zarr"), *argv]) == 0
    task, calls = slab._block_task, []

    def stop_after_block_0(out, source, setup, blocks, index):
        if index == 1:
            raise KeyboardInterrupt
        return task(out, source, setup, blocks, index)

    monkeypatch.setattr(slab, "_block_task", stop_after_block_0)
    assert run(["stack", str(path), "--out", str(tmp_path / "cut.zarr"), *argv]) == 130
    assert zarr.open_group(str(tmp_path / "cut.zarr"), mode="r")["done"][:].tolist() == [True, False, False]
    monkeypatch.setattr(slab, "_block_task", lambda *a: calls.append(a[-1]) or task(*a))
    assert run(["stack", str(path), "--out", str(tmp_path / "cut.zarr"), *argv]) == 0
    assert calls == [1, 2]  # the done block is not computed again
    whole, cut = _chunks(tmp_path / "whole.zarr"), _chunks(tmp_path / "cut.zarr")
    assert len(whole) == 4 and whole == cut  # 3 chunks and the metadata, byte for byte
    # other motion options on the same output: refused; --overwrite replaces it
    capsys.readouterr()
    other = [a if a != "1.2" else "0.5" for a in argv]
    assert run(["stack", str(path), "--out", str(tmp_path / "cut.zarr"), *other]) == 2
    assert "other motion options" in capsys.readouterr().err
    assert run(["stack", str(path), "--out", str(tmp_path / "cut.zarr"), *other, "--overwrite"]) == 0
    assert _chunks(tmp_path / "cut.zarr") != whole


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--block", "0"], "--block 0"),
        (["--block", "-3"], "--block -3"),
        (["--rows", "5:99"], "--rows 5:99"),
        (["--rows", "7:3"], "--rows '7:3'"),
        (["--method", "dremel"], "--method 'dremel'"),
        (["--open-beam"], "--open-beam"),
        (["--motion-slices", "0,40"], "--motion-slices"),
        (["--store", "x"], "not both"),
    ],
)
def test_bad_input_is_one_error_line_and_writes_nothing(scan, tmp_path, capsys, extra, message):
    path, read, *_ = scan
    assert run(["stack", str(path), "--out", str(tmp_path / "o.zarr"), "-w", "0", "-q", *read, *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and message in err and err.count("\n") == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_scan_file_needs_out_or_store_and_a_store_takes_no_out(scan, tmp_path, capsys):
    path, read, *_ = scan
    assert run(["stack", str(path), "-q", *read]) == 2
    assert "--out OUT.zarr" in capsys.readouterr().err
    assert run(["stack", str(path), "--store", str(tmp_path / "s"), "--block", "4", "-q", *read]) == 2
    assert "--block goes with --out" in capsys.readouterr().err and not (tmp_path / "s").exists()
    assert run(["import", str(path), "--out", str(tmp_path / "store"), "--rows", "0:2", "-q", *read]) == 0
    assert run(["stack", str(tmp_path / "store"), "--out", str(tmp_path / "o.zarr"), "-q"]) == 2
    assert "is a data set" in capsys.readouterr().err


def test_a_streamed_stack_names_dremel_options_the_centroids_left_unused(scan, tmp_path, capsys):
    path, read, *_ = scan
    argv = ["--rows", "0:6", "--block", "6", "--center-offset", "1.2", "--coarse-iter", "2", "-w", "0", "-q"]
    assert run(["stack", str(path), "--out", str(tmp_path / "s.zarr"), *argv, *read]) == 0
    out = capsys.readouterr().out
    info = dict(zarr.open_group(str(tmp_path / "s.zarr"), mode="r").attrs["info"])
    assert info["horizontal_method"] == "centroid" and "note     --coarse-iter not used" in out, out
