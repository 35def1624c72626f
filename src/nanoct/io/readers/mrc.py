"""MRC / IMOD tilt series: the reader of ``--format mrc``.

The stack is read by :mod:`nanoct.io.mrcio` (one image per tilt, a non-standard header read
permissively, ``--tilt-axis``); the angles come from ``--angles`` or from IMOD's ``.rawtlt`` /
``.tlt`` file beside the stack (``--angles-select`` picks lines of either).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from ...core.errors import NanoctError
from ..angles import read_angles
from ..mrcio import MRC_SUFFIXES, count_views, find_tilt_file, read_mrc
from ..rawscan import RawScan
from .base import Reader, ReadRequest

__all__ = ["READERS", "MrcReader"]


class MrcReader(Reader):
    """An MRC stack, one image per tilt, its angles beside it."""

    name = "mrc"
    title = "MRC / IMOD tilt series"
    extensions = MRC_SUFFIXES
    recognised_by = "the extension"
    rank = 60
    takes = frozenset({"tilt_axis", "angles_select"})

    def read(self, path: Path, request: ReadRequest) -> RawScan:
        opts, given, source = request.options, request.angles, {}
        if given is None:
            tilt = find_tilt_file(path)
            if tilt is None:
                raise NanoctError(
                    f"{path}: no {path.with_suffix('.rawtlt').name} or {path.with_suffix('.tlt').name} next to it; "
                    "pass --angles FILE (one angle per view)"
                )
            given = read_angles(tilt, degrees=True, units=opts.angle_units, select=opts.angles_select)
            source["angles_from"] = str(tilt)
        n_views = count_views(path)  # a non-standard header is read permissively (read_mrc warns)
        given = given(n_views) if callable(given) else given
        if given.size != n_views:
            raise NanoctError(f"{path}: {n_views} images but {given.size} tilt angle(s); give one angle per image")
        scan = read_mrc(path, request.window, given, tilt_axis=opts.tilt_axis)
        return replace(scan, source={**scan.source, **source})


READERS = (MrcReader(),)
