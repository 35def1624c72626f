"""Input checks shared by the public functions: clear errors instead of silent garbage."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["check_array", "check_bool", "check_choice", "check_float", "check_int", "check_int_list", "check_rng"]


def check_array(
    value: Any,
    name: str,
    *,
    shape: tuple[int, ...] | None = None,
    ndim: int | None = None,
    dtype: Any = np.float32,
    finite: bool = True,
) -> np.ndarray:
    """Validate an array argument and return it as a contiguous array.

    Parameters
    ----------
    value : array_like
        The argument.
    name : str
        Its name, used in error messages.
    shape : tuple of int, optional
        Required shape.
    ndim : int, optional
        Required number of dimensions (when the exact shape is not fixed).
    dtype : numpy dtype or None
        Real dtype to convert to (default float32); ``None`` keeps a real floating dtype.
    finite : bool
        Reject NaN and infinite values.

    Returns
    -------
    ndarray
        C-contiguous array of the requested dtype.

    Raises
    ------
    ValueError
        If the shape, dtype or values are wrong; the message names the argument.
    """
    arr = np.asarray(value)
    if arr.dtype.kind not in "fiub":
        raise ValueError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    if shape is not None and arr.shape != tuple(shape):
        raise ValueError(f"{name} has shape {arr.shape}, expected {tuple(shape)}")
    if ndim is not None and arr.ndim != ndim:
        raise ValueError(f"{name} must have {ndim} dimensions, got shape {arr.shape}")
    if finite and arr.size and not np.isfinite(arr).all():
        bad = int(arr.size - np.isfinite(arr).sum())
        raise ValueError(f"{name} contains {bad} NaN or infinite value(s); clean or regenerate it")
    target = dtype if dtype is not None else (arr.dtype if arr.dtype.kind == "f" else np.float64)
    return np.ascontiguousarray(arr, dtype=target)


def check_int(value: Any, name: str, minimum: int) -> int:
    """Validate an integer argument (bools and floats rejected) and return it as ``int``.

    Raises
    ------
    ValueError
        If ``value`` is not an integer or is below ``minimum``; the message names it.
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name}={value!r} must be an integer >= {minimum}; pass an int")
    if value < minimum:
        raise ValueError(f"{name}={value!r} is too small; use an integer >= {minimum}")
    return int(value)


def check_int_list(value: Any, name: str, minimum: int) -> list[int]:
    """Validate a non-empty list (or tuple, or 1-D array) of integers, each ``>= minimum``; return it as ints.

    Raises
    ------
    ValueError
        For anything else (a string, a number, floats, an empty list); the message names it.
    """
    items = value.tolist() if isinstance(value, np.ndarray) and value.ndim == 1 else value
    if not isinstance(items, (list, tuple)) or not items:
        raise ValueError(f"{name}={value!r} must be a non-empty list of integers >= {minimum}, e.g. [16, 32, 64]")
    return [check_int(v, name, minimum) for v in items]


def check_float(
    value: Any,
    name: str,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
) -> float:
    """Validate a finite real number (bools and strings rejected) within optional bounds.

    Parameters
    ----------
    value : Any
        The argument.
    name : str
        Its name, used in error messages.
    low, high : float, optional
        Bounds; ``low_open`` / ``high_open`` exclude them.

    Returns
    -------
    float
        ``float(value)``.

    Raises
    ------
    ValueError
        If ``value`` is not a finite real number or lies outside the bounds; the message
        names it and the accepted range.
    """
    lo = "" if low is None else ("(" if low_open else "[") + f"{low:g}"
    hi = "" if high is None else f"{high:g}" + (")" if high_open else "]")
    wanted = f"a finite number in {lo or '(-inf'}, {hi or 'inf)'}"
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name}={value!r} must be {wanted}")
    v = float(value)
    too_low = low is not None and (v <= low if low_open else v < low)
    too_high = high is not None and (v >= high if high_open else v > high)
    if not np.isfinite(v) or too_low or too_high:
        raise ValueError(f"{name}={value!r} is not allowed; use {wanted}")
    return v


def check_choice(value: Any, name: str, choices: tuple[str, ...]) -> str:
    """Require one of ``choices`` (strings).

    Raises
    ------
    ValueError
        For anything else; the message lists the choices.
    """
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"{name}={value!r} is unknown; use one of {', '.join(choices)}")
    return value


def check_bool(value: Any, name: str) -> bool:
    """Require a boolean (``True``/``False``, the integers 0 and 1, or the words true and false in any case).

    Raises
    ------
    ValueError
        For anything else.
    """
    if isinstance(value, str) and value.lower() in ("true", "false"):
        return value.lower() == "true"
    if isinstance(value, (bool, np.bool_)) or (isinstance(value, (int, np.integer)) and value in (0, 1)):
        return bool(value)
    raise ValueError(f"{name}={value!r} is not a boolean; {name} must be true or false")


def check_rng(rng: Any) -> np.random.Generator:
    """Require a ``numpy.random.Generator`` (never global random state).

    Raises
    ------
    TypeError
        For anything else.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(
            f"rng must be a numpy.random.Generator, got {type(rng).__name__}; "
            "build one with numpy.random.default_rng((seed, index))"
        )
    return rng
