"""A measured scan as read from its file (:class:`RawScan`), and the checks every reader applies.

A reader returns a :class:`RawScan`: the projections as a ``(K views, R detector rows, L
detector columns)`` float32 stack, optional flat and dark fields of shape ``(F, R, L)``, and the
view angles in radians. :func:`check_angles` refuses angles that cannot be what the scan meant,
:func:`drop_bad_views` frames with NaN or infinite values, :func:`drop_repeated_views` views
whose angle repeats an earlier one, and :func:`detector_window` checks a ``--rows`` / ``--crop``
selection against the detector (:func:`check_span`: one line naming the flag, its value and the range
the scan holds). :func:`axis_after` and :func:`raw_axis` convert a rotation-axis offset between the raw
detector and the detector an import kept (cropped and binned).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..core.errors import NanoctError

__all__ = [
    "RawScan",
    "angle_count_error",
    "axis_after",
    "check_angles",
    "check_span",
    "detector_window",
    "drop_bad_views",
    "drop_repeated_views",
    "listed",
    "raw_axis",
    "store_raw_axis",
]

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
        f"{listed(repeats)}"
    )
    keep = np.sort(first)
    return replace(scan, projections=scan.projections[keep], angles=scan.angles[keep], views=scan.views[keep]), [note]


def _bad_frames(stack: np.ndarray | None) -> np.ndarray:
    """Indices of the frames of a ``(F, R, L)`` stack that hold NaN or infinite values."""
    if stack is None:
        return np.zeros(0, int)
    return np.flatnonzero(~np.isfinite(stack).all(axis=(1, 2)))


def listed(indices: np.ndarray, limit: int = 8) -> str:
    """The first ``limit`` of ``indices``, comma-separated, and how many there are in all if more."""
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
        what = f"{where}: {name} {listed(bad)}"
        if name == "projections":
            what += f" (angles {listed(np.round(np.rad2deg(scan.angles[bad]), 3))} degrees)"
        if not drop:
            raise NanoctError(
                f"{what} hold NaN or infinite values; pass --drop-bad-views to leave them out, or repair the file"
            )
        if bad.size == stack.shape[0]:
            raise NanoctError(f"{what}: every one of the {stack.shape[0]} {name} holds NaN or infinite values")
        out[name] = np.delete(stack, bad, axis=0)
        if name == "projections":
            out["angles"], out["views"] = np.delete(scan.angles, bad), np.delete(scan.views, bad)
        notes.append(f"left out {bad.size} of {stack.shape[0]} {name} with NaN or infinite values ({listed(bad)})")
    return (replace(scan, **out) if out else scan), notes


def check_span(
    flag: str, span: tuple[int, int], size: int, unit: str, *, owner: str = "the scan", sep: str = ":"
) -> None:
    """Refuse a selection ``FIRST, STOP`` of ``size`` things that is not within ``0 <= FIRST < STOP <= size``.

    Parameters
    ----------
    flag : str
        The option that gave it, e.g. ``"--rows"``.
    span : (int, int)
        ``FIRST, STOP`` (STOP excluded).
    size : int
        How many there are.
    unit : str
        What they are, e.g. ``"detector rows"``.
    owner : str
        What holds them, e.g. ``"the scan"`` or an angles file.
    sep : str
        The separator the option is written with (``":"``; ``","`` for ``--crop``).

    Raises
    ------
    NanoctError
        One line naming the flag, the value and the valid range, e.g.
        ``--rows 5000:5001: the scan has 256 detector rows (0:256)``.
    """
    first, stop = (int(v) for v in span)
    if not 0 <= first < stop <= size:
        order = "; FIRST must be below STOP" if first >= stop else ""
        raise NanoctError(f"{flag} {first}{sep}{stop}: {owner} has {size} {unit} (0{sep}{size}){order}")


def detector_window(
    rows: slice | None, crop: tuple[int, int] | None
) -> Callable[[tuple[int, ...]], tuple[slice, slice]]:
    """``window((R, L)) -> (row slice, column slice)``: ``rows`` / ``crop`` on a detector of shape ``(R, L)``, checked.

    Parameters
    ----------
    rows : slice, optional
        Detector rows ``FIRST:STOP`` (default all).
    crop : (int, int), optional
        Detector columns ``[first, stop)`` (default all).

    Returns
    -------
    callable
        Raises :class:`NanoctError` (:func:`check_span`) when the selection does not fit the detector it is
        given, before anything of it is read.
    """
    if rows is not None and rows.step not in (None, 1):
        raise NanoctError(f"--rows {rows.start}:{rows.stop}:{rows.step}: give FIRST:STOP (every row between them)")

    def window(shape: tuple[int, ...]) -> tuple[slice, slice]:
        n_rows, n_cols = shape
        if rows is not None:
            check_span("--rows", (rows.start or 0, rows.stop or 0), n_rows, "detector rows")
        if crop is not None:
            check_span("--crop", crop, n_cols, "detector columns", sep=",")
        return (rows if rows is not None else slice(None)), (slice(*crop) if crop is not None else slice(None))

    return window


def angle_count_error(n_angles: int, n_views: int, lead: str = "") -> NanoctError:
    """The refusal of ``n_angles`` angles for ``n_views`` projections; more angles than views point to
    ``--angles-select`` (an angles file that lists the flats' and darks' lines too)."""
    pick = ", or pick the projections' lines with --angles-select FIRST:STOP" if n_angles > n_views else ""
    return NanoctError(f"{lead}{n_angles} angle(s) for {n_views} projection(s); give one angle per view{pick}")


def axis_after(offset: float, n_cols: int, crop: tuple[int, int] | None, binning: int) -> float:
    """The rotation-axis offset (from the detector centre) after cropping and binning, in new pixels: an
    ``offset`` of the raw detector (``--center-offset``) as the import converts it (:func:`raw_axis` inverts it)."""
    axis = (n_cols - 1) / 2 + offset  # raw column where the axis is seen
    first, width = _kept_columns(n_cols, crop, binning)
    return ((axis - first + 0.5) / binning - 0.5) - (width - 1) / 2


def raw_axis(offset: float, n_cols: int, crop: tuple[int, int] | None, binning: int) -> float:
    """The rotation-axis offset of the raw detector (pixels from its centre, ``--center-offset``) of an
    ``offset`` on the detector after cropping and binning: the inverse of the import's conversion."""
    first, width = _kept_columns(n_cols, crop, binning)
    return (offset + (width - 1) / 2 + 0.5) * binning - 0.5 + first - (n_cols - 1) / 2


def _kept_columns(n_cols: int, crop: tuple[int, int] | None, binning: int) -> tuple[int, int]:
    """The first raw column kept and the number of binned columns after ``crop`` and ``binning``."""
    first, stop = crop if crop is not None else (0, n_cols)
    return first, (stop - first) // binning


def store_raw_axis(store: Any, offset: float) -> float:
    """:func:`raw_axis` of an ``offset`` on data set ``store``'s detector (a simulated data set: as it is)."""
    scan = store.meta.get("scan") or {}
    shape = scan.get("detector_shape")
    if not shape:
        return float(offset)
    crop = scan.get("crop")
    return raw_axis(float(offset), int(shape[1]), None if crop is None else tuple(crop), int(scan.get("binning") or 1))
