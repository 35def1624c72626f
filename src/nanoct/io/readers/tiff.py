"""TIFF scans: a multi-page stack, or a folder of one TIFF per projection (``--format tiff``).

Read by :mod:`nanoct.io.tiffio` (a damaged or truncated file refused, not read in part); the
angles come from ``--angles``, flat and dark fields from ``--flats`` / ``--darks``.
"""

from __future__ import annotations

from pathlib import Path

from ..rawscan import RawScan
from ..tiffio import read_stack
from .base import Reader, ReadRequest

__all__ = ["READERS", "TiffReader"]


class TiffReader(Reader):
    """A multi-page TIFF, or a folder of TIFFs sorted by name."""

    name = "tiff"
    title = "TIFF: a multi-page stack, or a folder of one file per projection"
    extensions = (".tif", ".tiff")
    recognised_by = "the extension, or a folder"
    rank = 40
    takes = frozenset({"flats", "darks"})

    def recognises(self, path: Path, allow: tuple[str, ...] = ()) -> bool:
        return path.is_dir() or path.suffix.lower() in self.extensions

    def read(self, path: Path, request: ReadRequest) -> RawScan:
        return read_stack(path, self.name, request.window, request.angles, request.flats, request.darks)


READERS = (TiffReader(),)
