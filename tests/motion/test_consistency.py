"""The held-out consistency score and the selection by it, on exact line integrals of ellipses."""

from __future__ import annotations

import numpy as np
import pytest

from nanoct.core.errors import NanoctError
from nanoct.motion.consistency import Candidate, compare, heldout_misfit, score_binning, select
from nanoct.sim.analytic import ellipse_sinogram, stack_phantom

L, K, OFFSET = 96, 120, 4.3
ANGLES = np.arange(K) * np.pi / K


def _sinograms(shifts=None, offset=OFFSET, noise=0.0, seed=0):
    rows = np.stack(
        [ellipse_sinogram(e, ANGLES, L, center_offset=offset, shifts=shifts) for e in stack_phantom(72, 2, seed=3)]
    )
    return rows + noise * np.random.default_rng(seed).standard_normal(rows.shape)


def _motion():
    return 2.0 * np.sin(3 * ANGLES) * np.exp(-ANGLES) + 0.4 * np.random.default_rng(1).standard_normal(K)


def test_the_true_axis_scores_best():
    sino = _sinograms()
    scores = {c: heldout_misfit(sino, ANGLES, c).score for c in (OFFSET - 2, OFFSET - 0.5, OFFSET, OFFSET + 0.5)}
    assert min(scores, key=scores.get) == OFFSET
    better = compare(heldout_misfit(sino, ANGLES, OFFSET), heldout_misfit(sino, ANGLES, OFFSET + 2))
    assert better.better and not better.worse


def test_the_true_motion_beats_none_and_its_opposite():
    """A sign error in how the shifts enter the reconstruction or the reprojection would favour ``-d``."""
    d = _motion()
    sino = _sinograms(shifts=d)
    true, none, opposite = (heldout_misfit(sino, ANGLES, OFFSET, s) for s in (d, None, -d))
    assert compare(true, none).better and compare(true, opposite).better
    assert true.per_view.sum() == pytest.approx(true.score) and true.per_view.shape == (K,)


def test_the_other_interleave_agrees():
    d = _motion()
    sino = _sinograms(shifts=d)
    pairs = [heldout_misfit(sino, ANGLES, OFFSET, s, split="pairs") for s in (d, None)]
    assert compare(*pairs).better


def test_selection_keeps_no_motion_on_a_still_noisy_scan():
    sino = _sinograms(noise=0.02)
    spurious = 0.8 * np.random.default_rng(5).standard_normal(K)
    candidates = [Candidate("none", OFFSET, None, "none"), Candidate("shifts", OFFSET, spurious, "shifts")]
    selection = select(
        candidates, lambda c, split: heldout_misfit(sino, ANGLES, c.center_offset, c.shifts, split=split)
    )
    assert selection.chosen.name == "none" and selection.decided
    assert selection.scores["shifts"] > selection.scores["none"]
    assert any("shifts fits worse" in note for note in selection.notes)


def test_selection_takes_the_motion_where_the_data_support_it():
    d = _motion()
    sino = _sinograms(shifts=d, noise=0.02)
    candidates = [
        Candidate("none", OFFSET, None, "none"),
        Candidate("axis only", OFFSET + 0.1, None, "axis"),
        Candidate("shifts", OFFSET, d, "shifts"),
    ]
    selection = select(
        candidates, lambda c, split: heldout_misfit(sino, ANGLES, c.center_offset, c.shifts, split=split)
    )
    assert selection.chosen.name == "shifts"
    assert selection.check["against"] == "none" and not selection.check["worse"]
    record = selection.to_dict()
    assert record["chosen"] == "shifts" and set(record["scores"]) == {"none", "axis only", "shifts"}


def test_a_preferred_estimate_is_dropped_only_where_it_fits_worse():
    sino = _sinograms(noise=0.02)

    def score(c, split):
        return heldout_misfit(sino, ANGLES, c.center_offset, c.shifts, split=split)

    none = Candidate("none", OFFSET, None, "none")
    spurious = Candidate("shifts", OFFSET, 0.8 * np.random.default_rng(5).standard_normal(K), "shifts")
    dropped = select([none, spurious], score, prefer=spurious)
    assert dropped.chosen is none and any("shifts dropped for none" in note for note in dropped.notes)
    slight = Candidate("shifts", OFFSET, np.full(K, 1e-4), "shifts")  # indistinguishable from none
    kept = select([none, slight], score, prefer=slight)
    assert kept.chosen is slight and not kept.decided and kept.check["against"] == "none"
    assert select([none, slight], score).chosen is none  # without a preference the simpler one


def test_a_full_turn_with_its_last_view_at_360_degrees_is_scored():
    """Views at 0 and 360 degrees (a real neutron scan's layout) would put one angle twice into a half."""
    angles = np.linspace(0, 2 * np.pi, 121)
    sino = np.stack([ellipse_sinogram(e, angles, L, center_offset=OFFSET) for e in stack_phantom(72, 1, seed=3)])
    true, off = (heldout_misfit(sino, angles, c) for c in (OFFSET, OFFSET + 2))
    assert true.per_view.shape == (120,) and compare(true, off).better


def test_binning_and_bad_input():
    assert score_binning(256) == 1 and score_binning(257) == 2 and score_binning(627) == 3 and score_binning(2048) == 8
    sino = _sinograms()
    with pytest.raises(NanoctError, match="need .S, K, L."):
        heldout_misfit(sino[:, :4], ANGLES[:4], 0.0)
    with pytest.raises(NanoctError, match="shifts of shape"):
        heldout_misfit(sino, ANGLES, 0.0, np.zeros(3))
    with pytest.raises(NanoctError, match="shifts"):
        heldout_misfit(sino, ANGLES, 0.0, np.full(K, np.nan))
    a = heldout_misfit(sino, ANGLES, 0.0)
    with pytest.raises(NanoctError, match="same views and split"):
        compare(a, heldout_misfit(sino, ANGLES, 0.0, split="pairs"))
    with pytest.raises(NanoctError, match="no candidate"):
        select([], lambda c, s: a)
