"""Streaming slab reconstruction: a scan of any height, a block of detector rows at a time, into Zarr.

:func:`reconstruct_slabs` never holds the scan: each task reads one block of detector rows of
every view from the scan file (a hyperslab: HDF5 and ``.npy`` files read only those rows),
applies the flat/dark correction (:func:`~nanoct.io.scanio.line_integrals`), moves every view
back by its vertical and horizontal shift, reconstructs the block's slices with gridrec (two
slices per complex transform, :class:`~nanoct.recon.gridrec.GridrecPlan`, built once per
process) and writes them as one Zarr chunk, then sets the block's progress flag. Memory is
bounded by a block (its rows of every view, a few rows above and below for the vertical shift,
and its images), not by the volume. Blocks are independent tasks
(:func:`~nanoct.core.fanout.run_tasks`: in this process, on local Dask workers or a cluster); a
run that is stopped resumes with the blocks whose flag is not set, and since every step is
deterministic the bytes written are those of an undisturbed run.

Motion convention (``docs/conventions.md``, extended to the rows): the measured projection is
``p_k(u, z) = P_k(u + d_k, z + v_k)`` for the static object's projection ``P_k``, ``d_k`` in
detector columns (as ``nanoct stack``'s shifts) and ``v_k`` in detector rows. The vertical shift
is undone by linear interpolation along the rows (the first and last rows repeat outside the
detector); the horizontal one is a phase ramp inside gridrec.

The output group holds ``slices`` (rows, N, N) float32 chunked by block, ``done`` (one flag per
block) and the attribute ``nanoct`` with the parameters (a second run with other parameters is
refused: choose another output or delete it).
"""

from __future__ import annotations

import hashlib
import json
import os
import uuid
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import zarr

from ..core.errors import NanoctError
from ..core.fanout import run_tasks, usable_cpus, worker_threads
from ..core.geometry import Geometry
from ..io.rawscan import check_span
from ..io.scanio import line_integrals, read_scan

__all__ = ["SLAB_FORMAT", "check_selection", "read_block", "read_slab_record", "reconstruct_slabs", "slab_blocks"]

#: Version of the output layout.
SLAB_FORMAT = 1


def slab_blocks(first: int, stop: int, block: int) -> list[tuple[int, int]]:
    """Detector rows ``[first, stop)`` cut into ``[r0, r1)`` blocks of ``block`` rows (the last may be shorter)."""
    return [(r0, min(r0 + block, stop)) for r0 in range(first, stop, block)]


def check_selection(rows: tuple[int, int] | None, block: Any, n_rows: int) -> tuple[int, int]:
    """The detector rows ``[first, stop)`` to reconstruct (all for ``None``), checked with the block size.

    Raises
    ------
    NanoctError
        For rows outside the detector's ``n_rows`` or a block that is not a whole number >= 1.
    """
    first, stop = (0, n_rows) if rows is None else (int(rows[0]), int(rows[1]))
    check_span("--rows", (first, stop), n_rows, "detector rows")
    if isinstance(block, bool) or not isinstance(block, (int, np.integer)) or block < 1:
        raise NanoctError(f"--block {block!r} must be a whole number of detector rows >= 1, e.g. 16")
    return first, stop


def _unshift_rows(data: np.ndarray, vertical: np.ndarray, top: int, rows: tuple[int, int], n_rows: int) -> np.ndarray:
    """Rows ``rows`` of the static projections from ``data`` (K, R', L), which starts at detector row ``top``.

    Row ``z`` of view ``k`` is read at ``z - v_k``, linearly between the two rows around it; the
    detector's first and last rows repeat outside it (as :func:`nanoct.workflows.stack.read_straight`).
    """
    z = np.arange(*rows, dtype=np.float64)
    out = np.empty((data.shape[0], z.size, data.shape[2]), dtype=np.float32)
    last = max(data.shape[1] - 2, 0)
    for k, v in enumerate(vertical):
        pos = np.clip(z - v, 0, n_rows - 1) - top
        lo = np.clip(np.floor(pos).astype(int), 0, last)
        frac = (pos - lo)[:, None]
        out[k] = (1 - frac) * data[k, lo] + frac * data[k, np.minimum(lo + 1, data.shape[1] - 1)]
    return out


def read_block(source: dict[str, Any], rows: tuple[int, int], vertical: np.ndarray | None = None) -> np.ndarray:
    """Sinograms ``(S, K, L)`` of detector rows ``[r0, r1)``: read, flat/dark corrected, vertical shift undone.

    Parameters
    ----------
    source : dict
        ``path`` of the scan and the keyword arguments of :func:`~nanoct.io.scanio.read_scan`
        (``fmt``, ``angles_file``, ``flats``, ``darks``, ...), and ``n_rows`` (detector rows).
    rows : (int, int)
        The block's detector rows.
    vertical : ndarray of shape (K,), optional
        Per-view vertical shifts ``v_k`` in detector rows (module docstring).

    Returns
    -------
    ndarray of shape (r1 - r0, K, L), float32
    """
    options = {k: v for k, v in source.items() if k not in ("path", "n_rows")}
    pad = 0 if vertical is None else int(np.ceil(np.abs(vertical).max())) + 1
    top, bottom = max(0, rows[0] - pad), min(int(source["n_rows"]), rows[1] + pad)
    raw = read_scan(source["path"], rows=slice(top, bottom), **options)
    data = line_integrals(raw, flat_tolerance=BLOCK_FLAT_TOLERANCE)
    if vertical is None:
        block = data[:, rows[0] - top : rows[1] - top]
    else:
        block = _unshift_rows(data, vertical, top, rows, int(source["n_rows"]))
    return np.ascontiguousarray(block.transpose(1, 0, 2))


#: Fraction of a block's detector pixels whose flat may lie at or below the dark (line integral 0
#: there). A detector's dead pixels gather in some rows (the I13 24737 scan: 0.6 % of the pixels of
#: its first rows, under 0.1 % of the whole detector), so a block is refused only where most of
#: its flat is below the dark: a wrong flat or dark, not a few dead pixels.
BLOCK_FLAT_TOLERANCE = 0.5

_PLAN: dict[tuple, Any] = {}  # this process's gridrec plan (one scan's geometry and motion)


def _block_task(out: str, source: dict[str, Any], setup: dict[str, Any], blocks: list, index: int) -> int:
    """One task: block ``index`` reconstructed and written (:func:`_write_block`)."""
    return _write_block(out, source, setup, blocks, index)


def _write_block(out: str, source: dict[str, Any], setup: dict[str, Any], blocks: list, index: int) -> int:
    """Reconstruct block ``index`` and write it (its chunk, then its flag)."""
    from .gridrec import GridrecPlan

    key = (out, setup["digest"])
    if key not in _PLAN:
        _PLAN.clear()
        geometry = Geometry.from_dict(setup["geometry"])
        _PLAN[key] = GridrecPlan(geometry, setup["shifts"], threads=setup["threads"])
    r0, r1 = blocks[index]
    images = _PLAN[key](read_block(source, (r0, r1), setup["vertical"]))
    group = zarr.open_group(out, mode="r+")
    first = blocks[0][0]
    group["slices"][r0 - first : r1 - first] = images  # type: ignore[index]
    group["done"][index] = True  # type: ignore[index]
    return index


def _digest(*arrays: np.ndarray | None) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(b"none" if a is None else np.ascontiguousarray(a, dtype=np.float64).tobytes())
    return h.hexdigest()[:16]


def _open_output(out: Path, meta: dict[str, Any], shape: tuple[int, int, int], block: int, info: Any) -> zarr.Group:
    """The output group: created atomically (temporary sibling, then renamed), or reopened with the same parameters."""
    if out.exists():
        group = zarr.open_group(str(out), mode="r+")
        if dict(group.attrs.get("nanoct", {})) != meta:
            raise NanoctError(
                f"{out} holds slabs made with other rows, block, reading options or motion; "
                "choose another --out or add --overwrite"
            )
        return group
    tmp = out.parent / f".{out.name}.creating-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    group = zarr.open_group(str(tmp), mode="w")
    group.attrs["nanoct"] = meta
    group.attrs["info"] = json.loads(json.dumps(info))
    n_blocks = -(-shape[0] // block)
    group.create_array("slices", shape=shape, chunks=(block, *shape[1:]), dtype="float32", fill_value=np.nan)
    group.create_array("done", shape=(n_blocks,), chunks=(1,), dtype="bool", fill_value=False)
    os.replace(tmp, out)
    return zarr.open_group(str(out), mode="r+")


def read_slab_record(out: str | os.PathLike[str]) -> tuple[dict[str, Any], dict[str, Any], np.ndarray]:
    """What a slab output records: its parameters (attribute ``nanoct``), the motion and axis it was made with
    (attribute ``info``; empty where there is none) and the progress flag of each block."""
    group = zarr.open_group(str(out), mode="r")
    return dict(group.attrs["nanoct"]), dict(group.attrs.get("info") or {}), np.asarray(group["done"][:])  # type: ignore[index]


def reconstruct_slabs(
    scan: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    shifts: Any = None,
    vertical: Any = None,
    center_offset: float = 0.0,
    rows: tuple[int, int] | None = None,
    block: int = 16,
    read: dict[str, Any] | None = None,
    workers: int = 0,
    scheduler: str | None = None,
    progress: bool = True,
    info: Any = None,
) -> Path:
    """Reconstruct every detector row of a scan (or ``rows``) block by block into a Zarr group (resumable).

    Parameters
    ----------
    scan : path
        Scan file (NXtomo, Data Exchange, TIFF, ``.npy``; :func:`~nanoct.io.scanio.read_scan`).
    out : path
        Output Zarr group (created, or resumed when it exists with the same parameters).
    shifts, vertical : array_like of shape (K,), optional
        Per-view horizontal (detector columns) and vertical (detector rows) shifts (module docstring).
    center_offset : float
        Rotation axis minus the detector centre, in detector columns.
    rows : (int, int), optional
        Detector rows ``[first, stop)`` to reconstruct (default all).
    block : int
        Rows per block: per task, per Zarr chunk, and the unit of resuming.
    read : dict, optional
        More keyword arguments of :func:`~nanoct.io.scanio.read_scan` (``fmt``, ``angles_file``,
        ``flats``, ``darks``, ``entry``, ``is_line_integral``).
    workers, scheduler, progress
        See :func:`nanoct.core.fanout.run_tasks`; each worker runs one pair of slices per thread.
    info : JSON-able, optional
        Recorded with a new output as the attribute ``info`` (e.g. how the motion was found).

    Returns
    -------
    Path
        The output group.

    Raises
    ------
    NanoctError
        For bad rows, block or shifts, an unreadable scan, or an output made with other parameters.
    """
    source = {"path": str(scan), **(read or {})}
    head = read_scan(scan, rows=slice(0, 1), **(read or {}))
    n_rows, n_cols = int(head.source["detector_shape"][0]), int(head.projections.shape[-1])
    first, stop = check_selection(rows, block, n_rows)
    block = int(block)
    k = head.n_views
    arrays = []
    for label, value in (("shifts", shifts), ("vertical", vertical)):
        arr = None if value is None else np.asarray(value, dtype=np.float64)
        if arr is not None and (arr.shape != (k,) or not np.isfinite(arr).all()):
            raise NanoctError(f"{label} must be {k} finite values, one per view")
        arrays.append(arr)
    geometry = Geometry.from_angles(head.angles, n_cols, n_cols, center_offset=float(center_offset))
    blocks = slab_blocks(first, stop, block)
    meta = {
        "format": SLAB_FORMAT,
        "source": {k_: str(v) for k_, v in source.items()},
        "rows": [first, stop],
        "block": block,
        "geometry": geometry.to_dict(),
        "motion": _digest(*arrays),
    }
    group = _open_output(Path(out), meta, (stop - first, n_cols, n_cols), block, info)
    done = np.asarray(group["done"][:])  # type: ignore[index]
    pending = [i for i in range(len(blocks)) if not done[i]]
    threads = worker_threads(workers) if workers and not scheduler else usable_cpus()
    setup = {
        "geometry": geometry.to_dict(),
        "shifts": arrays[0],
        "vertical": arrays[1],
        "threads": threads,
        "digest": _digest(*arrays) + json.dumps(meta["geometry"], sort_keys=True) + str(threads),
    }
    source["n_rows"] = n_rows
    task = partial(_block_task, str(Path(out)), source, setup, blocks)
    fan = {"workers": workers, "scheduler": scheduler, "progress": progress, "unit": "block"}
    run_tasks(task, pending, desc=Path(out).name, done=len(blocks) - len(pending), **fan)
    return Path(out)
