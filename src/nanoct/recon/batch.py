"""Batch reconstruction of a data set: every sample of a split, resumable, over Dask.

Besides the solver's own parameters a batch run takes the method's batch parameters
(:attr:`~nanoct.recon.registry.MethodSpec.batch_params`): where eta comes from
(:mod:`nanoct.recon.eta_source`) and, for Dremel, a motion shared by several slices or read
from a file (:mod:`nanoct.recon.shared`). What they need from the store is checked and
prepared here, in the calling process, before any sample task starts; a shared motion is
estimated once and kept with the reconstruction, so a resumed run does not estimate it again.

Measured data (:func:`~nanoct.recon.eta_source.carries_motion`: an open beam not at zero or an
object cut by the detector edges, the rule of the methods and of ``nanoct stack``) get the
defaults of ``nanoct stack``: RESESOP on an imported scan estimates eta from the residual of
Dremel (``eta="estimate:residual"`` unless given; so does a set of a scan's measured pairs alone,
``generate --like --mix 0,0,0,1``) and runs after Dremel's motion, its model
carrying that motion and eta the residual left after it
(:class:`~nanoct.recon.eta_source.EtaPlan`); Dremel starts each slice from a joint motion of
the stack and refines it (a simulation holds the joint motion fixed and RESESOP keeps the
unperturbed model). Where Dremel rejects a sample's shift estimate as a runaway (it keeps the
shifts at their start: :func:`~nanoct.recon.dremel.runaway_shifts`), the sample is recorded in the
reconstruction's note ``sample_shift_check`` (:func:`shift_check_warning` words it). The files a run
reads (a ``shifts_from`` file, a reference store's eta) are recorded by path and by the SHA-256 of
their content: the same content under another path resumes, other content is refused.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from ..core.fanout import run_tasks
from ..core.geometry import Geometry
from ..io.fileio import disk_space_needed, file_sha256
from ..io.lock import exclusive
from ..io.store import DataStore, Sample, open_cached
from .eta_source import EtaPlan, carries_motion, plan_eta
from .names import reconstruction_name
from .registry import check_method_params, method_spec
from .result import ReconResult
from .shared import joint_shifts, read_store_shifts

__all__ = ["reconstruct_dataset", "reconstruct_sample", "shift_check_recorder", "shift_check_warning"]


def reconstruct_sample(
    method: str, geometry: Geometry, sample: Sample, params: dict[str, Any], *, eta: np.ndarray | None = None
) -> ReconResult:
    """Reconstruct one sample with ``method`` using the unperturbed (inexact) operator.

    ``params`` are keyword arguments of the method's function; a method that needs eta
    (:attr:`~nanoct.recon.registry.MethodSpec.needs_eta`) gets ``eta`` or else the sample's
    per-view model error (scaled by ``params["eta_scale"]`` inside the method).
    """
    spec = method_spec(method)
    if spec.needs_eta and eta is None:
        eta = sample.eta
    return spec.run(geometry, sample.sinogram, eta, **params)


@dataclass(frozen=True)
class _Inputs:
    """What every sample task gets beside the solver parameters: an eta source, start or fixed shifts."""

    eta: EtaPlan | None = None
    shifts0: np.ndarray | None = None
    fixed: bool = False
    refine_measured: bool = False


def _sample_inputs(
    store: DataStore, index: int, sample: Sample, params: dict[str, Any], inputs: _Inputs
) -> tuple[dict[str, Any], np.ndarray | None]:
    """The solver parameters and eta of one sample (measured data: the motion carried or refined)."""
    measured = carries_motion(sample.sinogram, params.get("measured", "auto"))
    eta = None
    if inputs.eta is not None:
        motion = inputs.eta.motion(store, index) if measured else None
        eta = inputs.eta.eta(store, index, sample, shifts=motion)
        if motion is not None:
            params = {**params, "shifts": motion}
    if inputs.shifts0 is not None:
        fixed = inputs.fixed and not (inputs.refine_measured and measured)
        params = {**params, "shifts0": inputs.shifts0, "fix_shifts": fixed}
    return params, eta


def _reconstruct_into(
    path: str, method: str, name: str, params: dict[str, Any], inputs: _Inputs, index: int
) -> tuple[int, str | None]:
    """Reconstruct and write one sample; its index, and why its shift estimate was rejected (None: it was not).

    A sample with a rejected estimate is written without its progress flag: :func:`shift_check_recorder`'s
    callback notes it and sets the flag, so that an interrupted run redoes it rather than lose the note.
    """
    store = open_cached(path)
    sample = store.read_sample(index)
    params, eta = _sample_inputs(store, index, sample, params, inputs)
    result = reconstruct_sample(method, store.geometry, sample, params, eta=eta)
    if not np.isfinite(result.image).all():
        raise NanoctError(f"{method} produced non-finite values on sample {index}; check the parameters {params}")
    reason = result.params.get("shift_check")
    store.recons.write(name, index, result.image, result.motion, done=reason is None)
    return index, reason


def shift_check_recorder(store: DataStore, name: str) -> Callable[[tuple[int, str | None]], None]:
    """The ``on_result`` callback of a run of ``name`` that keeps the note ``sample_shift_check`` (sample index ->
    reason) of the samples whose shift estimate was rejected.

    The callback adds such a sample to the note, then sets its progress flag; it drops a sample redone
    without a rejection from the note. The note is read once, here, and written only when it changes.

    Parameters
    ----------
    store : DataStore
        The data set, opened for writing (only the calling process writes the note).
    name : str
        The reconstruction.

    Returns
    -------
    callable
        Called with a sample task's outcome: its index and the reason its estimate was rejected (None: not).
    """
    reasons = dict(store.recons.note(name, "sample_shift_check") or {})

    def record(outcome: tuple[int, str | None]) -> None:
        index, reason = outcome
        if reason is None and str(index) not in reasons:
            return
        if reason is None:  # redone without a rejection (repaired, or on other threads): no longer counted
            reasons.pop(str(index))
        else:
            reasons[str(index)] = reason
        store.recons.set_note(name, "sample_shift_check", dict(reasons) or None)
        if reason is not None:
            store.recons.mark_done(name, index)

    return record


def shift_check_warning(store: DataStore, name: str, unit: str = "sample") -> str | None:
    """The warning for the samples of reconstruction ``name`` whose shift estimate was rejected (None: none were).

    Parameters
    ----------
    store : DataStore
        The data set.
    name : str
        A reconstruction of it.
    unit : str
        What a sample is called in the text (``"slice"`` for a stack).

    Returns
    -------
    str or None
        How many samples and which (runs of neighbours as ranges, the first 10), and the first one's reason.
    """
    reasons = store.recons.note(name, "sample_shift_check")
    if not reasons:
        return None
    samples = np.array(sorted(int(i) for i in reasons))
    runs = np.split(samples, np.flatnonzero(np.diff(samples) != 1) + 1)
    listed = ", ".join(f"{r[0]}-{r[-1]}" if r.size > 1 else f"{r[0]}" for r in runs[:10])
    listed += ", ..." if len(runs) > 10 else ""
    first = int(samples[0])
    return (
        f"{samples.size} {unit}(s) of {name} ({listed}) kept their start shifts; {unit} {first}: " + reasons[str(first)]
    )


def _measured_only(store: DataStore) -> bool:
    """Whether every sample is measured data: an imported scan, or a set of a scan's measured pairs alone
    (``generate --like --mix 0,0,0,1``, reconstructed as the scan is to calibrate on it)."""
    mix = (store.meta.get("simulation") or {}).get("like", {}).get("mix", {})
    return store.is_scan or mix.get("measured") == 1.0


def _batch_values(method: str, store: DataStore, params: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Checked parameters (all), and the user's parameters with the batch ones normalised, defaults left out.

    An imported stack with one motion for all slices gets ``motion_slices="all"`` unless the
    motion is given (``fix_shifts``) or the slices are chosen; a method that needs eta gets
    ``eta="estimate:residual"`` (from Dremel's reconstruction) on an imported scan unless given.
    """
    spec = method_spec(method)
    if spec.needs_eta and _measured_only(store) and params.get("eta") is None:
        params = {**params, "eta": "estimate:residual"}
    checked = check_method_params(method, params, store.geometry)
    shared = store.is_scan and bool(store.meta["scan"].get("shared_motion"))
    if spec.estimates_motion and shared and checked["motion_slices"] is None and not checked["fix_shifts"]:
        params = {**params, "motion_slices": "all"}
        checked["motion_slices"] = "all"
    stored = dict(params)
    if spec.batch_params is not None:
        defaults = check_method_params(method, {}, store.geometry)
        for key in spec.batch_parameter_names():
            stored.pop(key, None)
            if checked[key] != defaults[key]:
                stored[key] = checked[key]
    return checked, stored


#: Parameters naming a file or data set, and the stored parameter that identifies its content.
_FILE_IDENTITIES = {"shifts_from": ("shifts_from_sha256",), "eta": ("eta_reference_sha256",)}


def _file_identities(checked: dict[str, Any], eta: EtaPlan | None) -> dict[str, str]:
    """SHA-256 of what the files a run reads hold (the shifts file, the reference store's eta), stored with its
    parameters: a resume from a moved file is then told from a run on another one."""
    out = {}
    if checked.get("shifts_from") is not None:
        out["shifts_from_sha256"] = file_sha256(checked["shifts_from"])
    if eta is not None and eta.reference is not None:
        out["eta_reference_sha256"] = hashlib.sha256(np.asarray(eta.reference, np.float64).tobytes()).hexdigest()
    return out


def _motion_slices(store: DataStore, value: str) -> np.ndarray:
    done = np.flatnonzero(store.done)
    if value == "all":
        return done
    chosen = np.array([int(v) for v in value.split(",")])
    bad = chosen[~np.isin(chosen, done)]  # done holds indices below n only
    if bad.size:
        raise NanoctError(
            f"--param motion_slices: sample(s) {bad.tolist()} are not generated samples of {store.path} "
            f"(it has {store.n}, indices 0..{store.n - 1})"
        )
    return chosen


def _plan_motion(
    store: DataStore, checked: dict[str, Any], notes: list[str]
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Start shifts (from ``shifts_from``, brought to the data set's axis: ``notes``) and the slices of a joint
    estimate, checked."""
    path = checked["shifts_from"]
    shifts0 = None if path is None else read_store_shifts(path, store, notes)
    if checked["fix_shifts"] and shifts0 is None:
        raise NanoctError("--param fix_shifts=true needs the motion to use: add --param shifts_from=FILE")
    if checked["fix_shifts"] and checked["motion_slices"] is not None:
        raise NanoctError(
            "--param fix_shifts=true uses the motion of shifts_from as given; --param motion_slices would estimate "
            "one: choose one of the two"
        )
    slices = None if checked["motion_slices"] is None else _motion_slices(store, checked["motion_slices"])
    return shifts0, slices


def _shared_shifts(
    store: DataStore, name: str, solver_params: dict[str, Any], slices: np.ndarray, shifts0: np.ndarray | None
) -> np.ndarray:
    """The stored joint estimate of ``name``, or estimated now from ``slices`` and stored."""
    shifts = store.recons.shared_shifts(name)
    if shifts is None:
        sinograms = store.read_array("sinograms", slices)
        rejected: list[str] = []
        shifts, _ = joint_shifts(store.geometry, sinograms, solver_params, shifts0, notes=rejected)
        store.recons.set_shared_shifts(name, shifts)
        if rejected:
            store.recons.set_note(
                name, "shift_check", f"{len(rejected)} of {len(sinograms)} slices of the joint motion: {rejected[0]}"
            )
    return shifts


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
        Keyword arguments of the method and its batch parameters (``eta`` for RESESOP;
        ``motion_slices``, ``shifts_from`` for Dremel; see the module docstring); stored with
        the result, a second run with other parameters under the same name is refused unless
        ``overwrite``.
    name : str, optional
        Output name (default :func:`~nanoct.names.reconstruction_name`).
    overwrite : bool
        Delete an existing reconstruction of that name first.
    workers, scheduler, progress
        See :func:`nanoct.core.fanout.run_tasks`.

    Returns
    -------
    str
        The output name.

    Raises
    ------
    NanoctError
        For an unknown method, a bad parameter, samples of the split not generated yet, or an
        eta source or motion the store cannot give (nothing is written then).
    """
    spec = method_spec(method)
    store = DataStore.open(path, mode="r+")
    checked, stored = _batch_values(method, store, dict(params or {}))
    name = name or reconstruction_name(method, stored)
    wanted = store.indices(split)
    not_done = ~store.done[wanted]
    if not_done.any():
        missing = int(not_done.sum())
        raise NanoctError(
            f"{missing} sample(s) of split '{split}' are not generated yet; finish 'nanoct generate' first"
        )
    solver_params = {k: v for k, v in stored.items() if k not in spec.batch_parameter_names()}
    inputs = _Inputs(eta=plan_eta(store, checked["eta"], wanted)) if spec.needs_eta else _Inputs()
    if inputs.eta is not None and inputs.eta.first == name:
        raise NanoctError(f"--name {name} is the first reconstruction its eta is estimated from; choose another name")
    axis_notes: list[str] = []
    shifts0, slices = _plan_motion(store, checked, axis_notes) if spec.estimates_motion else (None, None)
    image, shifts = int(np.prod(store.geometry.image_shape)), store.geometry.n_angles * spec.estimates_motion
    needed = 4 * (image + shifts) * len(wanted)  # float32, uncompressed: an upper bound
    with exclusive(store.path, name, f"reconstructions/{name} of {store.path}"), disk_space_needed(store.path, needed):
        if overwrite:
            store.delete_reconstruction(name)
        params = {"method": method, **stored, **_file_identities(checked, inputs.eta)}
        store.recons.relocate(name, params, _FILE_IDENTITIES)  # a shifts file or reference store moved
        store.prepare_reconstruction(name, params, shifts=spec.estimates_motion)
        if axis_notes:
            store.recons.set_note(name, "shifts_axis", axis_notes[0])
        if slices is not None:
            shifts0 = _shared_shifts(store, name, solver_params, slices, shifts0)
        if shifts0 is not None:
            fixed = slices is not None or checked["fix_shifts"]
            if checked["fix_shifts"]:  # a joint estimate was stored by _shared_shifts already
                store.recons.set_shared_shifts(name, shifts0)
            refine = slices is not None and not checked["fix_shifts"]  # a joint estimate: refined on measured data
            inputs = _Inputs(shifts0=shifts0, fixed=fixed, refine_measured=refine)
        pending = [int(i) for i in wanted[~store.reconstruction_done(name, wanted)]]
        task = partial(_reconstruct_into, str(store.path), method, name, solver_params, inputs)
        record = shift_check_recorder(store, name)
        fan = {"workers": workers, "scheduler": scheduler, "progress": progress, "done": len(wanted) - len(pending)}
        run_tasks(task, pending, desc=name, on_result=record, **fan)
    return name
