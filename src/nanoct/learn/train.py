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

Multi-process: ``torchrun --nproc_per_node P -m nanoct train STORE --model unet ...``
(``WORLD_SIZE > 1``) initialises a process group (NCCL on CUDA, gloo on CPU), splits each
global batch of ``batch_size`` over the processes, averages gradients with DDP and lets only
rank 0 write files.
"""

from __future__ import annotations

import csv
import inspect
import io
import json
import math
import os
import random
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
from torch import nn
from torch.utils.data import DataLoader, DistributedSampler, Subset

from ..core.errors import NanoctError
from ..core.version import __version__
from ..io.fileio import atomic_link, atomic_write_bytes, remove_stale_temporaries
from ..io.lock import exclusive
from ..io.provenance import environment_info
from ..io.store import DataStore
from .base import PostProcessor
from .checkpoint import load_checkpoint, save_checkpoint, set_rng_state
from .data import PatchDataset, ReconDataset
from .models import build_model, model_class, model_spec

__all__ = [
    "PRECISIONS",
    "TrainConfig",
    "check_precision",
    "cosine_lr",
    "keep_freed_memory",
    "model_arguments",
    "native_bf16",
    "resolve_device",
    "resolve_precision",
    "seed_everything",
    "train",
]

SCHEDULERS = ("none", "plateau", "cosine")
PLATEAU = {"factor": 0.5, "patience": 10, "min_lr": 1e-7}
COSINE_MIN_FRACTION = 0.1  # cosine annealing ends at lr / 10 (dival's UNet: 1e-3 -> 1e-4)
# keys of config.json that must agree for a run to be resumed
MATCH_KEYS = (
    "model",
    "hparams",
    "input",
    "data",
    "image_size",
    "batch_size",
    "lr",
    "seed",
    "clip_grad",
    "scheduler",
    "precision",
)
#: Value of a request key in runs recorded before the key existed.
_MATCH_DEFAULTS = {"precision": "fp32"}
#: Arithmetic of the training steps: "fp32", or "bf16" (forward pass under bfloat16 autocast).
PRECISIONS = ("fp32", "bf16")
#: What a request may name: a precision, or "auto" (:func:`resolve_precision`).
PRECISION_REQUESTS = (*PRECISIONS, "auto")


def native_bf16(device: str | torch.device) -> bool:
    """Whether ``device`` runs bfloat16 convolutions natively.

    A CUDA device that supports bfloat16, or a CPU on which oneDNN has bfloat16 kernels (AVX512 or
    AMX on x86, BF16 on Arm). On other CPUs (e.g. AVX2 only) autocast emulates bfloat16 and a
    training step is 5-9x slower than in float32 (measured on a 2-core AVX2 AMD EPYC,
    ``benchmarks/bench_precision.py``).
    """
    device = torch.device(device)
    if device.type == "cuda":
        return bool(torch.cuda.is_available() and torch.cuda.is_bf16_supported())
    if device.type != "cpu":
        return False
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):  # a torch build without oneDNN
        return False


def check_precision(precision: str, name: str = "precision") -> str:
    """``precision`` if it is one of :data:`PRECISION_REQUESTS`.

    Raises
    ------
    NanoctError
        Naming ``name`` (the argument or flag that gave the value) and the known requests.
    """
    if precision not in PRECISION_REQUESTS:
        raise NanoctError(f"{name} {precision!r} is unknown; use one of {', '.join(PRECISION_REQUESTS)}")
    return precision


def resolve_precision(precision: str, device: str | torch.device) -> str:
    """The precision a training run on ``device`` uses for the request ``precision``.

    ``"auto"`` is ``"bf16"`` where :func:`native_bf16` holds and ``"fp32"`` elsewhere; ``"fp32"``
    and ``"bf16"`` are taken as they are.

    Raises
    ------
    NanoctError
        If ``precision`` is none of :data:`PRECISION_REQUESTS`.
    """
    check_precision(precision)
    if precision != "auto":
        return precision
    return "bf16" if native_bf16(device) else "fp32"


def resolve_device(device: str | torch.device | None = None, local_rank: int = 0) -> torch.device:
    """``device`` as given, else CUDA (``cuda:<local_rank>``) when available, else CPU."""
    if device is not None:
        dev = torch.device(device)
        if dev.type == "cuda" and not torch.cuda.is_available():
            raise NanoctError(f"device {device} was requested but CUDA is not available here")
        return dev
    return torch.device(f"cuda:{local_rank}") if torch.cuda.is_available() else torch.device("cpu")


#: glibc ``mallopt`` parameters and the values :func:`keep_freed_memory` sets (bytes).
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_KEEP_FREED = {_M_MMAP_THRESHOLD: 64 * 2**20, _M_TRIM_THRESHOLD: 128 * 2**20}
_kept_freed: list[bool] = []


def keep_freed_memory() -> bool:
    """Let glibc's ``malloc`` keep the memory a CPU training or sampling step frees for the next step.

    By default glibc returns the step's large freed blocks to the system and the next step
    faults them in again, zero-filled: about 40,000 page faults per float32 UNet step of the tiny
    study (batch 16, 63 x 63), 11-13 % of its CPU time (2-core AVX2 AMD EPYC,
    ``benchmarks/bench_cpu_training.py --settings``; CiUNetRes: 6,000, no measurable gain).
    Blocks up to 64 MiB come from the heap here and up to 128 MiB of its free top is kept, so the
    steady state has no faults. Where a block lies does not change a result: the weights come out
    bit-identical. Once per process,
    on Linux with glibc only, and not where ``MALLOC_MMAP_THRESHOLD_`` or ``MALLOC_TRIM_THRESHOLD_``
    is set (the user's choice wins).

    Returns
    -------
    bool
        Whether the settings are in effect in this process.
    """
    if _kept_freed:
        return _kept_freed[0]
    done = False
    if sys.platform.startswith("linux") and not any(
        k in os.environ for k in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")
    ):
        import ctypes
        import platform

        try:
            if platform.libc_ver()[0] == "glibc":
                libc = ctypes.CDLL("libc.so.6")
                done = all(libc.mallopt(k, v) == 1 for k, v in _KEEP_FREED.items())
        except (OSError, AttributeError):  # no glibc to tune
            done = False
    _kept_freed.append(done)
    return done


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
    return [k for k in MATCH_KEYS if a.get(k, _MATCH_DEFAULTS.get(k)) != b.get(k, _MATCH_DEFAULTS.get(k))]


def _to(t: torch.Tensor, device: torch.device, channels_last: bool) -> torch.Tensor:
    t = t.to(device, non_blocking=True)
    return t.contiguous(memory_format=torch.channels_last) if channels_last else t


@dataclass(frozen=True)
class TrainConfig:
    """What one training run is asked to do; ``None`` means the model's registry default.

    Parameters
    ----------
    model : str
        Registered model (:func:`nanoct.learn.models.model_names`), e.g. "unet".
    input : str
        Input reconstruction, e.g. "fbp", "dremel".
    epochs, batch_size, lr : optional
        Default: the model's registry entry (UNet: 500 epochs, batch 16, lr 1e-3, as in the
        paper). ``batch_size`` is the global batch, split over DDP processes.
    seed : int
        Seeds the initial weights, the shuffling and every epoch's random state.
    scheduler : {"none", "plateau", "cosine"}, optional
        Learning-rate schedule (default: the model's). "plateau": ReduceLROnPlateau on the
        validation loss, factor 0.5, patience 10 epochs. "cosine": cosine annealing per epoch
        from ``lr`` in the first epoch to ``lr / 10`` after the last (dival's UNet schedule,
        ``CosineAnnealingLR(T_max=epochs)``); a computed function of (epoch, epochs), so a
        resumed run follows the same curve and an extended run follows the new one.
    model_kwargs : dict, optional
        Architecture keyword arguments (e.g. ``{"channels": [8, 8, 16, 16, 32]}``).
    clip_grad : float, optional
        Gradient-norm clipping (default: the model's; 0 disables).
    precision : {"fp32", "bf16", "auto"}
        "bf16" runs the training steps' forward pass under ``torch.autocast`` with bfloat16
        (convolutions and what follows them in bfloat16, ``mse_loss`` and the ops autocast
        lists as float32 in float32; weights, optimiser state, gradients and validation stay
        float32). About twice the steps per second on a CPU with native
        bfloat16 (AVX512-BF16 / AMX) or a recent GPU; 5-9x slower where bfloat16 is emulated
        (an AVX2-only CPU). "auto": "bf16" where the device runs it natively, else "fp32"
        (:func:`resolve_precision`); ``config.json`` records the precision taken.
    max_steps : int, optional
        Stop after this many optimizer steps in total (the epoch in progress is then
        validated and checkpointed as finished); for smoke tests and fixed-step budgets.
    n_train : int, optional
        Train on the first ``n_train`` samples of the train split only (nested subsets for
        data-scaling studies; default: the whole split). Recorded in ``config.json``
        (``data.train``), so a run of another size is not resumed from it.
    device : str, optional
        Default: CUDA when available, else CPU.
    num_workers : int
        DataLoader worker processes.
    in_memory : bool, optional
        See :class:`~nanoct.learn.data.ReconDataset`.
    channels_last : bool, optional
        Default: True on CPU (faster convolutions there), False on CUDA.
    patch : int, optional
        Train on ``patch`` x ``patch`` patches of the images, one per image and epoch at a position
        drawn from (seed, epoch, image), and validate on the patches of a grid that covers every
        validation image (:class:`~nanoct.learn.data.PatchDataset`): the network's trained size is
        then ``patch``, it predicts larger images in tiles of that size (``predict --tile 0``) and
        its intervals are fitted on the validation images predicted in those tiles
        (:func:`~nanoct.learn.calibration.tiled_outputs`). Recorded in ``config.json``.
    """

    model: str = "unet"
    input: str = "fbp"
    epochs: int | None = None
    batch_size: int | None = None
    lr: float | None = None
    seed: int = 0
    scheduler: str | None = None
    model_kwargs: dict[str, Any] | None = None
    clip_grad: float | None = None
    precision: str = "fp32"
    max_steps: int | None = None
    n_train: int | None = None
    device: str | torch.device | None = None
    num_workers: int = 0
    in_memory: bool | None = None
    channels_last: bool | None = None
    patch: int | None = None


#: Architecture arguments that a network on a set matched to a measured scan takes as ``"range"`` unless
#: asked otherwise: the invertible networks' training noise on the target, the UNet's squared error.
RANGE_ARGUMENTS = ("target_noise_scale", "loss_scale")


def model_arguments(
    store_path: str | os.PathLike[str], model_name: str, given: dict[str, Any] | None = None
) -> dict[str, Any]:
    """The architecture arguments a run on ``store_path`` builds ``model_name`` with.

    ``given``, and on a set matched to a measured scan (``nanoct generate --like``) each of
    :data:`RANGE_ARGUMENTS` the model takes as ``"range"`` unless ``given`` names it: the images of
    such a set differ in contrast by orders of magnitude, and the paper's absolute target noise
    drowns the faint ones while its absolute MSE ignores them. On the I13 set, against Dremel:
    CiUNetRes +1.44 dB on the validation split with the noise relative, -0.89 dB absolute; the UNet
    -2.54 dB with the error relative, -5.17 dB absolute (docs/semireal_networks.md).

    Parameters
    ----------
    store_path : path
        The training data set (one that cannot be opened adds nothing; training reports it).
    model_name : str
        A registered model name.
    given : dict, optional
        Arguments asked for (``--param``); they always win.

    Returns
    -------
    dict
        The arguments.
    """
    kwargs = dict(given or {})
    takes = inspect.signature(model_class(model_name)).parameters
    missing = [k for k in RANGE_ARGUMENTS if k in takes and k not in kwargs]
    if not missing:
        return kwargs
    try:
        like = (DataStore.open(store_path).meta.get("simulation") or {}).get("like")
    except NanoctError:  # a missing or unreadable store is reported where the data are read
        return kwargs
    if like:
        kwargs.update(dict.fromkeys(missing, "range"))
    return kwargs


def train(
    store_path: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    config: TrainConfig | None = None,
    *,
    progress: bool = True,
    on_epoch_end: Callable[[int, dict[str, Any]], None] | None = None,
) -> Path:
    """Train a post-processing network on ``reconstructions/<config.input>`` -> phantoms.

    Parameters
    ----------
    store_path : path
        Data-set store with ``reconstructions/<input>`` for the train and val splits.
    out_dir : path
        Run directory (created; resumed when it holds a run of the same request).
    config : TrainConfig, optional
        What to train and how (default: a UNet on FBP with the registry's settings).
    progress : bool
        Progress bars (rank 0 only).
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
    c = config or TrainConfig()
    model_name, input_name, seed = c.model, c.input, c.seed
    spec = model_spec(model_name)
    epochs = spec.epochs if c.epochs is None else int(c.epochs)
    batch_size = spec.batch_size if c.batch_size is None else int(c.batch_size)
    lr = spec.lr if c.lr is None else float(c.lr)
    clip = spec.clip_grad if c.clip_grad is None else (float(c.clip_grad) or None)
    sched = (spec.scheduler or "none") if c.scheduler is None else str(c.scheduler)
    _check_request(epochs, batch_size, lr, c.max_steps, sched)
    if int(seed) < 0:
        raise NanoctError(f"--seed {seed} must be >= 0")

    # ---------------------------------------------------------------- processes and device
    world = int(os.environ.get("WORLD_SIZE", "1"))
    local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    dev = resolve_device(c.device, local_rank)
    precision = resolve_precision(c.precision, dev)
    own_group = False
    if world > 1 and not dist.is_initialized():
        if dev.type == "cuda":
            torch.cuda.set_device(dev)
        dist.init_process_group("nccl" if dev.type == "cuda" else "gloo")
        own_group = True
    distributed = world > 1 and dist.is_initialized()
    if dev.type == "cpu":
        keep_freed_memory()
    rank = dist.get_rank() if distributed else 0
    world = dist.get_world_size() if distributed else 1
    local_batch = batch_size // world
    use_cl = (dev.type == "cpu") if c.channels_last is None else bool(c.channels_last)
    main_rank = rank == 0

    settings = _Settings(
        store_path=store_path,
        model_name=model_name,
        input_name=input_name,
        out=Path(out_dir),
        epochs=epochs,
        batch_size=batch_size,
        local_batch=local_batch,
        lr=lr,
        seed=int(seed),
        dev=dev,
        use_cl=use_cl,
        precision=precision,
        progress=progress and main_rank,
        max_steps=c.max_steps,
        n_train=c.n_train,
        model_kwargs=model_arguments(store_path, model_name, c.model_kwargs),
        clip=clip,
        sched=sched,
        num_workers=c.num_workers,
        in_memory=c.in_memory,
        patch=c.patch,
        rank=rank,
        world=world,
        distributed=distributed,
        on_epoch_end=on_epoch_end,
    )
    try:
        if batch_size % world:
            raise NanoctError(f"batch size {batch_size} is not divisible by the {world} processes")
        if not main_rank:  # rank 0 holds the lock; torchrun stops the other ranks when it is refused
            return _run(settings)
        with exclusive(settings.out, "train", f"the training run {settings.out}"):
            return _run(settings)
    finally:
        if own_group and dist.is_initialized():
            dist.destroy_process_group()


def _check_request(epochs: int, batch_size: int, lr: float, max_steps: int | None, sched: str) -> None:
    """NanoctError for a non-positive count or rate, or an unknown schedule."""
    if epochs < 1 or batch_size < 1 or not 0 < lr < math.inf or (max_steps is not None and max_steps < 1):
        raise NanoctError(
            f"epochs ({epochs}), batch size ({batch_size}), lr ({lr}) and max steps ({max_steps}) must be positive "
            "(and finite)"
        )
    if sched not in SCHEDULERS:
        raise NanoctError(f"scheduler {sched!r} is unknown; use one of {', '.join(SCHEDULERS)}")


@dataclass(frozen=True)
class _Settings:
    """The resolved request of one training run (what :func:`train` was asked to do, and where)."""

    store_path: Any
    model_name: str
    input_name: str
    out: Path
    epochs: int
    batch_size: int
    local_batch: int
    lr: float
    seed: int
    dev: torch.device
    use_cl: bool
    precision: str
    progress: bool
    max_steps: int | None
    n_train: int | None
    model_kwargs: dict[str, Any]
    clip: float | None
    sched: str
    num_workers: int
    in_memory: bool | None
    patch: int | None
    rank: int
    world: int
    distributed: bool
    on_epoch_end: Callable[[int, dict[str, Any]], None] | None

    @property
    def main_rank(self) -> bool:
        return self.rank == 0

    def path(self, name: str) -> Path:
        """``config.json``, ``log.csv``, ``last.pt`` or ``best.pt`` of the run directory."""
        return self.out / name


@dataclass
class _State:
    """What changes while a run trains: the model and optimiser, the counters, the history."""

    model: PostProcessor
    config: dict[str, Any]
    image_size: int
    optimizer: torch.optim.Optimizer
    lr_sched: Any
    start_epoch: int = 1
    step: int = 0
    best_val: float = math.inf
    best_epoch: int = 0
    history: list[dict[str, Any]] = field(default_factory=list)

    def done(self, s: _Settings) -> bool:
        """The run has reached its epoch count or its step limit."""
        return self.start_epoch > s.epochs or (s.max_steps is not None and self.step >= s.max_steps)


def _config(s: _Settings, model: PostProcessor, train_ds: ReconDataset, val_ds: ReconDataset) -> dict[str, Any]:
    """The request as written to ``config.json`` (also stored in every checkpoint)."""
    store = DataStore.open(s.store_path)
    config = {
        "model": s.model_name,
        "hparams": model.hparams,
        "input": s.input_name,
        "data": {
            "n": store.n,
            "seed": store.seed,
            "geometry": store.geometry.to_dict(),
            "train": len(train_ds),
            "val": len(val_ds),
        },
        "image_size": train_ds.image_size,
        **({"patch": s.patch} if s.patch is not None else {}),
        "batch_size": s.batch_size,
        "lr": s.lr,
        "seed": s.seed,
        "clip_grad": s.clip,
        "scheduler": s.sched,
        "epochs": s.epochs,
        "max_steps": s.max_steps,
        "store": str(Path(s.store_path).resolve()),
        "world_size": s.world,
        "device": str(s.dev),
        "channels_last": s.use_cl,
        "precision": s.precision,
        "nanoct_version": __version__,
        # what the weights depend on beyond the request (library versions, threads, CPU kernels);
        # recorded, not compared on resume
        "environment": environment_info(),
    }
    return json.loads(json.dumps(config))


def _previous(s: _Settings, config: dict[str, Any]) -> dict[str, Any] | None:
    """The last checkpoint of an existing run in the directory, None for a new one.

    Raises
    ------
    NanoctError
        If the directory holds a run of another request.
    """
    last_path = s.path("last.pt")
    if not last_path.exists():  # a config.json without last.pt holds no training state (a diverged run): redo
        return None
    ckpt = load_checkpoint(last_path, model_name=s.model_name, hparams=config["hparams"])  # image size: in the diff
    differs = _diff(config, ckpt.get("config") or {})
    if differs:
        raise NanoctError(
            f"{s.out} holds a run made with other settings (differs in: {', '.join(differs)}); "
            "choose another --out, or repeat the original command to resume it"
        )
    return ckpt


def _resume(s: _Settings, state: _State, ckpt: dict[str, Any]) -> None:
    """Load weights, optimiser, schedule, RNG and counters of the last checkpoint into ``state``."""
    try:
        state.model.load_state_dict(ckpt["model_state"])
        state.optimizer.load_state_dict(ckpt["optimizer_state"])
        if state.lr_sched is not None and ckpt.get("scheduler_state") is not None:
            state.lr_sched.load_state_dict(ckpt["scheduler_state"])
    except (RuntimeError, ValueError, KeyError, TypeError) as exc:
        raise NanoctError(
            f"{s.path('last.pt')} does not fit this model ({exc}); delete the run directory or choose another --out"
        ) from exc
    set_rng_state(ckpt.get("rng", {}))
    state.start_epoch, state.step = int(ckpt["epoch"]) + 1, int(ckpt.get("step", 0))
    state.best_val, state.best_epoch = float(ckpt.get("best_val_loss", math.inf)), int(ckpt.get("best_epoch", 0))
    state.history = list(ckpt.get("history", []))


def _start(s: _Settings, train_ds: ReconDataset, val_ds: ReconDataset) -> tuple[_State, bool]:
    """Build the model (seeded), check the directory, resume; returns (state, whether it resumed)."""
    seed_everything(s.seed, 0x5EED)
    model = build_model(s.model_name, **s.model_kwargs)
    config = _config(s, model, train_ds, val_ds)
    ckpt = _previous(s, config)
    model = model.to(s.dev, memory_format=torch.channels_last) if s.use_cl else model.to(s.dev)
    optimizer = torch.optim.Adam(model.parameters(), lr=s.lr)
    lr_sched = torch.optim.lr_scheduler.ReduceLROnPlateau(optimizer, **PLATEAU) if s.sched == "plateau" else None
    state = _State(model, config, train_ds.image_size, optimizer, lr_sched)
    if ckpt is not None:
        _resume(s, state, ckpt)
    if s.main_rank:
        s.out.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(s.out)  # left by a kill during a checkpoint write
        _atomic_json(s.path("config.json"), config)
        _write_log(s.path("log.csv"), state.history)  # drops rows of an epoch whose checkpoint was never written
    return state, ckpt is not None


@dataclass
class _Loaders:
    """The train loader with its seeded sampler and generator, and this rank's share of validation."""

    train: DataLoader
    sampler: DistributedSampler
    generator: torch.Generator
    val: DataLoader


def _loaders(s: _Settings, train_ds: ReconDataset, val_ds: ReconDataset) -> _Loaders:
    sampler = DistributedSampler(
        train_ds, num_replicas=s.world, rank=s.rank, shuffle=True, seed=s.seed, drop_last=False
    )
    gen = torch.Generator()
    kw: dict[str, Any] = {"num_workers": s.num_workers, "pin_memory": s.dev.type == "cuda"}
    if s.num_workers > 0:
        kw["worker_init_fn"] = _worker_init
    train_loader = DataLoader(train_ds, batch_size=s.local_batch, sampler=sampler, generator=gen, **kw)
    val_loader = DataLoader(
        Subset(val_ds, list(range(s.rank, len(val_ds), s.world))), batch_size=s.local_batch, shuffle=False, **kw
    )
    return _Loaders(train_loader, sampler, gen, val_loader)


def _data_init(s: _Settings, model: PostProcessor, train_ds: ReconDataset) -> None:
    """Data-dependent initialisation (ActNorm) from the same first train images on every rank, before DDP."""
    first = [train_ds[i] for i in range(min(s.local_batch, len(train_ds)))]
    x_tilde0 = _to(torch.stack([a for a, _ in first]), s.dev, s.use_cl)
    x0 = _to(torch.stack([b for _, b in first]), s.dev, s.use_cl)
    with torch.no_grad():
        model.data_init(x_tilde0, x0)


def _reduce(s: _Settings, sums: dict[str, float], count: int, keys: list[str]) -> dict[str, float]:
    """Sample-weighted means of ``sums`` over all ranks (ranks without samples still take part)."""
    t = torch.tensor(
        [sums.get(k, 0.0) for k in keys] + [count],
        dtype=torch.float64,
        device=s.dev if s.dev.type == "cuda" else "cpu",
    )
    if s.distributed:
        dist.all_reduce(t)
    red = t.tolist()
    return {k: v / max(red[-1], 1) for k, v in zip(keys, red[:-1])}


def _train_epoch(s: _Settings, state: _State, loaders: _Loaders, step_model: nn.Module, epoch: int) -> dict[str, float]:
    """One pass over the train split (or up to the step limit); mean loss and logged values."""
    from tqdm.auto import tqdm

    model, optimizer = state.model, state.optimizer
    model.train()
    sums: dict[str, float] = {}
    count = 0
    for x_tilde, x in tqdm(loaders.train, desc=f"epoch {epoch}", unit="batch", leave=False, disable=not s.progress):
        x_tilde, x = _to(x_tilde, s.dev, s.use_cl), _to(x, s.dev, s.use_cl)
        optimizer.zero_grad(set_to_none=True)
        with torch.autocast(s.dev.type, dtype=torch.bfloat16, enabled=s.precision == "bf16"):
            loss, logs = step_model(x_tilde, x)
        loss.backward()
        if s.clip:
            torch.nn.utils.clip_grad_norm_(model.parameters(), s.clip)
        optimizer.step()
        state.step += 1
        lv = float(loss.detach())
        if not math.isfinite(lv):
            raise NanoctError(f"training diverged (loss {lv}) in epoch {epoch}, step {state.step}; try a smaller --lr")
        b = x.shape[0]
        count += b
        for k, v in {"loss": lv, **logs}.items():
            sums[k] = sums.get(k, 0.0) + float(v) * b
        if s.max_steps is not None and state.step >= s.max_steps:
            break
    return _reduce(s, sums, count, sorted(sums))


def _validate(s: _Settings, state: _State, loader: DataLoader, keys: list[str]) -> dict[str, float]:
    """Mean loss (for the flows: the NLL in bits/dim) and logged values on this rank's validation share."""
    model = state.model
    model.eval()
    sums: dict[str, float] = {}
    count = 0
    with torch.no_grad():
        for x_tilde, x in loader:
            x_tilde, x = _to(x_tilde, s.dev, s.use_cl), _to(x, s.dev, s.use_cl)
            loss, logs = model.loss(x_tilde, x)
            b = x.shape[0]
            count += b
            for k, v in {"loss": float(loss), **logs}.items():
                sums[k] = sums.get(k, 0.0) + float(v) * b
    return _reduce(s, sums, count, sorted(set(keys) | set(sums)))


def _record(state: _State, epoch: int, train_stats: dict[str, float], val_stats: dict[str, float], t0: float) -> bool:
    """Step the plateau schedule, update the best epoch and append the log row; True if improved."""
    val_loss = val_stats["loss"]
    if state.lr_sched is not None:
        state.lr_sched.step(val_loss)
    improved = val_loss < state.best_val
    if improved:
        state.best_val, state.best_epoch = val_loss, epoch
    train_stats, val_stats = dict(train_stats), dict(val_stats)
    row: dict[str, Any] = {"epoch": epoch, "train_loss": train_stats.pop("loss"), "val_loss": val_stats.pop("loss")}
    row.update({f"train_{k}": v for k, v in train_stats.items()})
    row.update({f"val_{k}": v for k, v in val_stats.items()})
    row.update(
        {
            "lr": state.optimizer.param_groups[0]["lr"],
            "best": int(improved),
            "steps": state.step,
            "seconds": round(time.perf_counter() - t0, 3),
        }
    )
    state.history.append(row)
    return improved


def _save(s: _Settings, state: _State, epoch: int, improved: bool) -> None:
    """Write ``best.pt`` (if improved), ``last.pt`` and ``log.csv`` (rank 0), then call ``on_epoch_end``."""
    kw = dict(
        model=state.model,
        input_name=s.input_name,
        image_size=state.image_size,
        epoch=epoch,
        step=state.step,
        optimizer=state.optimizer,
        scheduler=state.lr_sched,
        best_val_loss=state.best_val,
        best_epoch=state.best_epoch,
        history=state.history,
        config=state.config,
    )
    if improved:  # best first, then last.pt as a link to it: a kill in between replays this epoch
        save_checkpoint(s.path("best.pt"), **kw)
        atomic_link(s.path("best.pt"), s.path("last.pt"))
    else:
        save_checkpoint(s.path("last.pt"), **kw)
    _write_log(s.path("log.csv"), state.history)
    if s.on_epoch_end is not None:
        s.on_epoch_end(epoch, state.history[-1])


def _run(s: _Settings) -> Path:
    """Train from the start or from the last checkpoint to ``s.epochs`` (or ``s.max_steps``)."""
    from tqdm.auto import tqdm

    train_ds: Any = ReconDataset(s.store_path, s.input_name, "train", in_memory=s.in_memory, limit=s.n_train)
    val_ds: Any = ReconDataset(s.store_path, s.input_name, "val", in_memory=s.in_memory)
    if s.patch is not None:
        train_ds, val_ds = PatchDataset(train_ds, s.patch, s.seed), PatchDataset(val_ds, s.patch, grid=True)
    state, resumed = _start(s, train_ds, val_ds)
    if state.done(s):
        if s.progress:
            print(
                f"{s.out}: already trained to epoch {state.start_epoch - 1} of {s.epochs}; nothing to do",
                file=sys.stderr,
            )
        return s.out
    loaders = _loaders(s, train_ds, val_ds)
    if not resumed and hasattr(state.model, "data_init"):
        _data_init(s, state.model, train_ds)
    step_model: nn.Module = _LossModule(state.model)
    if s.distributed:
        from torch.nn.parallel import DistributedDataParallel

        step_model = DistributedDataParallel(step_model, device_ids=[s.dev.index] if s.dev.type == "cuda" else None)
    bar = tqdm(
        desc=f"train {s.model_name}",
        unit="epoch",
        disable=not s.progress,
        initial=state.start_epoch - 1,
        total=s.epochs,
    )
    for epoch in range(state.start_epoch, s.epochs + 1):
        t0 = time.perf_counter()
        if s.sched == "cosine":
            for group in state.optimizer.param_groups:
                group["lr"] = cosine_lr(s.lr, epoch, s.epochs)
        seed_everything(s.seed, epoch, s.rank)
        loaders.sampler.set_epoch(epoch)
        if s.patch is not None:
            train_ds.set_epoch(epoch)
        loaders.generator.manual_seed(s.seed * 1_000_003 + epoch)
        train_stats = _train_epoch(s, state, loaders, step_model, epoch)
        improved = _record(
            state, epoch, train_stats, _validate(s, state, loaders.val, list(train_stats) + ["loss"]), t0
        )
        if s.main_rank:
            _save(s, state, epoch, improved)
            row = state.history[-1]
            bar.set_postfix(train=f"{row['train_loss']:.3g}", val=f"{row['val_loss']:.3g}", best=state.best_epoch)
        bar.update()
        if s.max_steps is not None and state.step >= s.max_steps:
            if epoch < s.epochs:
                bar.set_description(f"train {s.model_name} (stopped at --max-steps {s.max_steps})")
            break
    bar.close()
    if s.distributed:
        dist.barrier()
    return s.out
