"""Calibration of a sampling network's std on the validation split, stored with its run.

The std of a conditional invertible network (over M latent samples) is rarely calibrated: far
more (or fewer) than 68 % of the pixels fall within one std of the mean. Per run and checkpoint,
on the validation split of the data set and input the network was trained on (the test split is
never read), two calibrations are fitted: a map from raw to calibrated std, strictly increasing
in the std, for each quartile of the predicted value (:func:`nanoct.evaluation.metrics.fit_value_std_map`,
fitted bin by bin of the raw std at 1, 2 and 3 std), which is the one applied, and, for
comparison, one factor ``s`` making ``s * std`` cover 68.27 % of the validation pixels
(temperature scaling). On the same validation outputs the factor of the edge baseline
(:func:`nanoct.evaluation.metrics.edge_std` of the network's mean) is fitted, so that its coverage can be
compared at equal footing.

The fit lives in ``<run>/calibration.json``, one entry per checkpoint (``"best"``, ``"last"``).
An entry is reused only if it was fitted for the same checkpoint file (SHA-256), data set,
input and sampling arguments (M); otherwise it is fitted again. Validation outputs are made as
:func:`nanoct.learn.predict.predict` makes them: one image at a time, latent samples seeded
with the sample index, so the fit sees exactly the std that ``predict --split val`` would store.
Conventions and the metrics: ``docs/uncertainty.md``.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..core.errors import NanoctError
from ..evaluation.metrics import (
    EDGE_SIGMA,
    GAUSSIAN_COVERAGE,
    apply_std_map,
    coverage,
    edge_std,
    fit_std_scale,
    fit_value_std_map,
)
from ..io.fileio import atomic_write_text
from ..io.store import DataStore
from .base import PostProcessor
from .checkpoint import load_checkpoint, model_from_checkpoint
from .data import check_input
from .models import model_class
from .train import resolve_device

__all__ = [
    "CALIBRATION_FILE",
    "CALIBRATION_FORMAT",
    "Inference",
    "calibrate",
    "fit_scales",
    "load_calibration",
    "sample_outputs",
]

CALIBRATION_FILE = "calibration.json"
#: Version of a calibration entry; entries of another version are fitted again (2: the std map;
#: 3: one std map per bin of the predicted value).
CALIBRATION_FORMAT = 3


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _n_samples(model_name: str, kwargs: dict[str, Any]) -> int | None:
    """M: the ``n_samples`` passed, else the default of the model's ``reconstruct``."""
    if "n_samples" in kwargs:
        return int(kwargs["n_samples"])
    param = inspect.signature(model_class(model_name).reconstruct).parameters.get("n_samples")
    return None if param is None or param.default is inspect.Parameter.empty else int(param.default)


class Inference:
    """A model on its device (channels-last on CPU), called on a batch: (mean, calibrated std or None) as numpy.

    A sampling model is called one image at a time with ``seed`` = the sample's index, so a
    prediction does not depend on batching or resumption; its std goes through ``std_map``
    (:func:`nanoct.evaluation.metrics.apply_std_map` with the mean as the predicted values; None keeps the
    raw std).
    :func:`nanoct.learn.predict.predict` and :func:`sample_outputs` both use it, so the calibration
    sees exactly the std that predict stores.
    """

    def __init__(
        self,
        model: Any,
        kwargs: dict[str, Any],
        sampling: bool,
        std_map: dict[str, Any] | None,
        device: str | torch.device | None,
    ) -> None:
        self.dev = resolve_device(device)
        self.channels_last = self.dev.type == "cpu"
        model = model.to(self.dev, memory_format=torch.channels_last) if self.channels_last else model.to(self.dev)
        model.eval()
        self.model, self.kwargs, self.sampling, self.std_map = model, kwargs, sampling, std_map

    def __call__(self, x_tilde: np.ndarray, first_index: int) -> tuple[np.ndarray, np.ndarray | None]:
        x = torch.from_numpy(np.ascontiguousarray(x_tilde, np.float32))[:, None].to(self.dev)
        if self.channels_last:
            x = x.contiguous(memory_format=torch.channels_last)
        call = {"seed": first_index, **self.kwargs} if self.sampling else self.kwargs
        with torch.no_grad():
            mean, std = self.model.reconstruct(x, **call)
        mean_np = mean.float().cpu().numpy()[:, 0]
        std_np = None if std is None else std.float().cpu().numpy()[:, 0]
        if std_np is not None and self.std_map is not None:
            if not (np.isfinite(std_np).all() and np.isfinite(mean_np).all()):
                raise NanoctError(
                    f"the {self.model.name} network gave a non-finite mean or std for sample {first_index}; "
                    "its checkpoint is damaged or training diverged: train it again"
                )
            std_np = apply_std_map(std_np, self.std_map, mean_np).astype(np.float32)
        return mean_np, std_np


def sample_outputs(
    model: PostProcessor,
    store: DataStore,
    input_name: str,
    indices: np.ndarray,
    reconstruct_kwargs: dict[str, Any] | None = None,
    device: str | torch.device | None = None,
    progress: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Mean and raw std of a sampling network for ``reconstructions/<input_name>`` at ``indices``.

    One image per call of ``model.reconstruct`` with ``seed`` = the sample index, on ``device``
    (channels-last on CPU), as :func:`nanoct.learn.predict.predict` does.

    Returns
    -------
    (means, stds) : float32 arrays (n, H, W)
    """
    from tqdm.auto import tqdm

    infer = Inference(model, dict(reconstruct_kwargs or {}), True, None, device)
    n = store.geometry.n
    means, stds = np.empty((len(indices), n, n), np.float32), np.empty((len(indices), n, n), np.float32)
    for j, i in enumerate(tqdm(indices, desc="calibrate", unit="img", disable=not progress)):
        mean, std = infer(store.read_reconstruction(input_name, [int(i)]), int(i))
        if std is None:
            raise NanoctError(f"a '{model.name}' network gives no std; only sampling networks are calibrated")
        means[j], stds[j] = mean[0], std[0]
    return means, stds


def fit_scales(means: np.ndarray, stds: np.ndarray, gts: np.ndarray, edge_sigma: float = EDGE_SIGMA) -> dict[str, Any]:
    """Fit the std's calibration map, its one factor and the edge baseline's factor on validation outputs.

    The map is :func:`nanoct.evaluation.metrics.fit_value_std_map` (coverage at 1, 2 and 3 std, bin by bin
    of the raw std, within each quartile of the mean); each factor is
    :func:`nanoct.evaluation.metrics.fit_std_scale` at the Gaussian 1-std level (68.27 %). All pixels of
    all images are pooled.

    Returns
    -------
    dict
        ``std_map`` (the knots, applied by predict), ``level``, ``scale`` (the one factor), and
        the validation coverages at 1/2/3 std ``coverage_raw``, ``coverage_scaled`` (one factor)
        and ``coverage_calibrated`` (map) of the network's std; ``edge_sigma``, ``edge_scale``,
        ``edge_coverage`` (after scaling).

    Raises
    ------
    NanoctError
        If no positive finite factor or map exists (e.g. a std that is zero where the error is not).
    """
    err = np.abs(np.asarray(means, np.float64) - np.asarray(gts, np.float64))
    stds = np.asarray(stds, np.float64)
    edges = edge_std(means, edge_sigma)
    level = GAUSSIAN_COVERAGE["1"]
    try:
        scale, edge_scale = fit_std_scale(err, stds, level), fit_std_scale(err, edges, level)
        std_map = fit_value_std_map(err, stds, means)
    except ValueError as exc:
        raise NanoctError(f"cannot calibrate on the validation outputs: {exc}") from exc
    return {
        "std_map": std_map,
        "level": level,
        "scale": scale,
        "coverage_raw": coverage(err, stds),
        "coverage_scaled": coverage(err, scale * stds),
        "coverage_calibrated": coverage(err, apply_std_map(stds, std_map, means)),
        "edge_sigma": float(edge_sigma),
        "edge_scale": edge_scale,
        "edge_coverage": coverage(err, edge_scale * edges),
    }


def load_calibration(run_dir: str | os.PathLike[str]) -> dict[str, dict[str, Any]]:
    """The entries of ``<run>/calibration.json`` by checkpoint name (empty if absent or unreadable)."""
    path = Path(run_dir) / CALIBRATION_FILE
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def calibrate(
    store: DataStore | str | os.PathLike[str],
    run_dir: str | os.PathLike[str],
    checkpoint: str = "best",
    *,
    reconstruct_kwargs: dict[str, Any] | None = None,
    device: str | torch.device | None = None,
    progress: bool = False,
    refit: bool = False,
) -> dict[str, Any]:
    """The calibration of a run's checkpoint: reused from ``calibration.json`` if valid, else fitted and stored.

    Parameters
    ----------
    store : DataStore or path
        Data set whose validation split (of the run's training input) is used.
    run_dir : path
        Training run of a sampling network.
    checkpoint : {"best", "last"}
        Checkpoint to calibrate.
    reconstruct_kwargs : dict, optional
        Passed to ``reconstruct`` (e.g. ``{"n_samples": M}``); part of the validity key.
    device, progress
        As for :func:`nanoct.learn.predict.predict`.
    refit : bool
        Fit again even if a valid entry exists.

    Returns
    -------
    dict
        The entry: what it was fitted for (``format``, ``checkpoint``, ``checkpoint_sha256``,
        ``epoch``, ``store``, ``input``, ``reconstruct``, ``n_samples``, ``split`` = "val",
        ``n_images``) and :func:`fit_scales`'s result.

    Raises
    ------
    NanoctError
        A missing or bad checkpoint, a network without std, an empty validation split or an
        incomplete input, or validation outputs that admit no factor or map.
    """
    store = store if isinstance(store, DataStore) else DataStore.open(store)
    run = Path(run_dir)
    ckpt_path = run / f"{checkpoint}.pt"
    entries = load_calibration(run)
    key = {
        "format": CALIBRATION_FORMAT,
        "checkpoint": checkpoint,
        "checkpoint_sha256": _sha256(ckpt_path) if ckpt_path.is_file() else None,
        "store": str(store.path.resolve()),
        "reconstruct": json.loads(json.dumps(dict(reconstruct_kwargs or {}))),
        "split": "val",
    }
    old = entries.get(checkpoint)
    if not refit and isinstance(old, dict) and all(old.get(k) == v for k, v in key.items()):
        return old  # the same checkpoint file (so the same model, input and epoch), data set and M
    if isinstance(old, dict) and store.indices("val").size == 0:
        # a data set without validation samples (an imported scan): the fit on the run's own
        # validation data holds for the same checkpoint file and M
        if all(old.get(k) == v for k, v in key.items() if k != "store"):
            return old
    ckpt = load_checkpoint(ckpt_path, image_size=store.geometry.n)
    if not model_class(str(ckpt["model"])).has_uncertainty:
        raise NanoctError(f"the run at {run} holds a '{ckpt['model']}' network, which gives no std to calibrate")
    kwargs = key["reconstruct"]
    key |= {
        "epoch": int(ckpt["epoch"]),
        "input": str(ckpt["input"]),
        "n_samples": _n_samples(str(ckpt["model"]), kwargs),
    }
    val = store.indices("val")
    if val.size == 0:
        raise NanoctError(
            f"{store.path} has no validation samples to calibrate the std of {run} on; predict on the data "
            "set the run was trained on first (it fits the calibration), or predict with --no-calibrate"
        )
    check_input(store, key["input"], val, "val")
    model = model_from_checkpoint(ckpt, ckpt_path)
    means, stds = sample_outputs(model, store, key["input"], val, kwargs, device, progress)
    entry = key | {"n_images": int(val.size)} | fit_scales(means, stds, store.read_phantoms(val))
    entries[checkpoint] = entry
    atomic_write_text(run / CALIBRATION_FILE, json.dumps(entries, indent=2))
    return entry
