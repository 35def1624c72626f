"""Shifts files: per-view shifts as nabu's ``translation_movements_file``, written and read.

One row ``horizontal vertical`` per projection, in detector pixels, ``horizontal`` the
displacement of the projection along increasing detector columns (nabu adds it to the axis
position in its back projection). nanoct's own shifts (Dremel's ``t . e_u``,
:mod:`nanoct.recon.dremel`) move the projection the other way, so ``horizontal = -shift``.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from .angles import load_table

__all__ = [
    "AXIS_COMMENT",
    "LEFT_OUT",
    "SHIFTS_HEADER",
    "read_shifts",
    "shifts_axis",
    "write_shifts",
    "write_stack_shifts",
]

SHIFTS_HEADER = "horizontal vertical"  # nabu's column order, the header line of a shifts file
LEFT_OUT = "left out by the import"  # marks the rows of a shifts file for views a data set does not hold
#: The comment that records the rotation axis the shifts go with (raw detector pixels from the centre):
#: reconstructing view k about axis a with shift e_k is reconstructing it about a - e_k, so the shifts of
#: one axis fit another only after adding the difference (:func:`nanoct.recon.shared.read_store_shifts`).
AXIS_COMMENT = "axis"
_AXIS_LINE = re.compile(rf"^#\s*{AXIS_COMMENT}\s+([-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?)\s+raw detector pixels", re.M)


def write_shifts(
    path: str | os.PathLike[str],
    shifts: Any,
    *,
    angles: Any = None,
    pixel_size_m: float | None = None,
    notes: list[str] | None = None,
    left_out: Any = (),
    vertical: Any = None,
    axis: float | None = None,
) -> Path:
    """Per-view shifts as nabu's ``translation_movements_file``, atomically.

    One row ``horizontal vertical`` per view, in detector pixels, loadable with
    ``np.loadtxt`` into shape ``(K, 2)`` (nabu's reader): ``horizontal = -shifts`` (the
    displacement of the projection along increasing detector columns, nabu's sign; see the
    module docstring), ``vertical = -v`` (the displacement along increasing detector rows of a
    view measured as ``m_k(z, x) = Q_k(z + v_k, x + d_k)``; 0 where not estimated). Comment lines
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
    vertical : array_like of shape (K,), optional
        nanoct's vertical shift ``v_k`` per view (detector rows; :mod:`nanoct.motion.vertical`).
    left_out : sequence of int
        Rows of projections the data set does not hold (views an import left out): the file
        still has one row per projection of the scan, as nabu expects; these rows get the
        value interpolated from their neighbours in acquisition order, marked by a comment,
        and :func:`read_shifts` skips them.
    axis : float, optional
        The rotation axis the shifts go with, in raw detector pixels from the raw detector's
        centre (``--center-offset``), written as a comment (:data:`AXIS_COMMENT`).

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
    up = np.zeros(values.size) if vertical is None else np.asarray(vertical, dtype=np.float64).ravel()
    if up.shape != values.shape or not np.isfinite(up).all():
        raise NanoctError(f"{up.size} vertical shifts for {values.size} views, or not finite; nothing was written")
    down = np.interp(np.arange(rows), present, -up) + 0.0
    lines = [
        f"# {SHIFTS_HEADER}: nabu translation_movements_file, one row per projection, detector pixels",
        "# horizontal = displacement of the projection towards higher detector columns (nabu's sign);",
        "# nanoct's object shift t.e_u (Dremel) is -horizontal; vertical likewise towards higher rows"
        + ("" if vertical is not None else " (not estimated: 0)"),
    ]
    if axis is not None:
        lines.append(
            f"# {AXIS_COMMENT} {axis:+.6f} raw detector pixels from the detector centre (--center-offset): "
            "the shifts go with this rotation axis"
        )
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
    for k, (h, v) in enumerate(zip(horizontal, down)):
        comments = ([f"{h * pixel_size_m * 1e9:.3f} nm"] if pixel_size_m is not None else []) + (
            [LEFT_OUT] if k in skipped else []
        )
        lines.append(f"{h:.6f} {v:.6f}" + (f"  # {'; '.join(comments)}" if comments else ""))
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
    table = load_table(path, "shifts")
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


def shifts_axis(path: str | os.PathLike[str]) -> float | None:
    """The rotation axis a shifts file records (:data:`AXIS_COMMENT`, raw detector pixels), or None."""
    with open(path, encoding="utf-8", errors="replace") as f:
        found = _AXIS_LINE.search(f.read())
    return None if found is None else float(found.group(1))


def _comment_text(path: str | os.PathLike[str]) -> str:
    """The ``#`` comments of a text file, joined (read after :func:`_load_table` succeeded)."""
    with open(path, encoding="utf-8", errors="replace") as f:
        return " ".join(line.split("#", 1)[1] for line in f if "#" in line)


def write_stack_shifts(store: Any, name: str, out: str | os.PathLike[str]) -> Path | None:
    """The motion of a stack result (``nanoct stack``) as nabu's shifts file; None for another result.

    A stack result keeps one motion for all slices, ``d_k`` in the data set's detector pixels
    with the sign of Dremel's shifts (view ``k`` is read at ``u - d_k``,
    :func:`nanoct.recon.stack.corrected_fbp`): the rows are ``horizontal = -d_k`` times the
    import's binning (raw detector pixels), and ``vertical = -v_k`` (the stack's vertical motion,
    0 where it was not estimated), one per projection of the scan file (views the import left out
    interpolated, as :func:`write_shifts` does).

    Parameters
    ----------
    store : DataStore
    name : str
        The reconstruction.
    out : path
        The text file.

    Returns
    -------
    Path or None
        The file written, or None when ``name`` holds no shared motion (not a stack result).
    """
    from .rawscan import store_raw_axis

    present = name in store.reconstruction_names()
    shifts = store.recons.shared_shifts(name) if present else None
    info = store.recons.motion_info(name) if present else None
    if shifts is None or info is None:
        return None
    scan = store.meta.get("scan") or {}
    pixel = scan.get("raw_pixel_size_m")
    binning = int(scan.get("binning") or 1)
    kept = scan.get("rows") or [0, (scan.get("detector_shape") or [store.n])[0]]
    rows_binned = binning if kept[1] - kept[0] >= binning else 1  # the import bins rows where there are enough
    vertical = info.get("vertical")
    return write_shifts(
        out,
        np.asarray(shifts, dtype=np.float64) * binning,
        axis=store_raw_axis(store, info.get("center_offset", store.geometry.center_offset)),
        vertical=None if vertical is None else np.asarray(vertical, dtype=np.float64) * rows_binned,
        angles=store.geometry.angles,
        pixel_size_m=None if pixel is None else float(pixel[0]),
        notes=[f"motion of the stack result {name} (nanoct stack)"]
        + [note for note in scan.get("notes", []) if note.startswith("left out")],
        left_out=list(scan.get("left_out_views") or []),
    )
