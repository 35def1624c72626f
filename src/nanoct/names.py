"""Names of results and settings: the one place their grammar is built and parsed.

Every array of reconstructions in a store has a name; predictions of a network have a name
built from their input's. The grammar::

    reconstruction   <method>[_est-<source>[-<first>]][_eta<scale>]
                     fbp, dremel, resesop_eta0.8, resesop_est-residual, resesop_est-reference_eta1.2
    stack            <method>_stack  (``nanoct stack``: one motion and axis for all slices)
                     fbp_stack, dremel_stack
    prediction       <input>+<model>[@<train input>][%seed<S>]
                     dremel+unet, fbp+cinn-res@resesop (trained on resesop, applied to fbp),
                     resesop+unet%seed1 (training seed 1; seed 0 has no suffix)
    scaling run      <input>+<model>%n<K>x<steps>[%seed<S>]
                     dremel+unet%n640x640%seed1 (data-scaling study: first K training images)
    setting          parallel | fan | unperturbed  (the paper's tables: geometry kind and motion)

The ``_est-...`` and ``_eta<scale>`` parts belong to methods that use the model error eta
(:attr:`nanoct.recon.registry.MethodSpec.needs_eta`); :func:`reconstruction_name` gives the
default name of a batch run and :func:`reconstruct_command` the command that makes a name.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from .recon.registry import METHODS, method_spec

__all__ = [
    "SETTINGS",
    "ResultName",
    "eta_label",
    "is_prediction",
    "parse_name",
    "predict_command",
    "prediction_name",
    "reconstruct_command",
    "reconstruction_name",
    "scaling_name",
    "seed_name",
    "setting_key",
    "stack_name",
    "strip_seed",
]

#: The paper's three settings: key -> (geometry kind, perturbed).
SETTINGS: dict[str, tuple[str, bool]] = {
    "parallel": ("parallel", True),
    "fan": ("fan", True),
    "unperturbed": ("parallel", False),
}

_SEED = "%seed"


def setting_key(kind: str, perturbed: bool) -> str | None:
    """The paper's setting of data of geometry ``kind`` with or without motion (None: not one of them)."""
    return next((key for key, value in SETTINGS.items() if value == (kind, bool(perturbed))), None)


@dataclass(frozen=True)
class ResultName:
    """A parsed result name: its input, the network (None for a first reconstruction), the
    network's training input (the input itself unless mixed) and its training seed."""

    input: str
    model: str | None = None
    train_input: str | None = None
    seed: int = 0

    @classmethod
    def parse(cls, name: str) -> ResultName:
        """Parse ``<input>[+<model>[@<train input>]][%seed<S>]``."""
        base, sep, seed = name.partition(_SEED)
        if "+" not in base:
            return cls(base, None, base, int(seed) if sep and seed.isdigit() else 0)
        test_input, rest = base.split("+", 1)
        model, _, train_input = rest.partition("@")
        return cls(test_input, model, train_input or test_input, int(seed) if sep and seed.isdigit() else 0)

    @property
    def base(self) -> str:
        """The name without its seed suffix."""
        if self.model is None:
            return self.input
        return prediction_name(self.input, self.model, self.train_input)

    def __str__(self) -> str:
        return seed_name(self.base, self.seed)


def prediction_name(input_name: str, model_name: str, train_input: str | None = None, seed: int = 0) -> str:
    """Store name of a prediction: ``<input>+<model>``, ``@<train_input>`` when trained on another input,
    ``%seed<S>`` for training seed S > 0."""
    name = f"{input_name}+{model_name}"
    if train_input is not None and train_input != input_name:
        name += f"@{train_input}"
    return seed_name(name, seed)


def scaling_name(input_name: str, model_name: str, n_train: int, steps: int, seed: int = 0) -> str:
    """Store name of a data-scaling study's prediction: ``<input>+<model>%n<K>x<steps>`` (network
    trained on the first K training images for ``steps`` optimiser steps), ``%seed<S>`` for seed S > 0."""
    return seed_name(f"{prediction_name(input_name, model_name)}%n{n_train}x{steps}", seed)


def seed_name(name: str, seed: int) -> str:
    """Store name of a prediction of training seed ``seed`` (seed 0: the name itself)."""
    return name if seed == 0 else f"{name}{_SEED}{seed}"


def strip_seed(name: str) -> str:
    """``name`` without its ``%seed<S>`` suffix."""
    return name.split(_SEED)[0]


def parse_name(name: str) -> tuple[str, str | None, str]:
    """Split a result name into (test input, model or None, training input); a seed suffix is kept
    on the last part it follows (see :class:`ResultName` to parse it off)."""
    if "+" not in name:
        return name, None, name
    test_input, rest = name.split("+", 1)
    model, _, train_input = rest.partition("@")
    return test_input, model, train_input or test_input


def is_prediction(name: str) -> bool:
    """Whether ``name`` is a network's prediction (``<input>+<model>...``)."""
    return "+" in name


# ------------------------------------------------------------------ reconstruction names
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
