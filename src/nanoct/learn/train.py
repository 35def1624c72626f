"""Training loop shared by every post-processing network (single process or DDP via torchrun).

A run directory holds::

    config.json   the request (model, architecture, input, data set, optimiser settings)
    last.pt       checkpoint after the last finished epoch (resume point)
    best.pt       checkpoint with the lowest validation loss so far
    log.csv       one row per finished epoch: losses, logged metrics, learning rate, seconds

Resume: calling :func:`train` again with the same request continues after the last finished
epoch (a larger ``epochs`` extends a finished run). Every epoch reseeds torch, numpy and
``random`` from (seed, epoch, rank) and shuffles with a sampler seeded by (seed, epoch), so a
resumed run on CPU ends with exactly the weights of an uninterrupted one.

Multi-process: ``torchrun --nproc_per_node P -m nanoct.learn.train STORE --model unet ...``
(``WORLD_SIZE > 1``) initialises a process group (NCCL on CUDA, gloo on CPU), splits each
global batch of ``batch_size`` over the processes, averages gradients with DDP and lets only
rank 0 write files.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import os
import random
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
from torch import nn
from torch.utils.data import DataLoader, DistributedSampler, Subset

from .. import __version__
from ..errors import NanoctError
from ..fileio import atomic_write_bytes, remove_stale_temporaries
from ..store import DataStore
from .base import PostProcessor
from .checkpoint import load_checkpoint, save_checkpoint, set_rng_state
from .data import ReconDataset
from .models import build_model, model_spec

__all__ = ["cosine_lr", "main", "resolve_device", "seed_everything", "train"]

SCHEDULERS = ("none", "plateau", "cosine")
PLATEAU = {"factor": 0.5, "patience": 10, "min_lr": 1e-7}
COSINE_MIN_FRACTION = 0.1  # cosine annealing ends at lr / 10 (dival's UNet: 1e-3 -> 1e-4)
# keys of config.json that must agree for a run to be resumed
MATCH_KEYS = ("model", "hparams", "input", "data", "image_size", "batch_size", "lr", "seed", "clip_grad", "scheduler")


def resolve_device(device: str | torch.device | None = None, local_rank: int = 0) -> torch.device:
    """``device`` as given, else CUDA (``cuda:<local_rank>``) when available, else CPU."""
    if device is not None:
        dev = torch.device(device)
        if dev.type == "cuda" and not torch.cuda.is_available():
            raise NanoctError(f"device {device} was requested but CUDA is not available here")
        return dev
    return torch.device(f"cuda:{local_rank}") if torch.cuda.is_available() else torch.device("cpu")


def seed_everything(*keys: int) -> int:
    """Seed torch, numpy's global generator and ``random`` from a tuple of integers."""
    s = int(np.random.SeedSequence([int(k) for k in keys]).generate_state(1, dtype=np.uint64)[0] % (2**63 - 1))
    torch.manual_seed(s)
    np.random.seed(s % 2**32)
    random.seed(s)
    return s


def _worker_init(_: int) -> None:
    s = torch.initial_seed() % 2**32
    np.random.seed(s)
    random.seed(s)


class _LossModule(nn.Module):
    """Makes ``model.loss`` the forward pass, so DDP sees (and synchronises) the backward."""

    def __init__(self, model: PostProcessor) -> None:
        super().__init__()
        self.module = model

    def forward(self, x_tilde: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, dict[str, float]]:
        return self.module.loss(x_tilde, x)


def cosine_lr(lr: float, epoch: int, epochs: int) -> float:
    """Learning rate of the 1-based ``epoch`` of ``epochs`` under cosine annealing to ``lr / 10``.

    Parameters
    ----------
    lr : float
        Initial learning rate (that of epoch 1).
    epoch, epochs : int
        The epoch (1-based) and the number of epochs of the schedule.

    Returns
    -------
    float
        ``lr_min + (lr - lr_min) (1 + cos(pi (epoch - 1) / epochs)) / 2``, ``lr_min = lr / 10``;
        the values of :class:`torch.optim.lr_scheduler.CosineAnnealingLR` with ``T_max=epochs``
        stepped once per epoch.
    """
    lr_min = lr * COSINE_MIN_FRACTION
    return lr_min + (lr - lr_min) * (1.0 + math.cos(math.pi * (epoch - 1) / epochs)) / 2.0


def _atomic_json(path: Path, obj: Any) -> None:
    atomic_write_bytes(path, (json.dumps(obj, indent=2, sort_keys=True) + "\n").encode())


def _write_log(path: Path, history: list[dict[str, Any]]) -> None:
    if not history:
        path.unlink(missing_ok=True)  # a log without a checkpoint behind it
        return
    fields = ["epoch", "train_loss", "val_loss"]
    extra = sorted({k for row in history for k in row} - set(fields) - {"lr", "best", "seconds", "steps"})
    fields += extra + ["lr", "best", "steps", "seconds"]
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fields, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    writer.writerows(history)
    atomic_write_bytes(path, buf.getvalue().encode())


def _diff(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    return [k for k in MATCH_KEYS if a.get(k) != b.get(k)]


def _to(t: torch.Tensor, device: torch.device, channels_last: bool) -> torch.Tensor:
    t = t.to(device, non_blocking=True)
    return t.contiguous(memory_format=torch.channels_last) if channels_last else t


def train(
    store_path: str | os.PathLike[str],
    model_name: str = "unet",
    input_name: str = "fbp",
    out_dir: str | os.PathLike[str] = "runs/unet-fbp",
    *,
    epochs: int | None = None,
    batch_size: int | None = None,
    lr: float | None = None,
    seed: int = 0,
    device: str | torch.device | None = None,
    progress: bool = True,
    max_steps: int | None = None,
    model_kwargs: dict[str, Any] | None = None,
    clip_grad: float | None = None,
    scheduler: str | None = None,
    num_workers: int = 0,
    in_memory: bool | None = None,
    channels_last: bool | None = None,
    on_epoch_end: Callable[[int, dict[str, Any]], None] | None = None,
) -> Path:
    """Train a post-processing network on ``reconstructions/<input_name>`` -> phantoms.

    Parameters
    ----------
    store_path : path
        Data-set store with ``reconstructions/<input_name>`` for the train and val splits.
    model_name : str
        Registered model (:func:`nanoct.learn.models.model_names`), e.g. "unet".
    input_name : str
        Input reconstruction, e.g. "fbp", "dremel".
    out_dir : path
        Run directory (created; resumed when it holds a run of the same request).
    epochs, batch_size, lr : optional
        Default: the model's registry entry (UNet: 500 epochs, batch 16, lr 1e-3, as in the
        paper). ``batch_size`` is the global batch, split over DDP processes.
    seed : int
        Seeds the initial weights, the shuffling and every epoch's random state.
    device : str, optional
        Default: CUDA when available, else CPU.
    progress : bool
        Progress bars (rank 0 only).
    max_steps : int, optional
        Stop after this many optimizer steps in total (the epoch in progress is then
        validated and checkpointed as finished); for smoke tests.
    model_kwargs : dict, optional
        Architecture keyword arguments (e.g. ``{"channels": [8, 8, 16, 16, 32]}``).
    clip_grad : float, optional
        Gradient-norm clipping (default: the model's; 0 disables).
    scheduler : {"none", "plateau", "cosine"}, optional
        Learning-rate schedule (default: the model's). "plateau": ReduceLROnPlateau on the
        validation loss, factor 0.5, patience 10 epochs. "cosine": cosine annealing per epoch
        from ``lr`` in the first epoch to ``lr / 10`` after the last (dival's UNet schedule,
        ``CosineAnnealingLR(T_max=epochs)``); a computed function of (epoch, epochs), so a
        resumed run follows the same curve and an extended run follows the new one.
    num_workers : int
        DataLoader worker processes.
    in_memory : bool, optional
        See :class:`~nanoct.learn.data.ReconDataset`.
    channels_last : bool, optional
        Default: True on CPU (faster convolutions there), False on CUDA.
    on_epoch_end : callable, optional
        ``f(epoch, row)`` after each epoch's checkpoint and log are written (rank 0).

    Returns
    -------
    Path
        The run directory.

    Raises
    ------
    NanoctError
        Missing or incomplete input, empty split, unknown model or bad settings, or an
        existing run in ``out_dir`` made with another request.
    """
    spec = model_spec(model_name)
    epochs = spec.epochs if epochs is None else int(epochs)
    batch_size = spec.batch_size if batch_size is None else int(batch_size)
    lr = spec.lr if lr is None else float(lr)
    clip = spec.clip_grad if clip_grad is None else (float(clip_grad) or None)
    sched = (spec.scheduler or "none") if scheduler is None else str(scheduler)
    if epochs < 1 or batch_size < 1 or not lr > 0 or (max_steps is not None and max_steps < 1):
        raise NanoctError(
            f"epochs ({epochs}), batch size ({batch_size}), lr ({lr}) and max steps ({max_steps}) must be positive"
        )
    if sched not in SCHEDULERS:
        raise NanoctError(f"scheduler {sched!r} is unknown; use one of {', '.join(SCHEDULERS)}")

    # ---------------------------------------------------------------- processes and device
    world = int(os.environ.get("WORLD_SIZE", "1"))
    local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    dev = resolve_device(device, local_rank)
    own_group = False
    if world > 1 and not dist.is_initialized():
        if dev.type == "cuda":
            torch.cuda.set_device(dev)
        dist.init_process_group("nccl" if dev.type == "cuda" else "gloo")
        own_group = True
    distributed = world > 1 and dist.is_initialized()
    rank = dist.get_rank() if distributed else 0
    world = dist.get_world_size() if distributed else 1
    local_batch = batch_size // world
    use_cl = (dev.type == "cpu") if channels_last is None else bool(channels_last)
    main_rank = rank == 0

    try:
        if batch_size % world:
            raise NanoctError(f"batch size {batch_size} is not divisible by the {world} processes")
        return _train(
            store_path,
            model_name,
            input_name,
            Path(out_dir),
            epochs=epochs,
            batch_size=batch_size,
            local_batch=local_batch,
            lr=lr,
            seed=int(seed),
            dev=dev,
            use_cl=use_cl,
            progress=progress and main_rank,
            max_steps=max_steps,
            model_kwargs=dict(model_kwargs or {}),
            clip=clip,
            sched=sched,
            num_workers=num_workers,
            in_memory=in_memory,
            rank=rank,
            world=world,
            distributed=distributed,
            on_epoch_end=on_epoch_end,
        )
    finally:
        if own_group and dist.is_initialized():
            dist.destroy_process_group()


def _train(
    store_path: Any,
    model_name: str,
    input_name: str,
    out: Path,
    *,
    epochs: int,
    batch_size: int,
    local_batch: int,
    lr: float,
    seed: int,
    dev: torch.device,
    use_cl: bool,
    progress: bool,
    max_steps: int | None,
    model_kwargs: dict[str, Any],
    clip: float | None,
    sched: str,
    num_workers: int,
    in_memory: bool | None,
    rank: int,
    world: int,
    distributed: bool,
    on_epoch_end: Callable[[int, dict[str, Any]], None] | None,
) -> Path:
    from tqdm.auto import tqdm

    main_rank = rank == 0
    train_ds = ReconDataset(store_path, input_name, "train", in_memory=in_memory)
    val_ds = ReconDataset(store_path, input_name, "val", in_memory=in_memory)
    store = DataStore.open(store_path)

    seed_everything(seed, 0x5EED)
    model = build_model(model_name, **model_kwargs)
    config = {
        "model": model_name,
        "hparams": json.loads(json.dumps(model.hparams)),
        "input": input_name,
        "data": {
            "n": store.n,
            "seed": store.seed,
            "geometry": store.geometry.to_dict(),
            "train": len(train_ds),
            "val": len(val_ds),
        },
        "image_size": train_ds.image_size,
        "batch_size": batch_size,
        "lr": lr,
        "seed": seed,
        "clip_grad": clip,
        "scheduler": sched,
        "epochs": epochs,
        "max_steps": max_steps,
        "store": str(Path(store_path).resolve()),
        "world_size": world,
        "device": str(dev),
        "channels_last": use_cl,
        "nanoct_version": __version__,
    }
    config = json.loads(json.dumps(config))

    # ---------------------------------------------------------------- existing run?
    last_path, best_path, cfg_path, log_path = out / "last.pt", out / "best.pt", out / "config.json", out / "log.csv"
    ckpt = None
    if last_path.exists():
        ckpt = load_checkpoint(
            last_path, model_name=model_name, image_size=train_ds.image_size, hparams=config["hparams"]
        )
        old = ckpt.get("config") or {}
    else:
        old = None  # a config.json without last.pt holds no training state (e.g. a run that diverged): redo it
    if old is not None and _diff(config, old):
        raise NanoctError(
            f"{out} holds a run made with other settings (differs in: {', '.join(_diff(config, old))}); "
            "choose another --out, or repeat the original command to resume it"
        )

    model = model.to(dev, memory_format=torch.channels_last) if use_cl else model.to(dev)
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)
    lr_sched = torch.optim.lr_scheduler.ReduceLROnPlateau(optimizer, **PLATEAU) if sched == "plateau" else None
    start_epoch, step, best_val, best_epoch, history = 1, 0, math.inf, 0, []
    if ckpt is not None:
        try:
            model.load_state_dict(ckpt["model_state"])
            optimizer.load_state_dict(ckpt["optimizer_state"])
            if lr_sched is not None and ckpt.get("scheduler_state") is not None:
                lr_sched.load_state_dict(ckpt["scheduler_state"])
        except (RuntimeError, ValueError, KeyError, TypeError) as exc:
            raise NanoctError(
                f"{last_path} does not fit this model ({exc}); delete the run directory or choose another --out"
            ) from exc
        set_rng_state(ckpt.get("rng", {}))
        start_epoch, step = int(ckpt["epoch"]) + 1, int(ckpt.get("step", 0))
        best_val, best_epoch = float(ckpt.get("best_val_loss", math.inf)), int(ckpt.get("best_epoch", 0))
        history = list(ckpt.get("history", []))
    if main_rank:
        out.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(out)  # left by a kill during a checkpoint write
        _atomic_json(cfg_path, config)
        _write_log(log_path, history)  # drops rows of an epoch whose checkpoint was never written
    if start_epoch > epochs or (max_steps is not None and step >= max_steps):
        if main_rank and progress:
            print(f"{out}: already trained to epoch {start_epoch - 1} of {epochs}; nothing to do", file=sys.stderr)
        return out

    # ---------------------------------------------------------------- data
    train_sampler = DistributedSampler(
        train_ds, num_replicas=world, rank=rank, shuffle=True, seed=seed, drop_last=False
    )
    loader_gen = torch.Generator()
    loader_kw: dict[str, Any] = {"num_workers": num_workers, "pin_memory": dev.type == "cuda"}
    if num_workers > 0:
        loader_kw["worker_init_fn"] = _worker_init
    train_loader = DataLoader(
        train_ds, batch_size=local_batch, sampler=train_sampler, generator=loader_gen, **loader_kw
    )
    val_loader = DataLoader(
        Subset(val_ds, list(range(rank, len(val_ds), world))), batch_size=local_batch, shuffle=False, **loader_kw
    )

    if ckpt is None and hasattr(model, "data_init"):
        # data-dependent initialisation (ActNorm) from the same first train images on every
        # rank, before DDP wraps the model
        first = [train_ds[i] for i in range(min(local_batch, len(train_ds)))]
        x_tilde0 = _to(torch.stack([a for a, _ in first]), dev, use_cl)
        x0 = _to(torch.stack([b for _, b in first]), dev, use_cl)
        with torch.no_grad():
            model.data_init(x_tilde0, x0)
    step_model: nn.Module = _LossModule(model)
    if distributed:
        from torch.nn.parallel import DistributedDataParallel

        step_model = DistributedDataParallel(step_model, device_ids=[dev.index] if dev.type == "cuda" else None)

    def reduce(values: list[float]) -> list[float]:
        t = torch.tensor(values, dtype=torch.float64, device=dev if dev.type == "cuda" else "cpu")
        if distributed:
            dist.all_reduce(t)
        return t.tolist()

    epoch_bar = tqdm(
        range(start_epoch, epochs + 1),
        desc=f"train {model_name}",
        unit="epoch",
        disable=not progress,
        initial=start_epoch - 1,
        total=epochs,
    )
    for epoch in epoch_bar:
        t0 = time.perf_counter()
        if sched == "cosine":
            for group in optimizer.param_groups:
                group["lr"] = cosine_lr(lr, epoch, epochs)
        seed_everything(seed, epoch, rank)
        train_sampler.set_epoch(epoch)
        loader_gen.manual_seed(seed * 1_000_003 + epoch)
        # ------------------------------------------------ train
        model.train()
        sums: dict[str, float] = {}
        count = 0
        for x_tilde, x in tqdm(train_loader, desc=f"epoch {epoch}", unit="batch", leave=False, disable=not progress):
            x_tilde, x = _to(x_tilde, dev, use_cl), _to(x, dev, use_cl)
            optimizer.zero_grad(set_to_none=True)
            loss, logs = step_model(x_tilde, x)
            loss.backward()
            if clip:
                torch.nn.utils.clip_grad_norm_(model.parameters(), clip)
            optimizer.step()
            step += 1
            lv = float(loss.detach())
            if not math.isfinite(lv):
                raise NanoctError(f"training diverged (loss {lv}) in epoch {epoch}, step {step}; try a smaller --lr")
            b = x.shape[0]
            count += b
            for k, v in {"loss": lv, **logs}.items():
                sums[k] = sums.get(k, 0.0) + float(v) * b
            if max_steps is not None and step >= max_steps:
                break
        keys = sorted(sums)
        red = reduce([sums[k] for k in keys] + [count])
        train_stats = {k: v / max(red[-1], 1) for k, v in zip(keys, red[:-1])}
        # ------------------------------------------------ validate
        model.eval()
        vsums: dict[str, float] = {}
        vcount = 0
        with torch.no_grad():
            for x_tilde, x in val_loader:
                x_tilde, x = _to(x_tilde, dev, use_cl), _to(x, dev, use_cl)
                loss, logs = model.loss(x_tilde, x)
                b = x.shape[0]
                vcount += b
                for k, v in {"loss": float(loss), **logs}.items():
                    vsums[k] = vsums.get(k, 0.0) + float(v) * b
        vkeys = sorted(set(keys) | set(vsums))  # ranks without val samples still take part
        vred = reduce([vsums.get(k, 0.0) for k in vkeys] + [vcount])
        val_stats = {k: v / max(vred[-1], 1) for k, v in zip(vkeys, vred[:-1])}
        val_loss = val_stats["loss"]
        if lr_sched is not None:
            lr_sched.step(val_loss)
        improved = val_loss < best_val
        if improved:
            best_val, best_epoch = val_loss, epoch
        row: dict[str, Any] = {"epoch": epoch, "train_loss": train_stats.pop("loss"), "val_loss": val_stats.pop("loss")}
        row.update({f"train_{k}": v for k, v in train_stats.items()})
        row.update({f"val_{k}": v for k, v in val_stats.items()})
        row.update(
            {
                "lr": optimizer.param_groups[0]["lr"],
                "best": int(improved),
                "steps": step,
                "seconds": round(time.perf_counter() - t0, 3),
            }
        )
        history.append(row)
        # ------------------------------------------------ write (rank 0)
        if main_rank:
            kw = dict(
                model=model,
                input_name=input_name,
                image_size=train_ds.image_size,
                epoch=epoch,
                step=step,
                optimizer=optimizer,
                scheduler=lr_sched,
                best_val_loss=best_val,
                best_epoch=best_epoch,
                history=history,
                config=config,
            )
            if improved:
                save_checkpoint(best_path, **kw)
            save_checkpoint(last_path, **kw)
            _write_log(log_path, history)
            epoch_bar.set_postfix(train=f"{row['train_loss']:.3g}", val=f"{row['val_loss']:.3g}", best=best_epoch)
            if on_epoch_end is not None:
                on_epoch_end(epoch, row)
        if max_steps is not None and step >= max_steps:
            break
    epoch_bar.close()
    if distributed:
        dist.barrier()
    return out


def main(argv: list[str] | None = None) -> int:
    """Command-line entry for ``python -m nanoct.learn.train`` (also under ``torchrun``)."""
    p = argparse.ArgumentParser(prog="python -m nanoct.learn.train", description=__doc__.splitlines()[0])
    p.add_argument("store")
    p.add_argument("--model", default="unet")
    p.add_argument("--input", default="fbp")
    p.add_argument("--out", required=True)
    p.add_argument("--epochs", type=int)
    p.add_argument("--batch-size", type=int)
    p.add_argument("--lr", type=float)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device")
    p.add_argument("--max-steps", type=int)
    p.add_argument("--model-kwargs", default="{}", help="JSON dict of architecture arguments")
    p.add_argument("--clip-grad", type=float)
    p.add_argument("--scheduler", choices=SCHEDULERS)
    p.add_argument("--num-workers", type=int, default=0)
    p.add_argument("--no-progress", action="store_true")
    a = p.parse_args(argv)
    try:
        train(
            a.store,
            a.model,
            a.input,
            a.out,
            epochs=a.epochs,
            batch_size=a.batch_size,
            lr=a.lr,
            seed=a.seed,
            device=a.device,
            progress=not a.no_progress,
            max_steps=a.max_steps,
            model_kwargs=json.loads(a.model_kwargs),
            clip_grad=a.clip_grad,
            scheduler=a.scheduler,
            num_workers=a.num_workers,
        )
    except NanoctError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
