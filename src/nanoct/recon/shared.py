"""One motion for a whole stack: joint shift estimation, shifts files, and their batch parameters.

The slices of a measured 3-D scan (an imported store with ``meta["scan"]["shared_motion"]``)
were all recorded at once, so they share one per-view object shift. Dremel run on each slice
alone estimates it once per slice, each estimate up to a translation common to all views,
``a cos(phi_k) + b sin(phi_k)``, that the slice's image absorbs (see :func:`~nanoct.recon.dremel.dremel`).
:func:`joint_shifts` runs Dremel on the chosen slices, removes that term from each estimate
(:func:`~nanoct.core.geometry.remove_translation`) and takes the per-view median, which is robust to a slice with
little structure whose estimate is noise. Every slice of a simulation is then reconstructed
with these shifts held fixed (``fix_shifts=True``), so all slices of the stack are corrected
alike; on measured data (:func:`~nanoct.recon.eta_source.carries_motion`) each slice starts from
them and refines them, as ``nanoct stack --method dremel`` does with the stack's motion (on the
semi-real benchmark of ``docs/reconstruction.md`` the refinement gained 0.68 dB on average over
holding the joint motion, 0.51 dB with the object wider than the field of view). The joint
motion is kept with the reconstruction (``shared_shifts``), each slice's row holds its own.

The batch parameters of the methods that estimate motion (the CLI's ``--param``), checked with
the method's own parameters before anything is written (:func:`check_motion_params`):

``motion_slices``
    ``"all"`` or comma-separated slice (sample) indices ``"0,5,9"``: estimate one shared motion
    from these slices. Default on an imported stack with shared motion: ``"all"``; on a
    simulated store: each sample its own motion.
``shifts_from``
    A shifts file (nabu's ``translation_movements_file`` layout, or the two-column ``view
    shift_px`` files, :func:`nanoct.io.shiftfile.read_shifts`): the starting motion of every
    estimate, or with ``fix_shifts=true`` (a parameter of Dremel itself) the motion used as
    given; e.g. a beamline's estimate from nabu.

Shifts files are in detector pixels (nabu's: raw detector pixels, before the import's
binning); Dremel's shifts are in image pixels along the detector axis; the two differ by
``magnification / det_spacing`` (1 for the parallel presets).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from ..core.geometry import Geometry, remove_translation
from ..io.rawscan import store_raw_axis
from ..io.shiftfile import read_shifts, shifts_axis, write_shifts
from ..io.store import DataStore
from .dremel import dremel
from .params import MethodParams
from .registry import methods_with_motion

__all__ = [
    "SharedMotionParams",
    "joint_shifts",
    "parse_slices",
    "read_shifts_file",
    "read_store_shifts",
    "scan_layout",
    "write_store_shifts",
]


def _det_per_obj(geometry: Geometry) -> float:
    return geometry.magnification / geometry.det_spacing


def parse_slices(value: Any) -> str | None:
    """Normalise ``motion_slices``: None, ``"all"`` or sorted unique indices as ``"0,5,9"``.

    Raises
    ------
    ValueError
        For anything else (``motion_slices=...`` named, as parameter checks do).
    """
    if value is None or value == "all":
        return value
    items = value if isinstance(value, (list, tuple)) else str(value).split(",")
    try:
        indices = sorted({int(str(v).strip()) for v in items})
    except ValueError:
        indices = []
    if not indices or indices[0] < 0:
        raise ValueError(f"motion_slices={value!r}: use 'all' or comma-separated sample indices >= 0, e.g. 0,5,9")
    return ",".join(str(i) for i in indices)


def read_shifts_file(
    path: str | os.PathLike[str], geometry: Geometry, binning: int = 1, left_out: Any = ()
) -> np.ndarray:
    """A shifts file (detector pixels, :func:`~nanoct.io.shiftfile.read_shifts`) as Dremel shifts, float64.

    Dremel's shifts are image pixels along the detector axis. ``binning`` and ``left_out``
    describe how an import made the data set from the scan (:func:`scan_layout`): nabu's raw
    detector pixels are divided by the binning, rows of left-out projections skipped.
    """
    return read_shifts(path, geometry.n_angles, binning=binning, left_out=left_out) / _det_per_obj(geometry)


def read_store_shifts(path: str | os.PathLike[str], store: DataStore, notes: list[str] | None = None) -> np.ndarray:
    """The shifts file ``path`` given as ``--param shifts_from`` for data set ``store``, as Dremel shifts.

    A file that records the rotation axis its shifts go with (:data:`~nanoct.io.shiftfile.AXIS_COMMENT`,
    as nanoct's exports do) is brought to the data set's axis: reconstructing view ``k`` about axis
    ``a`` with shift ``e_k`` is reconstructing it about ``a - e_k``, so the shifts get the axes'
    difference added (the I13 scan with an added motion, the stack's shifts of axis +7.39 px on a
    data set imported at +6.33 px: 33.33 dB as written, 36.63 dB brought to the axis, 36.62 dB
    with the stack's own axis). ``notes`` gets what was done.

    Raises
    ------
    NanoctError
        Naming the parameter, for a file that does not fit the data set's views.
    """
    layout = scan_layout(store)
    try:
        shifts = read_shifts_file(path, store.geometry, **layout)
    except NanoctError as exc:
        raise NanoctError(f"--param shifts_from={path}: {exc}") from None
    axis = shifts_axis(path)
    if axis is None:
        return shifts
    own = store_raw_axis(store, store.geometry.center_offset)
    if abs(own - axis) > 1e-6 and notes is not None:
        notes.append(
            f"the shifts of {path} go with the axis {axis:+.3f} raw px; brought to this data set's axis "
            f"{own:+.3f} raw px (each shift {own - axis:+.3f} raw px)"
        )
    return shifts + (own - axis) / (layout["binning"] * _det_per_obj(store.geometry))


def scan_layout(store: DataStore) -> dict[str, Any]:
    """``binning`` and ``left_out`` (projections of the scan not in the data set) of an imported data set.

    Simulated data sets give binning 1 and no left-out views.
    """
    scan = store.meta.get("scan") or {}
    return {"binning": int(scan.get("binning") or 1), "left_out": list(scan.get("left_out_views") or [])}


@dataclass(frozen=True)
class SharedMotionParams(MethodParams):
    """Batch parameters of a method that estimates motion (used by the batch runner, not the solver).

    Parameters
    ----------
    motion_slices : str, optional
        One motion for several slices of a stack: ``all`` or sample indices ``0,5,9``, estimated
        jointly before the slices are reconstructed with it.
    shifts_from : str, optional
        A shifts file whose motion starts (or, with ``fix_shifts=true``, fixes) the estimate.
    """

    motion_slices: str | None = None
    shifts_from: str | None = None

    def __post_init__(self) -> None:
        self._set("motion_slices", parse_slices(self.motion_slices))

    def resolve(self, geometry: Geometry) -> dict[str, Any]:
        """The values for ``geometry``: the shifts file is read (a missing or malformed one fails
        here, before anything is written; its number of rows is checked against the data set,
        which knows the views an import left out, by :func:`read_store_shifts`) and its path
        made absolute."""
        out = super().resolve(geometry)
        if self.shifts_from is not None:
            try:
                read_shifts(str(self.shifts_from), None)
            except NanoctError as exc:
                raise ValueError(f"shifts_from={self.shifts_from!r}: {exc}") from exc
            out["shifts_from"] = str(Path(str(self.shifts_from)).resolve())
        return out


def joint_shifts(
    geometry: Geometry, sinograms: Any, params: dict[str, Any], shifts0: Any = None, notes: list[str] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """One per-view shift for several slices that share a motion.

    Parameters
    ----------
    geometry : Geometry
        Scan geometry.
    sinograms : array_like of shape (S, K, L)
        The chosen slices' sinograms.
    params : dict
        Dremel parameters (checked, :func:`~nanoct.recon.dremel.check_params`).
    shifts0 : array_like of shape (K,), optional
        Starting shifts of every slice's estimate.
    notes : list of str, optional
        Gets the reason of every slice whose estimate was rejected as a runaway (``shift_check``,
        :func:`~nanoct.recon.dremel.runaway_shifts`; that slice counts with its start).

    Returns
    -------
    shared : ndarray of shape (K,), float32
        Per-view median over slices of the estimates, each with its translation term removed.
    per_slice : ndarray of shape (S, K), float32
        The slices' own estimates (translation removed).
    """
    estimates = []
    for sino in np.asarray(sinograms):
        result = dremel(geometry, sino, **{**params, "fix_shifts": False}, shifts0=shifts0)
        estimates.append(remove_translation(result.motion, geometry.angles))
        if notes is not None and "shift_check" in result.params:
            notes.append(result.params["shift_check"])
    per_slice = np.asarray(estimates, dtype=np.float32)
    return np.median(per_slice, axis=0).astype(np.float32), per_slice


def write_store_shifts(
    path: str | os.PathLike[str], name: str, out: str | os.PathLike[str], sample: int | None = None
) -> Path:
    """Write the shifts of reconstruction ``name`` of a store as nabu's ``translation_movements_file``.

    The rows are in raw detector pixels (the data set's pixels times its binning), nabu's sign
    (:func:`nanoct.io.shiftfile.write_shifts`); an imported scan with a pixel size adds nm.

    Parameters
    ----------
    path : path
        Data-set store.
    name : str
        A reconstruction with shifts (Dremel's).
    out : path
        The text file to write (detector pixels, :func:`nanoct.io.shiftfile.write_shifts`).
    sample : int, optional
        Which sample's shifts; may be omitted when the reconstruction has one motion shared by
        all slices (an imported stack) or the store has a single sample.

    Raises
    ------
    NanoctError
        For a reconstruction without shifts, or per-sample shifts and no ``sample``.
    """
    store = DataStore.open(path)
    if name not in store.reconstruction_names():
        raise NanoctError(f"{store.path} has no reconstruction '{name}'; present: {store.reconstruction_names()}")
    method = store.reconstruction_params(name).get("method")
    if method not in methods_with_motion():
        raise NanoctError(f"reconstructions/{name} ({method}) has no estimated shifts; export a Dremel result")
    shifts = store.recons.shared_shifts(name)
    if shifts is None:
        if sample is None and store.n != 1:
            raise NanoctError(
                f"reconstruction '{name}' of {store.path} has one motion per sample; choose the sample to export"
            )
        shifts = store.read_shifts(name, [0 if sample is None else sample])[0]
    scan = store.meta.get("scan") or {}
    pixel = scan.get("raw_pixel_size_m")
    layout = scan_layout(store)
    return write_shifts(
        out,
        np.asarray(shifts) * _det_per_obj(store.geometry) * layout["binning"],
        axis=store_raw_axis(store, store.geometry.center_offset),
        angles=store.geometry.angles,
        pixel_size_m=None if pixel is None else float(pixel[0]),
        notes=[note for note in scan.get("notes", []) if note.startswith("left out")],
        left_out=layout["left_out"],
    )
