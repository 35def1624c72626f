"""TIFF stacks and ``.npy`` arrays: projections, flat and dark fields, read with tifffile and numpy (``--format
tiff`` and ``npy``: :mod:`nanoct.io.readers.tiff`, :mod:`nanoct.io.readers.npy`).

A multi-page TIFF is one stack; a folder of TIFFs (sorted by name) holds one projection per
file. A truncated or damaged file is refused rather than read in part (tifffile logs, rather
than raises, some damage: those log messages are caught).
"""

from __future__ import annotations

import logging
import os
import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from .rawscan import RawScan, angle_count_error

__all__ = ["read_array", "read_field", "read_stack", "read_tiff", "read_tiff_folder"]


def read_stack(path: Path, fmt: str, window: Any, given: Any, flats: Any = None, darks: Any = None) -> RawScan:
    """A TIFF stack or folder (``fmt`` ``"tiff"``), or a ``.npy`` array (``"npy"``), with separate flat and dark files.

    ``window``: the part of the detector (:func:`~nanoct.io.rawscan.detector_window`); ``given``: the angles
    (radians), or a function of the number of views; these formats have none of their own.
    """
    if given is None:
        raise NanoctError(f"a {fmt} scan has no angles; pass --angles FILE (one angle per view)")
    folder = fmt == "tiff" and path.is_dir()
    if folder:  # one file per projection: each cut as it is read
        stack, detector = read_tiff_folder(path, window)
    else:
        stack = read_array(path, fmt, mmap=True)
        stack = stack[:, None, :] if stack.ndim == 2 else stack  # one sinogram (K, L): one detector row
        detector = stack.shape[1:]
    if stack.ndim != 3:
        raise NanoctError(f"{path} holds an array of shape {stack.shape}; expected (views, rows, columns)")
    r, c = window(detector)
    stack = stack if folder else stack[:, r, c]

    def frames(file: str | os.PathLike[str] | None, what: str) -> np.ndarray | None:
        return None if file is None else read_field(Path(file), what, detector)[:, r, c]

    given = given(stack.shape[0]) if callable(given) else given
    if given.size != stack.shape[0]:
        raise angle_count_error(given.size, stack.shape[0])
    return RawScan(
        np.asarray(stack, dtype=np.float32),
        given,
        flats=frames(flats, "flats"),
        darks=frames(darks, "darks"),
        source={"file": str(path), "format": fmt, "detector_shape": list(detector)},
    )


def read_field(path: Path, what: str, detector: tuple[int, ...]) -> np.ndarray:
    """Flat or dark fields ``(F, R, L)`` from a TIFF or ``.npy`` file, checked against the detector ``(R, L)``.

    One frame ``(R, L)`` is accepted, and for a one-row detector (a sinogram) frames ``(F, L)`` or ``(L,)``.

    Parameters
    ----------
    path : Path
    what : {"flats", "darks"}
        For the message.
    detector : (int, int)
        Rows and columns of one projection.

    Returns
    -------
    ndarray of shape (F, R, L)
    """
    field = read_array(path, None)
    n_rows, n_cols = detector
    if field.ndim == 3 and field.shape[1:] == tuple(detector):
        return field
    if field.ndim == 2 and field.shape == tuple(detector):
        return field[None]
    if n_rows == 1 and field.ndim in (1, 2) and field.shape[-1] == n_cols:
        return field.reshape(-1, 1, n_cols)
    raise NanoctError(
        f"--{what} {path}: {what} have shape {field.shape}, but one projection is {tuple(detector)} "
        f"(rows, columns); give {what} recorded with the same detector size and binning as the projections"
    )


def read_array(path: Path, fmt: str | None, *, mmap: bool = False) -> np.ndarray:
    """A ``.npy`` file (memory-mapped with ``mmap``: read as it is sliced), a TIFF or a folder of TIFFs.

    Parameters
    ----------
    path : Path
    fmt : {"npy", "tiff"} or None
        None: from the extension.
    mmap : bool
        Memory-map a ``.npy`` file.

    Returns
    -------
    ndarray
    """
    if not path.exists():
        raise NanoctError(f"{path} does not exist")
    fmt = fmt or ("npy" if path.suffix.lower() == ".npy" else "tiff")
    if fmt == "npy":
        try:
            return np.load(path, allow_pickle=False, mmap_mode="r" if mmap else None)
        except (OSError, ValueError, EOFError) as exc:
            raise NanoctError(f"cannot read {path} as .npy ({exc}); is the file complete?") from exc
    return read_tiff_folder(path)[0] if path.is_dir() else read_tiff(path)


def read_tiff_folder(
    path: Path, window: Callable[..., tuple[slice, slice]] | None = None
) -> tuple[np.ndarray, tuple[int, ...]]:
    """The TIFFs of a folder (sorted by name, one image each) stacked, each cut to ``window`` as it is read.

    Parameters
    ----------
    path : Path
        The folder.
    window : callable, optional
        ``window((R, L)) -> (row slice, column slice)`` (:func:`nanoct.io.rawscan.detector_window`).

    Returns
    -------
    ndarray
        The stack.
    tuple of int
        The shape of one full image.
    """
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in (".tif", ".tiff"))
    if not files:
        raise NanoctError(f"{path} holds no .tif/.tiff files")
    images, first = [], None
    for file in files:
        image = read_tiff(file)
        first = first or (file, image.shape)
        if image.shape != first[1]:
            raise NanoctError(
                f"{file} has shape {image.shape}, but {first[0].name} has {first[1]}; "
                f"every TIFF of {path} must be one projection of the same size"
            )
        if window is not None and image.ndim == 2:
            image = np.ascontiguousarray(image[window(image.shape)])
        images.append(image)
    return np.stack(images), first[1]


# what tifffile logs (rather than raises) when the page list of a file is cut or damaged
_TIFF_DAMAGE = ("invalid page offset", "invalid offset to page", "corrupted", "truncated", "failed to read")


class _Complaints(logging.Handler):
    """Collects tifffile's log messages that say a file is damaged (they are logged, not raised)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        if any(word in message for word in _TIFF_DAMAGE):
            self.messages.append(message)


def read_tiff(path: Path) -> np.ndarray:
    """A TIFF file as an array; a truncated or damaged file is refused rather than read in part.

    Parameters
    ----------
    path : Path

    Returns
    -------
    ndarray
        One image ``(R, L)`` or a stack ``(K, R, L)``.
    """
    import tifffile

    complaints = _Complaints()
    logger = logging.getLogger("tifffile")
    logger.addHandler(complaints)
    try:
        with tifffile.TiffFile(path) as tif:
            series = tif.series
            # a file written page by page can hold one series per image: read them all, not the first
            shapes = {(s.shape, s.dtype) for s in series}
            if len(series) > 1 and len(shapes) > 1:
                raise NanoctError(
                    f"{path} holds {len(series)} image series of different shapes or types "
                    f"({', '.join(sorted({str(s.shape) for s in series}))}); write one stack of equal images"
                )
            image = np.stack([s.asarray() for s in series]) if len(series) > 1 else tif.asarray()
    except (OSError, ValueError, EOFError, struct.error) as exc:
        raise NanoctError(f"cannot read {path} as TIFF ({exc}); the file may be truncated - copy it again") from exc
    finally:
        logger.removeHandler(complaints)
    if complaints.messages:
        raise NanoctError(
            f"{path} is damaged or truncated (tifffile: {complaints.messages[0]}); copy it again or rewrite it"
        )
    return image
