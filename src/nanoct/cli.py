"""Command-line interface: parses arguments and calls the library; holds no science."""

from __future__ import annotations

import errno
import inspect
import json
import os
import re
import shlex
import sys
import traceback
import warnings
from pathlib import Path
from typing import Any

import typer

from . import __version__
from .core.errors import NanoctError
from .io.fileio import free_space
from .names import is_prediction
from .recon.registry import method_help, method_spec, methods_with_eta

app = typer.Typer(
    help="nanoct: CT reconstruction with inexact (motion-perturbed) forward operators.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    # plain help: flags read "-q, --quiet" (rich help shows "<bool>" after every flag in typer 0.29)
    rich_markup_mode=None,
)

# the exceptions module of the click that the installed typer uses: click itself up to typer 0.28,
# typer._click (vendored) from 0.29 on
_CLICK = sys.modules[typer.BadParameter.__module__]


def _show_version(value: bool) -> None:
    if value:
        typer.echo(f"nanoct {__version__}")
        raise typer.Exit()


@app.callback()
def _options(
    version: bool = typer.Option(
        False, "--version", help="Print the version and exit.", callback=_show_version, is_eager=True
    ),
) -> None:
    """nanoct: CT reconstruction with inexact (motion-perturbed) forward operators."""


WORKERS = typer.Option(2, "--workers", "-w", help="Local Dask worker processes (0: run in this process).")
SCHEDULER = typer.Option(None, "--scheduler", help="Address of a running Dask scheduler (instead of a local cluster).")
QUIET = typer.Option(False, "--quiet", "-q", help="No progress bars.")
QUIET_OUTPUT = typer.Option(False, "--quiet", "-q", help="Print nothing but errors.")

# how to read a scan file: shared by 'import' and 'stack' (which imports a scan file first)
FORMAT = typer.Option(
    None,
    "--format",
    help="nxtomo | diamond | diamond-nxtomo | dxchange | hdf5 | tiff | npy | mrc (default: from the file).",
)
ANGLES = typer.Option(
    None,
    "--angles",
    help="Angles: text file, one per view (IMOD .tlt/.rawtlt too), FILE.h5:/dataset, or FIRST:STOP (evenly "
    "spaced, STOP excluded).",
)
ANGLES_SELECT = typer.Option(
    None, "--angles-select", help="Use only the values FIRST:STOP (0-based, STOP excluded) of the --angles file."
)
RADIANS = typer.Option(False, "--radians", help="The --angles text file is in radians (default degrees).")
ANGLE_UNITS = typer.Option(
    None,
    "--angles-units",
    help="deg | rad: the unit of the angles, overriding the file's units attribute and the check that the values "
    "look like that unit (--radians keeps the check): for scans that fail it, e.g. more than two turns in radians.",
)
DATA_PATH = typer.Option(None, "--data-path", help="HDF5: dataset of the frames (frames, rows, columns).")
KEY_PATH = typer.Option(
    None, "--image-key-path", help="HDF5: dataset of the NXtomo image keys (0 proj, 1 flat, 2 dark)."
)
ANGLES_PATH = typer.Option(None, "--angles-path", help="HDF5: dataset of the angles (one per frame).")
ALLOW = typer.Option(
    [], "--allow-outside", help="HDF5: a folder outside the scan's own that links may read (repeatable)."
)
TILT_AXIS = typer.Option("columns", "--tilt-axis", help="MRC: the tilt axis runs along the image columns | rows.")
FLATS = typer.Option(None, "--flats", help="Flat fields (TIFF or .npy) for TIFF and .npy scans.")
DARKS = typer.Option(None, "--darks", help="Dark fields (TIFF or .npy) for TIFF and .npy scans.")
ENTRY = typer.Option(None, "--entry", help="NXtomo entry to read (when the file has several).")
# corrections of measured projections (nanoct.preprocess, docs/corrections.md), all off by default
OUTLIERS = typer.Option(
    None, "--outliers", help="Replace outliers (zingers) beyond this many robust noise units (e.g. 5)."
)
OUTLIER_SIZE = typer.Option(3, "--outlier-size", help="Median window of the outlier filter (odd).")
OUTLIER_KIND = typer.Option("both", "--outlier-kind", help="Outliers to replace: both | bright | dark.")
OPEN_BEAM = typer.Option(
    False, "--open-beam", help="Divide each view by its open beam fitted to air (beam decay, flat mismatch)."
)
AIR_COLUMNS = typer.Option(
    None, "--air-columns", help="With --open-beam: columns seeing only air, FIRST:STOP[,FIRST:STOP]."
)
OPEN_BEAM_DEGREE = typer.Option("auto", "--open-beam-degree", help="Open-beam surface per view: auto | 0 | 1 | 2.")
DELTA_BETA = typer.Option(None, "--delta-beta", help="Paganin phase retrieval: delta/beta (needs the next three).")
ENERGY = typer.Option(None, "--energy-kev", help="Paganin: photon energy in keV.")
DISTANCE = typer.Option(None, "--distance-m", help="Paganin: propagation distance in metres.")
PIXEL = typer.Option(None, "--pixel-size-m", help="Paganin: detector pixel size in metres.")
STRIPES = typer.Option(None, "--stripes", help="Ring/stripe removal (algotom): all | sorting | filtering | fitting.")
STRIPE_PARAMS = typer.Option(
    None, "--stripe-params", help="Stripe method parameters by algotom's names, e.g. snr=3,la_size=51."
)
ROWS = typer.Option(None, "--rows", help="Detector rows (slices) FIRST:STOP (default all).")
CROP = typer.Option(None, "--crop", help="Detector columns FIRST,STOP to keep.")
LINE_INTEGRALS = typer.Option(
    False, "--line-integrals", help="The data are already -log normalised (no flat/dark correction)."
)
#: The options above by their parameter names in 'import' and 'stack': how to read a scan file, and the
#: corrections of its projections. Given to 'stack' on a data set they are refused (they apply when importing).
_READING = (
    "fmt", "angles", "angles_select", "radians", "angles_units", "data_path", "image_key_path", "angles_path",
    "allow_outside", "tilt_axis", "flats", "darks", "line_integrals", "rows", "crop", "entry",
)  # fmt: skip
_CORRECTING = (
    "outliers", "outlier_size", "outlier_kind", "open_beam", "air_columns", "open_beam_degree", "delta_beta",
    "energy_kev", "distance_m", "pixel_size_m", "stripes", "stripe_params",
)  # fmt: skip
#: Options that set how another one works, with the one each needs (given alone, nothing would use them).
_NEEDS = {"outlier_size": "outliers", "outlier_kind": "outliers", "open_beam_degree": "open_beam"}


def _option_infos(command: Any) -> dict[str, Any]:
    """The options of a command's function by parameter name (their flags and defaults: the signature's)."""
    params = inspect.signature(command).parameters
    return {name: p.default for name, p in params.items() if isinstance(p.default, typer.models.OptionInfo)}


def _long_flag(info: Any) -> str:
    return next(d for d in info.param_decls if d.startswith("--"))


def _given(command: Any, flags: dict[str, Any], names: Any) -> dict[str, Any]:
    """The options ``names`` of ``command`` whose value in ``flags`` (its ``locals()``) is not their default, as
    ``{flag: value}`` in the order of ``names``; the defaults are those of the command's own signature."""
    infos = _option_infos(command)
    given = {}
    for name in names:
        value, default = flags[name], infos[name].default
        if isinstance(default, list):  # a repeatable option
            value = list(value)
        if value != default:
            given[_long_flag(infos[name])] = value
    return given


def _parse_fractions(text: str) -> tuple[float, float, float]:
    try:
        parts = tuple(float(v) for v in text.split(","))
    except ValueError:
        parts = ()
    if len(parts) != 3 or not all(0 <= p < float("inf") for p in parts) or abs(sum(parts) - 1) > 1e-6:
        raise NanoctError(
            f"--split-fractions {text!r} must be three comma-separated numbers >= 0 summing to 1, e.g. 0.95,0.04,0.01"
        )
    return parts  # type: ignore[return-value]


def _check_name(name: str | None) -> str | None:
    from .io.store_recon import check_name

    return None if name is None else check_name(name)


# internal parameter names that appear in library messages -> the flag a user typed
_FLAGS = {"max_shift": "--max-shift", "noise_std": "--noise-std", "oversample": "--oversample", "workers": "--workers"}


def _as_flags(message: str) -> str:
    """Rewrite ``max_shift=-1`` in a library message as ``--max-shift -1``."""
    return re.sub(r"\b(" + "|".join(_FLAGS) + r")=", lambda m: _FLAGS[m.group(1)] + " ", message)


def _check_device(device: str | None) -> None:
    if device is None:
        return
    import torch

    try:
        torch.device(device)
    except (RuntimeError, ValueError) as exc:
        raise NanoctError(f"--device {device!r} is not a device; use cpu, cuda or cuda:<index>") from exc


def _reconstructions(directory: Path) -> dict[str, tuple[Any, int]]:
    """Each reconstruction of the data set at ``directory``: (its creation id, samples done); empty where the data
    set cannot be read (the command itself then says why)."""
    from .io.store import DataStore

    try:
        store = DataStore.open(directory)
        return {
            n: (store.recons.fingerprint(n)["created"], int(store.reconstruction_done(n).sum()))
            for n in store.reconstruction_names()
        }
    except (NanoctError, OSError, KeyError, ValueError):
        return {}


def _written(directory: Path, name: str, before: dict[str, tuple[Any, int]]) -> str:
    """What a reconstruct or predict run did to ``reconstructions/<name>``, against :func:`_reconstructions`
    ``before`` it: the samples it wrote, or that it was complete already."""
    after = _reconstructions(directory)
    if name not in after:  # nothing to compare with
        return f"wrote reconstructions/{name}"
    created, done = after[name]
    kept = before.get(name)
    new = done - kept[1] if kept is not None and kept[0] == created else done
    if new == 0:
        return f"reconstructions/{name} was complete already ({done} sample{'s' * (done != 1)}); nothing to do"
    return f"wrote reconstructions/{name} ({new} sample{'s' * (new != 1)}; {done} done)"


def _parse_params(items: list[str]) -> dict[str, Any]:
    """``--param name=value`` items as keyword arguments: each value read as JSON (0.2, [16,32], true), the words
    true and false in any case (Python's True, False) as booleans, anything else as the string it is."""
    params: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise NanoctError(f"--param {item!r} must look like name=value (e.g. relaxation=0.2)")
        try:
            params[key] = json.loads(value)
        except json.JSONDecodeError:
            params[key] = value.lower() == "true" if value.lower() in ("true", "false") else value
    return params


@app.command()
def generate(
    preset: str | None = typer.Option(
        None, "--preset", "-p", help="Geometry preset: tiny-/small-/paper- + parallel/fan (or --like)."
    ),
    n: int = typer.Option(..., "--n", help="Number of samples."),
    out: Path = typer.Option(..., "--out", "-o", help="Output store directory (Zarr v3)."),
    like: Path | None = typer.Option(
        None, "--like", help="A measured scan's data set ('nanoct import'): simulate a set matched to it."
    ),
    bin_: int = typer.Option(1, "--bin", help="With --like: bin the scan's detector (and slices) by this factor."),
    mix: str = typer.Option(
        "0.4,0.2,0.4",
        "--mix",
        help="With --like: proportions of paper shapes, ellipses, the scan's own slices[, measured pairs: the "
        "scan's own views with a motion added, its FBP as reference; to train on (with --hold-out) or, alone, "
        "for predict --calibrate-on].",
    ),
    motion_from: str | None = typer.Option(
        None,
        "--motion-from",
        help="With --like: the 'nanoct stack' (or Dremel) result whose motion to match (default: the one the --out "
        "set was made with, else the first complete one).",
    ),
    hold_out: str | None = typer.Option(
        None,
        "--hold-out",
        help="With --like: scan rows (e.g. 28:34,38:44) whose slices serve as no phantom and no measured pair "
        "(keep the slices you evaluate on out of training).",
    ),
    plan: bool = typer.Option(False, "--plan", help="Print what would be made and write nothing."),
    seed: int = typer.Option(0, "--seed", help="Data-set seed; sample i depends only on (seed, i)."),
    no_motion: bool = typer.Option(False, "--no-motion", help="Unperturbed data (the paper's sanity case)."),
    max_shift: float | None = typer.Option(
        None, "--max-shift", help="Bound of the sinusoidal object shift in px (default 2.0; --like: measured)."
    ),
    oversample: int = typer.Option(2, "--oversample", help="Simulation grid refinement (1 = inverse crime)."),
    noise_std: float | None = typer.Option(
        None, "--noise-std", help="Std of additive Gaussian noise on y (default 0, as the paper; --like: measured)."
    ),
    split_fractions: str = typer.Option("0.95,0.04,0.01", "--split-fractions", help="Train,val,test proportions."),
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
    fractions = _parse_fractions(split_fractions)
    if like is not None:
        _generate_like(like, n, out, locals())
        return
    from .core.geometry import get_preset
    from .sim.generate import generate_dataset
    from .sim.motion import MotionParams
    from .sim.simulate import SimulationConfig

    if preset is None:
        raise NanoctError("give --preset NAME (a simulated geometry) or --like STORE (a measured scan's data set)")
    for flag, value in (
        ("--bin", bin_ != 1),
        ("--motion-from", motion_from),
        ("--hold-out", hold_out),
        ("--plan", plan),
    ):
        if value:
            raise NanoctError(f"{flag} needs --like STORE (a measured scan to match); drop it for --preset")
    geometry = get_preset(preset)
    overrides = {} if max_shift is None else {"max_shift": max_shift}
    config = SimulationConfig(  # its ValueErrors name max_shift=...: the error boundary shows them as flags
        motion=MotionParams.for_kind(geometry.kind, **overrides),
        perturbed=not no_motion,
        oversample=oversample,
        noise_std=0.0 if noise_std is None else noise_std,
    )
    store = generate_dataset(
        out, geometry, n, seed=seed, config=config, split_fractions=fractions, workers=workers,
        scheduler=scheduler, progress=not quiet,
    )  # fmt: skip
    info = store.info()
    typer.echo(f"{store.path}: {info['done']}/{info['n']} samples, splits {info['splits']}")


def _generate_like(like: Path, n: int, out: Path, flags: dict[str, Any]) -> None:
    """``generate --like``: measure the scan, print the plan, and (unless --plan) simulate the matched set."""
    from .io.store import DataStore, comparable_description
    from .sim.matched import generate_like, parse_mix, parse_rows, plan_matched

    f = flags
    for flag, value in (("--preset", f["preset"]), ("--max-shift", f["max_shift"]), ("--noise-std", f["noise_std"])):
        if value is not None:
            raise NanoctError(f"{flag} cannot be combined with --like (the scan gives it); drop {flag}")
    if n <= 0:
        raise NanoctError(f"--n {n} must be a positive number of samples")
    matched = plan_matched(
        like, binning=f["bin_"], mix=parse_mix(f["mix"]), motion_from=f["motion_from"],
        perturbed=not f["no_motion"], oversample=f["oversample"], hold_out=parse_rows(f["hold_out"]), out=out,
    )  # fmt: skip
    fractions = _parse_fractions(f["split_fractions"])
    if f["plan"]:
        done = 0
        if (out / "zarr.json").is_file():
            old = DataStore.open(out)
            simulation = comparable_description({"simulation": json.loads(json.dumps(matched.simulation))})
            wanted = (simulation, matched.geometry, n, f["seed"], list(fractions))
            have = (comparable_description({"simulation": old.meta.get("simulation")}), old.geometry, old.n, old.seed,
                    old.meta.get("split_fractions"))  # fmt: skip
            done = int(old.done.sum()) if have == wanted else -1
        typer.echo("\n".join(matched.describe()))
        state = {-1: "holds ANOTHER data set (the run would stop)", 0: "new"}.get(done, f"{done} already made")
        typer.echo(f"would make {n} samples into {out} ({state}); nothing written (--plan)")
        return
    if not f["quiet"]:
        typer.echo("\n".join(matched.describe()), err=True)
    store = generate_like(
        out, matched, n, seed=f["seed"], split_fractions=fractions,
        workers=f["workers"], scheduler=f["scheduler"], progress=not f["quiet"],
    )  # fmt: skip
    info = store.info()
    typer.echo(f"{store.path}: {info['done']}/{info['n']} samples, splits {info['splits']}")


@app.command()
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
        callback=_check_name,
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
    from .io.store import DataStore
    from .recon.batch import reconstruct_dataset, shift_check_warning

    params = _parse_params(param)
    if method_spec(method).needs_eta:
        params.setdefault("eta_scale", 1.0 if eta_scale is None else eta_scale)
        if eta is not None:
            params["eta"] = eta
    elif eta_scale is not None or eta is not None:
        with_eta = " or ".join(f"--method {m}" for m in methods_with_eta())
        flag = "--eta-scale" if eta_scale is not None else "--eta"
        raise NanoctError(f"{flag} applies to {with_eta} only (methods that use eta), not to --method {method}")
    before = _reconstructions(directory)
    written = reconstruct_dataset(
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
    typer.echo(_written(directory, written, before))
    store = DataStore.open(directory)
    for key, label in (("shifts_axis", "note"), ("shift_check", "warning")):
        text = store.recons.note(written, key)
        if text:
            typer.echo(f"{label}: {text}", err=True)
    text = shift_check_warning(store, written)
    if text:
        typer.echo(f"warning: {text}", err=True)


@app.command()
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

    from .recon.registry import METHODS

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


@app.command()
def train(
    directory: Path = typer.Argument(..., help="Data-set store."),
    model: str = typer.Option("unet", "--model", "-m", help="unet | cinn | cinn-res | ciunet | ciunet-res"),
    input_name: str = typer.Option(
        ..., "--input", "-i", help="Input reconstruction, e.g. fbp, dremel, resesop_eta0.8."
    ),
    out: Path | None = typer.Option(None, "--out", "-o", help="Run directory (default DIR/../runs/<model>-<input>)."),
    epochs: int | None = typer.Option(None, "--epochs", "-e", help="Epochs (default: the paper's 500)."),
    batch_size: int | None = typer.Option(None, "--batch-size", help="Global batch size (paper: 16)."),
    lr: float | None = typer.Option(None, "--lr", help="Adam learning rate (paper: 1e-3 UNet, 1e-5 invertible nets)."),
    seed: int = typer.Option(0, "--seed", help="Seed of weights, shuffling and noise."),
    device: str | None = typer.Option(None, "--device", help="cpu, cuda, cuda:1 ... (default: CUDA when present)."),
    lr_schedule: str | None = typer.Option(
        None,
        "--lr-schedule",
        help="none | plateau | cosine (default: the model's; UNet cosine to lr/10, iNNs plateau).",
    ),
    param: list[str] = typer.Option([], "--param", help="Model architecture argument name=value (repeatable)."),
    precision: str = typer.Option(
        "fp32",
        "--precision",
        help="fp32 | bf16 | auto (bf16: bfloat16 autocast, up to 2x faster on CPUs with native bfloat16, "
        "5-9x slower on others; auto: bf16 where native, else fp32).",
    ),
    clip_grad: float | None = typer.Option(
        None, "--clip-grad", help="Gradient-norm clipping (default: the model's; 0 disables)."
    ),
    max_steps: int | None = typer.Option(
        None, "--max-steps", help="Stop after this many optimizer steps in total (smoke tests)."
    ),
    num_workers: int = typer.Option(0, "--num-workers", help="DataLoader worker processes."),
    patch: int | None = typer.Option(
        None,
        "--patch",
        help="Train on PxP patches (a random one per image and epoch; validation on a grid of patches covering "
        "each image); the network then predicts in tiles of P (predict --tile 0), its intervals fitted on the "
        "validation images so predicted.",
    ),
    quiet: bool = QUIET,
) -> None:
    """Train a post-processing network on reconstructions/<input> -> phantoms.

    Keeps the checkpoint with the lowest validation loss (best.pt) and the last one
    (last.pt), logs losses to log.csv; running the same command again resumes after the
    last finished epoch. Under torchrun it trains with DDP, e.g.
    torchrun --nproc-per-node 2 -m nanoct train DIR --input fbp. On a set matched to a
    measured scan (generate --like) the invertible networks' training noise on the target
    and the UNet's squared error are relative to each image's range
    (target_noise_scale=range, loss_scale=range; --param ...=absolute keeps the paper's).
    --param residual=true makes the UNet a correction of its input (not the paper's).
    """
    from .learn.train import TrainConfig
    from .learn.train import train as train_model

    _check_device(device)
    run = out or Path(directory).resolve().parent / "runs" / f"{model}-{input_name}"
    config = TrainConfig(
        model,
        input_name,
        epochs=epochs,
        batch_size=batch_size,
        lr=lr,
        seed=seed,
        scheduler=lr_schedule,
        model_kwargs=_parse_params(param) or None,
        clip_grad=clip_grad,
        precision=precision,
        max_steps=max_steps,
        device=device,
        num_workers=num_workers,
        patch=patch,
    )
    path = train_model(directory, run, config, progress=not quiet)
    typer.echo(f"run: {path}")


@app.command()
def predict(
    directory: Path = typer.Argument(..., help="Data-set store."),
    run: Path = typer.Option(..., "--run", "-r", help="Training run directory."),
    input_name: str | None = typer.Option(
        None, "--input", "-i", help="Input reconstruction (default: the training input)."
    ),
    split: str = typer.Option("test", "--split", help="test | val | train | all"),
    checkpoint: str = typer.Option("best", "--checkpoint", help="best (lowest validation loss) or last."),
    samples: int | None = typer.Option(
        None, "--samples", "-M", help="Latent samples per image for invertible nets (default 100)."
    ),
    antithetic: bool = typer.Option(
        False,
        "--antithetic",
        help="Invertible nets: latent samples in antithetic pairs (z, -z); less noise in the mean.",
    ),
    device: str | None = typer.Option(None, "--device", help="cpu, cuda, ... (default: CUDA when present)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an earlier result made with other parameters."),
    no_calibrate: bool = typer.Option(
        False, "--no-calibrate", help="Invertible nets: fit no intervals (default: calibrated on validation data)."
    ),
    levels: str = typer.Option(
        "0.68,0.9,0.95", "--levels", help="Invertible nets: interval levels (nominal coverage), comma-separated."
    ),
    tile: int | None = typer.Option(
        None,
        "--tile",
        help="Predict in overlapping tiles of this size (0: the size the network was trained on), blended "
        "smoothly: images of any size in bounded memory; the intervals are the run's own calibration (fitted on "
        "the data set it was trained on) where the data set has no validation split or, for a run not trained "
        "on patches, another image size.",
    ),
    tile_overlap: int | None = typer.Option(
        None,
        "--tile-overlap",
        help="With --tile: pixels shared by neighbouring tiles (default 16, at most half a tile).",
    ),
    out_name: str | None = typer.Option(
        None,
        "--name",
        help="Store the result as reconstructions/NAME (default: <input>+<model>), e.g. to keep two "
        "runs' predictions side by side.",
    ),
    calibrate_on: Path | None = typer.Option(
        None,
        "--calibrate-on",
        help="Invertible nets: fit the intervals on this data set's validation split instead, e.g. a scan's own "
        "measured pairs (generate --like SCAN --mix 0,0,0,1).",
    ),
    quiet: bool = QUIET,
) -> None:
    """Post-process reconstructions/<input> with a trained network.

    Writes reconstructions/<input>+<model> (unet-res for a residual UNet; and
    uncertainty/<input>+<model> for invertible nets), or <input>+<model>@<train input> when
    applied to another input than it was trained on (the paper's input-mixing tables). The
    stored std of invertible nets is the network's own; intervals mean +- multiplier x g(std),
    one multiplier per level and group (background, and the five std fifths of the object's
    support as the network's mean shows it; for measured references the background split at the
    sample's footprint), are fitted
    once on the validation split of the data it was trained on (group-conditional split
    conformal, with the coverage guaranteed with probability 90 %) and stored with the result
    (export them with 'nanoct export --interval'); --calibrate-on fits them on another data
    set's validation split, e.g. a measured scan's own slices with a known motion added and its
    FBP as reference, where each group's multiplier also covers the reference's object pixels it
    holds (object-conditional; docs/uncertainty.md). Images whose std level is above the
    validation split's, whose sinogram shows more apparent motion than the training scans, or
    (intervals calibrated on one scan's measured pairs) with more than 2 % of their object outside
    that scan's footprint are reported as out of distribution (docs/uncertainty.md).
    """
    from .learn.predict import predict as predict_model

    _check_device(device)
    if samples is not None and samples <= 0:
        raise NanoctError(f"--samples {samples} must be a positive number of latent samples")
    kwargs = ({} if samples is None else {"n_samples": samples}) | ({"antithetic": True} if antithetic else {})
    before = _reconstructions(directory)
    name = predict_model(
        directory,
        run,
        input_name,
        split=split,
        checkpoint=checkpoint,
        device=device,
        progress=not quiet,
        overwrite=overwrite,
        reconstruct_kwargs=kwargs or None,
        calibrate=not no_calibrate,
        levels=tuple(_parse_levels(levels)),
        tile=tile,
        overlap=tile_overlap,
        name=out_name,
        calibrate_on=calibrate_on,
    )
    typer.echo(_written(directory, name, before))
    _print_ood(directory, name)


def _print_ood(directory: Path, name: str) -> None:
    """Print the out-of-distribution summary (:func:`_ood_line`) of ``reconstructions/<name>``, where it has one."""
    from .io.store import DataStore, ood_brief

    try:
        ood = _ood_line(ood_brief(DataStore.open(directory).reconstruction_note(name, "ood")).get("ood"))
    except (NanoctError, OSError, KeyError, ValueError):  # nothing to summarise
        ood = ""
    if ood:
        typer.echo(f"out-of-distribution check of reconstructions/{name} (every image so far): {ood}")


def _parse_levels(text: str) -> list[float]:
    """``"0.68,0.9"`` -> [0.68, 0.9]; a clear error for anything else."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if not values or not all(0 < v < 1 for v in values):
        raise NanoctError(f"--levels {text!r} must be comma-separated coverages between 0 and 1, e.g. 0.68,0.9,0.95")
    return values


@app.command()
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
    from .io.store import DataStore

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


def _ood_line(ood: dict[str, Any] | None, lead: str = "") -> str:
    """An out-of-distribution summary (:func:`nanoct.io.store.ood_brief`): ``lead`` + "2 of 40 flagged: 20, 32;
    checks std, scan"; empty without one."""
    if not ood:
        return ""
    flagged = ood["flagged"]
    which = f": {', '.join(map(str, flagged[:10]))}{' ...' if len(flagged) > 10 else ''}" if flagged else ""
    left = f"; {len(ood['unchecked'])} left out by footprint (mean too noisy)" if ood["unchecked"] else ""
    return f"{lead}{len(flagged)} of {ood['checked']} flagged{which}; checks {', '.join(ood['checks'])}{left}"


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
    shown = [f"{k} ({v['done']}/{data['n']}{_ood_line(v.get('ood'), ', ood: ')})" for k, v in recons.items()]
    typer.echo("reconstructions " + (", ".join(shown) or "none"))
    if "damaged" in data:
        typer.echo("check      " + ("no damaged samples" if not data["damaged"] else "DAMAGED (see below)"))


@app.command()
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
    from .evaluation.figures import show_sample
    from .io.store import DataStore

    store = DataStore.open(directory)
    if not 0 <= index < store.n:
        raise NanoctError(f"--index {index} is out of range 0..{store.n - 1}")
    written = show_sample(store, index, out)
    if not quiet:
        typer.echo(f"wrote {written}")


@app.command()
def evaluate(
    directory: Path = typer.Argument(..., help="Data-set store."),
    split: str = typer.Option("test", "--split", help="Split to evaluate on."),
    out: Path | None = typer.Option(None, "--out", "-o", help="Directory for evaluation.md/json (default DIR/report)."),
    as_json: bool = typer.Option(False, "--json", help="Print evaluation.json instead of the Markdown tables."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Write the files, print nothing."),
) -> None:
    """PSNR/SSIM (mean ± std over a split, and per image) of every reconstruction in the store.

    Also the input-mixing tables (models applied to inputs they were not trained on), for
    sampling models the std/error correlation and calibration, and the paper's conclusions
    checked on the per-image values (paired differences) for the paper's setting of the store.
    """
    from .evaluation.evaluate import store_setting, write_report_tables
    from .io.store import DataStore
    from .study.report import evaluate_rows

    store = DataStore.open(directory)
    scores = evaluate_rows(store, split, store_setting(store))
    if not scores.results:
        raise NanoctError(
            f"no reconstruction in {directory} covers the '{split}' split; run 'nanoct reconstruct' first"
        )
    md, js = write_report_tables(
        store,
        scores.results,
        out or Path(directory) / "report",
        split,
        conclusions=scores.checks,
        setting=scores.setting,
    )
    if not quiet:
        typer.echo(js.read_text() if as_json else md.read_text())
        typer.echo(f"wrote {md} and {js}", err=True)


@app.command()
def reproduce(
    preset: str = typer.Option(
        "tiny-parallel",
        "--preset",
        "-p",
        help="Study preset: a geometry preset name, or tiny-quick (a first result in minutes, docs/study.md).",
    ),
    scale: str | None = typer.Option(
        None, "--scale", help="Run the paper's three settings at a scale (tiny, small, paper) instead of one preset."
    ),
    out: Path | None = typer.Option(
        None, "--out", "-o", help="Output directory (default runs/<preset> or runs/<scale>)."
    ),
    n: int | None = typer.Option(None, "--n", help="Override the number of samples of the preset."),
    no_motion: bool = typer.Option(False, "--no-motion", help="The unperturbed sanity case."),
    models: str | None = typer.Option(
        None,
        "--models",
        help="Comma-separated post-processing networks, or 'none' (default: the preset's; tiny-quick: unet,ciunet-res; "
        "the others: unet,cinn,cinn-res,ciunet,ciunet-res).",
    ),
    seed: int = typer.Option(0, "--seed", help="Seed of the data set(s)."),
    seeds: int = typer.Option(1, "--seeds", help="Training seeds per network row (spread in the conclusion checks)."),
    precision: str | None = typer.Option(
        None,
        "--precision",
        help="Training precision fp32 | bf16 | auto (default: the study's; tiny: auto, i.e. bf16 where the CPU or "
        "GPU runs it natively, else fp32; small, paper: fp32).",
    ),
    plan: bool = typer.Option(False, "--plan", help="Print the stages, jobs, disk and time estimates; run nothing."),
    cores: int = typer.Option(2, "--cores", help="With --plan: CPU cores to plan for."),
    gpus: int = typer.Option(0, "--gpus", help="With --plan: GPUs for training and prediction."),
    gpu_speedup: float | None = typer.Option(
        None, "--gpu-speedup", help="With --plan and --gpus: one GPU's speed relative to one CPU core (not measured)."
    ),
    workers: int = WORKERS,
    scheduler: str | None = SCHEDULER,
    quiet: bool = QUIET,
) -> None:
    """Run the study end to end: generate, reconstruct, train, predict, evaluate, report.

    Every stage is cached in the output directory: a second run only redoes what is
    missing, and a killed run resumes. The report (Markdown and a self-contained HTML file)
    puts the paper's numbers next to ours and checks the paper's conclusions.
    """
    from .study.runner import reproduce_scale, reproduce_study

    chosen = None if models is None else _model_list(models)
    if scale is not None and (n is not None or no_motion):
        raise NanoctError("--n and --no-motion apply to one --preset; --scale runs the study's three settings")
    study = _study_with_precision(scale, preset, precision)
    if plan:
        from .study.plan import format_plan, plan_study

        typer.echo(
            format_plan(
                plan_study(
                    scale,
                    preset=preset,
                    perturbed=not no_motion,
                    n=n,
                    models=chosen,
                    study=study,
                    seeds=seeds,
                    cores=cores,
                    gpus=gpus,
                    gpu_speedup=gpu_speedup,
                )
            )
        )
        return
    run = dict(out=out, models=chosen, study=study, seed=seed, seeds=seeds, workers=workers, scheduler=scheduler)
    run["progress"] = not quiet
    _precision_note(study.precision)
    if scale is not None:
        report = reproduce_scale(scale, **run)
    else:
        report = reproduce_study(preset, n=n, perturbed=not no_motion, **run)
    typer.echo(report.read_text())
    typer.echo(f"report: {report} (and {report.with_suffix('.html').name})", err=True)


def _model_list(models: str) -> tuple[str, ...]:
    """``reproduce --models``: the comma-separated networks, ``()`` for ``none``."""
    return () if models.strip() == "none" else tuple(m.strip() for m in models.split(",") if m.strip())


def _study_with_precision(scale: str | None, preset: str, precision: str | None) -> Any:
    """The study of ``reproduce --scale``/``--preset``, with ``--precision`` where given."""
    from dataclasses import replace

    from .study.config import preset_study, scale_study

    study = scale_study(scale) if scale is not None else preset_study(preset)
    if precision is None:
        return study
    from .learn.train import check_precision

    return replace(study, precision=check_precision(precision, "--precision"))


def _precision_note(precision: str) -> None:
    """Say which precision the training runs take here, and why where that is not bfloat16 natively."""
    from .learn.train import native_bf16, resolve_device, resolve_precision

    device = resolve_device()
    taken, native = resolve_precision(precision, device), native_bf16(device)
    why = ""
    if taken == "bf16" and not native:
        why = f" (emulated on this {device.type.upper()}: 5-9x slower than fp32; --precision auto takes fp32 here)"
    elif precision == "auto" and taken == "fp32":
        why = (
            f" ({device.type.upper()} without native bfloat16, where bfloat16 steps are 5-9x slower); the tiny "
            "study's tables in docs/results.md were trained in bf16, so this run's networks and tables differ from "
            "them by training noise (docs/study.md)"
        )
    typer.echo(f"note: training precision {taken}{why}", err=True)


@app.command("shift-test")
def shift_test(
    directory: Path = typer.Argument(..., help="Output directory of 'nanoct reproduce --preset ...'."),
    preset: str = typer.Option("tiny-parallel", "--preset", "-p", help="The study's preset."),
    n: int = typer.Option(20, "--n", help="Test images per shifted set."),
    workers: int = WORKERS,
    quiet: bool = QUIET,
) -> None:
    """Score a study's invertible networks on shifted test sets (motion x0.5 / x1.5, noise, none, other phantoms).

    Coverage of the 90 % intervals, correlation of the std with the error and the share of
    images predict flags as out of distribution, per shifted set next to the study's own test
    split; written to DIRECTORY/shift/shift.{md,json} (cached; a rerun only redoes what is missing).
    """
    from .study.shift import format_shift_table, shift_study

    if n < 1:
        raise NanoctError(f"--n {n} must be a positive number of test images")
    results = shift_study(directory, preset, n=n, workers=workers, progress=not quiet)
    typer.echo(format_shift_table(results))


@app.command()
def scaling(
    out: Path = typer.Option(Path("runs/scaling"), "--out", "-o", help="Output directory of the study."),
    plan: bool = typer.Option(
        False,
        "--plan",
        help="Measure the per-sample and per-step costs here and print the cost of what is left; run nothing.",
    ),
    steps: int = typer.Option(640, "--steps", help="Optimiser steps of every run (the same at every size)."),
    sizes: str = typer.Option("160,640,2560", "--sizes", help="Comma-separated training-set sizes."),
    seeds: str = typer.Option("3,2,2", "--seeds", help="Training seeds at each size (comma-separated)."),
    only: str | None = typer.Option(
        None, "--only", help="Run only the units whose run name matches this shell pattern (e.g. 'unet-dremel-*')."
    ),
    workers: int = WORKERS,
    quiet: bool = QUIET,
) -> None:
    """Data-scaling study: UNet and CiUNetRes on FBP, Dremel and RESESOP (tiny-parallel) trained on
    growing nested training sets for a fixed number of steps, plus 4x the steps at the largest size.

    Resumable: every (network, input, size, seed) is a unit skipped once complete; a killed run
    continues with the same command. The report (report.md, report.json, scaling.png in --out)
    gives the gain over the input per size with the spread over seeds, the paper's gain and the
    paper's conclusion checks at each size.
    """
    from .study.scaling import ScalingStudy, format_scaling_plan, plan_scaling, run_scaling

    try:
        study = ScalingStudy(
            sizes=tuple(int(v) for v in sizes.split(",")), seeds=tuple(int(v) for v in seeds.split(",")), steps=steps
        )
    except ValueError:
        raise NanoctError(f"--sizes {sizes!r} and --seeds {seeds!r} must be comma-separated integers") from None
    if plan:
        typer.echo(format_scaling_plan(plan_scaling(study, out), study))
        return
    report = run_scaling(out, study, only=only, workers=workers, progress=not quiet)
    typer.echo(report.read_text())
    typer.echo(f"report: {report}", err=True)


def _parse_range(text: str | None, flag: str, sep: str) -> tuple[int, int] | None:
    if text is None:
        return None
    try:
        first, stop = (int(v) for v in text.split(sep))
    except ValueError:
        raise NanoctError(f"{flag} {text!r} must be two integers FIRST{sep}STOP, e.g. 10{sep}20") from None
    if not 0 <= first < stop:
        raise NanoctError(f"{flag} {text!r} must satisfy 0 <= FIRST < STOP")
    return first, stop


def _reader_options(
    data_path: str | None,
    key_path: str | None,
    angles_path: str | None,
    units: str | None,
    allow: list[Path],
    tilt: str,
    select: str | None,
) -> Any:
    """The reading options of 'import' and 'stack', checked."""
    from .io.scanio import ReaderOptions

    if units is not None and units not in ("deg", "rad"):
        raise NanoctError(f"--angles-units {units!r}: use deg or rad")
    if tilt not in ("columns", "rows"):
        raise NanoctError(f"--tilt-axis {tilt!r}: use columns (IMOD's, vertical) or rows (horizontal)")
    allowed = tuple(str(a) for a in allow)
    return ReaderOptions(
        data_path, key_path, angles_path, units, tilt, allowed, _parse_range(select, "--angles-select", ":")
    )


@app.command("import")
def import_(
    src: Path = typer.Argument(..., help="Scan: HDF5/NeXus (.h5/.nxs), .tif stack or folder, .npy, or MRC (.mrc/.st)."),
    out: Path = typer.Option(..., "--out", "-o", help="New data-set directory."),
    fmt: str | None = FORMAT,
    angles: str | None = ANGLES,
    angles_select: str | None = ANGLES_SELECT,
    radians: bool = RADIANS,
    angles_units: str | None = ANGLE_UNITS,
    data_path: str | None = DATA_PATH,
    image_key_path: str | None = KEY_PATH,
    angles_path: str | None = ANGLES_PATH,
    allow_outside: list[Path] = ALLOW,
    tilt_axis: str = TILT_AXIS,
    flats: Path | None = FLATS,
    darks: Path | None = DARKS,
    line_integrals: bool = LINE_INTEGRALS,
    rows: str | None = ROWS,
    crop: str | None = CROP,
    binning: int = typer.Option(
        1, "--binning", help="Average this many detector columns (and rows); a remainder is left out, with a note."
    ),
    center_offset: str = typer.Option(
        "0",
        "--center-offset",
        help="Rotation axis minus the raw detector centre, in raw pixels (TomoPy center - (L-1)/2), or auto "
        "(every estimator: opposite views, find_center_vo, centroids; see docs/measured_data.md).",
    ),
    size: int | None = typer.Option(
        None, "--size", help="Image size N (default: detector columns after crop/binning; at most 4 times them)."
    ),
    tolerance: float = typer.Option(
        1e-3,
        "--tolerance",
        help="Largest fraction of non-positive flat/dark-corrected values (dead pixels), filled from their row.",
    ),
    entry: str | None = ENTRY,
    drop_bad_views: bool = typer.Option(
        False, "--drop-bad-views", help="Leave out projections (and flats/darks) holding NaN or infinite values."
    ),
    outliers: float | None = OUTLIERS,
    outlier_size: int = OUTLIER_SIZE,
    outlier_kind: str = OUTLIER_KIND,
    open_beam: bool = OPEN_BEAM,
    air_columns: str | None = AIR_COLUMNS,
    open_beam_degree: str = OPEN_BEAM_DEGREE,
    delta_beta: float | None = DELTA_BETA,
    energy_kev: float | None = ENERGY,
    distance_m: float | None = DISTANCE,
    pixel_size_m: float | None = PIXEL,
    stripes: str | None = STRIPES,
    stripe_params: str | None = STRIPE_PARAMS,
    quiet: bool = QUIET_OUTPUT,
) -> None:
    """Import a measured parallel-beam scan: one sample per detector row, all sharing one motion.

    Flat/dark correction and -log, slice selection, cropping and binning; the view angles come
    from the file (NXtomo rotation_angle in its units, other HDF5 layouts in theirs, Data
    Exchange theta: degrees, IMOD .rawtlt/.tlt next to an MRC stack) or --angles, the pixel size
    from NXtomo or the MRC header. An HDF5 file of a known layout (NXtomo, Diamond's scan NeXus,
    Data Exchange) is read without options; any other with --data-path (and --image-key-path,
    --angles-path). External links and virtual datasets are followed only below the file's
    folder (and --allow-outside folders). Corrections (off by default, recorded with the data
    set): outliers, the open beam from air, Paganin phase retrieval, stripe removal. The data
    set has no ground truth: reconstruct it (Dremel estimates one shift per view for the whole
    stack), post-process it with a network trained on data simulated with its geometry, and
    export the images.
    """
    if line_integrals and _given(import_, locals(), ["tolerance"]):
        raise NanoctError(f"--tolerance {tolerance:g}: for the flat/dark correction, which --line-integrals skips")
    store = _import_from_flags(
        src, out, locals(), binning=binning, center_offset=_parse_center(center_offset), size=size,
        tolerance=tolerance, drop_bad=drop_bad_views,
    )  # fmt: skip
    if not quiet:
        _echo_import(store)


def _import_from_flags(src: Path, out: Path, flags: dict[str, Any], **settings: Any) -> Any:
    """:func:`~nanoct.io.scanio.import_scan` with the reading and correction flags ``import`` and ``stack`` share.

    ``flags`` holds the command's parameters by name (its ``locals()``); ``settings`` the
    import's other keywords (binning, axis, ...), which only ``import`` offers.
    """
    from .io.scanio import import_scan

    f = flags
    row_range = _parse_range(f["rows"], "--rows", ":")
    for name, needed in _NEEDS.items():
        alone = _given(import_, f, [name])
        if alone and not _given(import_, f, [needed]):
            flag, other = next(iter(alone)), _long_flag(_option_infos(import_)[needed])
            raise NanoctError(f"{flag} {alone[flag]}: used only with {other} (add {other}, or drop {flag})")
    corrections = _corrections(
        f["outliers"], f["outlier_size"], f["outlier_kind"], f["open_beam"], f["air_columns"], f["open_beam_degree"],
        (f["delta_beta"], f["energy_kev"], f["distance_m"], f["pixel_size_m"]), f["stripes"], f["stripe_params"],
    )  # fmt: skip
    return import_scan(
        src, out, **_read_settings(f), rows=None if row_range is None else slice(*row_range),
        crop=_parse_range(f["crop"], "--crop", ","), corrections=corrections, **settings,
    )  # fmt: skip


def _read_settings(flags: dict[str, Any]) -> dict[str, Any]:
    """The keywords of :func:`~nanoct.io.scanio.read_scan` that the reading flags of ``import`` and ``stack`` give,
    other than the rows and columns."""
    f = flags
    options = _reader_options(
        f["data_path"], f["image_key_path"], f["angles_path"], f["angles_units"], f["allow_outside"],
        f["tilt_axis"], f["angles_select"],
    )  # fmt: skip
    return {
        "fmt": f["fmt"], "angles_file": f["angles"], "degrees": not f["radians"], "flats": f["flats"],
        "darks": f["darks"], "is_line_integral": f["line_integrals"], "entry": f["entry"], "options": options,
    }  # fmt: skip


def _corrections(
    outliers: float | None,
    outlier_size: int,
    outlier_kind: str,
    open_beam: bool,
    air_columns: str | None,
    open_beam_degree: str,
    paganin: tuple[float | None, float | None, float | None, float | None],
    stripes: str | None,
    stripe_params: str | None,
) -> Any:
    """The :class:`~nanoct.preprocess.pipeline.Corrections` the import flags ask for (None: none)."""
    from .preprocess import Corrections, parse_columns, parse_stripe_params

    delta_beta, energy, distance, pixel = paganin
    degree: int | str = (
        open_beam_degree
        if open_beam_degree == "auto"
        else _parse_ints(open_beam_degree, "--open-beam-degree", low=0)[0]
    )
    corrections = Corrections(
        outliers=outliers, outlier_size=outlier_size, outlier_kind=outlier_kind, open_beam=open_beam,
        air_columns=None if air_columns is None else parse_columns(air_columns), open_beam_degree=degree,
        delta_beta=delta_beta, energy_kev=energy, distance_m=distance, pixel_size_m=pixel, stripes=stripes,
        stripe_params={} if stripe_params is None else parse_stripe_params(stripe_params),
    )  # fmt: skip
    return None if corrections == Corrections() else corrections


def _echo_import(store: Any) -> None:
    g = store.geometry
    scan = store.meta.get("scan") or {}
    pixel = f", pixel {scan['pixel_size_m'][0] * 1e9:.4g} nm" if scan.get("pixel_size_m") else ""
    typer.echo(
        f"{store.path}: {store.n} slice(s), {g.n_angles} views x {g.n_det} detector pixels, image {g.n}x{g.n}, "
        f"axis offset {g.center_offset:+.2f} px{pixel} ({scan.get('format')})"
    )
    for note in scan.get("notes", []):
        typer.echo(f"note: {note}", err=True)
    binned = (scan.get("binning") or 1) > 1 or scan.get("crop")
    raw = "; values in unbinned detector pixels from the centre of the columns read" if binned else ""
    for note in (scan.get("axis") or {}).get("notes", []):  # --center-offset auto: estimators that disagree
        if note.startswith("warning"):
            typer.echo(note + raw, err=True)


def _parse_center(text: str) -> float | str:
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return float(text)
    except ValueError:
        raise NanoctError(f"--center-offset {text!r}: give a number of pixels or 'auto'") from None


@app.command()
def stack(
    source: Path = typer.Argument(
        ..., help="Data-set store, or a scan file: streamed into --out, or imported into --store first."
    ),
    store_dir: Path | None = typer.Option(None, "--store", help="With a scan file: the new data set to import into."),
    out: Path | None = typer.Option(
        None, "--out", "-o", help="With a scan file: stream it block by block into this Zarr group (bounded memory)."
    ),
    block: int | None = typer.Option(None, "--block", help="With --out: detector rows per block (default 16)."),
    method: str = typer.Option(
        "fbp", "--method", "-m", help="Each slice: fbp | gridrec (FBP in Fourier space) | dremel (fixed) | resesop."
    ),
    eta: str = typer.Option(
        "auto",
        "--eta",
        help="resesop: uncertainty level per view: auto (half the FBP's largest residual) | NUMBER | FILE.npy (K,).",
    ),
    center_offset: str = typer.Option("auto", "--center-offset", help="Axis offset in detector pixels, or auto."),
    motion_slices: str = typer.Option("auto", "--motion-slices", help="auto (up to 4) | all | 0,5,9"),
    binning: int = typer.Option(
        8,
        "--binning",
        help="Binning of the coarse Dremel estimate (used with --refine, or where autofocus is rejected).",
    ),
    coarse_iter: int = typer.Option(8, "--coarse-iter", help="Dremel iterations on the binned data (0: none)."),
    refine: str = typer.Option(
        "auto",
        "--refine",
        help="Dremel + projection matching with these binnings, e.g. 2,2,1, air seen or not (auto: the views' "
        "centroids where air is seen, else autofocus + matching; see docs).",
    ),
    model: str | None = typer.Option(None, "--model", help="DEGREE,HARMONICS: use a smooth model of the motion."),
    name: str | None = typer.Option(None, "--name", help="Output name (default METHOD_stack).", callback=_check_name),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing result of that name."),
    fmt: str | None = FORMAT,
    angles: str | None = ANGLES,
    angles_select: str | None = ANGLES_SELECT,
    radians: bool = RADIANS,
    angles_units: str | None = ANGLE_UNITS,
    data_path: str | None = DATA_PATH,
    image_key_path: str | None = KEY_PATH,
    angles_path: str | None = ANGLES_PATH,
    allow_outside: list[Path] = ALLOW,
    tilt_axis: str = TILT_AXIS,
    flats: Path | None = FLATS,
    darks: Path | None = DARKS,
    line_integrals: bool = LINE_INTEGRALS,
    rows: str | None = ROWS,
    crop: str | None = CROP,
    entry: str | None = ENTRY,
    outliers: float | None = OUTLIERS,
    outlier_size: int = OUTLIER_SIZE,
    outlier_kind: str = OUTLIER_KIND,
    open_beam: bool = OPEN_BEAM,
    air_columns: str | None = AIR_COLUMNS,
    open_beam_degree: str = OPEN_BEAM_DEGREE,
    delta_beta: float | None = DELTA_BETA,
    energy_kev: float | None = ENERGY,
    distance_m: float | None = DISTANCE,
    pixel_size_m: float | None = PIXEL,
    stripes: str | None = STRIPES,
    stripe_params: str | None = STRIPE_PARAMS,
    workers: int = WORKERS,
    scheduler: str | None = SCHEDULER,
    quiet: bool = QUIET,
) -> None:
    """Whole measured stack: one motion and rotation axis (coarse to fine), then every slice (resumable).

    Given a scan file and --out, streams it block by block of detector rows (memory bounded by a
    block, resumable by block; docs/commands.md). Given a scan file and --store, imports it first
    with the reading and correction options of 'nanoct import' (--format, --angles, --data-path,
    --open-beam, --stripes ...; the axis is then estimated here, not at import).
    Ends with a summary: the axis and how it was found, the range of the motion, where the
    slices are, and the slices whose Dremel refinement ran away (they keep the stack's motion).
    """
    from .io.store import DataStore
    from .workflows.stack import reconstruct_stack

    flags = dict(locals())
    source = _stack_source(source, flags)
    if source is None:  # streamed into --out
        return
    written = reconstruct_stack(
        source, method=method, center=_parse_center(center_offset), motion_slices=motion_slices,
        binning=binning, coarse_iter=coarse_iter, model=_parse_model(model), eta=_parse_eta(eta),
        refine=None if refine == "auto" else _parse_ints(refine, "--refine"),
        name=name, overwrite=overwrite, workers=workers, scheduler=scheduler, progress=not quiet,
    )  # fmt: skip
    store = DataStore.open(source)
    typer.echo(_stack_summary(store, written) + _note_unused_dremel(flags, store.recons.motion_info(written) or {}))


def _note_unused_dremel(flags: dict[str, Any], info: dict[str, Any]) -> str:
    """A summary line where ``--binning`` / ``--coarse-iter`` were given but the views' centroids gave the
    motion ("" elsewhere)."""
    given = _given(stack, flags, ("binning", "coarse_iter")) if info.get("horizontal_method") == "centroid" else {}
    if not given:
        return ""
    return (
        f"\n  note     {', '.join(given)} not used: air is seen around the object, so the views' centroids gave "
        "the motion; add --refine (e.g. 2,2,2,1) for Dremel and projection matching with them"
    )


def _stack_source(source: Path, flags: dict[str, Any]) -> Any:
    """The data set ``nanoct stack`` works on: ``source``, or the scan file imported into ``--store``.

    A scan file with ``--out`` is streamed here instead (its summary printed; ``None`` returned).
    ``flags`` holds the command's parameters by name (its ``locals()``): an option that does not
    apply to ``source`` is refused.
    """
    f = flags
    store_dir, out, block = f["store_dir"], f["out"], f["block"]
    if f["eta"] != "auto" and f["method"] != "resesop":
        raise NanoctError(f"--eta {f['eta']}: RESESOP's uncertainty level, used only with --method resesop")
    if (source / "zarr.json").is_file():
        scan_only = _given(stack, f, ["store_dir", "out", "block"])
        if scan_only:
            raise NanoctError(
                f"{', '.join(scan_only)}: for a scan file (--out streams it, --block sets its blocks, --store imports "
                f"it); {source} is a data set (drop {'them' if len(scan_only) > 1 else 'it'})"
            )
        _refuse_reading(source, f)
        return source
    if out is not None and store_dir is None:
        typer.echo(_stream_stack(source, out, flags))
        return None
    if not source.exists():
        raise NanoctError(
            f"{source} does not exist; give a data set (nanoct import), or a scan file or folder with --out OUT.zarr "
            "or --store NEW_DIR"
        )
    if store_dir is None or out is not None:
        raise NanoctError(
            f"{source} is not a data set: stream the scan file with --out OUT.zarr (memory bounded by a block, "
            "resumable), or import it first with --store NEW_DIR (not both)"
        )
    if block is not None:
        raise NanoctError("--block goes with --out (streaming); a data set made with --store runs slice by slice")
    return _import_from_flags(source, store_dir, flags).path


def _refuse_reading(directory: Path, flags: dict[str, Any]) -> None:
    """Refuse the reading and correction flags given to ``nanoct stack`` on the data set ``directory``: they apply
    when a scan file is read, so the message gives the import that applies them."""
    from .io.store import DataStore

    given = _given(stack, flags, (*_READING, *_CORRECTING))
    if not given:
        return
    try:
        scan = DataStore.open(directory).meta.get("scan") or {}
    except (NanoctError, OSError, KeyError, ValueError):  # the stack itself then says what is wrong
        scan = {"file": "SCAN"}
    names = ", ".join(given)
    if not scan:
        raise NanoctError(f"{names}: reading and correction options are for a scan file; {directory} is simulated")
    words = ["nanoct", "import", str(scan.get("file") or "SCAN"), "--out", "NEW_DIR"]
    for flag, value in given.items():
        values = value if isinstance(value, list) else [value]  # a repeatable option: once per value
        words += [flag] if value is True else [w for v in values for w in (flag, str(v))]
    raise NanoctError(
        f"{names}: reading and correction options apply when importing; the data set {directory} is already "
        f"imported: use {shlex.join(words)} (or give stack the scan file with --store NEW_DIR or --out OUT.zarr)"
    )


#: ``nanoct stack`` options the streaming path (``--out``) does not apply (their defaults: the signature's).
_NOT_STREAMED = ("crop", *_CORRECTING, "name", "eta")


def _stream_stack(src: Path, out: Path, flags: dict[str, Any]) -> str:
    """``nanoct stack SCAN --out OUT.zarr``: the scan streamed block by block (``reconstruct_scan``)."""
    from .workflows.slabs import reconstruct_scan
    from .workflows.stack import fbp_engine

    f = flags
    given = _given(stack, f, _NOT_STREAMED)
    if given:
        raise NanoctError(
            f"{', '.join(given)}: not applied when streaming with --out; import with --store NEW_DIR instead"
        )
    if f["method"] not in ("fbp", "gridrec"):
        raise NanoctError(f"--method {f['method']!r}: streaming with --out runs fbp or gridrec (Fourier space)")
    if fbp_engine("auto") != "gridrec":
        raise NanoctError("streaming with --out needs finufft (pip install finufft); or import with --store NEW_DIR")
    center = _parse_center(f["center_offset"])
    motion_rows: Any = f["motion_slices"]
    if motion_rows not in ("auto", "all"):
        motion_rows = list(_parse_ints(motion_rows, "--motion-slices", low=0))
    elif motion_rows == "all":
        raise NanoctError("--motion-slices all: give auto or the rows to use, e.g. 0,50,100, when streaming")
    read = _read_settings(f)
    written = reconstruct_scan(
        src, out, rows=_parse_range(f["rows"], "--rows", ":"), motion_rows=motion_rows,
        center=None if center == "auto" else float(center), block=16 if f["block"] is None else f["block"],
        read={k: v for k, v in read.items() if v is not None},
        motion={"binning": f["binning"], "coarse_iter": f["coarse_iter"], "model": _parse_model(f["model"]),
                "refine": None if f["refine"] == "auto" else _parse_ints(f["refine"], "--refine")},
        overwrite=f["overwrite"], workers=f["workers"], scheduler=f["scheduler"], progress=not f["quiet"],
    )  # fmt: skip
    return _slab_summary(written, f)


def _slab_summary(out: Path, flags: dict[str, Any]) -> str:
    """What the streaming stack found and wrote (``flags``: the command's, for :func:`_note_unused_dremel`)."""
    import numpy as np
    import zarr

    group = zarr.open_group(str(out), mode="r")
    info, meta = dict(group.attrs.get("info") or {}), dict(group.attrs["nanoct"])
    shifts = info.get("shifts") or [0.0]
    first, stop = meta["rows"]
    done = np.asarray(group["done"][:])  # type: ignore[index]
    lines = [
        f"wrote {out}: rows {first}:{stop} in blocks of {meta['block']}, axis offset "
        f"{info.get('center_offset', float('nan')):+.3f} px, {_how_found(info.get('center_method'))}",
        f"  motion   {min(shifts):+.3f} to {max(shifts):+.3f} px over {len(shifts)} views "
        f"(from rows {info.get('motion_rows')})",
        *_motion_lines(info),
        f"  slices   {int(done.sum())} of {done.size} blocks done; the images are the array 'slices' of {out}",
    ]
    return "\n".join(lines) + _note_unused_dremel(flags, info)


def _parse_model(model: str | None) -> tuple[int, ...] | None:
    """``--model DEGREE,HARMONICS``."""
    smooth = None if model is None else _parse_ints(model, "--model", low=0)
    if smooth is not None and len(smooth) != 2:
        raise NanoctError(f"--model {model!r}: give DEGREE,HARMONICS, e.g. 3,3")
    return smooth


def _how_found(method: str | None) -> str:
    if method == "given":
        return "as given (--center-offset)"
    if method == "estimators":
        return "from every axis estimator on the motion-corrected views"
    return f"found by {method or 'an unrecorded method'}"


def _motion_lines(info: dict[str, Any]) -> list[str]:
    """The summary's lines on the axis estimators, the vertical motion, the axis tilt and the shifts."""
    lines = []
    axis = info.get("axis") or {}
    if axis.get("estimates"):
        values = ", ".join(f"{k} {v:+.2f}" for k, v in axis["estimates"].items())
        lines.append(f"  axis by  {values} px; used: {', '.join(axis.get('used', []))}")
        lines += [f"  {note}" for note in axis.get("notes", []) if note.startswith("warning")]
    vertical = info.get("vertical")
    if vertical is not None and any(vertical):
        lines.append(f"  vertical {min(vertical):+.3f} to {max(vertical):+.3f} px ({info.get('vertical_method')})")
    elif (info.get("vertical_guard") or {}).get("significant") is False:
        lines.append(f"  vertical {info['vertical_guard']['note']}")
    tilt = info.get("tilt") or {}
    if "tilt_deg" in tilt:
        lines.append(f"  tilt     {tilt['tilt_deg']:+.3f} degrees of the axis on the detector")
    lines.append(f"  shifts   by {info.get('horizontal_method', 'an unrecorded method')}")
    from .workflows.stack import consistency_lines

    return lines + consistency_lines(info)


def _stack_summary(store: Any, name: str) -> str:
    """What 'nanoct stack' found and wrote: axis, how it was found, the motion's range, where the slices are."""
    import numpy as np

    info = store.recons.motion_info(name) or {}
    shifts = store.recons.shared_shifts(name)
    g, scan = store.geometry, store.meta.get("scan") or {}
    column = (g.n_det - 1) / 2 + info.get("center_offset", float("nan"))
    lines = [
        f"wrote reconstructions/{name}: axis offset {info.get('center_offset', float('nan')):+.3f} px, "
        f"shift RMS {info.get('shift_rms', float('nan')):.3f} px",
        f"  axis     column {column:.2f} of 0..{g.n_det - 1} (offset {info.get('center_offset', float('nan')):+.3f} "
        f"px from the centre), {_how_found(info.get('center_method'))}",
    ]
    if shifts is not None and np.isfinite(shifts).all():
        size = (scan.get("pixel_size_m") or [None])[0]
        nm = f" ({shifts.min() * size * 1e9:+.4g} to {shifts.max() * size * 1e9:+.4g} nm)" if size else ""
        lines.append(f"  motion   {shifts.min():+.3f} to {shifts.max():+.3f} px over {shifts.size} views{nm}")
    lines += _motion_lines(info)
    done = int(store.reconstruction_done(name).sum())
    lines.append(
        f"  slices   {done} of {store.n} in {store.path}/reconstructions/{name}; "
        f"nanoct export {store.path} --name {name} --out slices.tif"
    )
    from .recon.batch import shift_check_warning

    kept = shift_check_warning(store, name, unit="slice")
    if kept:
        lines.append(f"  warning  {kept}")
    return "\n".join(lines)


def _parse_eta(text: str) -> Any:
    """``--eta``: ``auto``, a number, or a ``.npy`` file of per-view levels (checked by the stack)."""
    if text == "auto":
        return text
    if text.endswith(".npy"):
        import numpy as np

        if not Path(text).is_file():
            raise NanoctError(f"--eta {text!r}: no such file; give auto, a number or a .npy file of per-view levels")
        return np.load(text)
    try:
        return float(text)
    except ValueError:
        raise NanoctError(f"--eta {text!r}: give auto, a number >= 0 or a .npy file of per-view levels") from None


def _parse_ints(text: str, flag: str, low: int = 1) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise NanoctError(f"{flag} {text!r}: give comma-separated whole numbers, e.g. 2,2,1") from None
    if not values or min(values) < low:
        raise NanoctError(f"{flag} {text!r}: every value must be >= {low}")
    return values


@app.command()
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
    from .io.scanio import write_images
    from .io.shiftfile import write_stack_shifts
    from .io.store import DataStore
    from .recon.shared import write_store_shifts

    if out.suffix.lower() == ".txt":
        path = write_stack_shifts(DataStore.open(directory), name, out)
        path = path or write_store_shifts(directory, name, out, sample=index)
        if not quiet:
            typer.echo(f"wrote the shifts of reconstructions/{name} to {path}")
        return
    store = DataStore.open(directory)
    if name not in store.reconstruction_names():
        known = ", ".join(store.reconstruction_names()) or "none"
        raise NanoctError(f"--name {name!r}: no such reconstruction in {directory} (present: {known})")
    idx = store.indices(split)
    idx = idx[store.reconstruction_done(name, idx)]
    if idx.size == 0:
        raise NanoctError(f"reconstructions/{name} has no finished sample in split '{split}'; reconstruct it first")
    if (std or interval is not None) and not store.has_uncertainty(name):
        raise NanoctError(f"reconstructions/{name} has no std (only invertible networks give one)")
    if interval is not None:
        from .learn.calibration import half_width

        std, mean = store.read_uncertainty(name, idx), store.read_reconstruction(name, idx)
        images = half_width(store.reconstruction_params(name), std, interval, guaranteed, mean=mean).astype("float32")
        content = f"half-width of the {interval:g} interval"
    elif std:
        images, content = store.read_uncertainty(name, idx), "std"
    else:
        images, content = store.read_reconstruction(name, idx), "image"
    attrs = {"store": str(store.path), "name": name, "content": content, "samples": str(idx.tolist())}
    path = write_images(out, images, attrs=attrs)
    if not quiet:
        typer.echo(f"wrote {idx.size} {content} map(s) of reconstructions/{name} to {path}")


def _expected_error(exc: BaseException) -> str | None:
    """The one-line message for an expected failure, or None for a bug."""
    if isinstance(exc, (NanoctError, ValueError)):
        return str(exc)
    if isinstance(exc, MemoryError):
        return (
            "not enough memory for this request; ask for less at once (a smaller --n, preset, --size, --tile, "
            "--samples or --batch-size, or fewer rows), or run it on a machine with more memory"
        )
    if isinstance(exc, OSError):
        where = " ".join(str(f) for f in (exc.filename, exc.filename2) if f)
        reason = exc.strerror or errno.errorcode.get(exc.errno or 0) or str(exc)
        denied = "check its permissions, or write somewhere else"
        again = "run the same command again (it resumes where it stopped)"
        free = free_space(exc.filename) if exc.filename else None
        free_text = "" if free is None else f" ({free / 2**20:.1f} MiB free)"
        hints = {
            errno.EACCES: denied,
            errno.EPERM: denied,
            errno.EROFS: denied,
            errno.ENOSPC: f"free some disk space{free_text} and {again}",
            errno.EIO: f"the device reported a read or write error: check the disk, then {again}",
        }
        hint = hints.get(exc.errno or 0, "check the path")
        return f"{reason}: {where or '?'}; {hint}"
    return None


def _usage_message(exc: Exception) -> str:
    """One line for a click usage error: its message (with typer's hint) and where the help is."""
    message = " ".join(exc.format_message().split())  # type: ignore[attr-defined]
    ctx = getattr(exc, "ctx", None)
    return f"{message.rstrip('.')} (see '{ctx.command_path} --help')" if ctx is not None else message


def run(argv: list[str] | None = None) -> int:
    """Run the CLI on ``argv`` (default ``sys.argv[1:]``) and return the exit status.

    Every expected failure (a usage error such as an unknown option or a value of the wrong
    type, a :class:`NanoctError`, bad numbers, a file-system error, not enough memory)
    becomes one ``error:`` line and status 2; Ctrl-C prints how to resume and
    gives 130; anything else is a bug: its traceback is printed with a request to report it
    (status 1).
    """
    try:
        # typer turns Ctrl-C into exit status 130, returned (not raised) without standalone mode
        code = app(args=argv, prog_name="nanoct", standalone_mode=False)
    except (KeyboardInterrupt, typer.Abort):
        code = 130
    except typer.Exit as exc:
        code = exc.exit_code
    except _CLICK.ClickException as exc:  # usage errors: unknown option or command, missing or bad value
        if type(exc).__name__ == "NoArgsIsHelpError":  # 'nanoct' alone: the help text
            exc.show()
            return 2
        typer.secho(f"error: {_usage_message(exc)}", fg=typer.colors.RED, err=True)
        return 2
    except Exception as exc:  # the one error boundary of the CLI
        message = _expected_error(exc)
        if message is None:
            traceback.print_exc()
            typer.secho(
                "this is a bug in nanoct; please report it with the command and the traceback above",
                fg=typer.colors.RED,
                err=True,
            )
            return 1
        typer.secho(f"error: {_as_flags(' '.join(message.split()))}", fg=typer.colors.RED, err=True)
        return 2
    if code == 130:
        typer.secho("interrupted; run the same command again to resume", fg=typer.colors.YELLOW, err=True)
    return code if isinstance(code, int) else 0


def _show_warning(message: Warning | str, category: type[Warning], *args: Any, **kwargs: Any) -> None:
    """A warning on the command line: one ``warning:`` line, without Python's source location; nanoct's own
    with its parameters written as flags, another library's with its category."""
    text = " ".join(str(message).split())
    own = category is UserWarning or category.__module__.startswith("nanoct")  # nanoct warns with these
    line = _as_flags(text) if own else f"{category.__name__}: {text}"
    typer.secho(f"warning: {line}", fg=typer.colors.YELLOW, err=True)


def main() -> None:
    """Entry point: :func:`run` on the command line, exit with its status.

    Warnings print as ``warning:`` lines. After Ctrl-C the process ends at once (``os._exit``), as
    a kill would, which every command survives: the teardown of background threads still running
    (the stores' I/O loop, torch's workers) could otherwise abort it (status 134) after the resume
    hint was printed.
    """
    warnings.showwarning = _show_warning
    code = run()
    if code == 130:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(130)
    sys.exit(code)
