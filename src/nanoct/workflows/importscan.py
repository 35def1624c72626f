"""Importing a measured scan into a data set (``nanoct import``): read, correct, find the axis, store.

:func:`import_scan` reads the file (:func:`nanoct.io.scanio.read_scan`), takes line integrals and
applies the corrections (:mod:`nanoct.preprocess`), estimates the rotation axis where asked
(:func:`nanoct.motion.axis.estimate_axis`), and writes the sinograms with their geometry and the
import's record (:func:`nanoct.io.store.create_scan`); the same import again resumes it, another one
into the same folder is refused naming what differs. Reading and writing are :mod:`nanoct.io`'s; this
module only joins them.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from ..io.rawscan import RawScan, axis_after, check_span, drop_bad_views, drop_repeated_views
from ..io.scanio import ReaderOptions, line_integrals, read_scan, sinograms

__all__ = ["MAX_SIZE_RATIO", "import_scan"]

#: The largest ``--size`` accepted, in detector columns (an image wider than the field of view, for an
#: object that leaves it, needs some margin; four times the detector is mostly outside every view).
MAX_SIZE_RATIO = 4


def _check_axis_and_size(raw_offset: float, offset: float, n_det: int, size: int | None) -> None:
    """NanoctError for a rotation axis (``offset`` from the centre of the ``n_det`` columns kept; ``raw_offset`` as
    given) outside the detector, or an image ``size`` of more than ``MAX_SIZE_RATIO`` times the columns."""
    if n_det > 0 and abs(offset) >= n_det / 2:
        raise NanoctError(
            f"--center-offset {raw_offset:g}: the rotation axis would lie at column {(n_det - 1) / 2 + offset:.1f} "
            f"of the {n_det} detector columns kept (after --crop and --binning), outside the detector; give its "
            "offset from the centre of the raw detector in raw pixels, or 'auto'"
        )
    if size is not None and n_det > 0 and size > MAX_SIZE_RATIO * n_det:
        raise NanoctError(
            f"--size {size} is more than {MAX_SIZE_RATIO} times the {n_det} detector columns kept: the image would "
            f"be mostly outside every view; leave --size out (N = {n_det}) or give at most {MAX_SIZE_RATIO * n_det}"
        )


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
    options: ReaderOptions | None = None,
    corrections: Any = None,
) -> Any:
    """Import a measured parallel-beam scan into a new data set, one sample per detector row.

    Reads the file (:func:`~nanoct.io.scanio.read_scan`), corrects flats and darks and takes ``-log``
    (:func:`~nanoct.io.scanio.line_integrals`), selects rows and crops and bins the detector
    (:func:`~nanoct.io.scanio.sinograms`), and stores the sinograms with a
    :class:`~nanoct.core.geometry.Geometry` built from the file's angles and the rotation-axis offset
    (:func:`nanoct.io.store.create_scan`). All slices share one motion (a stack is scanned at once),
    which Dremel then estimates jointly.

    Parameters
    ----------
    src, out : path
        Scan file (or TIFF folder) and the new data set's directory.
    fmt, angles_file, degrees, flats, darks, is_line_integral
        See :func:`~nanoct.io.scanio.read_scan`.
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
        Fraction of non-positive flat/dark-corrected values tolerated (see :func:`~nanoct.io.scanio.line_integrals`).
    entry : str, optional
        NXtomo entry (see :func:`~nanoct.io.scanio.read_scan`).
    drop_bad : bool
        Leave out projections (and flat or dark frames) with NaN or infinite values in the
        selected rows and columns instead of refusing the scan (:func:`~nanoct.io.rawscan.drop_bad_views`).
    options : ReaderOptions, optional
        HDF5 dataset paths, angle units, MRC tilt axis, folders links may read (recorded with
        the import as ``scan["reader"]`` when any differs from the default).
    corrections : Corrections, optional
        Corrections of the projections (:class:`nanoct.preprocess.Corrections`: outliers, open
        beam, Paganin, stripes), applied to the selected rows and columns before binning and
        before the axis is estimated; recorded as ``scan["corrections"]``.

    Returns
    -------
    DataStore
        The new data set. Re-running the same import on it writes only the slices that an
        interrupted import left unwritten or that are damaged (:meth:`~nanoct.io.store.DataStore.complete_scan`).

    Raises
    ------
    NanoctError
        Any problem with the file, the options or the output directory; nothing is written.
    """
    from ..core.geometry import Geometry

    # only the selected rows and columns are read, checked and corrected
    raw = read_scan(
        src, fmt=fmt, angles_file=angles_file, degrees=degrees, flats=flats, darks=darks,
        is_line_integral=is_line_integral, entry=entry, rows=rows, crop=crop, options=options,
    )  # fmt: skip
    n_rows, n_cols = raw.source["detector_shape"]
    kept_cols = (crop[1] - crop[0]) if crop is not None else n_cols
    for span in getattr(corrections, "air_columns", None) or ():  # counted in the columns read
        owner = "the detector read (from --crop's first column)" if crop is not None else "the detector"
        check_span("--air-columns", span, kept_cols, "columns", owner=owner)
    if not 1 <= binning <= kept_cols:
        raise NanoctError(f"--binning {binning} must be between 1 and the {kept_cols} detector columns kept")
    kept, dropped = drop_bad_views(raw, drop=drop_bad)
    kept, repeated = drop_repeated_views(kept)
    left_out = np.setdiff1d(np.arange(raw.n_views), kept.views)
    lines, notes = _corrected(kept, tolerance, corrections)
    axis_record = None
    if center_offset == "auto":
        shift, estimate = _auto_center(lines, kept.angles, n_cols, crop)
        center_offset = float(shift + estimate.offset)
        axis_record = {**estimate.to_dict(), "offset_raw": center_offset}
    first, stop = crop if crop is not None else (0, n_cols)
    n_det = (stop - first) // binning
    offset = axis_after(center_offset, n_cols, crop, binning)
    _check_axis_and_size(center_offset, offset, n_det, size)
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
        "notes": [*raw.source.get("notes", []), *dropped, *repeated, *_angle_notes(kept.angles)]
        + [*_binning_notes(lines.shape[1], lines.shape[2], binning), *notes],
    }
    if corrections is not None:
        scan["corrections"] = corrections.to_dict()
    if axis_record is not None:
        scan["axis"] = axis_record
    if options is not None and options != ReaderOptions():
        scan["reader"] = {k: v for k, v in asdict(options).items() if v != getattr(ReaderOptions(), k)}
    if left_out.size:  # shifts files keep one row per projection of the file (nabu's layout)
        scan.update(file_views=raw.n_views, left_out_views=left_out.tolist())
    if "raw_pixel_size_m" in raw.source:  # one stored detector pixel, after binning
        n_kept_rows = (rows.stop - rows.start) if rows is not None else n_rows
        x, y = raw.source["raw_pixel_size_m"]
        scan["pixel_size_m"] = [x * binning, y * (binning if n_kept_rows >= binning else 1)]
    return _store_scan(out, geometry, sinograms(lines, binning=binning), scan)


def _store_scan(out: str | os.PathLike[str], geometry: Any, stack: np.ndarray, scan: dict[str, Any]) -> Any:
    """A new data set of the sinograms; the same import again writes only the slices an interrupted import
    left or that were lost or damaged (:meth:`~nanoct.io.store.DataStore.complete_scan`)."""
    from ..io.store import DataStore, create_scan

    if (Path(out) / "zarr.json").is_file():
        store = DataStore.open(out, mode="r+")
        recorded = store.meta.get("scan")
        if recorded is not None:  # an import: the same one again (from any path to the file) resumes it
            differs = _import_difference(recorded, json.loads(json.dumps(scan)), store.geometry == geometry)
            if differs:
                raise NanoctError(
                    f"{out} holds an import of {recorded.get('file')} with {differs}; import into a new --out "
                    "(or delete it first), or rerun the import with its options"
                )
            store.complete_scan(stack)
            return store
    return create_scan(out, geometry, stack, scan)


#: The ``nanoct import`` options recorded in a scan's record, with their flags, in the order a refusal names them:
#: what the user gave before what follows from it (the estimated axis, the pixel size after binning, ...);
#: ``--center-offset`` last (given as ``auto`` twice, it follows from the rest: compared with the derived values).
_GIVEN = {
    "rows": "--rows",
    "crop": "--crop",
    "binning": "--binning",
    "line_integrals": "--line-integrals",
    "flats": "--flats",
    "darks": "--darks",
    "corrections": None,
    "reader": None,
    "center_offset_raw": "--center-offset",
}
#: Fields of ``reader`` whose flag is not the field's name with dashes.
_READER_FLAGS = {"angle_units": "--angles-units", "allow": "--allow-outside"}
#: Correction fields filled in from another (``--stripes`` records its method's default parameters): not named
#: where that other differs too.
_FOLLOWS = {"stripe_params": "stripes"}


def _nested_defaults(key: str) -> dict[str, Any]:
    """What an import records as ``key`` (``corrections`` or ``reader``) when every field has its default."""
    from ..preprocess import Corrections

    defaults = Corrections().to_dict() if key == "corrections" else asdict(ReaderOptions())
    return json.loads(json.dumps(defaults))


def _given_difference(recorded: dict[str, Any], scan: dict[str, Any]) -> str | None:
    """The options of :data:`_GIVEN` that differ, each with its flag (a correction or reader field by name)."""
    both_estimated = "axis" in recorded and "axis" in scan  # --center-offset auto twice: the axis follows
    named: list[str] = []
    for key, flag in _GIVEN.items():
        old, new = recorded.get(key), scan.get(key)
        if key == "center_offset_raw" and both_estimated:
            continue
        if flag is not None:
            if old != new:
                named.append(f"{key} {old!r} (this import: {new!r}), set by {flag}")
            continue
        defaults = _nested_defaults(key)
        old, new = {**defaults, **(old or {})}, {**defaults, **(new or {})}
        differ = {f for f in old.keys() | new.keys() if old.get(f) != new.get(f)}
        for field in sorted(f for f in differ if _FOLLOWS.get(f) not in differ):
            field_flag = _READER_FLAGS.get(field, "--" + field.replace("_", "-"))
            named.append(f"{key}.{field} {old.get(field)!r} (this import: {new.get(field)!r}), set by {field_flag}")
    return " and ".join(named) or None


def _import_difference(recorded: dict[str, Any], scan: dict[str, Any], same_geometry: bool) -> str | None:
    """What differs between a kept import's record and this import's, other than the paths of the files; None: nothing.

    The options the user gives (:data:`_GIVEN`: rows, binning, corrections, ...) are named first, all that
    differ, each with its flag; only where none differs, the first value that follows from them (e.g. the
    axis that ``--center-offset auto`` estimated), so that a refusal names the option that was changed. The
    angles are compared in the geometry, and the file itself slice by slice
    (:meth:`~nanoct.io.store.DataStore.complete_scan`).
    """
    given = _given_difference(recorded, scan)
    if given is not None:
        return given
    for key in sorted((recorded.keys() | scan.keys()) - {"file", "angles_from", "notes", "corrections", "reader"}):
        if recorded.get(key) != scan.get(key):
            return f"{key} {recorded.get(key)!r} (this import: {scan.get(key)!r})"
    if recorded.get("notes") != scan.get("notes") or not same_geometry:
        return "other data (its notes or geometry differ: another file, or the file changed since)"
    return None


def _corrected(scan: RawScan, tolerance: float, corrections: Any) -> tuple[np.ndarray, list[str]]:
    """Line integrals of the scan, with ``corrections`` applied (and what they noted)."""
    lines = line_integrals(scan, tolerance=tolerance, normalised_later=bool(getattr(corrections, "open_beam", False)))
    if corrections is None:
        return lines, []
    from ..preprocess import apply_corrections

    result = apply_corrections(lines, corrections, kind="line_integrals")
    return result.line_integrals, list(result.notes)


def _auto_center(lines: np.ndarray, angles: np.ndarray, n_cols: int, crop: tuple[int, int] | None) -> Any:
    """The axis from 8 of the read rows (:func:`nanoct.motion.axis.estimate_axis`) and the raw shift of its origin."""
    from ..motion.axis import axis_rows, estimate_axis

    estimate = estimate_axis(sinograms(lines[:, axis_rows(lines.shape[1])]), angles)
    first = crop[0] if crop is not None else 0
    return first + (lines.shape[2] - 1) / 2 - (n_cols - 1) / 2, estimate


def _binning_notes(n_rows: int, n_cols: int, binning: int) -> list[str]:
    """What ``binning`` leaves out of ``n_rows`` x ``n_cols`` selected pixels (the remainder, last rows and columns)."""
    notes = []
    if n_cols % binning:
        notes.append(
            f"--binning {binning} keeps {n_cols // binning * binning} of the {n_cols} detector columns selected "
            f"(the last {n_cols % binning} are left out; --crop chooses which)"
        )
    if binning > 1 and n_rows >= binning and n_rows % binning:
        notes.append(
            f"--binning {binning} keeps {n_rows // binning * binning} of the {n_rows} rows selected "
            f"(the last {n_rows % binning} are left out; --rows chooses which)"
        )
    return notes


def _angle_notes(angles: np.ndarray) -> list[str]:
    """What an import tells about angles it keeps as they are (acquisition order)."""
    steps = np.diff(angles)
    if steps.size and not ((steps >= 0).all() or (steps <= 0).all()):
        return ["the angles are not monotone; the views are kept in acquisition order, each with its angle"]
    return []
