"""Measured scans in: the format of a file, and reading it.

:func:`read_scan` reads any supported file into a :class:`~nanoct.io.rawscan.RawScan`
(projections ``(K, R, L)``, flats and darks, angles in radians); :func:`line_integrals` turns
it into ``-log((p - d) / (f - d))`` and :func:`sinograms` into one ``(K, L)`` sinogram per
detector row, cropped and binned. Importing a scan into a data set (all three, the corrections,
the axis and the store) is :func:`nanoct.workflows.importscan.import_scan`.
Each format has its own reader module:

* HDF5 / NeXus (:mod:`nanoct.io.nxtomo` for NXtomo, :mod:`nanoct.io.hdf5_layouts` for
  Diamond's scan NeXus, Data Exchange and any layout given by dataset paths), read through
  :class:`~nanoct.io.h5tree.H5Tree` (external links and virtual data sets only below the
  scan's folder);
* TIFF stacks, folders of TIFFs and ``.npy`` (:mod:`nanoct.io.tiffio`);
* MRC / IMOD tilt series (:mod:`nanoct.io.mrcio`);
* angles from text files, IMOD ``.tlt`` / ``.rawtlt`` or an HDF5 dataset (:mod:`nanoct.io.angles`).

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
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from .angles import H5_SUFFIXES, read_angles, split_h5_spec, uniform_spec
from .h5tree import H5Tree
from .hdf5_layouts import LAYOUTS, custom_layout, detect_layout, read_layout
from .imagefiles import EXPORT_FORMATS, write_images
from .mrcio import MRC_SUFFIXES, count_views, find_tilt_file, read_mrc
from .nxtomo import read_nxtomo, to_unit
from .rawscan import RawScan, angle_count_error, check_angles, detector_window, drop_bad_views, drop_repeated_views
from .shiftfile import LEFT_OUT, SHIFTS_HEADER, read_shifts, write_shifts
from .tiffio import read_array, read_field, read_tiff_folder

__all__ = [
    "EXPORT_FORMATS",
    "FORMATS",
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

HDF5_FORMATS = ("nxtomo", *LAYOUTS, "hdf5")
FORMATS = (*HDF5_FORMATS, "tiff", "npy", "mrc")


@dataclass(frozen=True)
class ReaderOptions:
    """How to read a file beyond its format: HDF5 dataset paths, angle units, tilt axis, links.

    Attributes
    ----------
    data_path, image_key_path, angles_path : str, optional
        HDF5 datasets of the frames, their NXtomo image keys and the angles (``--data-path``
        ...): they override a known layout's paths, or describe a file of no known layout.
    angle_units : {"deg", "rad"}, optional
        Unit of the angles, as the user states it (overrides the file's ``units`` attribute
        and ``--radians``; the check that the span fits the unit is then skipped).
    tilt_axis : {"columns", "rows"}
        MRC tilt series: along which image direction the tilt axis runs (:mod:`nanoct.io.mrcio`).
    allow : tuple of str
        Folders outside the scan's own that external links and virtual data sets may read.
    angles_select : (int, int), optional
        Use only the values ``[FIRST, STOP)`` of the angles file (0-based), e.g. the
        projections' lines of a file that also lists the flats' and darks' angles.
    """

    data_path: str | None = None
    image_key_path: str | None = None
    angles_path: str | None = None
    angle_units: str | None = None
    tilt_axis: str = "columns"
    allow: tuple[str, ...] = ()
    angles_select: tuple[int, int] | None = None

    @property
    def has_paths(self) -> bool:
        """Whether any HDF5 dataset path was given."""
        return any((self.data_path, self.image_key_path, self.angles_path))


def detect_format(path: str | os.PathLike[str], allow: tuple[str, ...] = ()) -> str:
    """Guess a scan's format from its path (and, for HDF5, its content).

    Raises
    ------
    NanoctError
        For a missing path, an unknown extension (the message lists :data:`FORMATS`), or an
        HDF5 file of no known layout (the message says which options read it).
    """
    path = Path(path)
    if not path.exists():
        raise NanoctError(f"{path} does not exist; give the scan file or TIFF folder")
    suffix = path.suffix.lower()
    if path.is_dir() or suffix in (".tif", ".tiff"):
        return "tiff"
    if suffix == ".npy":
        return "npy"
    if suffix in MRC_SUFFIXES:
        return "mrc"
    if suffix in H5_SUFFIXES:
        with H5Tree(path, allow) as tree:
            found = detect_layout(tree)
        if found is None:
            known = ", ".join(f"{n} ({v.data})" for n, v in LAYOUTS.items())
            raise NanoctError(
                f"{path} is HDF5 but of no known layout (NXtomo; {known}); give the dataset paths with "
                "--data-path (and --image-key-path, --angles-path)"
            )
        return found
    raise NanoctError(f"cannot tell the format of {path} from its extension; pass --format ({', '.join(FORMATS)})")


def _read_hdf5(path: Path, fmt: str, entry: str | None, window: Any, opts: ReaderOptions, need_angles: bool) -> RawScan:
    """An HDF5 scan: NXtomo by :mod:`~nanoct.io.nxtomo`, any other layout by :mod:`~nanoct.io.hdf5_layouts`."""
    with H5Tree(path, opts.allow) as tree:
        if fmt == "nxtomo" and not opts.has_paths:
            frames = read_nxtomo(tree, entry, window)
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
        layout = custom_layout(LAYOUTS.get(fmt), opts.data_path, opts.image_key_path, opts.angles_path, None)
        return read_layout(tree, layout, window, units=opts.angle_units, need_angles=need_angles)


def _restated(frames: Any, units: str) -> np.ndarray:
    """NXtomo angles re-read in the unit the user states (the file's ``units`` attribute ignored)."""
    stored = frames.source["angle_units"].split(" ")[0]
    raw = to_unit(frames.angles, "radian", stored, default="degree", where=str(stored))
    return np.deg2rad(raw) if units == "deg" else raw


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
        One of :data:`FORMATS`; guessed from the path (and an HDF5 file's content) by default.
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
    if fmt not in FORMATS:
        raise NanoctError(f"--format {fmt!r} is unknown; use one of {', '.join(FORMATS)}")
    if entry is not None and fmt != "nxtomo":
        raise NanoctError(f"--entry {entry!r} is for NXtomo files; {path} is {fmt}")
    if opts.has_paths and fmt not in HDF5_FORMATS:
        raise NanoctError(f"--data-path, --image-key-path and --angles-path are for HDF5 files; {path} is {fmt}")
    _check_unused(path, fmt, angles_file, degrees, (flats, darks), is_line_integral, opts)
    window = detector_window(rows, crop)
    given = None if angles_file is None else _given_angles(angles_file, degrees, opts)
    if fmt in HDF5_FORMATS:
        scan = _read_hdf5(Path(path), fmt, entry, window, opts, need_angles=given is None)
    elif fmt == "mrc":
        scan = _read_mrc(Path(path), window, given, opts)
    else:
        scan = _read_stack(Path(path), fmt, window, given, flats, darks)
    if given is not None:
        values = given(scan.n_views) if callable(given) else given
        if values.size != scan.n_views:
            raise angle_count_error(values.size, scan.n_views, f"--angles {angles_file}: ")
        scan = replace(scan, angles=values, source={**scan.source, "angles_from": str(angles_file)})
    if is_line_integral:
        scan = replace(scan, is_line_integral=True, flats=None, darks=None)
    return scan


def _check_unused(
    path: Any, fmt: str, angles_file: Any, degrees: bool, fields: tuple[Any, Any], line: bool, opts: ReaderOptions
) -> None:
    """Refuse the reading options that the file's format and the other options leave unused (each silently
    ignored otherwise): flat and dark files beside an HDF5 or MRC scan or with line integrals, ``--tilt-axis``
    of another format than MRC, ``--allow-outside`` without an HDF5 file, ``--angles-select`` and ``--radians``
    without an angles file they apply to."""
    given = [flag for flag, value in zip(("--flats", "--darks"), fields) if value is not None]
    them = "them" if len(given) > 1 else "it"
    if given and fmt not in ("tiff", "npy"):
        raise NanoctError(f"{' and '.join(given)}: for TIFF and .npy scans; {path} is {fmt} (drop {them})")
    if given and line:
        raise NanoctError(f"{' and '.join(given)}: --line-integrals takes no flat/dark correction (drop {them})")
    if opts.tilt_axis != "columns" and fmt != "mrc":
        raise NanoctError(f"--tilt-axis {opts.tilt_axis}: for MRC tilt series; {path} is {fmt} (drop it)")
    h5_angles = angles_file is not None and split_h5_spec(angles_file) is not None
    if opts.allow and fmt not in HDF5_FORMATS and not h5_angles:
        raise NanoctError(f"--allow-outside: for HDF5 files (the folders their links may read); {path} is {fmt}")
    if opts.angles_select is not None:
        first, stop = opts.angles_select
        if angles_file is None and fmt != "mrc":
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


def _read_mrc(path: Path, window: Any, given: np.ndarray | None, opts: ReaderOptions) -> RawScan:
    source = {}
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
    scan = read_mrc(path, window, given, tilt_axis=opts.tilt_axis)
    return replace(scan, source={**scan.source, **source})


def _read_stack(path: Path, fmt: str, window: Any, given: np.ndarray | None, flats: Any, darks: Any) -> RawScan:
    """A TIFF stack or folder, or a ``.npy`` array, with separate flat and dark files."""
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
