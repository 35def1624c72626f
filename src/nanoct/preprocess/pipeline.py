"""The corrections of measured projections, in their order, described by one :class:`Corrections`.

Order (each step on what the previous one made)::

    flat/dark-normalised transmission (or raw counts with an open beam in view)
      1. outliers      remove_outliers       transmission, per projection   (--outliers)
      2. open beam     normalize_open_beam   transmission, per view         (--open-beam)
      3. Paganin       paganin               transmission, per projection   (--delta-beta ...)
      4. -log          line integrals = -log(max(t, 1e-6))
      5. stripes       remove_stripes        line integrals, per sinogram   (--stripes)

Outliers go first so that no zinger enters the air estimate or spreads through the Paganin
filter; Paganin needs the open beam at 1 (it filters ``I / I_0``); stripes are removed on the
``-log`` sinograms, where a detector pixel's gain error is an additive constant along the
angles. Every step is off by default: ``Corrections()`` changes nothing but taking ``-log``.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from .openbeam import estimate_open_beam, normalize_open_beam
from .outliers import OUTLIER_KINDS, remove_outliers
from .phase import paganin
from .stripes import remove_stripes, stripe_function

__all__ = ["CorrectionResult", "Corrections", "apply_corrections", "parse_columns", "parse_stripe_params"]

_FLOOR = 1e-6  # transmissions at or below 0 (dead pixels) are raised to this before -log


def parse_columns(text: str) -> tuple[tuple[int, int], ...]:
    """``"0:30,480:503"`` -> ``((0, 30), (480, 503))``: detector column ranges ``FIRST:STOP``.

    Raises
    ------
    NanoctError
        For text that is not comma-separated ``FIRST:STOP`` pairs of integers with FIRST < STOP.
    """
    ranges = []
    for part in str(text).split(","):
        try:
            first, stop = (int(value) for value in part.split(":"))
        except ValueError:
            raise NanoctError(f"--air-columns {text!r} must be FIRST:STOP[,FIRST:STOP...], e.g. 0:30,480:503") from None
        if not 0 <= first < stop:
            raise NanoctError(f"--air-columns range {part!r} must satisfy 0 <= FIRST < STOP")
        ranges.append((first, stop))
    return tuple(ranges)


def parse_stripe_params(text: str) -> dict[str, float]:
    """``"snr=3,la_size=61"`` -> ``{"snr": 3.0, "la_size": 61.0}`` (:class:`Corrections` casts them).

    Raises
    ------
    NanoctError
        For text that is not comma-separated ``NAME=NUMBER`` pairs.
    """
    params = {}
    for part in str(text).split(","):
        name, _, value = part.partition("=")
        try:
            params[name.strip()] = float(value)
        except ValueError:
            raise NanoctError(
                f"--stripe-params {text!r} must be NAME=NUMBER[,NAME=NUMBER...], e.g. snr=3,la_size=61"
            ) from None
    return params


@dataclass(frozen=True)
class Corrections:
    """Which corrections to apply to measured projections, with their parameters.

    Parameters
    ----------
    outliers : float, optional
        Outlier threshold in units of the robust pixel noise (:func:`remove_outliers`); None: off.
    outlier_size : int
        Median window width (odd).
    outlier_kind : {"both", "bright", "dark"}
        Which outliers to replace.
    open_beam : bool
        Divide each view by its open beam fitted to air (:func:`estimate_open_beam`).
    air_columns : tuple of (int, int), optional
        Detector columns ``[first, stop)`` that see only air; None: found automatically.
    open_beam_degree : {"auto", 0, 1, 2}
        Degree of the open-beam surface per view (0: one level; ``"auto"``: the highest degree
        each view's air determines, see :func:`estimate_open_beam`).
    delta_beta : float, optional
        Paganin's ``delta / beta``; None: no phase retrieval. Needs ``energy_kev``,
        ``distance_m`` and ``pixel_size_m``.
    energy_kev, distance_m, pixel_size_m : float, optional
        Photon energy (keV), propagation distance (m), detector pixel size (m) for Paganin.
    stripes : {"all", "sorting", "filtering", "fitting"}, optional
        Stripe-removal method (:func:`remove_stripes`); None: off.
    stripe_params : dict
        The stripe method's parameters by algotom's names; missing ones take the defaults.
    """

    outliers: float | None = None
    outlier_size: int = 3
    outlier_kind: str = "both"
    open_beam: bool = False
    air_columns: tuple[tuple[int, int], ...] | None = None
    open_beam_degree: int | str = "auto"
    delta_beta: float | None = None
    energy_kev: float | None = None
    distance_m: float | None = None
    pixel_size_m: float | None = None
    stripes: str | None = None
    stripe_params: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.outliers is not None and not self.outliers > 0:
            raise NanoctError(f"--outliers {self.outliers} must be > 0 (robust noise units)")
        if not (isinstance(self.outlier_size, int) and self.outlier_size >= 3 and self.outlier_size % 2):
            raise NanoctError(f"--outlier-size {self.outlier_size} must be an odd integer >= 3")
        if self.outlier_kind not in OUTLIER_KINDS:
            raise NanoctError(f"--outlier-kind {self.outlier_kind!r} must be one of {', '.join(OUTLIER_KINDS)}")
        if self.open_beam_degree not in (0, 1, 2, "auto"):
            raise NanoctError(f"--open-beam-degree {self.open_beam_degree} must be 0, 1, 2 or auto")
        if self.air_columns is not None:
            object.__setattr__(self, "air_columns", tuple((int(a), int(b)) for a, b in self.air_columns))
            if not self.open_beam:
                raise NanoctError("--air-columns needs --open-beam")
        paganin_args = (self.energy_kev, self.distance_m, self.pixel_size_m)
        if self.delta_beta is not None and None in paganin_args:
            raise NanoctError(
                "--delta-beta needs --energy-kev, --distance-m and --pixel-size-m (Paganin phase retrieval)"
            )
        if self.delta_beta is None and any(value is not None for value in paganin_args):
            raise NanoctError("--energy-kev, --distance-m and --pixel-size-m are used only with --delta-beta")
        if self.stripes is not None:  # the full parameter set, defaults filled in, is what is recorded
            object.__setattr__(self, "stripe_params", stripe_function(self.stripes, self.stripe_params)[1])
        elif self.stripe_params:
            raise NanoctError("stripe parameters are used only with --stripes")

    def __hash__(self) -> int:  # stripe_params is a dict: hash the record instead
        return hash(json.dumps(self.to_dict(), sort_keys=True))

    @property
    def any(self) -> bool:
        """Whether any correction is on."""
        return self != Corrections()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description (for a store's provenance); :meth:`from_dict` reads it back."""
        data = asdict(self)
        if self.air_columns is not None:
            data["air_columns"] = [list(pair) for pair in self.air_columns]
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Corrections:
        """The corrections described by :meth:`to_dict`'s output.

        Raises
        ------
        NanoctError
            For an unknown key or a bad value.
        """
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise NanoctError(f"unknown correction {unknown[0]!r}; known: {', '.join(sorted(names))}")
        values = dict(data)
        if values.get("air_columns") is not None:
            values["air_columns"] = tuple(tuple(pair) for pair in values["air_columns"])
        return cls(**values)


@dataclass(frozen=True)
class CorrectionResult:
    """What :func:`apply_corrections` made.

    Attributes
    ----------
    line_integrals : ndarray of shape (K, R, L), float32
        The corrected line integrals.
    notes : list of str
        One line per correction applied (what it did, in numbers), for the store's notes.
    open_beam_levels : ndarray of shape (K,) or None
        Each view's mean open beam before normalisation (in the input's units).
    """

    line_integrals: np.ndarray
    notes: list[str]
    open_beam_levels: np.ndarray | None = None


def _transmission_steps(data: np.ndarray, corr: Corrections, notes: list[str]) -> tuple[np.ndarray, Any]:
    """Steps 1-3 (outliers, open beam, Paganin) on transmissions."""
    levels = None
    if corr.outliers is not None:
        data, count = remove_outliers(data, threshold=corr.outliers, size=corr.outlier_size, kind=corr.outlier_kind)
        notes.append(f"outliers: {count} pixels ({count / data.size:.3%}) beyond {corr.outliers} noise units replaced")
    if corr.open_beam:
        columns = None if corr.air_columns is None else list(corr.air_columns)
        beam = estimate_open_beam(data, columns=columns, degree=corr.open_beam_degree)
        data, levels = normalize_open_beam(data, beam), beam.levels
        where = "automatic air" if columns is None else f"air columns {corr.air_columns}"
        notes.append(
            f"open beam ({where}, degree {corr.open_beam_degree}): level {levels.min():.4g} to {levels.max():.4g}, "
            f"air {beam.air_fraction.min():.0%} to {beam.air_fraction.max():.0%} of each view"
        )
    if corr.delta_beta is not None:
        data = paganin(
            data, delta_beta=corr.delta_beta, energy_kev=corr.energy_kev,
            distance_m=corr.distance_m, pixel_size_m=corr.pixel_size_m,
        )  # fmt: skip
        notes.append(
            f"Paganin: delta/beta {corr.delta_beta:g}, {corr.energy_kev:g} keV, {corr.distance_m:g} m, "
            f"pixel {corr.pixel_size_m:g} m"
        )
    return data, levels


def apply_corrections(data: np.ndarray, corrections: Corrections, *, kind: str = "transmission") -> CorrectionResult:
    """Apply ``corrections`` in their order (module docstring) and return line integrals.

    Parameters
    ----------
    data : ndarray of shape (K, R, L)
        Projections, views first: flat/dark-normalised transmissions (``kind="transmission"``;
        raw counts too when the open beam is normalised from air), or line integrals
        ``-log(transmission)`` (``kind="line_integrals"``; converted to transmissions by
        ``exp(-p)`` when a transmission step is on).
    corrections : Corrections
    kind : {"transmission", "line_integrals"}

    Returns
    -------
    CorrectionResult
        ``line_integrals`` ``-log(max(t, 1e-6))`` after steps 1-3, then step 5.

    Raises
    ------
    NanoctError
        For bad input or a correction that cannot be applied (e.g. no air found).
    """
    if kind not in ("transmission", "line_integrals"):
        raise NanoctError(f"kind {kind!r} must be 'transmission' or 'line_integrals'")
    data = np.asarray(data)
    if data.ndim != 3 or 0 in data.shape:
        raise NanoctError(f"projections of shape {data.shape} must be (views, rows, columns), none empty")
    notes: list[str] = []
    corr = corrections
    on_transmission = corr.outliers is not None or corr.open_beam or corr.delta_beta is not None
    if kind == "line_integrals" and not on_transmission:
        lines = data.astype(np.float32, copy=True)
        levels = None
    else:
        trans = np.exp(-data.astype(np.float64)) if kind == "line_integrals" else data.astype(np.float32)
        trans, levels = _transmission_steps(trans, corr, notes)
        low = ~(trans > _FLOOR)
        if low.any():
            notes.append(f"-log: {int(low.sum())} transmissions at or below {_FLOOR:g} raised to it")
        lines = (-np.log(np.maximum(trans, _FLOOR))).astype(np.float32)
    if corr.stripes is not None:
        lines = remove_stripes(lines, corr.stripes, corr.stripe_params)
        params = ", ".join(f"{key}={value}" for key, value in corr.stripe_params.items())
        notes.append(f"stripes: algotom {corr.stripes} ({params}) on {lines.shape[1]} sinograms")
    return CorrectionResult(line_integrals=lines, notes=notes, open_beam_levels=levels)
