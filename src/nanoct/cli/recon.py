"""Reconstruction commands: ``reconstruct`` (every sample of a split) and ``methods`` (what each method takes)."""

from __future__ import annotations

from pathlib import Path

import typer

from ..core.errors import NanoctError
from ..recon.registry import method_help, method_spec, methods_with_eta
from .options import QUIET, SCHEDULER, WORKERS
from .output import reconstructions, written
from .parsing import check_name, parse_params


def reconstruct(
    directory: Path = typer.Argument(..., help="Data-set store."),
    method: str = typer.Option(..., "--method", "-m", help=f"Reconstruction method. {method_help()}."),
    split: str = typer.Option("all", "--split", help="test | val | train | all"),
    eta_scale: float | None = typer.Option(
        None,
        "--eta-scale",
        help=f"Methods that use eta ({', '.join(methods_with_eta())}): its scale (default 1; paper: 0.8, 1.0, 1.2).",
    ),
    eta: str | None = typer.Option(
        None,
        "--eta",
        help="Methods that use eta: true (the store's; default of a simulated data set), "
        "estimate:residual[=RECONSTRUCTION] (from a first reconstruction, default dremel; default of an imported "
        "scan, where on measured data RESESOP then carries Dremel's motion) or estimate:reference=STORE (per-view "
        "median of a simulated store's eta).",
    ),
    param: list[str] = typer.Option(
        [],
        "--param",
        help="Method parameter name=value (repeatable); 'nanoct methods METHOD' lists them. Dremel also: "
        "motion_slices=all|0,5,9 (one motion for these slices; on measured data each slice refines it), "
        "shifts_from=FILE (start motion), fix_shifts=true "
        "(use it as given).",
    ),
    name: str | None = typer.Option(
        None,
        "--name",
        help="Output name (default: method, resesop_eta<F>, resesop_est-residual...).",
        callback=check_name,
    ),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing reconstruction of that name."),
    workers: int = WORKERS,
    scheduler: str | None = SCHEDULER,
    quiet: bool = QUIET,
) -> None:
    """Reconstruct every sample of a split into reconstructions/<name> (resumable).

    Dremel on measured data keeps a slice's shifts at their start where its estimate runs away
    (a shift of more than a quarter of the detector); a joint motion with such slices, and the
    samples so kept (counted over resumed runs), are reported as warnings.
    """
    from ..io.store import DataStore
    from ..recon.batch import reconstruct_dataset, shift_check_warning

    params = parse_params(param)
    if method_spec(method).needs_eta:
        params.setdefault("eta_scale", 1.0 if eta_scale is None else eta_scale)
        if eta is not None:
            params["eta"] = eta
    elif eta_scale is not None or eta is not None:
        with_eta = " or ".join(f"--method {m}" for m in methods_with_eta())
        flag = "--eta-scale" if eta_scale is not None else "--eta"
        raise NanoctError(f"{flag} applies to {with_eta} only (methods that use eta), not to --method {method}")
    before = reconstructions(directory)
    result = reconstruct_dataset(
        directory,
        method,
        split=split,
        params=params,
        name=name,
        overwrite=overwrite,
        workers=workers,
        scheduler=scheduler,
        progress=not quiet,
    )
    typer.echo(written(directory, result, before))
    store = DataStore.open(directory)
    for key, label in (("shifts_axis", "note"), ("shift_check", "warning")):
        text = store.recons.note(result, key)
        if text:
            typer.echo(f"{label}: {text}", err=True)
    text = shift_check_warning(store, result)
    if text:
        typer.echo(f"warning: {text}", err=True)


def methods(
    method: str | None = typer.Argument(None, help="A method (default: all of them)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Only the methods' names, one per line."),
) -> None:
    """List the reconstruction methods and the parameters each takes (--param NAME=VALUE).

    The parameters, their defaults and help come from each method's parameter class
    (nanoct.recon.params); batch parameters (--eta, motion_slices, shifts_from) are used by
    'nanoct reconstruct' itself and never reach the solver.
    """
    from dataclasses import fields

    from ..recon.registry import METHODS

    for name in [method_spec(method).name] if method else list(METHODS):
        spec = METHODS[name]
        if quiet:
            typer.echo(name)
            continue
        typer.echo(f"{name}: {spec.help}")
        defaults = {f.name: f.default for f in fields(spec.params_class())}
        batch = set(spec.batch_parameter_names())
        for param, text in spec.parameter_help().items():
            where = " (batch)" if param in batch else f" = {defaults[param]!r}"
            typer.echo(f"  {param}{where}  {text}")
