"""The held-out consistency check on every real scan at hand: axis candidates and motion candidates.

For each real scan of :func:`real_axis.scans` (the vendored ones in ``tests/data/realdata`` and
those in ``../shared/realdata``), on the rows ``nanoct import --center-offset auto`` reads:

* every axis estimator's value and its held-out score
  (:func:`nanoct.motion.consistency.heldout_misfit`), the axis kept by
  :func:`nanoct.motion.axis.estimate_axis`, whether the data decide it, and its distance from the
  reference (the mean of the mirror match and ``find_center_vo``; for the dendrite cut to 600
  columns, ``find_center_vo`` on the full width, -1.75 px);
* the still scan as it is: the views' centroid shifts (what ``nanoct stack`` proposes where air is
  seen) against no motion, through :func:`nanoct.motion.consistency.select`: which is kept;
* the scan with a known horizontal motion added (a damped sinusoid of 2 px plus 0.3 px jitter,
  each view moved by linear interpolation): the same candidates, which is kept, and the
  gauge-free RMS error of the kept shifts from the added motion (the terms 1, cos, sin removed).

Run::

    PYTHONPATH=src python benchmarks/real_consistency.py [NAME ...]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from nanoct.motion.axis import axis_rows, estimate_axis, object_rows, remove_air  # noqa: E402
from nanoct.motion.center import centroid_motion  # noqa: E402
from nanoct.motion.consistency import Candidate, heldout_misfit, score_binning, select  # noqa: E402
from real_axis import scans  # noqa: E402

#: The axis the dendrite cut to 600 columns should get: ``find_center_vo`` on the full width.
REFERENCES = {"I12 dendrite 330:930": -1.75}


def _gauge_free(shifts: np.ndarray, angles: np.ndarray) -> np.ndarray:
    basis = np.stack([np.ones_like(angles), np.cos(angles), np.sin(angles)], axis=1)
    return shifts - basis @ np.linalg.lstsq(basis, shifts, rcond=None)[0]


def _moved(sino: np.ndarray, shifts: np.ndarray) -> np.ndarray:
    """Each view moved by ``shifts``: ``p_k(u) = P_k(u + d_k)``, the sign of :mod:`nanoct.sim.analytic`, edges held."""
    columns = np.arange(sino.shape[-1], dtype=np.float64)
    out = np.empty_like(sino)
    for k, d in enumerate(shifts):
        for r in range(sino.shape[0]):
            out[r, k] = np.interp(columns + d, columns, sino[r, k])
    return out


def _motion_check(clean: np.ndarray, angles: np.ndarray, axis: float, truth: np.ndarray | None) -> dict:
    """Select between no motion and the centroid shifts; the kept one's gauge-free error from ``truth``."""
    binning = score_binning(clean.shape[2])
    rows = object_rows(clean)  # as the stack does: rows of air hold no centroid
    _, centroid, _ = centroid_motion(clean[rows] if rows.any() else clean, angles)
    candidates = [Candidate("none", axis, None, "none"), Candidate("centroid", axis, centroid, "shifts")]
    selection = select(
        candidates,
        lambda c, split: heldout_misfit(clean, angles, c.center_offset, c.shifts, split=split, binning=binning),
    )
    kept = selection.chosen.shifts if selection.chosen.shifts is not None else np.zeros_like(angles)
    error = None if truth is None else float(np.sqrt(np.mean(_gauge_free(kept - truth, angles) ** 2)))
    return {"kept": selection.chosen.name, "decided": selection.decided, "error": error, "scores": selection.scores}


def main(names: list[str]) -> None:
    """Print one table over every real scan present (or those whose name contains one of ``names``)."""
    rng = np.random.default_rng(0)
    print("| scan | estimates (score) | kept | decided | off reference | still: kept | moved: kept | error px | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, load in scans().items():
        if names and not any(n in name for n in names):
            continue
        start = time.perf_counter()
        sino, angles = load()
        rows = sino[axis_rows(sino.shape[0])]
        estimate = estimate_axis(rows, angles)
        values = ", ".join(
            f"{k} {v:+.2f} ({estimate.scores[k]:.5f})" if k in estimate.scores else f"{k} {v:+.2f}"
            for k, v in estimate.estimates.items()
        )
        ref = REFERENCES.get(name)
        if ref is None and {"mirror", "vo"} <= set(estimate.estimates):
            ref = (estimate.estimates["mirror"] + estimate.estimates["vo"]) / 2
        off = "-" if ref is None else f"{estimate.offset - ref:+.2f}"
        clean, _ = remove_air(rows, zero_air=True)
        still = _motion_check(clean, angles, estimate.offset, None)
        truth = 2.0 * np.sin(2 * angles) * np.exp(-0.3 * np.arange(angles.size) / angles.size)
        truth = truth + 0.3 * rng.standard_normal(angles.size)
        moved = _motion_check(_moved(clean, truth), angles, estimate.offset, truth)
        print(
            f"| {name} | {values} | {'+'.join(estimate.used)} {estimate.offset:+.2f} | {estimate.decided} | {off} | "
            f"{still['kept']} | {moved['kept']} | {moved['error']:.3f} | {time.perf_counter() - start:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main(sys.argv[1:])
