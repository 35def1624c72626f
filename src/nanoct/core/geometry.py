"""Scan geometries (parallel and fan beam) and their presets.

Conventions (the one place they are defined; see ``docs/conventions.md``)
--------------------------------------------------------------------------
* Units are image pixels. The image is ``x[row, col]`` of shape (N, N), centred on the
  rotation axis, with physical coordinates ``r1 = col - (N-1)/2`` (to the right) and
  ``r2 = (N-1)/2 - row`` (upwards).
* A sinogram is ``y[k, l]`` of shape (K angles, L detector pixels).
* View ``k`` has angle ``phi_k = k * angle_range / K`` (counter-clockwise from the r1 axis), or
  the ``k``-th entry of ``view_angles`` when a scan gives its angles explicitly (any order,
  any range, radians).
  In parallel beam the detector coordinate of a point r is ``s = r1 cos(phi) + r2 sin(phi)``
  and detector pixel ``l`` is centred at ``s = (l - (L-1)/2 - center_offset) * det_spacing``:
  the rotation axis is seen at pixel ``(L-1)/2 + center_offset`` (``center_offset`` > 0: the
  axis lies towards higher detector indices; TomoPy's ``center`` is ``(L-1)/2 + center_offset``).
  In fan beam the source sits at ``source_radius * (sin(phi), -cos(phi))`` and the flat
  detector, centred at ``detector_radius * (-sin(phi), cos(phi))``, has its pixel axis along
  ``(cos(phi), sin(phi))``; at ``phi = 0`` the rays travel upwards (+r2).
  These are ASTRA's ``parallel`` / ``fanflat`` conventions, used through its ``*_vec`` forms.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any, Literal

import numpy as np

from .validation import check_int

__all__ = ["PRESETS", "UNIFORM_ATOL", "Geometry", "get_preset", "preset_names", "remove_translation"]

#: Angles within this many radians of a uniform scan are taken as that scan (1e-6 rad: far
#: below any motor's accuracy, far above float rounding of degrees read from a file).
UNIFORM_ATOL = 1e-6

Kind = Literal["parallel", "fan"]

# The paper's geometries (table "Parallel and fan beam geometry").
_PAPER_N = 255
_PAPER = {
    "parallel": {"n_angles": 567, "n_det": 363},
    "fan": {"n_angles": 133, "n_det": 723, "source_radius": 7773.4},
}


@dataclass(frozen=True)
class Geometry:
    """Immutable description of a 2D scan geometry.

    Parameters
    ----------
    kind : {"parallel", "fan"}
        Beam geometry.
    n : int
        Image size N (the image is N x N pixels of unit size).
    n_angles : int
        Number of views K.
    n_det : int
        Number of detector pixels L.
    det_spacing : float
        Detector pixel size in image pixels (on the detector, i.e. not demagnified).
    angle_range : float
        Views are spread uniformly over ``[0, angle_range)`` (pi for parallel, 2 pi for fan).
    source_radius : float
        Distance source - rotation axis in pixels (fan beam only, else 0).
    detector_radius : float
        Distance rotation axis - detector in pixels (fan beam only, else 0).
    view_angles : tuple of float, optional
        Explicit view angles in radians (K of them, any order and range), as a measured scan
        gives them; ``None`` spreads the views uniformly over ``[0, angle_range)``.
    center_offset : float
        Position of the rotation axis on the detector relative to its centre, in detector
        pixels (see the module docstring for the sign).

    Notes
    -----
    ``view_angles`` and ``center_offset`` are left out of :meth:`to_dict` (and so of cache
    keys and stored data sets) while they have their defaults, so the presets' descriptions
    are the same as before these fields existed.
    """

    kind: Kind
    n: int
    n_angles: int
    n_det: int
    det_spacing: float = 1.0
    angle_range: float = math.pi
    source_radius: float = 0.0
    detector_radius: float = 0.0
    view_angles: tuple[float, ...] | None = None
    center_offset: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in ("parallel", "fan"):
            raise ValueError(f"geometry kind {self.kind!r} is unknown; use 'parallel' or 'fan'")
        for name in ("n", "n_angles", "n_det"):  # plain ints: JSON and cache keys
            object.__setattr__(self, name, check_int(getattr(self, name), name, 1))
        for name in ("det_spacing", "angle_range", "source_radius", "detector_radius", "center_offset"):
            value = getattr(self, name)
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise ValueError(f"{name}={value!r} must be a number")
            object.__setattr__(self, name, float(value))
        if not self.det_spacing > 0:
            raise ValueError(f"det_spacing={self.det_spacing!r} must be > 0")
        if not 0 < self.angle_range <= 2 * math.pi + 1e-12:
            raise ValueError(f"angle_range={self.angle_range!r} must lie in (0, 2 pi]")
        if self.kind == "fan":
            if not self.source_radius > self.n * math.sqrt(0.5):
                raise ValueError(
                    f"source_radius={self.source_radius!r} must exceed the image half-diagonal "
                    f"{self.n * math.sqrt(0.5):.1f} px"
                )
            if not self.detector_radius >= 0:
                raise ValueError(f"detector_radius={self.detector_radius!r} must be >= 0")
        if not math.isfinite(self.center_offset):
            raise ValueError(f"center_offset={self.center_offset!r} must be a finite number of detector pixels")
        if self.view_angles is not None:
            self._check_view_angles()

    def _check_view_angles(self) -> None:
        angles = np.asarray(self.view_angles, dtype=np.float64)
        if angles.ndim != 1 or angles.size != self.n_angles:
            raise ValueError(
                f"view_angles has {angles.size} value(s) but n_angles={self.n_angles}; give one angle per view"
            )
        if not np.isfinite(angles).all():
            raise ValueError("view_angles contains NaN or infinite values")
        if np.unique(np.round(np.mod(angles, 2 * math.pi), 12)).size != angles.size:
            raise ValueError("view_angles repeats an angle (modulo 2 pi); each view needs its own angle")
        object.__setattr__(self, "view_angles", tuple(float(a) for a in angles))

    # ------------------------------------------------------------------ derived values
    @property
    def angles(self) -> np.ndarray:
        """View angles ``phi_k`` in radians, shape (K,), float64."""
        if self.view_angles is not None:
            return np.array(self.view_angles, dtype=np.float64)
        return np.arange(self.n_angles) * (self.angle_range / self.n_angles)

    @property
    def angle_weights(self) -> np.ndarray:
        """Angular quadrature weight of each view in radians, shape (K,), float64.

        Uniform views get ``angle_range / K`` each (scaled by ``period / angle_range`` for a
        scan over more than the period). Explicit ``view_angles`` get half the gap
        to each angular neighbour on the circle of period ``pi`` (parallel beam, opposite
        rays carry the same data) or ``2 pi`` (fan beam), scaled so that the weights add up to
        ``pi`` (parallel) or ``2 pi`` (fan): a scan over more than the period (e.g. 360 degrees
        in parallel beam) then counts every direction once on average.
        """
        period = math.pi if self.kind == "parallel" else 2 * math.pi
        if self.view_angles is None:  # a scan over more than the period sees every direction more than once
            return np.full(self.n_angles, self.angle_range / self.n_angles * min(1.0, period / self.angle_range))
        phase = np.mod(self.angles, period)
        order = np.argsort(phase, kind="stable")
        sorted_phase = phase[order]
        gaps = np.diff(np.concatenate([sorted_phase, sorted_phase[:1] + period]))  # gap to the next view
        half = 0.5 * (gaps + np.roll(gaps, 1))
        weights = np.empty(self.n_angles)
        weights[order] = half
        return weights * (period / weights.sum())

    @property
    def image_shape(self) -> tuple[int, int]:
        """Shape (N, N) of an image."""
        return (self.n, self.n)

    @property
    def sino_shape(self) -> tuple[int, int]:
        """Shape (K, L) of a sinogram."""
        return (self.n_angles, self.n_det)

    @property
    def magnification(self) -> float:
        """Geometric magnification at the rotation axis (1 for parallel beam)."""
        if self.kind == "parallel":
            return 1.0
        return (self.source_radius + self.detector_radius) / self.source_radius

    def covers_image(self) -> bool:
        """Whether every ray through the image is measured.

        True when the shadow of the image's circumscribed circle lies within the centres of
        the outermost detector pixels, so these pixels only see rays that miss the image.
        """
        radius = (self.n / 2) * math.sqrt(2.0)
        half_det = (self.n_det - 1) * self.det_spacing / 2
        if self.kind == "parallel":
            return half_det >= radius
        src = self.source_radius
        reach = (src + self.detector_radius) * radius / math.sqrt(src**2 - radius**2)
        return half_det >= reach

    # ------------------------------------------------------------------ (de)serialisation
    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON description (stored with every data set); scan fields only when set."""
        data = asdict(self)
        if self.view_angles is None:
            del data["view_angles"]
        else:
            data["view_angles"] = list(self.view_angles)
        if self.center_offset == 0.0:
            del data["center_offset"]
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Geometry:
        """Inverse of :meth:`to_dict`."""
        data = dict(data)
        if data.get("view_angles") is not None:
            data["view_angles"] = tuple(data["view_angles"])
        return cls(**data)

    @classmethod
    def from_angles(
        cls,
        angles: Any,
        n: int,
        n_det: int,
        *,
        kind: Kind = "parallel",
        degrees: bool = False,
        center_offset: float = 0.0,
        det_spacing: float = 1.0,
        source_radius: float = 0.0,
        detector_radius: float = 0.0,
    ) -> Geometry:
        """Geometry of a measured scan from its list of view angles.

        Parameters
        ----------
        angles : array_like of shape (K,)
            View angles, in radians unless ``degrees``; any order and range.
        n : int
            Reconstructed image size N.
        n_det : int
            Detector pixels L of one sinogram row.
        kind : {"parallel", "fan"}
            Beam geometry.
        degrees : bool
            The angles are in degrees (NXtomo, Data Exchange files and CIL use degrees).
        center_offset : float
            Rotation-axis position relative to the detector centre, in detector pixels.
        det_spacing, source_radius, detector_radius : float
            As in :class:`Geometry`.

        Returns
        -------
        Geometry
            Angles ``k * range / K`` (range pi or 2 pi, within :data:`UNIFORM_ATOL`) give the
            uniform geometry (``view_angles`` None), so that a scan with the views of a preset has
            the preset's geometry (and can use networks trained on it); any other angles are kept
            in ``view_angles`` (radians), with ``angle_range`` their span, for information.
        """
        values = np.asarray(angles, dtype=np.float64).ravel()
        if degrees:
            values = np.deg2rad(values)
        if values.size == 0:
            raise ValueError("angles is empty; a scan needs at least one view")
        full = math.pi if kind == "parallel" else 2 * math.pi
        for angle_range in dict.fromkeys((full, 2 * math.pi)):  # the uniform scans of the presets
            if np.allclose(values, np.arange(values.size) * (angle_range / values.size), rtol=0, atol=UNIFORM_ATOL):
                return cls(kind, n, values.size, n_det, det_spacing, angle_range, source_radius, detector_radius,
                           center_offset=center_offset)  # fmt: skip
        span = float(np.ptp(values)) * (1 + 1 / max(values.size - 1, 1)) if values.size > 1 else full
        return cls(
            kind, n, values.size, n_det, det_spacing, min(max(span, 1e-9), 2 * math.pi),
            source_radius, detector_radius, tuple(values.tolist()), center_offset,
        )  # fmt: skip

    def key(self) -> str:
        """Short stable string identifying the geometry (used in cache keys)."""
        d = self.to_dict()
        return "-".join(f"{k}={d[k]!r}" for k in sorted(d))


def _odd_at_least(value: float) -> int:
    m = math.ceil(value - 1e-9)
    return m if m % 2 == 1 else m + 1


def _scaled(kind: Kind, n: int) -> Geometry:
    """Paper geometry scaled to image size n, keeping the ratios K/N and L/N."""
    p = _PAPER[kind]
    scale = n / _PAPER_N
    n_angles = max(4, round(p["n_angles"] * scale))
    n_det = _odd_at_least(p["n_det"] * scale) if n != _PAPER_N else p["n_det"]
    if kind == "parallel":
        geometry = Geometry("parallel", n, n_angles, n_det)
    else:
        radius = p["source_radius"] * scale
        # The paper gives only the source radius. We put the detector as far behind the axis
        # as the source is in front of it (magnification 2) with 1 px detector pixels: then
        # the 723 pixels just cover the image's circumscribed circle, as the paper requires.
        geometry = Geometry("fan", n, n_angles, n_det, 1.0, 2 * math.pi, radius, radius)
    while not geometry.covers_image():  # rounding can leave the corners' shadow uncovered
        geometry = replace(geometry, n_det=geometry.n_det + 2)
    return geometry


PRESETS: dict[str, Geometry] = {
    f"{size}-{kind}": _scaled(kind, n)
    for size, n in (("paper", 255), ("small", 127), ("tiny", 63))
    for kind in ("parallel", "fan")
}


def preset_names() -> list[str]:
    """Names of the geometry presets."""
    return sorted(PRESETS)


def get_preset(name: str) -> Geometry:
    """Return the geometry preset ``name``.

    Raises
    ------
    ValueError
        If the preset is unknown; the message lists the known ones.
    """
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; choose one of: {', '.join(preset_names())}") from None


def remove_translation(shifts: Any, angles: Any) -> np.ndarray:
    """``shifts`` minus their least-squares fit ``a cos(phi) + b sin(phi)`` (a translation of the object).

    An object moved by ``(a, b)`` is seen at ``s = a cos(phi) + b sin(phi)`` along the detector (the
    conventions above), so per-view shifts that differ by this term describe the same motion up to where
    the object sits: what Dremel estimates per slice, and what the motion estimators compare.

    Parameters
    ----------
    shifts : array_like of shape (K,)
        Per-view shifts along the detector axis.
    angles : array_like of shape (K,)
        View angles in radians.

    Returns
    -------
    ndarray of shape (K,), float64
    """
    phi = np.asarray(angles, dtype=np.float64)
    s = np.asarray(shifts, dtype=np.float64)
    basis = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    coef, *_ = np.linalg.lstsq(basis, s, rcond=None)
    return s - basis @ coef
