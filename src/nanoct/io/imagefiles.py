"""Images out: reconstructions and std maps as float32 TIFF, ``.npy`` or HDF5, written atomically."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from .fileio import atomic_target

__all__ = ["EXPORT_FORMATS", "write_images"]

EXPORT_FORMATS = {".tif": "tiff", ".tiff": "tiff", ".npy": "npy", ".h5": "hdf5", ".hdf5": "hdf5"}


def write_images(
    path: str | os.PathLike[str], images: Any, *, dataset: str = "data", attrs: dict | None = None
) -> Path:
    """Write a stack of images ``(S, N, N)`` as float32 TIFF (one page each), ``.npy`` or HDF5.

    The format follows the extension (:data:`EXPORT_FORMATS`). The file is written to a
    temporary sibling and renamed, so a failed or interrupted export leaves no partial file.

    Parameters
    ----------
    path : path
        Output file.
    images : array_like of shape (S, N, N) or (N, N)
        Reconstructions or std maps.
    dataset : str
        HDF5 dataset name.
    attrs : dict, optional
        HDF5 attributes of the dataset (JSON-able values), e.g. where the images came from.

    Returns
    -------
    Path
    """
    path = Path(path)
    fmt = EXPORT_FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise NanoctError(f"cannot tell the export format of {path}; use one of {', '.join(sorted(EXPORT_FORMATS))}")
    stack = np.asarray(images, dtype=np.float32)
    stack = stack[None] if stack.ndim == 2 else stack
    if stack.ndim != 3:
        raise NanoctError(f"images have shape {stack.shape}; expected (slices, rows, columns)")
    with atomic_target(path) as tmp:
        if fmt == "tiff":
            import tifffile

            tifffile.imwrite(tmp, stack, photometric="minisblack")
        elif fmt == "npy":
            np.save(tmp, stack)
        else:
            import h5py

            with h5py.File(tmp, "w") as f:
                ds = f.create_dataset(dataset, data=stack)
                for key, value in (attrs or {}).items():
                    ds.attrs[key] = value if isinstance(value, (int, float, str)) else repr(value)
    return path
