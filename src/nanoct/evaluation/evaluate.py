"""Evaluation of the reconstructions in a store: the paper's tables as Markdown and JSON.

Reconstruction names follow one scheme:

* ``<method>``: a first reconstruction (``fbp``, ``dremel``, ``resesop``, ``resesop_eta0.8``);
* ``<input>+<model>``: ``<input>`` post-processed by ``<model>`` trained on that input;
* ``<input>+<model>@<train_input>``: the same model trained on another input (input mixing).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from ..io.fileio import atomic_write_text
from ..io.provenance import environment_info
from ..io.store import DataStore
from ..names import parse_name, setting_key
from .conclusions import format_conclusions
from .metrics import EDGE_SIGMA, edge_std, raw_std, summarize, support_mask, uncertainty_summary

__all__ = [
    "evaluate_store",
    "format_mixing",
    "format_table",
    "format_uncertainty_table",
    "mixing_matrices",
    "per_image_values",
    "read_std",
    "store_setting",
    "uncertainty_scores",
    "write_report_tables",
]


def read_std(
    store: DataStore, name: str, indices: np.ndarray, recos: np.ndarray | None = None
) -> tuple[np.ndarray, dict[str, Any]]:
    """Raw (uncalibrated) std of reconstruction ``name`` and the calibration stored with it.

    :func:`nanoct.learn.predict.predict` stores the calibrated std (the raw std through the
    map ``std_map`` of each pixel's predicted value, strictly increasing in the std,
    :func:`nanoct.evaluation.metrics.apply_std_map`) and records ``{"std_map", "scale", "edge_scale",
    "edge_sigma", ...}`` under ``calibration`` in the parameters of the result; the raw std is
    recovered by inverting the map (:func:`nanoct.evaluation.metrics.invert_std_map`, with the stored
    reconstruction as the values). A result calibrated by the one factor
    only (no ``std_map`` recorded) stores ``scale * raw``: raw = stored / scale. Without a calibration
    the stored std is the raw one and the returned dict is empty. ``recos``: the reconstructions
    ``name`` at ``indices`` if the caller has read them already (else they are read).
    """
    cal = dict(store.reconstruction_params(name).get("calibration") or {})
    recos = store.read_reconstruction(name, indices) if recos is None else recos
    return raw_std(store.read_uncertainty(name, indices), cal, recos), cal


def uncertainty_scores(
    stds: np.ndarray,
    recos: np.ndarray,
    gts: np.ndarray,
    calibration: dict[str, Any] | None = None,
    support: np.ndarray | None = None,
) -> dict[str, Any]:
    """Uncertainty scores of one reconstruction and of the edge baseline, over all pixels and the support.

    Parameters
    ----------
    stds, recos, gts : array (n, H, W)
        Raw std, reconstructions (the network's mean) and ground truths.
    calibration : dict, optional
        ``std_map`` and ``scale`` of the std and ``edge_scale`` / ``edge_sigma`` of the edge
        baseline, fitted on validation data (:mod:`nanoct.learn.calibration`); without them the
        scaled and calibrated coverages are None. The edge baseline is calibrated by its one
        factor only.
    support : bool array (n, H, W), optional
        The object's support (default :func:`nanoct.evaluation.metrics.support_mask` of ``gts``).

    Returns
    -------
    dict
        ``std_error_corr`` (all pixels), ``uncertainty`` = {``all``, ``support``} and
        ``edge_baseline`` = {``sigma``, ``scale``, ``all``, ``support``}, each region a
        :func:`nanoct.evaluation.metrics.uncertainty_summary`.
    """
    cal = calibration or {}
    support = support_mask(gts) if support is None else support
    sigma = float(cal.get("edge_sigma", EDGE_SIGMA))
    edges = edge_std(recos, sigma)

    def both(std: np.ndarray, scale: float | None, std_map: dict[str, Any] | None = None) -> dict[str, Any]:
        return {
            "all": uncertainty_summary(std, recos, gts, scale=scale, std_map=std_map),
            "support": uncertainty_summary(std, recos, gts, scale=scale, std_map=std_map, mask=support),
        }

    own = both(stds, cal.get("scale"), cal.get("std_map"))
    return {
        "std_error_corr": own["all"]["std_error_corr"],
        "uncertainty": own,
        "edge_baseline": {"sigma": sigma, "scale": cal.get("edge_scale"), **both(edges, cal.get("edge_scale"))},
    }


def per_image_values(results: dict[str, dict[str, Any]]) -> dict[str, dict[str, np.ndarray]]:
    """``{name: {"psnr": values, "ssim": values}}`` per image: the input of the conclusion checks."""
    return {
        name: {m: np.asarray(r[f"{m}_values"], dtype=np.float64) for m in ("psnr", "ssim")}
        for name, r in results.items()
        if "psnr_values" in r
    }


def store_setting(store: DataStore) -> str | None:
    """Which of the paper's settings a store's data correspond to (``parallel``, ``fan``, ``unperturbed``).

    Fan beam without motion is not one of the paper's settings and gives None.
    """
    perturbed = bool((store.meta.get("simulation") or {}).get("perturbed", True))
    return setting_key(store.geometry.kind, perturbed)


def evaluate_store(store: DataStore, split: str = "test", names: list[str] | None = None) -> dict[str, dict[str, Any]]:
    """PSNR/SSIM (mean, std, n, and per image) of reconstructions over a split, plus uncertainty scores.

    Per-image values (``psnr_values``, ``ssim_values``) follow the split's index order, the same
    for every reconstruction, so rows can be compared image by image (paired differences).

    ``names`` gives the reconstructions and their order (default: all present, sorted);
    those that do not cover the whole split are left out. Reconstructions with a pixel-wise
    std also get :func:`uncertainty_scores` (the std's own scores and the edge baseline's).

    Raises
    ------
    NanoctError
        If the split is empty.
    """
    idx = store.indices(split)
    if idx.size == 0:
        raise NanoctError(
            f"the data set at {store.path} has no '{split}' samples; generate more samples or change "
            "the split fractions"
        )
    gts = store.read_phantoms(idx)
    support = support_mask(gts)
    results: dict[str, dict[str, Any]] = {}
    for name in names or store.reconstruction_names():
        if not store.reconstruction_done(name, idx).all():
            continue
        recos = store.read_reconstruction(name, idx)
        results[name] = summarize(recos, gts)
        if store.has_uncertainty(name):
            raw, cal = read_std(store, name, idx, recos)
            results[name].update(uncertainty_scores(raw, recos, gts, cal, support))
    return results


def mixing_matrices(results: dict[str, dict[str, Any]]) -> dict[str, dict[str, dict[str, dict[str, Any]]]]:
    """Input-mixing tables: ``{model: {train_input: {test_input: scores}}}``.

    Only models applied to at least two inputs, or trained on at least two, appear.
    """
    out: dict[str, dict[str, dict[str, dict[str, Any]]]] = {}
    for name, scores in results.items():
        test_input, model, train_input = parse_name(name)
        if model is not None:
            out.setdefault(model, {}).setdefault(train_input, {})[test_input] = scores
    return {m: rows for m, rows in out.items() if any(test != train for train, cols in rows.items() for test in cols)}


def _cell(r: dict[str, Any]) -> tuple[str, str]:
    return f"{r['psnr_mean']:.2f} ± {r['psnr_std']:.2f}", f"{r['ssim_mean']:.3f} ± {r['ssim_std']:.3f}"


def format_table(results: dict[str, dict[str, Any]], title: str = "") -> str:
    """Markdown table like the paper's: first reconstructions, then one block per model."""
    lines = [f"### {title}", ""] if title else []
    lines += ["| reconstruction | PSNR [dB] | SSIM | n |", "|---|---|---|---|"]
    groups: dict[str | None, list[str]] = {}
    for name in results:
        groups.setdefault(parse_name(name)[1], []).append(name)
    for model in sorted(groups, key=lambda m: (m is not None, m or "")):
        if len(groups) > 1:
            label = "no post-processing" if model is None else f"+ {model}"
            lines.append(f"| **{label}** | | | |")
        for name in groups[model]:
            r = results[name]
            psnr_text, ssim_text = _cell(r)
            lines.append(f"| {name} | {psnr_text} | {ssim_text} | {r['n']} |")
    return "\n".join(lines) + "\n"


def _percent(cov: dict[str, float] | None) -> str:
    return "-" if cov is None else " / ".join(f"{cov[k] * 100:.0f}" for k in ("1", "2", "3"))


def _num(x: float | None, fmt: str = ".3f") -> str:
    return "-" if x is None or x != x else format(x, fmt)


def format_uncertainty_table(results: dict[str, dict[str, Any]], title: str = "") -> str:
    """Markdown table of the uncertainty scores: two rows (all pixels, support) per reconstruction with a std.

    Columns: std/error correlation; coverage within 1/2/3 std side by side for the raw std, the
    one-factor std (with its factor s) and the calibrated std (the map predict applied); AUSE
    next to the random order's; the same for the edge baseline (coverage after its validation
    scaling). Empty string when no result has a std.
    """
    names = [n for n, r in results.items() if "uncertainty" in r]
    if not names:
        return ""
    lines = [f"### {title}", ""] if title else []
    lines += [
        "| reconstruction | pixels | std/error corr | within 1/2/3 std, raw [%] | one factor [%] | factor s "
        "| calibrated (map) [%] | AUSE / random (ratio) | edge: corr | edge: within 1/2/3 [%] "
        "| edge: AUSE / random (ratio) |",
        "|---" * 11 + "|",
    ]
    for name in names:
        r, edge = results[name]["uncertainty"], results[name]["edge_baseline"]
        for region in ("all", "support"):
            u, e = r[region], edge[region]
            lines.append(
                f"| {name} | {region} | {_num(u['std_error_corr'])} | {_percent(u['coverage']['raw'])} "
                f"| {_percent(u['coverage'].get('scaled'))} | {_num(u['scale'], '.3g')} "
                f"| {_percent(u['coverage']['calibrated'])} "
                f"| {_num(u['ause'])} / {_num(u['ause_random'])} ({_num(u['ause_ratio'], '.2f')}) "
                f"| {_num(e['std_error_corr'])} | {_percent(e['coverage']['calibrated'])} "
                f"| {_num(e['ause'])} / {_num(e['ause_random'])} ({_num(e['ause_ratio'], '.2f')}) |"
            )
    sigma = results[names[0]]["edge_baseline"]["sigma"]
    lines += [
        "",
        "A calibrated Gaussian std has 68 / 95 / 100 % (68.3 / 95.4 / 99.7) of the pixels within 1 / 2 / 3 std. "
        "One factor = raw std times s; calibrated = the raw std through the increasing map from raw to "
        "calibrated std that predict applies (fitted per bin of the raw std at 1, 2 and 3 std); both fitted "
        "on the validation split. AUSE: area between the sparsification "
        "curve (mean absolute error of the pixels left after removing those of largest std) and the oracle's, "
        "normalised by the MAE of all pixels; random = the area of removing pixels in random order; ratio < 0.5 "
        f"is 'below random by >= 50 %'. Edge: Gaussian(sigma = {sigma:g} px)-smoothed Sobel magnitude of the "
        "mean, scaled on the validation split. Support: ground truth > 0 dilated by 2 px. Conventions: "
        "docs/uncertainty.md.",
    ]
    return "\n".join(lines) + "\n"


def format_mixing(mixing: dict[str, dict[str, dict[str, dict[str, Any]]]]) -> str:
    """Markdown input-mixing tables (rows: training input, columns: test input)."""
    blocks = []
    for model, rows in mixing.items():
        cols = sorted({c for r in rows.values() for c in r})
        for metric, i in (("PSNR [dB]", 0), ("SSIM", 1)):
            lines = [f"### {model}: {metric}, rows = trained on, columns = applied to", ""]
            lines += ["| trained on \\ applied to | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
            for train in sorted(rows):
                cells = [_cell(rows[train][c])[i] if c in rows[train] else "" for c in cols]
                lines.append(f"| {train} | " + " | ".join(cells) + " |")
            blocks.append("\n".join(lines) + "\n")
    return "\n".join(blocks)


def write_report_tables(
    store: DataStore,
    results: dict[str, dict[str, Any]],
    out_dir: str | os.PathLike[str],
    split: str = "test",
    conclusions: list[dict[str, Any]] | None = None,
    setting: str | None = None,
) -> tuple[Path, Path]:
    """Write ``evaluation.md`` and ``evaluation.json`` into ``out_dir``; returns their paths.

    The JSON has, per reconstruction name, ``psnr_mean``, ``psnr_std``, ``ssim_mean``,
    ``ssim_std``, ``n``, ``psnr_values``, ``ssim_values`` (per image, split order; and where a
    std exists ``std_error_corr``, ``uncertainty`` and ``edge_baseline``, see
    :func:`uncertainty_scores`), the input-mixing tables under ``"mixing"``, the paper's
    setting under ``"setting"``, the conclusion checks
    (:func:`nanoct.evaluation.conclusions.check_conclusions`) under ``"conclusions"`` and
    :func:`nanoct.io.provenance.environment_info` under ``"environment"``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    g = store.geometry
    title = f"{g.kind} beam, N={g.n}, K={g.n_angles}, L={g.n_det}; split '{split}'"
    mixing = mixing_matrices(results)
    uq = format_uncertainty_table(results, f"Uncertainty, split '{split}'")
    text = format_table(results, title) + ("\n" + uq if uq else "") + ("\n" + format_mixing(mixing) if mixing else "")
    if conclusions:
        text += f"\n### The paper's conclusions ({setting})\n\n" + format_conclusions(conclusions)
    md, js = out / "evaluation.md", out / "evaluation.json"
    payload = {
        "split": split,
        "geometry": g.to_dict(),
        "simulation": store.meta.get("simulation"),
        "results": results,
        "mixing": mixing,
        "setting": setting,
        "conclusions": conclusions or [],
        "environment": environment_info(),
    }
    atomic_write_text(md, text)
    atomic_write_text(js, json.dumps(payload, indent=2))
    return md, js
