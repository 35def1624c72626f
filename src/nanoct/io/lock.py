"""Lock files: one writer at a time for a reconstruction of a store or a training run.

Two processes running the same ``nanoct reconstruct``, ``predict`` or ``train`` on one store
or run directory would interleave their writes (and each would remove the other's temporary
files when it resumes). :func:`exclusive` lets the first one in and refuses the second with a
:class:`~nanoct.core.errors.BusyError` naming the owner.

The lock is a file ``DIR/.<name>.lock`` created with ``O_EXCL`` and holding its owner's pid,
the start time of that process, the host name and the command line. A lock whose owner is gone
(same host; no process with that pid, or one started at another time: the pid was reused; or
this very process, which no longer holds it) is stale and is broken by the next writer; a lock
held on another host (a shared file system) is never broken automatically, the message says
which file to delete once that process is gone.
"""

from __future__ import annotations

import json
import os
import socket
import sys
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import psutil

from ..core.errors import BusyError

__all__ = ["exclusive", "lock_path", "pid_alive"]

# tokens of the locks this process holds now: a lock naming this process but not listed here was
# left by a block that an exception (or a simulated kill) ended without its clean-up
_HELD: set[str] = set()

# a lock file still empty (or garbled) after this many seconds was left by a writer killed between
# creating and filling it
_EMPTY_GRACE_S = 30.0


def lock_path(directory: str | os.PathLike[str], name: str) -> Path:
    """The lock file of ``name`` in ``directory``: ``DIR/.<name>.lock``."""
    return Path(directory) / f".{name}.lock"


def pid_alive(pid: int, started: float | None = None) -> bool:
    """Whether process ``pid`` runs on this host (and, given ``started``, is the one started then)."""
    try:
        process = psutil.Process(pid)
        return started is None or abs(process.create_time() - started) < 0.5
    except psutil.NoSuchProcess:
        return False
    except psutil.AccessDenied:  # exists, owned by someone else
        return True


def _owner_record() -> dict[str, Any]:
    return {
        "pid": os.getpid(),
        "started": psutil.Process().create_time(),
        "host": socket.gethostname(),
        "since": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        "command": " ".join(["nanoct", *sys.argv[1:]]) if sys.argv else "",
        "token": uuid.uuid4().hex,
    }


def _read(lock: Path) -> dict[str, Any] | None:
    """The owner record of ``lock``, or None when it is gone, empty or garbled."""
    try:
        record = json.loads(lock.read_text())
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) and {"pid", "started", "host"} <= record.keys() else None


def _stale(lock: Path, owner: dict[str, Any] | None) -> bool:
    if owner is None:  # being written right now, or its writer died before filling it (or it was garbled)
        try:
            return time.time() - lock.stat().st_mtime > _EMPTY_GRACE_S
        except FileNotFoundError:
            return False
    if owner.get("host") != socket.gethostname():
        return False  # cannot look at processes on another host
    if owner.get("pid") == os.getpid() and owner.get("token") not in _HELD:
        return True
    try:
        return not pid_alive(int(owner["pid"]), float(owner["started"]))
    except (KeyError, TypeError, ValueError):
        return False


def _break(lock: Path, seen: dict[str, Any] | None) -> None:
    """Remove a stale ``lock``; a live lock taken in its place meanwhile is put back."""
    grave = lock.with_name(f"{lock.name}.stale-{uuid.uuid4().hex[:8]}")
    try:
        os.rename(lock, grave)
    except FileNotFoundError:  # another writer broke it first
        return
    try:
        if _read(grave) != seen:
            try:
                os.link(grave, lock)
            except FileExistsError:
                pass
    finally:
        grave.unlink(missing_ok=True)


def _busy(lock: Path, what: str, owner: dict[str, Any] | None) -> BusyError:
    if owner is None:
        who = "another nanoct process (it is writing the lock file now)"
    else:
        who = (
            f"another nanoct process (pid {owner.get('pid')} on {owner.get('host')}, since {owner.get('since')}: "
            f"{owner.get('command')})"
        )
    return BusyError(
        f"{what} is being written by {who}; wait for it to finish and run the command again "
        f"(if that process is gone, delete {lock})"
    )


def _acquire(lock: Path, what: str, record: dict[str, Any]) -> None:
    """Create ``lock`` holding ``record``, breaking a stale one; :class:`BusyError` where a live process holds it."""
    for _ in range(3):
        try:
            fd = os.open(lock, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            owner = _read(lock)
            if not _stale(lock, owner):
                if lock.exists():
                    raise _busy(lock, what, owner) from None
                continue  # released meanwhile
            _break(lock, owner)
            continue
        with os.fdopen(fd, "w") as f:
            f.write(json.dumps(record))
            f.flush()
            os.fsync(f.fileno())
        return
    raise _busy(lock, what, _read(lock))


@contextmanager
def exclusive(directory: str | os.PathLike[str], name: str, what: str, wait: float = 0.0) -> Iterator[Path]:
    """Hold the lock ``DIR/.<name>.lock`` for the duration of the block.

    Parameters
    ----------
    directory : path-like
        Where the lock file lives (a store or a run directory); created when missing, and
        removed again on exit when the block left it empty.
    name : str
        What is locked within the directory (a reconstruction name, ``train``).
    what : str
        How the error message names the locked thing, e.g. ``"reconstructions/fbp of DIR"``.
    wait : float
        Seconds to wait for a live holder to release the lock before refusing (for blocks that
        take milliseconds, such as the update of a small file); 0: refuse at once.

    Yields
    ------
    Path
        The lock file.

    Raises
    ------
    BusyError
        If a live process holds the lock (for longer than ``wait``).
    """
    directory = Path(directory)
    made = [p for p in (directory, *directory.parents) if not p.exists()]
    directory.mkdir(parents=True, exist_ok=True)
    lock = lock_path(directory, name)
    record = _owner_record()
    deadline = time.monotonic() + wait
    try:
        while True:
            try:
                _acquire(lock, what, record)
                break
            except BusyError:
                if time.monotonic() >= deadline:
                    raise
                time.sleep(0.05)
        _HELD.add(record["token"])
        try:
            yield lock
        finally:
            _HELD.discard(record["token"])
            if (_read(lock) or {}).get("token") == record["token"]:
                lock.unlink(missing_ok=True)
    finally:
        for p in made:  # innermost first
            try:
                p.rmdir()
            except OSError:  # not empty: the block wrote into it
                break
