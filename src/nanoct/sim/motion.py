"""Per-view rigid motion of the object: damped sinusoids plus Gaussian jitter.

The paper (section "Data set generation") moves the whole phantom at scan angle ``phi`` as

    x_perturbed(phi)(r) = x(R(theta(phi)) r + t(phi)),    t(phi) = xi_r(phi) + eps(phi),

where ``R`` is the counter-clockwise rotation in the (r1, r2) plane, ``eps`` is a sum of damped
sinusoids with random onsets (38 for parallel beam, 9 for fan beam) bounded in each of the r1-
and r2-directions, and ``xi_r``, ``theta`` are per-view Gaussian jitter whose standard
deviations are drawn once per sample from N(0.127, 0.0254^2).

A motion array has shape (K, 3), float32, one row per view in acquisition order, with columns
``(t1, t2, theta)``: shifts in pixels along r1 (right) and r2 (up), rotation in degrees.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.validation import check_int, check_rng

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = [
    "MotionParams",
    "sample_motion_components",
    "sample_motion",
    "no_motion",
    "rotation_matrix",
    "plot_motion",
    "N_SINUSOIDS",
]

#: Number of damped sinusoids per sample in the paper, by geometry kind.
N_SINUSOIDS = {"parallel": 38, "fan": 9}


def _check_range(name: str, value: tuple[float, float]) -> tuple[float, float]:
    try:
        low, high = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}={value!r} must be a pair (low, high) of numbers") from None
    if not (math.isfinite(low) and math.isfinite(high) and 0.0 <= low <= high):
        raise ValueError(f"{name}={value!r} must satisfy 0 <= low <= high (finite)")
    return (low, high)


@dataclass(frozen=True)
class MotionParams:
    """Distribution of the per-view rigid motion of one sample.

    Parameters
    ----------
    n_sinusoids : int, optional
        Number of damped sinusoids summed into ``eps`` (paper: 38 parallel, 9 fan; see
        :meth:`for_kind`). Default 38.
    max_shift : float, optional
        Bound in pixels on ``|eps|`` in each of the r1- and r2-directions. Default 2.0.
    jitter_std_mean, jitter_std_std : float, optional
        The standard deviation of the per-view jitter is drawn once per sample and per
        component (t1 and t2 in pixels, theta in degrees) as ``|N(mean, std^2)|``.
        Defaults 0.127 and 0.0254 (paper).
    frequency_range : tuple of float, optional
        Sinusoid frequency, oscillations per scan, uniform in this range. Default (0.5, 20).
    damping_range : tuple of float, optional
        Exponential damping rate per scan (amplitude ``exp(-d * tau)``, ``tau`` the normalised
        time since onset), uniform in this range. Default (0, 5).
    amplitude_range : tuple of float, optional
        Sinusoid amplitude in pixels, uniform in this range; the direction in the (r1, r2)
        plane is uniform on the circle. Default (0, 1).
    jitter : bool, optional
        Include the Gaussian jitter. Default True.
    sinusoids : bool, optional
        Include the damped sinusoids ``eps``. Default True.

    Notes
    -----
    Each sinusoid also has an onset uniform in normalised time [0, 1) (it is 0 before) and a
    phase uniform in [0, 2 pi); these have no parameters.
    """

    n_sinusoids: int = N_SINUSOIDS["parallel"]
    max_shift: float = 2.0
    jitter_std_mean: float = 0.127
    jitter_std_std: float = 0.0254
    frequency_range: tuple[float, float] = (0.5, 20.0)
    damping_range: tuple[float, float] = (0.0, 5.0)
    amplitude_range: tuple[float, float] = (0.0, 1.0)
    jitter: bool = True
    sinusoids: bool = True

    def __post_init__(self) -> None:
        if (
            isinstance(self.n_sinusoids, bool)
            or not isinstance(self.n_sinusoids, (int, np.integer))
            or self.n_sinusoids < 0
        ):
            raise ValueError(f"n_sinusoids={self.n_sinusoids!r} must be an integer >= 0")
        object.__setattr__(self, "n_sinusoids", int(self.n_sinusoids))
        for name in ("max_shift", "jitter_std_mean", "jitter_std_std"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float, np.floating, np.integer)) and value >= 0):
                raise ValueError(f"{name}={value!r} must be a number >= 0")
            if not math.isfinite(value):
                raise ValueError(f"{name}={value!r} must be finite")
            object.__setattr__(self, name, float(value))
        for name in ("frequency_range", "damping_range", "amplitude_range"):
            object.__setattr__(self, name, _check_range(name, getattr(self, name)))
        for name in ("jitter", "sinusoids"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name}={getattr(self, name)!r} must be True or False")
            object.__setattr__(self, name, bool(getattr(self, name)))

    @classmethod
    def for_kind(cls, kind: str, **overrides: Any) -> MotionParams:
        """Parameters of the paper for a geometry kind.

        Parameters
        ----------
        kind : {"parallel", "fan"}
            Geometry kind; sets ``n_sinusoids`` to 38 or 9.
        **overrides
            Any other field (or ``n_sinusoids`` itself) to override.

        Returns
        -------
        MotionParams
        """
        if kind not in N_SINUSOIDS:
            raise ValueError(f"kind={kind!r} is unknown; use one of {sorted(N_SINUSOIDS)}")
        return cls.from_dict({"n_sinusoids": N_SINUSOIDS[kind], **overrides})

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible dictionary of all fields (ranges as lists)."""
        return {
            f.name: list(v) if isinstance(v := getattr(self, f.name), tuple) else v for f in dataclasses.fields(self)
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> MotionParams:
        """Inverse of :meth:`to_dict`; missing fields take their defaults.

        Parameters
        ----------
        data : dict
            Field values, e.g. read back from JSON attributes.

        Returns
        -------
        MotionParams
        """
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ValueError(f"unknown MotionParams fields {unknown}; valid fields: {sorted(names)}")
        values = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
        return cls(**values)


def sample_motion_components(
    rng: np.random.Generator, n_angles: int, params: MotionParams
) -> tuple[np.ndarray, np.ndarray]:
    """Draw the two parts of the motion of one sample.

    All random numbers are drawn whatever the switches ``params.sinusoids`` and
    ``params.jitter``, which only zero their part afterwards; so the same generator gives the
    same jitter with and without sinusoids, and vice versa.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of randomness, e.g. ``numpy.random.default_rng((seed, index))``.
    n_angles : int
        Number of views ``K``; view ``k`` is at normalised time ``k / K``.
    params : MotionParams
        Motion distribution.

    Returns
    -------
    eps : ndarray of shape (K, 2), float32
        Sum of damped sinusoids (pixels along r1, r2). Each component is scaled down, if
        needed, so that ``max_k |eps[k, c]| <= params.max_shift``; a component already within
        the bound is left unchanged. Scaling (rather than clipping) keeps the sinusoids smooth,
        so whenever the raw sum exceeds the bound, the bound is attained.
    jitter : ndarray of shape (K, 3), float32
        Gaussian jitter ``(t1 [px], t2 [px], theta [deg])``, zero mean, one standard deviation
        ``|N(jitter_std_mean, jitter_std_std^2)|`` per component for the whole sample.
    """
    rng = check_rng(rng)
    n_angles = check_int(n_angles, "n_angles", 1)
    if not isinstance(params, MotionParams):
        raise ValueError(f"params must be a MotionParams, got {type(params).__name__}")
    m = params.n_sinusoids
    amplitude = rng.uniform(*params.amplitude_range, size=m)
    direction = rng.uniform(0.0, 2.0 * math.pi, size=m)
    frequency = rng.uniform(*params.frequency_range, size=m)
    damping = rng.uniform(*params.damping_range, size=m)
    phase = rng.uniform(0.0, 2.0 * math.pi, size=m)
    onset = rng.uniform(0.0, 1.0, size=m)
    std = np.abs(rng.normal(params.jitter_std_mean, params.jitter_std_std, size=3))
    noise = rng.standard_normal((n_angles, 3))

    eps = np.zeros((n_angles, 2))
    if params.sinusoids and m:
        tau = np.arange(n_angles)[:, None] / n_angles - onset  # (K, m) time since onset
        wave = np.where(
            tau >= 0.0,
            amplitude * np.exp(-damping * tau) * np.sin(2.0 * math.pi * frequency * tau + phase),
            0.0,
        )
        eps = wave @ np.stack([np.cos(direction), np.sin(direction)], axis=1)
        peak = np.abs(eps).max(axis=0)
        over = peak > params.max_shift
        eps[:, over] *= params.max_shift / peak[over]
    jitter = noise * std if params.jitter else np.zeros((n_angles, 3))
    return eps.astype(np.float32), jitter.astype(np.float32)


def sample_motion(rng: np.random.Generator, n_angles: int, params: MotionParams) -> np.ndarray:
    """Draw the per-view rigid motion of one sample.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of randomness, e.g. ``numpy.random.default_rng((seed, index))``.
    n_angles : int
        Number of views ``K``.
    params : MotionParams
        Motion distribution.

    Returns
    -------
    ndarray of shape (K, 3), float32
        ``(t1, t2, theta)`` per view: ``t = eps + jitter[:, :2]`` in pixels and
        ``theta = jitter[:, 2]`` in degrees, with ``eps, jitter`` from
        :func:`sample_motion_components` called on the same generator.
    """
    eps, jitter = sample_motion_components(rng, n_angles, params)
    motion = jitter.copy()
    motion[:, :2] += eps
    return motion


def no_motion(n_angles: int) -> np.ndarray:
    """Motion array of a static object: zeros of shape (K, 3), float32."""
    return np.zeros((check_int(n_angles, "n_angles", 1), 3), dtype=np.float32)


def rotation_matrix(theta_deg: float | np.ndarray) -> np.ndarray:
    """Counter-clockwise rotation matrices in the (r1, r2) plane.

    Parameters
    ----------
    theta_deg : float or array_like
        Angle(s) in degrees.

    Returns
    -------
    ndarray of shape (..., 2, 2), float64
        ``[[cos, -sin], [sin, cos]]``; rotates (1, 0) by 90 degrees to (0, 1).
    """
    theta = np.deg2rad(np.asarray(theta_deg, dtype=np.float64))
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], axis=-1), np.stack([s, c], axis=-1)], axis=-2)


def plot_motion(motion: np.ndarray, ax: Axes | None = None, angles: np.ndarray | None = None) -> Figure:
    """Plot a motion array: shifts on the left axis, rotation on a twin right axis.

    Parameters
    ----------
    motion : ndarray of shape (K, 3)
        ``(t1 [px], t2 [px], theta [deg])`` per view.
    ax : matplotlib.axes.Axes, optional
        Axes to draw into; a new figure (not registered with pyplot, so safe under any
        backend) is made when omitted.
    angles : ndarray of shape (K,), optional
        View angles in radians (as ``Geometry.angles``), shown in degrees; the view index is
        used when omitted.

    Returns
    -------
    matplotlib.figure.Figure
        The figure holding ``ax`` and its twin axis for theta.
    """
    motion = np.asarray(motion)
    if motion.ndim != 2 or motion.shape[1] != 3:
        raise ValueError(f"motion has shape {motion.shape}; expected (K, 3) of (t1, t2, theta)")
    if angles is None:
        x, xlabel = np.arange(motion.shape[0]), "view index k"
    else:
        angles = np.asarray(angles, dtype=np.float64)
        if angles.shape != (motion.shape[0],):
            raise ValueError(f"angles has shape {angles.shape}; pass one angle per view, shape ({motion.shape[0]},)")
        x, xlabel = np.rad2deg(angles), r"view angle $\varphi$ [deg]"
    if ax is None:
        from matplotlib.figure import Figure

        ax = Figure(figsize=(8, 3.5), layout="constrained").subplots()
    ax.plot(x, motion[:, 0], label=r"$t_1$ [px]", color="C0", lw=1)
    ax.plot(x, motion[:, 1], label=r"$t_2$ [px]", color="C1", lw=1)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("shift [px]")
    ax_theta = ax.twinx()
    ax_theta.plot(x, motion[:, 2], label=r"$\theta$ [deg]", color="C2", lw=0.8, alpha=0.8)
    ax_theta.set_ylabel(r"rotation $\theta$ [deg]")
    lines = ax.get_lines() + ax_theta.get_lines()
    ax.legend(lines, [line.get_label() for line in lines], loc="upper right", fontsize="small")
    return ax.figure
