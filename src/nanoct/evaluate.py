"""Evaluation of the reconstructions in a store: PSNR/SSIM tables as Markdown and JSON."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from .errors import NanoctError
from .metrics import summarize
from .store import DataStore

__all__ = ["evaluate_store", "format_table", "write_report_tables"]


def evaluate_store(store: DataStore, split: str = "test", names: list[str] | None = None) -> dict[str, dict[str, Any]]:
    """PSNR/SSIM (mean, std, n) of reconstructions over a split.

    ``names`` gives the reconstructions and their order (default: all present, sorted);
    those that do not cover the whole split are left out.

    Raises
    ------
    NanoctError
        If the split is empty.
    """
    idx = store.indices(split)
    if idx.size == 0:
        raise NanoctError(f"the data set at {store.path} has no '{split}' samples; generate more samples or change the split fractions")
    gts = store.read_phantoms(idx)
    results: dict[str, dict[str, Any]] = {}
    for name in names or store.reconstruction_names():
        if not store.reconstruction_done(name)[idx].all():
            continue
        results[name] = summarize(store.read_reconstruction(name, idx), gts)
    return results


def format_table(results: dict[str, dict[str, Any]], title: str = "") -> str:
    """Markdown table: method, PSNR [dB] and SSIM as mean ± std, n."""
    lines = [f"### {title}", ""] if title else []
    lines += ["| reconstruction | PSNR [dB] | SSIM | n |", "|---|---|---|---|"]
    for name, r in results.items():
        lines.append(f"| {name} | {r['psnr_mean']:.2f} ± {r['psnr_std']:.2f} | {r['ssim_mean']:.3f} ± {r['ssim_std']:.3f} | {r['n']} |")
    return "\n".join(lines) + "\n"


def write_report_tables(store: DataStore, results: dict[str, dict[str, Any]], out_dir: str | os.PathLike[str], split: str = "test") -> tuple[Path, Path]:
    """Write ``evaluation.md`` and ``evaluation.json`` into ``out_dir``; returns their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    g = store.geometry
    title = f"{g.kind} beam, N={g.n}, K={g.n_angles}, L={g.n_det}; split '{split}'"
    md, js = out / "evaluation.md", out / "evaluation.json"
    payload = {"split": split, "geometry": g.to_dict(), "simulation": store.meta.get("simulation"), "results": results}
    for path, text in ((md, format_table(results, title)), (js, json.dumps(payload, indent=2))):
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_text(text)
        os.replace(tmp, path)
    return md, js
