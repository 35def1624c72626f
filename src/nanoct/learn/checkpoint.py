"""Training checkpoints: written atomically, validated on load.

A checkpoint is a ``torch.save`` dict (loaded with ``weights_only=True``)::

    format, nanoct_version, model (registry name), hparams, image_size, input (method name),
    epoch (last finished epoch, 1-based), step (optimizer steps so far), best_val_loss,
    best_epoch, model_state, optimizer_state, scheduler_state, rng (torch/numpy/python/cuda),
    history (one dict per finished epoch: the rows of log.csv), config (the training request)

:func:`load_checkpoint` adds ``file_sha256``, the hash of the very bytes it loaded: what identifies the
weights a result was made with wherever the run lies, without a window in which the file could be
replaced between hashing and loading.

It is written with :func:`nanoct.io.fileio.atomic_write_bytes`, so a kill at any moment leaves
either the old or the new file.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import random
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from ..core.errors import NanoctError
from ..core.version import __version__
from ..io.fileio import atomic_write_bytes
from .base import PostProcessor
from .models import build_model

__all__ = [
    "CHECKPOINT_FORMAT",
    "get_rng_state",
    "load_checkpoint",
    "model_from_checkpoint",
    "save_checkpoint",
    "set_rng_state",
    "unwrap",
]

CHECKPOINT_FORMAT = 1
_REQUIRED = ("format", "model", "hparams", "image_size", "input", "epoch", "model_state")


def unwrap(model: nn.Module) -> nn.Module:
    """The network inside DDP / loss wrappers."""
    while hasattr(model, "module") and isinstance(model.module, nn.Module):
        model = model.module
    return model


def get_rng_state() -> dict[str, Any]:
    """RNG states of torch, numpy's legacy global generator, ``random`` and CUDA."""
    kind, keys, pos, has_gauss, gauss = np.random.get_state()
    state: dict[str, Any] = {
        "torch": torch.get_rng_state(),
        "numpy": {
            "kind": str(kind),
            "keys": torch.from_numpy(np.asarray(keys, dtype=np.int64)),
            "pos": int(pos),
            "has_gauss": int(has_gauss),
            "gauss": float(gauss),
        },
        "python": random.getstate(),
    }
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict[str, Any]) -> None:
    """Restore what :func:`get_rng_state` returned (missing parts are left alone)."""
    if "torch" in state:
        torch.set_rng_state(state["torch"])
    if "numpy" in state:
        s = state["numpy"]
        np.random.set_state((s["kind"], s["keys"].numpy().astype(np.uint32), s["pos"], s["has_gauss"], s["gauss"]))
    if "python" in state:
        py = state["python"]
        random.setstate((py[0], tuple(py[1]), py[2]))
    if "cuda" in state and torch.cuda.is_available() and len(state["cuda"]) == torch.cuda.device_count():
        torch.cuda.set_rng_state_all(state["cuda"])


def save_checkpoint(
    path: str | os.PathLike[str],
    *,
    model: nn.Module,
    input_name: str,
    image_size: int,
    epoch: int,
    step: int = 0,
    optimizer: torch.optim.Optimizer | None = None,
    scheduler: Any = None,
    best_val_loss: float = float("inf"),
    best_epoch: int = 0,
    history: list[dict[str, Any]] | None = None,
    config: dict[str, Any] | None = None,
) -> None:
    """Write a checkpoint of ``model`` (a PostProcessor, possibly DDP-wrapped) atomically."""
    net = unwrap(model)
    if not isinstance(net, PostProcessor):
        raise TypeError(f"expected a PostProcessor, got {type(net).__name__}")
    payload = {
        "format": CHECKPOINT_FORMAT,
        "nanoct_version": __version__,
        "model": net.name,
        "hparams": json.loads(json.dumps(net.hparams)),
        "image_size": int(image_size),
        "input": input_name,
        "epoch": int(epoch),
        "step": int(step),
        "best_val_loss": float(best_val_loss),
        "best_epoch": int(best_epoch),
        "model_state": {k: v.detach().cpu().contiguous() for k, v in net.state_dict().items()},
        "optimizer_state": optimizer.state_dict() if optimizer is not None else None,
        "scheduler_state": scheduler.state_dict() if scheduler is not None else None,
        "rng": get_rng_state(),
        "history": list(history or []),
        "config": dict(config or {}),
    }
    buf = io.BytesIO()
    torch.save(payload, buf)
    atomic_write_bytes(path, buf.getvalue())


def load_checkpoint(
    path: str | os.PathLike[str],
    *,
    model_name: str | None = None,
    image_size: int | None = None,
    hparams: dict[str, Any] | None = None,
    map_location: str | torch.device = "cpu",
) -> dict[str, Any]:
    """Load and validate a checkpoint.

    Parameters
    ----------
    path : path
        Checkpoint file.
    model_name, image_size, hparams : optional
        What the caller expects; a checkpoint of another model, image size or architecture
        is refused.

    Returns
    -------
    dict
        The checkpoint's fields, plus ``file_sha256``: the SHA-256 (hex) of the bytes loaded.

    Raises
    ------
    NanoctError
        If the file is missing, unreadable or corrupt, or does not match the expectation.
    """
    path = Path(path)
    if not path.is_file():
        raise NanoctError(f"checkpoint {path} does not exist; train a model first ('nanoct train')")
    try:
        data = path.read_bytes()
        ckpt = torch.load(io.BytesIO(data), map_location=map_location, weights_only=True)
    except Exception as exc:
        raise NanoctError(
            f"checkpoint {path} is corrupt or not a nanoct checkpoint ({type(exc).__name__}: {exc}); "
            "delete it and train again"
        ) from exc
    if not isinstance(ckpt, dict) or any(k not in ckpt for k in _REQUIRED):
        raise NanoctError(f"{path} is not a nanoct checkpoint (missing fields); delete it and train again")
    if ckpt["format"] != CHECKPOINT_FORMAT:
        raise NanoctError(
            f"checkpoint {path} has format {ckpt['format']}, this nanoct reads format {CHECKPOINT_FORMAT}"
        )
    if model_name is not None and ckpt["model"] != model_name:
        raise NanoctError(f"checkpoint {path} holds a '{ckpt['model']}' model, not '{model_name}'")
    if image_size is not None and int(ckpt["image_size"]) != int(image_size):
        raise NanoctError(
            f"checkpoint {path} was trained on {ckpt['image_size']}x{ckpt['image_size']} images, "
            f"the data here are {image_size}x{image_size}; train a model for this image size"
        )
    if hparams is not None and ckpt["hparams"] != hparams:
        diff = sorted(k for k in set(hparams) | set(ckpt["hparams"]) if hparams.get(k) != ckpt["hparams"].get(k))
        raise NanoctError(f"checkpoint {path} has another architecture (differs in: {', '.join(diff)})")
    return ckpt | {"file_sha256": hashlib.sha256(data).hexdigest()}


def model_from_checkpoint(ckpt: dict[str, Any], path: str | os.PathLike[str] = "checkpoint") -> PostProcessor:
    """Rebuild the model of a loaded checkpoint and load its weights (on CPU).

    Raises
    ------
    NanoctError
        If the weights do not fit the architecture the checkpoint names.
    """
    model = build_model(ckpt["model"], **ckpt["hparams"])
    try:
        model.load_state_dict(ckpt["model_state"])
    except RuntimeError as exc:
        raise NanoctError(
            f"the weights in {path} do not fit a '{ckpt['model']}' with {ckpt['hparams']}: {exc}"
        ) from exc
    return model
