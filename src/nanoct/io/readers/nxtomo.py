"""NXtomo files (ESRF's ``nxtomo``, NeXus writers): the reader of ``--format nxtomo``.

The file's layout is read by :mod:`nanoct.io.nxtomo` (entries, image keys, angle units, pixel
size) through :class:`~nanoct.io.h5tree.H5Tree` (links only below the scan's folder). With HDF5
dataset paths given (``--data-path`` ...) the file is read by those paths instead
(:func:`nanoct.io.readers.layouts.read_by_paths`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..angles import H5_SUFFIXES
from ..h5tree import H5Tree
from ..nxtomo import nxtomo_entries, read_nxtomo, to_unit
from ..rawscan import RawScan, check_angles
from .base import Reader, ReadRequest
from .layouts import read_by_paths

__all__ = ["READERS", "NXtomoReader"]


class NXtomoReader(Reader):
    """An HDF5 file with an ``NXentry`` whose ``definition`` is ``NXtomo``."""

    name = "nxtomo"
    title = "NXtomo (ESRF's `nxtomo`, NeXus writers)"
    extensions = H5_SUFFIXES
    recognised_by = "an `NXentry` whose `definition` is `NXtomo`"
    rank = 10
    takes = frozenset({"entry", "data_path", "allow"})
    follows_links = True

    def recognises(self, path: Path, allow: tuple[str, ...] = ()) -> bool:
        if not super().recognises(path):
            return False
        with H5Tree(path, allow) as tree:
            return bool(nxtomo_entries(tree))

    def read(self, path: Path, request: ReadRequest) -> RawScan:
        opts = request.options
        need_angles = request.angles is None
        with H5Tree(path, opts.allow) as tree:
            if opts.has_paths:
                return read_by_paths(tree, None, request)
            frames = read_nxtomo(tree, request.entry, request.window)
            scan = RawScan(
                frames.projections,
                frames.angles if opts.angle_units is None else _restated(frames, opts.angle_units),
                flats=frames.flats,
                darks=frames.darks,
                source={"file": str(path), "format": "nxtomo", **frames.source},
            )
            if need_angles and opts.angle_units is None:
                units = frames.source["angle_units"]
                deg = bool(np.isclose(to_unit(1.0, units.split(" ")[0], "degree", default="degree", where=units), 1))
                where = f"{path}:{frames.source['entry']}/sample/rotation_angle"
                check_angles(scan.angles, degrees=deg, where=where, fix="correct its units attribute or pass --angles")
            return scan


def _restated(frames: Any, units: str) -> np.ndarray:
    """NXtomo angles re-read in the unit the user states (the file's ``units`` attribute ignored)."""
    stored = frames.source["angle_units"].split(" ")[0]
    raw = to_unit(frames.angles, "radian", stored, default="degree", where=str(stored))
    return np.deg2rad(raw) if units == "deg" else raw


READERS = (NXtomoReader(),)
