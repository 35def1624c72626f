"""Measured data for the row-action methods: the open-beam level, objects wider than the field of view, noise.

A simulated sinogram is zero where the rays miss the object, the object lies inside the
reconstruction disc and the noise level is known. A measured scan breaks all three: after
flat/dark correction the open beam rarely reads zero absorbance (Diamond I13-2 scan 24737
reads about 0.38 in air, the flat being brighter than the projections' open beam), the object
is often wider than the detector (interior tomography, the normal case in nanoCT), and the
noise is unknown. To a Kaczmarz-type solver with ``x >= 0`` a per-view level across the whole
detector is an object filling it, and the cross-correlation of Dremel follows it.

:func:`prepare_measured` makes the data fit the model, with stated estimators:

1. **Open-beam level** (:func:`air_level`): per view, the median of the outermost
   ``EDGE_FRACTION`` of the detector pixels on both sides (``max(2, round(L / 10))`` pixels
   each) is taken as the air level and subtracted from the view. Where the object is wider
   than the detector these pixels see the object; the level subtracted then also holds the
   object's projection at the edges, which the extension below would otherwise have to carry.
2. **Objects wider than the field of view** (:func:`extend_sinogram`): each view is extended
   on both sides by ``pad`` pixels (default ``PAD_FRACTION * L``) from the mean of its three
   outermost pixels down to zero with a ``cos^2`` taper, and the image grid grows by as many
   pixels on each side (:func:`padded_geometry`), so the mass outside the field of view has
   pixels to go to; the reconstruction is cropped back to the requested grid.
3. **Noise** (:func:`noise_level`): the noise standard deviation per ray, estimated from the
   second differences along the detector (``1.4826 MAD / sqrt(6)``, exact for white noise
   on a locally linear signal; the smaller of the estimates over the whole detector and over
   its edge bands). Kaczmarz and Dremel stop by the discrepancy principle when
   the residual over the measured rays falls below ``DISCREPANCY_TAU * sigma * sqrt(K L)``;
   RESESOP takes ``sigma`` as its noise level ``delta`` unless one is given.

A motion estimated elsewhere (the stack's, or Dremel's own) is carried by reading each view at
``u - d_k`` (:func:`read_moved`, the edges held): RESESOP's ``shifts`` and the residual eta
estimate after that motion (:func:`~nanoct.recon.eta.eta_from_residual`) use it.

``measured="auto"`` (the methods' default) applies these, unless the caller gives the system
matrix, when :func:`looks_measured` finds a
non-zero level at the detector edges (open beam not at zero, or an object cut by the edges):
the per-view edge median exceeds ``DETECT_LEVEL`` times the sinogram's 99.9th percentile in
at least half of the views. A simulation (zero at the edges up to noise) is left exactly as
before. Measurements on a real scan: ``docs/reconstruction.md`` ("Measured data").
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..core.geometry import Geometry
from ..core.validation import check_array, check_choice, check_int
from .result import ReconResult

__all__ = [
    "DETECT_LEVEL",
    "DISCREPANCY_TAU",
    "EDGE_FRACTION",
    "MEASURED_MODES",
    "PAD_FRACTION",
    "MeasuredData",
    "air_level",
    "check_measured",
    "edge_width",
    "extend_sinogram",
    "looks_measured",
    "noise_level",
    "padded_geometry",
    "prepare_measured",
    "read_moved",
    "solve_measured",
]

#: ``measured`` parameter values: ``"auto"`` detects a measured sinogram, ``"on"`` / ``"off"`` force,
#: ``"extend"``: the extension and the noise rule without removing an air level.
MEASURED_MODES = ("auto", "on", "extend", "off")
#: Fraction of the detector width on each side whose per-view median is the air level.
EDGE_FRACTION = 0.1
#: Edge level (relative to the sinogram's 99.9th percentile) above which ``"auto"`` treats data as measured.
DETECT_LEVEL = 0.02
#: Default extension on each side, as a fraction of the detector width.
PAD_FRACTION = 0.25
#: Discrepancy factor of the noise stopping rule of Kaczmarz and Dremel.
DISCREPANCY_TAU = 1.1


def check_measured(measured: Any, pad: Any) -> tuple[str, int | None]:
    """Check the ``measured`` and ``pad`` parameters; raise ``ValueError`` naming the bad one."""
    measured = check_choice(measured, "measured", MEASURED_MODES)
    if pad is not None:
        pad = check_int(pad, "pad", 0)
    return measured, pad


def edge_width(n_det: int) -> int:
    """Number of detector pixels on each side whose median is the air level: ``max(2, round(L / 10))``."""
    return max(2, int(round(EDGE_FRACTION * n_det)))


def air_level(sino: np.ndarray) -> np.ndarray:
    """Per-view air (open-beam) level: the median of the :func:`edge_width` outermost pixels on both sides.

    Parameters
    ----------
    sino : ndarray of shape (K, L)

    Returns
    -------
    ndarray of shape (K,), float64
    """
    w = min(edge_width(sino.shape[1]), max(1, sino.shape[1] // 2))
    edges = np.concatenate([sino[:, :w], sino[:, -w:]], axis=1).astype(np.float64)
    return np.median(edges, axis=1)


def looks_measured(sino: np.ndarray) -> bool:
    """Whether a sinogram has a non-zero level at the detector edges (open beam not at zero, or truncation).

    True when ``|air_level|`` exceeds ``DETECT_LEVEL`` times the 99.9th percentile of ``|sino|``
    in at least half of the views.
    """
    scale = float(np.percentile(np.abs(sino), 99.9))
    if not scale > 0:
        return False
    return bool(np.mean(np.abs(air_level(sino)) > DETECT_LEVEL * scale) >= 0.5)


def noise_level(sino: np.ndarray) -> float:
    """Noise standard deviation per ray from the second differences along the detector.

    ``1.4826 * MAD(d) / sqrt(6)`` for the second differences ``d`` (exact for white noise on a
    locally linear signal), over the whole detector and over the two edge bands
    (:func:`edge_width`), whichever is smaller: the object's own curvature only raises the
    estimate, and the edge bands see the least of it.
    """
    y = np.asarray(sino, dtype=np.float64)
    if y.shape[1] < 3:
        return 0.0
    d = y[:, 2:] - 2.0 * y[:, 1:-1] + y[:, :-2]
    w = min(edge_width(y.shape[1]), d.shape[1] // 2)
    parts = [d, np.concatenate([d[:, :w], d[:, -w:]], axis=1)] if w > 0 else [d]
    return float(min(1.4826 * np.median(np.abs(p - np.median(p))) for p in parts) / math.sqrt(6.0))


def read_moved(sino: Any, shifts: Any, interpolation: str = "linear") -> np.ndarray:
    """Each view ``k`` read at ``u - d_k``: the views of a moved object as the unmoved one gives them.

    Beyond the detector's ends each view keeps its edge value (an open beam not at zero, or an
    object cut by the edges, is not turned into a step to 0). The same convention as
    :func:`~nanoct.recon.stack.corrected_fbp` and Dremel's ``motion`` (in detector pixels).

    Parameters
    ----------
    sino : array_like of shape (K, L)
    shifts : array_like of shape (K,)
        Per-view detector shifts ``d_k`` in detector pixels.
    interpolation : {"linear", "fourier"}
        ``"linear"`` (what the row-action methods model) low-passes a sub-pixel read: white
        noise keeps ``(1 - f)^2 + f^2`` of its variance at a fractional shift ``f`` (half at
        ``f = 1/2``). ``"fourier"`` is the band-limited shift (each view extended by its edge
        values by ``L // 2 + ceil(max |d_k|)`` pixels to an odd length, then a phase ramp of its
        DFT): an all-pass filter, so measured noise keeps its power spectrum (for data that must
        look as measured, e.g. :func:`nanoct.sim.matched.measured_pair`); equal to ``"linear"``
        for whole-pixel shifts away from the ends.

    Returns
    -------
    ndarray of shape (K, L), float64
    """
    y = np.asarray(sino, dtype=np.float64)
    d = check_array(shifts, "shifts", shape=(y.shape[0],), dtype=np.float64)
    check_choice(interpolation, "interpolation", ("linear", "fourier"))
    if not y.size:
        return y.copy()
    if interpolation == "fourier":
        n_det = y.shape[1]
        pad = n_det // 2 + math.ceil(float(np.abs(d).max()))
        extended = np.pad(y, ((0, 0), (pad, pad + (n_det + 1) % 2)), mode="edge")  # odd length: no Nyquist bin
        freq = np.fft.rfftfreq(extended.shape[1])
        spectrum = np.fft.rfft(extended, axis=1) * np.exp(-2j * np.pi * freq[None, :] * d[:, None])
        return np.fft.irfft(spectrum, extended.shape[1], axis=1)[:, pad : pad + n_det]
    u = np.arange(y.shape[1], dtype=np.float64)
    return np.stack([np.interp(u - dk, u, view) for view, dk in zip(y, d)])


def extend_sinogram(sino: np.ndarray, pad: int) -> np.ndarray:
    """Each view extended by ``pad`` pixels on each side, from its edge value to zero with a ``cos^2`` taper.

    The edge value is the mean of the three outermost pixels; the extension at distance
    ``j = 1 .. pad`` from the edge is ``edge * cos^2(pi j / (2 pad))`` (zero at ``j = pad``).

    Returns
    -------
    ndarray of shape (K, L + 2 pad), float32
    """
    if pad == 0:
        return np.asarray(sino, dtype=np.float32).copy()
    y = np.asarray(sino, dtype=np.float64)
    k = min(3, y.shape[1])
    taper = np.cos(0.5 * np.pi * np.arange(1, pad + 1) / pad) ** 2
    left = y[:, :k].mean(axis=1, keepdims=True) * taper[::-1]
    right = y[:, -k:].mean(axis=1, keepdims=True) * taper
    return np.concatenate([left, y, right], axis=1).astype(np.float32)


def padded_geometry(geometry: Geometry, pad: int) -> tuple[Geometry, int]:
    """The geometry with ``pad`` more detector pixels on each side and the image grown to match.

    Returns
    -------
    Geometry
        Same views, axis offset and pixel sizes; ``n_det + 2 pad`` detector pixels and an
        image ``2 m`` pixels wider, ``m = ceil(pad * det_spacing / magnification)``.
    int
        ``m``, the image pixels added on each side.
    """
    m = int(math.ceil(pad * geometry.det_spacing / geometry.magnification - 1e-9))
    data = geometry.to_dict()
    data.update(n=geometry.n + 2 * m, n_det=geometry.n_det + 2 * pad)
    return Geometry.from_dict(data), m


@dataclass(frozen=True)
class MeasuredData:
    """A measured sinogram made to fit the row-action model (:func:`prepare_measured`).

    Attributes
    ----------
    geometry : Geometry
        The padded geometry the solver runs on.
    sinogram : ndarray of shape (K, L + 2 pad), float32
        Air level removed, extended at the edges.
    air : ndarray of shape (K,)
        The air level removed from each view.
    pad : int
        Detector pixels added on each side.
    margin : int
        Image pixels added on each side.
    noise : float
        The estimated noise standard deviation per ray (:func:`noise_level`).
    n_rays : int
        Measured rays ``K L`` (the extension not counted).
    """

    geometry: Geometry
    sinogram: np.ndarray
    air: np.ndarray
    pad: int
    margin: int
    noise: float
    n_rays: int

    def pad_image(self, x0: Any) -> Any:
        """A start image of the requested grid, zero-padded to the solver's grid (None stays None)."""
        if x0 is None or self.margin == 0:
            return x0
        return np.pad(np.asarray(x0, dtype=np.float32), self.margin)

    def pad_eta(self, eta: Any) -> Any:
        """A per-ray eta (K, L) extended with its edge values; a per-view eta (K,) as it is."""
        arr = np.asarray(eta)
        if arr.ndim == 2 and self.pad:
            return np.pad(arr, ((0, 0), (self.pad, self.pad)), mode="edge")
        return eta

    def crop(self, image: np.ndarray) -> np.ndarray:
        """The solver's image cut back to the requested grid."""
        m = self.margin
        return image if m == 0 else np.ascontiguousarray(image[m:-m, m:-m])

    def discrepancy(self) -> float:
        """The residual bound of the noise stopping rule: ``DISCREPANCY_TAU * noise * sqrt(K L)``."""
        return DISCREPANCY_TAU * self.noise * math.sqrt(self.n_rays)

    def summary(self) -> dict[str, Any]:
        """What was done, for the result's ``params``."""
        return {
            "air_level_mean": float(self.air.mean()),
            "pad": self.pad,
            "noise": self.noise,
            "discrepancy": self.discrepancy(),
        }


def prepare_measured(geometry: Geometry, sino: np.ndarray, measured: str, pad: int | None) -> MeasuredData | None:
    """The measured-data treatment of ``sino`` (see the module docstring), or None where it does not apply.

    Parameters
    ----------
    geometry : Geometry
        The requested geometry.
    sino : ndarray of shape (K, L)
        The sinogram as given.
    measured : {"auto", "on", "extend", "off"}
        ``"auto"``: apply when :func:`looks_measured`; ``"on"``: always; ``"extend"``: always,
        but without removing an air level (an object wider than the detector, open beam at
        zero); ``"off"``: never (the data are used as given, as for a simulation).
    pad : int or None
        Detector pixels added on each side; None: ``round(PAD_FRACTION * L)``.

    Returns
    -------
    MeasuredData or None
    """
    if measured == "off" or (measured == "auto" and not looks_measured(sino)):
        return None
    y = np.asarray(sino, dtype=np.float64)
    air = np.zeros(y.shape[0]) if measured == "extend" else air_level(y)
    y = y - air[:, None]
    pad = int(round(PAD_FRACTION * geometry.n_det)) if pad is None else pad
    padded, margin = padded_geometry(geometry, pad)
    return MeasuredData(padded, extend_sinogram(y, pad), air, pad, margin, noise_level(y), int(y.size))


def solve_measured(
    solve: Callable[[MeasuredData, Any, Any], ReconResult],
    geometry: Geometry,
    sino: Any,
    params: dict[str, Any],
    *,
    x0: Any = None,
    callback: Callable[[int, np.ndarray, Any], Any] | None = None,
    matrix: Any = None,
) -> ReconResult | None:
    """Run a solver on the measured-data treatment of ``sino``, or return None where it does not apply.

    Parameters
    ----------
    solve : callable
        ``solve(data, x0, callback) -> ReconResult`` on ``data.geometry`` and ``data.sinogram``
        (the solver itself, called with ``measured="off"``).
    geometry : Geometry
        The requested geometry.
    sino : array_like of shape (K, L)
        The sinogram as given.
    params : dict
        The method's checked parameters (``measured``, ``pad``).
    x0, callback, matrix
        The solver's arguments for the requested grid; ``callback`` sees the cropped image.

    Returns
    -------
    ReconResult or None
        The result cropped to the requested grid, its ``params`` with ``measured`` and ``pad`` as
        requested (not the inner solver's ``"off"``) and ``params["measured_data"]`` holding
        :meth:`MeasuredData.summary`; None when ``params["measured"]`` does not apply
        (``"off"``, or ``"auto"`` with data that do not look measured or with a ``matrix``
        given: a caller that brings the system matrix brings its model).

    Raises
    ------
    ValueError
        A ``matrix`` given for data that need the extension (its grid would not match).
    """
    mode = params["measured"]
    if mode == "auto" and matrix is not None:  # a caller that brings its rays brings its model
        return None
    y = check_array(sino, "sinogram", shape=geometry.sino_shape)
    data = prepare_measured(geometry, y, mode, params["pad"])
    if data is None:
        return None
    if matrix is not None and data.pad:
        raise ValueError(
            "matrix= holds the rays of the requested grid, but measured data are extended at the detector edges; "
            "pass pad=0, measured='off', or no matrix"
        )

    def cropped(it: int, x: np.ndarray, extra: Any) -> Any:
        return callback(it, data.crop(x), extra)  # type: ignore[misc]

    result = solve(data, data.pad_image(x0), None if callback is None else cropped)
    outer = {"measured": params["measured"], "pad": params["pad"], "measured_data": data.summary()}
    return replace(result, image=data.crop(result.image), params={**result.params, **outer})
