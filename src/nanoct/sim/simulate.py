"""Simulation of one sample of the paper's data set.

Sample ``i`` of a data set with seed ``S`` is a pure function of ``(S, i)`` and the
configuration: the phantom, the motion and the noise each draw from their own child of
``numpy.random.SeedSequence(S, spawn_key=(i,))``, so the bytes do not depend on the number of
workers or the order in which samples are made.

Avoiding the inverse crime: by default the data are computed from the phantom rasterised on a
grid ``oversample = 2`` times finer than the reconstruction grid (same field of view, same
ASTRA projector family), while reconstructions use the N x N grid. The ground truth is the
block mean of the fine phantom. ``oversample = 1`` reproduces the inverse crime.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from ..core.geometry import Geometry
from ..core.operators import RayTransform, system_matrix
from ..core.validation import check_int
from ..io.store import Sample
from .motion import MotionParams, sample_motion
from .phantoms import PHANTOM_FAMILIES, downsample, family_phantom

__all__ = ["SimulationConfig", "model_error", "sample_rngs", "simulate_from_phantom", "simulate_sample"]


@dataclass(frozen=True)
class SimulationConfig:
    """How samples are simulated.

    Parameters
    ----------
    motion : MotionParams
        Distribution of the per-view motion (paper defaults for the geometry kind).
    perturbed : bool
        Move the object during the scan (``False`` gives the paper's unperturbed case:
        ``y == y_eta`` and ``eta == 0``).
    oversample : int
        Sub-pixels per pixel of the simulation grid (default 2; 1 = inverse crime).
    projector : str or None
        ASTRA projector for the simulation (default: the reconstruction projector family,
        ``line`` / ``line_fanflat``, on the finer grid).
    noise_std : float
        Standard deviation of additive Gaussian noise on ``y`` in sinogram units (line
        integrals in pixel units); 0 (the paper's setting) by default.
    phantoms : {"shapes", "ellipses"}
        Phantom family (:func:`nanoct.sim.phantoms.family_phantom`): the paper's generator
        (default) or Shepp-Logan-like ellipses (a shifted test set). The default is left out of
        :meth:`to_dict`, so data sets of the paper's family keep their stored description.
    """

    motion: MotionParams = field(default_factory=MotionParams)
    perturbed: bool = True
    oversample: int = 2
    projector: str | None = None
    noise_std: float = 0.0
    phantoms: str = "shapes"

    def __post_init__(self) -> None:
        object.__setattr__(self, "oversample", check_int(self.oversample, "oversample", 1))
        if self.phantoms not in PHANTOM_FAMILIES:
            raise ValueError(f"phantoms={self.phantoms!r} is unknown; use one of {', '.join(PHANTOM_FAMILIES)}")
        if not (np.isfinite(self.noise_std) and self.noise_std >= 0):
            raise ValueError(f"noise_std={self.noise_std!r} must be a finite number >= 0")

    @classmethod
    def for_geometry(cls, geometry: Geometry, **overrides: Any) -> SimulationConfig:
        """Paper defaults for a geometry (38 sinusoids for parallel, 9 for fan)."""
        motion = overrides.pop("motion", None) or MotionParams.for_kind(geometry.kind)
        return cls(motion=motion, **overrides)

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible description (stored in the data set's attributes)."""
        d = asdict(self)
        d["motion"] = self.motion.to_dict()
        if self.phantoms == "shapes":
            del d["phantoms"]
        return d

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SimulationConfig:
        """Inverse of :meth:`to_dict` (the key ``like`` of a matched set, :mod:`nanoct.sim.matched`, is left aside)."""
        data = dict(data)
        data.pop("like", None)
        data["motion"] = MotionParams.from_dict(data["motion"])
        return cls(**data)


def sample_rngs(seed: int, index: int) -> tuple[np.random.Generator, np.random.Generator, np.random.Generator]:
    """Independent generators (phantom, motion, noise) of sample ``index`` under ``seed``."""
    if seed < 0 or index < 0:
        raise ValueError(f"seed={seed} and index={index} must be non-negative")
    children = np.random.SeedSequence(seed, spawn_key=(index,)).spawn(3)
    return tuple(np.random.default_rng(c) for c in children)  # type: ignore[return-value]


def model_error(sinogram: np.ndarray, sinogram_eta: np.ndarray) -> np.ndarray:
    """Per-view model error ``eta_k = max_l |y[k, l] - y_eta[k, l]|`` (paper, section 4)."""
    return np.abs(sinogram.astype(np.float64) - sinogram_eta).max(axis=1).astype(np.float32)


def simulate_sample(geometry: Geometry, config: SimulationConfig, seed: int, index: int) -> Sample:
    """Simulate sample ``index`` of the data set with seed ``seed``.

    Returns
    -------
    Sample
        Phantom (N, N), measured sinogram y (perturbed object, exact per-view motion),
        model sinogram y_eta (unperturbed object), motion (K, 3) and eta (K,), the model
        error of the noise-free data (the noise level is the separate ``delta``).
    """
    rng_phantom, rng_motion, rng_noise = sample_rngs(seed, index)
    fine = family_phantom(config.phantoms, rng_phantom, geometry.n, oversample=config.oversample)
    return simulate_from_phantom(geometry, config, fine, rng_motion, rng_noise)


def simulate_from_phantom(
    geometry: Geometry,
    config: SimulationConfig,
    fine: np.ndarray,
    rng_motion: np.random.Generator,
    rng_noise: np.random.Generator,
) -> Sample:
    """Simulate one sample of a given phantom: its motion, sinograms, eta and noise.

    Parameters
    ----------
    geometry : Geometry
        Scan geometry.
    config : SimulationConfig
        Motion, noise and grid settings (``config.phantoms`` is not used).
    fine : ndarray of shape (N * oversample, N * oversample)
        The phantom on the simulation grid; its block mean is the ground truth.
    rng_motion, rng_noise : numpy.random.Generator
        Sources of the motion and of the noise (:func:`sample_rngs`).

    Returns
    -------
    Sample
        As :func:`simulate_sample`.
    """
    s = config.oversample
    phantom = downsample(fine, s) if s > 1 else fine
    motion = sample_motion(rng_motion, geometry.n_angles, config.motion)
    if not config.perturbed:
        motion = np.zeros_like(motion)
    # the unperturbed projection is the same for every sample: the cached matrix is ~2.5x
    # faster than ASTRA on the fly (paper-parallel: 120 ms against 310 ms) and gives equal values
    matrix = system_matrix(geometry, config.projector, oversample=s)
    y_eta = (matrix @ fine.ravel()).reshape(geometry.sino_shape)
    y = (
        RayTransform(geometry, motion, projector=config.projector, oversample=s).forward(fine)
        if config.perturbed
        else y_eta.copy()
    )
    eta = model_error(y, y_eta)  # the model error alone; noise is the separate level delta
    if config.noise_std > 0:
        y = (y + rng_noise.normal(0.0, config.noise_std, size=y.shape)).astype(np.float32)
    return Sample(phantom=phantom, sinogram=y, sinogram_eta=y_eta, motion=motion.astype(np.float32), eta=eta)
