"""HDF5 scans of the known layouts (Diamond, Data Exchange) and of any layout given by dataset paths.

One reader per row of :data:`nanoct.io.hdf5_layouts.LAYOUTS` (``--format diamond``,
``diamond-nxtomo``, ``dxchange``), recognised by that row's frames being in the file (the first row
that fits; an NXtomo entry is :mod:`nanoct.io.readers.nxtomo`'s), and ``--format hdf5``, which reads
a file of no known layout by the paths the user gives (``--data-path``, ``--image-key-path``,
``--angles-path``). A new layout is one row of ``LAYOUTS`` (and of the docs' table). Every path is
read through :class:`~nanoct.io.h5tree.H5Tree`: links only below the scan's folder.
"""

from __future__ import annotations

from pathlib import Path

from ..angles import H5_SUFFIXES
from ..h5tree import H5Tree
from ..hdf5_layouts import LAYOUTS, H5Layout, custom_layout, detect_layout, read_layout
from ..rawscan import RawScan
from .base import Reader, ReadRequest

__all__ = ["READERS", "LayoutReader", "read_by_paths"]


def read_by_paths(tree: H5Tree, base: H5Layout | None, request: ReadRequest) -> RawScan:
    """The scan of an open file read as ``base`` (None: no known layout) with the dataset paths given."""
    opts = request.options
    layout = custom_layout(base, opts.data_path, opts.image_key_path, opts.angles_path, None)
    return read_layout(tree, layout, request.window, units=opts.angle_units, need_angles=request.angles is None)


class LayoutReader(Reader):
    """An HDF5 file of one known layout, or (``layout`` None) of the layout the dataset paths give."""

    extensions = H5_SUFFIXES
    takes = frozenset({"data_path", "allow"})
    follows_links = True

    def __init__(self, layout: H5Layout | None, rank: int) -> None:
        self.layout = layout
        self.rank = rank
        if layout is None:
            self.name, self.title = "hdf5", "HDF5 of any other layout, read by the dataset paths given"
            self.recognised_by = "never: `--data-path` (or `--format hdf5`) chooses it"
        else:
            self.name, self.title = layout.name, layout.title
            self.recognised_by = f"frames at `{layout.data}` (no NXtomo entry)"

    def recognises(self, path: Path, allow: tuple[str, ...] = ()) -> bool:
        if self.layout is None or not super().recognises(path):
            return False
        with H5Tree(path, allow) as tree:
            return detect_layout(tree) == self.name

    def unrecognised(self, path: Path) -> str | None:
        if self.layout is not None or not super().recognises(path):
            return None
        known = ", ".join(f"{n} ({v.data})" for n, v in LAYOUTS.items())
        return (
            f"{path} is HDF5 but of no known layout (NXtomo; {known}); give the dataset paths with "
            "--data-path (and --image-key-path, --angles-path)"
        )

    def read(self, path: Path, request: ReadRequest) -> RawScan:
        with H5Tree(path, request.options.allow) as tree:
            return read_by_paths(tree, self.layout, request)


READERS = (*(LayoutReader(layout, 20 + i) for i, layout in enumerate(LAYOUTS.values())), LayoutReader(None, 30))
