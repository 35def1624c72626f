"""The data-scaling study of the learned rows: the same networks on nested training sets.

One data set of the tiny-parallel geometry holds ``max(sizes)`` training samples plus fixed
validation and test splits. Every network (UNet, CiUNetRes) is trained on every input (FBP,
Dremel, RESESOP) on the first K training images for K in ``sizes``, always for the same number
of optimiser steps (so the curve isolates data from compute), with several training seeds per
size, plus one point at the largest size with ``long_factor`` times the steps (compute at fixed
data). Each (network, input, size, steps, seed) is a *unit*: its training run and its test
prediction; a complete unit is skipped, a killed one resumes from its last checkpoint.

Why a command of its own (``nanoct scaling``) rather than a ``reproduce`` preset: the reproduce
studies have one training set per setting and report the paper's tables; this study varies the
training set within one data set, names its rows by size (:func:`nanoct.names.scaling_name`) and
reports curves (:mod:`nanoct.study.scaling_report`). Its definition and units are
:mod:`nanoct.study.scaling_config`.
"""

from __future__ import annotations

import fnmatch
import json
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..core.errors import NanoctError
from ..core.geometry import get_preset
from ..io.fileio import atomic_write_text
from ..io.store import DataStore
from ..learn.models import build_model, model_class, model_spec
from ..recon.batch import reconstruct_dataset
from ..recon.names import reconstruction_name
from ..sim.generate import generate_dataset
from ..sim.simulate import SimulationConfig
from .scaling_config import INPUTS, ScalingStudy, ScalingUnit, scaling_units

__all__ = ["format_scaling_plan", "measure_costs", "plan_scaling", "run_scaling"]


def _unit_done(store: DataStore, unit: ScalingUnit) -> bool:
    return unit.name in store.reconstruction_names() and bool(
        store.reconstruction_done(unit.name, store.indices("test")).all()
    )


def _run_unit(store_path: Path, runs: Path, study: ScalingStudy, unit: ScalingUnit, progress: bool) -> None:
    from ..learn.predict import predict
    from ..learn.train import TrainConfig, train

    base = study.base
    config = TrainConfig(
        unit.model,
        unit.input,
        epochs=unit.epochs(model_spec(unit.model).batch_size),
        lr=base.lr.get(unit.model),
        scheduler=study.scheduler,
        model_kwargs=base.model_kwargs.get(unit.model),
        seed=unit.seed,
        precision=base.precision,
        max_steps=unit.steps,
        n_train=unit.n_train,
    )
    train(store_path, runs / unit.run, config, progress=progress)
    sampling = model_class(unit.model).has_uncertainty
    predict(
        store_path,
        runs / unit.run,
        unit.input,
        split="test",
        progress=False,
        name=unit.name,
        reconstruct_kwargs=base.sampling if sampling else None,
    )


def _data(out: Path, study: ScalingStudy, workers: int, progress: bool) -> DataStore:
    geometry = get_preset(study.preset)
    config = SimulationConfig.for_geometry(geometry, perturbed=True)
    store = generate_dataset(
        out / "data",
        geometry,
        study.n,
        seed=study.seed,
        config=config,
        split_fractions=study.split_fractions,
        workers=workers,
        progress=progress,
    )
    counts = tuple(int(store.indices(s).size) for s in ("train", "val", "test"))
    if counts != (max(study.sizes), study.n_val, study.n_test):
        raise NanoctError(f"the data set at {out / 'data'} has train/val/test {counts}, not the study's")
    return store


@contextmanager
def _timed(path: Path, key: str) -> Iterator[None]:
    """Add the wall time of the block to ``key`` in the JSON file of measured times, also when the
    block is interrupted (the times of a stage add up over sittings)."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        times = json.loads(path.read_text()) if path.exists() else {}
        times[key] = times.get(key, 0.0) + time.perf_counter() - t0
        atomic_write_text(path, json.dumps(times, indent=2, sort_keys=True))


def run_scaling(
    out: str | Path,
    study: ScalingStudy | None = None,
    *,
    only: str | None = None,
    workers: int = 2,
    progress: bool = True,
) -> Path:
    """Run (or continue) the study in ``out`` and write its report; returns the Markdown report's path.

    Stages: the data set (``out/data``), the first reconstructions of every sample, then the units
    of :func:`scaling_units` one after another (``out/runs/<unit>``), each trained and then
    predicted on the test split, then the report (:func:`nanoct.study.scaling_report.write_scaling_report`).
    The wall time of every stage and unit is added to ``out/seconds.json`` (an interrupted one's
    too). The study's definition is written to ``out/study.json``; a directory of another
    definition is refused. ``only``: a
    shell pattern of unit run names (``unet-dremel-*``) to run in this sitting; the others are
    left for a later one (the report marks the points it lacks as partial).

    Raises
    ------
    NanoctError
        If ``out`` holds a study of another definition, or from the stages (bad data, a diverged run).
    """
    from tqdm.auto import tqdm

    from .scaling_report import write_scaling_report

    study = study or ScalingStudy()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    definition = json.loads(json.dumps(asdict(study)))
    stored = out / "study.json"
    if stored.exists() and json.loads(stored.read_text()) != definition:
        raise NanoctError(f"{out} holds a scaling study of another definition ({stored}); choose another --out")
    atomic_write_text(stored, json.dumps(definition, indent=2))
    seconds = out / "seconds.json"
    with _timed(seconds, "data"):
        store = _data(out, study, workers, progress)
    for name in study.inputs:
        method, params = INPUTS[name]
        with _timed(seconds, f"reconstruction/{name}"):
            reconstruct_dataset(
                out / "data",
                method,
                params=params,
                name=reconstruction_name(method, params),
                workers=workers,
                progress=progress,
            )
    units = [u for u in scaling_units(study) if only is None or fnmatch.fnmatchcase(u.run, only)]
    for unit in tqdm(units, desc="scaling units", unit="unit", disable=not progress):
        if _unit_done(store, unit):
            continue
        with _timed(seconds, f"unit/{unit.run}"):
            _run_unit(out / "data", out / "runs", study, unit, progress=False)
    return write_scaling_report(out, study)


def measure_costs(study: ScalingStudy, samples: int = 4, steps: int = 3) -> dict[str, float]:
    """Measure on this machine, now: seconds per sample of generation and of each first
    reconstruction (``samples`` samples in a temporary store, timed after a first pass that
    compiles the kernels and builds the cached matrix), and seconds per training step
    (batch of the model's size, the study's precision) and per image forward pass of each network.

    Returns
    -------
    dict
        ``generate``, ``recon/<input>``, ``step/<model>``, ``forward/<model>`` in seconds.
    """
    import torch

    from ..learn.train import resolve_precision

    costs: dict[str, float] = {}
    geometry = get_preset(study.preset)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        generate_dataset(
            Path(tmp) / "d",
            geometry,
            samples,
            seed=study.seed,
            config=SimulationConfig.for_geometry(geometry),
            split_fractions=(1.0, 0.0, 0.0),
            workers=0,
            progress=False,
        )
        costs["generate"] = (time.perf_counter() - t0) / samples
        for name in study.inputs:
            method, params = INPUTS[name]
            # a first pass compiles the kernels (numba) and builds the cached matrix: not per sample
            kwargs = {"params": params, "workers": 0, "progress": False}
            reconstruct_dataset(Path(tmp) / "d", method, name=f"warm-up-{name}", **kwargs)
            t0 = time.perf_counter()
            reconstruct_dataset(Path(tmp) / "d", method, **kwargs)
            costs[f"recon/{name}"] = (time.perf_counter() - t0) / samples
    n = geometry.n
    bf16 = resolve_precision(study.base.precision, "cpu") == "bf16"
    for m in study.models:
        batch = model_spec(m).batch_size
        torch.manual_seed(0)
        model = build_model(m, **(study.base.model_kwargs.get(m) or {})).to(memory_format=torch.channels_last)
        x = torch.rand(batch, 1, n, n).to(memory_format=torch.channels_last)
        x_tilde = (x + 0.05 * torch.randn_like(x)).to(memory_format=torch.channels_last)
        if hasattr(model, "data_init"):
            with torch.no_grad():
                model.data_init(x_tilde, x)
        opt = torch.optim.Adam(model.parameters(), lr=1e-4)
        times = []
        for _ in range(steps + 1):  # the first step warms up
            t0 = time.perf_counter()
            opt.zero_grad(set_to_none=True)
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
                loss, _ = model.loss(x_tilde, x)
            loss.backward()
            opt.step()
            times.append(time.perf_counter() - t0)
        costs[f"step/{m}"] = float(np.median(times[1:]))
        model.eval()
        with torch.no_grad():
            model.reconstruct(x_tilde[:1])
            t0 = time.perf_counter()
            model.reconstruct(x_tilde, **({"n_samples": 2} if model_class(m).has_uncertainty else {}))
            per = (time.perf_counter() - t0) / batch
        costs[f"forward/{m}"] = per / 2 if model_class(m).has_uncertainty else per  # per latent sample
    return costs


@dataclass(frozen=True)
class _PlanRow:
    stage: str
    jobs: int
    done: int
    seconds: float


def plan_scaling(study: ScalingStudy, out: str | Path | None = None, costs: dict[str, float] | None = None) -> dict:
    """Cost of the study (or of what is left of it in ``out``) from per-sample and per-step costs.

    ``costs``: :func:`measure_costs`'s figures (measured when not given). Training units cost
    ``steps`` steps plus one validation pass per epoch; predictions cost the forward passes over
    the test split (the invertible network: ``n_samples`` latent samples over test and
    validation, the calibration). Checkpoint writes are not counted. Where ``out`` already holds
    finished units of a network, their measured wall time per step (``seconds.json``: training,
    validation, checkpoints and prediction) prices that network's remaining units instead.

    Returns
    -------
    dict
        ``rows`` (stage, jobs, done, seconds still to spend), ``total`` seconds, ``costs`` and
        ``unit_step`` (per network: measured seconds per step of finished units, if any).
    """
    costs = measure_costs(study) if costs is None else costs
    store = None
    if out is not None and (Path(out) / "data").exists():
        try:
            store = DataStore.open(Path(out) / "data")
        except Exception:  # noqa: BLE001 - an unreadable store is planned as missing
            store = None
    measured = {}
    if out is not None and (Path(out) / "seconds.json").exists():
        measured = json.loads((Path(out) / "seconds.json").read_text())
    unit_step = {}
    for m in study.models:
        finished = [
            u
            for u in scaling_units(study)
            if u.model == m and f"unit/{u.run}" in measured and (store is None or _unit_done(store, u))
        ]
        per_step = [measured[f"unit/{u.run}"] / u.steps for u in finished]
        if per_step:
            unit_step[m] = float(np.mean(per_step))
    done_samples = int(store.done.sum()) if store is not None else 0
    rows = [_PlanRow("data", study.n, done_samples, (study.n - done_samples) * costs["generate"])]
    for name in study.inputs:
        key = reconstruction_name(*INPUTS[name])
        done = 0
        if store is not None and key in store.reconstruction_names():
            done = int(store.reconstruction_done(key, np.arange(store.n)).sum())
        rows.append(_PlanRow(f"reconstruction {name}", study.n, done, (study.n - done) * costs[f"recon/{name}"]))
    units = scaling_units(study)
    for label, chosen in (
        (f"units at {study.steps} steps", [u for u in units if u.steps == study.steps]),
        (f"units at {study.steps * study.long_factor} steps", [u for u in units if u.steps != study.steps]),
    ):
        left = [u for u in chosen if store is None or not _unit_done(store, u)]
        sec = 0.0
        for u in left:
            if u.model in unit_step:
                sec += u.steps * unit_step[u.model]
                continue
            fwd = costs[f"forward/{u.model}"]
            val = u.epochs(model_spec(u.model).batch_size) * study.n_val * fwd
            inn = model_class(u.model).has_uncertainty
            pred = (study.n_test + study.n_val) * study.base.n_samples * fwd if inn else study.n_test * fwd
            sec += u.steps * costs[f"step/{u.model}"] + val + pred
        rows.append(_PlanRow(label, len(chosen), len(chosen) - len(left), sec))
    total = sum(r.seconds for r in rows)
    return {"rows": [asdict(r) for r in rows], "total": total, "costs": costs, "unit_step": unit_step}


def format_scaling_plan(plan: dict, study: ScalingStudy) -> str:
    """The plan as a text table with the measured per-unit costs it was computed from."""
    lines = [
        f"Data-scaling study: {', '.join(study.models)} on {', '.join(study.inputs)} ({study.preset}), "
        f"training sizes {', '.join(map(str, study.sizes))} (seeds {', '.join(map(str, study.seeds))}), "
        f"{study.steps} steps per run, plus {study.long_seeds} seed(s) at {max(study.sizes)} with "
        f"{study.long_factor * study.steps} steps; {study.n} samples (val {study.n_val}, test {study.n_test}).",
        "",
        f"{'stage':<28} {'jobs':>6} {'done':>6}  time left",
        "-" * 60,
    ]
    for r in plan["rows"]:
        lines.append(f"{r['stage']:<28} {r['jobs']:>6} {r['done']:>6}  {_duration(r['seconds'])}")
    lines += ["-" * 60, f"{'total':<42}  {_duration(plan['total'])}", "", "Measured on this machine now:"]
    c = plan["costs"]
    lines.append(
        f"- per sample: generation {c['generate']:.3f} s, "
        + ", ".join(f"{i} {c[f'recon/{i}']:.3f} s" for i in study.inputs)
    )
    lines.append(
        "- per training step: "
        + ", ".join(f"{m} {c[f'step/{m}']:.3f} s" for m in study.models)
        + "; per image forward (invertible: per latent sample): "
        + ", ".join(f"{m} {c[f'forward/{m}'] * 1000:.1f} ms" for m in study.models)
    )
    if plan.get("unit_step"):
        lines.append(
            "- remaining units priced by the finished ones (wall seconds per step, all included): "
            + ", ".join(f"{m} {v:.3f} s" for m, v in plan["unit_step"].items())
        )
    lines.append("- a loaded or shared machine takes longer; checkpoint writes are not counted")
    return "\n".join(lines) + "\n"


def _duration(seconds: float) -> str:
    return f"{seconds:,.0f} s" + (f" ({seconds / 3600:.2f} h)" if seconds >= 600 else "")
