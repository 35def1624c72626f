"""What the data-scaling study trains and on how much data: its definition and its units.

:class:`ScalingStudy` is the study's definition (``nanoct scaling``), :class:`ScalingUnit` one
network trained on one training-set size and its test prediction, :func:`scaling_units` all of them
in the order they run; the runner and planner (:mod:`nanoct.study.scaling`) and the report
(:mod:`nanoct.study.scaling_report`) both read them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..core.errors import NanoctError
from ..core.names import scaling_name
from ..learn.models import model_spec
from .config import STUDIES, Study

__all__ = ["INPUTS", "ScalingStudy", "ScalingUnit", "scaling_units"]

#: The first reconstructions a network of the study is trained on: input -> (method, parameters).
INPUTS = {"fbp": ("fbp", {}), "dremel": ("dremel", {}), "resesop": ("resesop", {"eta_scale": 1.0})}


@dataclass(frozen=True)
class ScalingStudy:
    """What the data-scaling study trains and on how much data.

    Attributes
    ----------
    preset : str
        Geometry preset of the data set.
    sizes : tuple of int
        Training-set sizes (nested: the first K training samples).
    seeds : tuple of int
        Training seeds at each size (same length as ``sizes``).
    steps : int
        Optimiser steps of every run (batch 16: ``steps * 16 / K`` epochs at size K).
    long_factor, long_seeds : int
        The extra point: ``long_seeds`` runs at the largest size with ``long_factor * steps``
        steps (0 seeds: no extra point).
    n_val, n_test : int
        Validation (best checkpoint, std calibration) and test samples, the same at every size.
    models, inputs : tuple of str
        Networks and the first reconstructions they are trained on.
    seed : int
        Seed of the data set.
    base : Study
        Learning rates, architectures, precision and sampling of the networks (the tiny study's).
    scheduler : str
        Learning-rate schedule of every run ("cosine": over the run's epochs, at every size).
    """

    preset: str = "tiny-parallel"
    sizes: tuple[int, ...] = (160, 640, 2560)
    seeds: tuple[int, ...] = (3, 2, 2)
    steps: int = 640
    long_factor: int = 4
    long_seeds: int = 1
    n_val: int = 20
    n_test: int = 100
    models: tuple[str, ...] = ("unet", "ciunet-res")
    inputs: tuple[str, ...] = ("fbp", "dremel", "resesop")
    seed: int = 0
    base: Study = field(default_factory=lambda: STUDIES["tiny"])
    scheduler: str = "cosine"

    def __post_init__(self) -> None:
        if len(self.sizes) != len(self.seeds) or not self.sizes:
            raise NanoctError(f"sizes {self.sizes} and seeds {self.seeds} must be non-empty and of the same length")
        if min(self.sizes) < 1 or min(self.seeds) < 1 or self.steps < 1 or self.long_factor < 1:
            raise NanoctError(
                f"sizes {self.sizes}, seeds {self.seeds}, steps {self.steps} and long factor {self.long_factor} "
                "must be positive"
            )
        if self.n_val < 1 or self.n_test < 2 or self.long_seeds < 0:
            raise NanoctError(f"n_val {self.n_val} >= 1, n_test {self.n_test} >= 2, long_seeds >= 0 are needed")
        unknown = [i for i in self.inputs if i not in INPUTS]
        if unknown:
            raise NanoctError(f"unknown input(s) {unknown}; choose from {', '.join(INPUTS)}")
        for m in self.models:
            model_spec(m)  # rejects an unknown model

    @property
    def n(self) -> int:
        """Samples of the data set."""
        return max(self.sizes) + self.n_val + self.n_test

    @property
    def split_fractions(self) -> tuple[float, float, float]:
        """Train/val/test fractions that give exactly ``max(sizes)``, ``n_val``, ``n_test`` samples."""
        return (max(self.sizes) / self.n, self.n_val / self.n, self.n_test / self.n)


@dataclass(frozen=True)
class ScalingUnit:
    """One network trained on the first ``n_train`` training images for ``steps`` steps, and its test prediction."""

    model: str
    input: str
    n_train: int
    steps: int
    seed: int

    @property
    def name(self) -> str:
        """Store name of the prediction (:func:`nanoct.names.scaling_name`)."""
        return scaling_name(self.input, self.model, self.n_train, self.steps, self.seed)

    @property
    def run(self) -> str:
        """Run directory name below ``runs/``."""
        return f"{self.model}-{self.input}-n{self.n_train}x{self.steps}" + (f"-seed{self.seed}" if self.seed else "")

    def epochs(self, batch_size: int) -> int:
        """Epochs that hold ``steps`` steps at this size (the last may stop early)."""
        return math.ceil(self.steps / math.ceil(self.n_train / batch_size))


def scaling_units(study: ScalingStudy) -> list[ScalingUnit]:
    """Every unit, in the order they run: seed by seed over all sizes (so an interrupted run has
    the first seed of the whole curve first), then the extra point with more steps."""
    units = [
        ScalingUnit(m, i, k, study.steps, s)
        for s in range(max(study.seeds))
        for k, seeds in zip(study.sizes, study.seeds)
        if s < seeds
        for m in study.models
        for i in study.inputs
    ]
    big = max(study.sizes)
    units += [
        ScalingUnit(m, i, big, study.steps * study.long_factor, s)
        for s in range(study.long_seeds)
        for m in study.models
        for i in study.inputs
    ]
    return units
