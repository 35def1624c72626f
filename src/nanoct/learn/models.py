"""Registry of post-processing networks and their training defaults.

A model is registered by name with the import path of its :class:`~nanoct.learn.base.PostProcessor`
subclass (imported only when used, so the registry costs nothing) and the paper's training
settings for it. To add a model::

    MODELS["mynet"] = ModelSpec("nanoct.learn.mynet:MyNet", lr=1e-4, batch_size=16, clip_grad=1.0)
"""

from __future__ import annotations

import importlib
import inspect
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ..core.errors import NanoctError

if TYPE_CHECKING:  # the registry itself does not import torch (the study planner reads it)
    from .base import PostProcessor

__all__ = [
    "MODELS",
    "ModelSpec",
    "build_model",
    "model_class",
    "model_names",
    "model_spec",
    "table_order",
]


@dataclass(frozen=True)
class ModelSpec:
    """Where a model lives and its default training settings (the paper's)."""

    target: str  # "module:Class"
    lr: float = 1e-3
    batch_size: int = 16
    epochs: int = 500
    clip_grad: float | None = None
    scheduler: str | None = None


#: Registered models, in the order of the paper's tables (see :func:`table_order`).
MODELS: dict[str, ModelSpec] = {
    # the paper: Adam with *initial* lr 1e-3, batch 16, 500 epochs; the decay is dival's UNet
    # default (cosine annealing to 1e-4); dival is by two of the paper's authors
    "unet": ModelSpec("nanoct.learn.unet:UNetPost", lr=1e-3, batch_size=16, epochs=500, scheduler="cosine"),
    # the paper: Adam lr 1e-5, batch 16, 500 epochs; gradient clipping at 1.0 and a plateau
    # schedule as in cinn_for_imaging (see docs/learn.md)
    "cinn": ModelSpec("nanoct.learn.cinn:CiNN", lr=1e-5, batch_size=16, epochs=500, clip_grad=1.0, scheduler="plateau"),
    "cinn-res": ModelSpec(
        "nanoct.learn.cinn:CiNNRes", lr=1e-5, batch_size=16, epochs=500, clip_grad=1.0, scheduler="plateau"
    ),
    "ciunet": ModelSpec(
        "nanoct.learn.ciunet:CiUNet", lr=1e-5, batch_size=16, epochs=500, clip_grad=1.0, scheduler="plateau"
    ),
    "ciunet-res": ModelSpec(
        "nanoct.learn.ciunet:CiUNetRes", lr=1e-5, batch_size=16, epochs=500, clip_grad=1.0, scheduler="plateau"
    ),
}


def model_names() -> list[str]:
    """Registered model names."""
    return sorted(MODELS)


def table_order() -> tuple[str, ...]:
    """Registered model names in the paper's table order (the registry's order)."""
    return tuple(MODELS)


def model_spec(name: str) -> ModelSpec:
    """The registry entry of ``name``.

    Raises
    ------
    NanoctError
        If no model of that name is registered.
    """
    if name not in MODELS:
        raise NanoctError(f"model {name!r} is unknown; use one of {', '.join(model_names())}")
    return MODELS[name]


def model_class(name: str) -> type[PostProcessor]:
    """The PostProcessor subclass registered as ``name`` (imports its module, and torch)."""
    from .base import PostProcessor

    module, _, attr = model_spec(name).target.partition(":")
    cls = getattr(importlib.import_module(module), attr)
    if not (isinstance(cls, type) and issubclass(cls, PostProcessor)):  # pragma: no cover - registry bug
        raise TypeError(f"{model_spec(name).target} is not a PostProcessor")
    return cls


def build_model(name: str, **kwargs: Any) -> PostProcessor:
    """Build model ``name`` with architecture keyword arguments ``kwargs``.

    Raises
    ------
    NanoctError
        If the name is unknown or the keyword arguments are not accepted.
    """
    cls = model_class(name)
    accepted = [p for p in inspect.signature(cls.__init__).parameters if p != "self"]
    unknown = sorted(set(kwargs) - set(accepted))
    if unknown and not any(p.kind is p.VAR_KEYWORD for p in inspect.signature(cls.__init__).parameters.values()):
        raise NanoctError(
            f"model {name!r} has no parameter {', '.join(unknown)}; its parameters are {', '.join(accepted)}"
        )
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise NanoctError(f"cannot build model {name!r} with {kwargs}: {exc}") from exc
