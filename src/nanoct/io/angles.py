"""View angles from outside the scan file: text files (IMOD ``.tlt`` / ``.rawtlt``) or an HDF5 dataset.

``FIRST:STOP`` (two numbers) spaces the views evenly from FIRST on, STOP excluded
(``numpy.linspace(FIRST, STOP, K, endpoint=False)``). A text file lists one angle per view
(one per line, ``view angle`` lines, or all on one line; ``#`` starts a comment); IMOD's
``.rawtlt`` and ``.tlt`` files are such files, in degrees. An HDF5 dataset is named
``FILE.h5:/path/to/dataset``; its unit is the ``--angles-units`` given, else its ``units``
attribute, else degrees. Returned angles are radians and pass
:func:`nanoct.io.rawscan.check_angles` (unless the user stated the unit).
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..core.errors import NanoctError
from .rawscan import check_angles, check_span

__all__ = ["ANGLE_UNITS", "H5_SUFFIXES", "in_radians", "load_table", "read_angles", "split_h5_spec", "uniform_spec"]

ANGLE_UNITS = ("deg", "rad")
H5_SUFFIXES = (".h5", ".hdf5", ".hdf", ".nx", ".nxs")
_UNIFORM = re.compile(r"^\s*([-+]?\d+(?:\.\d*)?)\s*:\s*([-+]?\d+(?:\.\d*)?)\s*$")
_H5_SPEC = re.compile(r"^(.*?(?:" + "|".join(re.escape(s) for s in H5_SUFFIXES) + r")):(/?[^:]+)$", re.IGNORECASE)


def load_table(path: str | os.PathLike[str], what: str) -> np.ndarray:
    """A text table of numbers (``#`` comments), one row per line, as a 2-D float64 array.

    Raises
    ------
    NanoctError
        A missing or unreadable file, or text that is not numbers.
    """
    try:
        return np.loadtxt(path, dtype=np.float64, ndmin=2, comments="#")
    except OSError as exc:
        raise NanoctError(f"cannot read the {what} file {path}: {exc}") from exc
    except ValueError as exc:
        raise NanoctError(f"the {what} file {path} is not a table of numbers ({exc})") from exc


def split_h5_spec(spec: str | os.PathLike[str]) -> tuple[Path, str] | None:
    """``FILE.h5:/dataset`` as ``(FILE.h5, /dataset)``; None for a plain path."""
    match = _H5_SPEC.match(str(spec))
    return None if match is None else (Path(match.group(1)), "/" + match.group(2).lstrip("/"))


def uniform_spec(spec: str | os.PathLike[str]) -> tuple[float, float] | None:
    """``FIRST:STOP`` (two numbers, no such file) as ``(FIRST, STOP)``: views evenly spaced, STOP excluded."""
    match = _UNIFORM.match(str(spec))
    if match is None or Path(spec).exists():
        return None
    first, stop = float(match.group(1)), float(match.group(2))
    if first == stop:
        raise NanoctError(f"--angles {spec}: FIRST and STOP are equal; give the range the views span, e.g. 0:180")
    return first, stop


def in_radians(values: np.ndarray, units: str, where: str) -> np.ndarray:
    """``values`` in ``units`` (``deg``/``rad`` or any angle unit pint knows) as radians."""
    from .nxtomo import to_unit

    unit = {"deg": "degree", "rad": "radian"}.get(units, units)
    return to_unit(values, unit, "radian", default="degree", where=where)


def read_angles(
    path: str | os.PathLike[str],
    *,
    degrees: bool = True,
    units: str | None = None,
    allow: Sequence[str | os.PathLike[str]] = (),
    select: tuple[int, int] | None = None,
) -> np.ndarray:
    """Angles (radians) from a text file with one value per view, or an HDF5 dataset ``FILE.h5:/path``.

    Parameters
    ----------
    path : path or str
        Text file (``.txt``, IMOD ``.tlt`` / ``.rawtlt``) or ``FILE.h5:/dataset``.
    degrees : bool
        Unit of a text file when ``units`` is not given.
    units : {"deg", "rad"}, optional
        The unit, stated by the user (overrides ``degrees`` and an HDF5 ``units`` attribute;
        the span check of :func:`~nanoct.io.rawscan.check_angles` is then skipped).
    allow : sequence of path
        Folders an HDF5 file's links may point into besides its own (:class:`~nanoct.io.h5tree.H5Tree`).
    select : (int, int), optional
        Keep only the values ``[FIRST, STOP)`` (0-based), e.g. the projections of a file that
        lists the flats' and darks' angles too.

    Raises
    ------
    NanoctError
        If the file or dataset is missing or not numeric, or the angles fail the check.
    """
    if units is not None and units not in ANGLE_UNITS:
        raise NanoctError(f"--angles-units {units!r}: use deg or rad")
    spec = split_h5_spec(path)
    if spec is not None:
        from .h5tree import H5Tree

        file, name = spec
        if not file.is_file():
            raise NanoctError(f"--angles {path}: {file} does not exist")
        with H5Tree(file, allow) as tree:
            values, stored = tree.read(name)
        values = np.asarray(values, dtype=np.float64).ravel()
        unit = units or stored or "degree"
        angles = in_radians(values, unit, f"{file}:{name}")
        degrees = bool(np.isclose(in_radians(np.array(1.0), unit, f"{file}:{name}"), np.pi / 180))
    else:
        table = load_table(path, "angles")
        # one angle per line, "view angle" lines, or all angles on one line
        values = table[0] if table.shape[0] == 1 else table[:, -1]
        degrees = degrees if units is None else units == "deg"
        angles = np.deg2rad(values) if degrees else values
    if select is not None:
        check_span("--angles-select", select, angles.size, "values", owner=f"the angles file {path}")
        angles = angles[select[0] : select[1]]
    if units is None:
        check_angles(angles, degrees=degrees, where=f"the angles {path}", fix="--angles-units rad")
    elif not np.isfinite(angles).all():
        raise NanoctError(f"the angles {path}: {int((~np.isfinite(angles)).sum())} value(s) are NaN or infinite")
    return np.asarray(angles, dtype=np.float64)
