"""An HDF5 file is untrusted input: links leave the scan's folder only where the user allows, and a
damaged file is one error line, never a traceback."""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from nanoct.cli import run
from nanoct.core.errors import NanoctError
from nanoct.io.h5tree import H5Tree
from nanoct.io.scanio import ReaderOptions, read_scan

K, R, L = 9, 2, 5
PATHS = ReaderOptions(data_path="/scan/data", angles_path="/scan/theta")


def _scan_with(path: Path, data_link=None, theta=None) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with h5py.File(path, "w") as f:
        if data_link is None:
            f["scan/data"] = np.ones((K, R, L), np.float32)
        else:
            f["scan/data"] = data_link
        f["scan/theta"] = np.linspace(0, 180, K, endpoint=False) if theta is None else theta
    return path


def _frames_file(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with h5py.File(path, "w") as f:
        f["frames"] = np.full((K, R, L), 0.5, np.float32)
    return path


def _one_error_line(argv, capsys) -> str:
    assert run(argv) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and "Traceback" not in err, err
    return lines[0]


def test_an_external_link_to_etc_passwd_is_refused_naming_it(tmp_path, capsys):
    path = _scan_with(tmp_path / "scan.h5", data_link=h5py.ExternalLink("/etc/passwd", "/x"))
    with pytest.raises(NanoctError, match="/etc/passwd.*outside the scan's folder"):
        read_scan(path, options=PATHS)
    line = _one_error_line(["import", str(path), "--out", str(tmp_path / "o"), "--data-path", "/scan/data",
                            "--angles-path", "/scan/theta"], capsys)  # fmt: skip
    assert "/etc/passwd" in line and not (tmp_path / "o").exists()


def test_a_link_up_the_tree_is_refused_unless_allowed(tmp_path, capsys):
    outside = _frames_file(tmp_path / "x.h5")
    path = _scan_with(tmp_path / "a" / "b" / "scan.h5", data_link=h5py.ExternalLink("../../x.h5", "/frames"))
    with pytest.raises(NanoctError, match=r"\.\./\.\./x\.h5.*refused.*--allow-outside"):
        read_scan(path, options=PATHS)
    scan = read_scan(path, options=ReaderOptions(**{**PATHS.__dict__, "allow": (str(tmp_path),)}))
    np.testing.assert_array_equal(scan.projections, 0.5)
    argv = ["import", str(path), "--out", str(tmp_path / "o"), "--data-path", "/scan/data", "--angles-path",
            "/scan/theta", "--line-integrals", "-q"]  # fmt: skip
    assert "x.h5" in _one_error_line(argv, capsys)
    assert run([*argv, "--allow-outside", str(outside.parent)]) == 0
    assert capsys.readouterr().out == ""  # -q


def test_a_virtual_dataset_reading_outside_is_refused(tmp_path):
    _frames_file(tmp_path / "elsewhere" / "frames.h5")
    layout = h5py.VirtualLayout(shape=(K, R, L), dtype=np.float32)
    layout[:] = h5py.VirtualSource(str(tmp_path / "elsewhere" / "frames.h5"), "frames", shape=(K, R, L))
    path = tmp_path / "scan" / "scan.h5"
    _scan_with(path)
    with h5py.File(path, "a") as f:
        del f["scan/data"]
        f.create_virtual_dataset("scan/data", layout)
    with pytest.raises(NanoctError, match="virtual dataset.*frames.h5.*outside"):
        read_scan(path, options=PATHS)
    allowed = ReaderOptions(**{**PATHS.__dict__, "allow": (str(tmp_path / "elsewhere"),)})
    np.testing.assert_array_equal(read_scan(path, options=allowed).projections, 0.5)


def test_missing_targets_loops_and_non_hdf5_targets_are_named(tmp_path):
    path = _scan_with(tmp_path / "s1.h5", data_link=h5py.ExternalLink("raw/none.h5", "/frames"))
    with pytest.raises(NanoctError, match="raw/none.h5, which is missing"):
        read_scan(path, options=PATHS)
    (tmp_path / "raw").mkdir()
    (tmp_path / "raw" / "text.h5").write_text("not hdf5")
    path = _scan_with(tmp_path / "s2.h5", data_link=h5py.ExternalLink("raw/text.h5", "/frames"))
    with pytest.raises(NanoctError, match="cannot open .*text.h5 as HDF5"):
        read_scan(path, options=PATHS)
    path = _scan_with(tmp_path / "s3.h5", data_link=h5py.SoftLink("/scan/loop"))
    with h5py.File(path, "a") as f:
        f["scan/loop"] = h5py.SoftLink("/scan/data")
    with pytest.raises(NanoctError, match="more than .* links"):
        read_scan(path, options=PATHS)
    with H5Tree(path) as tree:
        assert tree.get("/scan/nothing") is None and tree.keys("/nothing") == []


@pytest.mark.parametrize("damage", ["truncated", "garbage", "empty", "linked-truncated"])
def test_a_damaged_file_is_one_error_line(tmp_path, capsys, damage):
    src = Path(__file__).resolve().parents[1] / "data" / "realdata" / "k11-18014-nexus"
    shutil.copytree(src, tmp_path / "k11")
    path = tmp_path / "k11" / "k11-18014.nxs"
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif damage == "garbage":
        path.write_bytes(np.random.default_rng(0).bytes(4096))
    elif damage == "empty":
        path.write_bytes(b"")
    else:  # the frames file behind the external link cut short
        frames = tmp_path / "k11" / "k11-18014" / "k11-18014-imaging.h5"
        frames.write_bytes(frames.read_bytes()[: frames.stat().st_size // 3])
    with pytest.raises(NanoctError):
        read_scan(path)
    line = _one_error_line(["import", str(path), "--out", str(tmp_path / "o")], capsys)
    assert str(tmp_path / "k11") in line
    assert not (tmp_path / "o").exists()
