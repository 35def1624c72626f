"""Measured scans in and results out: NXtomo / Data Exchange HDF5, TIFF stacks, ``.npy``.

A reader returns a :class:`RawScan`: the projections as a ``(K views, R detector rows, L
detector columns)`` float32 stack, optional flat and dark fields of shape ``(F, R, L)``, and the
view angles in radians. :func:`line_integrals` turns it into sinograms ``-log((p - d) / (f - d))``
and :func:`sinograms` into one ``(K, L)`` sinogram per detector row (slice), optionally cropped
and binned along the detector. Files are read with h5py and tifffile; nothing here parses a
file format by hand.

Conventions at this border (inside nanoct angles are radians and sinograms ``(K, L)``):
NXtomo ``rotation_angle`` and Data Exchange ``theta`` are degrees (as NeXus, TomoPy's files
and CIL use them); angle files are text with one angle per view, degrees unless stated.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from .fileio import atomic_target

__all__ = [
    "EXPORT_FORMATS",
    "FORMATS",
    "RawScan",
    "detect_format",
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

# NXtomo: where the detector data, image keys and angles usually live (first found is used)
_NX_DATA = ("entry/instrument/detector/data", "entry/data/data", "entry1/instrument/detector/data")
_NX_KEYS = ("entry/instrument/detector/image_key", "entry/data/image_key", "entry1/instrument/detector/image_key")
_NX_ANGLES = ("entry/sample/rotation_angle", "entry/data/rotation_angle", "entry1/sample/rotation_angle")


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
    """

    projections: np.ndarray
    angles: np.ndarray
    flats: np.ndarray | None = None
    darks: np.ndarray | None = None
    is_line_integral: bool = False
    source: dict[str, Any] = field(default_factory=dict)

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
        for name in ("flats", "darks"):
            value = getattr(self, name)
            if value is None:
                continue
            arr = np.asarray(value, dtype=np.float32)
            arr = arr[None] if arr.ndim == 2 else arr
            if arr.ndim != 3 or arr.shape[1:] != proj.shape[1:]:
                raise NanoctError(
                    f"{name} have shape {arr.shape}, but one projection is {proj.shape[1:]} (rows, columns); "
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
            if _first(f, _NX_DATA) is not None:
                return "nxtomo"
        raise NanoctError(
            f"{path} is HDF5 but neither NXtomo ({_NX_DATA[0]}) nor Data Exchange (exchange/data); "
            "pass --format and the dataset layout, or convert the file"
        )
    raise NanoctError(f"cannot tell the format of {path} from its extension; pass --format ({', '.join(FORMATS)})")


def read_angles(path: str | os.PathLike[str], *, degrees: bool = True) -> np.ndarray:
    """Angles from a text file with one value per view (radians returned).

    Raises
    ------
    NanoctError
        If the file is missing or not numeric.
    """
    table = _load_table(path, "angles")
    # one angle per line, "view angle" lines, or all angles on one line
    values = table[0] if table.shape[0] == 1 else table[:, -1]
    return np.deg2rad(values) if degrees else values


def read_scan(
    path: str | os.PathLike[str],
    *,
    fmt: str | None = None,
    angles_file: str | os.PathLike[str] | None = None,
    degrees: bool = True,
    flats: str | os.PathLike[str] | None = None,
    darks: str | os.PathLike[str] | None = None,
    is_line_integral: bool = False,
) -> RawScan:
    """Read a measured scan.

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

    Returns
    -------
    RawScan

    Raises
    ------
    NanoctError
        A missing file, dataset or key, angle count != projection count, flats or darks of
        another shape, an unknown format; each message names the file and what to do.
    """
    fmt = fmt or detect_format(path)
    if fmt not in FORMATS:
        raise NanoctError(f"--format {fmt!r} is unknown; use one of {', '.join(FORMATS)}")
    if fmt == "nxtomo":
        scan = _read_nxtomo(Path(path))
    elif fmt == "dxchange":
        scan = _read_dxchange(Path(path))
    else:
        if angles_file is None:
            raise NanoctError(f"a {fmt} scan has no angles; pass --angles FILE (one angle per view)")
        stack = _read_array(Path(path), fmt)
        scan = RawScan(
            stack,
            read_angles(angles_file, degrees=degrees),
            flats=None if flats is None else _read_array(Path(flats), None),
            darks=None if darks is None else _read_array(Path(darks), None),
            source={"file": str(path), "format": fmt},
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
    if not np.isfinite(proj).all():
        raise NanoctError(f"the projections contain {int((~np.isfinite(proj)).sum())} NaN or infinite value(s)")
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
        detector. ``"auto"``: estimated from up to 8 of the selected rows, from the views'
        centroids (:func:`nanoct.recon.center.centroid_motion`, which the motion does not bias)
        when the object stays on the detector, else from opposite views
        (:func:`nanoct.recon.center.fit_center`, no motion assumed).
    size : int, optional
        Reconstructed image size N (default: the number of detector columns after cropping
        and binning; one image pixel = one binned detector pixel).
    tolerance : float
        Fraction of non-positive flat/dark-corrected values tolerated (see :func:`line_integrals`).

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

    raw = read_scan(
        src, fmt=fmt, angles_file=angles_file, degrees=degrees, flats=flats, darks=darks,
        is_line_integral=is_line_integral,
    )  # fmt: skip
    n_cols = raw.projections.shape[2]
    if center_offset == "auto":
        center_offset = _auto_center(raw, rows, crop, tolerance)
    first, stop = crop if crop is not None else (0, n_cols)
    n_det = (stop - first) // max(binning, 1)
    offset = _axis_after(center_offset, n_cols, crop, max(binning, 1))
    try:
        geometry = Geometry.from_angles(
            raw.angles, n_det if size is None else size, max(n_det, 1), center_offset=offset
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
        "flats": 0 if raw.flats is None else int(raw.flats.shape[0]),
        "darks": 0 if raw.darks is None else int(raw.darks.shape[0]),
        "shared_motion": True,
    }
    if (Path(out) / "zarr.json").is_file():
        store = DataStore.open(out)
        if store.meta.get("scan") == json.loads(json.dumps(scan)) and store.geometry == geometry:
            return store  # the same import again: nothing to do
    # select rows and columns before the correction: only the kept pixels are corrected and judged
    stack = sinograms(line_integrals(_select(raw, rows, crop), tolerance=tolerance), binning=binning)
    return create_scan(out, geometry, stack, scan)


def _auto_center(raw: RawScan, rows: slice | None, crop: tuple[int, int] | None, tolerance: float) -> float:
    """The axis offset (raw detector pixels) from up to 8 of the selected rows: centroids, else opposite views."""
    from ..recon.center import centroid_motion, fit_center

    n_rows, n_cols = raw.projections.shape[1:]
    first_row, stop_row = (rows.start or 0, rows.stop or n_rows) if rows is not None else (0, n_rows)
    picked = np.unique(np.linspace(first_row, max(stop_row - 1, first_row), 8).round().astype(int))
    sinos = np.concatenate([sinograms(line_integrals(_select(raw, slice(r, r + 1), crop), tolerance=tolerance))
                            for r in picked])  # fmt: skip
    first = crop[0] if crop is not None else 0
    offset, _, spread = centroid_motion(sinos, raw.angles)  # from the centre of the kept columns
    if spread > 0.01:  # the object leaves the detector: the centroids do not hold, use opposite views
        offset = fit_center(sinos, raw.angles, max_offset=sinos.shape[2] / 4)
    return float(first + (sinos.shape[2] - 1) / 2 + offset - (n_cols - 1) / 2)


def _select(raw: RawScan, rows: slice | None, crop: tuple[int, int] | None) -> RawScan:
    """The scan restricted to detector ``rows`` and columns ``crop`` (projections, flats, darks alike)."""
    _, n_rows, n_cols = raw.projections.shape
    if rows is not None and not (rows.step in (None, 1) and 0 <= (rows.start or 0) < (rows.stop or 0) <= n_rows):
        raise NanoctError(f"--rows {rows.start}:{rows.stop} must satisfy 0 <= FIRST < STOP <= {n_rows} rows")
    if crop is not None and not 0 <= crop[0] < crop[1] <= n_cols:
        raise NanoctError(f"--crop {crop[0]},{crop[1]} must satisfy 0 <= first < stop <= {n_cols} columns")
    r = rows if rows is not None else slice(None)
    c = slice(*crop) if crop is not None else slice(None)

    def cut(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else a[:, r, c]

    return replace(raw, projections=cut(raw.projections), flats=cut(raw.flats), darks=cut(raw.darks))


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


def _first(f: Any, candidates: tuple[str, ...]) -> str | None:
    return next((c for c in candidates if c in f), None)


def _read_nxtomo(path: Path) -> RawScan:
    with _open_h5(path) as f:
        data_path = _first(f, _NX_DATA)
        if data_path is None:
            raise NanoctError(f"{path}: no NXtomo detector data (looked for {', '.join(_NX_DATA)})")
        keys_path, angles_path = _first(f, _NX_KEYS), _first(f, _NX_ANGLES)
        if angles_path is None:
            raise NanoctError(f"{path}: no rotation angles (looked for {', '.join(_NX_ANGLES)}); pass --angles FILE")
        data = np.asarray(f[data_path][()], dtype=np.float32)
        angles = np.asarray(f[angles_path][()], dtype=np.float64).ravel()
        keys = np.zeros(data.shape[0], int) if keys_path is None else np.asarray(f[keys_path][()]).ravel()
    if keys.size != data.shape[0] or angles.size != data.shape[0]:
        raise NanoctError(
            f"{path}: {data.shape[0]} detector frames but {keys.size} image keys and {angles.size} angles; "
            "NXtomo lists one key and one angle per frame"
        )
    proj = keys == 0
    if not proj.any():
        raise NanoctError(f"{path}: no projection frames (image_key 0)")
    return RawScan(
        data[proj],
        np.deg2rad(angles[proj]),
        flats=data[keys == 1] if (keys == 1).any() else None,
        darks=data[keys == 2] if (keys == 2).any() else None,
        source={"file": str(path), "format": "nxtomo", "data": data_path, "image_key": keys_path},
    )


def _read_dxchange(path: Path) -> RawScan:
    with _open_h5(path) as f:
        if "exchange/theta" not in f:
            raise NanoctError(f"{path}: no /exchange/theta (angles in degrees); pass --angles FILE")
        data = np.asarray(f["exchange/data"][()], dtype=np.float32)
        theta = np.asarray(f["exchange/theta"][()], dtype=np.float64)
        flats = np.asarray(f["exchange/data_white"][()], np.float32) if "exchange/data_white" in f else None
        darks = np.asarray(f["exchange/data_dark"][()], np.float32) if "exchange/data_dark" in f else None
    return RawScan(data, np.deg2rad(theta), flats=flats, darks=darks, source={"file": str(path), "format": "dxchange"})


def _read_array(path: Path, fmt: str | None) -> np.ndarray:
    if not path.exists():
        raise NanoctError(f"{path} does not exist")
    fmt = fmt or ("npy" if path.suffix.lower() == ".npy" else "tiff")
    try:
        if fmt == "npy":
            return np.load(path, allow_pickle=False)
        import tifffile

        if path.is_dir():
            files = sorted(p for p in path.iterdir() if p.suffix.lower() in (".tif", ".tiff"))
            if not files:
                raise NanoctError(f"{path} holds no .tif/.tiff files")
            return np.stack([tifffile.imread(p) for p in files])
        return tifffile.imread(path)
    except (OSError, ValueError) as exc:
        raise NanoctError(f"cannot read {path} as {fmt} ({exc})") from exc


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


def write_shifts(path: str | os.PathLike[str], shifts: Any, *, angles: Any = None) -> Path:
    """Per-view shifts as a two-column text file ``view shift_px`` (nabu-style), atomically.

    Parameters
    ----------
    path : path
        Output text file.
    shifts : array_like of shape (K,)
        Shift of the object along the detector axis per view, in detector pixels (sign of
        ``t . e_u``, as Dremel estimates it).
    angles : array_like of shape (K,), optional
        View angles in radians, written as a comment line for the reader's benefit.

    Returns
    -------
    Path
    """
    from .fileio import atomic_write_text

    values = np.asarray(shifts, dtype=np.float64).ravel()
    if not np.isfinite(values).all():
        raise NanoctError("the shifts contain NaN or infinite values; nothing was written")
    lines = ["# view shift_px (object shift along the detector axis, detector pixels; nanoct)"]
    if angles is not None:
        lines.append("# angles_deg " + " ".join(f"{a:.6f}" for a in np.rad2deg(np.asarray(angles).ravel())))
    lines += [f"{k} {v:.6f}" for k, v in enumerate(values)]
    return atomic_write_text(Path(path), "\n".join(lines) + "\n")


def read_shifts(path: str | os.PathLike[str], n_views: int) -> np.ndarray:
    """Read per-view shifts: a two-column ``view shift`` text file or one shift per line.

    Raises
    ------
    NanoctError
        If the file is missing, not numeric, or has another number of views.
    """
    table = _load_table(path, "shifts")
    if table.shape[1] == 1:
        shifts = table[:, 0]
    else:
        views = table[:, 0].astype(int)
        if not np.array_equal(np.sort(views), np.arange(views.size)):
            raise NanoctError(f"the shifts file {path} must list the views 0..{views.size - 1} once each")
        shifts = np.empty(views.size)
        shifts[views] = table[:, 1]
    if shifts.size != n_views:
        raise NanoctError(f"the shifts file {path} has {shifts.size} views, the data set {n_views}")
    return shifts
