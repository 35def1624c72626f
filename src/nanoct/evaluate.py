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

from .errors import NanoctError
from .fileio import atomic_write_text
from .metrics import summarize, uncertainty_summary
from .store import DataStore

__all__ = [
    "evaluate_store",
    "format_mixing",
    "format_table",
    "mixing_matrices",
    "parse_name",
    "write_report_tables",
]


def parse_name(name: str) -> tuple[str, str | None, str]:
    """Split a reconstruction name into (test input, model or None, training input)."""
    if "+" not in name:
        return name, None, name
    test_input, rest = name.split("+", 1)
    model, _, train_input = rest.partition("@")
    return test_input, model, train_input or test_input


def evaluate_store(store: DataStore, split: str = "test", names: list[str] | None = None) -> dict[str, dict[str, Any]]:
    """PSNR/SSIM (mean, std, n) of reconstructions over a split, plus uncertainty scores.

    ``names`` gives the reconstructions and their order (default: all present, sorted);
    those that do not cover the whole split are left out. Reconstructions with a pixel-wise
    std also get ``std_error_corr`` and ``calibration`` (:func:`nanoct.metrics.uncertainty_summary`).

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
    results: dict[str, dict[str, Any]] = {}
    for name in names or store.reconstruction_names():
        if not store.reconstruction_done(name, idx).all():
            continue
        recos = store.read_reconstruction(name, idx)
        results[name] = summarize(recos, gts)
        if store.has_uncertainty(name):
            results[name].update(uncertainty_summary(store.read_uncertainty(name, idx), recos, gts))
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
    uq = any("std_error_corr" in r for r in results.values())
    head = "| reconstruction | PSNR [dB] | SSIM | n |" + (
        " std/error corr | within 1/2/3 std (68/95/99.7 %) |" if uq else ""
    )
    lines += [head, "|---" * (head.count("|") - 1) + "|"]
    groups: dict[str | None, list[str]] = {}
    for name in results:
        groups.setdefault(parse_name(name)[1], []).append(name)
    for model in sorted(groups, key=lambda m: (m is not None, m or "")):
        if len(groups) > 1:
            label = "no post-processing" if model is None else f"+ {model}"
            lines.append(f"| **{label}** | | | |" + (" | |" if uq else ""))
        for name in groups[model]:
            r = results[name]
            psnr_text, ssim_text = _cell(r)
            row = f"| {name} | {psnr_text} | {ssim_text} | {r['n']} |"
            if uq:
                if "std_error_corr" in r:
                    obs = r["calibration"]["observed"]
                    within = " / ".join(f"{obs[k] * 100:.0f}" for k in ("1", "2", "3"))
                    row += f" {r['std_error_corr']:.3f} | {within} % |"
                else:
                    row += " | |"
            lines.append(row)
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
    store: DataStore, results: dict[str, dict[str, Any]], out_dir: str | os.PathLike[str], split: str = "test"
) -> tuple[Path, Path]:
    """Write ``evaluation.md`` and ``evaluation.json`` into ``out_dir``; returns their paths.

    The JSON has, per reconstruction name, ``psnr_mean``, ``psnr_std``, ``ssim_mean``,
    ``ssim_std``, ``n`` (and ``std_error_corr``, ``calibration`` where a std exists), and
    the input-mixing tables under ``"mixing"``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    g = store.geometry
    title = f"{g.kind} beam, N={g.n}, K={g.n_angles}, L={g.n_det}; split '{split}'"
    mixing = mixing_matrices(results)
    text = format_table(results, title) + ("\n" + format_mixing(mixing) if mixing else "")
    md, js = out / "evaluation.md", out / "evaluation.json"
    payload = {
        "split": split,
        "geometry": g.to_dict(),
        "simulation": store.meta.get("simulation"),
        "results": results,
        "mixing": mixing,
    }
    atomic_write_text(md, text)
    atomic_write_text(js, json.dumps(payload, indent=2))
    return md, js
