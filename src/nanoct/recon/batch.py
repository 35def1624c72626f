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
from .registry import check_method_params, method_spec, output_name
from .result import ReconResult

__all__ = ["reconstruct_dataset", "reconstruct_sample"]


def reconstruct_sample(method: str, geometry: Geometry, sample: Sample, params: dict[str, Any]) -> ReconResult:
    """Reconstruct one sample with ``method`` using the unperturbed (inexact) operator.

    ``params`` are keyword arguments of the method's function; a method that needs eta
    (:attr:`~nanoct.recon.registry.MethodSpec.needs_eta`) gets the sample's per-view model
    error (scaled by ``params["eta_scale"]`` inside the method).
    """
    spec = method_spec(method)
    data = (sample.sinogram, sample.eta) if spec.needs_eta else (sample.sinogram,)
    return spec.solver()(geometry, *data, **params)


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

    The method and its parameters are checked (:func:`~nanoct.recon.registry.check_method_params`)
    before anything is written or any worker starts.

    Parameters
    ----------
    path : path
        Data-set store.
    method : str
        A registered method (:data:`nanoct.recon.registry.METHODS`).
    split : {"all", "train", "val", "test"}
        Which samples to reconstruct (others are left missing and can be added later).
    params : dict, optional
        Keyword arguments of the method (stored with the result; a second run with other
        parameters under the same name is refused unless ``overwrite``).
    name : str, optional
        Output name (default :func:`~nanoct.recon.registry.output_name`).
    overwrite : bool
        Delete an existing reconstruction of that name first.
    workers, scheduler, progress
        See :func:`nanoct.fanout.run_tasks`.

    Returns
    -------
    str
        The output name.

    Raises
    ------
    NanoctError
        For an unknown method, a bad parameter, or samples of the split not generated yet.
    """
    spec = method_spec(method)
    params = dict(params or {})
    store = DataStore.open(path, mode="r+")
    check_method_params(method, params, store.geometry)
    name = name or output_name(method, params)
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
    store.prepare_reconstruction(name, stored, shifts=spec.estimates_motion)
    pending = [int(i) for i in wanted[~store.reconstruction_done(name, wanted)]]
    task = partial(_reconstruct_into, str(store.path), method, name, params)
    run_tasks(task, pending, workers=workers, scheduler=scheduler, desc=name, progress=progress)
    return name
