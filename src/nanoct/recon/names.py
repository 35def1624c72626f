"""Names of reconstructions: the default name of a method's run and the command that makes a name.

The grammar as a whole is described in :mod:`nanoct.names`; the names of predictions and settings,
which need no method, are :mod:`nanoct.core.names`.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from ..core.names import is_prediction
from .registry import METHODS, method_spec

__all__ = ["eta_label", "predict_command", "reconstruct_command", "reconstruction_name", "stack_name"]


def eta_label(eta: str) -> str:
    """Short name of an eta source for output names: ``""`` (true), ``est-residual``, ``est-reference``.

    A residual estimate from another first reconstruction than ``dremel`` adds it: ``est-residual-NAME``.
    """
    kind, _, arg = eta.partition("=")
    if kind == "true" or not kind:
        return ""
    label = "est-" + kind.split(":", 1)[1]
    return f"{label}-{arg}" if kind == "estimate:residual" and arg not in ("", "dremel") else label


def reconstruction_name(method: str, params: dict[str, Any] | None = None) -> str:
    """Default store name of a reconstruction by ``method`` with ``params``, e.g. ``resesop_eta0.8``.

    Methods that use eta add the eta source (``resesop_est-residual``) and a scale other than 1
    (``_eta0.8``); other methods are named by the method.

    Raises
    ------
    NanoctError
        For an unknown method.
    """
    spec = method_spec(method)
    params = dict(params or {})
    if not spec.needs_eta:
        return method
    label = eta_label(str(params.get("eta", "true")).strip())
    base = f"{method}_{label}" if label else method
    scale = params.get("eta_scale", 1.0)
    return base if np.isclose(scale, 1.0) else f"{base}_eta{scale:g}"


def stack_name(method: str) -> str:
    """Default store name of a stack reconstruction by ``method`` (``fbp_stack``)."""
    return f"{method}_stack"


def _eta_command(path: str | os.PathLike[str], method: str, name: str) -> str | None:
    """The command of a default name of a method that uses eta (``resesop_est-residual_eta0.8``), or None."""
    base, sep, scale = name.rpartition("_eta")
    try:
        value = float(scale) if sep and base.startswith(method) else 1.0
    except ValueError:
        return None
    scale_flag = f" --eta-scale {scale}" if sep and base.startswith(method) else ""
    for eta in ("true", "estimate:residual", "estimate:reference=STORE"):
        if reconstruction_name(method, {"eta": eta, "eta_scale": value}) == name:
            eta_flag = "" if eta == "true" else f" --eta {eta}"
            return f"nanoct reconstruct {path} --method {method}{eta_flag}{scale_flag}"
    return None


def reconstruct_command(path: str | os.PathLike[str], name: str) -> str:
    """The ``nanoct reconstruct`` command that makes the reconstruction ``name`` (a hint for messages).

    Default output names (``fbp``, ``resesop_eta0.8``, ``resesop_est-residual``, ``fbp_stack``:
    ``nanoct stack``) give the exact
    command (``STORE`` standing for the reference store of ``resesop_est-reference``); any other
    name gives a template with ``--name``.
    """
    for method, spec in METHODS.items():
        if name == method:
            return f"nanoct reconstruct {path} --method {method}"
        if name == stack_name(method):
            return f"nanoct stack {path} --method {method}"
        command = _eta_command(path, method, name) if spec.needs_eta else None
        if command is not None:
            return command
    return f"nanoct reconstruct {path} --method <{'|'.join(METHODS)}> --name {name}"


def predict_command(path: str | os.PathLike[str], name: str) -> str:
    """The command that makes result ``name`` (quoted): ``nanoct predict`` for a prediction, else
    :func:`reconstruct_command`."""
    if is_prediction(name):
        return f"'nanoct predict {path} --run RUN' (a run of a network trained on {name.split('+')[0]})"
    return f"'{reconstruct_command(path, name)}'"
