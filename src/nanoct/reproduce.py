"""The whole study from one call: generate, reconstruct, evaluate, report.

Every stage is cached in the output directory: the data set and each reconstruction resume
where they stopped and are skipped when complete; tables and figures are cheap and redone.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .errors import NanoctError
from .evaluate import evaluate_store, format_table, write_report_tables
from .figures import compare_reconstructions, show_sample
from .generate import generate_dataset
from .geometry import get_preset, preset_names
from .recon.batch import reconstruct_dataset
from .simulate import SimulationConfig

__all__ = ["STUDIES", "Study", "reproduce_study"]


@dataclass(frozen=True)
class Study:
    """Scale of a reproduction: number of samples and split proportions."""

    n: int
    split_fractions: tuple[float, float, float]


def _recons(perturbed: bool = True) -> dict[str, tuple[str, dict[str, Any]]]:
    if not perturbed:  # the paper's unperturbed table: RESESOP with eta = 0
        return {"fbp": ("fbp", {}), "dremel": ("dremel", {}), "resesop": ("resesop", {"eta_scale": 0.0})}
    return {
        "fbp": ("fbp", {}),
        "dremel": ("dremel", {}),
        "resesop": ("resesop", {"eta_scale": 1.0}),
        "resesop_eta0.8": ("resesop", {"eta_scale": 0.8}),
        "resesop_eta1.2": ("resesop", {"eta_scale": 1.2}),
    }


# tiny: enough test samples for a mean ± std on a laptop; paper: the paper's 32,095 / 95-4-1.
STUDIES: dict[str, Study] = {
    "tiny": Study(n=200, split_fractions=(0.8, 0.1, 0.1)),
    "small": Study(n=2000, split_fractions=(0.9, 0.05, 0.05)),
    "paper": Study(n=32095, split_fractions=(0.95, 0.04, 0.01)),
}


def reproduce_study(
    preset: str,
    *,
    out: str | os.PathLike[str] | None = None,
    n: int | None = None,
    perturbed: bool = True,
    workers: int = 2,
    scheduler: str | None = None,
    progress: bool = True,
) -> Path:
    """Run the study for a geometry preset and return the path of its Markdown report.

    Parameters
    ----------
    preset : str
        Geometry preset (``tiny-parallel``, ``paper-fan``, ...); its size prefix picks the
        scale in :data:`STUDIES`.
    out : path, optional
        Output directory (default ``runs/<preset>`` or ``runs/<preset>-nomotion``); the data
        set is ``<out>/data``, the report ``<out>/report``.
    n : int, optional
        Number of samples instead of the scale's default.
    perturbed : bool
        False gives the unperturbed sanity case.
    workers, scheduler, progress
        See :func:`nanoct.fanout.run_tasks`.
    """
    if preset not in preset_names():
        raise NanoctError(f"unknown preset {preset!r}; choose one of: {', '.join(preset_names())}")
    geometry = get_preset(preset)
    study = STUDIES[preset.split("-")[0]]
    out = Path(out or Path("runs") / (preset if perturbed else f"{preset}-nomotion"))
    data = out / "data"
    config = SimulationConfig.for_geometry(geometry, perturbed=perturbed)
    store = generate_dataset(
        data, geometry, n or study.n, seed=0, config=config, split_fractions=study.split_fractions,
        workers=workers, scheduler=scheduler, progress=progress,
    )
    recons = _recons(perturbed)
    for name, (method, params) in recons.items():
        reconstruct_dataset(data, method, params=params, name=name, workers=workers, scheduler=scheduler, progress=progress)
    report_dir = out / "report"
    results = evaluate_store(store, "test", names=list(recons))
    write_report_tables(store, results, report_dir, "test")
    test = [int(i) for i in store.indices("test")[:3]]
    compare_reconstructions(store, list(recons), test, report_dir / "reconstructions.png")
    show_sample(store, test[0], report_dir / "sample.png")
    report = report_dir / "report.md"
    text = [
        f"# nanoct study: {preset}{'' if perturbed else ' (no motion)'}",
        "",
        f"{store.n} samples (train/val/test {store.info()['splits']}), seed {store.seed}.",
        "",
        format_table(results, "Test split, no post-processing"),
        "![reconstructions](reconstructions.png)",
        "",
        "![sample](sample.png)",
        "",
    ]
    tmp = report.with_name(".report.md.tmp")
    tmp.write_text("\n".join(text))
    os.replace(tmp, report)
    return report
