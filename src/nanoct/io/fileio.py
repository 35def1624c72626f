"""Atomic file writes: a kill at any moment leaves either the old file or the new one.

Every small result file nanoct writes (checkpoints, training logs, run configurations,
evaluation tables, reports, figures) goes through :func:`atomic_write_bytes`: the data is
written to a temporary sibling ``.<name>.tmp-<hex>``, flushed to disk and renamed over the
target with ``os.replace``. A kill between the write and the rename leaves only the temporary
behind; :func:`remove_stale_temporaries` clears those when a job resumes in the directory.

A write that fails for want of space (``ENOSPC``, ``EDQUOT``) leaves the old file and no
temporary, and becomes one :class:`~nanoct.core.errors.DiskFullError` naming the file, the free
space and the space the write needed (:func:`disk_space_needed` does the same for a whole job).
"""

from __future__ import annotations

import errno
import functools
import hashlib
import os
import shutil
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TypeVar

from ..core.errors import DiskFullError

__all__ = [
    "atomic_link",
    "atomic_target",
    "atomic_write_bytes",
    "atomic_write_text",
    "cached_by_file",
    "disk_space_needed",
    "file_sha256",
    "free_space",
    "remove_stale_temporaries",
]

_NO_SPACE = (errno.ENOSPC, errno.EDQUOT)

_T = TypeVar("_T")

_TMP_TAG = ".tmp-"


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` via a temporary sibling file and ``os.replace``.

    Parameters
    ----------
    path : path-like
        Target file; its directory must exist.
    data : bytes
        The whole new content.

    Returns
    -------
    Path
        ``path``.
    """
    with atomic_target(path, len(data)) as tmp, open(tmp, "wb") as f:
        f.write(data)
    return Path(path)


@contextmanager
def atomic_target(path: str | os.PathLike[str], needed: int | None = None) -> Iterator[Path]:
    """A temporary sibling of ``path`` to write to; on success it is flushed to disk and renamed to ``path``.

    For writers that need a file name (numpy, tifffile, h5py). The temporary keeps the suffix of
    ``path`` (``.<name>.tmp-<hex><suffix>``), so writers that add one do not rename it; on an
    error it is removed and ``path`` is untouched. A full disk raises :class:`DiskFullError`
    naming ``path`` and ``needed`` (bytes, when the caller knows them).
    """
    path = Path(path)
    tmp = path.parent / f".{path.name}{_TMP_TAG}{uuid.uuid4().hex[:8]}{path.suffix}"
    try:
        with disk_space_needed(path, needed):
            yield tmp
            with open(tmp, "rb+") as f:
                os.fsync(f.fileno())
            os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def atomic_link(src: str | os.PathLike[str], path: str | os.PathLike[str]) -> Path:
    """Make ``path`` the same file as ``src`` (a hard link, else a copy), replacing ``path`` atomically.

    A later atomic write of ``src`` replaces its directory entry with a new file, so ``path``
    keeps the content it was linked to. Saves writing the same bytes twice (a training run's
    ``best.pt`` and ``last.pt`` after an improving epoch).
    """
    with atomic_target(path, os.path.getsize(src)) as tmp:
        try:
            os.link(src, tmp)
        except OSError:  # a file system without hard links
            shutil.copyfile(src, tmp)
    return Path(path)


def _size(n: float) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024
    raise AssertionError  # unreachable: the loop returns at GiB


def free_space(path: str | os.PathLike[str]) -> int | None:
    """Bytes free on the file system of ``path`` (its nearest existing ancestor), or None if unknown."""
    for p in (Path(path), *Path(path).parents):
        if p.exists():
            try:
                return shutil.disk_usage(p).free
            except OSError:
                return None
    return None


@contextmanager
def disk_space_needed(path: str | os.PathLike[str], needed: int | None) -> Iterator[None]:
    """Turn a full-disk error in the block into a :class:`DiskFullError` naming ``path`` and the space needed.

    Parameters
    ----------
    path : path-like
        The file or directory being written (named in the message).
    needed : int or None
        Bytes the block still had to write (an upper bound; None when unknown).
    """
    try:
        yield
    except OSError as exc:
        if exc.errno not in _NO_SPACE or isinstance(exc, DiskFullError):
            raise
        free = free_space(path)
        have = "unknown free space" if free is None else f"{_size(free)} free"
        want = "" if needed is None else f", about {_size(needed)} more needed"
        raise DiskFullError(
            errno.ENOSPC,
            f"no space left on the device of {path} ({have}{want}); free some space and run the same command "
            "again (it resumes where it stopped)",
            str(path),
        ) from exc


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; see :func:`atomic_write_bytes`."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def file_sha256(path: str | os.PathLike[str]) -> str:
    """SHA-256 of a file's bytes (hex), read in 1 MiB blocks: what identifies a checkpoint wherever it lies.

    Parameters
    ----------
    path : path-like
        An existing file.

    Returns
    -------
    str
        The hex digest.
    """
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def remove_stale_temporaries(directory: str | os.PathLike[str]) -> list[Path]:
    """Delete the temporaries that a killed :func:`atomic_write_bytes` left in ``directory``.

    Call this only from the process that owns the directory, before it writes again: a
    temporary of a write in progress elsewhere would be removed too.

    Parameters
    ----------
    directory : path-like
        A run or report directory; nothing happens when it does not exist.

    Returns
    -------
    list of Path
        The files removed.
    """
    directory = Path(directory)
    if not directory.is_dir():
        return []
    stale = [p for p in directory.iterdir() if p.name.startswith(".") and _TMP_TAG in p.name and p.is_file()]
    for p in stale:
        p.unlink(missing_ok=True)
    return stale


def _file_stamp(path: Path) -> tuple[int, int]:
    """``(inode, mtime in ns)`` of a file, ``(0, 0)`` if it is missing."""
    try:
        info = os.stat(path)
    except OSError:
        return (0, 0)
    return (info.st_ino, info.st_mtime_ns)


def cached_by_file(relative: str, maxsize: int) -> Callable[[Callable[[str], _T]], Callable[[str], _T]]:
    """A per-process cache of ``func(path)`` that is read again once ``path / relative`` is written or made again.

    Keyed by the path and the file's ``(inode, mtime)``, not by the path alone: a store deleted and
    made again at the same path within one process (a notebook, a test, a benchmark running the CLI
    in-process) is another store, whose cached handle or arrays must not be the old one's.

    Parameters
    ----------
    relative : str
        The file under ``path`` whose change invalidates the entry (e.g. ``"zarr.json"``).
    maxsize : int
        Entries kept (least recently used dropped).
    """

    def wrap(func: Callable[[str], _T]) -> Callable[[str], _T]:
        @functools.lru_cache(maxsize=maxsize)
        def cached(path: str, stamp: tuple[int, int]) -> _T:
            return func(path)

        @functools.wraps(func)
        def call(path: str) -> _T:
            return cached(path, _file_stamp(Path(path) / relative))

        return call

    return wrap
