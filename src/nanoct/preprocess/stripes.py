"""Ring-artefact removal: stripe removal in the sinograms, with algotom's methods.

A detector pixel whose response differs from the flat field's makes a vertical stripe in every
sinogram (constant along the angle axis) and a ring in the slice. The methods are those of Vo,
Atwood and Drakopoulos, Opt. Express 26, 28396 (2018), as implemented in
``algotom.prep.removal`` (algotom 1.7), applied to each detector row's sinogram ``(K, L)`` of
line integrals (after ``-log``):

``"all"`` (the default)
    ``remove_all_stripe(snr=3, la_size=51, sm_size=21, drop_ratio=0.1)``: dead stripes, then
    large stripes, then small-to-medium stripes by sorting (algorithms 6, 5, 4 and 3).
``"sorting"``
    ``remove_stripe_based_sorting(size=21)``: sort each column along the angles, median-filter
    across the columns, sort back (algorithm 3).
``"filtering"``
    ``remove_stripe_based_filtering(sigma=3, size=21)``: the low-pass part along the angles is
    smoothed by a median across the columns (algorithm 2).
``"fitting"``
    ``remove_stripe_based_fitting(order=2, sigma=10)``: a polynomial fit along the angles,
    then a Fourier filter (algorithm 1; for low-contrast sinograms).

Parameters not given take algotom's defaults above; their names are algotom's.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.errors import NanoctError

__all__ = ["STRIPE_METHODS", "remove_stripes", "stripe_function"]

#: Each method's algotom function and its parameters with their defaults.
STRIPE_METHODS: dict[str, tuple[str, dict[str, float | int]]] = {
    "all": ("remove_all_stripe", {"snr": 3.0, "la_size": 51, "sm_size": 21, "drop_ratio": 0.1}),
    "sorting": ("remove_stripe_based_sorting", {"size": 21}),
    "filtering": ("remove_stripe_based_filtering", {"sigma": 3.0, "size": 21}),
    "fitting": ("remove_stripe_based_fitting", {"order": 2, "sigma": 10.0}),
}


def stripe_function(method: str, params: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
    """algotom's function for ``method`` and the full set of its parameters (defaults filled in).

    Raises
    ------
    NanoctError
        For an unknown method or parameter.
    """
    if method not in STRIPE_METHODS:
        raise NanoctError(f"--stripes {method!r} must be one of {', '.join(STRIPE_METHODS)}")
    name, defaults = STRIPE_METHODS[method]
    params = dict(params or {})
    unknown = sorted(set(params) - set(defaults))
    if unknown:
        raise NanoctError(f"stripe parameter {unknown[0]!r} is not one of method {method!r}'s: {', '.join(defaults)}")
    full = {key: type(value)(params.get(key, value)) for key, value in defaults.items()}
    if any(isinstance(value, int) and params.get(key, value) != value for key, value in full.items()):
        raise NanoctError(f"stripe parameters {params} must be whole numbers where algotom's are ({defaults})")
    if any(not value > 0 for value in full.values()):
        raise NanoctError(f"stripe parameters {full} must all be > 0")
    from algotom.prep import removal

    return getattr(removal, name), full


def remove_stripes(line_integrals: np.ndarray, method: str = "all", params: dict[str, Any] | None = None) -> np.ndarray:
    """Remove stripes from each detector row's sinogram.

    Parameters
    ----------
    line_integrals : ndarray of shape (K, R, L) or (K, L)
        Line integrals (``-log`` of the transmission), views first: row ``r``'s sinogram is
        ``line_integrals[:, r, :]``.
    method : {"all", "sorting", "filtering", "fitting"}
        See the module docstring.
    params : dict, optional
        The method's parameters by algotom's names (see :data:`STRIPE_METHODS`).

    Returns
    -------
    ndarray of the input's shape, float32

    Raises
    ------
    NanoctError
        For an unknown method or parameter, non-finite values, or a window (``size``,
        ``la_size``, ``sm_size``) larger than the detector row.
    """
    func, full = stripe_function(method, params)
    data = np.asarray(line_integrals, dtype=np.float32)
    stack = data[:, None, :] if data.ndim == 2 else data
    if stack.ndim != 3:
        raise NanoctError(f"line integrals of shape {data.shape} must be (views, rows, columns) or (views, columns)")
    if not np.all(np.isfinite(stack)):
        raise NanoctError("the line integrals hold NaN or infinite values; remove outliers first (--outliers)")
    windows = {key: value for key, value in full.items() if key.endswith("size")}
    if any(value > stack.shape[2] for value in windows.values()):
        raise NanoctError(f"stripe windows {windows} must not exceed the {stack.shape[2]} detector columns")
    out = np.empty(stack.shape, np.float32)
    for r in range(stack.shape[1]):
        out[:, r, :] = func(stack[:, r, :], **full)
    return out[:, 0, :] if data.ndim == 2 else out
