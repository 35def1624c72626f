"""Reading per-sample Zarr chunks so that a lost or damaged chunk can never pass as data.

Float arrays of a store (format 2) are created with a NaN fill value, and every value nanoct
writes is finite; so a sample whose chunk file was deleted reads as NaN, and one whose chunk
file is truncated or garbled fails to decode. :func:`read_samples` turns both into a
:class:`~nanoct.core.errors.StoreError` naming the samples (and an undecodable chunk's file) and the
command that repairs them; :func:`damaged_samples` finds them by reading everything (``nanoct
info --check``), :func:`missing_chunks` finds lost chunk files from their names alone (what a
rerun does before it resumes, so that resuming a large store stays cheap).
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import zarr

from ..core.errors import StoreError

__all__ = [
    "chunk_file",
    "damaged_samples",
    "find_damaged",
    "missing_chunks",
    "read_flags",
    "read_samples",
    "remove_partial_writes",
]

# Zarr's LocalStore writes a chunk to path.with_suffix(".<uuid4 hex>.partial"), then renames it
_PARTIAL = re.compile(r"\.[0-9a-f]{32}\.partial$")


def remove_partial_writes(root: Path, keys: Iterable[str]) -> list[Path]:
    """Delete the temporary chunk files that a killed write left under the arrays ``keys`` of ``root``.

    Call it only from the process that is about to (re)write these arrays, before it fans
    out: a write in progress elsewhere in the same arrays would lose its temporary.

    Parameters
    ----------
    root : Path
        The store directory.
    keys : iterable of str
        Array paths in the group, e.g. ``"phantoms"`` or ``"reconstructions/fbp"``.

    Returns
    -------
    list of Path
        The files removed.
    """
    removed = []
    for key in keys:
        folder = Path(root) / key
        if folder.is_dir():
            for p in folder.rglob("*.partial"):
                if _PARTIAL.search(p.name) and p.is_file():
                    p.unlink(missing_ok=True)
                    removed.append(p)
    return removed


def chunk_file(folder: Path, index: int, ndim: int) -> Path:
    """The file of sample ``index``'s chunk in the array folder ``folder`` (Zarr v3 default key encoding)."""
    return Path(folder, "c", str(index), *["0"] * (ndim - 1))


def missing_chunks(folder: Path, indices: np.ndarray, ndim: int) -> np.ndarray:
    """Indices among ``indices`` whose chunk file in ``folder`` is absent or empty (one ``stat`` each)."""
    idx = np.asarray(indices, dtype=int)

    def lost(i: int) -> bool:
        try:
            return chunk_file(folder, i, ndim).stat().st_size == 0
        except FileNotFoundError:
            return True

    return np.array([i for i in idx.tolist() if lost(i)], dtype=int)


def read_flags(group: zarr.Group, key: str, idx: np.ndarray) -> np.ndarray:
    """Boolean flags ``group[key][idx]`` (all False when the array is absent); reads only their chunks."""
    if key not in group or len(idx) == 0:
        return np.zeros(len(idx), dtype=bool)
    try:
        return np.asarray(group[key].get_coordinate_selection(idx), dtype=bool)  # type: ignore[union-attr]
    except Exception as exc:  # an undecodable flag chunk
        raise StoreError(f"the flags '{key}' are damaged ({exc}); delete the store and generate it again") from exc


def _bad_rows(data: np.ndarray) -> np.ndarray:
    if not np.issubdtype(data.dtype, np.floating):
        return np.zeros(len(data), dtype=bool)
    return ~np.isfinite(data.reshape(len(data), -1)).all(axis=1)


def _select(array: zarr.Array, idx: np.ndarray) -> np.ndarray:
    return array.get_orthogonal_selection((idx, *[slice(None)] * (array.ndim - 1)))


def damaged_samples(array: zarr.Array, indices: np.ndarray, block: int = 64) -> np.ndarray:
    """Indices among ``indices`` whose chunk of ``array`` is missing, undecodable or not finite.

    Parameters
    ----------
    array : zarr.Array
        A per-sample array (sample on the first axis, one chunk per sample).
    indices : array of int
        Samples that claim to be written.
    block : int
        Samples read per request (a failing block is re-read sample by sample).

    Returns
    -------
    numpy.ndarray
        The damaged indices, sorted.
    """
    idx = np.asarray(indices, dtype=int)
    bad: list[int] = []
    for start in range(0, idx.size, block):
        part = idx[start : start + block]
        try:
            bad += part[_bad_rows(_select(array, part))].tolist()
        except Exception:  # some chunk of the block cannot be decoded: find which
            for i in part:
                try:
                    if _bad_rows(_select(array, np.array([i])))[0]:
                        bad.append(int(i))
                except Exception:
                    bad.append(int(i))
    return np.array(sorted(bad), dtype=int)


def read_samples(array: zarr.Array, indices: np.ndarray, *, what: str, repair: str, folder: Path) -> np.ndarray:
    """Read ``array[indices]`` (first axis), refusing missing or damaged chunks.

    Parameters
    ----------
    array : zarr.Array
        A per-sample array.
    indices : array of int
        Samples to read; they must claim to be written.
    what : str
        How to name the array in a message, e.g. ``"phantoms of runs/d"``.
    repair : str
        The command that rewrites damaged samples, e.g. ``"nanoct generate"``.
    folder : Path
        The array's folder (to name an undecodable chunk file, which must be deleted first).

    Raises
    ------
    StoreError
        If a chunk is missing (reads as NaN) or cannot be read or decoded.
    """
    idx = np.asarray(indices, dtype=int)
    try:
        data = _select(array, idx)
        bad = idx[_bad_rows(data)]
        cause = "missing data (a chunk file is gone);"
    except Exception as exc:
        bad, data = damaged_samples(array, idx), None
        files = [str(chunk_file(folder, i, array.ndim)) for i in bad[:3]]
        cause = f"an unreadable chunk ({type(exc).__name__}: {exc}); delete {' '.join(files)} and"
    if bad.size or data is None:
        raise StoreError(
            f"{what} is damaged: sample(s) {bad[:5].tolist()}{' ...' if bad.size > 5 else ''} have {cause} "
            f"run '{repair}' again with the same arguments to rewrite them"
        )
    return data


def find_damaged(group: zarr.Group, root: Path, keys: Iterable[str], done: np.ndarray, full: bool) -> np.ndarray:
    """Samples among ``done`` with a lost (or, with ``full``, unreadable) chunk in any array ``keys`` of ``group``.

    ``full`` reads every such chunk (:func:`damaged_samples`); without it only the chunk files'
    names are looked up (:func:`missing_chunks`). Keys absent from the group are skipped.
    """
    bad = [np.zeros(0, int)]
    for key in (k for k in keys if k in group):
        array = group[key]
        bad.append(damaged_samples(array, done) if full else missing_chunks(root / key, done, array.ndim))
    return np.unique(np.concatenate(bad))
