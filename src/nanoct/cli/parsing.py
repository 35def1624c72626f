"""Option values given as text (``0.95,0.04,0.01``, ``10:20``, ``name=value``) read into typed values, with
one clear error naming the flag for anything else."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..core.errors import NanoctError


def parse_fractions(text: str) -> tuple[float, float, float]:
    """``--split-fractions``: three numbers >= 0 summing to 1."""
    try:
        parts = tuple(float(v) for v in text.split(","))
    except ValueError:
        parts = ()
    if len(parts) != 3 or not all(0 <= p < float("inf") for p in parts) or abs(sum(parts) - 1) > 1e-6:
        raise NanoctError(
            f"--split-fractions {text!r} must be three comma-separated numbers >= 0 summing to 1, e.g. 0.95,0.04,0.01"
        )
    return parts  # type: ignore[return-value]


def check_name(name: str | None) -> str | None:
    """``--name``: a reconstruction name the store accepts (typer callback)."""
    from ..io.store_recon import check_name as store_check_name

    return None if name is None else store_check_name(name)


def check_device(device: str | None) -> None:
    """``--device``: a device torch knows (cpu, cuda, cuda:<index>)."""
    if device is None:
        return
    import torch

    try:
        torch.device(device)
    except (RuntimeError, ValueError) as exc:
        raise NanoctError(f"--device {device!r} is not a device; use cpu, cuda or cuda:<index>") from exc


def parse_params(items: list[str]) -> dict[str, Any]:
    """``--param name=value`` items as keyword arguments: each value read as JSON (0.2, [16,32], true), the words
    true and false in any case (Python's True, False) as booleans, anything else as the string it is."""
    params: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise NanoctError(f"--param {item!r} must look like name=value (e.g. relaxation=0.2)")
        try:
            params[key] = json.loads(value)
        except json.JSONDecodeError:
            params[key] = value.lower() == "true" if value.lower() in ("true", "false") else value
    return params


def parse_levels(text: str) -> list[float]:
    """``"0.68,0.9"`` -> [0.68, 0.9]; a clear error for anything else."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if not values or not all(0 < v < 1 for v in values):
        raise NanoctError(f"--levels {text!r} must be comma-separated coverages between 0 and 1, e.g. 0.68,0.9,0.95")
    return values


def parse_range(text: str | None, flag: str, sep: str) -> tuple[int, int] | None:
    """``FIRST<sep>STOP`` with ``0 <= FIRST < STOP`` (None stays None)."""
    if text is None:
        return None
    try:
        first, stop = (int(v) for v in text.split(sep))
    except ValueError:
        raise NanoctError(f"{flag} {text!r} must be two integers FIRST{sep}STOP, e.g. 10{sep}20") from None
    if not 0 <= first < stop:
        raise NanoctError(f"{flag} {text!r} must satisfy 0 <= FIRST < STOP")
    return first, stop


def parse_ints(text: str, flag: str, low: int = 1) -> tuple[int, ...]:
    """Comma-separated whole numbers, each at least ``low``."""
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise NanoctError(f"{flag} {text!r}: give comma-separated whole numbers, e.g. 2,2,1") from None
    if not values or min(values) < low:
        raise NanoctError(f"{flag} {text!r}: every value must be >= {low}")
    return values


def parse_center(text: str) -> float | str:
    """``--center-offset``: a number of pixels or ``auto``."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return float(text)
    except ValueError:
        raise NanoctError(f"--center-offset {text!r}: give a number of pixels or 'auto'") from None


def parse_model(model: str | None) -> tuple[int, ...] | None:
    """``--model DEGREE,HARMONICS``."""
    smooth = None if model is None else parse_ints(model, "--model", low=0)
    if smooth is not None and len(smooth) != 2:
        raise NanoctError(f"--model {model!r}: give DEGREE,HARMONICS, e.g. 3,3")
    return smooth


def parse_eta(text: str) -> Any:
    """``--eta``: ``auto``, a number, or a ``.npy`` file of per-view levels (checked by the stack)."""
    if text == "auto":
        return text
    if text.endswith(".npy"):
        import numpy as np

        if not Path(text).is_file():
            raise NanoctError(f"--eta {text!r}: no such file; give auto, a number or a .npy file of per-view levels")
        return np.load(text)
    try:
        return float(text)
    except ValueError:
        raise NanoctError(f"--eta {text!r}: give auto, a number >= 0 or a .npy file of per-view levels") from None


def parse_models(models: str) -> tuple[str, ...]:
    """``reproduce --models``: the comma-separated networks, ``()`` for ``none``."""
    return () if models.strip() == "none" else tuple(m.strip() for m in models.split(",") if m.strip())
