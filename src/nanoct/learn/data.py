"""Torch data set of (first reconstruction, ground truth) pairs from a nanoct store.

Memory: in memory, a split needs ``2 * n * N^2 * 4`` bytes. At paper scale (N = 255) the
train split of 30,490 samples takes 7.9 GB (input + target), validation (1,284) 0.33 GB and
test (321) 0.08 GB; tiny (63) and small (127) sets fit easily. ``in_memory=None`` (default)
loads a split into memory when it needs at most ``NANOCT_DATA_MEMORY_GB`` (default 4) and
otherwise reads each sample from the store when it is requested (one Zarr chunk per array,
~0.3 ms at N = 255; use DataLoader workers to hide it).

No normalisation is applied: phantoms lie in [0, 1] (the UNet's sigmoid range) and the
first reconstructions are on the same intensity scale.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from ..core.errors import NanoctError, StoreError
from ..io.store import SPLITS, DataStore
from ..recon.names import predict_command

__all__ = ["PatchDataset", "ReconDataset", "check_input", "grid_starts", "grid_windows"]


def _memory_limit_bytes() -> float:
    try:
        return float(os.environ.get("NANOCT_DATA_MEMORY_GB", "4")) * 2**30
    except ValueError:
        return 4 * 2**30


def check_input(store: DataStore, input_name: str, indices: np.ndarray, what: str) -> None:
    """Raise a NanoctError unless ``reconstructions/<input_name>`` covers ``indices``."""
    if input_name not in store.reconstruction_names():
        present = ", ".join(store.reconstruction_names()) or "none"
        raise NanoctError(
            f"{store.path} has no reconstruction '{input_name}' (present: {present}); "
            f"make it first: {predict_command(store.path, input_name)}"
        )
    done = store.reconstruction_done(input_name, indices)
    if not done.all():
        missing = indices[~done]
        raise NanoctError(
            f"reconstruction '{input_name}' of {store.path} is missing {missing.size} of the {indices.size} {what} "
            f"sample(s) (e.g. {missing[:5].tolist()}); run 'nanoct reconstruct' again to finish it"
        )


class ReconDataset(Dataset):
    """Pairs ``(x_tilde, x)`` of one split, each a (1, N, N) float32 tensor.

    Parameters
    ----------
    store_path : path
        Data-set store.
    input_name : str
        Reconstruction used as network input, ``reconstructions/<input_name>`` (e.g. "fbp").
    split : {"train", "val", "test", "all"}
        Which samples.
    in_memory : bool, optional
        Load the whole split at construction (True), read per item (False), or decide by
        size (None, see the module docstring).
    limit : int, optional
        Use only the first ``limit`` samples of the split (in store order), so that the sets of
        growing limits are nested.

    Raises
    ------
    NanoctError
        If the store cannot be opened, the split is empty or smaller than ``limit``, or the
        input reconstruction is missing or incomplete for the samples used.
    """

    def __init__(
        self,
        store_path: str | os.PathLike[str],
        input_name: str,
        split: str,
        *,
        in_memory: bool | None = None,
        limit: int | None = None,
    ) -> None:
        if split != "all" and split not in SPLITS:
            raise NanoctError(f"split {split!r} is unknown; use one of train, val, test, all")
        store = DataStore.open(store_path)
        self.store_path = str(store_path)
        self.input_name = input_name
        self.split = split
        self.indices = store.indices(split)
        self.image_size = int(store.geometry.n)
        if self.indices.size == 0:
            raise NanoctError(
                f"the {split} split of {store.path} is empty; generate the data set with more samples "
                "or other split fractions"
            )
        if limit is not None:
            if not 1 <= limit <= self.indices.size:
                raise NanoctError(
                    f"limit {limit} must be between 1 and the {self.indices.size} samples of the {split} split "
                    f"of {store.path}; generate more samples or ask for fewer"
                )
            self.indices = self.indices[:limit]
        if not store.done[self.indices].all():
            raise NanoctError(f"{store.path} is not completely generated; run 'nanoct generate' again to finish it")
        check_input(store, input_name, self.indices, split)
        nbytes = 2 * self.indices.size * self.image_size**2 * 4
        self.in_memory = bool(nbytes <= _memory_limit_bytes()) if in_memory is None else bool(in_memory)
        self._store: DataStore | None = None
        self._pid: int | None = None
        self._x_tilde: torch.Tensor | None = None
        self._x: torch.Tensor | None = None
        if self.in_memory:
            try:
                x_tilde = store.read_reconstruction(input_name, self.indices)
                x = store.read_phantoms(self.indices)
            except StoreError as exc:
                raise NanoctError(str(exc)) from exc
            self._x_tilde = torch.from_numpy(np.ascontiguousarray(x_tilde, dtype=np.float32)).unsqueeze(1)
            self._x = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32)).unsqueeze(1)

    def __len__(self) -> int:
        return int(self.indices.size)

    def _open(self) -> DataStore:
        # one handle per process (DataLoader workers are forked or spawned)
        if self._store is None or self._pid != os.getpid():
            self._store = DataStore.open(self.store_path)
            self._pid = os.getpid()
        return self._store

    def __getitem__(self, item: int) -> tuple[torch.Tensor, torch.Tensor]:
        if self._x_tilde is not None and self._x is not None:
            return self._x_tilde[item], self._x[item]
        store = self._open()
        i = int(self.indices[item])
        x_tilde = store.read_reconstruction(self.input_name, [i])[0]
        x = store.read_phantoms([i])[0]
        return torch.from_numpy(np.asarray(x_tilde, np.float32))[None], torch.from_numpy(np.asarray(x, np.float32))[
            None
        ]

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_store"] = None  # reopened in the worker
        return state


def grid_starts(n: int, patch: int) -> np.ndarray:
    """The first pixels of the fewest ``patch``-wide windows, evenly spread, that cover ``n`` pixels.

    ``ceil(n / patch)`` windows from 0 to ``n - patch`` (rounded): neighbours overlap, none leaves a gap.
    """
    k = -(-n // patch)
    return np.unique(np.round(np.linspace(0, n - patch, k)).astype(int))


def grid_windows(n: int, patch: int) -> list[tuple[slice, slice]]:
    """The (rows, columns) windows of the ``patch``-square grid that covers an ``n``-square image.

    :func:`grid_starts` in both directions, row by row: the validation patches of ``train --patch``
    (:class:`PatchDataset` with ``grid=True``).
    """
    starts = grid_starts(n, patch)
    return [(slice(r, r + patch), slice(c, c + patch)) for r in starts for c in starts]


class PatchDataset(Dataset):
    """Square patches of the pairs of a :class:`ReconDataset` (``train --patch``): a network of any image size.

    Parameters
    ----------
    base : ReconDataset
        The pairs, (1, N, N) each.
    patch : int
        Patch side P, at most N.
    seed : int
        With ``grid=False``: the seed of the patch positions.
    grid : bool
        ``False`` (training): one patch per pair, at a position drawn from ``(seed, epoch, item)``
        (:meth:`set_epoch`), so every epoch sees other parts of every image and a resumed run the
        same. ``True`` (validation): the patches of a fixed grid that covers each
        image (:func:`grid_starts` in both directions), the same in every epoch.

    Raises
    ------
    NanoctError
        If ``patch`` is not a whole number between 8 and the image size.
    """

    def __init__(self, base: ReconDataset, patch: int, seed: int = 0, grid: bool = False) -> None:
        n = base.image_size
        if isinstance(patch, bool) or not isinstance(patch, int) or not 8 <= patch <= n:
            raise NanoctError(f"--patch {patch!r} must be a whole number from 8 to the image size {n}")
        self.base, self.patch, self.seed, self.grid, self.epoch = base, patch, int(seed), grid, 0
        self.image_size = patch
        self._grid: list[tuple[int, int, int]] | None = None
        if grid:
            self._grid = [
                (item, rows.start, cols.start) for item in range(len(base)) for rows, cols in grid_windows(n, patch)
            ]

    def set_epoch(self, epoch: int) -> None:
        """Draw the training patches of ``epoch`` (set before the epoch's loader is iterated)."""
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return len(self._grid) if self._grid is not None else len(self.base)

    def position(self, index: int) -> tuple[int, int, int]:
        """The pair (item of ``base``) and first row and column of patch ``index``."""
        if self._grid is not None:
            return self._grid[index]
        rng = np.random.default_rng([self.seed, self.epoch, index])
        r, c = rng.integers(0, self.base.image_size - self.patch + 1, size=2)
        return index, int(r), int(c)

    def __getitem__(self, index: int) -> tuple[torch.Tensor, torch.Tensor]:
        item, r, c = self.position(index)
        window = (slice(None), slice(r, r + self.patch), slice(c, c + self.patch))
        x_tilde, x = self.base[item]
        return x_tilde[window].contiguous(), x[window].contiguous()
