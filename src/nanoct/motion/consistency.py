"""A truth-free check of a scan's geometry: how well one half of the views predicts the other.

Every estimate of the rotation axis and of the per-view motion is a hypothesis about the
measured data. :func:`heldout_misfit` tests one the same way for every candidate: the views are
split into two interleaved halves; the slices are reconstructed (FBP, Hann-apodised ramp) from
one half with its shifts and reprojected to the other half's angles with theirs, and the misfit
with the measured views of that half is summed, both ways round. A wrong axis or a wrong shift
moves the reconstruction of one half away from the views of the other, so the misfit grows; noise
and the FBP's own error add the same floor to every candidate, which cancels in a comparison.

The score is one minus the normalised correlation of each held-out view with its prediction,
averaged over the views. A correlation, not a squared misfit: where the prediction is poor (too few
views for the object's width, an object wider than the field of view, reconstructed from columns
edge-extended by :data:`PAD_FRACTION`) a squared misfit rewards a wrong axis, whose blurred,
weaker prediction hedges (measured on Diamond I12's dendrite cut to 600 columns, where the squared
misfit fell steadily away from the axis), while a correlation is blind to the prediction's scale
and falls only where its structure departs from the data.

Two candidates are compared view by view (:func:`compare`). The noise of the difference of their
totals is estimated twice, and the smaller estimate counts: from blocks of contiguous views
(``sqrt(B)`` times the spread of the ``B`` block sums; views close in angle share their errors, so
blocks, not single views, are independent), which also counts as noise how a real difference
varies with the angle (a wrong axis hurts some directions more than others: on noise-free
ellipses a 2-pixel error of the axis read as only 1.8 times this noise); and from the differences
of views two apart (``sqrt(K mean((d[k+2] - d[k])^2) / 2)``), blind to a difference that varies
slowly with the angle but which counts as noise a difference that varies from view to view (the
harm of spurious per-view shifts). A difference within :data:`NOISE_FACTOR` times that noise
cannot be decided by the data. :func:`select` keeps the simplest candidate that no more
complex one beats beyond the noise, and checks the choice on another interleave of the views
(``split="pairs"``), which the selection did not use.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from ..core.geometry import Geometry
from ..core.validation import check_choice
from ..recon.stack import bin_sinograms, corrected_fbp, reproject

__all__ = [
    "LEVELS",
    "NOISE_FACTOR",
    "Candidate",
    "Comparison",
    "Consistency",
    "Selection",
    "compare",
    "heldout_misfit",
    "score_binning",
    "select",
]

#: A difference of scores counts only beyond this many times its noise.
NOISE_FACTOR = 3.0

#: Each side of the detector is extended by its edge values over this fraction of its width
#: before the reconstruction (an object wider than the field of view, cut at the edges).
PAD_FRACTION = 0.25

#: Scores are computed on the detector binned to at most this many columns (:func:`score_binning`) ...
SCORE_COLUMNS = 256

#: ... and on at most this many views (every ``ceil(K / SCORE_VIEWS)``-th): a full-size scan of 2048
#: columns and 1800 views costs about a second a candidate on 2 cores, not a minute.
SCORE_VIEWS = 512

#: The candidates' simplicity, simplest first: a more complex one must fit better beyond the noise.
LEVELS = ("none", "axis", "model", "shifts")

#: The interleaves of the views: ``alternate`` (even / odd views) and ``pairs`` (views 0, 1, 4, 5,
#: ... / 2, 3, 6, 7, ...), which selection and check use in turn.
SPLITS = ("alternate", "pairs")


@dataclass(frozen=True)
class Consistency:
    """The held-out misfit of one candidate geometry.

    Attributes
    ----------
    score : float
        Mean over the views of one minus the held-out correlation, both halves (0 = perfect).
    per_view : ndarray of shape (K',)
        Each scored view's term of that mean (sums to ``score``; every view, or every
        ``ceil(K / max_views)``-th, a repeated angle once).
    split : str
        The interleave of the views (:data:`SPLITS`).
    """

    score: float
    per_view: np.ndarray
    split: str


@dataclass(frozen=True)
class Comparison:
    """Candidate ``a`` against ``b`` on the same views: ``difference`` < 0 where ``a`` fits better."""

    difference: float
    noise: float

    @property
    def better(self) -> bool:
        """``a`` fits better than ``b`` beyond :data:`NOISE_FACTOR` times the noise."""
        return self.difference < -NOISE_FACTOR * self.noise

    @property
    def worse(self) -> bool:
        """``a`` fits worse than ``b`` beyond :data:`NOISE_FACTOR` times the noise."""
        return self.difference > NOISE_FACTOR * self.noise


def _halves(n_views: int, split: str) -> tuple[np.ndarray, np.ndarray]:
    check_choice(split, "split", SPLITS)
    index = np.arange(n_views)
    first = index % 2 == 0 if split == "alternate" else index % 4 < 2
    return index[first], index[~first]


def heldout_misfit(
    sinograms: Any,
    angles: Any,
    center_offset: float,
    shifts: Any = None,
    *,
    split: str = "alternate",
    binning: int = 1,
    max_views: int = SCORE_VIEWS,
) -> Consistency:
    """The held-out misfit of a candidate axis and per-view shifts (see the module docstring).

    Parameters
    ----------
    sinograms : array_like of shape (S, K, L) or (K, L)
        Line integrals of a few rows, air at zero (:func:`~nanoct.motion.axis.remove_air`).
    angles : array_like of shape (K,)
        View angles in radians.
    center_offset : float
        Candidate rotation axis minus the detector centre (detector pixels, unbinned).
    shifts : array_like of shape (K,), optional
        Candidate horizontal shift per view (detector pixels, unbinned; view ``k`` of the object
        moved by ``d_k``), zero where omitted.
    split : {"alternate", "pairs"}
        The interleave of the views.
    binning : int
        Detector binning applied first (faster, blind below ``binning`` pixels).
    max_views : int
        At most this many views are scored: every ``ceil(K / max_views)``-th, and of views at the
        same angle (modulo 360 degrees, e.g. a last view at 360) only the first.

    Returns
    -------
    Consistency
    """
    sino = np.asarray(sinograms, dtype=np.float32)
    sino = sino[None] if sino.ndim == 2 else sino
    phi = np.asarray(angles, dtype=np.float64)
    if sino.ndim != 3 or sino.shape[1] != phi.size or phi.size < 8:
        raise NanoctError(f"sinograms of shape {sino.shape} and {phi.size} angles: need (S, K, L) with K >= 8")
    d = np.zeros(phi.size) if shifts is None else np.asarray(shifts, dtype=np.float64)
    if d.shape != phi.shape or not np.isfinite(d).all():
        raise NanoctError(f"shifts of shape {d.shape} do not match {phi.size} views (or are not finite)")
    axis = (sino.shape[2] - 1) / 2 + center_offset  # detector column of the axis, unbinned
    step = -(-phi.size // max_views)  # every step-th view: the cost does not grow with the scan
    _, first = np.unique(np.round(np.mod(phi[::step], 2 * np.pi), 12), return_index=True)
    views = np.arange(phi.size)[::step][np.sort(first)]  # a view at 360 degrees repeats the one at 0: once
    sino, phi, d = sino[:, views], phi[views], d[views]
    if binning > 1:
        sino = bin_sinograms(sino, binning)
    n_det = sino.shape[2]
    pad = int(round(PAD_FRACTION * n_det))
    wide = np.pad(sino, ((0, 0), (0, 0), (pad, pad)), mode="edge")
    centre = (axis + 0.5) / binning - 0.5 - (n_det - 1) / 2
    cross, norm_p, norm_s = (np.zeros(phi.size) for _ in range(3))
    first, second = _halves(phi.size, split)
    for source, target in ((first, second), (second, first)):
        rec_geometry = Geometry.from_angles(phi[source], wide.shape[2], wide.shape[2], center_offset=centre)
        out_geometry = Geometry.from_angles(phi[target], wide.shape[2], wide.shape[2], center_offset=centre)
        for row in range(sino.shape[0]):
            image = corrected_fbp(rec_geometry, wide[row][source], d[source] / binning, filter="hann")
            predicted = reproject(out_geometry, image, d[target] / binning)[:, pad : pad + n_det].astype(np.float64)
            measured = sino[row][target].astype(np.float64)
            cross[target] += np.sum(predicted * measured, axis=1)
            norm_p[target] += np.sum(predicted**2, axis=1)
            norm_s[target] += np.sum(measured**2, axis=1)
    per_view = (1 - cross / np.sqrt(np.maximum(norm_p * norm_s, np.finfo(float).tiny))) / phi.size
    return Consistency(float(per_view.sum()), per_view, split)


def score_binning(n_det: int, max_columns: int = SCORE_COLUMNS) -> int:
    """The smallest detector binning that leaves at most ``max_columns`` columns."""
    return max(1, -(-n_det // max_columns))


def compare(a: Consistency, b: Consistency, blocks: int = 16) -> Comparison:
    """``a``'s score minus ``b``'s, with the noise of that difference from blocks of contiguous views.

    Parameters
    ----------
    a, b : Consistency
        Two candidates scored on the same views and split.
    blocks : int
        Number of blocks of contiguous views (in the views' order) the noise is estimated from.

    Returns
    -------
    Comparison
    """
    if a.per_view.shape != b.per_view.shape or a.split != b.split:
        raise NanoctError("the two candidates were not scored on the same views and split")
    diff = a.per_view - b.per_view
    sums = np.array([chunk.sum() for chunk in np.array_split(diff, min(blocks, diff.size))])
    by_blocks = np.sqrt(sums.size) * sums.std(ddof=1)
    by_neighbours = np.sqrt(diff.size * np.mean((diff[2:] - diff[:-2]) ** 2) / 2)
    return Comparison(float(diff.sum()), float(min(by_blocks, by_neighbours)))


@dataclass(frozen=True)
class Candidate:
    """One hypothesis about the scan's geometry.

    Attributes
    ----------
    name : str
        Who proposed it (``"none"``, ``"mirror"``, ``"centroid"``, ``"projection matching"``, ...).
    center_offset : float
        Rotation axis minus the detector centre (detector pixels).
    shifts : ndarray of shape (K,) or None
        Horizontal shift per view; ``None`` for a still object.
    level : str
        Its simplicity (:data:`LEVELS`).
    """

    name: str
    center_offset: float
    shifts: np.ndarray | None = None
    level: str = "axis"


@dataclass(frozen=True)
class Selection:
    """The candidate kept and why.

    Attributes
    ----------
    chosen : Candidate
    scores : dict of str to float
        Every candidate's score on the selection split.
    decided : bool
        The chosen candidate beats every simpler one beyond the noise, or is the simplest
        (``False``: the data cannot tell the chosen one from a simpler one it is kept over).
    check : dict
        The choice against the simplest candidate on the other split: ``difference``, ``noise``,
        ``worse`` (the chosen one fits worse there beyond the noise).
    notes : tuple of str
        In words: which candidates were rejected and why.
    """

    chosen: Candidate
    scores: dict[str, float]
    decided: bool
    check: dict[str, Any] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record."""
        return {
            "chosen": self.chosen.name,
            "center_offset": self.chosen.center_offset,
            "scores": dict(self.scores),
            "decided": self.decided,
            "check": dict(self.check),
            "notes": list(self.notes),
        }


def select(
    candidates: Sequence[Candidate],
    score: Callable[[Candidate, str], Consistency],
    prefer: Candidate | None = None,
) -> Selection:
    """The most consistent candidate, a more complex one only where it is better beyond the noise.

    Candidates are taken level by level (:data:`LEVELS`); within a level the lowest score wins. The
    best of a higher level replaces the current choice only where :func:`compare` finds it better.
    With ``prefer`` (an estimate to keep unless the data speak against it), that choice replaces
    ``prefer`` only where ``prefer`` fits worse than it beyond the noise; else ``prefer`` is kept,
    undecided. The final choice is then compared with the simplest candidate on the other split.

    Parameters
    ----------
    candidates : sequence of Candidate
        At least one; names unique.
    score : callable
        ``score(candidate, split)`` -> :class:`Consistency` (e.g. :func:`heldout_misfit` bound to
        the scan's rows); each candidate and split is asked for once.
    prefer : Candidate, optional
        One of ``candidates``.

    Returns
    -------
    Selection
    """
    if not candidates:
        raise NanoctError("no candidate geometry to select from")
    scored = {c.name: score(c, "alternate") for c in candidates}
    order = sorted(candidates, key=lambda c: LEVELS.index(c.level))
    chosen, decided, notes = None, True, []
    for level in LEVELS:
        group = [c for c in order if c.level == level]
        if not group:
            continue
        best = min(group, key=lambda c: scored[c.name].score)
        if chosen is None:
            chosen = best
            continue
        result = compare(scored[best.name], scored[chosen.name])
        if result.better:
            chosen = best
        else:
            verdict = "fits worse" if result.worse else "is not better beyond the noise"
            notes.append(
                f"{best.name} {verdict} than {chosen.name} ({result.difference:+.2e}, noise {result.noise:.1e})"
            )
            decided = decided and result.worse
    assert chosen is not None
    if prefer is not None and chosen is not prefer:
        result = compare(scored[prefer.name], scored[chosen.name])
        if result.worse:
            change = f"{result.difference:+.2e}, noise {result.noise:.1e}"
            notes.append(f"{prefer.name} dropped for {chosen.name} ({change})")
        else:
            chosen, decided = prefer, False
    simplest = order[0]
    check: dict[str, Any] = {"against": simplest.name}
    if chosen is not simplest:
        other = compare(score(chosen, "pairs"), score(simplest, "pairs"))
        check.update(difference=other.difference, noise=other.noise, worse=other.worse)
        if other.worse:
            notes.append(f"warning: on another interleave of the views {chosen.name} fits worse than {simplest.name}")
    return Selection(chosen, {k: v.score for k, v in scored.items()}, decided, check, tuple(notes))
