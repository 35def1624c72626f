"""Scan readers, one module a format, in one registry.

Every module of this package but :mod:`~nanoct.io.readers.base` is a format's (or, for the HDF5
layouts, a family's): it holds ``READERS``, its :class:`~nanoct.io.readers.base.Reader` objects,
which are registered when the package is imported. :data:`READERS` holds them by ``--format``
name in rank order; :func:`detect_format` asks each in turn whether it recognises a file, and
:func:`nanoct.io.scanio.read_scan` reads the file with the one chosen. The formats that
``--format`` lists and the table of formats in ``docs/measured_data.md`` come from here
(``tests/io/test_readers.py`` holds the table to the registry).

Adding a format: a module here whose ``READERS`` holds its reader (name, title, extensions, how it
recognises a file, how it reads one), a writer of a small file of it in ``tests/scan_files.py``
(``tests/io/test_readers.py`` runs every registered reader over its file: round trip, angles, pixel
size, a truncated file, an untrusted link), and its row in the docs' table.
"""

from __future__ import annotations

import importlib
import os
import pkgutil
from pathlib import Path

from ...core.errors import NanoctError
from .base import Reader, ReaderOptions, ReadRequest

__all__ = ["READERS", "Reader", "ReadRequest", "ReaderOptions", "detect_format", "reader", "register"]

#: Every registered reader by its ``--format`` name, in rank order.
READERS: dict[str, Reader] = {}


def register(new: Reader) -> Reader:
    """Add a reader to :data:`READERS` (kept in rank order, ties by name) and return it.

    Raises
    ------
    ValueError
        If a reader of that name is registered already.
    """
    if new.name in READERS:
        raise ValueError(f"a reader named {new.name!r} is registered already ({READERS[new.name]!r})")
    ordered = sorted([*READERS.values(), new], key=lambda r: (r.rank, r.name))
    READERS.clear()
    READERS.update((r.name, r) for r in ordered)
    return new


def reader(name: str) -> Reader:
    """The reader of ``--format name``.

    Raises
    ------
    NanoctError
        For a name no reader has (the message lists the formats).
    """
    if name not in READERS:
        raise NanoctError(f"--format {name!r} is unknown; use one of {', '.join(READERS)}")
    return READERS[name]


def detect_format(path: str | os.PathLike[str], allow: tuple[str, ...] = ()) -> str:
    """The format of a scan file, from its path and, where the readers look into it, its content.

    ``allow``: folders outside the scan's own that the readers may follow links to while they look.

    Raises
    ------
    NanoctError
        For a missing path, a file no reader recognises (the message lists the formats, or says
        what reads it, e.g. the dataset options of an HDF5 file of no known layout), or a file a
        reader cannot open.
    """
    path = Path(path)
    if not path.exists():
        raise NanoctError(f"{path} does not exist; give the scan file or TIFF folder")
    for candidate in READERS.values():
        if candidate.recognises(path, allow):
            return candidate.name
    for candidate in READERS.values():
        refusal = candidate.unrecognised(path)
        if refusal is not None:
            raise NanoctError(refusal)
    raise NanoctError(f"cannot tell the format of {path} from its extension; pass --format ({', '.join(READERS)})")


def _register_modules() -> None:
    """Register the ``READERS`` of every module of this package but ``base``."""
    for module in pkgutil.iter_modules(__path__):
        if module.name == "base":
            continue
        found = importlib.import_module(f"{__name__}.{module.name}")
        if not hasattr(found, "READERS"):
            raise TypeError(f"{found.__name__} holds no READERS; every module of {__name__} but base is a format's")
        for one in found.READERS:
            register(one)


_register_modules()
