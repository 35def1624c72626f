"""Registry of reconstruction methods: the one place that lists them.

Each method is registered by name with the import paths of its solver and of its parameter
check (both imported only when used, so reading the registry costs nothing), whether it needs
the per-view model error ``eta``, whether it estimates motion, how its output is named in a
store, and a one-line help. :mod:`nanoct.recon.batch`, the CLI's ``reconstruct`` command and
:mod:`nanoct.reproduce` read it. To add a method, write its module (a solver following the
contract of :mod:`nanoct.recon` and a ``check_params(op, **params)`` with the same keyword names
and defaults) and add one entry::

    METHODS["sart"] = MethodSpec("nanoct.recon.sart:sart", "nanoct.recon.sart:check_params", "SART")

A method may also have batch parameters, used by the batch runner and not passed to the
solver (where RESESOP's eta comes from; a motion shared by several slices for Dremel), checked
by its ``batch_checker`` together with the solver's parameters.
"""

from __future__ import annotations

import importlib
import inspect
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import NanoctError
from ..geometry import Geometry

__all__ = [
    "METHODS",
    "MethodSpec",
    "check_method_params",
    "method_help",
    "method_spec",
    "methods_with_eta",
    "methods_with_motion",
    "output_name",
    "reconstruct_command",
]


def _plain_name(method: str, params: dict[str, Any]) -> str:
    return method


def _eta_name(method: str, params: dict[str, Any]) -> str:
    """``resesop`` for the true eta, ``resesop_est-residual`` for an estimate; ``_eta0.8`` added when scaled."""
    from .eta_source import check_eta_param, eta_label

    label = eta_label(check_eta_param(None, eta=params.get("eta", "true"))["eta"])  # type: ignore[arg-type]
    base = f"{method}_{label}" if label else method
    scale = params.get("eta_scale", 1.0)
    return base if np.isclose(scale, 1.0) else f"{base}_eta{scale:g}"


@dataclass(frozen=True)
class MethodSpec:
    """A reconstruction method: where it lives and how the tools treat it.

    Attributes
    ----------
    target : str
        ``"module:function"`` of the solver ``f(op, sino[, eta], **params) -> ReconResult``.
    checker : str
        ``"module:function"`` of its parameter check ``check_params(op, **params) -> dict``
        (keyword-only parameters = the parameters a user may set).
    help : str
        One line for the CLI.
    needs_eta : bool
        The solver takes the per-view model error ``eta`` as third argument (scaled by the
        ``eta_scale`` parameter, the CLI's ``--eta-scale``).
    estimates_motion : bool
        The result carries per-view shifts (stored as ``reconstructions/<name>_shifts``).
    output_name : callable
        ``output_name(method, params) -> str``: the default store name of a result.
    batch_checker : str, optional
        ``"module:function"`` of the check of the parameters the batch runner uses itself and
        does not pass to the solver (e.g. where eta or a shared motion comes from), same form
        as ``checker``.
    """

    target: str
    checker: str
    help: str
    needs_eta: bool = False
    estimates_motion: bool = False
    output_name: Callable[[str, dict[str, Any]], str] = _plain_name
    batch_checker: str | None = None

    def solver(self) -> Callable[..., Any]:
        """The solver function (imported on first use)."""
        return _load(self.target)

    def check_function(self) -> Callable[..., dict[str, Any]]:
        """The parameter check ``check_params(op, **params)`` (imported on first use)."""
        return _load(self.checker)

    def parameter_names(self) -> tuple[str, ...]:
        """The parameters a user may set (keyword-only parameters of both checks)."""
        return self.solver_parameter_names() + self.batch_parameter_names()

    def solver_parameter_names(self) -> tuple[str, ...]:
        """The parameters passed to the solver (keyword-only parameters of ``checker``)."""
        return _keywords(self.check_function())

    def batch_parameter_names(self) -> tuple[str, ...]:
        """The parameters the batch runner uses itself (not passed to the solver)."""
        return () if self.batch_checker is None else _keywords(_load(self.batch_checker))


def _keywords(function: Callable[..., Any]) -> tuple[str, ...]:
    sig = inspect.signature(function)
    return tuple(n for n, p in sig.parameters.items() if p.kind is inspect.Parameter.KEYWORD_ONLY)


def _load(target: str) -> Callable[..., Any]:
    module, _, attr = target.partition(":")
    return getattr(importlib.import_module(module), attr)


#: Registered methods, in the order the CLI lists them.
METHODS: dict[str, MethodSpec] = {
    "fbp": MethodSpec("nanoct.recon.fbp:fbp", "nanoct.recon.fbp:check_params", "filtered back projection (direct)"),
    "kaczmarz": MethodSpec(
        "nanoct.recon.kaczmarz:kaczmarz", "nanoct.recon.kaczmarz:check_params", "Kaczmarz (ART) sweeps"
    ),
    "dremel": MethodSpec(
        "nanoct.recon.dremel:dremel",
        "nanoct.recon.dremel:check_params",
        "Kaczmarz with per-view shift estimation (Algorithm 1)",
        estimates_motion=True,
        batch_checker="nanoct.recon.shared:check_motion_params",
    ),
    "resesop": MethodSpec(
        "nanoct.recon.resesop:resesop",
        "nanoct.recon.resesop:check_params",
        "RESESOP-Kaczmarz with model error eta (Algorithm 2)",
        needs_eta=True,
        output_name=_eta_name,
        batch_checker="nanoct.recon.eta_source:check_eta_param",
    ),
}


def methods_with_eta() -> tuple[str, ...]:
    """Names of the methods that take the model error eta (and ``--eta-scale``)."""
    return tuple(name for name, spec in METHODS.items() if spec.needs_eta)


def methods_with_motion() -> tuple[str, ...]:
    """Names of the methods that estimate per-view motion (their results carry shifts)."""
    return tuple(name for name, spec in METHODS.items() if spec.estimates_motion)


def method_help() -> str:
    """One line per method, ``name: help``, for the CLI."""
    return "; ".join(f"{name}: {spec.help}" for name, spec in METHODS.items())


def method_spec(method: str) -> MethodSpec:
    """The registry entry of ``method``.

    Raises
    ------
    NanoctError
        If no method of that name is registered; the message lists the registered ones.
    """
    if method not in METHODS:
        raise NanoctError(f"--method {method!r} is unknown; use one of {', '.join(METHODS)}")
    return METHODS[method]


def output_name(method: str, params: dict[str, Any] | None = None) -> str:
    """Default store name of a reconstruction by ``method`` with ``params``, e.g. ``resesop_eta0.8``."""
    return method_spec(method).output_name(method, dict(params or {}))


def _flag(param: str) -> str:
    return {"eta_scale": "--eta-scale", "eta": "--eta"}.get(param, f"--param {param}")


def check_method_params(method: str, params: dict[str, Any], geometry: Geometry) -> dict[str, Any]:
    """Check the user parameters of ``method`` for ``geometry`` before any work is done.

    Returns
    -------
    dict
        The parameters with defaults filled in and values normalised.

    Raises
    ------
    NanoctError
        For an unknown method or parameter name, or a bad value; the message names the CLI
        flag (``--param NAME`` or ``--eta-scale``) and the accepted names or values.
    """
    spec = method_spec(method)
    accepted = spec.parameter_names()
    unknown = sorted(set(params) - set(accepted))
    if unknown:
        raise NanoctError(
            f"{', '.join(_flag(u) for u in unknown)}: not a parameter of --method {method}; "
            f"accepted: {', '.join(accepted)}"
        )
    batch = set(spec.batch_parameter_names())
    try:
        checked = spec.check_function()(geometry, **{k: v for k, v in params.items() if k not in batch})
        if spec.batch_checker is not None:
            checked.update(_load(spec.batch_checker)(geometry, **{k: v for k, v in params.items() if k in batch}))
        return checked
    except (TypeError, ValueError) as exc:
        name = str(exc).partition("=")[0]
        flag = _flag(name) if name in accepted else "a parameter"
        raise NanoctError(f"{flag} of --method {method}: {exc}") from exc


def _eta_command(path: str | os.PathLike[str], method: str, name: str) -> str | None:
    """The command of a default name of a method that uses eta (``resesop_est-residual_eta0.8``), or None."""
    base, sep, scale = name.rpartition("_eta")
    try:
        value = float(scale) if sep and base.startswith(method) else 1.0
    except ValueError:
        return None
    scale_flag = f" --eta-scale {scale}" if sep and base.startswith(method) else ""
    for eta in ("true", "estimate:residual", "estimate:reference=STORE"):
        if output_name(method, {"eta": eta, "eta_scale": value}) == name:
            eta_flag = "" if eta == "true" else f" --eta {eta}"
            return f"nanoct reconstruct {path} --method {method}{eta_flag}{scale_flag}"
    return None


def reconstruct_command(path: str | os.PathLike[str], name: str) -> str:
    """The ``nanoct reconstruct`` command that makes the reconstruction ``name`` (a hint for messages).

    Default output names (``fbp``, ``resesop_eta0.8``, ``resesop_est-residual``) give the exact
    command (``STORE`` standing for the reference store of ``resesop_est-reference``); any other
    name gives a template with ``--name``.
    """
    for method in METHODS:
        if name == method:
            return f"nanoct reconstruct {path} --method {method}"
        command = _eta_command(path, method, name) if METHODS[method].needs_eta else None
        if command is not None:
            return command
    return f"nanoct reconstruct {path} --method <{'|'.join(METHODS)}> --name {name}"
