"""``nanoct stack``: one motion and axis for a whole measured stack, then every slice with them fixed.

The motion and the rotation axis are estimated once: the vertical shift per view from the row
profiles of every slice (:func:`~nanoct.motion.vertical.vertical_motion`, stacks of at least
:data:`MIN_VERTICAL_SLICES` slices; zero, with the reason recorded as ``vertical_guard``, where
the profiles do not show a significant motion); the axis as the import estimated it, else from
every axis estimator (:func:`~nanoct.motion.axis.estimate_axis`), so that ``import`` and
``stack`` give the same axis; the horizontal shift per view from a few slices, moved back
vertically and with their open beam removed, by the views' centroids where air is seen around
the object, else (an object wider than the field of view) as
:func:`~nanoct.motion.estimate.estimate_motion` finds it, from a central block of rows: an
autofocus of the slow motion, projection matching, and the autofocus again with the axis
(:func:`horizontal_motion`). The axis tilt on the detector is estimated from opposite views, or
on a limited-angle series from the views' centroids (:func:`~nanoct.motion.axis.axis_tilt`), only
where air is seen (on a truncated object the opposite views gave -6.2 degrees where the scan has
none). The horizontal motion may be replaced by a smooth model
(:func:`~nanoct.motion.model.fit_motion_model`). The result is then checked against the data
(:func:`consistent_motion`): no motion at the still object's axis, the axis alone, a smooth model
and the shifts are scored by how well half of the views predict the other half
(:mod:`~nanoct.motion.consistency`), and a motion that fits worse than a simpler candidate beyond
the score's noise is dropped (on PSI's static basalt scan the views' centroids proposed a motion
whose held-out misfit was 43 % above that of none: 0.00437 against 0.00305, noise 0.00006).
Both are recorded with the reconstruction
(``shared_shifts`` and ``motion_info`` attributes of ``reconstructions/<name>``). Every slice is
then reconstructed with the motion fixed, one task per slice (Dask across slices, a progress bar
per slice); a run that is stopped resumes where it was: the recorded motion is reused and the
slices already written are skipped (each slice is written with its progress flag last).

``--method gridrec`` reconstructs the slices in blocks (two slices per complex transform, one
pair per thread) with :class:`~nanoct.recon.gridrec.GridrecPlan`, built once per process for
the stack's motion. ``--method fbp`` does the same wherever gridrec is usable (``finufft``
importable, or the GPU path), as its images match FBP's (``docs/gridrec.md``), and falls back to
the pixel-driven :func:`~nanoct.recon.stack.corrected_fbp` otherwise; which one ran is recorded
with the reconstruction (the note ``engine``, read with ``store.recons.note(name, "engine")``).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from ..core.errors import NanoctError
from ..core.fanout import run_tasks, usable_cpus, worker_threads
from ..io.lock import exclusive
from ..io.store import DataStore, open_cached
from ..motion.axis import (
    MIN_SCORED_VIEWS,
    axis_rows,
    axis_tilt,
    estimate_axis,
    limited_angle_tilt,
    object_rows,
    remove_air,
)
from ..motion.center import centroid_motion, opposite_pairs
from ..motion.consistency import Candidate, heldout_misfit, score_binning, select
from ..motion.model import fit_motion_model
from ..motion.vertical import vertical_motion
from ..recon.batch import shift_check_recorder
from ..recon.measured import read_moved
from ..recon.names import stack_name
from ..recon.stack import corrected_fbp, reproject, with_center

__all__ = [
    "FBP_ENGINES",
    "MIN_VERTICAL_SLICES",
    "STACK_METHODS",
    "centroid_motion_axis",
    "consistency_lines",
    "consistent_motion",
    "fbp_engine",
    "horizontal_motion",
    "read_straight",
    "reconstruct_stack",
    "shift_corrected",
]

#: Reconstruction of each slice with the stack's motion: motion-corrected FBP, its Fourier-space
#: form (gridrec), Dremel (SART view steps) with the motion held fixed (on measured data: as its
#: start), or RESESOP-Kaczmarz with the motion (on measured data: Dremel's refinement of it).
STACK_METHODS = ("fbp", "gridrec", "dremel", "resesop")

#: How ``--method fbp`` runs: ``auto`` (gridrec where usable), ``gridrec`` or ``backprojection``.
FBP_ENGINES = ("auto", "gridrec", "backprojection")

#: The ``"auto"`` RESESOP level: this fraction of the corrected FBP's largest residual per view
#: (that residual also holds the FBP's own error; ``benchmarks/stack_eta.py`` measured 0.5
#: against 1, 0.2, the RMS, the 90th percentile and the residual with the FBP's error removed).
AUTO_ETA_FRACTION = 0.5

#: Vertical motion is estimated from the row profiles of stacks of at least this many slices
#: (a profile of fewer rows holds too little structure to register).
MIN_VERTICAL_SLICES = 16

#: The consistency check of the motion reads at most this many rows (:func:`consistent_motion`).
SCORE_ROWS = 4

#: The smooth candidate: :func:`~nanoct.motion.model.fit_motion_model` of this degree and harmonics.
SMOOTH_MODEL = (3, 3)

#: Where no air is seen, the autofocus and projection matching read a central block of at most
#: this many contiguous rows (all rows of the I13 crop wider than the field of view, 59) ...
MATCH_ROWS = 64

#: ... and of at most this many values (rows x views x columns; 8 rows at least).
MATCH_VALUES = 2**25


def _check_eta(eta: Any, n_views: int) -> str | float | list[float]:
    """``"auto"``, one level >= 0 for every view, or ``n_views`` levels >= 0 (as stored in the params)."""
    if isinstance(eta, str) and eta == "auto":
        return "auto"
    try:
        arr = np.asarray(eta, dtype=np.float64)
    except (TypeError, ValueError):
        arr = np.array([np.nan])
    if arr.ndim > 1 or (arr.ndim == 1 and arr.size != n_views) or not np.isfinite(arr).all() or (arr < 0).any():
        raise NanoctError(
            f"--eta {eta!r}: give 'auto', one finite level >= 0, or {n_views} per-view levels >= 0 (a .npy file)"
        )
    return float(arr) if arr.ndim == 0 else arr.tolist()


def shift_corrected(sinogram: np.ndarray, shifts: np.ndarray) -> np.ndarray:
    """The sinogram with view ``k`` read at ``u - d_k`` (linear interpolation, zero outside).

    Parameters
    ----------
    sinogram : ndarray of shape (K, L)
        Measured line integrals.
    shifts : ndarray of shape (K,)
        Per-view shifts ``d_k`` in detector pixels, as :func:`~nanoct.recon.stack.corrected_fbp` takes them.

    Returns
    -------
    ndarray of shape (K, L), float64
        The views as the unmoved object would give them.
    """
    u = np.arange(sinogram.shape[1], dtype=np.float64)
    return np.stack([np.interp(u - d, u, view, left=0.0, right=0.0) for view, d in zip(sinogram, shifts)])


def _dremel_slice(geometry: Any, sino: np.ndarray, shifts: np.ndarray) -> Any:
    """Dremel with the stack's motion (detector pixels): held fixed, or on measured data Dremel's start.

    On a measured sinogram (:func:`~nanoct.recon.measured.looks_measured`) Dremel starts from the
    stack's motion and refines it per slice (its measured-data defaults); a simulation keeps the
    stack's motion fixed.
    """
    from ..recon.dremel import dremel
    from ..recon.measured import looks_measured

    shifts_obj = shifts * geometry.det_spacing / geometry.magnification  # detector px -> object px
    return dremel(geometry, sino, shifts0=shifts_obj, fix_shifts=not looks_measured(sino))


def _resesop_slice(
    geometry: Any, sino: np.ndarray, shifts: np.ndarray, eta: str | float | list[float]
) -> tuple[np.ndarray, np.ndarray, str | None]:
    """RESESOP-Kaczmarz with the stack's motion; ``"auto"`` eta: half the largest residual per view after it.

    Measured data (:func:`~nanoct.recon.measured.looks_measured`): the model carries the motion
    (:func:`~nanoct.recon.resesop.resesop`'s ``shifts``); with ``"auto"`` the motion is Dremel's
    refinement of the stack's (:func:`_dremel_slice`) and eta half the largest residual of Dremel's
    image per view after that motion (:func:`~nanoct.recon.eta.eta_from_residual`, air level
    removed). A simulation: RESESOP on the shift-corrected sinogram, ``"auto"`` eta half the
    corrected FBP's largest residual per view.

    Returns
    -------
    image : ndarray of shape (N, N)
    motion : ndarray of shape (K,)
        The motion the slice was reconstructed with, in detector pixels: Dremel's refinement on
        measured data with ``"auto"`` eta, else the stack's ``shifts``.
    shift_check : str or None
        Why Dremel rejected that refinement (it kept the stack's motion); None where it did not, or did not run.
    """
    from ..recon.eta import eta_from_residual
    from ..recon.measured import looks_measured
    from ..recon.resesop import resesop

    to_obj = geometry.det_spacing / geometry.magnification  # detector px -> object px
    if looks_measured(sino):
        if eta == "auto":
            start = _dremel_slice(geometry, sino, shifts)
            reason = start.params.get("shift_check")
            motion = start.motion.astype(np.float64)
            levels = eta_from_residual(geometry, sino, start.image, scale=AUTO_ETA_FRACTION, shifts=motion)
        else:
            motion, reason = shifts * to_obj, None
            levels = np.broadcast_to(np.asarray(eta, dtype=np.float64), (geometry.sino_shape[0],))
        image = resesop(geometry, sino, levels, shifts=motion, projector="auto").image
        return image, (motion / to_obj if eta == "auto" else shifts), reason
    corrected = shift_corrected(sino.astype(np.float64), shifts)
    if eta == "auto":
        start = corrected_fbp(geometry, corrected)
        levels = AUTO_ETA_FRACTION * np.abs(corrected - reproject(geometry, start)).max(axis=1)
    else:
        levels = np.broadcast_to(np.asarray(eta, dtype=np.float64), (geometry.sino_shape[0],))
    return resesop(geometry, corrected, levels, projector="auto").image, shifts, None


def _motion_slices(store: DataStore, value: str | None) -> list[int]:
    done = np.flatnonzero(store.done)
    if value in (None, "auto"):  # up to 4 slices spread over the stack
        return sorted({int(i) for i in done[np.linspace(0, done.size - 1, min(4, done.size)).round().astype(int)]})
    if value == "all":
        return [int(i) for i in done]
    try:
        chosen = sorted({int(v) for v in value.split(",")})
    except ValueError:
        chosen = [-1]
    if not set(chosen) <= set(done.tolist()):
        raise NanoctError(
            f"--motion-slices {value!r}: give 'auto', 'all' or comma-separated slice numbers of 0..{store.n - 1}"
        )
    return chosen


def _profiles(store: DataStore, block: int = 32) -> np.ndarray:
    """``(K, S)`` row profiles of the stack: each slice's sinogram summed over the detector."""
    out = np.zeros((store.geometry.n_angles, store.n))
    for first in range(0, store.n, block):
        chosen = list(range(first, min(first + block, store.n)))
        out[:, chosen] = store.read_array("sinograms", chosen).sum(axis=2).T
    return out


def read_straight(store: DataStore, indices: list[int], vertical: np.ndarray) -> np.ndarray:
    """Sinograms of ``indices`` with every view moved back by its vertical shift, ``(len, K, L)``.

    View ``k`` of slice ``s`` is read at row ``s - v_k`` of the stack (``m_k(z, x) = Q_k(z + v_k,
    x)``), linearly between the two slices around it (the first and last slice repeat outside).
    """
    if not np.any(vertical):
        return store.read_array("sinograms", indices)
    out = np.empty((len(indices), store.geometry.n_angles, store.geometry.n_det), dtype=np.float32)
    views = np.arange(store.geometry.n_angles)
    for i, s in enumerate(indices):
        z = np.clip(s - vertical, 0, store.n - 1)
        lo = np.minimum(np.floor(z).astype(int), store.n - 2) if store.n > 1 else np.zeros(z.size, int)
        frac = (z - lo)[:, None]
        first, last = int(lo.min()), int(min(lo.max() + 1, store.n - 1))
        block = store.read_array("sinograms", list(range(first, last + 1)))
        below = block[lo - first, views]
        above = block[np.minimum(lo + 1, store.n - 1) - first, views]
        out[i] = (1 - frac) * below + frac * above
    return out


def _axis(store: DataStore, vertical: np.ndarray, shifts: np.ndarray) -> tuple[float, dict[str, Any]]:
    """:func:`~nanoct.motion.axis.estimate_axis` on the rows the import uses, every view moved back by its motion.

    With the motion undone the estimators see a still object, so the axis goes with ``shifts``
    (the centroid's, which have no constant); on a still scan it is the import's axis.
    """
    rows = [int(i) for i in axis_rows(store.n)]
    straight = read_straight(store, rows, vertical)
    corrected = np.stack([read_moved(sino, shifts) for sino in straight])  # the open beam held at the edges
    estimate = estimate_axis(corrected, store.geometry.angles)
    return estimate.offset, estimate.to_dict()


def _tilt(store: DataStore, vertical: np.ndarray, shifts: np.ndarray) -> dict[str, Any]:
    """The axis tilt on the detector (:func:`~nanoct.motion.axis.axis_tilt`) from 16 groups of 4 rows, motion undone.

    Called where air is seen: from opposite views, or (a limited-angle series) from the views'
    centroids, on contiguous rows rotated back until the line is vertical (:func:`_limited_tilt`).
    """
    if not opposite_pairs(store.geometry.angles)[0].size:
        return _limited_tilt(store, vertical, shifts)
    firsts = np.unique(np.linspace(0, store.n - 4, min(16, store.n // 4)).round().astype(int))
    rows = [int(r) for first in firsts for r in range(first, first + 4)]
    straight = read_straight(store, rows, vertical)
    corrected = np.stack([read_moved(sino, shifts) for sino in straight])  # the open beam held at the edges
    try:
        tilt = axis_tilt(corrected, store.geometry.angles, rows=rows, n_rows=store.n)
    except NanoctError as exc:
        return {"tilt": {"note": str(exc)}}
    return {"tilt": {"tilt_deg": tilt.tilt_deg, "slope": tilt.slope, "residual": tilt.residual}}


def _limited_tilt(store: DataStore, vertical: np.ndarray, shifts: np.ndarray) -> dict[str, Any]:
    """A limited-angle series' axis tilt (:func:`~nanoct.motion.axis.limited_angle_tilt`), motion undone.

    On a central block of contiguous rows (all of them where at most :data:`MATCH_VALUES` values).
    """
    geometry = store.geometry
    count = min(store.n, max(24, MATCH_VALUES // (geometry.n_angles * geometry.n_det)))
    first = (store.n - count) // 2
    straight = read_straight(store, list(range(first, first + count)), vertical)
    corrected = np.stack([read_moved(sino, shifts) for sino in straight])  # the open beam held at the edges
    try:
        tilt, trials = limited_angle_tilt(corrected.transpose(1, 0, 2), geometry.angles)
    except NanoctError as exc:
        return {"tilt": {"note": str(exc)}}
    found = {"tilt_deg": tilt.tilt_deg, "slope": tilt.slope, "residual": tilt.residual, "trials": trials}
    return {"tilt": {**found, "method": "centroid axis of row groups, rotated back until vertical"}}


def slice_center(info: dict[str, Any], index: int, n_slices: int) -> float:
    """The axis offset of slice ``index``: the stack's axis, moved along the tilt line where one was found."""
    slope = info.get("tilt", {}).get("slope", 0.0)
    return float(info["center_offset"] + slope * (index - (n_slices - 1) / 2))


def _matching_rows(store: DataStore) -> list[int]:
    """The central contiguous block of rows the autofocus and projection matching read (:data:`MATCH_ROWS`)."""
    count = min(store.n, MATCH_ROWS, max(8, MATCH_VALUES // (store.geometry.n_angles * store.geometry.n_det)))
    first = (store.n - count) // 2
    done = getattr(store, "done", None)  # a store's written slices (a scan file's rows are all there)
    return [first + i for i in range(count) if done is None or done[first + i]]


def _motion_label(name: str) -> str:
    """The progress label of the motion estimate of ``name``: ``"NAME: motion"``, or ``"motion"`` for that name."""
    return name if name == "motion" else f"{name}: motion"


def _focus_matching(
    store: DataStore, params: dict[str, Any], vertical: np.ndarray, bar: Any
) -> tuple[np.ndarray, dict[str, Any]] | None:
    """No air seen: :func:`~nanoct.motion.estimate.estimate_motion`'s path (autofocus, matching, autofocus).

    Reads the rows of :func:`_matching_rows`, moved back vertically, with their open beam removed;
    the vertical motion stays the stack's. The axis is the last autofocus's where it was accepted,
    else that of every axis estimator with the shifts undone; or the given one. ``None`` where a
    first autofocus from the start axis runs to its bounds (too little structure to focus on: the
    K11 interior crop, 22 x 26 pixels), so that the caller falls back to Dremel and matching.
    ``bar`` (a tqdm bar) counts six stages: the open beam, the start axis, the first autofocus
    and the three of :func:`~nanoct.motion.estimate.estimate_motion`.
    """
    from ..motion.estimate import estimate_motion, start_axis
    from ..motion.focus import focus_smooth

    rows = _matching_rows(store) or [int(i) for i in params["motion_slices"]]
    bar.set_postfix_str("open beam, matching rows")
    clean, _ = remove_air(read_straight(store, rows, vertical))
    bar.update()
    given = None if params["center"] == "auto" else float(params["center"])
    bar.set_postfix_str("start axis")
    start = start_axis(clean[axis_rows(len(rows))], store.geometry.angles) if given is None else given
    bar.update()
    projections = clean.transpose(1, 0, 2)
    bar.set_postfix_str("autofocus")
    if not focus_smooth(projections, store.geometry.angles, start).accepted:
        bar.update()
        return None
    bar.update()
    bar.set_postfix_str("focus+matching")
    motion = estimate_motion(
        projections, store.geometry.angles, center=given, horizontal="matching",
        vertical=False, prealign=False, tilt=False, progress=lambda stage: bar.update(),
    )  # fmt: skip
    accepted = motion.record["focus"]["accepted"]
    method = "focus+matching" if any(accepted) else "matching"
    center_method = "given" if given is not None else ", ".join(motion.axis.used)
    info: dict[str, Any] = {"horizontal_method": method, "center_method": center_method, "refine_steps": []}
    info.update(center_offset=motion.axis.offset, center_raw=motion.record["focus"]["start_axis"])
    info.update(mass_spread=motion.record["mass_spread"], matching_rows=[rows[0], rows[-1] + 1])
    info["focus"] = {"accepted": accepted, "axis": motion.record["focus"]["axis"]}
    if given is None:
        info["axis"] = motion.axis.to_dict()
    return motion.horizontal, info


def horizontal_motion(
    store: DataStore,
    params: dict[str, Any],
    vertical: np.ndarray,
    progress: bool,
    name: str,
    centroids: Callable[..., tuple[np.ndarray, dict[str, Any]]] | None = None,
) -> tuple[np.ndarray, dict[str, Any]]:
    """The horizontal shift per view and the axis (``info["center_offset"]``) of a stack.

    From the chosen slices, moved back vertically and with their open beam removed: the views'
    centroids where air is seen around the object (the axis then from every estimator on the
    rows the import uses, with the motion undone). Else (an object wider than the field of view)
    the path of :func:`~nanoct.motion.estimate.estimate_motion` on a central block of rows
    (:func:`_focus_matching`: autofocus of the slow motion, projection matching, autofocus with
    the axis; ``horizontal_method`` ``"focus+matching"``, or ``"matching"`` where both autofocus
    results were rejected). With ``refine`` given (air seen or not), or where a first autofocus
    runs to its bounds (too little structure to focus on), Dremel and projection matching on the
    chosen slices (:func:`~nanoct.motion.stack.estimate_stack_motion`, ``"dremel+matching"``).

    With ``progress`` one bar, labelled :func:`_motion_label` of ``name``, counts the stages and
    names the one running. ``centroids`` replaces :func:`centroid_motion_axis` where air is seen (same
    arguments; one stage on the bar): a scan streamed from its files takes the cheaper axis of
    :func:`nanoct.workflows.slabs.slab_centroids`.
    """
    refine = (2, 2, 2, 1) if params["refine"] is None else tuple(params["refine"])
    with tqdm(total=1, desc=_motion_label(name), disable=not progress, unit="stage") as bar:
        bar.set_postfix_str("open beam, motion slices")
        clean, air = remove_air(read_straight(store, params["motion_slices"], vertical), zero_air=True)
        by_centroids = air and params["refine"] is None  # a given refine asks for Dremel and matching
        bar.total += 1 if by_centroids else (6 if params["refine"] is None else 3 + len(refine))  # the stages to come
        bar.update()
        if by_centroids:
            return (centroids or centroid_motion_axis)(store, params, vertical, clean, bar)
        info: dict[str, Any] = {}
        if params["refine"] is None:
            found = _focus_matching(store, params, vertical, bar)
            if found is not None:
                return found
            info["focus"] = {"note": "the autofocus ran to its bounds (too little structure): Dremel and matching"}
            bar.total += len(refine)  # Dremel's 3 + len(refine) stages for the 3 of the matching not run
        return _dremel_matching(store, params, clean, info, refine, bar)


def centroid_motion_axis(
    store: DataStore, params: dict[str, Any], vertical: np.ndarray, clean: np.ndarray, bar: Any
) -> tuple[np.ndarray, dict[str, Any]]:
    """Air seen: the views' centroids give the shifts, every axis estimator the axis (one stage on ``bar``).

    Parameters
    ----------
    store : DataStore or ScanRows
        The stack's data set (or a scan file's selected rows).
    params : dict
        The motion options (``center``: ``"auto"`` or a given offset).
    vertical : ndarray of shape (K,)
        The vertical shifts the slices were moved back by.
    clean : ndarray of shape (S, K, L)
        The motion slices with their open beam removed.
    bar : tqdm
        The motion estimate's progress bar.

    Returns
    -------
    tuple
        The horizontal shifts (K,) and what is recorded with them (``center_offset``, ``horizontal_method``, ...).
    """
    rows = object_rows(clean)
    bar.set_postfix_str("centroids and axis")
    _, shifts, spread = centroid_motion(clean[rows] if rows.any() else clean, store.geometry.angles)
    info: dict[str, Any] = {}
    if params["center"] == "auto":
        center, info["axis"] = _axis(store, vertical, shifts)
    else:
        center = float(params["center"])
    bar.update()
    info.update(center_method="estimators" if params["center"] == "auto" else "given", horizontal_method="centroid")
    info.update(center_offset=center, center_raw=center, mass_spread=spread, refine_steps=[])
    return shifts, info


def _dremel_matching(
    store: DataStore, params: dict[str, Any], clean: np.ndarray, info: dict[str, Any], refine: tuple[int, ...], bar: Any
) -> tuple[np.ndarray, dict[str, Any]]:
    """Dremel and projection matching on the chosen slices (``3 + len(refine)`` stages on ``bar``)."""
    from ..motion.stack import estimate_stack_motion

    bar.set_postfix_str("dremel+matching")
    motion = estimate_stack_motion(
        store.geometry,
        clean,
        binning=params["binning"],
        coarse_iter=params["coarse_iter"],
        refine=refine,
        center=None if params["center"] == "auto" else float(params["center"]),
        progress=lambda stage: bar.update(),
    )
    info.update(center_offset=motion.center_offset, center_raw=motion.center_raw, horizontal_method="dremel+matching")
    info.update(center_method=motion.center_method, mass_spread=motion.mass_spread, refine_steps=motion.steps)
    return motion.shifts, info


def _still_axis(store: DataStore, params: dict[str, Any], clean: np.ndarray) -> float:
    """The axis of a still object: the given one, the import's estimate, else every axis estimator's on ``clean``."""
    if params["center"] != "auto":
        return float(params["center"])
    if (getattr(store, "meta", None) or {}).get("scan", {}).get("axis"):
        return float(store.geometry.center_offset)
    return estimate_axis(clean, store.geometry.angles).offset


def _candidates(
    store: DataStore, start: float, params: dict[str, Any], shifts: np.ndarray, center: float
) -> list[Candidate]:
    """No motion at the still axis (:func:`_still_axis`), the estimated axis alone, a smooth model, the shifts."""
    found = [Candidate("none", start, None, "none")]
    if abs(center - start) > 1e-6:
        found.append(Candidate("axis only", center, None, "axis"))
    if not np.any(shifts):
        return found
    if params["model"] is not None:
        return [*found, Candidate("motion model", center, shifts, "model")]
    smooth = fit_motion_model(shifts, store.geometry.angles, *SMOOTH_MODEL).shifts
    return [*found, Candidate("smooth motion", center, smooth, "model"), Candidate("shifts", center, shifts, "shifts")]


def consistent_motion(
    store: DataStore, params: dict[str, Any], vertical: np.ndarray, shifts: np.ndarray, info: dict[str, Any]
) -> np.ndarray:
    """The estimated motion, or a simpler candidate where the data do not support it beyond the noise.

    Every candidate of :func:`_candidates` is scored by its held-out misfit
    (:func:`~nanoct.motion.consistency.heldout_misfit`) on the rows the axis is estimated from
    (:func:`~nanoct.motion.axis.axis_rows`, at most :data:`SCORE_ROWS`), moved back vertically,
    air at zero; :func:`~nanoct.motion.consistency.select` finds the simplest one that no more
    complex one beats beyond the noise, and replaces the estimate (the last candidate, its
    ``prefer``) by it only where the estimate fits worse than it beyond the noise ("never worse
    than no correction"); where the data cannot tell them apart the estimate stays and the record
    says undecided. The
    choice, every score and the check on another interleave of the views go into
    ``info["consistency"]``; ``info["center_offset"]`` becomes the kept candidate's axis. Returns
    the kept shifts (zero for a still object).
    """
    angles = store.geometry.angles
    if angles.size < MIN_SCORED_VIEWS:
        info["consistency"] = {"note": f"not scored: fewer than {MIN_SCORED_VIEWS} views"}
        return shifts
    rows = [int(i) for i in axis_rows(store.n, SCORE_ROWS)]
    clean, _ = remove_air(read_straight(store, rows, vertical), zero_air=True)
    binning = score_binning(clean.shape[2])

    def score(candidate: Candidate, split: str) -> Any:
        return heldout_misfit(clean, angles, candidate.center_offset, candidate.shifts, split=split, binning=binning)

    candidates = _candidates(store, _still_axis(store, params, clean), params, shifts, float(info["center_offset"]))
    selection = select(candidates, score, prefer=candidates[-1])
    info["consistency"] = {**selection.to_dict(), "rows": rows, "binning": binning, "estimate": candidates[-1].name}
    if selection.chosen.shifts is None:
        info["center_offset"] = selection.chosen.center_offset
        return np.zeros_like(shifts)
    return selection.chosen.shifts


def consistency_lines(info: dict[str, Any]) -> list[str]:
    """The summary lines of a stack's consistency check (``nanoct stack`` prints them, stored or streamed)."""
    record = info.get("consistency")
    if not record or "scores" not in record:
        return [f"  check    {record['note']}"] if record else []
    scores = ", ".join(f"{name} {value:.5f}" for name, value in record["scores"].items())
    verdict = "" if record["decided"] else " (undecided: the data do not separate it from another candidate)"
    lines = [f"  check    held-out misfit {scores}; kept {record['chosen']}{verdict}"]
    lines += [f"           {note}" for note in record["notes"]]
    return lines


def _estimate(store: DataStore, name: str, params: dict[str, Any], progress: bool) -> None:
    """Estimate the stack's vertical and horizontal motion and its axis, and record them with ``name``."""
    vertical = np.zeros(store.geometry.n_angles)
    guard: dict[str, Any] = {"note": f"fewer than {MIN_VERTICAL_SLICES} slices: no vertical motion estimated"}
    if store.n >= MIN_VERTICAL_SLICES and store.done.all():
        estimate = vertical_motion(_profiles(store))
        vertical, guard = estimate.shifts, estimate.to_dict()
    shifts, info = horizontal_motion(store, params, vertical, progress, name)
    if params["model"] is not None:
        degree, harmonics = params["model"]
        model = fit_motion_model(shifts, store.geometry.angles, degree, harmonics)
        shifts = model.shifts
        info["model_residual_rms"] = model.residual_rms
    shifts = consistent_motion(store, params, vertical, shifts, info)
    if params["center"] == "auto" and store.n >= MIN_VERTICAL_SLICES and store.done.all():
        if info["horizontal_method"] == "centroid":
            info.update(_tilt(store, vertical, shifts))
        else:  # on the I13 crop wider than the field of view the opposite views gave -6.2 degrees for ~0
            info["tilt"] = {"note": "no air seen: the opposite views of a truncated object do not fix the axis tilt"}
    info["vertical_method"] = "row profiles" if np.any(vertical) else "none"
    info["vertical_guard"] = guard
    info["shift_rms"] = float(np.sqrt(np.mean(shifts**2)))
    info["vertical"] = [float(v) for v in vertical]
    store.recons.set_shared_shifts(name, shifts)
    store.recons.set_motion_info(name, info)


def _reconstruct_slice(
    path: str,
    name: str,
    method: str,
    info: dict[str, Any],
    eta: Any,
    shifts: np.ndarray,
    vertical: np.ndarray,
    index: int,
) -> tuple[int, str | None]:
    """Reconstruct slice ``index`` and write it with the motion it used (detector pixels); its index, and why
    Dremel (of ``method="dremel"``, or of RESESOP's ``"auto"`` eta) rejected its refinement: None where it did
    not (the progress flag is set here), else the callback of
    :func:`~nanoct.recon.batch.shift_check_recorder` sets it.

    The shifts row written is the stack's motion (``shifts``), except on measured data with
    Dremel, or RESESOP with ``"auto"`` eta, where it is Dremel's refinement of it for this slice
    (:func:`_dremel_slice`); the stack's motion stays recorded as the reconstruction's
    ``shared_shifts``.
    """
    store = open_cached(path)
    geometry = with_center(store.geometry, slice_center(info, index, store.n))
    sino = read_straight(store, [index], vertical)[0]
    motion, reason = shifts, None
    if method == "fbp":
        image = corrected_fbp(geometry, sino, shifts)
    elif method == "resesop":
        image, motion, reason = _resesop_slice(geometry, sino, shifts, eta)
    else:
        from ..recon.measured import looks_measured

        result = _dremel_slice(geometry, sino, shifts)
        image = result.image
        if looks_measured(sino):  # refined per slice: Dremel's motion, object -> detector pixels
            motion = result.motion.astype(np.float64) * geometry.magnification / geometry.det_spacing
        reason = result.params.get("shift_check")
    store.recons.write(name, index, image, motion.astype(np.float32), done=reason is None)
    return index, reason


def fbp_engine(choice: str = "auto") -> str:
    """How the stack's FBP runs: ``"gridrec"`` (Fourier space) or ``"backprojection"`` (pixel-driven).

    Parameters
    ----------
    choice : {"auto", "gridrec", "backprojection"}
        ``auto``: gridrec wherever a non-uniform FFT library is usable
        (:func:`~nanoct.recon.gridrec.gridrec_available` or :func:`~nanoct.recon.gridrec.gpu_available`).

    Raises
    ------
    NanoctError
        For an unknown choice, or ``gridrec`` without a usable library.
    """
    from ..recon.gridrec import gpu_available, gridrec_available, select_backend

    if choice not in FBP_ENGINES:
        raise NanoctError(f"fbp engine {choice!r} is unknown; use one of {', '.join(FBP_ENGINES)}")
    if choice == "gridrec":
        select_backend("auto")  # raises where no library is usable
    if choice == "auto":
        return "gridrec" if gridrec_available() or gpu_available() else "backprojection"
    return choice


_PLAN: dict[tuple, Any] = {}  # the last gridrec plan of this process (one stack's geometry and motion)


def _gridrec_block(
    path: str, name: str, info: dict[str, Any], motion: tuple, threads: int, blocks: list, block: int
) -> int:
    """Reconstruct one block of slices with gridrec (the plan kept for the next block) and write them.

    ``motion`` is ``(shifts, vertical)``: the slices are read with every view moved back by its
    vertical shift (:func:`read_straight`), the horizontal shifts are gridrec's phase ramps, and
    each slice's axis (:func:`slice_center`, along a tilted axis) a phase ramp of its own.
    """
    from ..recon.gridrec import GridrecPlan

    shifts, vertical = motion
    indices = blocks[block]
    store = open_cached(path)
    center = float(info["center_offset"])
    axis = np.array([slice_center(info, i, store.n) - center for i in range(store.n)])
    key = (path, name, center, shifts.tobytes(), axis.tobytes(), threads)
    if key not in _PLAN:
        _PLAN.clear()
        geometry = with_center(store.geometry, center)
        _PLAN[key] = GridrecPlan(geometry, shifts, threads=threads, axis_range=float(np.abs(axis).max()))
    images = _PLAN[key](read_straight(store, indices, vertical), axis=axis[indices] if axis.any() else None)
    for index, image in zip(indices, images):
        store.write_reconstruction(name, index, image, shifts.astype(np.float32))
    return block


def _run_gridrec(store: DataStore, name: str, info: dict, motion: tuple, slices: tuple, *run: Any) -> None:
    """The pending slices in blocks of two per thread (``motion``: shifts, vertical; ``slices``: the pending ones
    and the number made by an earlier run, counted on the bar in blocks; ``run``: workers etc.)."""
    pending, finished = slices
    from ..recon.gridrec import backend_label, select_backend

    workers, scheduler, progress = run
    threads = worker_threads(workers) if workers and not scheduler else usable_cpus()
    blocks = [pending[i : i + 2 * threads] for i in range(0, len(pending), 2 * threads)]
    _record_engine(store, name, backend_label(select_backend("auto")))
    task = partial(_gridrec_block, str(store.path), name, dict(info), motion, threads, blocks)
    fan = {"workers": workers, "scheduler": scheduler, "progress": progress, "unit": "block"}
    run_tasks(task, range(len(blocks)), desc=name, done=-(-finished // (2 * threads)), **fan)


def _record_engine(store: DataStore, name: str, label: str) -> None:
    """Add ``label`` to the engines recorded with ``name`` (a resumed run may use another)."""
    engines = list(store.recons.note(name, "engine") or [])
    if label not in engines:
        store.recons.set_note(name, "engine", [*engines, label])


def reconstruct_stack(
    path: str | os.PathLike[str],
    *,
    method: str = "fbp",
    center: float | str = "auto",
    motion_slices: str | None = None,
    binning: int = 8,
    coarse_iter: int = 8,
    refine: tuple[int, ...] | None = None,
    model: tuple[int, int] | None = None,
    eta: Any = "auto",
    name: str | None = None,
    overwrite: bool = False,
    workers: int = 2,
    scheduler: str | None = None,
    progress: bool = True,
    engine: str = "auto",
) -> str:
    """Estimate one motion and axis for a stack and reconstruct every slice with them (resumable).

    Parameters
    ----------
    path : path
        Data-set store (an imported scan, or a simulated parallel-beam store).
    method : {"fbp", "gridrec", "dremel", "resesop"}
        Slice reconstruction with the stack's motion (:data:`STACK_METHODS`). ``"gridrec"``: FBP in
        Fourier space (:class:`~nanoct.recon.gridrec.GridrecPlan`, slices in blocks of two per
        thread); ``"fbp"`` runs it too where it is usable (``engine``); both hold the motion
        fixed. ``"dremel"``: Dremel with the motion held fixed on a simulation; on measured data
        (:func:`~nanoct.recon.measured.looks_measured`) Dremel starts from it and refines it per
        slice. ``"resesop"`` runs :func:`~nanoct.recon.resesop.resesop` (20 sweeps at most,
        matrix-free rays for large slices): on a simulation on the sinogram with every view moved
        back by its shift (:func:`shift_corrected`); on measured data its model carries the motion,
        with ``"auto"`` eta Dremel's per-slice refinement of it. Each slice's shifts row holds the
        motion it was reconstructed with (the refined one where Dremel refined it, detector
        pixels); the stack's motion is the reconstruction's ``shared_shifts``.
    center : float or "auto"
        Rotation-axis offset in the store's detector pixels, or ``"auto"``: estimated with the motion.
    motion_slices : str, optional
        ``"auto"`` (default: up to 4 slices spread over the stack), ``"all"`` or ``"0,5,9"``.
    binning, coarse_iter, refine
        See :func:`~nanoct.motion.stack.estimate_stack_motion`.
    model : (int, int), optional
        Replace the estimate by its smooth model (polynomial degree, rotation harmonics).
    eta : "auto", float or array_like of shape (K,)
        RESESOP's model-uncertainty level per view (only with ``method="resesop"``). ``"auto"``:
        per view, half the largest ``|y_c - A x_0|`` of the shift-corrected sinogram ``y_c`` and
        its FBP ``x_0`` (:data:`AUTO_ETA_FRACTION`; on measured data ``x_0`` is Dremel's image and
        ``y_c`` the views read with Dremel's motion, :func:`_resesop_slice`); a number: that
        level for every view.
    name : str, optional
        Output name (default :func:`~nanoct.names.stack_name`).
    overwrite : bool
        Delete an existing reconstruction of that name first (its motion too).
    workers, scheduler, progress
        See :func:`nanoct.core.fanout.run_tasks`.
    engine : {"auto", "gridrec", "backprojection"}
        How ``method="fbp"`` runs (:func:`fbp_engine`); recorded with the reconstruction as the
        note ``engine`` (a list: a resumed run may add another).

    Returns
    -------
    str
        The output name.

    Raises
    ------
    NanoctError
        For a fan-beam store, an unknown method, bad slices, a bad ``eta``, or a name made with
        other settings.
    """
    if method not in STACK_METHODS:
        raise NanoctError(f"--method {method!r} is not a stack method; use one of {', '.join(STACK_METHODS)}")
    use_gridrec = method == "gridrec" or (method == "fbp" and fbp_engine(engine) == "gridrec")
    if method == "gridrec":
        fbp_engine("gridrec")  # a usable library, checked before anything is written
    store = DataStore.open(path, mode="r+")
    if store.geometry.kind != "parallel":
        raise NanoctError(f"{store.path} is a fan-beam data set; nanoct stack handles parallel-beam scans")
    if center != "auto" and not isinstance(center, (int, float)):
        raise NanoctError(f"--center-offset {center!r}: give a number of detector pixels or 'auto'")
    params = {
        "method": method,
        "center": center if center == "auto" else float(center),
        "motion_slices": _motion_slices(store, motion_slices),
        "binning": int(binning),
        "coarse_iter": int(coarse_iter),
        "refine": None if refine is None else [int(b) for b in refine],
        "model": None if model is None else [int(v) for v in model],
    }
    if method == "resesop":
        params["eta"] = _check_eta(eta, store.geometry.sino_shape[0])
    name = name or stack_name(method)
    with exclusive(store.path, name, f"reconstructions/{name} of {store.path}"):
        if overwrite:
            store.delete_reconstruction(name)
        remedy = (
            f"replace it (nanoct stack ... --name {name} --overwrite) or write this one under another name "
            "(nanoct stack ... --name NEW_NAME)"
        )
        store.prepare_reconstruction(name, params, shifts=True, remedy=remedy)
        if store.recons.motion_info(name) is None:
            _estimate(store, name, params, progress)
        info = store.recons.motion_info(name)
        shifts = store.recons.shared_shifts(name).astype(np.float64)
        vertical = np.asarray(info.get("vertical", np.zeros(shifts.size)), dtype=np.float64)
        pending = [int(i) for i in np.flatnonzero(store.done & ~store.reconstruction_done(name))]
        finished = int(store.done.sum()) - len(pending)  # slices made by an earlier run
        if use_gridrec:
            _run_gridrec(store, name, info, (shifts, vertical), (pending, finished), workers, scheduler, progress)
            return name
        if method == "fbp":
            _record_engine(store, name, "backprojection")
        task = partial(_reconstruct_slice, str(store.path), name, method, info, params.get("eta"), shifts, vertical)
        record = shift_check_recorder(store, name)
        fan = {"workers": workers, "scheduler": scheduler, "progress": progress, "unit": "slice"}
        run_tasks(task, pending, desc=name, on_result=record, done=finished, **fan)
        return name
