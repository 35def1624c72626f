"""Interval calibration of a sampling network's std on the validation split, stored with its run.

The std of a conditional invertible network (over M latent samples) ranks the pixels by how
uncertain they are, but its scale is rarely right. Per run and checkpoint, on the validation
split of the data set and input the network was trained on (the test split is never read), the
pixels are put in groups computable at prediction time (the background, and the five std fifths
of the object's support, the support being the network's mean above a threshold with its holes
filled, dilated by 2 px), and per interval level a strictly increasing width map of the std per
region and a split-conformal multiplier per group are fitted (:func:`fit_intervals`,
:func:`nanoct.evaluation.conformal.fit_group_intervals`): the interval of level ``p`` at a pixel
of group G is ``mean +- q_{p,G} * g_{p,R}(std)``, with the guarantee stated per group (coverage
at least ``p`` for exchangeable pixels of the group; the per-image coverage that holds with
probability ``1 - delta``, Hoeffding-Bentkus, risk-controlling prediction sets). The pooled
one-multiplier calibration is kept for comparison. Within a group the half-width is strictly
increasing in the std, so it keeps the network's ranking of the group's pixels exactly. On
the same validation outputs the multipliers of the edge baseline
(:func:`nanoct.evaluation.metrics.edge_std` of the network's mean) are fitted, and the
validation images' std level and the apparent-motion scores of the train and validation
sinograms (:func:`nanoct.learn.scan_ood.scan_reference`) are kept for the out-of-distribution
check of :func:`nanoct.learn.predict.predict`.

Where the validation references are reconstructions of measured data (a scan's measured pairs,
:func:`reference_rule`) the group multipliers are object-conditional: each is the larger of those
of the group's pixels on the reference's object and of its other pixels, so the coverage holds on
the object even where the network misses part of it.

The fit lives in ``<run>/calibration.json``, one entry per checkpoint (``"best"``, ``"last"``) for
the data set the run was trained on, and one per checkpoint and data set for a fit on another data
set's validation split (``nanoct predict --calibrate-on``: e.g. a scan's own measured pairs,
:func:`nanoct.sim.matched.measured_pair`; :func:`entry_name`).
An entry is reused only if it was fitted for the same checkpoint file (SHA-256), data set (its
path and the SHA-256 of its description), input, sampling arguments (M), levels and delta;
otherwise it is fitted again. Validation outputs are made as :func:`nanoct.learn.predict.predict`
makes them: one image at a time, latent samples seeded with the sample index, so the fit sees
exactly the std that ``predict --split val`` stores. Conventions and the metrics: ``docs/uncertainty.md``.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import os
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..core.errors import NanoctError
from ..evaluation.conformal import (
    DEFAULT_DELTA,
    DEFAULT_LEVELS,
    OBJECT_WIDTH_BINS,
    conformal_multiplier,
    encode_mask,
    fit_footprint,
    fit_group_cuts,
    fit_group_intervals,
    fit_support_threshold,
    fit_width_map,
    group_labels,
    guaranteed_coverage,
    half_width_of,
    level_key,
    rcps_multiplier,
    support_image,
    support_of,
)
from ..evaluation.metrics import EDGE_SIGMA, SUPPORT_RADIUS, edge_std, truth_support
from ..io.fileio import atomic_write_text
from ..io.lock import exclusive
from ..io.store import DataStore
from .base import PostProcessor
from .checkpoint import load_checkpoint, model_from_checkpoint
from .data import check_input
from .models import model_class
from .scan_ood import scan_reference
from .train import resolve_device

__all__ = [
    "CALIBRATION_FILE",
    "CALIBRATION_FORMAT",
    "DEFAULT_SUPPORT_SOURCE",
    "SUPPORT_SOURCES",
    "Inference",
    "OOD_ALPHA",
    "calibrate",
    "entry_name",
    "fit_intervals",
    "image_statistic",
    "load_calibration",
    "ood_p_values",
    "reference_rule",
    "sample_outputs",
    "tiled_outputs",
    "training_store",
]

CALIBRATION_FILE = "calibration.json"
#: Version of a calibration entry; entries of another version are fitted again.
CALIBRATION_FORMAT = 13
#: What the prediction-time support of the group-conditional calibration is computed from.
SUPPORT_SOURCES = ("std", "mean", "relative")
#: The mean: a network sure of an object (small std inside it) still shows it in its mean, so the
#: object's pixels are not left in the background group (``docs/uncertainty.md``).
DEFAULT_SUPPORT_SOURCE = "mean"
#: An image whose out-of-distribution p-value (:func:`ood_p_values`) is at most this is flagged.
OOD_ALPHA = 0.05


def _meta_sha256(store: DataStore) -> str:
    """SHA-256 of a data set's description (geometry, seed, simulation record, splits): a set made again at the
    same path with other settings is another data set, whose calibration is fitted again."""
    return hashlib.sha256(json.dumps(store.meta, sort_keys=True).encode()).hexdigest()


def _n_samples(model_name: str, kwargs: dict[str, Any]) -> int | None:
    """M: the ``n_samples`` passed, else the default of the model's ``reconstruct``."""
    if "n_samples" in kwargs:
        return int(kwargs["n_samples"])
    param = inspect.signature(model_class(model_name).reconstruct).parameters.get("n_samples")
    return None if param is None or param.default is inspect.Parameter.empty else int(param.default)


class Inference:
    """A model on its device (channels-last on CPU), called on a batch: (mean, raw std or None) as numpy.

    A sampling model is called one image at a time with ``seed`` = the sample's index, so a
    prediction does not depend on batching or resumption. :func:`nanoct.learn.predict.predict`
    and :func:`sample_outputs` both use it, so the calibration sees exactly the std that predict
    stores.
    """

    def __init__(self, model: Any, kwargs: dict[str, Any], sampling: bool, device: str | torch.device | None) -> None:
        self.dev = resolve_device(device)
        self.channels_last = self.dev.type == "cpu"
        model = model.to(self.dev, memory_format=torch.channels_last) if self.channels_last else model.to(self.dev)
        model.eval()
        self.model, self.kwargs, self.sampling = model, kwargs, sampling

    def __call__(self, x_tilde: np.ndarray, first_index: int) -> tuple[np.ndarray, np.ndarray | None]:
        x = torch.from_numpy(np.ascontiguousarray(x_tilde, np.float32))[:, None].to(self.dev)
        if self.channels_last:
            x = x.contiguous(memory_format=torch.channels_last)
        call = {"seed": first_index, **self.kwargs} if self.sampling else self.kwargs
        with torch.no_grad():
            mean, std = self.model.reconstruct(x, **call)
        mean_np = mean.float().cpu().numpy()[:, 0]
        std_np = None if std is None else std.float().cpu().numpy()[:, 0]
        if std_np is not None and not (np.isfinite(std_np).all() and np.isfinite(mean_np).all()):
            raise NanoctError(
                f"the {self.model.name} network gave a non-finite mean or std for sample {first_index}; "
                "its checkpoint is damaged or training diverged: train it again"
            )
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

    infer = Inference(model, dict(reconstruct_kwargs or {}), True, device)
    n = store.geometry.n
    means, stds = np.empty((len(indices), n, n), np.float32), np.empty((len(indices), n, n), np.float32)
    for j, i in enumerate(tqdm(indices, desc="calibrate", unit="img", disable=not progress)):
        mean, std = infer(store.read_reconstruction(input_name, [int(i)]), int(i))
        if std is None:
            raise NanoctError(f"a '{model.name}' network gives no std; only sampling networks are calibrated")
        means[j], stds[j] = mean[0], std[0]
    return means, stds


def tiled_outputs(
    infer: Inference,
    store: DataStore,
    input_name: str,
    indices: np.ndarray,
    tiling: dict[str, int],
    progress: bool = False,
    desc: str = "calibrate",
) -> Iterator[tuple[int, np.ndarray, np.ndarray | None]]:
    """Each sample's index, mean and raw std (or None) of a network applied to ``reconstructions/<input_name>``
    in tiles (:func:`~nanoct.learn.tiling.predict_tiled` with ``tiling``'s ``size``, ``overlap``, ``margin`` and
    ``batch``, latent samples seeded with the sample index), one progress bar per image. On the CPU, as many
    single-threaded network calls at once as torch has threads (:func:`~nanoct.learn.tiling.parallel_tiles`).

    :func:`nanoct.learn.predict.predict` writes these outputs; :func:`calibrate` fits a patch-trained run's
    intervals and out-of-distribution reference on those of the validation images, so that they are the
    very outputs a tiled prediction of a validation image gives.
    """
    from .tiling import parallel_tiles, predict_tiled

    with parallel_tiles(infer.dev) as workers:
        for i in indices:
            mean, std = predict_tiled(
                store.read_reconstruction(input_name, [int(i)])[0],
                infer,
                tiling["size"],
                overlap=tiling["overlap"],
                margin=tiling["margin"],
                batch=tiling["batch"],
                seed=int(i),
                workers=workers,
                progress=progress,
                desc=f"{desc} #{int(i)}",
            )
            yield int(i), mean, std


def _tiled_val_outputs(
    model: PostProcessor,
    store: DataStore,
    input_name: str,
    indices: np.ndarray,
    tiling: dict[str, int] | None,
    kwargs: dict[str, Any],
    device: str | torch.device | None,
    progress: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """Means and raw stds (n, N, N) of :func:`tiled_outputs` of a sampling network (sampling arguments ``kwargs``)."""
    if not tiling:
        raise NanoctError("a network trained on patches is calibrated on its tiled predictions: predict with --tile 0")
    infer = Inference(model, dict(kwargs or {}), True, device)
    means, stds = [], []
    for _, mean, std in tiled_outputs(infer, store, input_name, indices, tiling, progress):
        if std is None:
            raise NanoctError(f"a '{model.name}' network gives no std; only sampling networks are calibrated")
        means.append(mean)
        stds.append(std)
    return np.stack(means), np.stack(stds)


def image_statistic(stds: np.ndarray) -> np.ndarray:
    """The out-of-distribution statistic of each image: its mean raw std (the network's std level)."""
    return np.asarray(stds, np.float64).reshape(len(stds), -1).mean(axis=1)


def ood_p_values(values: np.ndarray, reference: list[float] | np.ndarray) -> np.ndarray:
    """Conformal p-values of images' statistics against the validation images' (larger = more unusual).

    ``p = (1 + #{reference >= value}) / (n + 1)``: for an image exchangeable with the n validation
    images, ``P(p <= a) <= a``, so flagging ``p <= a`` wrongly flags at most a fraction ``a`` of
    in-distribution images.
    """
    ref = np.sort(np.asarray(reference, np.float64))
    above = ref.size - np.searchsorted(ref, np.asarray(values, np.float64), side="left")
    return (1.0 + above) / (ref.size + 1.0)


def _support_rule(
    image: np.ndarray, gts: np.ndarray, source: str, fill: bool, radius: int, known: np.ndarray | None
) -> dict[str, Any]:
    """The prediction-time support (:func:`nanoct.evaluation.conformal.support_of` of ``image``, the
    :func:`nanoct.evaluation.conformal.support_image` of ``source``, holes filled with ``fill``, dilated
    by ``radius``) whose threshold best matches the validation images' true support
    (:func:`nanoct.evaluation.metrics.truth_support`, largest IoU) on the pixels ``known`` (default all)."""
    truth = truth_support(gts, radius, known=known)
    threshold = fit_support_threshold(image, truth, radius, fill=fill, mask=known)
    return {"source": source, "threshold": threshold, "radius": radius, "fill": fill}


def _level_fit(
    err: np.ndarray,
    stds: np.ndarray,
    means: np.ndarray,
    level: float,
    delta: float,
    groups: dict[str, Any],
    labels: np.ndarray,
    keep: np.ndarray,
    truth: np.ndarray | None = None,
) -> dict[str, Any]:
    """One level: the pooled one-multiplier intervals (for comparison) and the group-conditional ones (delivered),
    fitted on the pixels ``keep``; ``labels`` are the pixels' groups (:func:`group_labels`, -1 outside ``keep``);
    ``truth``: the references' object, for object-conditional multipliers."""
    width_map = fit_width_map(err[keep], stds[keep], level)
    scaled = half_width_of(stds, {"map": width_map, "multiplier": 1.0})
    q = conformal_multiplier(err[keep], scaled[keep], level)
    try:
        rcps: float | None = rcps_multiplier(err, scaled, level, delta, mask=keep)
    except ValueError:
        rcps = None
    pooled = {
        "map": width_map,
        "multiplier": q,
        "guaranteed_coverage": guaranteed_coverage(err, scaled, q, delta, mask=keep),
        "rcps_multiplier": rcps,
        "val_coverage": float(np.mean((err <= q * scaled)[keep])),
    }
    footprint = bool(groups.get("footprint"))
    grouped = groups | fit_group_intervals(err, stds, labels, level, delta, truth=truth, footprint=footprint)
    half = half_width_of(stds, {"groups": grouped}, image=means)
    group_rcps = grouped["rcps_multipliers"]
    return {
        "groups": grouped,
        "multiplier": q,
        "guaranteed_coverage": guaranteed_coverage(err, half, 1.0, delta, mask=keep),
        "rcps_multiplier": None if None in group_rcps else max(group_rcps),
        "val_coverage": float(np.mean((err <= half)[keep])),
        "pooled": pooled,
    }


def fit_intervals(
    means: np.ndarray,
    stds: np.ndarray,
    gts: np.ndarray,
    levels: tuple[float, ...] = DEFAULT_LEVELS,
    delta: float = DEFAULT_DELTA,
    edge_sigma: float = EDGE_SIGMA,
    support_source: str = DEFAULT_SUPPORT_SOURCE,
    fill_holes: bool = True,
    known: np.ndarray | None = None,
    support_radius: int = SUPPORT_RADIUS,
    object_conditional: bool = False,
    footprint: bool = False,
) -> dict[str, Any]:
    """Fit the intervals of the std and of the edge baseline on validation outputs (n, H, W).

    The delivered intervals are group-conditional (Mondrian) split-conformal intervals
    (:func:`nanoct.evaluation.conformal.fit_group_intervals`): the groups are the background and
    the five equal-count std bins (fifths) of the object's support, the support as seen at
    prediction time (``support_source``: the mean (default) or the std above a threshold, its holes
    filled with ``fill_holes``, dilated by 2 px; the threshold is the one whose support best
    matches the validation images' true support), the fifths' std cut points those of the
    validation support. Per level and group: a width map per region and a split-conformal
    multiplier, with each group's guarantee (its coverage at least
    the level for exchangeable pixels of the group; the per-image coverage of its pixels that holds
    with probability ``1 - delta``). Next to them, for comparison, the pooled calibration of
    earlier versions (``pooled``: one width map and one multiplier for all pixels). Also the edge
    baseline's conformal multiplier (:func:`nanoct.evaluation.metrics.edge_std` of the mean) and
    the validation images' out-of-distribution statistic (:func:`image_statistic`).

    ``support_source`` ``"relative"`` thresholds the mean divided by each image's own level
    (:func:`nanoct.evaluation.conformal.support_image`), for images whose intensity differs by orders
    of magnitude (the slices of a measured sample). ``known`` (bool, broadcast to (n, H, W)): fit on
    those pixels only (e.g. the field of view, where a measured reference is known); the truth's
    support is :func:`nanoct.evaluation.metrics.truth_support` (a reconstructed reference, with
    negative values, is thresholded, not taken as ``> 0``), dilated, like the prediction-time
    support, by ``support_radius`` px. ``object_conditional``: each group's multiplier is the larger
    of those of its pixels on the references' object (:func:`nanoct.evaluation.metrics.truth_support`
    of the known pixels, not dilated) and of its other pixels, so that the coverage holds on the
    object as the references show it even where the prediction-time support misses part of it
    (:func:`nanoct.evaluation.conformal.fit_group_intervals` with ``truth``). ``footprint``: the
    background is split in two groups, inside and outside the sample's footprint (the pixels in the
    prediction-time support of at least one validation image,
    :func:`nanoct.evaluation.conformal.fit_footprint`, stored with the groups), for validation images
    on the grid of the images the calibration will serve (the measured pairs of one scan): object
    pixels that the support misses lie inside the footprint, so the background outside it keeps
    narrow intervals; an image of another shape has all its background in the group inside it.

    Returns
    -------
    dict
        ``delta``, ``object_conditional``, ``support`` (the support rule), ``cuts`` (the object's std cut points),
        ``levels`` = {level key: {``groups`` (``support``, ``cuts``, with ``footprint`` the encoded mask
        (:func:`nanoct.evaluation.conformal.encode_mask`), ``maps``, ``multipliers``,
        ``rcps_multipliers``, ``guaranteed_coverage``, ``val_coverage``, ``n_pixels``: lists over
        background, object fifths 1..5 and, with ``footprint``, the background inside it),
        ``multiplier`` (the pooled one), ``guaranteed_coverage`` and ``val_coverage`` (the delivered
        intervals over all pixels), ``rcps_multiplier`` (the
        largest group's, None where a group has none), ``pooled``}}, ``edge_sigma``,
        ``edge_multipliers`` = {level key: multiplier}, ``ood`` = {``statistic``: "mean_std",
        ``alpha``, ``val``: the validation images' values, sorted}.

    Raises
    ------
    NanoctError
        If no positive finite multiplier exists (e.g. a std that is zero where the error is not).
    """
    if support_source not in SUPPORT_SOURCES:
        raise NanoctError(f"support source {support_source!r} must be one of {', '.join(SUPPORT_SOURCES)}")
    err = np.abs(np.asarray(means, np.float64) - np.asarray(gts, np.float64))
    stds = np.asarray(stds, np.float64)
    edges = edge_std(means, edge_sigma)
    keep = np.broadcast_to(np.asarray(True if known is None else known, bool), err.shape)
    fitted: dict[str, Any] = {}
    edge_fit: dict[str, float] = {}
    try:
        image = support_image(support_source, stds, means)
        rule = _support_rule(image, np.asarray(gts), support_source, fill_holes, support_radius, known)
        support = support_of(image, rule["threshold"], rule["radius"], fill_holes)
        cuts = fit_group_cuts(stds, support & keep, OBJECT_WIDTH_BINS)
        groups: dict[str, Any] = {"support": rule, "cuts": cuts}
        if footprint:
            groups["footprint"] = encode_mask(fit_footprint(support & keep))
        labels = np.where(keep, group_labels(stds, groups, means), -1)
        truth = truth_support(gts, 0, known=keep) & keep if object_conditional else None
        for level in levels:
            fitted[level_key(level)] = _level_fit(err, stds, means, level, delta, groups, labels, keep, truth)
            edge_fit[level_key(level)] = conformal_multiplier(err[keep], edges[keep], level)
    except ValueError as exc:
        raise NanoctError(f"cannot calibrate on the validation outputs: {exc}") from exc
    return {
        "delta": float(delta),
        "object_conditional": bool(object_conditional),
        "support": rule,
        "cuts": cuts,
        "levels": fitted,
        "edge_sigma": float(edge_sigma),
        "edge_multipliers": edge_fit,
        "ood": {"statistic": "mean_std", "alpha": OOD_ALPHA, "val": sorted(image_statistic(stds).tolist())},
    } | ({} if known is None else {"known_pixels": int(np.count_nonzero(keep))})


def load_calibration(run_dir: str | os.PathLike[str]) -> dict[str, dict[str, Any]]:
    """The entries of ``<run>/calibration.json`` by name (:func:`entry_name`; empty if absent).

    Raises
    ------
    NanoctError
        If the file exists but cannot be read or is not a JSON object: it is not overwritten, since
        it may hold other data sets' calibrations (deleting it makes ``predict`` fit them again).
    """
    path = Path(run_dir) / CALIBRATION_FILE
    if not path.exists():
        return {}
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        data = exc
    if not isinstance(data, dict):
        cause = f"{type(data).__name__}: {data}" if isinstance(data, Exception) else "not a JSON object"
        raise NanoctError(
            f"the calibrations of {run_dir} in {path} are damaged ({cause}); delete the file and run "
            "'nanoct predict' again (it fits the intervals again)"
        )
    return data


def calibrate(
    store: DataStore | str | os.PathLike[str],
    run_dir: str | os.PathLike[str],
    checkpoint: str = "best",
    *,
    reconstruct_kwargs: dict[str, Any] | None = None,
    device: str | torch.device | None = None,
    progress: bool = False,
    refit: bool = False,
    levels: tuple[float, ...] = DEFAULT_LEVELS,
    delta: float = DEFAULT_DELTA,
    tiling: dict[str, int] | None = None,
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
    levels : tuple of float
        Interval levels (nominal coverage, each in (0, 1)); part of the validity key.
    delta : float
        The guarantee's failure probability; part of the validity key.
    tiling : dict, optional
        The tiling of the prediction (:func:`nanoct.learn.predict.predict`'s ``tiling``: ``size``,
        ``overlap``, ``margin``, ``batch``) of a patch-trained run (``train --patch``); part of the validity
        key. On a data set of another image size than the patches, the intervals and the
        out-of-distribution reference are fitted on the validation images predicted with it
        (:func:`tiled_outputs`), the outputs a tiled prediction gives.

    Returns
    -------
    dict
        The entry: what it was fitted for (``format``, ``checkpoint``, ``checkpoint_sha256``,
        ``epoch``, ``store``, ``input`` and its ``input_fingerprint`` (refitted when the input is made
        again, e.g. with ``--overwrite``), ``reconstruct``, ``n_samples``, ``split`` = "val",
        ``n_images``) and :func:`fit_intervals`'s result, with ``ood.scan`` the reference of the
        apparent-motion statistic (:func:`nanoct.learn.scan_ood.scan_reference`) where the data
        set has train or validation samples. ``store`` (the data set's path) is recorded, not compared:
        a data set or run that moved keeps its fit (:func:`_kept_entry`).

    Raises
    ------
    NanoctError
        A missing or bad checkpoint, a network without std, an empty validation split or an
        incomplete input, levels outside (0, 1), or validation outputs that admit no multiplier.
    """
    store = store if isinstance(store, DataStore) else DataStore.open(store)
    run = Path(run_dir)
    ckpt_path = run / f"{checkpoint}.pt"
    ckpt = load_checkpoint(ckpt_path)
    entries = load_calibration(run)
    name = entry_name(run, checkpoint, store.path)
    key = {
        "format": CALIBRATION_FORMAT,
        "checkpoint": checkpoint,
        "checkpoint_sha256": ckpt["file_sha256"],
        "store": str(store.path.resolve()),
        "store_meta_sha256": _meta_sha256(store),
        "reconstruct": json.loads(json.dumps(dict(reconstruct_kwargs or {}))),
        "split": "val",
        "level_keys": [level_key(v) for v in levels],
        "delta": float(delta),
    } | ({"tiling": dict(tiling)} if tiling else {})
    if not 0 < delta < 1:
        raise NanoctError(f"delta {delta} must lie strictly between 0 and 1 (e.g. 0.1)")
    kept = None if refit else _kept_entry(entries, name, key, store, run)
    if kept is not None:
        return kept  # the same checkpoint file (so the same model, input and epoch), data set, input arrays and M
    patch = (ckpt.get("config") or {}).get("patch")  # train --patch: fitted on tiled predictions of whole images
    if not (patch and store.indices("val").size and store.geometry.n != patch):
        patch = None
        own = _runs_own(store, run, entries.get(checkpoint), key, int(ckpt["image_size"]))  # raises on another size
        if own is not None:
            return own
    if not model_class(str(ckpt["model"])).has_uncertainty:
        raise NanoctError(f"the run at {run} holds a '{ckpt['model']}' network, which gives no std to calibrate")
    kwargs = key["reconstruct"]
    key |= {
        "epoch": int(ckpt["epoch"]),
        "input": str(ckpt["input"]),
        "input_fingerprint": _input_fingerprint(store, str(ckpt["input"])),
        "n_samples": _n_samples(str(ckpt["model"]), kwargs),
    }
    val = store.indices("val")
    if val.size == 0:
        raise NanoctError(
            f"{store.path} has no validation samples to calibrate the std of {run} on; predict fits them on the "
            "data set the run was trained on, at the path the run's config.json records: put it back there, pass "
            "--calibrate-on a data set of the run's geometry, or --no-calibrate"
        )
    check_input(store, key["input"], val, "val")
    model = model_from_checkpoint(ckpt, ckpt_path)
    if patch:
        means, stds = _tiled_val_outputs(model, store, key["input"], val, tiling, kwargs, device, progress)
        key["patch"] = int(patch)
    else:
        means, stds = sample_outputs(model, store, key["input"], val, kwargs, device, progress)
    gts = store.read_phantoms(val)
    rule = reference_rule(store, gts)
    if rule.get("footprint"):
        _warn_noisy_footprint(store, means, stds, key, rule["known"])
    entry = key | {"n_images": len(means)} | fit_intervals(means, stds, gts, tuple(levels), delta, **rule)
    if rule:
        entry["references"] = "measured: support relative to each image, field of view only"
    reference = scan_reference(store)
    if reference is not None:
        entry["ood"]["scan"] = reference
    _write_entry(run, name, entry)
    return entry


def _warn_noisy_footprint(
    store: DataStore, means: np.ndarray, stds: np.ndarray, key: dict[str, Any], known: np.ndarray
) -> None:
    """Warn where the footprint is fitted on validation means of independent draws of which some are too noisy
    for their support to mean anything (:func:`nanoct.evaluation.conformal.mean_noise_ratio` above
    :data:`~nanoct.evaluation.conformal.FOOTPRINT_NOISY_MEAN`): their speckle widens the footprint."""
    from ..evaluation.conformal import FOOTPRINT_NOISY_MEAN, mean_noise_ratio

    if key["reconstruct"].get("antithetic") or not key["n_samples"]:
        return
    ratios = mean_noise_ratio(stds, means, int(key["n_samples"]), known)
    total, ratios = len(ratios), ratios[np.isfinite(ratios)]  # an image that is zero there has no support to speckle
    noisy = int((ratios > FOOTPRINT_NOISY_MEAN).sum())
    if noisy:
        warnings.warn(
            f"the intervals' footprint is fitted on the validation split of {store.path}, where the sampling noise of "
            f"{noisy} of {total} means of {key['n_samples']} independent draws is more than "
            f"{FOOTPRINT_NOISY_MEAN} of their level (up to {float(ratios.max()):.2f}), so their support is partly "
            "noise and the footprint wider than the sample; predict with --antithetic or more --samples",
            UserWarning,
            stacklevel=3,
        )


def _write_entry(run: Path, name: str, entry: dict[str, Any]) -> None:
    """Store ``entry`` under ``name`` in the run's ``calibration.json``: under the file's lock (waiting up to a
    minute for another process's update), read again just before the write, so that entries another process
    stored since this one read the file are kept."""
    with exclusive(run, CALIBRATION_FILE, f"{run / CALIBRATION_FILE}", wait=60.0):
        entries = load_calibration(run)
        entries[name] = entry
        atomic_write_text(run / CALIBRATION_FILE, json.dumps(entries, indent=2))


def _kept_entry(
    entries: dict[str, Any], name: str, key: dict[str, Any], store: DataStore, run: Path
) -> dict[str, Any] | None:
    """The entry fitted for ``key`` on this data set: the one under ``name``, else one fitted where the data set
    lay before it (or the run) was moved or copied. The data set is told by its description and its input
    array's creation id, not by its path; an entry found under another path is recorded under ``name``
    with this path (no refit). None where there is none."""
    fingerprint: dict[str, Any] = {}
    for k in [name, *(k for k in entries if k != name)]:
        entry = entries.get(k)
        if not (isinstance(entry, dict) and all(entry.get(f) == v for f, v in key.items() if f != "store")):
            continue
        inp = str(entry.get("input"))
        if inp not in fingerprint:
            fingerprint[inp] = _input_fingerprint(store, inp)
        if entry.get("input_fingerprint") != fingerprint[inp]:
            continue
        if entry.get("store") != key["store"] or k != name:
            entry = entry | {"store": key["store"]}
            _write_entry(run, name, entry)
        return entry
    return None


def _runs_own(store: DataStore, run: Path, own: Any, key: dict[str, Any], trained: int) -> dict[str, Any] | None:
    """The run's own calibration entry ``own`` where it serves ``store``: a data set without validation samples
    (an imported scan) or of another image size than the ``trained`` one (predicted in tiles), for the same
    checkpoint file and sampling; None where the store is calibrated on its own validation split.

    Raises
    ------
    NanoctError
        For a store of another image size without such an entry.
    """
    other_size = trained != store.geometry.n
    if isinstance(own, dict) and (store.indices("val").size == 0 or other_size):
        if all(own.get(k) == v for k, v in key.items() if k not in ("store", "store_meta_sha256")):
            return own
    if other_size:
        n = store.geometry.n
        raise NanoctError(
            f"{store.path} holds {n}x{n} images, the run at {run} was trained on {trained}x{trained}: its intervals "
            "are fitted on the data set it was trained on, which predict finds at the path the run's config.json "
            "records; put it back there, pass --calibrate-on a data set of the run's geometry, or --no-calibrate"
        )
    return None


def _input_fingerprint(store: DataStore, name: str | None) -> dict[str, Any] | None:
    """The store's fingerprint of the input reconstruction ``name`` (its parameters and creation id, as JSON
    reads it back), None where there is none: a calibration is refitted when its input was made again."""
    try:
        return json.loads(json.dumps(store.recons.fingerprint(str(name))))
    except KeyError:
        return None


def reference_rule(store: DataStore, gts: np.ndarray) -> dict[str, Any]:
    """How :func:`fit_intervals` treats a validation split whose ground truths are reconstructions.

    A measured pair's reference (:func:`nanoct.sim.matched.measured_pair`) is an FBP of measured data:
    noisy (negative values), known only inside the field of view (zero outside), and its slices
    differ in content by orders of magnitude. For a split holding such references the support is
    found relative to each image's own level (``support_source="relative"``), only the pixels of
    the field of view are fitted (``known``), and the multipliers are object-conditional
    (``object_conditional``): a network can miss a faint object altogether or smooth the rim of a
    bright one, so the support found from its prediction misses object pixels, which a group's one
    multiplier, set mostly by the background, would leave uncovered. Those pixels lie where the
    sample is in other slices, so where every validation reference is a reconstruction (a split of
    one scan's measured pairs, not a matched set that mixes them with phantoms at random places)
    the background is split at the pairs' footprint (``footprint``) and only the part inside it
    pays for them. Measured on the I13 scan's measured pairs
    (``docs/semireal_networks.md``), fitted on one half and scored on the other, object / background
    at 90 %: the std's support 64 / 88 %, the relative one 83 / 83 %, relative on the field of view
    83 / 90 % (without the 2 px dilation 76 / 92 %), with object-conditional multipliers 90 / 99 %,
    and with the footprint as well 90 / 92 %. For phantoms nothing changes (an empty dict).
    """
    from ..sim.matched import reference_view

    known = reference_view(store.geometry, gts)
    if known is None:
        return {}
    every = bool((np.asarray(gts).reshape(len(gts), -1).min(axis=1) < 0).all())
    return {"support_source": "relative", "known": known, "object_conditional": True, "footprint": every}


def entry_name(run_dir: str | os.PathLike[str], checkpoint: str, store_path: str | os.PathLike[str]) -> str:
    """The key of a calibration in ``calibration.json``: the checkpoint's name for a fit on the data set
    the run was trained on (its ``config.json``), ``<checkpoint>@<data set>`` for a fit on another
    (e.g. measured pairs of a scan, ``nanoct predict --calibrate-on``), so that both are kept."""
    trained_on = training_store(run_dir)
    here = str(Path(store_path).resolve())
    return checkpoint if trained_on is None or str(trained_on.resolve()) == here else f"{checkpoint}@{here}"


def training_store(run_dir: str | os.PathLike[str]) -> Path | None:
    """The path of the data set a run was trained on, as its ``config.json`` records it (None: not recorded).

    Parameters
    ----------
    run_dir : path
        A training run directory.

    Returns
    -------
    Path or None
        The recorded path; the data set need not be there any more.
    """
    try:
        recorded = json.loads((Path(run_dir) / "config.json").read_text()).get("store")
    except (OSError, ValueError, AttributeError):
        return None
    return Path(recorded) if isinstance(recorded, str) and recorded else None
