"""The rotation axis of a measured scan from several independent estimators, and their consensus.

A measured scan rarely has air at zero absorbance: after flat/dark correction the open beam of
Diamond I13-2 scan 24737 reads a transmission of about 0.67, an absorbance of about 0.4 over the
whole detector. To a centroid that is an object as wide as the detector, centred on it, and it
pulls every view's centroid (and so the axis) towards the detector centre; the mirror match of
opposite views sees the same box. :func:`remove_air` therefore first fits each view's open beam
to its air pixels (:func:`nanoct.preprocess.openbeam.estimate_open_beam`) and subtracts its
absorbance; data whose outer columns already read zero within the noise count as air seen too
(:func:`air_at_zero`: at a noise of a few per cent the open-beam fit finds no flat columns). Where
no air is seen (an object wider than the field of view) the data are used as they are and the
centroid is not trusted.

The estimators (each in detector pixels from the detector centre, positive to the right):

``mirror``
    Every pair of views 180 degrees apart (first and last of a 180-degree scan, all pairs of a
    360-degree or interlaced scan), the second mirrored and matched to the first by sub-pixel
    cross-correlation (:func:`nanoct.motion.center.fit_center`).
``vo``
    Algotom's ``find_center_vo`` (Vo et al., Opt. Express 22, 19078, 2014: the double-wedge
    energy of the sinogram joined to its mirror) on the views of one half turn, median over the
    rows; only where the views cover at least 179 degrees. A half turn of more than
    :data:`VO_FULL_VALUES` values a row (2048 columns and 1800 views: 30 s a row in algotom's own
    search) is searched with the same metric coarse to fine on binned columns and averaged
    views, on at most :data:`VO_MAX_ROWS` rows (:func:`_vo_bounded`: about 1 s a row).
``centroid``
    The constant of the least-squares fit of the views' centroids on ``(1, cos phi, sin phi)``
    (:func:`nanoct.motion.center.centroid_motion`) over the rows that hold the object; trusted only
    when the air was removed and the views' total mass varies by at most ``centroid_tolerance``.
``sharpness``
    Only when none of the above applies (a limited-angle tilt series): the offset that minimises
    the total variation of Hann-filtered FBP slices over their L2 norm inside the field of view (a
    wrong axis doubles every edge into arcs), over a 1-pixel grid refined to 0.1 pixel (of
    columns binned to at most :data:`SHARPNESS_MAX_COLS`). A best value
    at the grid's bound is no minimum and is not used; the untrusted centroid is then the axis,
    with a warning, and without it no estimator applies (an error asks for the offset).

The axis is the estimate the data support: each proposed one (the estimators that apply, and
the centroid, trusted or not) is scored by the held-out misfit of :mod:`nanoct.motion.consistency`
(reconstruct from one half of the views, predict the other, both ways) on the same rows, as a
still object and, for the trusted centroid, with the motion it implies too (the better counts).
Estimates that fit worse than the best beyond the score's noise are rejected; of those kept the
estimators' own rule picks: the trusted centroid, else the median of the trusted others, else the
best score (where the mirror match and ``find_center_vo`` disagree by 144 px on an object wider
than the field of view, ``find_center_vo`` is rejected and the mirror's kept). Kept estimates
more than :data:`TIE_PX` from the axis are named in the notes and the estimate is marked
undecided. Scans of fewer than :data:`MIN_SCORED_VIEWS` views, and limited-angle series (less
than a half turn: no mirror pair and no ``find_center_vo``), are not scored and keep the
estimators' own rule (on a +-60 degree series of a phantom wider than the detector the score
preferred the untrusted centroid, 0.84 px off, to the sharpness, 0.3 px off). When the
estimators differ by more than 0.5 pixel (the usual standard of a beamline's quality check) the
estimate carries a warning: motion, or a wrong axis.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from ..core.geometry import Geometry
from ..recon.stack import corrected_fbp
from .center import centroid_motion, fit_center, opposite_pairs
from .matching import apply_vertical, extend_edges

__all__ = [
    "AGREEMENT_PX",
    "AIR_BAND",
    "CENTROID_TOLERANCE",
    "MAX_ABSORBANCE",
    "MAX_AIR_FRACTION",
    "AxisEstimate",
    "AxisTilt",
    "air_at_zero",
    "axis_rows",
    "axis_tilt",
    "estimate_axis",
    "limited_angle_tilt",
    "remove_air",
]

#: Estimators further apart than this (pixels) make the estimate carry a warning.
AGREEMENT_PX = 0.5

#: Largest relative spread of the views' total mass for which the centroid is trusted.
CENTROID_TOLERANCE = 0.01

#: Where more than this fraction of a view's pixels reads as air, the "air" is taken for a flat,
#: low-contrast object (a crop inside the sample, Diamond K11 18014: every pixel within the band).
MAX_AIR_FRACTION = 0.9

#: A half turn of at most this many values per row (views x columns) goes to algotom's
#: ``find_center_vo`` as it is (every vendored real scan); a larger one is searched coarse to
#: fine on reduced data (:func:`_vo_bounded`) ...
VO_FULL_VALUES = 2**21

#: ... on views averaged to at most this many values per row, ...
VO_FINE_VALUES = 2**20

#: ... and on at most this many of the rows given.
VO_MAX_ROWS = 4

#: The sharpness search (limited-angle series) scores rows of at most this many columns; wider
#: rows are binned to it (:func:`_sharpness`).
SHARPNESS_MAX_COLS = 512

#: Scans of fewer views keep the old rule (the centroid where trusted, else the median of the others):
#: the held-out score needs two halves of at least four views.
MIN_SCORED_VIEWS = 8

#: Estimates closer than this (pixels) to the chosen one are not reported as undecided against it.
TIE_PX = 0.25

#: Columns on each side of the detector that :func:`air_at_zero` reads.
AIR_BAND = 8

#: Line integrals whose 99th percentile exceeds this (a transmission of 2e-9, beyond the range of
#: X-ray and neutron detectors) are in other units, e.g. the counts of a STEM HAADF tilt series
#: imported with ``--line-integrals``: :func:`remove_air` seeks their air on the data divided by
#: that percentile.
MAX_ABSORBANCE = 20.0


@dataclass(frozen=True)
class AxisEstimate:
    """The axis and how it was found.

    Attributes
    ----------
    offset : float
        Rotation axis minus the detector centre (detector pixels): the median of ``used``.
    estimates : dict of str to float
        Every estimator that ran, with its value.
    used : tuple of str
        The estimators the axis comes from: of those the held-out score keeps, the trusted
        centroid alone, else the trusted others, else the best-scored one (see the module docstring).
    notes : tuple of str
        Why an estimator was left out, and a warning when the used ones disagree.
    air_removed : bool
        Whether air was seen around the object: an open beam found and removed first, or the
        detector's outer columns at zero within the noise (:func:`air_at_zero`).
    scores : dict of str to float
        Each scored estimate's held-out misfit (:func:`~nanoct.motion.consistency.heldout_misfit`;
        empty where the views are not scored).
    decided : bool
        ``False`` where the score cannot tell the chosen estimate from another one.
    """

    offset: float
    estimates: dict[str, float]
    used: tuple[str, ...]
    notes: tuple[str, ...] = field(default_factory=tuple)
    air_removed: bool = False
    scores: dict[str, float] = field(default_factory=dict)
    decided: bool = True

    @property
    def spread(self) -> float:
        """Largest minus smallest of the used estimates (pixels)."""
        values = [self.estimates[name] for name in self.used]
        return float(max(values) - min(values)) if values else 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record (for a store's provenance)."""
        return {
            "offset": self.offset,
            "estimates": dict(self.estimates),
            "used": list(self.used),
            "spread": self.spread,
            "notes": list(self.notes),
            "air_removed": self.air_removed,
            "scores": dict(self.scores),
            "decided": self.decided,
        }


def axis_rows(n_rows: int, count: int = 8) -> np.ndarray:
    """The rows (slices) the axis is estimated from: ``count`` spread evenly over the detector."""
    return np.unique(np.linspace(0, n_rows - 1, min(count, n_rows)).round().astype(int))


def object_rows(sinograms: np.ndarray, fraction: float = 0.2) -> np.ndarray:
    """Rows of ``(S, K, L)`` sinograms holding the object: every view's mass at least ``fraction`` of the top row's."""
    mass = np.asarray(sinograms).sum(axis=2).min(axis=1)  # (S,): each row's smallest view mass
    return mass > fraction * max(float(mass.max()), 0.0)


def remove_air(sinograms: np.ndarray, *, zero_air: bool = False) -> tuple[np.ndarray, bool]:
    """Line integrals ``(S, K, L)`` less each view's open-beam absorbance, where air is seen.

    Returns the data unchanged and ``False`` when no air is found in some view, or when in the
    median view more than :data:`MAX_AIR_FRACTION` of the pixels read as air. Data in other units
    than absorbance (99th percentile above :data:`MAX_ABSORBANCE`) where no air was found are
    tried again divided by that percentile (the open beam of ``exp(-data)`` is otherwise lost to
    the exponential: on the counts of a STEM tilt series, a background of 22 counts read as a
    transmission of 3e-10), and the absorbance removed is scaled back. With ``zero_air``, data
    whose outer columns read zero within their noise (:func:`air_at_zero`) are returned unchanged
    with ``True`` where the open-beam fit found no air (``nanoct stack`` chooses its centroid path
    so; :func:`~nanoct.motion.estimate.estimate_motion` does not use it).
    """
    sino = np.asarray(sinograms, dtype=np.float64)
    clean, air = _remove_air(sino)
    scale = float(np.percentile(sino, 99)) if sino.size else 0.0
    if not air and scale > MAX_ABSORBANCE:
        clean, air = _remove_air(sino / scale)
        clean = clean * scale if air else sino
    return clean, air or (zero_air and air_at_zero(sino))


def air_at_zero(sinograms: np.ndarray) -> bool:
    """Whether the detector's outer columns read zero absorbance, within the noise, in most views.

    The open-beam estimator (:func:`~nanoct.preprocess.openbeam.estimate_open_beam`) looks for
    flat bright columns in transmission; at a noise of a few per cent per pixel (0.06 in absorbance
    in ``benchmarks/bench_large.py``'s scan) it sees none, although the object lies well inside
    the detector. Here the median of the :data:`AIR_BAND` outermost columns on each side of each
    view is compared with the noise of one pixel (``1.4826 MAD / sqrt(6)`` of the second
    differences along the detector): air is at zero when the median is within three noise
    levels of zero in at least 90 % of the views of every row. An object wider than the detector
    (its absorbance in those columns) or an open beam not removed fails the test.
    """
    sino = np.asarray(sinograms, dtype=np.float64)
    if sino.ndim != 3 or sino.shape[2] < 8 * AIR_BAND:
        return False
    second = np.diff(sino, n=2, axis=2)
    sigma = 1.4826 * float(np.median(np.abs(second - np.median(second)))) / np.sqrt(6)
    edges = np.concatenate([sino[..., :AIR_BAND], sino[..., -AIR_BAND:]], axis=2)
    level = np.median(edges, axis=2)  # (S, K)
    return bool(sigma > 0 and np.all(np.mean(np.abs(level) <= 3 * sigma, axis=1) >= 0.9))


def _remove_air(sino: np.ndarray) -> tuple[np.ndarray, bool]:
    """:func:`remove_air` on absorbance-scaled data."""
    from ..preprocess.openbeam import estimate_open_beam

    with np.errstate(over="ignore"):  # counts below -709 (the overshoot of an interpolation) read as inf
        projections = np.exp(-sino.transpose(1, 0, 2))  # (K, S, L) transmission
    try:
        beam = estimate_open_beam(projections)
    except NanoctError:
        return sino, False
    if np.median(beam.air_fraction) > MAX_AIR_FRACTION:  # a flat, low-contrast object is not air
        return sino, False
    fields = np.stack([beam.field(k) for k in range(projections.shape[0])])  # (K, S, L)
    return sino + np.log(fields).transpose(1, 0, 2), True


def _vo(sino: np.ndarray, phi: np.ndarray) -> float | None:
    """Algotom's ``find_center_vo`` on the views of one half turn, median over the rows.

    A half turn of at most :data:`VO_FULL_VALUES` values per row goes to ``find_center_vo`` as it
    is; a larger one to :func:`_vo_bounded`, whose cost does not grow with the scan.
    """
    from algotom.prep.calculation import find_center_vo

    order = np.argsort(phi)
    start = phi[order[0]]
    half = order[phi[order] <= start + np.pi + 1e-6]  # the view at 180 degrees included
    if np.ptp(phi[half]) < np.deg2rad(179.0) - np.pi / phi.size:
        return None
    n_det = sino.shape[2]
    lo, hi = n_det / 2 - n_det / 4, n_det / 2 + n_det / 4
    if half.size * n_det <= VO_FULL_VALUES:
        rows = [np.ascontiguousarray(row[half]) for row in sino]
        values = [find_center_vo(row, start=lo, stop=hi) - (n_det - 1) / 2 for row in rows]
    else:
        chosen = np.unique(np.linspace(0, sino.shape[0] - 1, min(sino.shape[0], VO_MAX_ROWS)).round().astype(int))
        values = [_vo_bounded(sino[r][half], lo, hi) - (n_det - 1) / 2 for r in chosen]
    return float(np.median(values))


def _vo_bounded(sino_180: np.ndarray, start: float, stop: float) -> float:
    """``find_center_vo``'s search of a large half turn ``(K, L)``, coarse to fine on reduced data.

    Algotom searches every integer centre between ``start`` and ``stop`` on its sinogram binned to
    about 640 columns and then 33 sub-pixel centres on the full sinogram: about 30 s a row at 2048
    columns and 1800 views. Here the same metric (algotom's ``coarse_search_cor`` and
    ``fine_search_cor``) runs on views averaged in groups: integer centres on at most 256 columns
    and 256 views (binned), then one-pixel steps within the binning on the columns binned by 2,
    then quarter pixels within 1 pixel at full width, both on views averaged to at most
    :data:`VO_FINE_VALUES` values (about 1 s a row at that size).
    """
    from algotom.prep.calculation import coarse_search_cor, fine_search_cor

    def reduced(factor: int, values: int) -> np.ndarray:
        """Columns binned by ``factor``, views averaged in groups to at most ``values`` values."""
        cols = sino_180[:, : sino_180.shape[1] // factor * factor]
        cols = cols.reshape(cols.shape[0], -1, factor).mean(axis=2)
        group = max(1, -(-cols.size // values))
        return cols[: cols.shape[0] // group * group].reshape(-1, group, cols.shape[1]).mean(axis=1)

    factor = max(1, -(-sino_180.shape[1] // 256))
    coarse = coarse_search_cor(reduced(factor, 256 * 256), start / factor, stop / factor, denoise=True)
    centre = coarse * factor + (factor - 1) / 2  # the binned column's centre in full-width columns
    if factor > 2:
        half = fine_search_cor(reduced(2, VO_FINE_VALUES // 2), (centre - 0.5) / 2, factor / 2, 0.5, denoise=True)
        centre = 2 * half + 0.5
    return float(fine_search_cor(reduced(1, VO_FINE_VALUES), centre, 1.0, 0.25, denoise=True))


def _sharpness(sino: np.ndarray, phi: np.ndarray) -> tuple[float, bool]:
    """The offset whose Hann FBP slices have the least total variation relative to their norm, and
    whether that is a minimum inside the search range (not at its bound).

    Searched on a 1-pixel grid over a quarter of the detector's half width each side of its
    centre, refined on a 0.1-pixel grid. A best value at either end of the grid is no minimum:
    on I13 24737 cut to its first 120 degrees the score falls all the way to the bound (+20 px,
    where the axis lies at +6.2), so it is returned flagged rather than trusted. The rows are
    extended smoothly by half their width each side (:func:`~nanoct.motion.matching.extend_edges`:
    an object wider than the field of view leaves no edge artefact) and scored inside the disc of
    radius 0.45 L, as total variation over the L2 norm: a wrong axis turns edges into arcs and
    doubles them, which adds variation, while the norm of an FBP image barely depends on the axis
    (each view fills its own line of the Fourier plane). Dividing by the L1 norm instead rewards the
    wrong axis on limited-angle data, whose smeared slices have the larger L1 norm. Rows wider than
    :data:`SHARPNESS_MAX_COLS` are scored with their columns binned to at most that many (the
    central columns a whole number of bins): the steps scale with the binning.
    """
    n_det = sino.shape[2]
    if n_det > SHARPNESS_MAX_COLS:  # scored on binned columns: the cost of a 2048-column scan is that of 512
        factor = -(-n_det // SHARPNESS_MAX_COLS)
        kept = n_det // factor * factor
        first = (n_det - kept) // 2
        binned = sino[..., first : first + kept].reshape(*sino.shape[:2], -1, factor).mean(axis=3)
        offset, found = _sharpness(binned, phi)
        return factor * offset + first + (kept - 1) / 2 - (n_det - 1) / 2, found
    pad = n_det // 2
    width = n_det + 2 * pad
    grid = np.arange(width) - (width - 1) / 2
    disc = np.hypot(*np.meshgrid(grid, grid, indexing="ij")) < 0.45 * n_det
    inner = disc[:-1, :-1]
    extended = extend_edges(sino, pad)

    def score(offset: float) -> float:
        geometry = Geometry.from_angles(phi, width, width, center_offset=offset)
        total = 0.0
        for row in extended:
            image = corrected_fbp(geometry, row, filter="hann").astype(np.float64)
            gradient = np.hypot(np.diff(image, axis=0)[:, :-1], np.diff(image, axis=1)[:-1, :])
            total += gradient[inner].sum() / max(float(np.sqrt((image[disc] ** 2).sum())), 1e-12)
        return total

    coarse = np.arange(-(n_det // 8), n_det // 8 + 1, 1.0)
    index = int(np.argmin([score(c) for c in coarse]))
    if index in (0, coarse.size - 1):
        return float(coarse[index]), False
    fine = coarse[index] + np.arange(-1.0, 1.0001, 0.1)
    return float(fine[int(np.argmin([score(c) for c in fine]))]), True


def estimate_axis(sinograms: Any, angles: Any, *, centroid_tolerance: float = CENTROID_TOLERANCE) -> AxisEstimate:
    """Rotation-axis offset from every estimator that applies (see the module docstring).

    Parameters
    ----------
    sinograms : array_like of shape (S, K, L) or (K, L)
        Line integrals of a few rows (e.g. :func:`axis_rows`).
    angles : array_like of shape (K,)
        View angles in radians.
    centroid_tolerance : float
        Largest relative spread of the views' mass for which the centroid is trusted.

    Returns
    -------
    AxisEstimate

    Raises
    ------
    NanoctError
        For data that are not finite or shapes that do not match, or views to which no estimator
        applies (limited-angle views without a sharpness minimum or a centroid).
    """
    sino = np.asarray(sinograms, dtype=np.float64)
    sino = sino[None] if sino.ndim == 2 else sino
    phi = np.asarray(angles, dtype=np.float64)
    if sino.ndim != 3 or sino.shape[1] != phi.size:
        raise NanoctError(f"sinograms of shape {sino.shape} do not match {phi.size} angles")
    if not np.isfinite(sino).all():
        raise NanoctError("the sinograms hold NaN or infinite values; correct or drop those views first")
    clean, air = remove_air(sino, zero_air=True)
    estimates: dict[str, float] = {}
    notes: list[str] = []
    used: list[str] = []
    if opposite_pairs(phi)[0].size:
        estimates["mirror"] = fit_center(clean, phi, max_offset=sino.shape[2] / 4)
        used.append("mirror")
    else:
        notes.append("mirror: no two views 180 degrees apart")
    vo = _vo(clean, phi)
    if vo is None:
        notes.append("vo: the views cover less than 180 degrees")
    else:
        estimates["vo"] = vo
        used.append("vo")
    shifts = _centroid(clean, phi, air, centroid_tolerance, estimates, used, notes)
    if not used:
        estimates["sharpness"], found = _sharpness(clean[:4], phi)
        if found:
            used.append("sharpness")
        else:
            notes.append(
                f"sharpness: not used (no minimum within +-{sino.shape[2] // 8} px: the best value lies at the "
                "search bound)"
            )
    if not used and "centroid" in estimates:
        used.append("centroid")
        notes.append("warning: the axis comes from the centroid alone, which is not trusted here; check it")
    if not used:
        raise NanoctError(
            "no estimator of the rotation axis applies to these views (" + "; ".join(notes) + "); give the axis "
            "offset in pixels (--center-offset)"
        )
    spread = float(np.ptp([estimates[name] for name in used]))
    if spread > AGREEMENT_PX:
        values = ", ".join(f"{name} {estimates[name]:+.2f}" for name in used)
        notes.append(f"warning: the axis estimators disagree by {spread:.2f} px ({values}); motion or a wrong axis")
    if phi.size < MIN_SCORED_VIEWS or not {"mirror", "vo"} & set(estimates):
        notes.append(f"consistency: not scored (fewer than {MIN_SCORED_VIEWS} views, or less than a half turn)")
        chosen = _own_rule(used)
        offset = float(np.median([estimates[name] for name in chosen]))
        return AxisEstimate(offset, estimates, tuple(chosen), tuple(notes), air)
    scores, kept = _scored(clean, phi, estimates, {"centroid": shifts} if "centroid" in used else {}, used)
    chosen = _own_rule([name for name in used if name in kept]) or [min(scores, key=scores.__getitem__)]
    offset = float(np.median([estimates[name] for name in chosen]))
    rejected = [name for name in used if name not in kept]
    undecided = [name for name in kept if name not in chosen and abs(estimates[name] - offset) > TIE_PX]
    if rejected:
        notes.append(f"consistency: {', '.join(rejected)} rejected (the held-out views fit worse beyond the noise)")
    if undecided:
        notes.append(f"consistency: the data cannot tell {', '.join(undecided)} from the chosen axis")
    return AxisEstimate(offset, estimates, tuple(chosen), tuple(notes), air, scores, not undecided)


def _own_rule(names: list[str]) -> list[str]:
    """The estimators' own choice among ``names``: the trusted centroid alone, else all (their median)."""
    return ["centroid"] if "centroid" in names else names


def _scored(
    clean: np.ndarray,
    phi: np.ndarray,
    estimates: dict[str, float],
    motions: dict[str, np.ndarray | None],
    used: list[str],
) -> tuple[dict[str, float], list[str]]:
    """Each proposed estimate's held-out misfit (:mod:`~nanoct.motion.consistency`), and those it keeps.

    Proposed: the estimators that apply and the centroid, trusted or not (the sharpness only where
    it found a minimum). Each is scored as a still object and, where it comes with a motion (the
    trusted centroid's shifts), with that motion too; the better of the two counts. Kept: the best
    and those not worse than it beyond the score's noise.
    """
    from .consistency import compare, heldout_misfit, score_binning

    binning = score_binning(clean.shape[2])
    proposed = {name: value for name, value in estimates.items() if name in used or name == "centroid"}
    scored = {name: heldout_misfit(clean, phi, value, binning=binning) for name, value in proposed.items()}
    for name, shifts in motions.items():
        moving = heldout_misfit(clean, phi, estimates[name], shifts, binning=binning)
        scored[name] = min(scored[name], moving, key=lambda result: result.score)
    best = min(scored, key=lambda name: scored[name].score)
    kept = [name for name in scored if name == best or not compare(scored[best], scored[name]).better]
    return {name: value.score for name, value in scored.items()}, kept


def _centroid(
    clean: np.ndarray,
    phi: np.ndarray,
    air: bool,
    tolerance: float,
    estimates: dict[str, float],
    used: list[str],
    notes: list[str],
) -> np.ndarray | None:
    """The centroid estimate over the rows that hold the object; its shifts where it can be trusted."""
    rows = object_rows(clean)
    if not rows.any():
        notes.append("centroid: no row holds an object")
        return None
    offset, shifts, spread = centroid_motion(clean[rows], phi)
    if not np.isfinite(spread):
        notes.append("centroid: a view has no mass")
        return None
    estimates["centroid"] = offset
    if not air:
        notes.append("centroid: not used (no air seen: the object may be wider than the field of view)")
    elif spread > tolerance:
        notes.append(f"centroid: not used (the views' mass varies by {spread:.1%}, above {tolerance:.0%})")
    else:
        used.append("centroid")
        return shifts
    return None


@dataclass(frozen=True)
class AxisTilt:
    """The rotation axis as a line on the detector: ``offset(z) = center + slope * (z - (R - 1) / 2)``.

    Attributes
    ----------
    tilt_deg : float
        In-plane tilt of the axis on the detector, ``atan(slope)`` in degrees (positive: the axis
        moves right going down the rows).
    center : float
        Axis offset at the middle row (detector pixels).
    slope : float
        Change of the axis offset per detector row.
    rows, offsets : ndarray
        The rows the axis was measured at and the mirror estimate there.
    residual : float
        RMS of the offsets about the line (pixels).
    """

    tilt_deg: float
    center: float
    slope: float
    rows: np.ndarray
    offsets: np.ndarray
    residual: float

    def offset_at(self, row: float, n_rows: int) -> float:
        """The axis offset at detector row ``row`` of ``n_rows``."""
        return float(self.center + self.slope * (row - (n_rows - 1) / 2))


def axis_tilt(sinograms: Any, angles: Any, *, group: int = 4, rows: Any = None, n_rows: int | None = None) -> AxisTilt:
    """In-plane tilt of the rotation axis from an estimate of the axis row by row.

    With the axis tilted by ``theta`` on the detector, the axis seen by row ``z`` is at
    ``c + tan(theta) (z - z_c)``: the opposite views are matched (:func:`~nanoct.motion.center.fit_center`)
    in groups of ``group`` consecutive rows that hold the object (their smallest view mass at least
    a fifth of the largest, after the open beam is removed) and a line is fitted through the
    offsets. First order in ``theta``: the vertical displacement the tilt also brings (``theta``
    times the distance from the axis) is not modelled; measured on the real I13 scan rotated by
    2 degrees: 1.85 degrees.

    Without opposite views (a limited-angle series) where air is seen around the object, the axis
    of a group is the constant of its views' centroids fitted on ``(1, cos phi, sin phi)``
    (:func:`~nanoct.motion.center.centroid_motion`); a per-view horizontal shift moves every
    group's constant alike and leaves the slope, so only the vertical motion must be undone
    first. This line is first order too (:func:`limited_angle_tilt` removes its bias): on ETSpy's
    STEM needle series (+-76 degrees) 2.71 degrees, 2.84 rotated back until vertical, where
    ETSpy's own alignment records 2.79 and the row profiles
    (:func:`~nanoct.motion.vertical.tilt_from_profiles`) gave 0.4 to 2.4 degrees depending on how
    the motion was undone.

    Parameters
    ----------
    sinograms : array_like of shape (R, K, L)
        Rows (slices) of the scan in detector order: every row, or groups of ``group``
        consecutive rows whose detector rows ``rows`` gives.
    angles : array_like of shape (K,)
        View angles in radians.
    group : int
        Rows matched together.
    rows : array_like of shape (R,), optional
        The detector row of each sinogram (default ``0 .. R-1``).
    n_rows : int, optional
        Rows of the detector (default ``R``): the tilt line is centred on its middle row.

    Returns
    -------
    AxisTilt

    Raises
    ------
    NanoctError
        Without opposite views and without air around the object, or with fewer than two row
        groups that hold the object.
    """
    sino = np.asarray(sinograms, dtype=np.float64)
    phi = np.asarray(angles, dtype=np.float64)
    if sino.ndim != 3 or sino.shape[1] != phi.size:
        raise NanoctError(f"sinograms of shape {sino.shape} do not match {phi.size} angles (rows, views, columns)")
    clean, air = remove_air(sino)
    opposite = bool(opposite_pairs(phi)[0].size)
    if not (opposite or air):
        raise NanoctError(
            "the axis tilt needs views 180 degrees apart or air around the object; for a limited-angle "
            "series without air use nanoct.motion.vertical.tilt_from_profiles"
        )
    starts = np.arange(0, sino.shape[0] - group + 1, group)
    mass = np.array([clean[r : r + group].sum(axis=2).min() for r in starts])
    starts = starts[mass >= 0.2 * max(float(mass.max()), 0.0)]
    if starts.size < 2:
        raise NanoctError(f"the axis tilt needs at least two groups of {group} rows holding the object")
    if opposite:
        offsets = np.array([fit_center(clean[r : r + group], phi, max_offset=sino.shape[2] / 4) for r in starts])
    else:
        offsets = np.array([centroid_motion(clean[r : r + group], phi)[0] for r in starts])
    index = np.arange(sino.shape[0], dtype=np.float64) if rows is None else np.asarray(rows, dtype=np.float64)
    rows = np.array([index[r : r + group].mean() for r in starts])
    middle = ((sino.shape[0] if n_rows is None else n_rows) - 1) / 2
    basis = np.stack([np.ones_like(rows), rows - middle], axis=1)
    (center, slope), *_ = np.linalg.lstsq(basis, offsets, rcond=None)
    residual = float(np.sqrt(np.mean((basis @ np.array([center, slope]) - offsets) ** 2)))
    return AxisTilt(float(np.rad2deg(np.arctan(slope))), float(center), float(slope), rows, offsets, residual)


def limited_angle_tilt(
    projections: Any, angles: Any, *, tolerance_deg: float = 0.01, max_steps: int = 8
) -> tuple[AxisTilt, list[float]]:
    """The axis tilt of a limited-angle series with air around the object, without the first-order bias.

    :func:`axis_tilt`'s centroid line is first order: a row of a tilted series also crosses the
    neighbouring slices (the tilt times the distance from the axis), which pulls the row's
    centroid axis towards the heavier of them; on a constructed series tilted by 2.5 and -1.5
    degrees it gave 1.53 and -0.80. So the projections are rotated back by a trial tilt
    (:func:`~nanoct.motion.matching.apply_vertical`, about the detector centre) and
    :func:`axis_tilt` measures the tilt that is left; the tilt is the root of that residual,
    found by secant steps from 0 and the first estimate until the residual is below
    ``tolerance_deg`` (or after ``max_steps`` measurements). At the root the rows are the slices
    (up to the interpolation of the rotations): 2.56 and -1.39 on the constructed series, 0.05
    on it untilted.

    Parameters
    ----------
    projections : array_like of shape (K, R, L)
        Line integrals of contiguous detector rows, every view moved back by its motion.
    angles : array_like of shape (K,)
        View angles in radians.
    tolerance_deg, max_steps : float, int
        When to stop.

    Returns
    -------
    tilt : AxisTilt
        ``tilt_deg`` and ``slope`` the root; ``center``, ``rows``, ``offsets`` and ``residual``
        from the last measurement (the projections rotated back by it).
    trials : list of float
        The trial tilts measured, in order (degrees).

    Raises
    ------
    NanoctError
        As :func:`axis_tilt` (no air around the object, too few rows holding it).
    """
    proj = np.asarray(projections, dtype=np.float64)
    phi = np.asarray(angles, dtype=np.float64)
    still = np.zeros(phi.size)

    def residual(trial: float) -> AxisTilt:
        turned = apply_vertical(proj, still, trial) if trial else proj
        return axis_tilt(turned.transpose(1, 0, 2), phi)

    before, left = 0.0, residual(0.0)
    trials, trial = [0.0], left.tilt_deg
    for _ in range(max_steps - 1):
        if abs(left.tilt_deg) < tolerance_deg:
            break
        now = residual(trial)
        trials.append(trial)
        step = now.tilt_deg - left.tilt_deg
        before, left, trial = trial, now, (trial - now.tilt_deg * (trial - before) / step if step else trial)
        if not step:
            break
    root = trials[-1]
    slope = float(np.tan(np.deg2rad(root)))
    return AxisTilt(root, left.center, slope, left.rows, left.offsets, left.residual), trials
