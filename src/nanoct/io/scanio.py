"""Measured scans in and results out: NXtomo / Data Exchange HDF5, TIFF stacks, ``.npy``.

A reader returns a :class:`RawScan`: the projections as a ``(K views, R detector rows, L
detector columns)`` float32 stack, optional flat and dark fields of shape ``(F, R, L)``, and the
view angles in radians. :func:`line_integrals` turns it into sinograms ``-log((p - d) / (f - d))``
and :func:`sinograms` into one ``(K, L)`` sinogram per detector row (slice), optionally cropped
and binned along the detector. Files are read with h5py and tifffile; nothing here parses a
file format by hand.

Conventions at this border (inside nanoct angles are radians and sinograms ``(K, L)``):
NXtomo ``rotation_angle`` is read in the unit of its ``units`` attribute (degrees without
one, :mod:`nanoct.io.nxtomo`), Data Exchange ``theta`` in degrees (as TomoPy's files and CIL
use it); angle files are text with one angle per view, degrees unless stated.

What is refused or corrected (``docs/measured_data.md``): files that cannot be read whole
(a truncated HDF5 or TIFF), angles that are all equal or whose span says they are in the
other unit, flats or darks of another detector size, and frames with NaN or infinite values
(named; :func:`drop_bad_views` leaves such projections out, with their angles, and says so).
Views are kept in acquisition order however the angles run: every reconstruction uses the
angle of each view, and the shifts files list the views in that order, as nabu does. A view
whose angle repeats an earlier one (modulo 360 degrees, e.g. the last view of a scan over
``[0, 360]``) is left out with a note (:func:`drop_repeated_views`): a geometry has one view
per direction.

Shifts files (:func:`write_shifts`, :func:`read_shifts`) use nabu's
``translation_movements_file`` layout: one row ``horizontal vertical`` per projection, in
detector pixels, ``horizontal`` the displacement of the projection along increasing
detector columns (nabu adds it to the axis position in its back projection). nanoct's own
shifts (Dremel's ``t . e_u``, :mod:`nanoct.recon.dremel`) move the projection the other way,
so ``horizontal = -shift``.
"""

from __future__ import annotations

import json
import logging
import os
import struct
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from .fileio import atomic_target
from .nxtomo import nxtomo_entries, read_h5_dataset, read_nxtomo, to_unit

__all__ = [
    "EXPORT_FORMATS",
    "FORMATS",
    "SHIFTS_HEADER",
    "RawScan",
    "check_angles",
    "detect_format",
    "drop_bad_views",
    "drop_repeated_views",
    "import_scan",
    "line_integrals",
    "read_angles",
    "read_scan",
    "read_shifts",
    "sinograms",
    "write_images",
    "write_shifts",
]

FORMATS = ("nxtomo", "dxchange", "tiff", "npy")
EXPORT_FORMATS = {".tif": "tiff", ".tiff": "tiff", ".npy": "npy", ".h5": "hdf5", ".hdf5": "hdf5"}
SHIFTS_HEADER = "horizontal vertical"  # nabu's column order, the header line of a shifts file
LEFT_OUT = "left out by the import"  # marks the rows of a shifts file for views a data set does not hold
_MIN_VIEWS_UNIT_CHECK = 8  # fewer views than this may span a few degrees on purpose (a test, an alignment)


@dataclass(frozen=True)
class RawScan:
    """Projections of a measured scan as read from its file.

    Attributes
    ----------
    projections : ndarray of shape (K, R, L), float32
        One detector image (R rows, L columns) per view; intensities, or line integrals when
        ``is_line_integral``.
    angles : ndarray of shape (K,), float64
        View angles in radians.
    flats, darks : ndarray of shape (F, R, L) or None
        Flat (open beam) and dark fields, if the file has them.
    is_line_integral : bool
        The projections are already ``-log`` normalised (no flat/dark correction applies).
    source : dict
        Where the data came from (file, format, dataset paths), stored with the import.
    views : ndarray of shape (K,), int, optional
        Index of each projection among the file's projections (default ``0 .. K-1``); views
        left out by :func:`drop_bad_views` or :func:`drop_repeated_views` are missing from it.
    """

    projections: np.ndarray
    angles: np.ndarray
    flats: np.ndarray | None = None
    darks: np.ndarray | None = None
    is_line_integral: bool = False
    source: dict[str, Any] = field(default_factory=dict)
    views: np.ndarray | None = None

    def __post_init__(self) -> None:
        proj = np.asarray(self.projections)
        if proj.ndim == 2:  # one sinogram (K, L): one detector row
            proj = proj[:, None, :]
        if proj.ndim != 3:
            raise NanoctError(
                f"projections have shape {proj.shape}; expected (views, rows, columns) or (views, columns)"
            )
        object.__setattr__(self, "projections", np.ascontiguousarray(proj, dtype=np.float32))
        angles = np.asarray(self.angles, dtype=np.float64).ravel()
        if angles.size != proj.shape[0]:
            raise NanoctError(
                f"{angles.size} angle(s) for {proj.shape[0]} projection(s); the angles must list one value per view"
            )
        if not np.isfinite(angles).all():
            raise NanoctError("the angles contain NaN or infinite values")
        object.__setattr__(self, "angles", angles)
        views = np.arange(proj.shape[0]) if self.views is None else np.asarray(self.views, dtype=int).ravel()
        if views.size != proj.shape[0]:
            raise NanoctError(f"{views.size} view indices for {proj.shape[0]} projection(s)")
        object.__setattr__(self, "views", views)
        for name in ("flats", "darks"):
            value = getattr(self, name)
            if value is None:
                continue
            arr = np.asarray(value, dtype=np.float32)
            arr = arr[None] if arr.ndim == 2 else arr
            if arr.ndim != 3 or arr.shape[1:] != proj.shape[1:]:
                where = f"{self.source['file']}: " if "file" in self.source else ""
                raise NanoctError(
                    f"{where}{name} have shape {arr.shape}, but one projection is {proj.shape[1:]} (rows, columns); "
                    f"give {name} of the same detector size"
                )
            object.__setattr__(self, name, arr)

    @property
    def n_views(self) -> int:
        """Number of projections K."""
        return int(self.projections.shape[0])


def detect_format(path: str | os.PathLike[str]) -> str:
    """Guess a scan's format from its path (and, for HDF5, its content).

    Raises
    ------
    NanoctError
        For a missing path or an unknown extension; the message lists :data:`FORMATS`.
    """
    path = Path(path)
    if not path.exists():
        raise NanoctError(f"{path} does not exist; give the scan file or TIFF folder")
    suffix = path.suffix.lower()
    if path.is_dir() or suffix in (".tif", ".tiff"):
        return "tiff"
    if suffix == ".npy":
        return "npy"
    if suffix in (".h5", ".hdf5", ".nx", ".nxs", ".hdf"):
        with _open_h5(path) as f:
            if "exchange/data" in f:
                return "dxchange"
            if nxtomo_entries(f):
                return "nxtomo"
        raise NanoctError(
            f"{path} is HDF5 but neither NXtomo (an NXentry with definition NXtomo, or entry/instrument/detector/data) "
            "nor Data Exchange (exchange/data); convert the file to one of them"
        )
    raise NanoctError(f"cannot tell the format of {path} from its extension; pass --format ({', '.join(FORMATS)})")


def read_angles(path: str | os.PathLike[str], *, degrees: bool = True) -> np.ndarray:
    """Angles from a text file with one value per view (radians returned).

    Raises
    ------
    NanoctError
        If the file is missing or not numeric, or the angles fail :func:`check_angles`.
    """
    table = _load_table(path, "angles")
    # one angle per line, "view angle" lines, or all angles on one line
    values = table[0] if table.shape[0] == 1 else table[:, -1]
    angles = np.deg2rad(values) if degrees else values
    check_angles(angles, degrees=degrees, where=f"the angles file {path}", fix="--radians")
    return angles


def check_angles(angles: np.ndarray, *, degrees: bool, where: str, fix: str) -> None:
    """Refuse view angles that cannot be what the scan meant.

    Parameters
    ----------
    angles : ndarray of shape (K,)
        Radians.
    degrees : bool
        The source gave them in degrees.
    where : str
        The file (and dataset), for the message.
    fix : str
        What sets the other unit (``--radians``, the ``units`` attribute).

    Raises
    ------
    NanoctError
        Non-finite angles; more than one view and all angles equal; at least
        :data:`_MIN_VIEWS_UNIT_CHECK` views in degrees spanning at most one turn in radians
        (``2 pi`` degrees: the values are radians), or in radians spanning more than two turns
        (the values are degrees).
    """
    if not np.isfinite(angles).all():
        raise NanoctError(f"{where}: {int((~np.isfinite(angles)).sum())} angle(s) are NaN or infinite")
    if angles.size < 2:
        return
    span = float(np.ptp(angles))
    if span == 0:
        raise NanoctError(f"{where}: all {angles.size} views have the angle {np.rad2deg(angles[0]):g} degrees")
    if angles.size >= _MIN_VIEWS_UNIT_CHECK and degrees and np.rad2deg(span) <= 2 * np.pi * (1 + 1e-6):
        raise NanoctError(
            f"{where}: {angles.size} views span only {np.rad2deg(span):.4g} degrees; these look like radians "
            f"({fix} if they are)"
        )
    if angles.size >= _MIN_VIEWS_UNIT_CHECK and not degrees and span > 4 * np.pi:
        raise NanoctError(
            f"{where}: {angles.size} views span {span:.4g} radians (more than two turns); these look like degrees"
        )


def read_scan(
    path: str | os.PathLike[str],
    *,
    fmt: str | None = None,
    angles_file: str | os.PathLike[str] | None = None,
    degrees: bool = True,
    flats: str | os.PathLike[str] | None = None,
    darks: str | os.PathLike[str] | None = None,
    is_line_integral: bool = False,
    entry: str | None = None,
    rows: slice | None = None,
    crop: tuple[int, int] | None = None,
) -> RawScan:
    """Read a measured scan, or the part of its detector that ``rows`` and ``crop`` select.

    Parameters
    ----------
    path : path
        NXtomo or Data Exchange HDF5 file, a multi-page TIFF, a folder of TIFFs (sorted by
        name, one projection each) or a ``.npy`` stack ``(K, R, L)`` / sinogram ``(K, L)``.
    fmt : {"nxtomo", "dxchange", "tiff", "npy"}, optional
        Format; guessed from the path by default.
    angles_file : path, optional
        Text file of view angles, required for TIFF and ``.npy`` (HDF5 files carry theirs;
        given anyway, it overrides them).
    degrees : bool
        Unit of the angles file (HDF5 angles are read in the unit their format defines).
    flats, darks : path, optional
        TIFF or ``.npy`` flat and dark fields for TIFF and ``.npy`` scans.
    is_line_integral : bool
        The data are already line integrals (no flat/dark correction, no ``-log``).
    entry : str, optional
        The NXtomo entry to read, needed when the file has several.
    rows : slice, optional
        Detector rows to read (default all). HDF5 and ``.npy`` files read only these rows and
        the ``crop`` columns from disk, so a few slices of a large scan fit in memory.
    crop : (int, int), optional
        Detector columns ``[first, stop)`` to read.

    Returns
    -------
    RawScan
        Projections, flats and darks of the selected rows and columns;
        ``source["detector_shape"]`` is the full detector ``[R, L]``.

    Raises
    ------
    NanoctError
        A missing, truncated or damaged file, a missing dataset or key, angle count !=
        projection count, angles that fail :func:`check_angles`, flats or darks of another
        shape, an unknown format; each message names the file and what to do.
    """
    fmt = fmt or detect_format(path)
    if fmt not in FORMATS:
        raise NanoctError(f"--format {fmt!r} is unknown; use one of {', '.join(FORMATS)}")
    if entry is not None and fmt != "nxtomo":
        raise NanoctError(f"--entry {entry!r} is for NXtomo files; {path} is {fmt}")
    check = angles_file is None  # angles given separately replace the file's, whatever they are
    window = _window(rows, crop)
    if fmt == "nxtomo":
        scan = _read_nxtomo(Path(path), entry, window, check=check)
    elif fmt == "dxchange":
        scan = _read_dxchange(Path(path), window, check=check)
    else:
        if angles_file is None:
            raise NanoctError(f"a {fmt} scan has no angles; pass --angles FILE (one angle per view)")
        folder = fmt == "tiff" and Path(path).is_dir()
        if folder:  # one file per projection: each cut as it is read
            stack, detector = _read_tiff_folder(Path(path), window)
        else:
            stack = _read_array(Path(path), fmt, mmap=True)
            stack = stack[:, None, :] if stack.ndim == 2 else stack  # one sinogram (K, L): one detector row
            detector = stack.shape[1:]
        if stack.ndim != 3:
            raise NanoctError(f"{path} holds an array of shape {stack.shape}; expected (views, rows, columns)")
        r, c = window(detector)
        stack = stack if folder else stack[:, r, c]

        def field(file: str | os.PathLike[str] | None, what: str) -> np.ndarray | None:
            return None if file is None else _read_field(Path(file), what, detector)[:, r, c]

        scan = RawScan(
            np.asarray(stack, dtype=np.float32),
            read_angles(angles_file, degrees=degrees),
            flats=field(flats, "flats"),
            darks=field(darks, "darks"),
            source={"file": str(path), "format": fmt, "detector_shape": list(detector)},
        )
    if angles_file is not None and fmt in ("nxtomo", "dxchange"):
        scan = replace(scan, angles=read_angles(angles_file, degrees=degrees))
    if is_line_integral:
        scan = replace(scan, is_line_integral=True, flats=None, darks=None)
    return scan


def line_integrals(scan: RawScan, *, tolerance: float = 1e-3, floor: float = 1e-6) -> np.ndarray:
    """Flat/dark-corrected line integrals ``-log((p - d) / (f - d))`` of a scan, ``(K, R, L)``.

    Mean flat and dark fields are used; without flats the projections are taken as already
    normalised transmissions, without darks the dark current is 0. Detector pixels whose flat is
    not above the dark (at most a fraction ``tolerance`` of them) get line integral 0. Transmissions that are not
    positive (dead pixels, a dark field above the signal) are raised to ``floor`` when they are
    at most a fraction ``tolerance`` of all values; more than that is taken for a wrong flat,
    dark or unit and refused.

    Raises
    ------
    NanoctError
        For NaN input, a non-positive flat-minus-dark, or too many non-positive transmissions.
    """
    if not 0 <= tolerance < 1:
        raise NanoctError(f"--tolerance {tolerance} must lie in [0, 1)")
    proj = scan.projections
    drop_bad_views(scan, drop=False)  # names the frames with NaN or infinite values
    if scan.is_line_integral:
        return proj.copy()
    dark = np.zeros(proj.shape[1:], np.float32) if scan.darks is None else scan.darks.mean(axis=0)
    flat = None if scan.flats is None else scan.flats.mean(axis=0)
    if flat is None:
        transmission = proj - dark
    else:
        gain = flat - dark
        bad = ~(gain > 0)
        if bad.mean() > tolerance:
            raise NanoctError(
                f"flat minus dark is not positive in {bad.mean():.1%} of detector pixels; "
                "check the flat and dark fields"
            )
        # a dead detector pixel (no flat signal) carries no information: line integral 0 there
        transmission = np.where(bad, 1.0, (proj - dark) / np.where(bad, 1.0, gain))
    nonpositive = ~(transmission > 0)
    if nonpositive.mean() > tolerance:
        raise NanoctError(
            f"{nonpositive.mean():.2%} of the flat/dark-corrected values are <= 0 (tolerance {tolerance:.2%}); "
            "check the flat and dark fields, or pass --line-integrals if the data are already -log normalised"
        )
    return -np.log(np.maximum(transmission, floor)).astype(np.float32)


def sinograms(
    data: np.ndarray,
    *,
    rows: slice | None = None,
    crop: tuple[int, int] | None = None,
    binning: int = 1,
) -> np.ndarray:
    """One sinogram ``(K, L')`` per detector row of a ``(K, R, L)`` stack: returns ``(S, K, L')``.

    Parameters
    ----------
    data : ndarray of shape (K, R, L)
        Line integrals.
    rows : slice, optional
        Detector rows (slices) to keep, e.g. ``slice(100, 110)``.
    crop : (int, int), optional
        Detector columns ``[first, stop)`` to keep.
    binning : int
        Average this many neighbouring detector columns (and rows, where the selection has at
        least that many), dropping a remainder; the detector pixel then grows by this factor.

    Raises
    ------
    NanoctError
        If the selection is empty or the binning does not fit.
    """
    stack = np.asarray(data, dtype=np.float32)
    if rows is not None:
        if not (rows.step in (None, 1) and 0 <= (rows.start or 0) < (rows.stop or 0) <= stack.shape[1]):
            raise NanoctError(
                f"--rows {rows.start}:{rows.stop} must satisfy 0 <= FIRST < STOP <= {stack.shape[1]} rows"
            )
        stack = stack[:, rows]
    if crop is not None:
        first, stop = crop
        if not 0 <= first < stop <= stack.shape[2]:
            raise NanoctError(f"--crop {first},{stop} must satisfy 0 <= first < stop <= {stack.shape[2]} columns")
        stack = stack[:, :, first:stop]
    if stack.shape[1] == 0:
        raise NanoctError(f"the row selection {rows} keeps no detector row of {data.shape[1]}")
    if not 1 <= binning <= stack.shape[2]:
        raise NanoctError(f"--binning {binning} must be between 1 and the {stack.shape[2]} detector columns")
    if binning > 1:  # columns always; rows (slices) too where there are enough of them
        k, r, c = stack.shape
        cols = c // binning * binning
        stack = stack[:, :, :cols].reshape(k, r, cols // binning, binning).mean(axis=3)
        if r >= binning:
            kept = r // binning * binning
            stack = stack[:, :kept].reshape(k, kept // binning, binning, -1).mean(axis=2)
    return np.ascontiguousarray(stack.transpose(1, 0, 2))


def _axis_after(offset: float, n_cols: int, crop: tuple[int, int] | None, binning: int) -> float:
    """The rotation-axis offset (from the detector centre) after cropping and binning, in new pixels."""
    axis = (n_cols - 1) / 2 + offset  # raw column where the axis is seen
    first, stop = crop if crop is not None else (0, n_cols)
    width = (stop - first) // binning
    return ((axis - first + 0.5) / binning - 0.5) - (width - 1) / 2


def import_scan(
    src: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    fmt: str | None = None,
    angles_file: str | os.PathLike[str] | None = None,
    degrees: bool = True,
    flats: str | os.PathLike[str] | None = None,
    darks: str | os.PathLike[str] | None = None,
    is_line_integral: bool = False,
    rows: slice | None = None,
    crop: tuple[int, int] | None = None,
    binning: int = 1,
    center_offset: float | str = 0.0,
    size: int | None = None,
    tolerance: float = 1e-3,
    entry: str | None = None,
    drop_bad: bool = False,
) -> Any:
    """Import a measured parallel-beam scan into a new data set, one sample per detector row.

    Reads the file (:func:`read_scan`), corrects flats and darks and takes ``-log``
    (:func:`line_integrals`), selects rows and crops and bins the detector (:func:`sinograms`),
    and stores the sinograms with a :class:`~nanoct.core.geometry.Geometry` built from the file's
    angles and the rotation-axis offset (:func:`nanoct.io.store.create_scan`). All slices share
    one motion (a stack is scanned at once), which Dremel then estimates jointly.

    Parameters
    ----------
    src, out : path
        Scan file (or TIFF folder) and the new data set's directory.
    fmt, angles_file, degrees, flats, darks, is_line_integral
        See :func:`read_scan`.
    rows : slice, optional
        Detector rows (slices) to import (default all).
    crop : (int, int), optional
        Detector columns ``[first, stop)`` to keep.
    binning : int
        Detector binning (columns, and rows where there are enough).
    center_offset : float or "auto"
        Rotation axis relative to the centre of the raw detector row, in raw detector pixels
        (TomoPy's ``center`` minus ``(L - 1) / 2``); converted to the cropped and binned
        detector. ``"auto"``: estimated from 8 of the selected rows by every estimator that
        applies, their median (:func:`nanoct.motion.axis.estimate_axis`: mirrored opposite
        views, algotom's ``find_center_vo``, centroids after the open beam is removed); the
        estimators' values are recorded in the store's ``scan["axis"]``.
    size : int, optional
        Reconstructed image size N (default: the number of detector columns after cropping
        and binning; one image pixel = one binned detector pixel).
    tolerance : float
        Fraction of non-positive flat/dark-corrected values tolerated (see :func:`line_integrals`).
    entry : str, optional
        NXtomo entry (see :func:`read_scan`).
    drop_bad : bool
        Leave out projections (and flat or dark frames) with NaN or infinite values in the
        selected rows and columns instead of refusing the scan (:func:`drop_bad_views`).

    Returns
    -------
    DataStore
        The new data set (re-running the same import on it is a no-op).

    Raises
    ------
    NanoctError
        Any problem with the file, the options or the output directory; nothing is written.
    """
    from ..core.geometry import Geometry
    from .store import DataStore, create_scan

    # only the selected rows and columns are read, checked and corrected
    raw = read_scan(
        src, fmt=fmt, angles_file=angles_file, degrees=degrees, flats=flats, darks=darks,
        is_line_integral=is_line_integral, entry=entry, rows=rows, crop=crop,
    )  # fmt: skip
    n_rows, n_cols = raw.source["detector_shape"]
    kept, dropped = drop_bad_views(raw, drop=drop_bad)
    kept, repeated = drop_repeated_views(kept)
    left_out = np.setdiff1d(np.arange(raw.n_views), kept.views)
    axis_record = None
    if center_offset == "auto":
        shift, estimate = _auto_center(kept, n_cols, crop, tolerance)
        center_offset = float(shift + estimate.offset)
        axis_record = {**estimate.to_dict(), "offset_raw": center_offset}
    first, stop = crop if crop is not None else (0, n_cols)
    n_det = (stop - first) // max(binning, 1)
    offset = _axis_after(center_offset, n_cols, crop, max(binning, 1))
    try:
        geometry = Geometry.from_angles(
            kept.angles, n_det if size is None else size, max(n_det, 1), center_offset=offset
        )
    except ValueError as exc:
        raise NanoctError(f"cannot build the scan geometry: {exc}") from exc
    scan = {
        **raw.source,
        "rows": None if rows is None else [rows.start, rows.stop],
        "crop": None if crop is None else list(crop),
        "binning": binning,
        "center_offset_raw": center_offset,
        "line_integrals": raw.is_line_integral,
        "flats": 0 if kept.flats is None else int(kept.flats.shape[0]),
        "darks": 0 if kept.darks is None else int(kept.darks.shape[0]),
        "shared_motion": True,
        "notes": [*raw.source.get("notes", []), *dropped, *repeated, *_angle_notes(kept.angles)],
    }
    if axis_record is not None:
        scan["axis"] = axis_record
    if left_out.size:  # shifts files keep one row per projection of the file (nabu's layout)
        scan.update(file_views=raw.n_views, left_out_views=left_out.tolist())
    if "raw_pixel_size_m" in raw.source:  # one stored detector pixel, after binning
        n_kept_rows = (rows.stop - rows.start) if rows is not None else n_rows
        x, y = raw.source["raw_pixel_size_m"]
        scan["pixel_size_m"] = [x * binning, y * (binning if n_kept_rows >= binning else 1)]
    if (Path(out) / "zarr.json").is_file():
        store = DataStore.open(out)
        if store.meta.get("scan") == json.loads(json.dumps(scan)) and store.geometry == geometry:
            return store  # the same import again: nothing to do
    stack = sinograms(line_integrals(kept, tolerance=tolerance), binning=binning)
    return create_scan(out, geometry, stack, scan)


def _auto_center(scan: RawScan, n_cols: int, crop: tuple[int, int] | None, tolerance: float) -> Any:
    """The axis (raw detector pixels) from 8 of the read rows: :func:`nanoct.motion.axis.estimate_axis`."""
    from ..motion.axis import axis_rows, estimate_axis

    picked = axis_rows(scan.projections.shape[1])
    some = replace(
        scan,
        projections=scan.projections[:, picked],
        flats=None if scan.flats is None else scan.flats[:, picked],
        darks=None if scan.darks is None else scan.darks[:, picked],
    )
    estimate = estimate_axis(sinograms(line_integrals(some, tolerance=tolerance)), scan.angles)
    first = crop[0] if crop is not None else 0
    n_kept = scan.projections.shape[2]
    return first + (n_kept - 1) / 2 - (n_cols - 1) / 2, estimate


def _angle_notes(angles: np.ndarray) -> list[str]:
    """What an import tells about angles it keeps as they are (acquisition order)."""
    steps = np.diff(angles)
    if steps.size and not ((steps >= 0).all() or (steps <= 0).all()):
        return ["the angles are not monotone; the views are kept in acquisition order, each with its angle"]
    return []


def drop_repeated_views(scan: RawScan) -> tuple[RawScan, list[str]]:
    """Leave out the views whose angle repeats that of an earlier view (modulo 360 degrees).

    A geometry has one view per direction (:class:`~nanoct.core.geometry.Geometry` refuses
    repeats), so the first view of each angle is kept: e.g. the 360-degree view of a scan
    over ``[0, 360]`` degrees, or a view measured again. Angles are compared as the geometry
    compares them (radians modulo ``2 pi``, rounded to 12 decimals).

    Returns
    -------
    RawScan
        The scan without the repeats (the same scan when there are none).
    list of str
        A note naming the views left out (indices among the projections), if any.
    """
    phase = np.round(np.mod(scan.angles, 2 * np.pi), 12)
    _, first = np.unique(phase, return_index=True)
    repeats = np.setdiff1d(np.arange(scan.n_views), first)
    if repeats.size == 0:
        return scan, []
    note = (
        f"left out {repeats.size} view(s) repeating the angle of an earlier view (modulo 360 degrees): "
        f"{_listed(repeats)}"
    )
    keep = np.sort(first)
    return replace(scan, projections=scan.projections[keep], angles=scan.angles[keep], views=scan.views[keep]), [note]


def _bad_frames(stack: np.ndarray | None) -> np.ndarray:
    """Indices of the frames of a ``(F, R, L)`` stack that hold NaN or infinite values."""
    if stack is None:
        return np.zeros(0, int)
    return np.flatnonzero(~np.isfinite(stack).all(axis=(1, 2)))


def _listed(indices: np.ndarray, limit: int = 8) -> str:
    shown = ", ".join(str(i) for i in indices[:limit])
    return shown + (f" ... ({indices.size} in all)" if indices.size > limit else "")


def drop_bad_views(scan: RawScan, *, drop: bool) -> tuple[RawScan, list[str]]:
    """Refuse, or leave out, the frames that hold NaN or infinite values.

    Parameters
    ----------
    scan : RawScan
    drop : bool
        Leave such projections out (with their angles) and such flat or dark frames out of
        the mean, instead of refusing the scan.

    Returns
    -------
    RawScan
        The scan without the bad frames (the same scan when there are none).
    list of str
        One note per kind of frame left out.

    Raises
    ------
    NanoctError
        Bad frames and not ``drop`` (the message names the frames, by index among the
        projections / flats / darks, and the angles); every frame of a kind bad.
    """
    where = scan.source.get("file", "the scan")
    notes: list[str] = []
    out = {}
    for name in ("projections", "flats", "darks"):
        stack = getattr(scan, name)
        bad = _bad_frames(stack)
        if bad.size == 0:
            continue
        what = f"{where}: {name} {_listed(bad)}"
        if name == "projections":
            what += f" (angles {_listed(np.round(np.rad2deg(scan.angles[bad]), 3))} degrees)"
        if not drop:
            raise NanoctError(
                f"{what} hold NaN or infinite values; pass --drop-bad-views to leave them out, or repair the file"
            )
        if bad.size == stack.shape[0]:
            raise NanoctError(f"{what}: every one of the {stack.shape[0]} {name} holds NaN or infinite values")
        out[name] = np.delete(stack, bad, axis=0)
        if name == "projections":
            out["angles"], out["views"] = np.delete(scan.angles, bad), np.delete(scan.views, bad)
        notes.append(f"left out {bad.size} of {stack.shape[0]} {name} with NaN or infinite values ({_listed(bad)})")
    return (replace(scan, **out) if out else scan), notes


def _window(rows: slice | None, crop: tuple[int, int] | None) -> Callable[[tuple[int, ...]], tuple[slice, slice]]:
    """The row and column slices of ``rows`` / ``crop`` on a detector of shape ``(R, L)``, checked."""

    def window(shape: tuple[int, ...]) -> tuple[slice, slice]:
        n_rows, n_cols = shape
        if rows is not None and not (rows.step in (None, 1) and 0 <= (rows.start or 0) < (rows.stop or 0) <= n_rows):
            raise NanoctError(f"--rows {rows.start}:{rows.stop} must satisfy 0 <= FIRST < STOP <= {n_rows} rows")
        if crop is not None and not 0 <= crop[0] < crop[1] <= n_cols:
            raise NanoctError(f"--crop {crop[0]},{crop[1]} must satisfy 0 <= first < stop <= {n_cols} columns")
        return (rows if rows is not None else slice(None)), (slice(*crop) if crop is not None else slice(None))

    return window


# ---------------------------------------------------------------------------------- readers
def _load_table(path: str | os.PathLike[str], what: str) -> np.ndarray:
    """A text table of numbers (``#`` comments), one row per line, as a 2-D float64 array."""
    try:
        return np.loadtxt(path, dtype=np.float64, ndmin=2, comments="#")
    except OSError as exc:
        raise NanoctError(f"cannot read the {what} file {path}: {exc}") from exc
    except ValueError as exc:
        raise NanoctError(f"the {what} file {path} is not a table of numbers ({exc})") from exc


def _open_h5(path: Path) -> Any:
    import h5py

    try:
        return h5py.File(path, "r")
    except OSError as exc:
        raise NanoctError(f"cannot open {path} as HDF5 ({exc}); is it a complete .h5/.nxs file?") from exc


def _read_nxtomo(path: Path, entry: str | None, window: Callable[..., tuple[slice, slice]], *, check: bool) -> RawScan:
    with _open_h5(path) as f:
        frames = read_nxtomo(path, f, entry, window)
    if check:
        units = frames.source["angle_units"]
        in_degrees = bool(np.isclose(to_unit(1.0, units.split(" ")[0], "degree", default="degree", where=units), 1.0))
        where = f"{path}:{frames.source['entry']}/sample/rotation_angle"
        check_angles(frames.angles, degrees=in_degrees, where=where, fix="correct its units attribute or pass --angles")
    return RawScan(
        frames.projections,
        frames.angles,
        flats=frames.flats,
        darks=frames.darks,
        source={"file": str(path), "format": "nxtomo", **frames.source},
    )


def _read_dxchange(path: Path, window: Callable[..., tuple[slice, slice]], *, check: bool) -> RawScan:
    with _open_h5(path) as f:
        if "exchange/theta" not in f:
            raise NanoctError(f"{path}: no /exchange/theta (angles in degrees); pass --angles FILE")
        shape = f["exchange/data"].shape
        if len(shape) != 3:
            raise NanoctError(f"{path}:exchange/data has shape {shape}; expected (views, rows, columns)")
        region = (slice(None), *window(shape[1:]))

        def frames(name: str) -> np.ndarray | None:
            if name not in f:
                return None
            if f[name].shape[1:] != shape[1:]:
                what = "flats" if name.endswith("white") else "darks"
                raise NanoctError(
                    f"{path}: {what} have shape {f[name].shape} ({name}), but one projection is {shape[1:]} "
                    f"(rows, columns); give {what} of the same detector size"
                )
            return read_h5_dataset(f, path, name, region)[0].astype(np.float32, copy=False)

        data, flats, darks = frames("exchange/data"), frames("exchange/data_white"), frames("exchange/data_dark")
        theta = read_h5_dataset(f, path, "exchange/theta")[0].astype(np.float64).ravel()
    angles = np.deg2rad(theta)
    if check:
        check_angles(angles, degrees=True, where=f"{path}:exchange/theta", fix="pass --angles FILE")
    source = {"file": str(path), "format": "dxchange", "detector_shape": list(shape[1:])}
    return RawScan(data, angles, flats=flats, darks=darks, source=source)


def _read_field(path: Path, what: str, detector: tuple[int, ...]) -> np.ndarray:
    """Flat or dark fields ``(F, R, L)`` from a TIFF or ``.npy`` file, checked against the detector ``(R, L)``.

    One frame ``(R, L)`` is accepted, and for a one-row detector (a sinogram) frames ``(F, L)`` or ``(L,)``.
    """
    field = _read_array(path, None)
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


def _read_array(path: Path, fmt: str | None, *, mmap: bool = False) -> np.ndarray:
    """A ``.npy`` file (memory-mapped with ``mmap``: read as it is sliced), a TIFF or a folder of TIFFs."""
    if not path.exists():
        raise NanoctError(f"{path} does not exist")
    fmt = fmt or ("npy" if path.suffix.lower() == ".npy" else "tiff")
    if fmt == "npy":
        try:
            return np.load(path, allow_pickle=False, mmap_mode="r" if mmap else None)
        except (OSError, ValueError, EOFError) as exc:
            raise NanoctError(f"cannot read {path} as .npy ({exc}); is the file complete?") from exc
    return _read_tiff_folder(path)[0] if path.is_dir() else _read_tiff(path)


def _read_tiff_folder(
    path: Path, window: Callable[..., tuple[slice, slice]] | None = None
) -> tuple[np.ndarray, tuple[int, ...]]:
    """The TIFFs of a folder (sorted by name, one image each) stacked, each cut to ``window`` as it is read.

    Returns the stack and the shape of one full image.
    """
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in (".tif", ".tiff"))
    if not files:
        raise NanoctError(f"{path} holds no .tif/.tiff files")
    images, first = [], None
    for file in files:
        image = _read_tiff(file)
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


def _read_tiff(path: Path) -> np.ndarray:
    """A TIFF file as an array; a truncated or damaged file is refused rather than read in part."""
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


# ---------------------------------------------------------------------------------- writers
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


def write_shifts(
    path: str | os.PathLike[str],
    shifts: Any,
    *,
    angles: Any = None,
    pixel_size_m: float | None = None,
    notes: list[str] | None = None,
    left_out: Any = (),
) -> Path:
    """Per-view shifts as nabu's ``translation_movements_file``, atomically.

    One row ``horizontal vertical`` per view, in detector pixels, loadable with
    ``np.loadtxt`` into shape ``(K, 2)`` (nabu's reader): ``horizontal = -shifts`` (the
    displacement of the projection along increasing detector columns, nabu's sign; see the
    module docstring), ``vertical = 0`` (nanoct estimates no vertical motion). Comment lines
    (``#``) say so; with ``pixel_size_m`` each row ends with a comment giving the horizontal
    value in nanometres.

    Parameters
    ----------
    path : path
        Output text file.
    shifts : array_like of shape (K,)
        nanoct's shift of the object along the detector axis per view, in detector pixels
        (sign of ``t . e_u``, as Dremel estimates it).
    angles : array_like of shape (K,), optional
        View angles in radians, written as a comment line.
    pixel_size_m : float, optional
        Size of one detector pixel at the sample, in metres.
    notes : list of str, optional
        More comment lines (e.g. why an import left views out).
    left_out : sequence of int
        Rows of projections the data set does not hold (views an import left out): the file
        still has one row per projection of the scan, as nabu expects; these rows get the
        value interpolated from their neighbours in acquisition order, marked by a comment,
        and :func:`read_shifts` skips them.

    Returns
    -------
    Path

    Raises
    ------
    NanoctError
        For NaN or infinite shifts or a pixel size that is not positive (nothing is written).
    """
    from .fileio import atomic_write_text

    values = np.asarray(shifts, dtype=np.float64).ravel()
    if not np.isfinite(values).all():
        raise NanoctError("the shifts contain NaN or infinite values; nothing was written")
    if pixel_size_m is not None and not (np.isfinite(pixel_size_m) and pixel_size_m > 0):
        raise NanoctError(f"pixel size {pixel_size_m!r} m must be a positive number; nothing was written")
    skipped = np.unique(np.asarray(left_out, dtype=int))
    rows = values.size + skipped.size
    if skipped.size and (skipped[0] < 0 or skipped[-1] >= rows):
        raise NanoctError(f"left-out rows {skipped.tolist()} do not fit {rows} projections; nothing was written")
    present = np.setdiff1d(np.arange(rows), skipped)
    horizontal = np.interp(np.arange(rows), present, -values) + 0.0  # + 0.0: no "-0.000000"
    lines = [
        f"# {SHIFTS_HEADER}: nabu translation_movements_file, one row per projection, detector pixels",
        "# horizontal = displacement of the projection towards higher detector columns (nabu's sign);",
        "# nanoct's object shift t.e_u (Dremel) is -horizontal; vertical: not estimated (0)",
    ]
    if pixel_size_m is not None:
        lines.append(f"# pixel size {pixel_size_m * 1e9:.6g} nm; the comment after each row: horizontal in nm")
    lines += [f"# {note}" for note in notes or []]
    if skipped.size:
        lines.append(f"# {LEFT_OUT}: rows {', '.join(map(str, skipped))} (interpolated; nanoct skips them)")
    if angles is not None:
        lines.append(
            "# angles_deg" + (" (rows not left out)" if skipped.size else "") + " "
            + " ".join(f"{a:.6f}" for a in np.rad2deg(np.asarray(angles).ravel()))
        )  # fmt: skip
    for k, h in enumerate(horizontal):
        comments = ([f"{h * pixel_size_m * 1e9:.3f} nm"] if pixel_size_m is not None else []) + (
            [LEFT_OUT] if k in skipped else []
        )
        lines.append(f"{h:.6f} 0.000000" + (f"  # {'; '.join(comments)}" if comments else ""))
    return atomic_write_text(Path(path), "\n".join(lines) + "\n")


def read_shifts(
    path: str | os.PathLike[str], n_views: int | None, *, binning: int = 1, left_out: Any = ()
) -> np.ndarray:
    """Read per-view shifts as nanoct's object shifts along the detector axis (pixels of a data set).

    Three layouts are read:

    * nabu's ``translation_movements_file`` (:func:`write_shifts`): rows ``horizontal
      vertical`` in raw detector pixels; returns ``-horizontal / binning``. The vertical
      column must be 0 (nanoct reconstructs slice by slice and cannot apply it).
    * nanoct's two-column ``view shift_px`` files, marked by that header: returned as
      written (they hold the data set's pixels and nanoct's sign).
    * one shift per line: nanoct's sign and the data set's pixels.

    A two-column file without a header whose first column is exactly ``0, 1, ..., K-1`` could
    be either of the first two and is refused.

    Parameters
    ----------
    path : path
        The text file.
    n_views : int or None
        Views of the data set; the file must have one row per view (None: any number, the
        file is only checked).
    binning : int
        Detector binning of the data set (nabu files are in raw detector pixels).
    left_out : sequence of int
        Projections of the scan the data set does not hold (``scan.left_out_views`` of an
        import): a nabu-layout file with one row per projection of the scan has these rows
        skipped; a file with ``n_views`` rows is read as it is.

    Returns
    -------
    ndarray of shape (n_views,), float64

    Raises
    ------
    NanoctError
        If the file is missing, not numeric, has another number of rows or columns, a
        non-zero vertical column, or the ambiguous layout above.
    """
    table = _load_table(path, "shifts")
    header = _comment_text(path)
    view_column = "view shift_px" in header
    if table.shape[1] == 1:
        shifts = table[:, 0]
    elif table.shape[1] != 2:
        raise NanoctError(
            f"the shifts file {path} has {table.shape[1]} columns; expected 'horizontal vertical' (nabu) per row"
        )
    elif view_column:
        views = table[:, 0].astype(int)
        if not np.array_equal(np.sort(views), np.arange(views.size)):
            raise NanoctError(f"the shifts file {path} must list the views 0..{views.size - 1} once each")
        shifts = np.empty(views.size)
        shifts[views] = table[:, 1]
    else:
        if SHIFTS_HEADER not in header and table.shape[0] > 2 and np.array_equal(table[:, 0], np.arange(len(table))):
            raise NanoctError(
                f"the shifts file {path} has no header and its first column is 0, 1, 2, ...: view numbers "
                f"(add the line '# view shift_px') or horizontal shifts (add '# {SHIFTS_HEADER}')?"
            )
        vertical = np.abs(table[:, 1]).max()
        if vertical > 1e-3:
            raise NanoctError(
                f"the shifts file {path} has vertical shifts up to {vertical:.3g} px; nanoct reconstructs slice by "
                "slice and cannot apply them: set the second column to 0 to use the horizontal ones"
            )
        shifts = -table[:, 0] / binning
        skipped = np.unique(np.asarray(left_out, dtype=int))
        if skipped.size and n_views is not None and shifts.size == n_views + skipped.size:
            shifts = np.delete(shifts, skipped)
    if n_views is not None and shifts.size != n_views:
        more = f" ({len(left_out)} more projections in the scan, left out by the import)" if len(left_out) else ""
        raise NanoctError(f"the shifts file {path} has {shifts.size} views, the data set {n_views}{more}")
    return shifts + 0.0


def _comment_text(path: str | os.PathLike[str]) -> str:
    """The ``#`` comments of a text file, joined (read after :func:`_load_table` succeeded)."""
    with open(path, encoding="utf-8", errors="replace") as f:
        return " ".join(line.split("#", 1)[1] for line in f if "#" in line)
