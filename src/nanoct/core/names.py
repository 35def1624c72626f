"""Names of predictions and settings: the part of the result-name grammar that needs no method.

The grammar as a whole is described in :mod:`nanoct.names`; this module builds and parses what
any layer may meet in a store (is a name a network's prediction, of which input, model and seed),
:mod:`nanoct.recon.names` the names that a method and its parameters give.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "SETTINGS",
    "ResultName",
    "is_prediction",
    "parse_name",
    "prediction_name",
    "scaling_name",
    "seed_name",
    "setting_key",
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
