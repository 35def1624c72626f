"""A ring-artefact metric of a reconstructed slice: the high-pass energy of its radial profile.

Rings are centred on the rotation axis (the image centre in nanoct's convention), so the
azimuthal mean of the slice keeps them at full strength while it averages the object's
structure, which is not centred there, into a smooth curve. The metric:

1. ``P(r)``: the mean of the pixels whose distance from the image centre ``((N - 1) / 2, (N -
   1) / 2)`` rounds to ``r``, for ``r = 0 .. N // 2 - 1`` (the inscribed disc);
2. ``H = P - savgol_filter(P, 11, 2)`` (scipy's Savitzky-Golay filter: a quadratic fitted over
   11 radii, ``mode="interp"`` at the ends): the part of the profile narrower than about 10
   pixels; a smooth profile's slope and curvature pass into the fit, not into ``H``;
3. ``ring_metric = sum over r >= r_min of H(r)^2`` (``r_min = 3``: the centre's few pixels have
   too few samples for a mean).
"""

from __future__ import annotations

import numpy as np
from scipy.signal import savgol_filter

__all__ = ["radial_profile", "ring_metric"]


def radial_profile(image: np.ndarray, *, offset: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """The azimuthal mean ``P(r)``, ``r = 0 .. N // 2 - 1 - max|offset|``, of a square image.

    About the image centre moved by ``offset`` = (rows, columns) pixels: off the rotation axis,
    rings spread over many radii, so the metric there measures the slice's other high-pass
    content (the floor the metric cannot go below).
    """
    img = np.asarray(image, np.float64)
    n = img.shape[0]
    if img.ndim != 2 or img.shape[1] != n:
        raise ValueError(f"image of shape {img.shape} must be square")
    y, x = np.indices(img.shape)
    dy, dx = offset
    radius = np.rint(np.hypot(x - (n - 1) / 2 - dx, y - (n - 1) / 2 - dy)).astype(int)
    inside = radius <= n // 2 - 1 - int(np.ceil(max(abs(dy), abs(dx))))
    return np.bincount(radius[inside], img[inside]) / np.bincount(radius[inside])


def ring_metric(
    image: np.ndarray, *, window: int = 11, r_min: int = 3, offset: tuple[float, float] = (0.0, 0.0)
) -> float:
    """The high-pass energy of ``image``'s radial profile (module docstring), in image units squared.

    ``offset``: about a point this many (rows, columns) pixels from the centre (see :func:`radial_profile`).
    """
    profile = radial_profile(image, offset=offset)
    window = min(window, profile.size - 1 + profile.size % 2)  # odd and within the profile
    if window < 3:
        raise ValueError(f"image of shape {np.shape(image)} is too small for a ring metric (at least 6 x 6)")
    high = profile - savgol_filter(profile, window, 2, mode="interp")
    return float(np.sum(high[r_min:] ** 2))
