"""The report of a setting: tables, the paper's numbers and conclusions, figures (Markdown + HTML)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.names import parse_name, prediction_name, seed_name, strip_seed
from ..evaluation.conclusions import check_conclusions, format_conclusions
from ..evaluation.evaluate import (
    evaluate_store,
    format_mixing,
    format_table,
    mixing_matrices,
    per_image_values,
    write_report_tables,
)
from ..evaluation.figures import compare_reconstructions, show_sample, uncertainty_report
from ..evaluation.paper import format_comparison, format_mixing_comparison
from ..io.fileio import atomic_write_text, remove_stale_temporaries
from ..io.provenance import environment_info, format_environment
from ..io.store import SPLITS, DataStore
from ..learn.models import table_order
from .config import CONCLUSION_K, Jobs, Setting, Study
from .report_html import write_html_report

__all__ = ["Evaluation", "SettingSections", "evaluate_rows", "format_duration", "report_stage", "setting_mixing"]


def _result_names(setting: Setting, models: tuple[str, ...], jobs: Jobs) -> tuple[list[str], list[str]]:
    """(table rows in order, extra-seed rows) of the setting's report."""
    names = list(setting.recons) + [prediction_name(i, m) for m in models for i in setting.train_inputs]
    names += [prediction_name(i, m, t) for m, t, i, s in jobs.predict if i != t and s == 0]
    extra = [seed_name(prediction_name(i, m, t), s) for m, t, i, s in jobs.predict if s]
    return names, extra


def _conclusion_values(results: dict[str, Any], extra: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Per-image values of every row, stacked over training seeds where a row has several."""
    values = per_image_values(results)
    for name, scores in extra.items():
        base = strip_seed(name)
        if base in values:
            for metric in ("psnr", "ssim"):
                values[base][metric] = np.vstack([values[base][metric], scores[f"{metric}_values"]])
    return values


def _figures(store: DataStore, setting: Setting, models: tuple[str, ...], report_dir: Path) -> list[str]:
    test = [int(i) for i in store.indices("test")[:3]]
    inputs = list(setting.train_inputs)
    compare_reconstructions(store, list(setting.recons), test, report_dir / "reconstructions.png")
    figures = [("reconstructions.png", "First reconstructions")]
    for m in models:
        names = [prediction_name(i, m) for i in inputs]
        compare_reconstructions(store, names, test, report_dir / f"reconstructions_{m}.png")
        figures.append((f"reconstructions_{m}.png", f"Post-processed by {m}"))
    show_sample(store, test[0], report_dir / "sample.png")
    figures.append(("sample.png", "A test sample: motion, sinograms, FBP"))
    return [f"## {title}\n\n![{title}]({png})\n" for png, title in figures]


def _paper_sections(setting: Setting, results: dict[str, Any], checks: list[dict[str, Any]]) -> list[str]:
    """Our rows next to the paper's, the mixing tables and the conclusion checks (Markdown)."""
    if setting.paper is None:
        return []
    title = f"Ours next to the paper ({setting.paper}; gain = row minus its input)"
    text = [format_comparison(results, setting.paper, title)]
    mixed = {m for m, *_ in setting_mixing(results)} if setting.paper == "parallel" else set()
    for model in [m for m in table_order() if m in mixed]:
        text.append(format_mixing_comparison(results, model))
    text += ["### The paper's conclusions", "", format_conclusions(checks, CONCLUSION_K)]
    return text


def setting_mixing(results: dict[str, Any]) -> list[tuple[str, str, str]]:
    """(model, train_input, input) of every input-mixing row in ``results``, in table order."""
    return [(m, t, i) for i, m, t in map(parse_name, results) if m is not None and i != t]


@dataclass(frozen=True)
class Evaluation:
    """Scores of a store's rows on a split and the paper's conclusions checked on them.

    Attributes
    ----------
    results : dict
        Per table row: :func:`nanoct.evaluation.evaluate.evaluate_store`'s scores.
    extra : dict
        Rows of further training seeds (``<row>%seed<S>``), which only the checks use.
    checks : list of dict
        :func:`nanoct.evaluation.conclusions.check_conclusions` for the store's setting.
    setting : str or None
        The paper's setting of the store (:func:`nanoct.names.setting_key`).
    """

    results: dict[str, Any]
    extra: dict[str, Any]
    checks: list[dict[str, Any]]
    setting: str | None


def evaluate_rows(
    store: DataStore, split: str, setting: str | None, names: list[str] | None = None, extra_names: list[str] = ()
) -> Evaluation:
    """Score ``names`` (default: every reconstruction) and ``extra_names`` on ``split`` in one pass
    over the ground truth, and check the paper's conclusions of ``setting`` (with the spread over
    training seeds where extra rows give one)."""
    scored = evaluate_store(store, split, names=None if names is None else [*names, *extra_names])
    keep = scored if names is None else names
    results = {n: scored[n] for n in keep if n in scored}
    extra = {n: scored[n] for n in extra_names if n in scored}
    checks = []
    if setting is not None and results:
        checks = check_conclusions(_conclusion_values(results, extra), setting, k=CONCLUSION_K)
    return Evaluation(results, extra, checks, setting)


@dataclass(frozen=True)
class SettingSections:
    """The named parts of a setting's report that the scale report repeats.

    Attributes
    ----------
    heading : str
        ``## <preset>`` (``(no motion)`` for the unperturbed setting).
    summary : str
        Samples and splits, seed, networks, epochs, schedules, training seeds.
    stage_times : str
        Wall time of each stage in this invocation (empty if not timed).
    paper : list of str
        Our rows next to the paper's, its input-mixing tables and conclusion checks.
    """

    heading: str
    summary: str
    stage_times: str
    paper: list[str]

    def for_scale_report(self) -> list[str]:
        """The sections in the order the scale report shows them."""
        return [self.heading, "", self.summary, "", self.stage_times, *self.paper]


def _summary(store: DataStore, study: Study, models: tuple[str, ...], jobs: Jobs) -> str:
    seeds = 1 + max((s for *_, s in jobs.train), default=0)
    schedules = ", ".join(f"{m} {study.scheduler[m]}" for m in models if m in study.scheduler)
    return (
        f"{store.n} samples (train/val/test { ({s: int(store.indices(s).size) for s in SPLITS}) }), seed {store.seed}; "
        f"networks: {', '.join(models) or 'none'}; epochs {', '.join(f'{m} {study.epochs[m]}' for m in models)}"
        + (f"; learning-rate schedule {schedules} (others: their model's default)" if schedules else "")
        + (f"; {seeds} training seeds per network row (tables: seed 0)" if seeds > 1 else "")
        + "."
    )


def report_stage(
    setting: Setting, study: Study, models: tuple[str, ...], jobs: Jobs, seconds: dict[str, float] | None = None
) -> tuple[Path, SettingSections]:
    """Tables, comparison with the paper, conclusion checks, figures, Markdown + HTML report.

    ``seconds``: wall time of each earlier stage in this invocation (a stage finished by an
    earlier invocation takes about 0 s), shown under the setting's heading.

    Returns the Markdown report's path and its sections that a scale report repeats.
    """
    store = DataStore.open(setting.out / "data")
    report_dir = setting.out / "report"
    names, extra_names = _result_names(setting, models, jobs)
    scores = evaluate_rows(store, "test", setting.paper, names, extra_names)
    results = scores.results
    remove_stale_temporaries(report_dir)  # left by a kill during an earlier report
    write_report_tables(store, results, report_dir, "test", conclusions=scores.checks, setting=setting.paper)
    mixing = mixing_matrices(results)
    name = setting.preset if setting.name is None else f"{setting.name} ({setting.preset} geometry)"
    title = f"{name}{'' if setting.perturbed else ' (no motion)'}"
    summary = _summary(store, study, models, jobs)
    sections = SettingSections(
        heading=f"## {title}",
        summary=f"{setting.note}\n\n{summary}" if setting.note else summary,
        stage_times=_format_seconds(seconds or {}),
        paper=_paper_sections(setting, results, scores.checks),
    )
    text = [f"# nanoct study: {title}", "", format_environment(environment_info())]
    text += [sections.summary, "", sections.stage_times, format_table(results, "Test split")]
    text += [*sections.paper, format_mixing(mixing) if mixing else ""]
    runs = setting.out / "runs"
    text.append(uncertainty_report(store, results, list(models), list(setting.train_inputs), runs, report_dir))
    text += _figures(store, setting, models, report_dir)
    md = atomic_write_text(report_dir / "report.md", "\n".join(text))
    write_html_report(md)
    return md, sections


def _format_seconds(seconds: dict[str, float]) -> str:
    """One line: the wall time of each stage in this invocation."""
    if not seconds:
        return ""
    parts = [f"{stage} {format_duration(s)}" for stage, s in seconds.items()]
    return f"Wall time of the stages in this run: {', '.join(parts)} (a stage completed by an earlier run: ~0 s).\n"


def format_duration(s: float) -> str:
    """``12 min 05 s`` or ``42 s``."""
    m, sec = divmod(round(s), 60)
    return f"{m} min {sec:02d} s" if m else f"{sec} s"
