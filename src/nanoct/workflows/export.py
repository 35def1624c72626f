"""A data set's reconstruction written out as image files or as a shifts file (what ``nanoct export`` runs).

:func:`export_images` writes the finished samples of a split as float32 images (one TIFF page,
``.npy`` or HDF5 slice per sample): the reconstruction, the pixel-wise std of an invertible
network's draws, or the half-width of its calibrated interval of a level.
:func:`export_shifts` writes the motion as nabu's ``translation_movements_file``: the one motion of
a stack result, else the shifts of one sample of a motion-estimating reconstruction.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from ..core.errors import NanoctError
from ..io.imagefiles import write_images
from ..io.shiftfile import write_stack_shifts
from ..io.store import DataStore
from ..recon.shared import write_store_shifts

__all__ = ["Exported", "export_images", "export_shifts"]


@dataclass(frozen=True)
class Exported:
    """What :func:`export_images` wrote: the file, how many samples, and what each map holds (``image``,
    ``std`` or ``half-width of the 0.9 interval``)."""

    path: Path
    samples: int
    content: str


def export_shifts(
    directory: str | os.PathLike[str], name: str, out: str | os.PathLike[str], sample: int | None
) -> Path:
    """Write the shifts of ``reconstructions/<name>`` to ``out`` in nabu's layout: a stack result's one motion,
    else those of ``sample`` (needed unless the motion is shared)."""
    path = write_stack_shifts(DataStore.open(directory), name, out)
    return path or write_store_shifts(directory, name, out, sample=sample)


def export_images(
    directory: str | os.PathLike[str],
    name: str,
    out: str | os.PathLike[str],
    *,
    split: str = "all",
    std: bool = False,
    interval: float | None = None,
    guaranteed: bool = False,
) -> Exported:
    """Write the finished samples of ``split`` of ``reconstructions/<name>`` to ``out`` (its suffix picks the format).

    ``std``: the network's std instead of the images; ``interval``: the half-width of the calibrated
    interval of that level (``guaranteed``: the risk-controlling multiplier).

    Raises
    ------
    NanoctError
        For an unknown reconstruction, a split with no finished sample, or a std asked of a result without one.
    """
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
        from ..evaluation.conformal import half_width

        spread, mean = store.read_uncertainty(name, idx), store.read_reconstruction(name, idx)
        images = half_width(store.reconstruction_params(name), spread, interval, guaranteed, mean=mean)
        images, content = images.astype("float32"), f"half-width of the {interval:g} interval"
    elif std:
        images, content = store.read_uncertainty(name, idx), "std"
    else:
        images, content = store.read_reconstruction(name, idx), "image"
    attrs = {"store": str(store.path), "name": name, "content": content, "samples": str(idx.tolist())}
    return Exported(write_images(out, images, attrs=attrs), int(idx.size), content)
