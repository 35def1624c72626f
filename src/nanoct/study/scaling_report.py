"""The data-scaling study's report: gains over the input against training-set size, and the
paper's conclusion checks at each size (Markdown, JSON and a figure)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ..core.names import prediction_name
from ..evaluation.conclusions import check_conclusions
from ..evaluation.evaluate import evaluate_store
from ..evaluation.paper import paper_value
from ..io.fileio import atomic_target, atomic_write_text
from ..io.store import DataStore
from .config import CONCLUSION_K
from .scaling_config import ScalingStudy, ScalingUnit, scaling_units

__all__ = ["scaling_points", "write_scaling_report"]

_NAMES = {"unet": "UNet", "ciunet-res": "CiUNetRes", "fbp": "FBP", "dremel": "Dremel", "resesop": "RESESOP"}


def scaling_points(study: ScalingStudy) -> list[tuple[int, int]]:
    """The study's points (training images, steps) in report order."""
    return [(k, study.steps) for k in study.sizes] + (
        [(max(study.sizes), study.steps * study.long_factor)] if study.long_seeds else []
    )


def _paper_gain(model: str, input_name: str, metric: str) -> float | None:
    row, base = paper_value("parallel", input_name, model), paper_value("parallel", input_name)
    if row is None or base is None:
        return None
    key = f"{metric}_mean"
    return float(getattr(row, key) - getattr(base, key))


def _point_values(
    scores: dict[str, Any], study: ScalingStudy, units: list[ScalingUnit]
) -> dict[str, dict[str, np.ndarray]]:
    """Per-image values of the inputs and, per network row, stacked over the point's measured seeds."""
    values = {i: {m: np.asarray(scores[i][f"{m}_values"]) for m in ("psnr", "ssim")} for i in study.inputs}
    for model in study.models:
        for i in study.inputs:
            rows = [u for u in units if u.model == model and u.input == i and u.name in scores]
            if rows:
                values[prediction_name(i, model)] = {
                    m: np.vstack([scores[u.name][f"{m}_values"] for u in rows]) for m in ("psnr", "ssim")
                }
    return values


def _summary(study: ScalingStudy, scores: dict[str, Any]) -> dict[str, Any]:
    """Gains per point, model and input (mean and std over seeds) and the conclusion checks per point."""
    units = scaling_units(study)
    points = []
    for k, steps in scaling_points(study):
        here = [u for u in units if u.n_train == k and u.steps == steps]
        gains: dict[str, Any] = {}
        for model in study.models:
            for i in study.inputs:
                rows = [u for u in here if u.model == model and u.input == i]
                entry: dict[str, Any] = {"planned": len(rows), "seeds": [u.seed for u in rows if u.name in scores]}
                for metric in ("psnr", "ssim"):
                    per_seed = [
                        scores[u.name][f"{metric}_mean"] - scores[i][f"{metric}_mean"] for u in rows if u.name in scores
                    ]
                    entry[metric] = per_seed
                    entry[f"{metric}_paper"] = _paper_gain(model, i, metric)
                gains[f"{i}+{model}"] = entry
        measured = [u for u in here if u.name in scores]
        checks = []
        if measured:
            checks = [
                {key: c[key] for key in ("id", "claim", "text", "verdict", "paper_verdict", "counts", "missing")}
                for c in check_conclusions(_point_values(scores, study, measured), "parallel", k=CONCLUSION_K)
                if c["verdict"] != "not applicable"
            ]
        points.append(
            {
                "n_train": k,
                "steps": steps,
                "units": len(here),
                "measured": len(measured),
                "gains": gains,
                "checks": checks,
            }
        )
    return {
        "points": points,
        "inputs": {i: {m: scores[i][f"{m}_mean"] for m in ("psnr", "ssim")} for i in study.inputs},
    }


def _log_summary(path: Path) -> tuple[float, float, int, int]:
    """(last train loss, best validation loss, its epoch, epochs) of a run's log."""
    import csv

    with open(path) as f:
        log = list(csv.DictReader(f))
    best = min(log, key=lambda r: float(r["val_loss"]))
    return float(log[-1]["train_loss"]), float(best["val_loss"]), int(best["epoch"]), len(log)


def _diagnostics(out: Path, study: ScalingStudy, scores: dict[str, Any]) -> list[str]:
    """Per point and row: last epoch's train loss, best validation loss and its epoch, mean over measured seeds.

    A train loss far below the validation loss points to too little data (over-fitting), both
    close and high to too little training or capacity.
    """
    points = scaling_points(study)
    head = " | ".join(f"{k:,} img, {steps} steps" for k, steps in points)
    lines = [
        f"| row | {head} |",
        "|---|" + "---|" * len(points),
    ]
    units = scaling_units(study)
    for model in study.models:
        for i in study.inputs:
            cells = []
            for k, steps in points:
                rows = [
                    _log_summary(out / "runs" / u.run / "log.csv")
                    for u in units
                    if (u.model, u.input, u.n_train, u.steps) == (model, i, k, steps) and u.name in scores
                ]
                if rows:
                    t, v, e, n = (float(np.mean([r[j] for r in rows])) for j in range(4))
                    cells.append(f"{t:.4g} / {v:.4g} (epoch {e:.0f} of {n:.0f})")
                else:
                    cells.append("–")
            lines.append(f"| {_NAMES[i]} + {_NAMES[model]} | {' | '.join(cells)} |")
    return lines


def _fmt(values: list[float], digits: int) -> str:
    if not values:
        return "–"
    mean = float(np.mean(values))
    spread = f" ± {np.std(values, ddof=1):.{digits}f}" if len(values) > 1 else ""
    return f"{mean:+.{digits}f}{spread} ({len(values)})"


def _gain_table(summary: dict[str, Any], study: ScalingStudy) -> list[str]:
    points = summary["points"]
    head = " | ".join(f"{p['n_train']:,} img, {p['steps']} steps" for p in points)
    lines = [
        f"| row | metric | {head} | paper |",
        "|---|---|" + "---|" * len(points) + "---|",
    ]
    for model in study.models:
        for i in study.inputs:
            for metric, digits, unit in (("psnr", 2, " dB"), ("ssim", 3, "")):
                cells = " | ".join(_fmt(p["gains"][f"{i}+{model}"][metric], digits) for p in points)
                paper = points[0]["gains"][f"{i}+{model}"][f"{metric}_paper"]
                paper_cell = "–" if paper is None else f"{paper:+.{digits}f}"
                lines.append(
                    f"| {_NAMES[i]} + {_NAMES[model]} | {metric.upper()} gain{unit} | {cells} | {paper_cell} |"
                )
    return lines


def _check_table(summary: dict[str, Any]) -> list[str]:
    points = summary["points"]
    texts: dict[str, str] = {}
    paper: dict[str, str] = {}
    for p in points:
        for c in p["checks"]:
            texts.setdefault(
                c["claim"], c["text"] + (f" (rows absent: {', '.join(c['missing'])})" if c["missing"] else "")
            )
            paper[c["claim"]] = c["paper_verdict"]
    head = " | ".join(f"{p['n_train']:,} img, {p['steps']} steps" for p in points)
    lines = [f"| conclusion | {head} | paper's table |", "|---|" + "---|" * len(points) + "---|"]
    for claim, text in texts.items():
        cells = []
        for p in points:
            c = next((c for c in p["checks"] if c["claim"] == claim), None)
            cells.append("–" if c is None else c["verdict"])
        lines.append(f"| {text} | {' | '.join(cells)} | {paper[claim]} |")
    return lines


def _figure(summary: dict[str, Any], study: ScalingStudy, path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5 * len(study.models), 3.8), layout="constrained")
    axes = fig.subplots(1, len(study.models), squeeze=False)[0]
    fixed = [p for p in summary["points"] if p["steps"] == study.steps]
    long = [p for p in summary["points"] if p["steps"] != study.steps]
    for ax, model in zip(axes, study.models):
        for j, i in enumerate(study.inputs):
            color = f"C{j}"
            xs, ys, es = [], [], []
            for p in fixed:
                g = p["gains"][f"{i}+{model}"]["psnr"]
                if g:
                    xs.append(p["n_train"])
                    ys.append(np.mean(g))
                    es.append(np.std(g, ddof=1) if len(g) > 1 else 0.0)
            if xs:
                ax.errorbar(xs, ys, yerr=es, marker="o", color=color, capsize=3, label=_NAMES[i])
            for p in long:
                g = p["gains"][f"{i}+{model}"]["psnr"]
                if g:
                    ax.plot([p["n_train"]], [np.mean(g)], marker="*", markersize=11, color=color, linestyle="none")
            paper = fixed[0]["gains"][f"{i}+{model}"]["psnr_paper"] if fixed else None
            if paper is not None:
                ax.axhline(paper, color=color, linestyle=":", linewidth=1)
        ax.axhline(0.0, color="k", linewidth=0.6)
        ax.set_xscale("log")
        ax.set_xticks(list(study.sizes), [str(k) for k in study.sizes])
        ax.set_xlabel(f"training images ({study.steps} steps; star: {study.long_factor}x steps)")
        ax.set_ylabel("PSNR gain over input [dB]")
        ax.set_title(f"{_NAMES.get(model, model)} (dotted: paper)")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    with atomic_target(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")


def write_scaling_report(out: str | Path, study: ScalingStudy) -> Path:
    """Evaluate every complete unit on the test split and write ``report.md``, ``report.json`` and
    ``scaling.png`` in ``out``; returns the Markdown report's path.

    A point whose units are not all complete is reported with the seeds it has and marked partial.
    """
    out = Path(out)
    store = DataStore.open(out / "data")
    units = scaling_units(study)
    scores = evaluate_store(store, "test", names=list(study.inputs) + [u.name for u in units])
    summary = _summary(study, scores)
    done = sum(p["measured"] for p in summary["points"])
    total = sum(p["units"] for p in summary["points"])
    seconds = json.loads((out / "seconds.json").read_text()) if (out / "seconds.json").exists() else {}
    summary |= {"study": json.loads((out / "study.json").read_text()), "seconds": seconds, "complete": done == total}
    atomic_write_text(out / "report.json", json.dumps(summary, indent=2))
    _figure(summary, study, out / "scaling.png")
    status = "complete" if done == total else f"PARTIAL: {done} of {total} units measured"
    inputs = ", ".join(f"{_NAMES[i]} {v['psnr']:.2f} dB / {v['ssim']:.3f}" for i, v in summary["inputs"].items())
    text = [
        f"# Data-scaling study ({study.preset}; {status})",
        "",
        f"Test split: {study.n_test} images, validation {study.n_val}, the same at every size; inputs: {inputs}.",
        f"Every run: {study.steps} optimiser steps (batch 16), {study.scheduler} learning-rate schedule over its "
        f"epochs; the last column: {study.long_factor}x the steps at {max(study.sizes):,} images.",
        "",
        "## Gain over the input (mean ± std over training seeds (seeds measured))",
        "",
        *_gain_table(summary, study),
        "",
        "## The paper's conclusions (parallel setting) at each size",
        "",
        f"A comparison holds when its paired mean difference over test images and seeds exceeds {CONCLUSION_K:g} "
        "standard errors; 'best row' conclusions compare only the rows this study has.",
        "",
        *_check_table(summary),
        "",
        "![PSNR gain against training-set size](scaling.png)",
        "",
        "## Training: last epoch's train loss / best validation loss (its epoch of the run's epochs)",
        "",
        "Mean over the measured seeds; UNet: MSE, CiUNetRes: NLL in bits per pixel. A train loss far below the "
        "validation loss means too little data for the network (over-fitting); both close and high, too little "
        "training or capacity.",
        "",
        *_diagnostics(out, study, scores),
        "",
        "Measured wall time (s, summed over sittings): "
        + ", ".join(f"{k} {v:.0f}" for k, v in sorted(seconds.items()) if not k.startswith("unit/"))
        + f"; units {sum(v for k, v in seconds.items() if k.startswith('unit/')):.0f}.",
    ]
    return atomic_write_text(out / "report.md", "\n".join(text) + "\n")
