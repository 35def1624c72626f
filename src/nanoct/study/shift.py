"""Uncertainty under distribution shift: test sets the networks of a study were not trained on.

For a finished one-setting study (``nanoct reproduce --preset ...``), each shift of
:data:`SHIFTS` gets a new data set of test samples only (other phantoms: another data-set seed),
simulated with the study's simulation changed in one respect: the motion amplitude halved or
1.5 times larger, Gaussian noise on the data (the training data have none), no motion, or
another phantom family (:func:`nanoct.sim.phantoms.random_ellipse_phantom`). The
study's first reconstructions that the networks take as input are made with the study's
parameters, each sampling network predicts with its own run and its calibration from the
study's calibration set, else its validation split (a data set without a validation split reuses
it; the study's own test split is predicted again where that calibration has changed), and the
uncertainty scores of :func:`nanoct.evaluation.evaluate.evaluate_store` are taken, including the
share of images that predict flagged as out of distribution. The in-distribution row is the
study's own test split. Everything is cached in ``<study>/shift``; a rerun only redoes what is
missing.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..core.errors import NanoctError
from ..core.geometry import get_preset
from ..core.names import prediction_name
from ..evaluation.evaluate import evaluate_store
from ..io.fileio import atomic_write_text
from ..io.store import DataStore
from ..learn.models import model_class
from ..learn.predict import predict
from ..recon.batch import reconstruct_dataset
from ..sim.generate import generate_dataset
from ..sim.simulate import SimulationConfig
from .config import preset_setting, preset_study

__all__ = ["SHIFTS", "SHIFT_SEED", "format_shift_table", "shift_config", "shift_study"]

#: The shifted test sets: name -> what changes in the study's simulation.
SHIFTS: dict[str, str] = {
    "motion_x0.5": "motion amplitude (sinusoids, bound and jitter) x 0.5",
    "motion_x1.5": "motion amplitude (sinusoids, bound and jitter) x 1.5",
    "noise": "Gaussian noise on the data, std 1 % of the largest value of a sinogram (training: none)",
    "unperturbed": "no motion",
    "phantoms": "Shepp-Logan-like phantoms of additive ellipses (a family outside the training generator)",
}
#: Data-set seed of the shifted sets (the study's is 0): other phantoms than the study's.
SHIFT_SEED = 1000
#: Noise of the ``noise`` shift relative to the largest value of the study's first test sinogram.
NOISE_FRACTION = 0.01


def shift_config(name: str, base: SimulationConfig, y_max: float) -> SimulationConfig:
    """The simulation of shift ``name`` (:data:`SHIFTS`) from the study's ``base``.

    ``y_max``: the largest value of a sinogram of the study (the scale of the added noise).

    Raises
    ------
    NanoctError
        For an unknown shift.
    """
    m = base.motion
    if name in ("motion_x0.5", "motion_x1.5"):
        f = 0.5 if name == "motion_x0.5" else 1.5
        motion = replace(
            m,
            max_shift=m.max_shift * f,
            amplitude_range=(m.amplitude_range[0] * f, m.amplitude_range[1] * f),
            jitter_std_mean=m.jitter_std_mean * f,
            jitter_std_std=m.jitter_std_std * f,
        )
        return replace(base, motion=motion)
    if name == "noise":
        return replace(base, noise_std=NOISE_FRACTION * y_max)
    if name == "unperturbed":
        return replace(base, perturbed=False)
    if name == "phantoms":
        return replace(base, phantoms="ellipses")
    raise NanoctError(f"unknown shift {name!r}; choose from {', '.join(SHIFTS)}")


def _scores(results: dict[str, Any], names: list[str], level: str) -> dict[str, dict[str, Any]]:
    """The rows of the shift table: per prediction the scores at ``level`` over all pixels."""
    rows = {}
    for name in names:
        r = results[name]
        u, e = r["uncertainty"]["all"], r["edge_baseline"]["all"]
        iv = u["intervals"].get(level, {})
        rows[name] = {
            "psnr_mean": r["psnr_mean"],
            "coverage": iv.get("coverage"),
            "coverage_by_width": iv.get("coverage_by_width"),
            "std_error_corr": u["std_error_corr"],
            "std_error_spearman": u["std_error_spearman"],
            "partial_corr_given_baseline": u["partial_corr_given_baseline"],
            "edge_corr": e["std_error_corr"],
            "fraction_flagged": (r.get("ood") or {}).get("fraction_flagged"),
        }
    return rows


def shift_study(
    study_dir: str | Path,
    preset: str = "tiny-parallel",
    *,
    shifts: tuple[str, ...] = tuple(SHIFTS),
    n: int = 20,
    level: str = "0.9",
    workers: int = 0,
    progress: bool = True,
) -> dict[str, Any]:
    """Score the sampling networks of a finished study on shifted test sets; writes ``<study>/shift/shift.{json,md}``.

    Parameters
    ----------
    study_dir : path
        Output directory of ``nanoct reproduce --preset preset`` (``data`` and ``runs`` below it).
    preset : str
        The study's preset.
    shifts : tuple of str
        Which of :data:`SHIFTS`.
    n : int
        Test images per shifted set.
    level : str
        Interval level whose coverage is tabulated.
    workers, progress
        As for :func:`nanoct.sim.generate.generate_dataset` and the reconstructions.

    Returns
    -------
    dict
        ``{shift: {prediction name: scores}}`` with ``"in_distribution"`` (the study's test split) first.

    Raises
    ------
    NanoctError
        If the study has no finished sampling run, or for an unknown shift.
    """
    root = Path(study_dir)
    study = preset_study(preset)
    setting = preset_setting(preset, True, root, ())
    data = DataStore.open(root / "data")
    runs = sorted(
        (p.name.split("-" + i)[0], i)
        for p in (root / "runs").glob("*")
        for i in setting.train_inputs
        if p.name.endswith("-" + i) and (p / "best.pt").is_file()
    )
    runs = [(m, i) for m, i in runs if model_class(m).has_uncertainty]
    if not runs:
        raise NanoctError(f"{root} has no finished run of an invertible network; run 'nanoct reproduce' first")
    for s in shifts:
        shift_config(s, SimulationConfig(), 1.0)  # rejects an unknown shift before any work
    names = [prediction_name(i, m) for m, i in runs]
    # the intervals of the study's predictions: fitted on its calibration set where it has one
    sampling_args = {"reconstruct_kwargs": study.sampling, "progress": progress}
    if study.n_calibration and (setting.calibration / "zarr.json").is_file():
        sampling_args["calibrate_on"] = setting.calibration
    for m, i in runs:  # the study's test split, checked for being out of distribution as the shifted sets are
        predict(data.path, root / "runs" / f"{m}-{i}", i, **sampling_args)
    data = DataStore.open(root / "data")
    test = data.indices("test")
    out = {"in_distribution": _scores(evaluate_store(data, "test", names), names, level)}
    base = SimulationConfig.from_dict(data.meta["simulation"])
    y_max = float(data.read_array("sinograms", [int(test[0])]).max())
    fan = {"workers": workers, "progress": progress}
    for s in shifts:
        path = root / "shift" / s
        store = generate_dataset(
            path,
            get_preset(preset),
            n,
            seed=SHIFT_SEED,
            config=shift_config(s, base, y_max),
            split_fractions=(0.0, 0.0, 1.0),
            **fan,
        )
        for i in sorted({i for _, i in runs}):
            method, params = setting.recons[i]
            reconstruct_dataset(path, method, params=params, name=i, **fan)
        for m, i in runs:
            predict(path, root / "runs" / f"{m}-{i}", i, **sampling_args)
        out[s] = _scores(evaluate_store(store, "test", names), names, level)
    payload = {"level": level, "n": n, "seed": SHIFT_SEED, "shifts": {k: SHIFTS[k] for k in shifts}, "results": out}
    (root / "shift").mkdir(exist_ok=True)
    atomic_write_text(root / "shift" / "shift.json", json.dumps(payload, indent=2))
    atomic_write_text(root / "shift" / "shift.md", format_shift_table(out, level))
    return out


def format_shift_table(results: dict[str, dict[str, dict[str, Any]]], level: str = "0.9") -> str:
    """Markdown table of :func:`shift_study`'s results: one row per (test set, prediction)."""

    def num(x: float | None, fmt: str) -> str:
        return "-" if x is None or x != x else format(x, fmt)

    lines = [
        f"| test set | prediction | PSNR [dB] | coverage at {level} [%] | width quintiles min / max [%] | corr "
        "| Spearman | partial corr. given edge | edge corr | OOD flagged [%] |",
        "|---" * 10 + "|",
    ]
    for shift, rows in results.items():
        for name, r in rows.items():
            q = r["coverage_by_width"]
            quint = "-" if not q else f"{100 * min(q):.1f} / {100 * max(q):.1f}"
            flagged = r["fraction_flagged"]
            lines.append(
                f"| {shift} | {name} | {r['psnr_mean']:.2f} | {num(r['coverage'] and 100 * r['coverage'], '.1f')} "
                f"| {quint} | {num(r['std_error_corr'], '.3f')} | {num(r['std_error_spearman'], '.3f')} "
                f"| {num(r['partial_corr_given_baseline'], '.3f')} | {num(r['edge_corr'], '.3f')} "
                f"| {num(None if flagged is None else 100 * flagged, '.0f')} |"
            )
    return "\n".join(lines) + "\n"
