"""Atomic writes and the clean-up of what a killed write leaves behind."""

from __future__ import annotations

import os

import pytest

import nanoct.io.fileio as fileio
from nanoct.io.fileio import atomic_link, atomic_write_bytes, atomic_write_text, remove_stale_temporaries


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
