"""Measured scans in: the format of a file, and reading it.

:func:`read_scan` reads any supported file into a :class:`~nanoct.io.rawscan.RawScan`
(projections ``(K, R, L)``, flats and darks, angles in radians); :func:`line_integrals` turns
it into ``-log((p - d) / (f - d))`` and :func:`sinograms` into one ``(K, L)`` sinogram per
detector row, cropped and binned. Importing a scan into a data set (all three, the corrections,
the axis and the store) is :func:`nanoct.workflows.importscan.import_scan`.
Each format has its reader, registered in :mod:`nanoct.io.readers` (one module a format:
NXtomo, the HDF5 layouts of Diamond and Data Exchange and any layout given by dataset paths, TIFF,
``.npy``, MRC tilt series), which says how it recognises a file (:func:`detect_format`) and reads
it; HDF5 files are read through :class:`~nanoct.io.h5tree.H5Tree` (external links and virtual data
sets only below the scan's folder). :func:`read_scan` checks the options against the reader's,
reads the angles given from outside the file (text files, IMOD ``.tlt`` / ``.rawtlt``, an HDF5
dataset or ``FIRST:STOP``: :mod:`nanoct.io.angles`) and hands the rest to the reader.

Results out: :mod:`nanoct.io.imagefiles` (images) and :mod:`nanoct.io.shiftfile` (nabu's
shifts files); their names are re-exported here.

Conventions at this border (inside nanoct angles are radians and sinograms ``(K, L)``):
NXtomo ``rotation_angle`` is read in the unit of its ``units`` attribute (degrees without
one), other HDF5 angles likewise unless ``--angles-units`` says otherwise, Data Exchange
``theta`` in degrees (as TomoPy's files and CIL use it); angle files are text with one angle
per view, degrees unless stated.

What is refused or corrected (``docs/measured_data.md``): files that cannot be read whole
(a truncated HDF5, TIFF or MRC), links that leave the scan's folder, angles that are all equal
or whose span says they are in the other unit, flats or darks of another detector size, and
frames with NaN or infinite values (named; :func:`drop_bad_views` leaves such projections out,
with their angles, and says so). Views are kept in acquisition order however the angles run: every
reconstruction uses the angle of each view, and the shifts files list the views in that order,
as nabu does. A view whose angle repeats an earlier one (modulo 360 degrees, e.g. the last view
of a scan over ``[0, 360]``) is left out with a note (:func:`drop_repeated_views`): a geometry
has one view per direction.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from .angles import H5_SUFFIXES, read_angles, split_h5_spec, uniform_spec
from .imagefiles import EXPORT_FORMATS, write_images
from .rawscan import RawScan, angle_count_error, check_angles, detector_window, drop_bad_views, drop_repeated_views
from .readers import Reader, ReaderOptions, ReadRequest, detect_format, reader
from .shiftfile import LEFT_OUT, SHIFTS_HEADER, read_shifts, write_shifts

__all__ = [
    "EXPORT_FORMATS",
    "LEFT_OUT",
    "MAX_TRANSMISSION",
    "SHIFTS_HEADER",
    "RawScan",
    "ReaderOptions",
    "check_angles",
    "detect_format",
    "drop_bad_views",
    "drop_repeated_views",
    "fill_along_rows",
    "line_integrals",
    "read_angles",
    "read_scan",
    "read_shifts",
    "sinograms",
    "write_images",
    "write_shifts",
]


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
    options: ReaderOptions | None = None,
) -> RawScan:
    """Read a measured scan, or the part of its detector that ``rows`` and ``crop`` select.

    Parameters
    ----------
    path : path
        An HDF5 / NeXus file (NXtomo, a :data:`~nanoct.io.hdf5_layouts.LAYOUTS` layout, or any
        layout with ``options.data_path``), a multi-page TIFF, a folder of TIFFs (sorted by
        name, one projection each), a ``.npy`` stack ``(K, R, L)`` / sinogram ``(K, L)``, or an
        MRC tilt series.
    fmt : str, optional
        A reader's name (:data:`nanoct.io.readers.READERS`); by default :func:`detect_format` tells it
        from the path (and an HDF5 file's content).
    angles_file : path, optional
        View angles: a text file (IMOD ``.tlt`` / ``.rawtlt`` too) or ``FILE.h5:/dataset``;
        required for TIFF and ``.npy``, found next to an MRC stack; given anyway, it overrides
        the file's own.
    degrees : bool
        Unit of a text angles file (``options.angle_units`` overrides it).
    flats, darks : path, optional
        TIFF or ``.npy`` flat and dark fields for TIFF and ``.npy`` scans.
    is_line_integral : bool
        The data are already line integrals (no flat/dark correction, no ``-log``).
    entry : str, optional
        The NXtomo entry to read, needed when the file has several.
    rows : slice, optional
        Detector rows to read (default all). HDF5, ``.npy`` and MRC files read only these rows
        and the ``crop`` columns from disk, so a few slices of a large scan fit in memory.
    crop : (int, int), optional
        Detector columns ``[first, stop)`` to read.
    options : ReaderOptions, optional
        HDF5 dataset paths, angle units, MRC tilt axis, folders links may read.

    Returns
    -------
    RawScan
        Projections, flats and darks of the selected rows and columns;
        ``source["detector_shape"]`` is the full detector ``[R, L]``.

    Raises
    ------
    NanoctError
        A missing, truncated or damaged file, a missing dataset or key, a link leaving the
        allowed folders, angle count != projection count, angles that fail
        :func:`check_angles`, flats or darks of another shape, an unknown format; each
        message names the file and what to do.
    """
    opts = options or ReaderOptions()
    fmt = fmt or ("hdf5" if opts.data_path and _is_h5(path) else detect_format(path, opts.allow))
    chosen = reader(fmt)
    if entry is not None and "entry" not in chosen.takes:
        raise NanoctError(f"--entry {entry!r} is for NXtomo files; {path} is {fmt}")
    if opts.has_paths and "data_path" not in chosen.takes:
        raise NanoctError(f"--data-path, --image-key-path and --angles-path are for HDF5 files; {path} is {fmt}")
    _check_unused(path, chosen, angles_file, degrees, (flats, darks), is_line_integral, opts)
    window = detector_window(rows, crop)
    given = None if angles_file is None else _given_angles(angles_file, degrees, opts)
    scan = chosen.read(Path(path), ReadRequest(window, given, flats, darks, entry, opts))
    if given is not None:
        values = given(scan.n_views) if callable(given) else given
        if values.size != scan.n_views:
            raise angle_count_error(values.size, scan.n_views, f"--angles {angles_file}: ")
        scan = replace(scan, angles=values, source={**scan.source, "angles_from": str(angles_file)})
    if is_line_integral:
        scan = replace(scan, is_line_integral=True, flats=None, darks=None)
    return scan


def _check_unused(
    path: Any, chosen: Reader, angles_file: Any, degrees: bool, fields: tuple[Any, Any], line: bool, opts: ReaderOptions
) -> None:
    """Refuse the reading options that the file's format and the other options leave unused (each silently
    ignored otherwise): flat and dark files beside an HDF5 or MRC scan or with line integrals, ``--tilt-axis``
    of another format than MRC, ``--allow-outside`` without an HDF5 file, ``--angles-select`` and ``--radians``
    without an angles file they apply to. What the format takes is its reader's
    (:attr:`~nanoct.io.readers.base.Reader.takes`)."""
    fmt = chosen.name
    given = [flag for flag, value in zip(("--flats", "--darks"), fields) if value is not None]
    them = "them" if len(given) > 1 else "it"
    if given and not {"flats", "darks"} <= chosen.takes:
        raise NanoctError(f"{' and '.join(given)}: for TIFF and .npy scans; {path} is {fmt} (drop {them})")
    if given and line:
        raise NanoctError(f"{' and '.join(given)}: --line-integrals takes no flat/dark correction (drop {them})")
    if opts.tilt_axis != "columns" and "tilt_axis" not in chosen.takes:
        raise NanoctError(f"--tilt-axis {opts.tilt_axis}: for MRC tilt series; {path} is {fmt} (drop it)")
    h5_angles = angles_file is not None and split_h5_spec(angles_file) is not None
    if opts.allow and "allow" not in chosen.takes and not h5_angles:
        raise NanoctError(f"--allow-outside: for HDF5 files (the folders their links may read); {path} is {fmt}")
    if opts.angles_select is not None:
        first, stop = opts.angles_select
        if angles_file is None and "angles_select" not in chosen.takes:
            raise NanoctError(
                f"--angles-select {first}:{stop}: picks values of an --angles file (or of an MRC stack's tilt file); "
                f"{path} is {fmt} and no --angles is given (drop it, or give --angles FILE)"
            )
        if angles_file is not None and uniform_spec(angles_file) is not None:
            raise NanoctError(
                f"--angles-select {first}:{stop}: picks values of an --angles file; --angles {angles_file} spaces "
                "the views evenly (drop one)"
            )
    if not degrees and opts.angle_units is not None:
        raise NanoctError(f"--radians and --angles-units {opts.angle_units}: both state the unit; give one")
    if not degrees and (angles_file is None or h5_angles):
        what = "no --angles is given" if angles_file is None else f"--angles {angles_file} is an HDF5 dataset"
        raise NanoctError(
            f"--radians: the unit of an --angles text file or FIRST:STOP; {what} (drop it; --angles-units rad "
            "states the unit of the file's own angles)"
        )


def _is_h5(path: str | os.PathLike[str]) -> bool:
    return Path(path).suffix.lower() in H5_SUFFIXES


def _given_angles(angles_file: str | os.PathLike[str], degrees: bool, opts: ReaderOptions) -> Any:
    """The angles of ``--angles`` (radians), or for ``FIRST:STOP`` a function of the number of views."""
    uniform = uniform_spec(angles_file)
    if uniform is not None:
        unit = opts.angle_units or ("deg" if degrees else "rad")

        def spaced(k: int) -> np.ndarray:
            values = np.linspace(*uniform, k, endpoint=False)
            return np.deg2rad(values) if unit == "deg" else values

        return spaced
    spec = split_h5_spec(angles_file)
    allow = opts.allow
    if spec is not None:  # an HDF5 file's links may read below its own folder
        allow = (*allow, str(spec[0].resolve().parent))
    values = read_angles(angles_file, degrees=degrees, units=opts.angle_units, allow=allow, select=opts.angles_select)
    return values


#: Without flats the projections are taken as transmissions; a median above this is raw counts
#: (the neutron sinogram of the real test data reads about 47,000 in its air), whose ``-log`` is no
#: line integral: refused unless a correction normalises each view by its air (``--open-beam``).
MAX_TRANSMISSION = 2.0


def line_integrals(
    scan: RawScan,
    *,
    tolerance: float = 1e-3,
    floor: float = 1e-6,
    flat_tolerance: float | None = None,
    normalised_later: bool = False,
) -> np.ndarray:
    """Flat/dark-corrected line integrals ``-log((p - d) / (f - d))`` of a scan, ``(K, R, L)``.

    Mean flat and dark fields are used; without flats the projections are taken as already
    normalised transmissions (refused when their median exceeds :data:`MAX_TRANSMISSION`, raw
    counts, unless ``normalised_later``: an open-beam correction follows), without darks the dark
    current is 0. Detector pixels whose flat is not above the dark (at most a fraction
    ``tolerance`` of them) get line integral 0. Transmissions that are not positive (a dead or
    saturated pixel reading 0, a dark field above the signal) are filled from their neighbours in
    the same view and row (:func:`fill_along_rows`; ``floor`` only where a whole row is such) when
    they are at most a fraction ``tolerance`` of all values; more than that is taken for a wrong
    flat, dark or unit and refused. Raised to ``floor`` instead, the neutron sinogram's 214 zero
    counts (columns 314 and 346, inside the object) would read about 13.8 where their neighbours
    read about 2.5, a jump the views' centroids follow. ``flat_tolerance`` (default
    ``tolerance``) is the fraction of detector pixels whose flat may lie at or below the dark: a
    reader of a few rows at a time sets it higher, since a detector's dead pixels gather in some
    rows.

    Raises
    ------
    NanoctError
        For NaN input, a non-positive flat-minus-dark, too many non-positive transmissions, or raw
        counts without flats.
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
        level = float(np.median(transmission))
        if level > MAX_TRANSMISSION and not normalised_later:
            raise NanoctError(
                f"without flats the projections are taken as transmissions, but their median is {level:.4g}: raw "
                "counts, whose -log is no line integral; give --flats (and --darks), or --open-beam to normalise "
                "each view by its air (nanoct import, or nanoct stack with --store), or --line-integrals if the data "
                "are already -log normalised"
            )
    else:
        gain = flat - dark
        bad = ~(gain > 0)
        if bad.mean() > (tolerance if flat_tolerance is None else flat_tolerance):
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
    return fill_along_rows(-np.log(np.maximum(transmission, floor)).astype(np.float32), nonpositive)


def fill_along_rows(lines: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``lines`` (K, R, L) with the values under ``mask`` interpolated linearly between the nearest unmasked
    columns of the same view and row (the nearest one beyond the last); a line with every value masked is
    left as it is. Modifies ``lines`` in place and returns it."""
    columns = np.arange(lines.shape[2])
    for k, r in zip(*np.nonzero(mask.any(axis=2) & ~mask.all(axis=2))):
        bad = mask[k, r]
        lines[k, r, bad] = np.interp(columns[bad], columns[~bad], lines[k, r, ~bad])
    return lines


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
    row_cut, column_cut = detector_window(rows, crop)(stack.shape[1:])
    stack = stack[:, row_cut, column_cut]
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
