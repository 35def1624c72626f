"""One entry point for the 3-D motion of a measured scan: which estimator runs, and why.

:func:`estimate_motion` takes a scan's projections and returns the vertical and horizontal shift
of every view with the rotation axis, and a record of the estimators that ran:

1. **vertical** from the views' row profiles (:func:`~nanoct.motion.vertical.vertical_shifts`);
   the projections are then moved back vertically
   (:func:`~nanoct.motion.matching.apply_vertical`);
2. **axis** from every estimator that applies, their median
   (:func:`~nanoct.motion.axis.estimate_axis`), unless given;
3. **horizontal**, chosen as the method registry chooses solvers, by what the data allow:

   ``centroid``
       where air was found around the object (its open beam removed): the centroid of every
       view, fitted on ``(1, cos phi, sin phi)`` (:func:`~nanoct.motion.center.centroid_motion`);
       no reconstruction, every view counts.
   ``matching``
       where no air is seen (an object wider than the field of view): projection matching,
       reconstruct / reproject / register, coarse to fine
       (:func:`~nanoct.motion.matching.match_projections`), which needs no centroid.

The horizontal shifts are given without the term ``a cos(phi) + b sin(phi)`` (a translation of the
object, which the data do not fix); the centroid's have no constant either (it is the axis), the
matching's keep theirs (a correction of the axis it was given).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from ..recon.shared import remove_translation
from .axis import AxisEstimate, axis_rows, estimate_axis, remove_air
from .center import centroid_motion
from .matching import apply_vertical, match_projections
from .vertical import row_profiles, vertical_shifts

__all__ = ["HORIZONTAL_ESTIMATORS", "Motion3D", "estimate_motion"]

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
    """

    horizontal: np.ndarray
    vertical: np.ndarray
    axis: AxisEstimate
    horizontal_method: str
    record: dict[str, Any] = field(default_factory=dict)


def estimate_motion(
    projections: Any,
    angles: Any,
    *,
    center: float | None = None,
    horizontal: str = "auto",
    vertical: bool = True,
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
    progress : callable, optional
        Called with the name of each finished stage.

    Returns
    -------
    Motion3D
    """
    proj = np.asarray(projections, dtype=np.float32)
    phi = np.asarray(angles, dtype=np.float64)
    if proj.ndim != 3 or proj.shape[0] != phi.size:
        raise NanoctError(f"projections of shape {proj.shape} do not match {phi.size} angles (views, rows, columns)")
    if horizontal not in HORIZONTAL_ESTIMATORS:
        raise NanoctError(f"horizontal estimator {horizontal!r}: choose one of {', '.join(HORIZONTAL_ESTIMATORS)}")
    tick = progress or (lambda stage: None)
    v = vertical_shifts(row_profiles(proj)) if vertical and proj.shape[1] >= 4 else np.zeros(phi.size)
    straight = apply_vertical(proj, v) if np.any(v) else proj
    tick("vertical")
    sinos = straight.transpose(1, 0, 2)
    axis = estimate_axis(sinos[axis_rows(sinos.shape[0])], phi)
    if center is not None:
        estimates = {**axis.estimates, "given": float(center)}
        axis = AxisEstimate(float(center), estimates, ("given",), axis.notes, axis.air_removed)
    tick("axis")
    method = horizontal if horizontal != "auto" else ("centroid" if axis.air_removed else "matching")
    record: dict[str, Any] = {"vertical": "row profiles" if vertical else "none", "horizontal": method}
    if method == "centroid":
        clean, air = remove_air(sinos)
        mass = clean.sum(axis=2).min(axis=1)
        rows = mass > 0.2 * max(float(mass.max()), 0.0)
        _, d, spread = centroid_motion(clean[rows] if rows.any() else clean, phi)
        record.update(air_removed=air, centroid_rows=int(rows.sum()), mass_spread=float(spread))
    else:
        d = match_projections(straight, phi, axis.offset, progress=lambda stage: None).horizontal
        record["why"] = "no air around the object: centroids do not hold" if horizontal == "auto" else "requested"
    d = remove_translation(d, phi)
    tick("horizontal")
    return Motion3D(d, v, axis, method, record)
