"""Apply a trained post-processing network to the reconstructions of a store.

The result goes to ``reconstructions/<input>+<model>`` when the input is the method the
network was trained on, and to ``reconstructions/<input>+<model>@<train_input>`` when a
network trained on one method is applied to another (the paper's input-mixing tables).
With ``tile``, images of any size are predicted in overlapping tiles of the size the network was
trained on (:mod:`nanoct.learn.tiling`). Networks that return a pixel-wise standard deviation
also write ``uncertainty/<name>``; their latent samples for sample ``i`` are drawn from a
generator seeded with ``i``, so results do not depend on batching or on interruptions (tiled, on the
batch of tiles, which is recorded: :func:`nanoct.learn.tiling.predict_tiled`). The
stored std is the network's own (raw) std; the calibration fitted on the validation split
(:mod:`nanoct.learn.calibration`: per interval level a multiplier per group of pixels, the
background (for measured references split at the sample's footprint) and the std fifths of the
object) is stored with the parameters (the half-width:
:func:`nanoct.evaluation.conformal.half_width`), and images whose std level is unlike the
validation split's, whose sinogram shows more apparent motion than the training scans, or (for
intervals calibrated on one scan's measured pairs) whose object leaves that scan's footprint, are
flagged (a warning, and the note ``ood`` of the result: :func:`ood_check`).

The parameters (run directory, checkpoint file and epoch, model, architecture, train input)
are stored with the result; running the same command again only fills in missing samples,
and a different checkpoint under the same name is refused unless ``overwrite``.
"""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..core.errors import NanoctError, StoreError
from ..core.names import prediction_name
from ..evaluation.conformal import (
    DEFAULT_DELTA,
    DEFAULT_LEVELS,
    FOOTPRINT_NOISY_MEAN,
    FOOTPRINT_TOLERANCE,
    footprint_fits,
    footprint_outside,
    mean_noise_ratio,
)
from ..io.fileio import disk_space_needed
from ..io.lock import exclusive
from ..io.store import SPLITS, DataStore
from ..io.store_recon import check_name, differing_keys, same_content
from .calibration import Inference, image_statistic, ood_p_values, tiled_outputs, training_store
from .calibration import calibrate as calibrate_run
from .checkpoint import load_checkpoint, model_from_checkpoint
from .data import check_input
from .models import model_class
from .scan_ood import store_scan_scores
from .tiling import DEFAULT_MARGIN, DEFAULT_OVERLAP

__all__ = ["GeometryWarning", "OutOfDistributionWarning", "geometry_difference", "ood_check", "predict"]


#: Images read at a time by the out-of-distribution checks (the footprint check's labels take about 33 bytes
#: per pixel), so that their memory does not grow with the split.
OOD_CHUNK = 16


class OutOfDistributionWarning(UserWarning):
    """Some predicted images look unlike the validation split the intervals were calibrated on."""


class GeometryWarning(UserWarning):
    """A run is applied in tiles to a data set of another geometry than its training data's."""


def _request(params: dict[str, Any], made_from: dict[str, Any]) -> dict[str, Any]:
    """What a prediction's parameters ask for: without what it was made from and without the
    calibration's fitted values (a refit of the same run's calibration is the same request),
    but with whether it is calibrated (a raw and a calibrated result are not)."""
    kept = {k: v for k, v in params.items() if k not in made_from and k != "calibration"}
    return kept | {"calibrated": "calibration" in params}


#: How far the axis of the data set may lie from the training data's, in pixels, for a run to apply untiled: two
#: estimates of one scan's axis (e.g. at another binning) differ by about 0.1 px; a post-processing network sees
#: reconstructions made about each data set's own axis.
AXIS_TOLERANCE = 0.5
#: View angles agreeing to this many radians are the same views (float32 angle files, degrees converted).
ANGLE_TOLERANCE = 1e-6


def geometry_difference(trained: dict[str, Any], here: dict[str, Any]) -> list[str]:
    """What differs between a run's training geometry and a data set's, e.g. ``["n_det 80 (here 160)"]``.

    The axis (``center_offset``) counts only beyond :data:`AXIS_TOLERANCE` pixels and view angles only
    beyond :data:`ANGLE_TOLERANCE` radians; other numbers must agree to 1e-9 (relative).

    Parameters
    ----------
    trained, here : dict
        ``Geometry.to_dict()`` of the training data and of the data set.

    Returns
    -------
    list of str
        One ``"<key> <trained> (here <value>)"`` per differing key, in key order; empty where they agree.
    """
    out = []
    for key in sorted(trained.keys() | here.keys()):
        a, b = trained.get(key), here.get(key)
        if key == "view_angles" and a is not None and b is not None and len(a) == len(b):
            same = bool(np.allclose(a, b, rtol=0, atol=ANGLE_TOLERANCE))
        elif key == "center_offset":  # absent: the detector's centre
            a, b = float(a or 0.0), float(b or 0.0)
            same = abs(a - b) <= AXIS_TOLERANCE
        elif isinstance(a, float) and isinstance(b, float):
            same = bool(np.isclose(a, b, rtol=1e-9, atol=0))
        else:
            same = a == b
        if not same:
            out.append(f"{key} {_shown(a, b)}")
    return out


def _shown(a: Any, b: Any) -> str:
    """Two differing geometry values as a message shows them: ``80 (here 160)``."""
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return f"differ by up to {np.abs(np.subtract(a, b)).max():.3g} rad"
    a, b = (f"{len(v)} views" if isinstance(v, list) else f"{v:.6g}" if isinstance(v, float) else v for v in (a, b))
    return f"{a} (here {b})"


def _check_geometry(store: DataStore, run: Path, ckpt: dict[str, Any], tiled: bool = False) -> None:
    """Refuse a run trained on another geometry than the data set's (before any work is done); ``tiled``
    (images of any size): warn instead, naming what differs besides the image size."""
    trained = (ckpt.get("config") or {}).get("data", {}).get("geometry")
    if trained is None:
        return
    differs = geometry_difference(trained, json.loads(json.dumps(store.geometry.to_dict())))
    if tiled:
        differs = [d for d in differs if not d.startswith("n ")]
        if differs:
            warnings.warn(
                f"the run {run.resolve()} was trained on another geometry than {store.path} ({'; '.join(differs)}): "
                "its tiles are predicted anyway, but where the views, detector or pixel size differ the images "
                "may look unlike its training images",
                GeometryWarning,
                stacklevel=3,
            )
        return
    if differs:
        scan = store.is_scan and store.indices("val").size == 0
        raise NanoctError(
            f"the run {run.resolve()} was trained on another geometry than the data set {store.path}: "
            f"{'; '.join(differs)}; "
            + (
                f"train a network on a set matched to it (nanoct generate --like {store.path} --bin B, with the "
                "binning of this data set's import), or predict in tiles (--tile 0)"
                if scan
                else "train a network on this data set"
            )
        )


#: What identifies a prediction's network wherever its run lies: the checkpoint file's hash (a sampling network's
#: result made before it was kept has it in its calibration); a moved calibration data set is recorded, not compared.
_WEIGHTS = {"run": ("checkpoint_sha256", "calibration.checkpoint_sha256")}


def _provenance(store: DataStore, out: str, params: dict[str, Any], weights: str, overwrite: bool) -> dict:
    """``params`` plus what the prediction is made from (geometry, input fingerprint, ``weights``: the hash of
    the checkpoint file as loaded).

    Deletes an earlier ``out`` made with other settings (with ``overwrite``) or with the same
    settings from an input or checkpoint file that has changed since or under another calibration of
    the same run (refitted after a format change, also where the run has moved since: the same checkpoint
    file under another path). An earlier ``out`` of the same checkpoint file whose run or calibration data
    set has moved since is kept, its parameters recording the new places.
    """
    here = json.loads(json.dumps(store.geometry.to_dict()))
    made_from = {
        "geometry": here,
        "input_fingerprint": store.recons.fingerprint(params["input"]),
        "checkpoint_sha256": weights,
    }
    new = json.loads(json.dumps({**params, **made_from}))
    if out in store.reconstruction_names():
        old = store.reconstruction_params(out)
        same_weights = {place: new[place] for place, keys in _WEIGHTS.items() if same_content(old, new, place, keys)}
        same_request = _request(old | same_weights, made_from) == _request(params, made_from)
        moved = store.recons.relocate(out, new, _WEIGHTS, ignored=("calibration.store",))
        if not moved and old != new and (overwrite or same_request):
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
    levels: tuple[float, ...] = DEFAULT_LEVELS,
    delta: float = DEFAULT_DELTA,
    tile: int | None = None,
    overlap: int | None = None,
    calibrate_on: str | os.PathLike[str] | None = None,
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
        For networks with a std: fit (or reuse) the run's interval calibration on the validation
        split (:func:`nanoct.learn.calibration.calibrate`) and record it under ``calibration`` in
        the stored parameters; after predicting, check each image of ``split`` for being out of
        distribution (:func:`ood_check`). The stored std is the raw std either way.
    levels, delta
        Interval levels and the guarantee's failure probability of the calibration.
    tile : int, optional
        Apply the network in ``tile`` x ``tile`` tiles (:func:`nanoct.learn.tiling.predict_tiled`;
        0: the image size the network was trained on), ``overlap`` pixels apart, blended with a
        smooth window: images of any size in bounded memory, with a progress bar per image. The
        geometry of the data set may then differ from the training data's (a :class:`GeometryWarning`
        names what differs); the calibration is the run's own (fitted on the validation split of the
        data set it was trained on, there and then if it is not yet) where the data set has no
        validation split or another image size than the run's. For a sampling network the stored ``tiling`` also
        records ``batch_size`` (tiles per call), on which its latent draws depend.
    overlap : int, optional
        Pixels shared by neighbouring tiles (default: 16, at most half the tile).
    calibrate_on : path, optional
        Fit the intervals on the validation split of this data set instead (it must have the
        geometry the run was trained on and hold the input reconstruction for its validation
        split): e.g. the scan's own measured pairs (``nanoct generate --like SCAN --mix 0,0,0,1``,
        :func:`nanoct.sim.matched.measured_pair`), whose references are the scan's FBP with its
        noise and ring artefacts. Its images also become the out-of-distribution reference.

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

    run = Path(run_dir)
    _check_arguments(run, checkpoint, split, batch_size)
    store = DataStore.open(store_path, mode="r+")
    ckpt_path = run / f"{checkpoint}.pt"
    ckpt = load_checkpoint(ckpt_path)
    tiling = _tiling(store, run, ckpt, tile, overlap)
    kwargs = dict(reconstruct_kwargs or {})
    sampling = model_class(str(ckpt["model"])).has_uncertainty
    if tiling and sampling:  # a tile's latent draws depend on the batch of tiles it is in: part of the result
        tiling["batch"] = int(batch_size)
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
    model_label = str(ckpt["model"]) + ("-res" if ckpt["hparams"].get("residual") else "")  # a residual UNet
    out = prediction_name(input_name, model_label, train_input) if name is None else check_name(name)
    params = {
        "input": input_name,
        "run": str(run.resolve()),
        "checkpoint": checkpoint,
        "epoch": int(ckpt["epoch"]),
        "model": ckpt["model"],
        "hparams": ckpt["hparams"],
        "train_input": train_input,
        "reconstruct": kwargs,
    } | ({"tiling": tiling} if tiling else {})
    on = _calibration_store(store, calibrate_on, run, ckpt, sampling, calibrate)
    if on is not None:
        fit = {"reconstruct_kwargs": kwargs, "device": device, "progress": progress, "levels": tuple(levels)}
        if (ckpt.get("config") or {}).get("patch"):  # fitted on the validation images predicted in these tiles
            fit["tiling"] = tiling
        params["calibration"] = _same_weights(calibrate_run(on, run, checkpoint, delta=delta, **fit), ckpt, ckpt_path)
    needed = 4 * int(np.prod(store.geometry.image_shape)) * (1 + sampling) * indices.size  # float32 mean (and std)
    with exclusive(store.path, out, f"reconstructions/{out} of {store.path}"), disk_space_needed(store.path, needed):
        params = _provenance(store, out, json.loads(json.dumps(params)), ckpt["file_sha256"], overwrite)
        try:
            store.prepare_reconstruction(out, params, uncertainty=sampling)
        except StoreError as exc:
            differs = ", ".join(differing_keys(store.reconstruction_params(out), params))
            raise NanoctError(
                f"reconstructions/{out} in {store.path} was made with another network, checkpoint, tiling or std "
                f"calibration (differs in: {differs}); use --overwrite to replace it, or --name to keep both"
            ) from exc
        todo = indices[~store.reconstruction_done(out, indices)]
        if todo.size:
            model = model_from_checkpoint(ckpt, ckpt_path)
            infer = Inference(model, kwargs, sampling, device)
            step = batch_size if tiling or not sampling else 1
            _write_outputs(store, infer, input_name, out, todo, step, progress, tiling)
        if "calibration" in params:
            ood_check(store, out, indices)
    return out


def _same_weights(calibration: dict[str, Any], ckpt: dict[str, Any], path: Path) -> dict[str, Any]:
    """``calibration``, fitted for the checkpoint file predict loaded (``ckpt``, from ``path``): its hash agrees.

    Raises
    ------
    NanoctError
        Where the file was replaced between predict's load and the calibration's.
    """
    if calibration["checkpoint_sha256"] != ckpt["file_sha256"]:
        raise NanoctError(
            f"the checkpoint {path} was replaced while predict read it (is 'nanoct train' still writing the run?); "
            "run the same command again once it is not"
        )
    return calibration


def _check_arguments(run: Path, checkpoint: str, split: str, batch_size: int) -> None:
    if checkpoint not in ("best", "last"):
        raise NanoctError(f"checkpoint {checkpoint!r} must be 'best' or 'last'")
    if split != "all" and split not in SPLITS:
        raise NanoctError(f"split {split!r} is unknown; use one of train, val, test, all")
    if batch_size < 1:
        raise NanoctError(f"batch size {batch_size} must be positive")
    if not run.is_dir():
        raise NanoctError(f"no training run at {run}; train one first ('nanoct train ... --out {run}')")


def _calibration_store(
    store: DataStore,
    path: str | os.PathLike[str] | None,
    run: Path,
    ckpt: dict[str, Any],
    sampling: bool,
    calibrate: bool,
) -> DataStore | None:
    """The data set the intervals are fitted on (None: not calibrated): that of ``--calibrate-on``, checked: it
    exists, has the run's geometry and a validation split; else ``store``, or, where ``store`` has no validation
    split or (for a run not trained on patches) another image size than the run's, the data set the run was
    trained on (:func:`_training_set`; its own calibration, fitted there if it is not yet)."""
    if path is None:
        if not (sampling and calibrate):
            return None
        patch = (ckpt.get("config") or {}).get("patch")  # fitted on tiled validation images of any size
        other_size = store.geometry.n != int(ckpt["image_size"]) and not patch
        own = _training_set(run, ckpt) if store.indices("val").size == 0 or other_size else None
        return store if own is None else own
    if not (sampling and calibrate):
        raise NanoctError(
            f"--calibrate-on {path}: the run at {run} holds a '{ckpt['model']}' network, whose output is not "
            "calibrated; leave the flag out"
            if not sampling
            else f"--calibrate-on {path} fits the intervals that --no-calibrate switches off: choose one"
        )
    if not (Path(path) / "zarr.json").is_file():
        raise NanoctError(
            f"--calibrate-on {path}: no data set there; make one, e.g. the scan's own measured pairs with "
            "'nanoct generate --like SCAN --bin B --mix 0,0,0,1 --split-fractions 0,1,0 --n 300 --out PAIRS' "
            f"and 'nanoct reconstruct PAIRS --method {ckpt['input']}'"
        )
    cal = DataStore.open(path)
    _check_geometry(cal, run, ckpt)
    if cal.indices("val").size == 0:
        raise NanoctError(
            f"--calibrate-on {path} has no validation samples to fit the intervals on; generate it with a validation "
            "split (e.g. --split-fractions 0,1,0)"
        )
    return cal


def _training_set(run: Path, ckpt: dict[str, Any]) -> DataStore | None:
    """The data set the run was trained on, where it is still at the path its ``config.json`` records, is the
    one it was trained on (its size, seed and geometry, as the checkpoint records them) and has a validation
    split; None otherwise."""
    path = training_store(run)
    if path is None or not (path / "zarr.json").is_file():
        return None
    try:
        own = DataStore.open(path)
    except NanoctError:
        return None
    data = (ckpt.get("config") or {}).get("data") or {}
    same = own.n == data.get("n") and own.seed == data.get("seed")
    if not same or json.loads(json.dumps(own.geometry.to_dict())) != data.get("geometry"):
        return None
    return own if own.indices("val").size else None


def ood_check(store: DataStore, name: str, indices: np.ndarray) -> dict[str, Any]:
    """Flag the images of a calibrated prediction that look unlike the data the run was calibrated on.

    Two conformal p-values per image, ``p <= a`` wrongly flagging at most a fraction ``a`` of
    in-distribution images (:func:`nanoct.learn.calibration.ood_p_values`):

    - ``std``: the image's mean std (:func:`nanoct.learn.calibration.image_statistic`) against the
      validation images';
    - ``scan``: the apparent motion of its measured sinogram (:mod:`nanoct.learn.scan_ood`) against
      the train and validation sinograms', where the calibration holds that reference.

    With both, an image is flagged if either p-value is at most alpha / 2 (Bonferroni: at most a
    fraction alpha of in-distribution images in all), and its p-value is
    ``min(1, 2 * min(p_std, p_scan))``; with the std alone, ``p_std <= alpha`` flags it.

    A calibration with a footprint (fitted on one scan's measured pairs) also flags, as
    ``footprint``, an image of which more than :data:`nanoct.evaluation.conformal.FOOTPRINT_TOLERANCE`
    of the prediction-time support lies outside the footprint
    (:func:`nanoct.evaluation.conformal.footprint_outside`; parallel beam: on the field of view, fan
    beam: on every pixel): not a slice of the calibrating scan as it lay there (another sample, the
    same one moved, or a slice with nothing in it, whose support is its noise), so its background
    may hide missed object pixels that the intervals do not cover. This check is not a p-value and
    has no false-alarm rate. It is not made on an image whose mean, of independent draws, is too noisy
    for its support to mean anything (:func:`nanoct.evaluation.conformal.mean_noise_ratio` above
    :data:`~nanoct.evaluation.conformal.FOOTPRINT_NOISY_MEAN`; recorded as ``unchecked``, with a
    warning), nor where the footprint has another image size than the prediction (a tiled
    prediction; all the background then takes the wider of the two background multipliers,
    :func:`nanoct.evaluation.conformal.half_width_of`).

    The record (merged with earlier ones of other samples) is stored as the note ``ood`` of ``name``
    and a :class:`OutOfDistributionWarning` names the flagged samples and which check flagged
    them: their intervals may not hold their level.

    Returns
    -------
    dict
        ``statistic``, ``alpha``, ``p_values`` = {sample index: p}, ``flagged`` (sorted indices: those with
        ``p <= alpha``, and those the footprint check flags), ``flagged_by`` = {sample index: the statistics
        with ``p <= alpha / 2`` (``alpha`` with the std alone), and ``footprint``} and per statistic (``std``,
        and ``scan`` where used) {``p_values``, ``flagged``: its own ``p <= alpha``}; with the footprint check,
        ``footprint`` = {``tolerance``, ``outside``: {sample index: fraction}, ``flagged``, and where some image
        was not checked ``noisy_mean`` and ``unchecked``: {sample index: noise ratio}}.
    """
    calibration = store.reconstruction_params(name)["calibration"]
    ood = calibration["ood"]
    alpha = float(ood["alpha"])
    keys = [str(int(i)) for i in indices]
    levels, outside, noise = _chunked_statistics(store, name, calibration, indices)
    p_by = {"std": ood_p_values(levels, ood["val"])}
    if ood.get("scan"):
        p_by["scan"] = ood_p_values(store_scan_scores(store, indices, ood["scan"]), ood["scan"]["scores"])
    old = store.reconstruction_note(name, "ood") or {}
    statistics = [ood["statistic"]] + ([ood["scan"]["statistic"]] if "scan" in p_by else [])
    share = alpha / len(p_by)
    combined = np.minimum(1.0, len(p_by) * np.min(np.stack(list(p_by.values())), axis=0))
    p_values = {**old.get("p_values", {}), **{k: float(v) for k, v in zip(keys, combined)}}
    record: dict[str, Any] = {"statistic": " + ".join(statistics), "alpha": alpha, "p_values": p_values}
    by = {k: [s for s, p in p_by.items() if p[j] <= share] for j, k in enumerate(keys)}
    off: set[str] = set()
    if outside is not None:
        record["footprint"] = _footprint_record(name, old.get("footprint") or {}, keys, outside, noise)
        off = {str(i) for i in record["footprint"]["flagged"]}
        by = {k: v + ["footprint"] * (k in off) for k, v in by.items()}
    record["flagged"] = sorted({int(i) for i, v in p_values.items() if v <= alpha} | {int(k) for k in off})
    earlier = {k: v for k, v in old.get("flagged_by", {}).items() if k not in by}
    record["flagged_by"] = earlier | {k: v for k, v in by.items() if v}
    for s, p in p_by.items():
        own = {**(old.get(s) or {}).get("p_values", {}), **{k: float(v) for k, v in zip(keys, p)}}
        record[s] = {"p_values": own, "flagged": sorted(int(i) for i, v in own.items() if v <= alpha)}
    record["cannot_flag"] = _blind_checks(name, ood, list(p_by), share)
    store.set_reconstruction_note(name, "ood", record)
    new = [int(k) for k in keys if by[k]]
    if new:
        which = sorted({s for k in keys for s in by[k]})
        what = {
            "std": f"std level above the validation split's, p <= {share:g}",
            "scan": f"more apparent motion in the sinogram than the training scans, p <= {share:g}",
            "footprint": f"more than {FOOTPRINT_TOLERANCE:.0%} of the support outside the footprint of the scan the "
            "intervals were calibrated on: another sample, this one moved, or a slice with nothing in it",
        }
        reasons = "; ".join(f"{s}: {what[s]}" for s in which)
        shown = ", ".join(f"{i} ({'+'.join(by[str(i)])})" for i in new[:10])
        warnings.warn(
            f"{len(new)} of {len(indices)} images of reconstructions/{name} look out of distribution ({reasons}): "
            f"samples {shown}{' ...' if len(new) > 10 else ''}; their intervals may not hold their stated level",
            OutOfDistributionWarning,
            stacklevel=2,
        )
    return record


def _footprint_record(
    name: str, old: dict[str, Any], keys: list[str], outside: np.ndarray, noise: np.ndarray | None
) -> dict[str, Any]:
    """The footprint check's record of ``name`` (merged with the ``old`` one of other samples): the fractions of
    the support outside the footprint, those above the tolerance flagged, except on images whose mean is too
    noisy for its support to mean anything (``noise`` above :data:`~nanoct.evaluation.conformal.FOOTPRINT_NOISY_MEAN`,
    ``unchecked``: {sample index: ratio}), which a warning names with what to do."""
    fractions = {**old.get("outside", {}), **dict(zip(keys, outside.tolist()))}
    # an image that is zero where it counts has no support to check (inf: nothing left out)
    noisy = {} if noise is None else {k: float(r) for k, r in zip(keys, noise) if FOOTPRINT_NOISY_MEAN < r < np.inf}
    unchecked = {k: v for k, v in old.get("unchecked", {}).items() if k not in keys} | noisy
    off = sorted(int(k) for k, v in fractions.items() if v > FOOTPRINT_TOLERANCE and k not in unchecked)
    if noisy:
        shown = ", ".join(list(noisy)[:10]) + (" ..." if len(noisy) > 10 else "")
        warnings.warn(
            f"the footprint check of reconstructions/{name} was not made on {len(noisy)} of {len(keys)} images "
            f"(samples {shown}): the sampling noise of their mean is {min(noisy.values()):.2f}-"
            f"{max(noisy.values()):.2f} of their level (more than {FOOTPRINT_NOISY_MEAN}), so their support is "
            "noise; predict with --antithetic or more --samples (with --name or --overwrite) to check them",
            UserWarning,
            stacklevel=3,
        )
    record = {"tolerance": FOOTPRINT_TOLERANCE, "outside": fractions, "flagged": off}
    return record | ({"noisy_mean": FOOTPRINT_NOISY_MEAN, "unchecked": unchecked} if unchecked else {})


def _blind_checks(name: str, ood: dict[str, Any], used: list[str], share: float) -> list[str]:
    """The out-of-distribution checks of ``name`` that cannot flag any image, each with a warning: a reference of
    n values gives no p-value below ``1 / (n + 1)``, so with ``1 / (n + 1) > share`` nothing is ever flagged."""
    sizes = {"std": len(ood["val"])} | ({"scan": len(ood["scan"]["scores"])} if "scan" in used else {})
    blind = [s for s, n in sizes.items() if 1.0 / (n + 1) > share]
    fix = {
        "std": "calibrate on at least {} validation images (e.g. predict --calibrate-on a larger set)",
        "scan": "calibrate on a data set of at least {} train and validation samples",
    }
    for s in blind:
        n, least = sizes[s], int(np.ceil(1.0 / share - 1.0 - 1e-9))
        warnings.warn(
            f"the out-of-distribution check '{s}' of reconstructions/{name} cannot flag any image: its reference "
            f"holds {n} values, so no p-value falls below 1/{n + 1} = {1 / (n + 1):.3f} > {share:g}; "
            f"{fix[s].format(least)} for it to flag",
            UserWarning,
            stacklevel=3,
        )
    return blind


def _chunked_statistics(
    store: DataStore, name: str, calibration: dict[str, Any], indices: np.ndarray
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Per image of ``name`` at ``indices``: the std statistic (:func:`nanoct.learn.calibration.image_statistic`),
    :func:`nanoct.evaluation.conformal.footprint_outside` (on the field of view for parallel beam; None where
    the calibration has no footprint of this image size) and, for a mean of independent draws, its
    :func:`nanoct.evaluation.conformal.mean_noise_ratio` (else None), each std read once, ``OOD_CHUNK`` images at
    a time."""
    groups = next(iter((calibration.get("levels") or {}).values()), {}).get("groups") or {}
    footprint = bool(groups.get("footprint")) and footprint_fits(groups, store.geometry.image_shape)
    known = None
    if footprint and store.geometry.kind == "parallel":
        from ..sim.matched import fov_disc

        known = fov_disc(store.geometry) > 0
    draws = calibration.get("n_samples") if not (calibration.get("reconstruct") or {}).get("antithetic") else None
    levels, outside, noise = [np.zeros(0)], [np.zeros(0)], [np.zeros(0)]
    for start in range(0, len(indices), OOD_CHUNK):
        chunk = indices[start : start + OOD_CHUNK]
        stds = store.read_uncertainty(name, chunk)
        levels.append(image_statistic(stds))
        if footprint:
            means = store.read_reconstruction(name, chunk)
            outside.append(footprint_outside(stds, groups, means, known))
            if draws:
                noise.append(mean_noise_ratio(stds, means, int(draws), known))
    if not footprint:
        return np.concatenate(levels), None, None
    return np.concatenate(levels), np.concatenate(outside), np.concatenate(noise) if draws else None


def _tiling(store: DataStore, run: Path, ckpt: dict[str, Any], tile: int | None, overlap: int | None) -> dict | None:
    """The tiling of a prediction (``size``, ``overlap``, ``margin``; ``tile`` 0 = the trained size, ``overlap``
    None = :data:`~nanoct.learn.tiling.DEFAULT_OVERLAP`, at most half the tile), None untiled; untiled, the
    data set's image size and geometry must be the training data's (tiled, another geometry is warned of)."""
    trained = int(ckpt["image_size"])
    if tile is None:
        if trained != store.geometry.n:
            raise NanoctError(
                f"the run {run} was trained on {trained}x{trained} images, the data here are "
                f"{store.geometry.n}x{store.geometry.n}; predict in tiles of the trained size (--tile 0) or train a "
                "network for this image size"
            )
        _check_geometry(store, run, ckpt)
        return None
    size = trained if tile == 0 else int(tile)
    margin = DEFAULT_MARGIN
    overlap = min(DEFAULT_OVERLAP, size // 2) if overlap is None else int(overlap)
    if size < 4 * margin + 2 or not 2 * margin + 1 <= overlap <= size // 2:
        raise NanoctError(
            f"tile {size} with overlap {overlap}: the tile must be at least {4 * margin + 2} pixels and the overlap "
            f"between {2 * margin + 1} and half the tile ({size // 2})"
            + (f"; e.g. --tile-overlap {min(DEFAULT_OVERLAP, size // 2)}" if size >= 4 * margin + 2 else "")
        )
    largest = max(trained, *store.geometry.image_shape)
    if size > largest:
        raise NanoctError(
            f"--tile {size} is larger than the images ({store.geometry.n}x{store.geometry.n}) and the trained size "
            f"({trained}): a tile of at most {largest} pixels covers them (e.g. --tile 0, the trained size)"
        )
    _check_geometry(store, run, ckpt, tiled=True)
    return {"size": size, "overlap": overlap, "margin": margin}


def _write_outputs(
    store: DataStore,
    infer: Inference,
    input_name: str,
    out: str,
    todo: np.ndarray,
    step: int,
    progress: bool,
    tiling: dict[str, int] | None = None,
) -> None:
    """Post-process ``reconstructions/<input_name>`` of the samples ``todo``, ``step`` at a time, into ``<out>``
    (with ``tiling``: one image at a time, ``step`` tiles at a time, :func:`nanoct.learn.calibration.tiled_outputs`)."""
    from tqdm.auto import tqdm

    if tiling:
        for i, mean, std in tiled_outputs(infer, store, input_name, todo, {**tiling, "batch": step}, progress, out):
            store.write_reconstruction(out, i, mean, std=std)
        return
    with tqdm(total=int(todo.size), desc=out, unit="img", disable=not progress) as bar:
        for start in range(0, todo.size, step):
            idx = todo[start : start + step]
            mean_np, std_np = infer(store.read_reconstruction(input_name, idx), int(idx[0]))
            for j, i in enumerate(idx):
                # the progress flag is written last, after the mean and the std
                store.write_reconstruction(out, int(i), mean_np[j], std=None if std_np is None else std_np[j])
            bar.update(len(idx))
