"""Learning commands: ``train`` a post-processing network and ``predict`` with it."""

from __future__ import annotations

from pathlib import Path

import typer

from ..core.errors import NanoctError
from .options import QUIET
from .output import print_ood, reconstructions, written
from .parsing import check_device, parse_levels, parse_params


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
    from ..learn.train import TrainConfig
    from ..learn.train import train as train_model

    check_device(device)
    run = out or Path(directory).resolve().parent / "runs" / f"{model}-{input_name}"
    config = TrainConfig(
        model,
        input_name,
        epochs=epochs,
        batch_size=batch_size,
        lr=lr,
        seed=seed,
        scheduler=lr_schedule,
        model_kwargs=parse_params(param) or None,
        clip_grad=clip_grad,
        precision=precision,
        max_steps=max_steps,
        device=device,
        num_workers=num_workers,
        patch=patch,
    )
    path = train_model(directory, run, config, progress=not quiet)
    typer.echo(f"run: {path}")


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
    from ..learn.predict import predict as predict_model

    check_device(device)
    if samples is not None and samples <= 0:
        raise NanoctError(f"--samples {samples} must be a positive number of latent samples")
    kwargs = ({} if samples is None else {"n_samples": samples}) | ({"antithetic": True} if antithetic else {})
    before = reconstructions(directory)
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
        levels=tuple(parse_levels(levels)),
        tile=tile,
        overlap=tile_overlap,
        name=out_name,
        calibrate_on=calibrate_on,
    )
    typer.echo(written(directory, name, before))
    print_ood(directory, name)
