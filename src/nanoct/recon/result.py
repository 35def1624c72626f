"""The result every reconstruction method returns."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["STOP_REASONS", "ReconResult"]

#: Why a method stopped: a direct method (``"direct"``), the iteration limit ``n_iter``
#: (``"max_iter"``), the discrepancy principle (``"discrepancy"``), or the callback (``"callback"``).
STOP_REASONS = ("direct", "max_iter", "discrepancy", "callback")


@dataclass
class ReconResult:
    """Outcome of one reconstruction.

    Attributes
    ----------
    image : ndarray of shape (N, N), float32
        The reconstruction.
    residuals : list of float
        Data residual ``||A x - y||_2`` after each sweep/iteration (empty for direct methods).
    stop_reason : str
        Why the method stopped, one of :data:`STOP_REASONS`.
    motion : ndarray of shape (K,), float32, optional
        Estimated per-view object shift in pixels along the detector axis (Dremel), else None.
    params : dict
        The parameters actually used (stored with batch results).
    """

    image: np.ndarray
    residuals: list[float] = field(default_factory=list)
    stop_reason: str = "direct"
    motion: np.ndarray | None = None
    params: dict[str, Any] = field(default_factory=dict)

    @property
    def iterations(self) -> int:
        """Number of sweeps/iterations performed."""
        return len(self.residuals)
