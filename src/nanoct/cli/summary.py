"""What ``import`` and ``stack`` print when they are done: the data set made, the axis and motion found, where
the slices are, and the notes on options that were not used."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from .flags import given


def echo_import(store: Any) -> None:
    """The data set ``import`` made (slices, views, detector, image, axis, pixel) and its notes and warnings."""
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


def _notes(settings: Any, info: dict[str, Any]) -> str:
    """The summary's closing note lines: the Dremel options given but left unused where the views' centroids gave
    the motion, and the former spelling ``--binning`` where it was used ("" where neither)."""
    text = ""
    unused = given(settings, ("dremel_binning", "binning", "coarse_iter"))
    if unused and info.get("horizontal_method") == "centroid":
        text += (
            f"\n  note     {', '.join(unused)} not used: air is seen around the object, so the views' centroids "
            "gave the motion; add --refine (e.g. 2,2,2,1) for Dremel and projection matching with them"
        )
    if settings.binning is not None:
        text += (
            "\n  note     --binning is the former spelling of --dremel-binning (the binning of the coarse Dremel "
            "estimate; 'nanoct import --binning' bins the detector)"
        )
    return text


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
    from ..workflows.stack import consistency_lines

    return lines + consistency_lines(info)


def stack_summary(store: Any, name: str, settings: Any, info: dict[str, Any]) -> str:
    """What 'nanoct stack' found and wrote on a data set (``info``: the motion recorded with ``name``): axis, how
    it was found, the motion's range, where the slices are."""
    import numpy as np

    from ..recon.batch import shift_check_warning

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
    kept = shift_check_warning(store, name, unit="slice")
    if kept:
        lines.append(f"  warning  {kept}")
    return "\n".join(lines) + _notes(settings, info)


def slab_summary(out: Path, settings: Any) -> str:
    """What the streaming stack (``--out``) found and wrote."""
    from ..recon.slab import read_slab_record

    meta, info, done = read_slab_record(out)
    shifts = info.get("shifts") or [0.0]
    first, stop = meta["rows"]
    lines = [
        f"wrote {out}: rows {first}:{stop} in blocks of {meta['block']}, axis offset "
        f"{info.get('center_offset', float('nan')):+.3f} px, {_how_found(info.get('center_method'))}",
        f"  motion   {min(shifts):+.3f} to {max(shifts):+.3f} px over {len(shifts)} views "
        f"(from rows {info.get('motion_rows')})",
        *_motion_lines(info),
        f"  slices   {int(done.sum())} of {done.size} blocks done; the images are the array 'slices' of {out}",
    ]
    return "\n".join(lines) + _notes(settings, info)
