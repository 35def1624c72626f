"""MRC / IMOD tilt series: an image stack read with ``mrcfile``, its angles from an IMOD angle file (``--format
mrc``: :mod:`nanoct.io.readers.mrc`).

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

Non-standard headers: a stack is opened as standard MRC2014 first. Where ``mrcfile`` rejects
its header (FEI, SerialEM and older IMOD files often lack the map ID ``MAP `` or the machine
stamp) it is opened again permissively, and when its images can be read they are, with one
:class:`MrcHeaderWarning` naming each non-standard field (and any bytes after the data that
the header does not account for). A file whose header promises more data than it holds (a
truncated copy) is refused.
"""

from __future__ import annotations

import os
import re
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from .rawscan import RawScan

__all__ = ["MRC_SUFFIXES", "TILT_AXES", "MrcHeaderWarning", "count_views", "find_tilt_file", "open_mrc", "read_mrc"]

MRC_SUFFIXES = (".mrc", ".mrcs", ".st", ".ali", ".preali", ".rec", ".map")
TILT_AXES = ("columns", "rows")

_HEADER_BYTES = 1024
_MAP_ID = slice(208, 212)  # the header's map ID bytes, b"MAP " in MRC2014
# mrcfile's permissive-mode warnings that it could not read the data (the file is then refused)
_UNREADABLE = re.compile(r" - data block (?:not|cannot be) read$|^Error opening memmap$|^Expected \d+ bytes in")


class MrcHeaderWarning(UserWarning):
    """An MRC stack whose header is not standard MRC2014 was read permissively."""


def find_tilt_file(path: str | os.PathLike[str]) -> Path | None:
    """The IMOD angle file next to a stack (``.tlt`` for ``.ali``, else ``.rawtlt`` first), or None."""
    path = Path(path)
    order = (".tlt", ".rawtlt") if path.suffix.lower() == ".ali" else (".rawtlt", ".tlt")
    return next((path.with_suffix(s) for s in order if path.with_suffix(s).is_file()), None)


def _layout(header: Any) -> tuple[str, int | None]:
    """The header's account of the file, in words, and the bytes it needs (None: no known data mode)."""
    from mrcfile import utils

    extended, mode = int(header.nsymbt), int(header.mode)
    shape = utils.data_shape_from_header(header)
    parts = f"{_HEADER_BYTES} header + {extended} extended header + {' x '.join(map(str, shape))} values of mode {mode}"
    try:
        itemsize = utils.data_dtype_from_header(header).itemsize
    except ValueError:
        return parts, None
    return f"{parts}, {itemsize} bytes each", _HEADER_BYTES + extended + itemsize * int(np.prod(shape))


def _describe(message: str, header: Any, raw: bytes) -> str:
    """What one of mrcfile's permissive-mode warnings says is non-standard, in terms of the header's fields."""
    if message.startswith("Map ID string not found"):
        return f"map ID {raw[_MAP_ID]!r} instead of b'MAP '"
    if found := re.fullmatch(r"Unrecognised machine stamp: (.*)", message):
        return (
            f"machine stamp {found[1]} instead of 0x44 0x44 (little-endian) or 0x11 0x11 (big-endian), "
            "taken as little-endian"
        )
    if found := re.fullmatch(r"Machine stamp '(.*)' does not match the apparent byte order '(.)'", message):
        order = "big" if found[2] == ">" else "little"
        return f"machine stamp {found[1]} names the other byte order than its mode, taken as {order}-endian"
    if found := re.fullmatch(r"MRC file is (\d+) bytes larger than expected", message):
        accounted = _layout(header)[0]
        return f"{found[1]} bytes after the data that the header ({accounted}) does not account for, left unread"
    if found := re.match(r"Unrecognised mode '(.*)'", message):
        return f"mode {found[1]} is not an MRC mode"
    return message


@contextmanager
def open_mrc(path: str | os.PathLike[str]) -> Iterator[tuple[Any, list[str]]]:
    """Open an MRC file read-only (memory-mapped): as standard MRC2014, else permissively.

    Parameters
    ----------
    path : path
        The MRC file.

    Yields
    ------
    mrc : mrcfile.mrcmemmap.MrcMemmap
        The open file, its data memory-mapped (nothing read yet); closed on leaving the block.
    nonstandard : list of str
        What is not standard in its header, one entry per field (empty for a standard file). Nothing
        is warned here: :func:`read_mrc` warns once with these.

    Raises
    ------
    NanoctError
        A file that cannot be read at all, whose header promises more data than the file holds
        or names no known data mode.
    """
    import mrcfile

    path = Path(path)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                mrc = mrcfile.mmap(path, mode="r", permissive=False)
            except ValueError:  # a header mrcfile does not accept: try again, permissively
                caught.clear()
                mrc = mrcfile.mmap(path, mode="r", permissive=True)
    except (ValueError, OSError, EOFError) as exc:
        raise NanoctError(f"cannot read {path} as MRC ({exc}); is the file complete?") from None
    with mrc:
        header = mrc.header
        raw = header.tobytes()
        messages = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
        failed = [m for m in messages if _UNREADABLE.search(m)]
        nonstandard = [_describe(m, header, raw) for m in messages if m not in failed]
        if mrc.data is None:
            parts, needed = _layout(header)
            size = path.stat().st_size
            if needed is not None and needed > size:
                reason = f"the header asks for {needed} bytes ({parts}) but the file has {size}"
            else:
                reason = "; ".join(_describe(re.sub(r" - data block .*", "", m), header, raw) for m in failed)
            found = f" (its header is non-standard too: {'; '.join(nonstandard)})" if nonstandard else ""
            raise NanoctError(f"cannot read {path} as MRC: {reason or 'no data'}{found}; is the file complete?")
        yield mrc, nonstandard


def count_views(path: str | os.PathLike[str]) -> int:
    """The number of images (header ``nz``) of an MRC stack, opened as :func:`read_mrc` opens it.

    Parameters
    ----------
    path : path
        The MRC stack.

    Returns
    -------
    int
        The header's ``nz``; a non-standard header is read permissively, without a warning
        (:func:`read_mrc` gives it). The data are only memory-mapped, not read, but checked as
        :func:`read_mrc` checks them: a header-only read would take the ``nz`` of a machine stamp
        naming the wrong byte order byte-swapped.

    Raises
    ------
    NanoctError
        A file that is not a complete MRC stack (:func:`open_mrc`).
    """
    with open_mrc(path) as (mrc, _):
        return int(mrc.header.nz)


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

    Returns
    -------
    RawScan
        The images as float32 and their angles; ``source["mrc_nonstandard"]`` lists what was not
        standard in the header, where something was.

    Raises
    ------
    NanoctError
        A file that is not a complete MRC stack, a single image, an unknown ``tilt_axis``.

    Warns
    -----
    MrcHeaderWarning
        Once, naming each non-standard field, for a header read permissively.
    """
    path = Path(path)
    if tilt_axis not in TILT_AXES:
        raise NanoctError(f"--tilt-axis {tilt_axis!r}: use columns (IMOD's, vertical) or rows (horizontal)")
    try:
        with open_mrc(path) as (mrc, nonstandard):
            data, voxel = mrc.data, mrc.voxel_size
            if data.ndim != 3:
                raise NanoctError(f"{path} holds an array of shape {data.shape}; a tilt series is a stack of images")
            detector = data.shape[1:] if tilt_axis == "columns" else data.shape[:0:-1]
            r, c = window(detector)
            stack = data[:, r, c] if tilt_axis == "columns" else data[:, c, r].transpose(0, 2, 1)
            stack = np.array(stack, dtype=np.float32)
            pixel = [float(voxel.x), float(voxel.y)][:: 1 if tilt_axis == "columns" else -1]
    except (ValueError, OSError, EOFError) as exc:
        raise NanoctError(f"cannot read {path} as MRC ({exc}); is the file complete?") from None
    source = {"file": str(path), "format": "mrc", "tilt_axis": tilt_axis, "detector_shape": list(detector)}
    if nonstandard:
        source["mrc_nonstandard"] = nonstandard
        warnings.warn(
            f"{path} has a non-standard MRC header, read permissively: {'; '.join(nonstandard)}",
            MrcHeaderWarning,
            stacklevel=2,
        )
    if all(p > 0 for p in pixel):
        source["raw_pixel_size_m"] = [p * 1e-10 for p in pixel]
        source["pixel_size_from"] = "MRC header voxel_size (angstrom)"
    return RawScan(stack, angles, source=source)
