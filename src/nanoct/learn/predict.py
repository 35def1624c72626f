"""Apply a trained post-processing network to the reconstructions of a store.

The result goes to ``reconstructions/<input>+<model>`` when the input is the method the
network was trained on, and to ``reconstructions/<input>+<model>@<train_input>`` when a
network trained on one method is applied to another (the paper's input-mixing tables).
Networks that return a pixel-wise standard deviation also write ``uncertainty/<name>``; their
latent samples for sample ``i`` are drawn from a generator seeded with ``i``, so results do
not depend on batching or on interruptions; their std is stored calibrated, through the map
from raw to calibrated std fitted on the validation split (:mod:`nanoct.learn.calibration`).

The parameters (run directory, checkpoint file and epoch, model, architecture, train input)
are stored with the result; running the same command again only fills in missing samples,
and a different checkpoint under the same name is refused unless ``overwrite``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..core.errors import NanoctError, StoreError
from ..io.fileio import disk_space_needed
from ..io.lock import exclusive
from ..io.store import SPLITS, DataStore
from ..names import prediction_name
from .calibration import Inference
from .calibration import calibrate as calibrate_run
from .checkpoint import load_checkpoint, model_from_checkpoint
from .data import check_input
from .models import model_class

__all__ = ["predict"]


def _request(params: dict[str, Any], made_from: dict[str, Any]) -> dict[str, Any]:
    """What a prediction's parameters ask for: without what it was made from and without the
    calibration's fitted values (a refit of the same run's calibration is the same request),
    but with whether it is calibrated (a raw and a calibrated result are not)."""
    kept = {k: v for k, v in params.items() if k not in made_from and k != "calibration"}
    return kept | {"calibrated": "calibration" in params}


def _check_geometry(store: DataStore, run: Path, ckpt: dict[str, Any]) -> None:
    """Refuse a run trained on another geometry than the data set's (before any work is done)."""
    trained = (ckpt.get("config") or {}).get("data", {}).get("geometry")
    here = json.loads(json.dumps(store.geometry.to_dict()))
    if trained is not None and trained != here:
        raise NanoctError(
            f"the run {run.resolve()} was trained on another geometry ({trained}) than the data set {store.path} "
            f"({here}); train a network on this data set"
        )


def _provenance(store: DataStore, out: str, params: dict[str, Any], overwrite: bool) -> dict:
    """``params`` plus what the prediction is made from (geometry, input fingerprint).

    Deletes an earlier ``out`` made with other settings (with ``overwrite``) or with the same
    settings from an input that has changed since or under another calibration of the same run
    (refitted after a format change).
    """
    here = json.loads(json.dumps(store.geometry.to_dict()))
    made_from = {"geometry": here, "input_fingerprint": store.recons.fingerprint(params["input"])}
    new = json.loads(json.dumps({**params, **made_from}))
    if out in store.reconstruction_names():
        old = store.reconstruction_params(out)
        same_request = _request(old, made_from) == _request(params, made_from)
        if old != new and (overwrite or same_request):
            store.delete_reconstruction(out)
    return new


def predict(
    store_path: str | os.PathLike[str],
    run_dir: str | os.PathLike[str],
    input_name: str | None = None,
    *,
    split: str = "test",
    checkpoint: str = "best",
    batch_size: int = 16,
    device: str | torch.device | None = None,
    progress: bool = True,
    overwrite: bool = False,
    name: str | None = None,
    reconstruct_kwargs: dict[str, Any] | None = None,
    calibrate: bool = True,
) -> str:
    """Post-process ``reconstructions/<input_name>`` of ``split`` with the network of a run.

    Parameters
    ----------
    store_path : path
        Data-set store.
    run_dir : path
        Training run directory (holds ``best.pt`` and ``last.pt``).
    input_name : str, optional
        Input reconstruction; default: the one the network was trained on.
    split : {"test", "val", "train", "all"}
        Samples to process (the paper evaluates the test split).
    checkpoint : {"best", "last"}
        Which checkpoint of the run to use (the paper: lowest validation loss).
    batch_size : int
        Images per forward pass.
    device : str, optional
        Default: CUDA when available, else CPU.
    progress : bool
        Show a progress bar.
    overwrite : bool
        Delete an existing result of that name made with other parameters first.
    name : str, optional
        Output name (default :func:`nanoct.names.prediction_name`).
    reconstruct_kwargs : dict, optional
        Passed to the model's ``reconstruct`` (e.g. the number of samples of a CiNN); stored
        with the result.
    calibrate : bool
        For networks with a std: store the calibrated std, the raw std through the map of the
        run's calibration on the validation split (:func:`nanoct.learn.calibration.calibrate`,
        fitted first if the run has none for this checkpoint and these sampling arguments;
        :func:`nanoct.evaluation.metrics.apply_std_map`), and record the calibration under ``calibration``
        in the stored parameters (raw std = :func:`nanoct.evaluation.metrics.invert_std_map` of the stored
        one). False stores the raw std.

    Returns
    -------
    str
        The output name.

    Raises
    ------
    NanoctError
        Missing run or checkpoint, a corrupt checkpoint or one for another image size, an
        empty split, a missing or incomplete input reconstruction, or ``reconstruct_kwargs``
        for a network without sampling (the UNet).
    """

    if checkpoint not in ("best", "last"):
        raise NanoctError(f"checkpoint {checkpoint!r} must be 'best' or 'last'")
    if split != "all" and split not in SPLITS:
        raise NanoctError(f"split {split!r} is unknown; use one of train, val, test, all")
    if batch_size < 1:
        raise NanoctError(f"batch size {batch_size} must be positive")
    run = Path(run_dir)
    if not run.is_dir():
        raise NanoctError(f"no training run at {run}; train one first ('nanoct train ... --out {run}')")
    store = DataStore.open(store_path, mode="r+")
    ckpt_path = run / f"{checkpoint}.pt"
    ckpt = load_checkpoint(ckpt_path, image_size=store.geometry.n)
    _check_geometry(store, run, ckpt)
    kwargs = dict(reconstruct_kwargs or {})
    sampling = model_class(str(ckpt["model"])).has_uncertainty
    if kwargs and not sampling:
        raise NanoctError(
            f"the run at {run} holds a '{ckpt['model']}', which gives one output per image and no std; the "
            f"sampling arguments {sorted(kwargs)} (--samples, --antithetic) apply to the invertible networks only: "
            "leave them out"
        )
    train_input = str(ckpt["input"])
    input_name = train_input if input_name is None else input_name
    indices = store.indices(split)
    if indices.size == 0:
        raise NanoctError(f"the {split} split of {store.path} has no samples; nothing to post-process")
    check_input(store, input_name, indices, split)
    out = name or prediction_name(input_name, str(ckpt["model"]), train_input)
    params = {
        "input": input_name,
        "run": str(run.resolve()),
        "checkpoint": checkpoint,
        "epoch": int(ckpt["epoch"]),
        "model": ckpt["model"],
        "hparams": ckpt["hparams"],
        "train_input": train_input,
        "reconstruct": kwargs,
    }
    std_map = None
    if sampling and calibrate:
        cal = calibrate_run(store, run, checkpoint, reconstruct_kwargs=kwargs, device=device, progress=progress)
        params["calibration"], std_map = cal, cal["std_map"]
    needed = 4 * int(np.prod(store.geometry.image_shape)) * (1 + sampling) * indices.size  # float32 mean (and std)
    with exclusive(store.path, out, f"reconstructions/{out} of {store.path}"), disk_space_needed(store.path, needed):
        params = _provenance(store, out, json.loads(json.dumps(params)), overwrite)
        try:
            store.prepare_reconstruction(out, params, uncertainty=sampling)
        except StoreError as exc:
            raise NanoctError(
                f"reconstructions/{out} in {store.path} was made with another network, checkpoint or std "
                f"calibration ({store.reconstruction_params(out)}); use --overwrite to replace it"
            ) from exc
        todo = indices[~store.reconstruction_done(out, indices)]
        if todo.size:
            model = model_from_checkpoint(ckpt, ckpt_path)
            infer = Inference(model, kwargs, sampling, std_map, device)
            _write_outputs(store, infer, input_name, out, todo, 1 if sampling else batch_size, progress)
    return out


def _write_outputs(
    store: DataStore, infer: Inference, input_name: str, out: str, todo: np.ndarray, step: int, progress: bool
) -> None:
    """Post-process ``reconstructions/<input_name>`` of the samples ``todo``, ``step`` at a time, into ``<out>``."""
    from tqdm.auto import tqdm

    with tqdm(total=int(todo.size), desc=out, unit="img", disable=not progress) as bar:
        for start in range(0, todo.size, step):
            idx = todo[start : start + step]
            mean_np, std_np = infer(store.read_reconstruction(input_name, idx), int(idx[0]))
            for j, i in enumerate(idx):
                # the progress flag is written last, after the mean and the std
                store.write_reconstruction(out, int(i), mean_np[j], std=None if std_np is None else std_np[j])
            bar.update(len(idx))
