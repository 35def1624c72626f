"""A measured scan of any height: its motion from a few detector rows, then every row streamed in blocks.

:func:`reconstruct_scan` reads only a few detector rows of the scan file to estimate the
horizontal per-view shifts and the rotation axis
(:func:`~nanoct.motion.stack.estimate_stack_motion`), records them with the output, and hands the
scan to :func:`~nanoct.recon.slab.reconstruct_slabs` (blocks of rows read as hyperslabs,
corrected, reconstructed with gridrec, written as Zarr chunks, resumable by block). A stopped run
resumes with the recorded motion.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import zarr

from ..core.geometry import Geometry
from ..io.scanio import read_scan
from ..motion.stack import estimate_stack_motion
from ..recon.slab import read_block, reconstruct_slabs

__all__ = ["reconstruct_scan"]


def reconstruct_scan(
    scan: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    rows: tuple[int, int] | None = None,
    motion_rows: int = 4,
    center: float | None = None,
    block: int = 16,
    read: dict[str, Any] | None = None,
    workers: int = 0,
    scheduler: str | None = None,
    progress: bool = True,
) -> Path:
    """A scan's motion and axis from a few rows, then every row block by block (``reconstruct_slabs``).

    Parameters
    ----------
    scan, out, rows, block, read, workers, scheduler, progress
        See :func:`~nanoct.recon.slab.reconstruct_slabs`.
    motion_rows : int
        Detector rows, spread over the selection, read (only they) to estimate the horizontal
        shifts and the axis (:func:`~nanoct.motion.stack.estimate_stack_motion`).
    center : float, optional
        Axis offset in detector columns, if known (else estimated with the motion).

    Returns
    -------
    Path
        The output group; its attribute ``info`` holds the shifts and axis used. A stopped run
        resumes with them (they are not estimated again).
    """
    out = Path(out)
    info = dict(zarr.open_group(str(out), mode="r").attrs.get("info") or {}) if out.exists() else {}
    if "shifts" not in info:
        head = read_scan(scan, rows=slice(0, 1), **(read or {}))
        n_rows, n_cols = (int(v) for v in head.source["detector_shape"])
        first, stop = (0, n_rows) if rows is None else (int(rows[0]), int(rows[1]))
        chosen = sorted({int(r) for r in np.linspace(first, max(first, stop - 1), max(1, motion_rows)).round()})
        source = {"path": str(scan), "n_rows": n_rows, **(read or {})}
        sinos = np.concatenate([read_block(source, (r, r + 1)) for r in chosen if 0 <= r < n_rows])
        geometry = Geometry.from_angles(head.angles, n_cols, n_cols)
        motion = estimate_stack_motion(geometry, sinos, center=center)
        info = {"shifts": motion.shifts.tolist(), "center_offset": float(motion.center_offset),
                "center_method": motion.center_method, "motion_rows": chosen}  # fmt: skip
    return reconstruct_slabs(
        scan, out, shifts=np.asarray(info["shifts"]), center_offset=info["center_offset"], rows=rows, block=block,
        read=read, workers=workers, scheduler=scheduler, progress=progress, info=info,
    )  # fmt: skip
