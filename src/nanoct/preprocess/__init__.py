"""Corrections of measured projections before reconstruction.

Outlier (zinger) removal (:mod:`.outliers`), open-beam normalisation from air per view
(:mod:`.openbeam`), Paganin's single-distance phase retrieval (:mod:`.phase`) and stripe (ring)
removal with algotom (:mod:`.stripes`, measured by :mod:`.rings`); :mod:`.pipeline` applies them in order from one
:class:`Corrections`. The order and the measured effect on real scans: docs/corrections.md.
"""

from .openbeam import OpenBeam, estimate_open_beam, normalize_open_beam
from .outliers import remove_outliers
from .phase import paganin, paganin_filter
from .pipeline import CorrectionResult, Corrections, apply_corrections, parse_columns, parse_stripe_params
from .rings import radial_profile, ring_metric
from .stripes import STRIPE_METHODS, remove_stripes

__all__ = [
    "STRIPE_METHODS",
    "CorrectionResult",
    "Corrections",
    "OpenBeam",
    "apply_corrections",
    "estimate_open_beam",
    "normalize_open_beam",
    "paganin",
    "paganin_filter",
    "parse_columns",
    "parse_stripe_params",
    "radial_profile",
    "remove_outliers",
    "remove_stripes",
    "ring_metric",
]
