"""Batch reconstruction of a data set: every sample of a split, resumable, over Dask."""

from __future__ import annotations

import os
from functools import partial
from typing import Any

import numpy as np

from ..errors import NanoctError
from ..fanout import run_tasks
from ..geometry import Geometry
from ..store import DataStore, Sample, open_cached
from .result import ReconResult

__all__ = ["METHODS", "output_name", "reconstruct_dataset", "reconstruct_sample"]

METHODS = ("fbp", "kaczmarz", "dremel", "resesop")


def output_name(method: str, eta_scale: float = 1.0) -> str:
    """Store name of a reconstruction: ``resesop_eta0.8`` for a scaled eta, else the method."""
    if method == "resesop" and not np.isclose(eta_scale, 1.0):
        return f"resesop_eta{eta_scale:g}"
    return method


def reconstruct_sample(method: str, geometry: Geometry, sample: Sample, params: dict[str, Any]) -> ReconResult:
    """Reconstruct one sample with ``method`` using the unperturbed (inexact) operator.

    ``params`` are keyword arguments of the method's function; RESESOP gets the sample's
    per-view model error ``eta`` (scaled by ``params["eta_scale"]`` inside the method).
    """
    if method == "fbp":
        from .fbp import fbp

        return fbp(geometry, sample.sinogram, **params)
    if method == "kaczmarz":
        from .kaczmarz import kaczmarz

        return kaczmarz(geometry, sample.sinogram, **params)
    if method == "resesop":
        from .resesop import resesop

        return resesop(geometry, sample.sinogram, sample.eta, **params)
    if method == "dremel":
        from .dremel import dremel

        return dremel(geometry, sample.sinogram, **params)
    raise NanoctError(f"method {method!r} is unknown; use one of {', '.join(METHODS)}")


def _reconstruct_into(path: str, method: str, name: str, params: dict[str, Any], index: int) -> int:
    store = open_cached(path)
    result = reconstruct_sample(method, store.geometry, store.read_sample(index), params)
    if not np.isfinite(result.image).all():
        raise NanoctError(f"{method} produced non-finite values on sample {index}; check the parameters {params}")
    store.write_reconstruction(name, index, result.image, result.motion)
    return index


def reconstruct_dataset(
    path: str | os.PathLike[str],
    method: str,
    *,
    split: str = "all",
    params: dict[str, Any] | None = None,
    name: str | None = None,
    overwrite: bool = False,
    workers: int = 2,
    scheduler: str | None = None,
    progress: bool = True,
) -> str:
    """Reconstruct the samples of ``split`` into ``reconstructions/<name>``.

    Parameters
    ----------
    path : path
        Data-set store.
    method : {"fbp", "kaczmarz", "dremel", "resesop"}
        Reconstruction method.
    split : {"all", "train", "val", "test"}
        Which samples to reconstruct (others are left missing and can be added later).
    params : dict, optional
        Keyword arguments of the method (stored with the result; a second run with other
        parameters under the same name is refused unless ``overwrite``).
    name : str, optional
        Output name (default :func:`output_name`).
    overwrite : bool
        Delete an existing reconstruction of that name first.
    workers, scheduler, progress
        See :func:`nanoct.fanout.run_tasks`.

    Returns
    -------
    str
        The output name.
    """
    if method not in METHODS:
        raise NanoctError(f"method {method!r} is unknown; use one of {', '.join(METHODS)}")
    params = dict(params or {})
    name = name or output_name(method, params.get("eta_scale", 1.0))
    store = DataStore.open(path, mode="r+")
    wanted = store.indices(split)
    not_done = ~store.done[wanted]
    if not_done.any():
        missing = int(not_done.sum())
        raise NanoctError(
            f"{missing} sample(s) of split '{split}' are not generated yet; finish 'nanoct generate' first"
        )
    if overwrite:
        store.delete_reconstruction(name)
    stored = {"method": method, **params}
    store.prepare_reconstruction(name, stored, shifts=(method == "dremel"))
    pending = [int(i) for i in wanted[~store.reconstruction_done(name, wanted)]]
    task = partial(_reconstruct_into, str(store.path), method, name, params)
    run_tasks(task, pending, workers=workers, scheduler=scheduler, desc=name, progress=progress)
    return name
