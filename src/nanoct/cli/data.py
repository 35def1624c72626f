"""Data-set commands: ``generate`` (simulate a set, or one matched to a measured scan), ``info``, ``show`` and
``export``."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import typer

from ..core.errors import NanoctError
from ..names import is_prediction
from .flags import flag_groups, option
from .options import QUIET, QUIET_OUTPUT, SCHEDULER, WORKERS, Execution
from .output import ood_line
from .parsing import parse_fractions


@dataclass(frozen=True)
class MatchedFlags:
    """``generate --like``: the measured scan to match, and how."""

    like: Path | None = option(
        None, "--like", help="A measured scan's data set ('nanoct import'): simulate a set matched to it."
    )
    binning: int = option(1, "--bin", help="With --like: bin the scan's detector (and slices) by this factor.")
    mix: str = option(
        "0.4,0.2,0.4",
        "--mix",
        help="With --like: proportions of paper shapes, ellipses, the scan's own slices[, measured pairs: the "
        "scan's own views with a motion added, its FBP as reference; to train on (with --hold-out) or, alone, "
        "for predict --calibrate-on].",
    )
    motion_from: str | None = option(
        None,
        "--motion-from",
        help="With --like: the 'nanoct stack' (or Dremel) result whose motion to match (default: the one the "
        "--out set was made with, else the first complete one).",
    )
    hold_out: str | None = option(
        None,
        "--hold-out",
        help="With --like: scan rows (e.g. 28:34,38:44) whose slices serve as no phantom and no measured pair "
        "(keep the slices you evaluate on out of training).",
    )
    plan: bool = option(False, "--plan", help="Print what would be made and write nothing.")


@dataclass(frozen=True)
class SimulationFlags:
    """``generate``: the seed and the simulation of the samples."""

    seed: int = option(0, "--seed", help="Data-set seed; sample i depends only on (seed, i).")
    no_motion: bool = option(False, "--no-motion", help="Unperturbed data (the paper's sanity case).")
    max_shift: float | None = option(
        None, "--max-shift", help="Bound of the sinusoidal object shift in px (default 2.0; --like: measured)."
    )
    oversample: int = option(2, "--oversample", help="Simulation grid refinement (1 = inverse crime).")
    noise_std: float | None = option(
        None, "--noise-std", help="Std of additive Gaussian noise on y (default 0, as the paper; --like: measured)."
    )
    split_fractions: str = option("0.95,0.04,0.01", "--split-fractions", help="Train,val,test proportions.")


@flag_groups()
def generate(
    *,
    preset: str | None = typer.Option(
        None, "--preset", "-p", help="Geometry preset: tiny-/small-/paper- + parallel/fan (or --like)."
    ),
    n: int = typer.Option(..., "--n", help="Number of samples."),
    out: Path = typer.Option(..., "--out", "-o", help="Output store directory (Zarr v3)."),
    matched: MatchedFlags,
    sim: SimulationFlags,
    workers: int = WORKERS,
    scheduler: str | None = SCHEDULER,
    quiet: bool = QUIET,
) -> None:
    """Simulate a data set: phantoms, motion, perturbed and model sinograms, eta, splits.

    With --like STORE (a measured scan imported with 'nanoct import'), the set is matched to the
    scan: its views, binned detector and axis, the noise measured in its air, the motion 'nanoct
    stack' (or Dremel's joint motion) estimated for it (else the paper's), and its own slices
    among the phantoms (see docs/data.md). Resumable: running the same command again completes an
    interrupted run and is a no-op when the data set is complete.
    """
    fractions = parse_fractions(sim.split_fractions)
    if matched.like is not None:
        _generate_like(matched.like, n, out, preset, matched, sim, Execution(workers, scheduler, not quiet))
        return
    from ..core.geometry import get_preset
    from ..sim.generate import generate_dataset
    from ..sim.motion import MotionParams
    from ..sim.simulate import SimulationConfig

    if preset is None:
        raise NanoctError("give --preset NAME (a simulated geometry) or --like STORE (a measured scan's data set)")
    for flag, value in (
        ("--bin", matched.binning != 1),
        ("--motion-from", matched.motion_from),
        ("--hold-out", matched.hold_out),
        ("--plan", matched.plan),
    ):
        if value:
            raise NanoctError(f"{flag} needs --like STORE (a measured scan to match); drop it for --preset")
    geometry = get_preset(preset)
    overrides = {} if sim.max_shift is None else {"max_shift": sim.max_shift}
    config = SimulationConfig(  # its ValueErrors name max_shift=...: the error boundary shows them as flags
        motion=MotionParams.for_kind(geometry.kind, **overrides),
        perturbed=not sim.no_motion,
        oversample=sim.oversample,
        noise_std=0.0 if sim.noise_std is None else sim.noise_std,
    )
    store = generate_dataset(
        out, geometry, n, seed=sim.seed, config=config, split_fractions=fractions, workers=workers,
        scheduler=scheduler, progress=not quiet,
    )  # fmt: skip
    info = store.info()
    typer.echo(f"{store.path}: {info['done']}/{info['n']} samples, splits {info['splits']}")


def _generate_like(
    like: Path, n: int, out: Path, preset: str | None, matched: MatchedFlags, sim: SimulationFlags, run: Execution
) -> None:
    """``generate --like``: measure the scan, print the plan, and (unless --plan) simulate the matched set."""
    from ..sim.matched import generate_like, parse_mix, parse_rows, plan_matched, samples_made

    for flag, value in (("--preset", preset), ("--max-shift", sim.max_shift), ("--noise-std", sim.noise_std)):
        if value is not None:
            raise NanoctError(f"{flag} cannot be combined with --like (the scan gives it); drop {flag}")
    if n <= 0:
        raise NanoctError(f"--n {n} must be a positive number of samples")
    plan = plan_matched(
        like, binning=matched.binning, mix=parse_mix(matched.mix), motion_from=matched.motion_from,
        perturbed=not sim.no_motion, oversample=sim.oversample, hold_out=parse_rows(matched.hold_out), out=out,
    )  # fmt: skip
    fractions = parse_fractions(sim.split_fractions)
    if matched.plan:
        done = samples_made(out, plan, n, seed=sim.seed, split_fractions=fractions)
        typer.echo("\n".join(plan.describe()))
        state = {None: "holds ANOTHER data set (the run would stop)", 0: "new"}.get(done, f"{done} already made")
        typer.echo(f"would make {n} samples into {out} ({state}); nothing written (--plan)")
        return
    if run.progress:
        typer.echo("\n".join(plan.describe()), err=True)
    store = generate_like(
        out, plan, n, seed=sim.seed, split_fractions=fractions,
        workers=run.workers, scheduler=run.scheduler, progress=run.progress,
    )  # fmt: skip
    info = store.info()
    typer.echo(f"{store.path}: {info['done']}/{info['n']} samples, splits {info['splits']}")


def info(
    directory: Path = typer.Argument(..., help="Data-set store."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
    check: bool = typer.Option(
        False, "--check", help="Read every written sample and list damaged ones (exit status 2 if any)."
    ),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing (with --check: only damage, as an error)."),
) -> None:
    """Sizes, splits, geometry, completeness and reconstructions of a data set.

    With --check, every sample and reconstruction that claims to be written is read; damaged
    ones (a lost or unreadable chunk) are listed with the command that rewrites them.
    """
    from ..io.store import DataStore

    store = DataStore.open(directory)
    data = store.info()
    if check:
        data["damaged"] = store.verify()
    if quiet:
        pass
    elif as_json:
        typer.echo(json.dumps(data, indent=2))
    else:
        _print_info(data)
    if data.get("damaged"):
        raise NanoctError(_damage_message(data["damaged"], store.writer))


def _damage_message(damaged: dict[str, list[int]], writer: str) -> str:
    parts = []
    for key, idx in damaged.items():
        command = writer if key == "samples" else "nanoct predict" if is_prediction(key) else "nanoct reconstruct"
        parts.append(f"{key}: {len(idx)} damaged sample(s) {idx[:5]} (rerun '{command}' to rewrite them)")
    return (
        "damaged data found: " + "; ".join(parts) + "; a chunk file that exists but cannot be read must be deleted "
        "first (reading the sample names it)"
    )


def _print_info(data: dict[str, Any]) -> None:
    g = data["geometry"]
    typer.echo(f"data set   {data['path']}  (nanoct {data['version']}, seed {data['seed']})")
    typer.echo(f"geometry   {g['kind']} beam, image {g['n']}x{g['n']}, sinogram {g['n_angles']}x{g['n_det']}")
    typer.echo(f"samples    {data['done']}/{data['n']} generated ({'complete' if data['complete'] else 'INCOMPLETE'})")
    typer.echo("splits     " + ", ".join(f"{k} {v}" for k, v in data["splits"].items()))
    scan, sim = data.get("scan"), data["simulation"]
    if scan:
        typer.echo(
            f"scan       imported from {scan.get('file')} ({scan.get('format')}); one sample per slice, motion shared; "
            "no ground truth (evaluate needs a simulated data set)"
        )
        if scan.get("pixel_size_m"):
            typer.echo(f"pixel      {scan['pixel_size_m'][0] * 1e9:.4g} nm (one stored detector pixel, at the sample)")
        for note in scan.get("notes", []):
            typer.echo(f"note       {note}")
    else:
        typer.echo(
            f"simulation perturbed={sim.get('perturbed')}, max_shift={sim.get('motion', {}).get('max_shift')} px, "
            f"oversample={sim.get('oversample')}, noise_std={sim.get('noise_std')}"
        )
    recons = data["reconstructions"]
    shown = [f"{k} ({v['done']}/{data['n']}{ood_line(v.get('ood'), ', ood: ')})" for k, v in recons.items()]
    typer.echo("reconstructions " + (", ".join(shown) or "none"))
    if "damaged" in data:
        typer.echo("check      " + ("no damaged samples" if not data["damaged"] else "DAMAGED (see below)"))


def show(
    directory: Path = typer.Argument(..., help="Data-set store."),
    index: int = typer.Option(0, "--index", "-i", help="Sample index."),
    out: Path = typer.Option(..., "--out", "-o", help="PNG file to write."),
    quiet: bool = QUIET_OUTPUT,
) -> None:
    """Figure of one sample: phantom, motion, sinograms with and without motion, FBPs.

    A slice of an imported scan (no ground truth): its measured sinogram, its FBP with the stored
    axis and up to three of its reconstructions in the store.
    """
    from ..evaluation.figures import show_sample
    from ..io.store import DataStore

    store = DataStore.open(directory)
    if not 0 <= index < store.n:
        raise NanoctError(f"--index {index} is out of range 0..{store.n - 1}")
    path = show_sample(store, index, out)
    if not quiet:
        typer.echo(f"wrote {path}")


def export(
    directory: Path = typer.Argument(..., help="Data-set store."),
    name: str = typer.Option(..., "--name", "-n", help="Reconstruction to export, e.g. dremel or dremel+ciunet-res."),
    out: Path = typer.Option(..., "--out", "-o", help="FILE.tif | .npy | .h5 (images or std) or FILE.txt (shifts)."),
    std: bool = typer.Option(
        False,
        "--std",
        help="Export the pixel-wise std of the network's draws instead of the images: where it is unsure, not on "
        "the scale of the error (use --interval for calibrated widths).",
    ),
    interval: float | None = typer.Option(
        None,
        "--interval",
        help="Export the half-width of the calibrated interval of this level (e.g. 0.9): the std mapped to widths "
        "that cover that share of the calibration set's errors, per pixel group.",
    ),
    guaranteed: bool = typer.Option(
        False, "--guaranteed", help="With --interval: the risk-controlling multiplier (guaranteed w.p. 1 - delta)."
    ),
    split: str = typer.Option("all", "--split", help="test | val | train | all"),
    index: int | None = typer.Option(
        None, "--index", "-i", help="With .txt: the sample whose shifts to write (needed unless motion is shared)."
    ),
    quiet: bool = QUIET_OUTPUT,
) -> None:
    """Export a reconstruction: float32 images (one TIFF page / .npy or HDF5 slice per sample) or shifts as text.

    A .txt output writes the per-view shifts of a stack result ('nanoct stack': its one
    motion) or of a motion-estimating reconstruction (Dremel) as nabu's
    translation_movements_file: one row "horizontal vertical" per view, raw detector pixels,
    nabu's sign, nm in comments when the scan gave a pixel size (read back with --param
    shifts_from=FILE): the stack's shared shifts for an imported scan, else those of sample
    --index.
    """
    from ..workflows.export import export_images, export_shifts

    if out.suffix.lower() == ".txt":
        path = export_shifts(directory, name, out, sample=index)
        if not quiet:
            typer.echo(f"wrote the shifts of reconstructions/{name} to {path}")
        return
    done = export_images(directory, name, out, split=split, std=std, interval=interval, guaranteed=guaranteed)
    if not quiet:
        typer.echo(f"wrote {done.samples} {done.content} map(s) of reconstructions/{name} to {done.path}")
