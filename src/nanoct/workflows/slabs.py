"""A measured scan of any height streamed from its file: the stack's motion, then every row in blocks.

:func:`reconstruct_scan` is what ``nanoct stack SCAN --out OUT.zarr`` runs. It never holds the
scan: it estimates the motion as ``nanoct stack`` does on a data set, from the scan file read a
few rows at a time (:class:`ScanRows` gives the estimators the rows they ask for, each read as a
hyperslab and flat/dark corrected), records it with the output, and hands the scan to
:func:`~nanoct.recon.slab.reconstruct_slabs` (blocks of rows read, corrected, moved back,
reconstructed with gridrec, written as Zarr chunks, resumable by block). The motion:

* vertical: one pass over the selected rows in blocks summing each view's rows
  (:func:`scan_profiles`), registered by :func:`~nanoct.motion.vertical.vertical_motion` (zero
  where not significant, the reason recorded as ``vertical_guard``), for selections of at least
  :data:`~nanoct.workflows.stack.MIN_VERTICAL_SLICES` rows (as the stack);
* horizontal and axis: :func:`~nanoct.workflows.stack.horizontal_motion` on a few rows, each
  moved back by the vertical shift, as ``nanoct stack`` on a data set (autofocus and projection
  matching on a central block of rows where no air is seen), except that where air is seen the
  axis is the centroids' as the stack chooses it, checked against opposite views
  (:func:`slab_centroids`; the slow ``find_center_vo`` is left out). The axis tilt is not
  estimated here (one axis for every row).

A stopped run resumes with the recorded motion; the same command with other motion options is
refused (another output, or ``overwrite``).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import zarr
from tqdm.auto import tqdm

from ..core.errors import NanoctError
from ..core.geometry import Geometry
from ..io.lock import exclusive
from ..io.scanio import read_scan
from ..motion.model import fit_motion_model
from ..motion.vertical import vertical_motion
from ..recon.slab import SLAB_FORMAT, check_selection, read_block, reconstruct_slabs, slab_blocks
from .stack import MIN_VERTICAL_SLICES, consistent_motion, horizontal_motion

__all__ = ["ScanRows", "reconstruct_scan", "scan_profiles", "slab_centroids"]


class ScanRows:
    """Detector rows ``[first, stop)`` of a scan file, read on demand as a data set's sinograms.

    The stack's motion estimators read a store through ``geometry``, ``n`` and
    ``read_array("sinograms", indices)``; this gives them rows of the scan file instead (row
    ``first + i`` for index ``i``), each run of consecutive rows read as one hyperslab.

    Parameters
    ----------
    source : dict
        As :func:`~nanoct.recon.slab.read_block` takes it (``path``, ``n_rows``, reading options).
    first, stop : int
        The selected detector rows.
    geometry : Geometry
        The scan's parallel-beam geometry (its axis offset is the estimators' start).
    """

    def __init__(self, source: dict[str, Any], first: int, stop: int, geometry: Geometry) -> None:
        self.source, self.first, self.n, self.geometry = source, first, stop - first, geometry

    def read_array(self, name: str, indices: list[int]) -> np.ndarray:
        """Sinograms ``(len(indices), K, L)`` float32 of the rows ``first + indices`` (``name`` is ignored)."""
        rows = [int(i) for i in indices]
        out = np.empty((len(rows), self.geometry.n_angles, self.geometry.n_det), np.float32)
        start = 0
        while start < len(rows):
            end = start + 1
            while end < len(rows) and rows[end] == rows[end - 1] + 1:
                end += 1
            r0 = self.first + rows[start]
            out[start:end] = read_block(self.source, (r0, r0 + end - start))
            start = end
        return out


def scan_profiles(source: dict[str, Any], rows: tuple[int, int], block: int, progress: bool = False) -> np.ndarray:
    """``(K, R)`` row profiles of rows ``[first, stop)``: each view's line integrals summed over the detector.

    One pass over the rows in blocks of ``block`` (memory bounded by a block), a progress bar per block.
    """
    blocks = slab_blocks(rows[0], rows[1], block)
    parts = []
    for r0, r1 in tqdm(blocks, desc="row profiles", disable=not progress, unit="block"):
        parts.append(read_block(source, (r0, r1)).sum(axis=2, dtype=np.float64))
    return np.concatenate(parts).T


def _motion_rows(value: Any, n: int) -> list[int]:
    """Indices into the selected rows the horizontal motion is read from: ``"auto"`` (4), a count, or the rows."""
    if value is None or value == "auto":
        value = 4
    if isinstance(value, int):
        return sorted({int(r) for r in np.linspace(0, n - 1, max(1, min(value, n))).round()})
    chosen = sorted({int(r) for r in value})
    if not chosen or chosen[0] < 0 or chosen[-1] >= n:
        text = ",".join(str(int(r)) for r in value)
        raise NanoctError(
            f"--motion-slices {text}: rows of the selection, counted from its first; it has {n} rows (0..{n - 1})"
        )
    return chosen


def _estimate(source: dict[str, Any], geometry: Geometry, selection: tuple[int, int], params: dict[str, Any],
              progress: bool) -> dict[str, Any]:  # fmt: skip
    """The motion of the selected rows (module docstring), as recorded with the output."""
    rows = ScanRows(source, *selection, geometry)
    vertical = np.zeros(geometry.n_angles)
    guard: dict[str, Any] = {"note": "no vertical motion estimated (vertical off)"}
    if rows.n < MIN_VERTICAL_SLICES:
        guard = {"note": f"fewer than {MIN_VERTICAL_SLICES} rows: no vertical motion estimated"}
    elif params["vertical"]:
        estimate = vertical_motion(scan_profiles(source, selection, params["block"], progress))
        vertical, guard = estimate.shifts, estimate.to_dict()
    motion = {**params, "motion_slices": _motion_rows(params["motion_slices"], rows.n)}
    shifts, info = horizontal_motion(rows, motion, vertical, progress, "motion", slab_centroids)  # type: ignore[arg-type]
    info["vertical_method"] = "row profiles" if np.any(vertical) else "none"
    info["vertical_guard"] = guard
    if params["model"] is not None:
        model = fit_motion_model(shifts, geometry.angles, *params["model"])
        shifts, info["model_residual_rms"] = model.shifts, model.residual_rms
    shifts = consistent_motion(rows, motion, vertical, shifts, info)  # type: ignore[arg-type]
    info["shift_rms"] = float(np.sqrt(np.mean(shifts**2)))
    info.update(shifts=[float(v) for v in shifts], vertical=[float(v) for v in vertical])
    info.update(motion_rows=[selection[0] + i for i in motion["motion_slices"]], params=params)
    return info


def slab_centroids(
    rows: ScanRows, params: dict[str, Any], vertical: np.ndarray, clean: np.ndarray, bar: Any
) -> tuple[np.ndarray, dict[str, Any]]:
    """Air seen around the object in ``clean`` (the motion slices, open beam removed): the views' centroids.

    Where the views' mass varies by at most 1 %, the axis is the centroids' (the value
    :func:`~nanoct.motion.axis.estimate_axis` uses then), checked against the opposite views'
    (``mirror``, with the shifts) on the same rows; the stack's other estimator
    (``find_center_vo``, about a minute per row at 2048 columns and 1800 views) is not run.
    Otherwise :func:`~nanoct.workflows.stack.centroid_motion_axis`, as on a data set. One stage
    on ``bar`` (:func:`~nanoct.workflows.stack.horizontal_motion`'s).

    Parameters
    ----------
    rows : ScanRows
        The selected rows of the scan file.
    params, vertical, clean, bar
        As for :func:`~nanoct.workflows.stack.centroid_motion_axis`.

    Returns
    -------
    tuple
        As :func:`~nanoct.workflows.stack.centroid_motion_axis`: the shifts and what is recorded with them.
    """
    from ..motion.axis import AGREEMENT_PX, object_rows
    from ..motion.center import centroid_motion, fit_center
    from .stack import centroid_motion_axis

    phi = rows.geometry.angles
    held = object_rows(clean)
    center, shifts, spread = centroid_motion(clean[held] if held.any() else clean, phi)
    if not spread <= 0.01:
        return centroid_motion_axis(rows, params, vertical, clean, bar)  # type: ignore[arg-type]
    bar.set_postfix_str("centroids and axis")
    info: dict[str, Any] = {"horizontal_method": "centroid", "mass_spread": spread, "refine_steps": []}
    if params["center"] != "auto":
        info.update(center_offset=float(params["center"]), center_method="given")
        bar.update()
        return shifts, info
    mirror = fit_center(clean, phi, shifts, max_offset=rows.geometry.n_det / 4)
    notes = []
    if abs(mirror - center) > AGREEMENT_PX:
        notes.append(f"warning: the axis estimators disagree by {abs(mirror - center):.2f} px "
                     f"(centroid {center:+.2f}, mirror {mirror:+.2f}); motion or a wrong axis")  # fmt: skip
    axis = {"offset": center, "estimates": {"centroid": center, "mirror": mirror}, "used": ["centroid"], "notes": notes}
    info.update(center_offset=float(center), center_raw=float(center), axis=axis)
    info["center_method"] = "the views' centroids (opposite views as a check)"
    bar.update()
    return shifts, info


def _existing_info(out: Path, params: dict[str, Any], overwrite: bool) -> dict[str, Any]:
    """The motion recorded with an existing output made with ``params``; ``{}`` where there is none."""
    if not out.exists():
        return {}
    try:
        group = zarr.open_group(str(out), mode="r")
        made = group.attrs.get("nanoct")
    except Exception:  # noqa: BLE001 - anything that is not a readable Zarr group
        made = None
    if not isinstance(made, dict) or made.get("format") != SLAB_FORMAT:
        raise NanoctError(f"{out} exists and is not a slab reconstruction; choose another --out")
    if overwrite:
        shutil.rmtree(out)
        return {}
    info = dict(group.attrs.get("info") or {})
    if info.get("params", params) != params:
        raise NanoctError(f"{out} holds slabs made with other motion options; choose another --out or add --overwrite")
    return info


def reconstruct_scan(
    scan: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    rows: tuple[int, int] | None = None,
    motion_rows: Any = 4,
    center: float | None = None,
    block: int = 16,
    read: dict[str, Any] | None = None,
    vertical: bool = True,
    motion: dict[str, Any] | None = None,
    overwrite: bool = False,
    workers: int = 0,
    scheduler: str | None = None,
    progress: bool = True,
) -> Path:
    """A scan's motion and axis (module docstring), then every row block by block (``reconstruct_slabs``).

    Parameters
    ----------
    scan, out, rows, block, read, workers, scheduler, progress
        See :func:`~nanoct.recon.slab.reconstruct_slabs`.
    motion_rows : int, "auto" or list of int
        How many detector rows, spread over the selection (``"auto"``: 4), or which rows of the
        selection (0-based within it), the horizontal motion is estimated from.
    center : float, optional
        Axis offset in detector columns, if known (else estimated with the motion).
    vertical : bool
        Estimate the vertical motion (selections of at least 16 rows; one more pass over the rows).
    motion : dict, optional
        ``binning``, ``coarse_iter``, ``refine`` (see :func:`~nanoct.motion.stack.estimate_stack_motion`)
        and ``model`` (degree, harmonics: a smooth model of the horizontal shifts).
    overwrite : bool
        Delete an existing slab output first.

    Returns
    -------
    Path
        The output group; its attribute ``info`` holds the motion and axis used. A stopped run
        resumes with them (they are not estimated again).

    Raises
    ------
    NanoctError
        For bad rows, block or motion rows (before anything is read or written), or an output
        made with other options.
    """
    out = Path(out)
    head = read_scan(scan, rows=slice(0, 1), **(read or {}))
    n_rows, n_cols = int(head.source["detector_shape"][0]), int(head.projections.shape[-1])
    first, stop = check_selection(rows, block, n_rows)
    extra = {"binning": 8, "coarse_iter": 8, "refine": None, "model": None, **(motion or {})}
    params = {
        "center": "auto" if center is None else float(center),
        "motion_slices": motion_rows if isinstance(motion_rows, (int, str)) else [int(r) for r in motion_rows],
        "vertical": bool(vertical),
        "block": block,
        "binning": int(extra["binning"]),
        "coarse_iter": int(extra["coarse_iter"]),
        "refine": None if extra["refine"] is None else [int(b) for b in extra["refine"]],
        "model": None if extra["model"] is None else [int(v) for v in extra["model"]],
    }
    _motion_rows(params["motion_slices"], stop - first)  # checked before anything is read
    with exclusive(out.parent, out.name, f"the slab output {out}"):  # one writer of OUT.zarr at a time
        info = _existing_info(out, params, overwrite)
        if "shifts" not in info:
            source = {"path": str(scan), "n_rows": n_rows, **(read or {})}
            geometry = Geometry.from_angles(head.angles, n_cols, n_cols)
            info = _estimate(source, geometry, (first, stop), params, progress)
        moved = np.asarray(info["vertical"])
        return reconstruct_slabs(
            scan, out, shifts=np.asarray(info["shifts"]), vertical=moved if moved.any() else None,
            center_offset=info["center_offset"], rows=(first, stop), block=block, read=read, workers=workers,
            scheduler=scheduler, progress=progress, info=info,
        )  # fmt: skip
