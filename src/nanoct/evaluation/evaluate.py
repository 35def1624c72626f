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
from ..core.names import parse_name, setting_key
from ..io.fileio import atomic_write_text
from ..io.provenance import environment_info
from ..io.store import DataStore
from .conclusions import format_conclusions
from .conformal import half_width_of
from .metrics import EDGE_SIGMA, edge_std, summarize, truth_support, uncertainty_summary

__all__ = [
    "GAUGE_NOTE",
    "evaluate_store",
    "format_mixing",
    "format_table",
    "format_uncertainty_table",
    "mixing_matrices",
    "per_image_values",
    "store_setting",
    "uncertainty_scores",
    "write_report_tables",
]


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
        The stored std (``uncertainty/<name>``), reconstructions (the network's mean) and ground truths.
    calibration : dict, optional
        The interval calibration stored with the prediction (:func:`nanoct.learn.calibration.fit_intervals`):
        ``levels`` (each level's width ``map``, ``multiplier``, ``guaranteed_coverage``,
        ``rcps_multiplier``: half-width :func:`nanoct.evaluation.conformal.half_width_of`), ``delta``,
        ``edge_sigma`` and ``edge_multipliers``; without it no intervals are scored.
    support : bool array (n, H, W), optional
        The object's support (default :func:`nanoct.evaluation.metrics.truth_support` of ``gts``: a
        phantom's ``gt > 0`` dilated, a measured reference's smoothed level above a fraction of its
        own 99th percentile).

    Returns
    -------
    dict
        ``std_error_corr`` (all pixels), ``uncertainty`` = {``all``, ``support``} (the std's
        :func:`nanoct.evaluation.metrics.uncertainty_summary`, with the partial correlation given the
        edge baseline), ``edge_baseline`` = {``sigma``, ``all``, ``support``} and ``guarantee`` =
        {``delta``, ``levels`` = {level key: {``multiplier``, ``guaranteed_coverage``, ``rcps_multiplier``}}} (the
        validation split's, empty without a calibration); where some of ``gts`` are measured
        references (with a negative value), ``measured_references`` (how many) and ``references`` (of how many).
    """
    cal = calibration or {}
    support = truth_support(gts) if support is None else support
    sigma = float(cal.get("edge_sigma", EDGE_SIGMA))
    edges = edge_std(recos, sigma)
    levels = cal.get("levels") or {}

    def both(std: np.ndarray, entries: dict[str, dict[str, Any]], edge: np.ndarray | None) -> dict[str, Any]:
        half = {k: half_width_of(std, v, image=recos) for k, v in entries.items()}
        return {
            region: uncertainty_summary(std, recos, gts, half_widths=half, baseline=edge, mask=mask)
            for region, mask in (("all", None), ("support", support))
        }

    own = both(stds, levels, edges)
    edge_entries = {k: {"multiplier": q} for k, q in (cal.get("edge_multipliers") or {}).items()}
    guarantee = {
        k: {"multiplier": v["multiplier"], "guaranteed_coverage": v["guaranteed_coverage"]}
        | {"rcps_multiplier": v["rcps_multiplier"]}
        for k, v in levels.items()
    }
    out = {
        "std_error_corr": own["all"]["std_error_corr"],
        "uncertainty": own,
        "edge_baseline": {"sigma": sigma, **both(edges, edge_entries, None)},
        "guarantee": {"delta": cal.get("delta"), "levels": guarantee},
    }
    lows = np.asarray(gts).reshape(-1, *np.shape(gts)[-2:]).min(axis=(1, 2))
    measured = int((lows < 0).sum())
    return out | ({"measured_references": measured, "references": int(lows.size)} if measured else {})


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
    std also get :func:`uncertainty_scores` of the stored std (the std's own scores and the edge
    baseline's) and, where predict checked them, ``ood``: the split's samples it flagged as out
    of distribution (``flagged``, ``fraction_flagged``, ``alpha``).

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
    from ..sim.matched import reference_view

    gts = store.read_phantoms(idx)
    support = truth_support(gts, known=reference_view(store.geometry, gts))
    results: dict[str, dict[str, Any]] = {}
    for name in names or store.reconstruction_names():
        if not store.reconstruction_done(name, idx).all():
            continue
        recos = store.read_reconstruction(name, idx)
        results[name] = summarize(recos, gts)
        if store.has_uncertainty(name):
            cal = store.reconstruction_params(name).get("calibration")
            stds = store.read_uncertainty(name, idx)
            results[name].update(uncertainty_scores(stds, recos, gts, cal, support))
            ood = store.reconstruction_note(name, "ood")
            if ood is not None:
                flagged = set(ood["flagged"])
                results[name]["ood"] = {
                    "alpha": ood["alpha"],
                    "flagged": sorted(int(i) for i in idx if int(i) in flagged),
                    "fraction_flagged": float(np.mean([int(i) in flagged for i in idx])),
                }
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


def _cell(r: dict[str, Any], gauge: str = "") -> tuple[str, str]:
    """``mean ± std`` of PSNR and SSIM; ``gauge="_registered"`` for the registered scores (a dash where absent)."""
    if f"psnr{gauge}_mean" not in r:
        return "–", "–"
    p, s = f"psnr{gauge}", f"ssim{gauge}"
    return f"{r[p + '_mean']:.2f} ± {r[p + '_std']:.2f}", f"{r[s + '_mean']:.3f} ± {r[s + '_std']:.3f}"


#: What the columns of :func:`format_table` measure.
GAUGE_NOTE = (
    "PSNR, SSIM: the images as reconstructed (the paper's convention; data range max - min of the ground truth). "
    "Registered: the same after the best sub-pixel translation of each image onto its ground truth (cross-"
    "correlation up-sampled 20x, Fourier shift; a translation common to all views is not fixed by the data); "
    "shift: the mean length of that translation in pixels."
)


def format_table(results: dict[str, dict[str, Any]], title: str = "") -> str:
    """Markdown table like the paper's: first reconstructions, then one block per model.

    Each row has the paper's scores (images as reconstructed) and the registered ones
    (:func:`~nanoct.evaluation.metrics.register`), with a note saying which is which.
    """
    lines = [f"### {title}", ""] if title else []
    lines += [
        "| reconstruction | PSNR [dB] | SSIM | PSNR registered [dB] | SSIM registered | shift [px] | n |",
        "|---|---|---|---|---|---|---|",
    ]
    groups: dict[str | None, list[str]] = {}
    for name in results:
        groups.setdefault(parse_name(name)[1], []).append(name)
    for model in sorted(groups, key=lambda m: (m is not None, m or "")):
        if len(groups) > 1:
            label = "no post-processing" if model is None else f"+ {model}"
            lines.append(f"| **{label}** | | | |")
        for name in groups[model]:
            r = results[name]
            cells = [*_cell(r), *_cell(r, "_registered"), _num(r.get("shift_mean"), ".2f")]
            lines.append(f"| {name} | {' | '.join(cells)} | {r['n']} |")
    return "\n".join(lines) + "\n\n" + GAUGE_NOTE + "\n"


def _num(x: float | None, fmt: str = ".3f") -> str:
    return "-" if x is None or x != x else format(x, fmt)


def _pct(x: float | None) -> str:
    return "-" if x is None or x != x else f"{100 * x:.1f}"


def format_uncertainty_table(results: dict[str, dict[str, Any]], title: str = "", level: str = "0.9") -> str:
    """Markdown tables of the uncertainty scores: two rows (all pixels, support) per reconstruction with a std.

    The first table scores the std's ranking next to the edge baseline's (Pearson and Spearman
    correlation with |error|, partial correlation given the edge baseline, AUSE / random); the
    second the calibrated intervals of each level (coverage, the validation guarantee, mean
    half-width, the smallest and largest coverage of the width quintiles, spread of per-image
    coverage); the edge baseline's coverage at ``level`` for comparison. Empty string when no
    result has a std.
    """
    names = [n for n, r in results.items() if "uncertainty" in r]
    if not names:
        return ""
    lines = [f"### {title}", ""] if title else []
    lines += [
        "| reconstruction | pixels | corr | Spearman | partial corr. given edge | AUSE / random (ratio) "
        "| edge: corr | edge: Spearman | edge: AUSE / random (ratio) | OOD flagged |",
        "|---" * 10 + "|",
    ]
    for name in names:
        r, edge = results[name]["uncertainty"], results[name]["edge_baseline"]
        ood = results[name].get("ood")
        flagged = "-" if ood is None else f"{len(ood['flagged'])} ({_pct(ood['fraction_flagged'])} %)"
        for region in ("all", "support"):
            u, e = r[region], edge[region]
            lines.append(
                f"| {name} | {region} | {_num(u['std_error_corr'])} | {_num(u['std_error_spearman'])} "
                f"| {_num(u['partial_corr_given_baseline'])} "
                f"| {_num(u['ause'])} / {_num(u['ause_random'])} ({_num(u['ause_ratio'], '.2f')}) "
                f"| {_num(e['std_error_corr'])} | {_num(e['std_error_spearman'])} "
                f"| {_num(e['ause'])} / {_num(e['ause_random'])} ({_num(e['ause_ratio'], '.2f')}) | {flagged} |"
            )
    lines += [
        "",
        "| reconstruction | pixels | level | coverage [%] | guaranteed (cal.) [%] | mean half-width | width/error corr "
        "| width quintiles: min / max coverage [%] | per image: min / max [%] (std) "
        f"| edge at {level}: coverage [%] | edge: quintiles min / max [%] |",
        "|---" * 11 + "|",
    ]
    for name in names:
        r, edge, g = results[name]["uncertainty"], results[name]["edge_baseline"], results[name]["guarantee"]
        for region in ("all", "support"):
            e = edge[region]["intervals"].get(level)
            e_cov = "-" if e is None else _pct(e["coverage"])
            e_q = "-" if e is None else f"{_pct(min(e['coverage_by_width']))} / {_pct(max(e['coverage_by_width']))}"
            for key, iv in r[region]["intervals"].items():
                gc = g["levels"].get(key, {}).get("guaranteed_coverage")
                q, im = iv["coverage_by_width"], iv["image_coverage"]
                lines.append(
                    f"| {name} | {region} | {key} | {_pct(iv['coverage'])} | {_pct(gc) if region == 'all' else ''} "
                    f"| {iv['mean_half_width']:.3g} | {_num(iv['width_error_corr'])} | {_pct(min(q))} / {_pct(max(q))} "
                    f"| {_pct(im['min'])} / {_pct(im['max'])} ({_pct(im['std'])}) "
                    f"| {e_cov if key == level else ''} | {e_q if key == level else ''} |"
                )
    delta = next((results[n]["guarantee"]["delta"] for n in names if results[n]["guarantee"]["delta"]), None)
    sigma = results[names[0]]["edge_baseline"]["sigma"]
    lines += [
        "",
        "All scores are computed on the stored std (`uncertainty/<name>`) and the intervals mean +- multiplier x "
        "g(stored std), g the level's quantile of |error| given the std (strictly increasing, one per region: "
        "background, object) and one multiplier per level and group (the background and the five std fifths of "
        "the object's support found from the network's mean) by split conformal prediction, fitted on the "
        "validation split of the data set or of a calibration set apart from it (`predict --calibrate-on`; the "
        "study's at tiny scale). "
        f"Guaranteed: the per-image coverage that holds with probability {1 - (delta or 0.1):.0%} "
        "(Hoeffding-Bentkus bound over the calibration images). Partial corr.: Pearson correlation of the std "
        "with |error| given the edge baseline. AUSE: area between the sparsification curve (mean absolute "
        "error of the pixels left after removing those of largest std) and the oracle's, normalised by the MAE "
        "of all pixels; random = the area of removing pixels in random order. Edge: Gaussian(sigma = "
        f"{sigma:g} px)-smoothed Sobel magnitude of the mean, its multipliers fitted the same way. Support: "
        "ground truth > 0 dilated by 2 px. Conventions: docs/uncertainty.md.",
    ]
    measured = max((results[n].get("measured_references", 0), results[n].get("references", 0)) for n in names)
    if measured[0]:
        lines[-1] += (
            f" {measured[0]} of the {measured[1]} references are measured (reconstructions, with negative values): "
            "their support is the reference smoothed above a fraction of its 99th percentile in the field of view, "
            "dilated by 2 px (nanoct.evaluation.metrics.truth_support)."
        )
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
    ``ssim_std``, ``n``, ``psnr_values``, ``ssim_values`` (per image, split order: the images
    as reconstructed, the paper's convention), the same after registration
    (``psnr_registered_mean``, ..., ``ssim_registered_values``, ``shift_values``,
    ``shift_mean``: :func:`~nanoct.evaluation.metrics.summarize`; and where a
    std exists ``std_error_corr``, ``uncertainty`` and ``edge_baseline``, see
    :func:`uncertainty_scores`), the input-mixing tables under ``"mixing"``, the paper's
    setting under ``"setting"``, the conclusion checks
    (:func:`nanoct.evaluation.conclusions.check_conclusions`) under ``"conclusions"`` and
    :func:`nanoct.io.provenance.environment_info` under ``"environment"``. The Markdown shows the
    conclusion checks only when at least one is applicable (a store with none of their rows, e.g. a
    set of measured pairs with Dremel and one network, has no such section).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    g = store.geometry
    title = f"{g.kind} beam, N={g.n}, K={g.n_angles}, L={g.n_det}; split '{split}'"
    mixing = mixing_matrices(results)
    uq = format_uncertainty_table(results, f"Uncertainty, split '{split}'")
    text = format_table(results, title) + ("\n" + uq if uq else "") + ("\n" + format_mixing(mixing) if mixing else "")
    if any(c["verdict"] != "not applicable" for c in conclusions or []):  # none: the store has none of their rows
        text += f"\n### The paper's conclusions ({setting})\n\n" + format_conclusions(conclusions)
    md, js = out / "evaluation.md", out / "evaluation.json"
    payload = {
        "split": split,
        "geometry": g.to_dict(),
        "simulation": store.meta.get("simulation"),
        "results": results,
        "gauge": {"plain": "images as reconstructed (the paper's convention)", "registered": GAUGE_NOTE},
        "mixing": mixing,
        "setting": setting,
        "conclusions": conclusions or [],
        "environment": environment_info(),
    }
    atomic_write_text(md, text)
    atomic_write_text(js, json.dumps(payload, indent=2))
    return md, js
