"""A simulated training set matched to a measured scan (``nanoct generate --like STORE``).

From a data set made by ``nanoct import`` (and, where present, the motion ``nanoct stack``
estimated for it) the matched set takes (estimators in :mod:`nanoct.sim.scan_stats`):

* the scan's **views** (angles in acquisition order) and **detector**, binned by ``b``
  (``--bin``): ``L / b`` detector pixels, image ``N / b``;
* the **rotation axis**: the stack's (``motion_info["center_offset"]``) where the store has a
  stack result with a motion (the motion source, :func:`plan_matched`), else the store's own
  (``nanoct import --center-offset``), moved to the binned detector;
* the **noise**: the std per ray measured in the air bands of the binned sinograms, added as
  white Gaussian noise (measured, like the slices below, on at most ``MAX_SLICES`` binned slices
  evenly spread over the stack);
* the **open beam**: the scan's air level per view (:func:`~nanoct.sim.scan_stats.open_beam_level`),
  added to every simulated sinogram (measured and model), so that the methods treat the matched
  set as they treat the scan (``measured="auto"`` finds an open beam not at zero on both: the
  level removed per view, objects wider than the view, stopping by the discrepancy principle);
  on a set matched to the I13 scan (2,500 pairs at bin 2), Dremel's 350 validation images
  reached 29.07 dB without the level (the simulation path: a fixed number of sweeps on noisy
  data) and 34.53 dB with it;
* the **motion**: with a stack motion, its smooth amplitude as the bound ``max_shift`` of the
  damped sinusoids and its jitter std as ``jitter_std_mean`` (``jitter_std_std`` = 0.2 times
  that, the paper's ratio 0.0254 / 0.127; the rotation jitter, which a detector shift does not
  show, takes the same number in degrees), both in binned pixels; without one, the paper's
  parallel-beam defaults (38 sinusoids, ``max_shift`` 2 px, jitter 0.127 +- 0.0254);
* the **intensity scale**: the 99.9th percentile of the scan's own slices (below) inside the
  field of view, ``value_scale``; the paper's phantoms (values in [0, 1]) are multiplied by it,
  so that simulated and measured reconstructions share one scale (absorbance per binned pixel).

Phantoms: per sample, drawn with the mix ``--mix SHAPES,ELLIPSES,SCAN[,MEASURED]`` (default 0.4,
0.2, 0.4, 0): the paper's shapes (:func:`~nanoct.sim.phantoms.random_phantom`), the ellipse family
(:func:`~nanoct.sim.phantoms.random_ellipse_phantom`), or one of the scan's own slices: the FBP
of a binned slice with the axis above, the per-view air level removed
(:func:`~nanoct.recon.measured.air_level`) and the stack's motion corrected where present
(:func:`~nanoct.recon.stack.corrected_fbp`; the stack's axis tilt and vertical motion are not
applied), smoothed by a Gaussian of ``SLICE_SMOOTH_PX`` px, negative values set to 0, zero
outside the field-of-view disc; slices whose 99th percentile is below ``MIN_CONTENT`` times
``value_scale`` (nearly empty, e.g. above or below the sample) are left out. Each sample's slice
is turned by a uniform random angle and mirrored with probability 1/2. These slices are stored
with the set (array ``like_slices``).

**Measured pairs** (the fourth family, ``MEASURED``; :func:`measured_pair`): not simulated at all
but the scan's own binned sinogram of one of those slices, its estimated motion undone and a
motion drawn from the matched motion model added by reading each view at shifted detector
positions (the translation's component along the detector; the rotation jitter, which the
projections cannot be turned by, is left out and stored as zero) with a band-limited (Fourier)
shift, which keeps the measured noise's power spectrum (a linear interpolation smooths it: on
I13 24737 binned 2 x 2 it kept 39 % of the power in the top quarter of the detector frequencies,
the band-limited shift 97 %, so the pairs' references were smoother than a reference of the scan
itself); no noise is added (the
data carry their own); the "phantom" is the reference a user holds for the scan: the FBP of the
unmoved sinogram, the per-view air level removed, zero outside the field of view (not smoothed,
not clipped: its noise and ring artefacts stay). A set of measured pairs alone (``--mix 0,0,0,1
--split-fractions 0,1,0``) calibrates a network's intervals on the scan itself (``nanoct predict
--calibrate-on``): the residuals are then those of the real detector (its noise, stripes and
open-beam drift) against the reference the scan's own FBP gives. The sinograms are stored with
the set (array ``like_measured``, the motion undone in its attribute ``shifts``, the first scan row
of each slice in ``rows``; :func:`matched_source` names a sample's slice).

Everything measured is recorded in ``attrs["nanoct"]["simulation"]["like"]``. The set resumes
like any generated set: the same command again finds the same description (measurements are
rounded to 6 significant digits, so the same scan gives the same record; the motion source the set
was made with is kept where ``--motion-from`` is not given) and makes only the missing samples; a
set that differs is refused naming the nested keys that differ (e.g. ``simulation.like.motion.from``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zarr
from scipy import ndimage

from ..core.errors import NanoctError, StoreError
from ..core.geometry import Geometry
from ..io.fileio import cached_by_file
from ..io.store import DataStore, Sample, comparable_description, data_set_description
from ..io.store_recon import differing_keys
from ..recon.fbp import fbp
from ..recon.measured import air_level, read_moved
from ..recon.stack import corrected_fbp
from .generate import check_run, fill_dataset
from .motion import MotionParams, sample_motion
from .phantoms import random_ellipse_phantom, random_phantom
from .scan_stats import air_noise, bin_sinograms, binned_geometry, motion_stats, open_beam_level
from .simulate import SimulationConfig, model_error, sample_rngs, simulate_from_phantom

__all__ = [
    "FAMILIES",
    "MAX_SLICES",
    "MIN_CONTENT",
    "MEASURED_SHIFT",
    "MIX",
    "SCALE_PERCENTILE",
    "SLICE_SMOOTH_PX",
    "MatchedPlan",
    "fov_disc",
    "generate_like",
    "reference_view",
    "matched_source",
    "samples_made",
    "measured_pair",
    "parse_mix",
    "parse_rows",
    "plan_matched",
    "scan_slices",
    "simulate_matched_sample",
]

#: Fewer scan slices than this among the phantoms: the plan warns that a network can learn them.
FEW_SLICES = 4
#: Default phantom mix: the paper's shapes, the ellipse family, the scan's own slices (no measured pairs).
MIX = (0.4, 0.2, 0.4)
#: The families of a matched set's samples, in ``--mix`` order.
FAMILIES = ("shapes", "ellipses", "scan", "measured")
#: Gaussian smoothing (px std) of the scan's slices before they serve as phantoms.
SLICE_SMOOTH_PX = 0.7
#: Percentile of the scan's slices (inside the field of view) that the paper's phantoms are scaled to.
SCALE_PERCENTILE = 99.9
#: At most this many (binned) slices of the scan are measured and reconstructed as phantoms, evenly spread.
MAX_SLICES = 128
#: A slice whose 99th percentile is below this fraction of ``value_scale`` is left out (nearly empty).
MIN_CONTENT = 0.01
#: jitter_std_std / jitter_std_mean of the paper (0.0254 / 0.127).
_JITTER_RATIO = 0.2
#: How a measured pair's views are moved (:func:`~nanoct.recon.measured.read_moved`); recorded in the set.
MEASURED_SHIFT = "fourier"
_SLICES = "like_slices"
_MEASURED = "like_measured"


def _round(value: float) -> float:
    return float(f"{value:.6g}")


def parse_mix(text: str) -> tuple[float, ...]:
    """``--mix SHAPES,ELLIPSES,SCAN[,MEASURED]``: three or four numbers >= 0 with a positive sum, normalised to 1.

    A fourth number of 0 is dropped (the same set as the three alone).
    """
    try:
        parts = tuple(float(v) for v in text.split(","))
    except ValueError:
        parts = ()
    total = sum(parts)
    if len(parts) not in (3, 4) or not all(math.isfinite(p) and p >= 0 for p in parts) or not 0 < total < math.inf:
        raise NanoctError(
            f"--mix {text!r} must be three or four numbers >= 0 (shapes, ellipses, scan slices[, measured pairs]) "
            "with a positive finite sum, e.g. 0.4,0.2,0.4 (training) or 0,0,0,1 (the scan's own pairs, for calibration)"
        )
    if len(parts) == 4 and parts[3] == 0:
        parts = parts[:3]
    return tuple(_round(p / total) for p in parts)


def parse_rows(text: str | None) -> tuple[int, ...]:
    """``--hold-out ROWS``: scan rows as a comma-separated list of rows and half-open ranges ``START:STOP``
    (``"30:36,50"`` is rows 30 to 35 and 50), sorted and without repeats; ``None`` or ``""`` is none."""
    rows: set[int] = set()
    for part in (text or "").split(",") if (text or "").strip() else []:
        try:
            ends = [int(v) for v in part.split(":")]
        except ValueError:
            ends = []
        if len(ends) not in (1, 2) or min(ends) < 0 or (len(ends) == 2 and ends[1] <= ends[0]):
            raise NanoctError(
                f"--hold-out {text!r}: {part!r} is not a row >= 0 or a range START:STOP with STOP > START; "
                "e.g. 30:36,50"
            )
        rows.update(range(ends[0], ends[-1] if len(ends) == 2 else ends[0] + 1))
    return tuple(sorted(rows))


def _open_scan(like: str | os.PathLike[str]) -> DataStore:
    path = Path(like)
    if not (path / "zarr.json").is_file():
        raise NanoctError(
            f"--like {path}: no data set there; import the measured scan first with 'nanoct import SCAN --out {path}'"
        )
    store = DataStore.open(path)
    if not store.is_scan:
        raise NanoctError(
            f"--like {path} is a simulated data set, not a measured scan; give a data set made by 'nanoct import'"
        )
    if store.geometry.kind != "parallel":
        raise NanoctError(f"--like {path} is a {store.geometry.kind}-beam scan; matched sets are parallel beam")
    if not store.done.all():
        raise StoreError(f"--like {path} is incomplete ({int(store.done.sum())} of {store.n} slices); import it again")
    return store


def _has_motion(store: DataStore, name: str) -> bool:
    """Whether result ``name`` holds one finite motion for the whole scan."""
    shifts = store.recons.shared_shifts(name)
    return shifts is not None and bool(np.isfinite(shifts).all())


def _recorded_source(out: str | os.PathLike[str] | None) -> tuple[bool, str | None]:
    """Whether ``out`` holds a matched set, and the result its motion was taken from (None: the paper's)."""
    if out is None or not (Path(out) / "zarr.json").is_file():
        return False, None
    try:
        motion = DataStore.open(out).meta["simulation"]["like"]["motion"]
        source = motion.get("from")
    except (NanoctError, KeyError, TypeError, AttributeError):  # no data set, or not a matched one: nothing to keep
        return False, None
    return True, source


def _motion_source(store: DataStore, name: str | None, out: str | os.PathLike[str] | None) -> tuple[str | None, str]:
    """The result whose motion to use (None: none) and, when it was not asked for, why it was chosen.

    ``name`` as given; else the source recorded in a matched set already at ``out`` (resuming it, so
    that results added to the scan since do not change it) where that result still holds a motion (or
    the set used none); else the first result in name order whose motion and slices are all done (an
    interrupted ``nanoct stack`` has its motion before its slices: it is passed over; where several are,
    the note names them).
    """
    names = store.reconstruction_names()
    if name is not None:
        if name not in names:
            raise NanoctError(
                f"--motion-from {name!r}: {store.path} has no such result (present: {', '.join(names) or 'none'}); "
                "run 'nanoct stack' on it first or leave the flag out"
            )
        if not _has_motion(store, name):
            raise NanoctError(f"--motion-from {name!r} has no estimated motion (it is not a 'nanoct stack' result)")
        return name, ""
    found, recorded = _recorded_source(out)
    if found and (recorded is None or (recorded in names and _has_motion(store, recorded))):
        return recorded, f"as the set at {out} was made"
    moved = [n for n in sorted(names) if _has_motion(store, n)]
    complete = [n for n in moved if store.reconstruction_done(n).all()]
    unfinished = [n for n in moved if n not in complete]
    notes = [f"passed over the unfinished {', '.join(unfinished)}"] if unfinished else []
    if len(complete) > 1:  # their motions may differ: say that one was picked, and how to pick another
        notes.append(f"the first by name of {', '.join(complete)}; --motion-from takes another")
    return (complete[0] if complete else None), "; ".join(notes)


def _stack_motion(store: DataStore, name: str | None) -> tuple[np.ndarray | None, dict[str, Any]]:
    """The motion (K,) of result ``name`` and what was recorded with it (None and {} for no result)."""
    if name is None:
        return None, {}
    return store.recons.shared_shifts(name).astype(np.float64), store.recons.motion_info(name) or {}


def scan_slices(sinograms: np.ndarray, geometry: Geometry, shifts: np.ndarray | None = None) -> np.ndarray:
    """The scan's slices as phantoms (see the module docstring), before the random turn.

    Parameters
    ----------
    sinograms : ndarray of shape (S, K, L)
        Binned sinograms of the scan.
    geometry : Geometry
        Their (binned) geometry.
    shifts : ndarray of shape (K,), optional
        The stack's motion in binned detector pixels (:func:`~nanoct.recon.stack.corrected_fbp`).

    Returns
    -------
    ndarray of shape (S, N, N), float32
        Non-negative, zero outside the field-of-view disc.
    """
    disc = fov_disc(geometry)
    out = np.empty((sinograms.shape[0], *geometry.image_shape), dtype=np.float32)
    for i, sino in enumerate(sinograms):
        level = air_level(sino)
        image = corrected_fbp(geometry, sino - level[:, None], shifts)
        out[i] = np.clip(ndimage.gaussian_filter(image, SLICE_SMOOTH_PX), 0.0, None) * disc
    return out


def fov_disc(geometry: Geometry) -> np.ndarray:
    """Pixels every view of a parallel-beam scan sees: within ``(L - 1) / 2 - |axis offset|`` of the axis
    (at least 1 px), as a float32 (N, N) mask; a measured pair's reference is known only there."""
    n = geometry.n
    radius = max(((geometry.n_det - 1) / 2 - abs(geometry.center_offset)) * geometry.det_spacing, 1.0)
    r = np.arange(n) - (n - 1) / 2
    return ((r[None, :] ** 2 + r[:, None] ** 2) <= radius**2).astype(np.float32)


def reference_view(geometry: Geometry, references: np.ndarray) -> np.ndarray | None:
    """Where references reconstructed from measured data are known: the field of view (:func:`fov_disc`, bool) of
    a parallel-beam scan whose references have negative values (an FBP's noise); None for phantoms (no negative
    value) and fan beam."""
    if geometry.kind != "parallel" or not np.asarray(references).min() < 0:
        return None
    return fov_disc(geometry) > 0


@dataclass(frozen=True)
class MatchedPlan:
    """What ``generate --like`` makes: the binned geometry, the simulation record and the scan's slices.

    Attributes
    ----------
    like : Path
        The measured scan's store.
    geometry : Geometry
        Geometry of the matched set.
    simulation : dict
        :class:`~nanoct.sim.simulate.SimulationConfig` description plus ``like`` (the measurements).
    slices : ndarray of shape (S, N, N)
        The scan's slices used as phantoms.
    measured : ndarray of shape (S, K, L), optional
        With measured pairs in the mix: the binned sinograms of those slices, as measured.
    shifts : ndarray of shape (K,), optional
        With measured pairs: the motion undone in them (the stack's, binned; zeros without one).
    rows : ndarray of shape (S,), optional
        With measured pairs: the first detector row of the scan that each binned slice averages.
    motion_note : str
        Where ``--motion-from`` was not given: why the motion source was taken instead of the default pick
        (a set already at ``--out`` was made with it), or the unfinished results the default passed over;
        "" otherwise.
    """

    like: Path
    geometry: Geometry
    simulation: dict[str, Any]
    slices: np.ndarray
    measured: np.ndarray | None = None
    shifts: np.ndarray | None = None
    rows: np.ndarray | None = None
    motion_note: str = ""

    def describe(self) -> list[str]:
        """Lines saying what the plan takes from the scan."""
        g, like = self.geometry, self.simulation["like"]
        noise, motion, mix, beam = like["noise"], like["motion"], like["mix"], like["open_beam"]["level"]
        moved = (
            f"from '{motion['from']}': smooth amplitude {motion['amplitude']:.3g} px, jitter {motion['jitter']:.3g} px"
            if motion["from"]
            else "none estimated: the paper's defaults (max shift 2 px, jitter 0.127 px)"
        ) + (f" ({self.motion_note})" if self.motion_note else "")
        return [
            f"like       {self.like} (bin {like['bin']})",
            f"geometry   {g.n_angles} views, {g.n_det} detector pixels, image {g.n}x{g.n}, "
            f"axis offset {g.center_offset:+.3f} px ({like['axis_from']})",
            f"noise      {noise['sigma']:.4g} per ray ({noise['estimator']})",
            f"open beam  {np.mean(beam):.4g} (views {min(beam):.4g} to {max(beam):.4g}), added to the sinograms",
            f"motion     {moved}",
            f"scale      paper phantoms x {like['value_scale']:.4g} (the {SCALE_PERCENTILE}th percentile of the scan's "
            "slices)",
            f"phantoms   shapes {mix['shapes']:.2f}, ellipses {mix['ellipses']:.2f}, scan slices {mix['scan']:.2f}"
            + (f", measured pairs {mix['measured']:.2f}" if "measured" in mix else "")
            + f" ({self.slices.shape[0]} slices kept, {like['slices_left_out']} nearly empty left out, "
            + (f"{like['held_out']['slices']} held out, " if "held_out" in like else "")
            + f"of {like['slices_measured']} measured)",
        ] + self._few_slices_note(mix)

    def _few_slices_note(self, mix: dict[str, float]) -> list[str]:
        """A warning line where the scan's share of the phantoms comes from fewer than :data:`FEW_SLICES` slices."""
        share = mix["scan"] + mix.get("measured", 0.0)
        if share <= 0 or self.slices.shape[0] >= FEW_SLICES:
            return []
        return [
            f"note       {share:.0%} of the phantoms are the scan's {self.slices.shape[0]} slice(s): a network can "
            "learn them, so scores on this set's images overstate how it does on other slices of the sample"
        ]


def plan_matched(
    like: str | os.PathLike[str],
    *,
    binning: int = 1,
    mix: tuple[float, ...] = MIX,
    motion_from: str | None = None,
    perturbed: bool = True,
    oversample: int = 2,
    hold_out: tuple[int, ...] = (),
    out: str | os.PathLike[str] | None = None,
) -> MatchedPlan:
    """Measure a scan and describe the matched set (nothing is written).

    Parameters
    ----------
    like : path
        A data set made by ``nanoct import`` (optionally with a ``nanoct stack`` result).
    binning : int
        Detector (and slice) binning; must divide the detector width and the image size.
    mix : tuple of float
        Proportions of the paper's shapes, the ellipse family, the scan's slices and (optional
        fourth) measured pairs (sum 1; :func:`parse_mix`).
    motion_from : str, optional
        The stack result whose motion to use. Default: the one a matched set already at ``out`` was made
        with (where it still holds its motion; none where the set used none), else the first in name order
        whose motion and slices are all done (an interrupted result is passed over), else none.
    perturbed, oversample
        As :class:`~nanoct.sim.simulate.SimulationConfig`.
    hold_out : tuple of int
        Scan rows (:func:`parse_rows`) whose binned slices serve as no phantom and no measured pair
        (kept out of training, e.g. the slices a result is evaluated on); the scan-wide measurements
        (noise, open beam, motion, axis, value scale) still use every slice.
    out : path, optional
        Where the set is to be made: a matched set already there keeps its motion source (resuming).

    Raises
    ------
    NanoctError
        For a missing or simulated ``like`` store, a binning that does not divide its sizes, an
        unknown ``motion_from``, a detector too narrow to measure the noise, or ``hold_out`` rows
        outside the scan or holding out every slice.
    """
    store = _open_scan(like)
    name, why = _motion_source(store, motion_from, out)
    shifts, info = _stack_motion(store, name)
    axis = float(info.get("center_offset", store.geometry.center_offset))
    geometry = binned_geometry(store.geometry, binning, axis)
    groups = _slice_groups(store.n, binning)
    sinos = bin_sinograms(store.read_array("sinograms", groups.ravel()), binning)
    noise = air_noise(sinos)
    noise.pop("values")
    level = open_beam_level(sinos)
    shifts_b = None if shifts is None else shifts / binning
    slices = scan_slices(sinos, geometry, shifts_b)
    scale = _round(float(np.percentile(slices[:, fov_disc(geometry) > 0], SCALE_PERCENTILE)))
    if not scale > 0:
        raise NanoctError(f"--like {store.path}: its slices are empty (no absorbing object); nothing to match")
    kept = np.percentile(slices.reshape(len(slices), -1), 99, axis=1) >= MIN_CONTENT * scale
    if not kept.any():
        raise NanoctError(f"--like {store.path}: every slice is nearly empty; nothing to match")
    nearly_empty = int((~kept).sum())
    if hold_out and max(hold_out) >= store.n:
        raise NanoctError(f"--hold-out row {max(hold_out)} is outside the scan (rows 0 to {store.n - 1})")
    held = np.isin(groups, hold_out).any(axis=1) & kept
    if held.sum() == kept.sum():
        raise NanoctError(f"--hold-out holds out every slice of {store.path} that has content; nothing to match")
    kept &= ~held
    slices = slices[kept]
    stats = {"from": None} if shifts_b is None else {"from": name, **motion_stats(shifts_b)}
    record = {
        "store": str(Path(like).resolve()),
        "bin": int(binning),
        "slices": int(slices.shape[0]),
        "slices_measured": int(groups.shape[0]),
        "slices_left_out": nearly_empty,
        "axis_from": f"the stack result '{name}'" if "center_offset" in info else "the imported scan",
        "noise": {k: _round(v) if isinstance(v, float) else v for k, v in noise.items()},
        "open_beam": {
            "estimator": "per view, the median of the air bands of each slice, median over slices",
            "level": [_round(float(v)) for v in level],
        },
        "motion": {k: _round(v) if isinstance(v, float) else v for k, v in stats.items()},
        "value_scale": scale,
        "slice_smooth_px": SLICE_SMOOTH_PX,
        "mix": dict(zip(FAMILIES, (_round(m) for m in mix))),
    }
    if hold_out:
        record["held_out"] = {"rows": [int(r) for r in hold_out], "slices": int(held.sum())}
    config = SimulationConfig(
        motion=_motion_params(record["motion"]),
        perturbed=perturbed,
        oversample=oversample,
        noise_std=record["noise"]["sigma"],
    )
    measured = None
    if len(mix) > 3 and mix[3] > 0:
        measured = (sinos[kept], np.zeros(geometry.n_angles) if shifts_b is None else shifts_b, groups[kept, 0])
        record["measured_shift"] = MEASURED_SHIFT
    simulation = {**config.to_dict(), "like": record}
    return MatchedPlan(Path(like), geometry, simulation, slices, *(measured or ()), motion_note=why)


def _slice_groups(n_slices: int, binning: int) -> np.ndarray:
    """Rows of the (binned) slices measured: at most ``MAX_SLICES`` groups of ``binning`` rows, evenly spread.

    Returns an array (groups, rows per group); with fewer rows than ``binning``, one group per row (the
    rows are then binned along the detector only, as :func:`~nanoct.sim.scan_stats.bin_sinograms` does).
    """
    if n_slices < binning:
        return np.arange(n_slices)[:, None]
    n_groups = n_slices // binning
    chosen = np.unique(np.round(np.linspace(0, n_groups - 1, min(n_groups, MAX_SLICES))).astype(int))
    return chosen[:, None] * binning + np.arange(binning)[None, :]


def _motion_params(stats: dict[str, Any]) -> MotionParams:
    if stats["from"] is None:
        return MotionParams.for_kind("parallel")
    jitter = stats["jitter"]
    return MotionParams.for_kind(
        "parallel", max_shift=stats["amplitude"], jitter_std_mean=jitter, jitter_std_std=_round(_JITTER_RATIO * jitter)
    )


def generate_like(
    out: str | os.PathLike[str],
    plan: MatchedPlan,
    n: int,
    *,
    seed: int = 0,
    split_fractions: tuple[float, float, float] = (0.95, 0.04, 0.01),
    workers: int = 2,
    scheduler: str | None = None,
    progress: bool = True,
) -> DataStore:
    """Simulate the matched set of ``plan`` into ``out`` (resuming where it is partly there).

    Raises
    ------
    NanoctError
        For a bad ``n``, ``seed`` or ``workers``, or when ``out`` holds another data set (a
        :class:`~nanoct.core.errors.StoreError` naming the values that differ, e.g.
        ``simulation.like.motion.from``, and the ``--motion-from`` that resumes it).
    """
    check_run(n, seed, workers)
    _check_same_set(Path(out), plan, n, seed, split_fractions)
    store = DataStore.create(Path(out), plan.geometry, n, seed, plan.simulation, split_fractions)
    group = zarr.open_group(str(store.path), mode="r+")
    if _SLICES not in group or not group[_SLICES].attrs.get("complete"):
        array = group.create_array(
            _SLICES, shape=plan.slices.shape, chunks=(1, *plan.slices.shape[1:]), dtype="float32", overwrite=True
        )
        array[:] = plan.slices
        array.attrs["complete"] = True
    if plan.measured is not None and (_MEASURED not in group or not group[_MEASURED].attrs.get("complete")):
        array = group.create_array(
            _MEASURED, shape=plan.measured.shape, chunks=(1, *plan.measured.shape[1:]), dtype="float32", overwrite=True
        )
        array[:] = plan.measured
        array.attrs["shifts"] = [float(v) for v in plan.shifts]
        array.attrs["rows"] = [int(v) for v in plan.rows]
        array.attrs["complete"] = True
    fill_dataset(store, simulate=simulate_matched_sample, workers=workers, scheduler=scheduler, progress=progress)
    return DataStore.open(store.path, mode="r+")


def samples_made(
    out: str | os.PathLike[str], plan: MatchedPlan, n: int, *, seed: int, split_fractions: tuple[float, float, float]
) -> int | None:
    """How many samples of the set ``plan`` describes (``n`` samples, ``seed``, ``split_fractions``) the data set at
    ``out`` holds already: 0 where there is none yet, None where ``out`` holds another data set (which
    :func:`generate_like` would refuse). What ``generate --like --plan`` reports; nothing is written."""
    out = Path(out)
    if not (out / "zarr.json").is_file():
        return 0
    old = DataStore.open(out)
    simulation = comparable_description({"simulation": json.loads(json.dumps(plan.simulation))})
    wanted = (simulation, plan.geometry, n, seed, list(split_fractions))
    have = (comparable_description({"simulation": old.meta.get("simulation")}), old.geometry, old.n, old.seed,
            old.meta.get("split_fractions"))  # fmt: skip
    return int(old.done.sum()) if have == wanted else None


def _check_same_set(out: Path, plan: MatchedPlan, n: int, seed: int, fractions: tuple[float, float, float]) -> None:
    """Refuse an ``out`` that holds another data set, naming the values that differ (nested: e.g.
    ``simulation.like.motion.from``) and, where the motion source is one, the ``--motion-from`` that resumes it.

    A data set that cannot be read is left to :meth:`~nanoct.io.store.DataStore.create` to report.
    """
    if not (out / "zarr.json").is_file():
        return
    try:
        existing = DataStore.open(out)
    except StoreError:
        return
    mine = comparable_description(data_set_description(plan.geometry, n, seed, plan.simulation, fractions))
    theirs = comparable_description(existing.meta)
    differs = differing_keys(mine, theirs, depth=None)
    if not differs:
        return
    source = "simulation.like.motion.from"
    shown = ([source] if source in differs else []) + [d for d in differs if d != source]
    listed = ", ".join(shown[:6]) + (f" and {len(shown) - 6} more" if len(shown) > 6 else "")
    advice = "use another --out, or repeat the original command to resume it"
    if source in differs:
        advice = _source_advice(plan, (theirs["simulation"] or {})["like"]["motion"].get("from"))
    raise StoreError(f"{out} holds a different data set (differs in: {listed}); {advice}")


def _source_advice(plan: MatchedPlan, recorded: str | None) -> str:
    """What to do when the set at ``--out`` took its motion from another source (``recorded``; None: none)."""
    mine = plan.simulation["like"]["motion"]["from"]
    mine_text = f"'{mine}'" if mine else "none"
    if recorded is None:
        return (
            f"it was made without a stack motion (the paper's defaults; this run: {mine_text}): leave --motion-from "
            "out to resume it, or use another --out"
        )
    try:
        present = recorded in DataStore.open(plan.like).reconstruction_names()
    except StoreError:
        present = False
    if not present:
        return (
            f"it took the motion of '{recorded}' (this run: {mine_text}), which {plan.like} no longer holds: "
            "use another --out"
        )
    return f"it took the motion of '{recorded}' (this run: {mine_text}): give --motion-from {recorded} to resume it"


@cached_by_file(f"{_SLICES}/zarr.json", maxsize=4)
def _stored_slices(path: str) -> np.ndarray:
    """The stored slices, read once per process (again where the set was made again at the same path)."""
    group = zarr.open_group(path, mode="r")
    if _SLICES not in group or not group[_SLICES].attrs.get("complete"):
        raise StoreError(f"{path} lacks the scan's slices of its matched set; run the same 'generate --like' again")
    return np.asarray(group[_SLICES][:], dtype=np.float32)


@cached_by_file(f"{_MEASURED}/zarr.json", maxsize=4)
def _stored_measured(path: str) -> tuple[np.ndarray, np.ndarray]:
    """The stored sinograms of the measured pairs and their undone motion, cached like :func:`_stored_slices`."""
    group = zarr.open_group(path, mode="r")
    if _MEASURED not in group or not group[_MEASURED].attrs.get("complete"):
        raise StoreError(
            f"{path} lacks the scan's sinograms of its measured pairs; run the same 'generate --like' again"
        )
    array = group[_MEASURED]
    return np.asarray(array[:], dtype=np.float32), np.asarray(array.attrs["shifts"], dtype=np.float64)


def _family(rng: np.random.Generator, like: dict[str, Any]) -> str:
    """The family of one sample, drawn with the mix (three families: the draws of the first matched sets)."""
    families = [f for f in FAMILIES if f in like["mix"]]
    mix = np.array([like["mix"][f] for f in families], dtype=np.float64)
    return families[int(rng.choice(len(families), p=mix / mix.sum()))]


def _phantom(
    rng: np.random.Generator, family: str, like: dict[str, Any], slices: np.ndarray, n: int, s: int
) -> np.ndarray:
    """The fine (``n s`` square) phantom of one sample of a simulated ``family``: its draws."""
    if family == "shapes":
        return (random_phantom(rng, n, oversample=s) * like["value_scale"]).astype(np.float32)
    if family == "ellipses":
        return (random_ellipse_phantom(rng, n, oversample=s) * like["value_scale"]).astype(np.float32)
    image = slices[int(rng.integers(slices.shape[0]))]
    image = ndimage.rotate(image, float(rng.uniform(0.0, 360.0)), reshape=False, order=1, mode="constant")
    if rng.random() < 0.5:
        image = image[:, ::-1]
    image = np.clip(image, 0.0, None)
    return np.kron(image, np.ones((s, s))).astype(np.float32)


def measured_pair(geometry: Geometry, sinogram: np.ndarray, shifts: np.ndarray, motion: np.ndarray) -> Sample:
    """A measured pair: the scan's sinogram with its motion undone, moved by ``motion``; the reference as phantom.

    Parameters
    ----------
    geometry : Geometry
        The (binned) parallel-beam geometry of the sinogram.
    sinogram : ndarray of shape (K, L)
        A slice's binned sinogram as measured (open-beam level included).
    shifts : ndarray of shape (K,)
        Its estimated per-view detector shift ``d_k`` (the convention of ``nanoct stack``), undone.
    motion : ndarray of shape (K, 3)
        The object motion to add (``docs/conventions.md``); its translation moves each view by
        ``t_k . e_u`` along the detector, the rotation is not applied (and returned as zero).

    Returns
    -------
    Sample
        ``sinogram`` the moved views ``y_k(u) = m_k(u - d_k + t_k . e_u)`` (one band-limited shift,
        :func:`~nanoct.recon.measured.read_moved` with ``interpolation="fourier"``: the noise keeps its
        spectrum), ``sinogram_eta`` the unmoved views ``m_k(u - d_k)`` (the same),
        ``phantom`` the FBP of the unmoved views with the per-view air level removed, zero outside the
        field of view; ``motion`` with zero rotation; ``eta`` the model error of the two.
    """
    motion = np.array(motion, dtype=np.float32)
    motion[:, 2] = 0.0
    phi = geometry.angles
    along = (motion[:, 0] * np.cos(phi) + motion[:, 1] * np.sin(phi)) / geometry.det_spacing
    y_eta = read_moved(sinogram, shifts, MEASURED_SHIFT)
    y = read_moved(sinogram, np.asarray(shifts, np.float64) - along, MEASURED_SHIFT)
    reference = fbp(geometry, y_eta - air_level(y_eta)[:, None]).image * fov_disc(geometry)
    return Sample(
        phantom=reference.astype(np.float32),
        sinogram=y.astype(np.float32),
        sinogram_eta=y_eta.astype(np.float32),
        motion=motion,
        eta=model_error(y, y_eta),
    )


def matched_source(store: DataStore, index: int) -> tuple[str, int | None]:
    """Where sample ``index`` of a matched set comes from: its family and, for ``scan`` and ``measured``,
    the index of the scan slice (in ``like_slices`` / ``like_measured``), replaying its draws."""
    like = store.meta["simulation"]["like"]
    rng = sample_rngs(store.seed, index)[0]
    family = _family(rng, like)
    if family not in ("scan", "measured"):
        return family, None
    count = (_stored_slices if family == "scan" else lambda p: _stored_measured(p)[0])(str(store.path)).shape[0]
    return family, int(rng.integers(count))


def simulate_matched_sample(store: DataStore, index: int) -> Sample:
    """Sample ``index`` of a matched set (a pure function of the set's seed, ``index`` and description)."""
    simulation = store.meta["simulation"]
    config = SimulationConfig.from_dict(simulation)
    rng_phantom, rng_motion, rng_noise = sample_rngs(store.seed, index)
    family = _family(rng_phantom, simulation["like"])
    if family == "measured":
        sinograms, shifts = _stored_measured(str(store.path))
        sinogram = sinograms[int(rng_phantom.integers(sinograms.shape[0]))]
        motion = sample_motion(rng_motion, store.geometry.n_angles, config.motion)
        return measured_pair(store.geometry, sinogram, shifts, motion if config.perturbed else 0 * motion)
    slices = _stored_slices(str(store.path))
    fine = _phantom(rng_phantom, family, simulation["like"], slices, store.geometry.n, config.oversample)
    sample = simulate_from_phantom(store.geometry, config, fine, rng_motion, rng_noise)
    if "open_beam" not in simulation["like"]:  # a set made before the open beam was matched
        return sample
    level = np.asarray(simulation["like"]["open_beam"]["level"], dtype=np.float32)[:, None]
    return dataclasses.replace(sample, sinogram=sample.sinogram + level, sinogram_eta=sample.sinogram_eta + level)
