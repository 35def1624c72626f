"""NumPy arrays: a ``.npy`` stack ``(views, rows, columns)`` or one sinogram ``(views, columns)`` (``--format npy``).

Read through a memory map (only the selected rows and columns are read from disk,
:mod:`nanoct.io.tiffio`); the angles come from ``--angles``, flat and dark fields from ``--flats`` /
``--darks``.
"""

from __future__ import annotations

from pathlib import Path

from ..rawscan import RawScan
from ..tiffio import read_stack
from .base import Reader, ReadRequest

__all__ = ["READERS", "NpyReader"]


class NpyReader(Reader):
    """A ``.npy`` file of projections or of one sinogram."""

    name = "npy"
    title = "NumPy `.npy`: projections (views, rows, columns) or a sinogram (views, columns)"
    extensions = (".npy",)
    recognised_by = "the extension"
    rank = 50
    takes = frozenset({"flats", "darks"})

    def read(self, path: Path, request: ReadRequest) -> RawScan:
        return read_stack(path, self.name, request.window, request.angles, request.flats, request.darks)


READERS = (NpyReader(),)
