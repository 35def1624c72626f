"""MRC / IMOD tilt series: an image stack read with ``mrcfile``, its angles from an IMOD angle file.

An MRC stack (``.mrc``, IMOD's raw ``.st`` and aligned ``.ali``) holds one image per tilt,
``(nz, ny, nx)`` = (views, image rows, image columns). IMOD lists the tilt angles (degrees,
one per line) in ``<stack>.rawtlt`` (raw stack) or ``<stack>.tlt`` (aligned): without
``--angles`` the file next to the stack is used, ``.tlt`` for an ``.ali`` stack, ``.rawtlt``
first otherwise.

The tilt axis (``tilt_axis``): ``"columns"`` (IMOD's convention, the default) when it runs
along the image columns (vertical, parallel to the image y axis): each image row is one slice,
its pixels the detector of that slice. ``"rows"`` when it runs along the image rows
(horizontal): the images are transposed, each image column becomes one slice and the image
y axis its detector. The pixel size (header ``voxel_size``, angstrom) is kept when set.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..core.errors import NanoctError
from .rawscan import RawScan

__all__ = ["MRC_SUFFIXES", "TILT_AXES", "find_tilt_file", "read_mrc"]

MRC_SUFFIXES = (".mrc", ".mrcs", ".st", ".ali", ".preali", ".rec", ".map")
TILT_AXES = ("columns", "rows")


def find_tilt_file(path: str | os.PathLike[str]) -> Path | None:
    """The IMOD angle file next to a stack (``.tlt`` for ``.ali``, else ``.rawtlt`` first), or None."""
    path = Path(path)
    order = (".tlt", ".rawtlt") if path.suffix.lower() == ".ali" else (".rawtlt", ".tlt")
    return next((path.with_suffix(s) for s in order if path.with_suffix(s).is_file()), None)


def read_mrc(
    path: str | os.PathLike[str],
    window: Callable[..., tuple[slice, slice]],
    angles: np.ndarray,
    *,
    tilt_axis: str = "columns",
) -> RawScan:
    """Read a tilt series (the ``window`` of its oriented detector) with ``mrcfile``.

    Parameters
    ----------
    path : path
        The MRC stack.
    window : callable
        ``window((R, L)) -> (row slice, column slice)`` on the oriented detector (rows = slices).
    angles : ndarray of shape (K,)
        Radians, one per image.
    tilt_axis : {"columns", "rows"}
        Along which image direction the tilt axis runs (see the module docstring).

    Raises
    ------
    NanoctError
        A file that is not a complete MRC stack, a single image, an unknown ``tilt_axis``.
    """
    import mrcfile

    path = Path(path)
    if tilt_axis not in TILT_AXES:
        raise NanoctError(f"--tilt-axis {tilt_axis!r}: use columns (IMOD's, vertical) or rows (horizontal)")
    try:
        with mrcfile.mmap(path, mode="r", permissive=False) as mrc:
            data, voxel = mrc.data, mrc.voxel_size
            if data is None or data.ndim != 3:
                shape = None if data is None else data.shape
                raise NanoctError(f"{path} holds an array of shape {shape}; a tilt series is a stack of images")
            detector = data.shape[1:] if tilt_axis == "columns" else data.shape[:0:-1]
            r, c = window(detector)
            stack = data[:, r, c] if tilt_axis == "columns" else data[:, c, r].transpose(0, 2, 1)
            stack = np.array(stack, dtype=np.float32)
            pixel = [float(voxel.x), float(voxel.y)][:: 1 if tilt_axis == "columns" else -1]
    except (ValueError, OSError, EOFError) as exc:
        raise NanoctError(f"cannot read {path} as MRC ({exc}); is the file complete?") from None
    source = {"file": str(path), "format": "mrc", "tilt_axis": tilt_axis, "detector_shape": list(detector)}
    if all(p > 0 for p in pixel):
        source["raw_pixel_size_m"] = [p * 1e-10 for p in pixel]
        source["pixel_size_from"] = "MRC header voxel_size (angstrom)"
    return RawScan(stack, angles, source=source)
