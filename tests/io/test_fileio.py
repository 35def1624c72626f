"""Atomic writes and the clean-up of what a killed write leaves behind."""

from __future__ import annotations

import errno
import os

import pytest

import nanoct.io.fileio as fileio
from nanoct.core.errors import DiskFullError
from nanoct.io.fileio import (
    atomic_link,
    atomic_write_bytes,
    atomic_write_text,
    disk_space_needed,
    free_space,
    remove_stale_temporaries,
)


def test_atomic_write_replaces_whole_file(tmp_path):
    target = tmp_path / "a.json"
    assert atomic_write_text(target, "old") == target
    atomic_write_bytes(target, b"new content")
    assert target.read_bytes() == b"new content"
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


def test_failed_write_keeps_old_file_and_no_temporary(tmp_path, monkeypatch):
    target = tmp_path / "a.txt"
    atomic_write_text(target, "old")

    def failing_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(fileio.os, "replace", failing_replace)
    with pytest.raises(OSError, match="disk full"):
        atomic_write_text(target, "new")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]


def test_remove_stale_temporaries(tmp_path):
    keep = [tmp_path / "last.pt", tmp_path / ".hidden", tmp_path / "x.tmp-1234"]
    for p in keep:
        p.write_bytes(b"k")
    stale = [tmp_path / ".last.pt.tmp-0a1b2c3d", tmp_path / ".log.csv.tmp-deadbeef"]
    for p in stale:
        p.write_bytes(b"partial")
    assert sorted(remove_stale_temporaries(tmp_path)) == sorted(stale)
    assert sorted(tmp_path.iterdir()) == sorted(keep)
    assert remove_stale_temporaries(tmp_path / "missing") == []


def test_atomic_link_shares_content_until_the_source_is_rewritten(tmp_path):
    src, dst = tmp_path / "best.pt", tmp_path / "last.pt"
    atomic_write_bytes(src, b"epoch 3")
    atomic_write_bytes(dst, b"epoch 2")
    assert atomic_link(src, dst) == dst
    assert dst.read_bytes() == b"epoch 3" and os.path.samefile(src, dst)
    atomic_write_bytes(src, b"epoch 5")  # an atomic rewrite of the source leaves the link's content alone
    assert dst.read_bytes() == b"epoch 3" and src.read_bytes() == b"epoch 5"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["best.pt", "last.pt"]


class _HalfWriter:
    """A file whose first write stores half the bytes, then fails as a full or broken disk does."""

    def __init__(self, path, mode, code):
        self._f, self._code = open(path, mode), code

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._f.close()

    def write(self, data):
        self._f.write(data[: len(data) // 2])
        raise OSError(self._code, os.strerror(self._code), self._f.name)


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EIO])
def test_write_failing_half_way_keeps_the_old_file(tmp_path, monkeypatch, code):
    target = tmp_path / "last.pt"
    atomic_write_bytes(target, b"old checkpoint")
    monkeypatch.setattr(fileio, "open", lambda p, m: _HalfWriter(p, m, code), raising=False)
    if code == errno.ENOSPC:
        with pytest.raises(DiskFullError) as info:
            atomic_write_bytes(target, b"x" * 3000)
        message = str(info.value)
        assert str(target) in message and "free" in message and "2.9 KiB more needed" in message
        assert info.value.errno == errno.ENOSPC and info.value.filename == str(target)
    else:
        with pytest.raises(OSError) as info:
            atomic_write_bytes(target, b"x" * 3000)
        assert info.value.errno == errno.EIO and not isinstance(info.value, DiskFullError)
    assert target.read_bytes() == b"old checkpoint"
    assert [p.name for p in tmp_path.iterdir()] == ["last.pt"]


def test_disk_space_needed_passes_other_errors(tmp_path):
    with pytest.raises(PermissionError):
        with disk_space_needed(tmp_path, 10):
            raise PermissionError(errno.EACCES, "Permission denied", str(tmp_path))
    with pytest.raises(DiskFullError, match=r"unknown free space|free\)"):
        with disk_space_needed(tmp_path / "new" / "deeper", None):
            raise OSError(errno.EDQUOT, "Disk quota exceeded")
    assert free_space(tmp_path / "missing" / "x") == free_space(tmp_path) > 0


def test_cached_by_file_reads_again_once_the_file_is_written_or_made_again(tmp_path):
    calls = []

    @fileio.cached_by_file("marker", maxsize=2)
    def read(path: str) -> str:
        calls.append(path)
        return (tmp_path / "d" / "marker").read_text()

    folder = tmp_path / "d"
    folder.mkdir()
    (folder / "marker").write_text("one")
    assert read(str(folder)) == read(str(folder)) == "one" and len(calls) == 1  # cached
    os.remove(folder / "marker")
    (folder / "marker").write_text("two")
    os.utime(folder / "marker", ns=(1, 1))  # another mtime even on a coarse clock
    assert read(str(folder)) == "two" and len(calls) == 2
