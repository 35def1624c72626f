"""nanoct: CT reconstruction with inexact (motion-perturbed) forward operators.

The reconstruction methods work on plain arrays from the top level (imported on first use,
so ``import nanoct`` stays cheap)::

    import nanoct
    result = nanoct.dremel(sinogram, angles=angles_rad, center_offset=1.5)
    result.image, result.motion

and the motion of a measured scan from its projections (views, rows, columns)::

    motion = nanoct.estimate_motion(projections, angles_rad)
    motion.horizontal, motion.vertical, motion.axis.offset
"""

from typing import Any

from .core.version import __version__

_API = ("fbp", "gridrec", "kaczmarz", "dremel", "resesop", "make_geometry")

_MOTION = ("estimate_motion", "estimate_axis")

__all__ = ["__version__", *_API, *_MOTION, "Geometry"]


def __getattr__(name: str) -> Any:
    """Import the array API (:mod:`nanoct.api`), the motion estimators and ``Geometry`` lazily."""
    if name in _API:
        from . import api

        return getattr(api, name)
    if name == "estimate_motion":
        from .motion.estimate import estimate_motion

        return estimate_motion
    if name == "estimate_axis":
        from .motion.axis import estimate_axis

        return estimate_axis
    if name == "Geometry":
        from .core.geometry import Geometry

        return Geometry
    raise AttributeError(f"module 'nanoct' has no attribute {name!r}")
