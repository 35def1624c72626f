"""One small scan file of every registered format, written from the same data (``from scan_files import ...``).

:data:`WRITERS` holds a writer per reader of :data:`nanoct.io.readers.READERS` (a new format adds
its own; the HDF5 layouts get theirs from their row of ``LAYOUTS``). A writer takes a folder and the
data (:class:`ScanData`) and returns a :class:`ScanFile`: where the file is, how to read it, and what
reading it gives back. ``tests/io/test_readers.py`` holds every reader to one contract with these;
``tests/io/test_import.py`` imports each through the CLI.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import h5py
import mrcfile
import numpy as np
import tifffile

from nanoct.io.hdf5_layouts import LAYOUTS
from nanoct.io.scanio import ReaderOptions

#: The pixel size the formats that store one are written with (metres, x then y).
PIXEL_M = (6.5e-6, 7.0e-6)


@dataclass(frozen=True)
class ScanData:
    """What every writer writes: intensities ``(K, R, L)``, flats and darks ``(F, R, L)``, angles (degrees)."""

    projections: np.ndarray
    flats: np.ndarray
    darks: np.ndarray
    degrees: np.ndarray

    @property
    def line_integrals(self) -> np.ndarray:
        """``-log((p - d) / (f - d))`` with the mean flat and dark, float32 (for formats without flats)."""
        dark, flat = self.darks.mean(axis=0), self.flats.mean(axis=0)
        return (-np.log((self.projections - dark) / (flat - dark))).astype(np.float32)


@dataclass(frozen=True)
class ScanFile:
    """A scan file as a writer left it, how to read it and what it holds.

    ``path``: what ``read_scan`` and ``nanoct import`` are given; ``payload``: the file that holds the
    frames (a truncation cuts it); ``frames``: the HDF5 dataset of the frames (a link can replace it;
    None: not HDF5); ``projections``, ``flats``, ``darks``: what ``read_scan`` returns; ``pixel_size``:
    its ``raw_pixel_size_m`` (None: the format records none); ``recognised``: ``detect_format`` tells the
    format without being told.
    """

    path: Path
    payload: Path
    projections: np.ndarray
    flats: np.ndarray | None = None
    darks: np.ndarray | None = None
    angles_file: Path | None = None
    flat_file: Path | None = None
    dark_file: Path | None = None
    line_integrals: bool = False
    options: ReaderOptions = field(default_factory=ReaderOptions)
    frames: str | None = None
    pixel_size: tuple[float, float] | None = None
    recognised: bool = True

    def read_kwargs(self) -> dict[str, Any]:
        """The keywords of ``read_scan`` that read it."""
        return {
            "angles_file": self.angles_file,
            "flats": self.flat_file,
            "darks": self.dark_file,
            "is_line_integral": self.line_integrals,
            "options": self.options,
        }

    def cli_args(self) -> list[str]:
        """The flags of ``nanoct import`` that read it."""
        args = ["--line-integrals"] if self.line_integrals else []
        for flag, value in (("--angles", self.angles_file), ("--flats", self.flat_file), ("--darks", self.dark_file)):
            args += [flag, str(value)] if value is not None else []
        paths = (("--data-path", "data_path"), ("--image-key-path", "image_key_path"), ("--angles-path", "angles_path"))
        for flag, name in paths:
            value = getattr(self.options, name)
            args += [flag, value] if value is not None else []
        return args


def _keyed(data: ScanData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frames darks, flats, projections in one stack with their NXtomo image keys and angles (0 for the fields)."""
    frames = np.concatenate([data.darks, data.flats, data.projections])
    n_fields = len(data.darks) + len(data.flats)
    keys = np.r_[np.full(len(data.darks), 2), np.full(len(data.flats), 1), np.zeros(len(data.projections), int)]
    return frames, keys, np.r_[np.zeros(n_fields), data.degrees]


def _nxtomo(folder: Path, data: ScanData) -> ScanFile:
    path = folder / "scan.nxs"
    frames, keys, angles = _keyed(data)
    with h5py.File(path, "w") as f:
        entry = f.create_group("entry")
        entry.attrs["NX_class"] = "NXentry"
        entry["definition"] = "NXtomo"
        entry["instrument/detector/data"] = frames
        entry["instrument/detector/image_key_control"] = keys
        entry["sample/rotation_angle"] = angles
        entry["sample/rotation_angle"].attrs["units"] = "degree"
        for axis, size in zip("xy", PIXEL_M):
            entry[f"sample/{axis}_pixel_size"] = size * 1e6
            entry[f"sample/{axis}_pixel_size"].attrs["units"] = "um"
    return ScanFile(
        path,
        path,
        data.projections,
        data.flats,
        data.darks,
        frames="/entry/instrument/detector/data",
        pixel_size=PIXEL_M,
    )


def _layout(name: str, folder: Path, data: ScanData) -> ScanFile:
    """A file of the layout ``name`` of ``LAYOUTS``, at its own paths."""
    layout, path = LAYOUTS[name], folder / f"{name}.h5"
    with h5py.File(path, "w") as f:
        if layout.image_key is not None:
            f[layout.data], f[layout.image_key], f[layout.angles] = _keyed(data)
            flats, darks = data.flats, data.darks
        else:
            f[layout.data], f[layout.angles] = data.projections, data.degrees
            flats = darks = None
            if layout.flats is not None:
                f[layout.flats], flats = data.flats, data.flats
            if layout.darks is not None:
                f[layout.darks], darks = data.darks, data.darks
    return ScanFile(path, path, data.projections, flats, darks, frames=layout.data)


def _by_paths(folder: Path, data: ScanData) -> ScanFile:
    """An HDF5 file of no known layout: read by the dataset paths given."""
    path = folder / "scan.h5"
    with h5py.File(path, "w") as f:
        f["scan/frames"], f["scan/keys"], f["scan/theta"] = _keyed(data)
    options = ReaderOptions(data_path="/scan/frames", image_key_path="/scan/keys", angles_path="/scan/theta")
    return ScanFile(
        path, path, data.projections, data.flats, data.darks, options=options, frames="/scan/frames", recognised=False
    )


def _beside(folder: Path, data: ScanData, suffix: str) -> dict[str, Path]:
    """An angles text file and flat and dark files of ``suffix`` (``.tif``, ``.npy``) beside the scan."""
    np.savetxt(folder / "angles.txt", data.degrees)
    files = {
        "angles_file": folder / "angles.txt",
        "flat_file": folder / f"flats{suffix}",
        "dark_file": folder / f"darks{suffix}",
    }
    for name, values in (("flat_file", data.flats), ("dark_file", data.darks)):
        if suffix == ".npy":
            np.save(files[name], values)
        else:
            tifffile.imwrite(files[name], values)
    return files


def _tiff(folder: Path, data: ScanData) -> ScanFile:
    path = folder / "scan.tif"
    with tifffile.TiffWriter(path) as writer:
        for image in data.projections:
            writer.write(image, contiguous=False)
    return ScanFile(path, path, data.projections, data.flats, data.darks, **_beside(folder, data, ".tif"))


def _npy(folder: Path, data: ScanData) -> ScanFile:
    path = folder / "scan.npy"
    np.save(path, data.projections)
    return ScanFile(path, path, data.projections, data.flats, data.darks, **_beside(folder, data, ".npy"))


def _mrc(folder: Path, data: ScanData) -> ScanFile:
    """An electron tomography tilt series: line integrals (an MRC stack has no flats), IMOD's angles beside it."""
    path = folder / "scan.mrc"
    with mrcfile.new(path) as mrc:
        mrc.set_data(data.line_integrals)
        mrc.voxel_size = (PIXEL_M[0] * 1e10, PIXEL_M[1] * 1e10, 1.0)  # angstrom
    np.savetxt(path.with_suffix(".rawtlt"), data.degrees)
    return ScanFile(path, path, data.line_integrals, line_integrals=True, pixel_size=PIXEL_M)


#: A writer per registered format: ``WRITERS[name](folder, data) -> ScanFile``.
WRITERS: dict[str, Callable[[Path, ScanData], ScanFile]] = {
    "nxtomo": _nxtomo,
    **{name: partial(_layout, name) for name in LAYOUTS},
    "hdf5": _by_paths,
    "tiff": _tiff,
    "npy": _npy,
    "mrc": _mrc,
}
