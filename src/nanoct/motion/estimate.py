"""One entry point for the 3-D motion of a measured scan: which estimator runs, and why.

:func:`estimate_motion` takes a scan's projections and returns the vertical and horizontal shift
of every view with the rotation axis, and a record of the estimators that ran:

0. for a limited-angle series (no two views 180 degrees apart), a coarse pre-alignment of
   neighbouring frames (:func:`prealign_neighbours`), for jumps of tens of pixels;
1. **vertical** from the views' row profiles (:func:`~nanoct.motion.vertical.vertical_motion`:
   zero where the profiles do not show a significant motion, the reason in
   ``record["vertical_guard"]``); the projections are then moved back vertically
   (:func:`~nanoct.motion.matching.apply_vertical`);
2. **horizontal**, chosen as the method registry chooses solvers, by what the data allow:

   ``centroid``
       where air was found around the object (its open beam removed): the centroid of every
       view, fitted on ``(1, cos phi, sin phi)`` (:func:`~nanoct.motion.center.centroid_motion`);
       no reconstruction, every view counts.
   ``matching``
       where no air is seen (an object wider than the field of view): an autofocus of the motion
       that is slow over the views (:func:`~nanoct.motion.focus.focus_smooth`), projection
       matching from there, reconstruct / reproject / register, coarse to fine
       (:func:`~nanoct.motion.matching.match_projections`), and the autofocus again with the
       axis; no centroid is needed. (Without
       air the views' mass may vary little, a crop inside the sample seeing nearly the same mass
       from every angle, while their centroids mean nothing: on the Diamond K11 crop they gave
       shifts of 11.7 px RMS. ``horizontal="centroid"`` forces them.)
3. **axis** from every estimator that applies (:func:`~nanoct.motion.axis.estimate_axis`) on the
   views moved back by their horizontal shifts, so that the axis goes with the shifts; on the
   ``matching`` path the axis of the last autofocus (``focus``) is used; unless given.

For a limited-angle series the in-plane tilt of the axis on the detector is estimated and undone
first: where air is seen, from the centroid axis of groups of rows
(:func:`~nanoct.motion.axis.limited_angle_tilt`), else from the row profiles
(:func:`~nanoct.motion.vertical.tilt_from_profiles`).

The horizontal shifts are given without the term ``a cos(phi) + b sin(phi)`` (a translation of the
object, which the data do not fix); their constant, if any, goes with the axis found in step 3.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.ndimage as ndi

from ..core.errors import NanoctError
from ..core.geometry import remove_translation
from .axis import AxisEstimate, axis_rows, estimate_axis, limited_angle_tilt, object_rows, remove_air
from .center import centroid_motion, fourier_shift, opposite_pairs
from .focus import focus_smooth
from .matching import apply_vertical, match_projections, views_and_angles
from .registration import register_shifts
from .vertical import row_profiles, tilt_from_profiles, vertical_motion

__all__ = ["HORIZONTAL_ESTIMATORS", "Motion3D", "estimate_motion", "prealign_neighbours", "start_axis"]

#: The horizontal estimators :func:`estimate_motion` chooses from.
HORIZONTAL_ESTIMATORS = ("auto", "centroid", "matching")


@dataclass
class Motion3D:
    """The motion of a scan and how it was found.

    Attributes
    ----------
    horizontal, vertical : ndarray of shape (K,)
        ``d_k`` and ``v_k`` (detector pixels): ``m_k(z, x) = Q_k(z + v_k, x + d_k)``.
    axis : AxisEstimate
        The rotation axis and its estimators (``axis.offset``).
    horizontal_method : str
        ``"centroid"`` or ``"matching"``.
    record : dict
        Why each choice was made (JSON-ready).
    tilt_deg : float
        In-plane tilt of the axis on the detector (degrees, the sign of
        :class:`~nanoct.motion.axis.AxisTilt`), undone before the shifts were estimated; 0 when not
        estimated.
    """

    horizontal: np.ndarray
    vertical: np.ndarray
    axis: AxisEstimate
    horizontal_method: str
    record: dict[str, Any] = field(default_factory=dict)
    tilt_deg: float = 0.0


def prealign_neighbours(projections: np.ndarray, *, max_shift: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Coarse ``(v_k, d_k)`` for jumps of tens of pixels: each view registered to the one before it.

    Consecutive views of a fine angular step look alike, so the 2-D cross-correlation of view
    ``k`` with view ``k - 1`` (:func:`~nanoct.motion.registration.register_shifts`, high-pass of 4
    pixels) gives the jump between them; the running sum is the coarse motion (with zero mean).
    The object's own rotation between the views adds a small bias to every jump, which the
    running sum carries along: the fine estimators correct it.

    Parameters
    ----------
    projections : ndarray of shape (K, R, L)
        In acquisition order.
    max_shift : float, optional
        Largest jump searched (default a third of the detector in each direction).

    Returns
    -------
    vertical, horizontal : ndarray of shape (K,)
    """
    proj = np.asarray(projections, dtype=np.float64)
    limit = (proj.shape[1] / 3, proj.shape[2] / 3) if max_shift is None else (max_shift, max_shift)
    jumps = register_shifts(proj[:-1], proj[1:], sigma=4.0, margin=(4, 4), max_shift=limit)
    steps = np.concatenate([np.zeros((1, 2)), np.cumsum(jumps, axis=0)])
    steps -= steps.mean(axis=0)
    return steps[:, 0], steps[:, 1]


def _match_and_focus(
    straight: np.ndarray, phi: np.ndarray, start: float, fit_axis: bool, record: dict[str, Any]
) -> tuple[np.ndarray, float]:
    """Horizontal shifts without a centroid: autofocus of the slow part, projection matching, autofocus again.

    :func:`~nanoct.motion.focus.focus_smooth` finds the motion that is slow over the views (which
    projection matching does not see), :func:`~nanoct.motion.matching.match_projections` the fast
    part from there, and a second autofocus corrects the slow part matching disturbed (with
    ``fit_axis``, also the constant: the axis of the sharpest slices). Returns the shifts and the
    axis they go with: ``start`` less the constant the last autofocus added, in the gauge of
    ``(1, cos phi, sin phi)``. An autofocus that ran to its bounds is not used
    (:class:`~nanoct.motion.focus.FocusResult` ``accepted``); ``record`` gets which were.
    """
    first = focus_smooth(straight, phi, start)
    matched = match_projections(straight, phi, start, horizontal=first.horizontal)
    final = focus_smooth(straight, phi, start, matched.horizontal, axis=fit_axis)
    d = final.horizontal
    basis = np.stack([np.ones_like(phi), np.cos(phi), np.sin(phi)], axis=1)
    constant = float(np.linalg.lstsq(basis, d, rcond=None)[0][0]) if fit_axis and final.accepted else 0.0
    record.update(accepted=[first.accepted, final.accepted], start_axis=start, axis=start - constant)
    return d, start - constant


def estimate_motion(
    projections: Any,
    angles: Any,
    *,
    center: float | None = None,
    horizontal: str = "auto",
    vertical: bool = True,
    prealign: bool | str = "auto",
    tilt: bool | str = "auto",
    progress: Callable[[str], Any] | None = None,
) -> Motion3D:
    """Vertical and horizontal shift per view and the rotation axis (see the module docstring).

    Parameters
    ----------
    projections : array_like of shape (K, R, L)
        Line integrals (after flat/dark correction and ``-log``), one projection per view.
    angles : array_like of shape (K,)
        View angles in radians.
    center : float, optional
        Axis offset (detector pixels) to use as given.
    horizontal : {"auto", "centroid", "matching"}
        Horizontal estimator (``"auto"``: centroid where air is seen, else matching).
    vertical : bool
        Estimate the vertical shifts (else zero).
    prealign : bool or "auto"
        Start from :func:`prealign_neighbours` (jumps of tens of pixels between frames);
        ``"auto"``: for a limited-angle series (no two views 180 degrees apart), where frames
        of a tilt series are acquired in angular order.
    tilt : bool or "auto"
        Estimate the in-plane tilt of the axis and undo it first (on a limited-angle series with
        air around the object from the centroid axis of groups of rows, else from the row profiles,
        :func:`~nanoct.motion.vertical.tilt_from_profiles`; ``record["tilt_method"]`` says which);
        ``"auto"``: for a limited-angle series (a scan with opposite views has
        :func:`~nanoct.motion.axis.axis_tilt`).
    progress : callable, optional
        Called with the name of each finished stage.

    Returns
    -------
    Motion3D
    """
    proj, phi = views_and_angles(projections, angles)
    if horizontal not in HORIZONTAL_ESTIMATORS:
        raise NanoctError(f"horizontal estimator {horizontal!r}: choose one of {', '.join(HORIZONTAL_ESTIMATORS)}")
    tick = progress or (lambda stage: None)
    if prealign == "auto":
        prealign = not opposite_pairs(phi)[0].size
    v0, d0 = prealign_neighbours(proj) if prealign else (np.zeros(phi.size), np.zeros(phi.size))
    if prealign:
        proj = np.stack([ndi.shift(p, (a, b), order=1, mode="nearest") for p, a, b in zip(proj, v0, d0)])
    limited = not opposite_pairs(phi)[0].size
    tilt_deg, tilt_method = _tilt(proj, phi, limited) if (limited if tilt == "auto" else tilt) else (0.0, "none")
    if tilt_deg:
        proj = apply_vertical(proj, np.zeros(phi.size), tilt_deg)
    guard: dict[str, Any] = {"note": "vertical motion not estimated"}
    v = np.zeros(phi.size)
    if vertical and proj.shape[1] >= 4:
        found = vertical_motion(row_profiles(proj))
        v, guard = found.shifts, found.to_dict()
    straight = apply_vertical(proj, v) if np.any(v) else proj
    tick("vertical")
    sinos = straight.transpose(1, 0, 2)
    clean, air = remove_air(sinos)
    rows = object_rows(clean)
    _, d_centroid, spread = centroid_motion(clean[rows] if rows.any() else clean, phi)
    method = horizontal if horizontal != "auto" else ("centroid" if air else "matching")
    record: dict[str, Any] = {"vertical": "row profiles" if vertical else "none", "horizontal": method}
    record.update(air_removed=air, centroid_rows=int(rows.sum()), mass_spread=float(spread), prealign=bool(prealign))
    record.update(tilt_deg=tilt_deg, tilt_method=tilt_method, vertical_guard=guard)
    if method == "centroid":
        d = d_centroid
    else:
        start = start_axis(sinos[axis_rows(sinos.shape[0])], phi) if center is None else float(center)
        record["focus"] = {}
        d, focus_axis = _match_and_focus(straight, phi, start, center is None, record["focus"])
    d = remove_translation(d, phi)
    tick("horizontal")
    # the axis with the views moved back by their shifts: the estimators then see a still object
    rows_axis = axis_rows(sinos.shape[0])
    corrected = np.stack([fourier_shift(sino, d) for sino in sinos[rows_axis]])
    focused = method == "matching" and center is None and record["focus"]["accepted"][1]
    try:
        axis = estimate_axis(corrected, phi)
    except NanoctError:
        if not (focused or center is not None):
            raise
        axis = AxisEstimate(0.0, {}, (), ("no axis estimator applies to the corrected views",), air)
    if focused:
        d = d - (start - focus_axis)  # the pair (start, d) as (focus_axis, d less the constant the focus found)
        note = "focus: the axis of the sharpest slices with the matched shifts (no opposite view or centroid trusted)"
        estimates = {**axis.estimates, "focus": focus_axis}
        axis = AxisEstimate(focus_axis, estimates, ("focus",), (*axis.notes, note), axis.air_removed)
    if center is not None:
        axis = AxisEstimate(float(center), {**axis.estimates, "given": float(center)}, ("given",), axis.notes, air)
    tick("axis")
    d = remove_translation(d + d0, phi)
    v = v + v0 if vertical else v
    return Motion3D(d, v - v.mean(), axis, method, record, tilt_deg)


def start_axis(sinos: np.ndarray, phi: np.ndarray) -> float:
    """The axis projection matching starts from: the estimators' (:func:`estimate_axis`), or the detector
    centre where none applies (the autofocus after matching fits the axis).

    Parameters
    ----------
    sinos : ndarray of shape (S, K, L)
        Line integrals of a few rows.
    phi : ndarray of shape (K,)
        View angles in radians.

    Returns
    -------
    float
        Axis offset from the detector centre (pixels).
    """
    try:
        return estimate_axis(sinos, phi).offset
    except NanoctError:
        return 0.0


def _tilt(proj: np.ndarray, phi: np.ndarray, limited: bool) -> tuple[float, str]:
    """The axis tilt and how it was found (0 for too few rows).

    A limited-angle series with air around the object: the line through the centroid axes of
    groups of rows, the views rotated back until it is vertical
    (:func:`~nanoct.motion.axis.limited_angle_tilt`), the views moved back by their vertical
    shifts (row profiles) first. Otherwise, or where that finds too few rows holding
    the object: the row profiles of the views with their open beam removed
    (:func:`~nanoct.motion.vertical.tilt_from_profiles`).
    """
    if proj.shape[1] < 24:
        return 0.0, "none"
    sinos = proj.transpose(1, 0, 2)
    clean, air = remove_air(sinos)
    if limited and air:
        v = vertical_motion(row_profiles(proj)).shifts
        straight = apply_vertical(proj, v) if np.any(v) else proj
        try:
            return limited_angle_tilt(straight, phi)[0].tilt_deg, "centroid axis of row groups"
        except NanoctError:
            pass
    return tilt_from_profiles(clean.transpose(1, 0, 2))[0], "row profiles"
