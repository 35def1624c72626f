"""HDF5 / NeXus scans of any layout: frames, image keys and angles at known or given dataset paths.

Beamlines write tomography to HDF5 in a few layouts. NXtomo (an ``NXentry`` whose
``definition`` is ``NXtomo``) is read by :mod:`nanoct.io.nxtomo`; the others are a row of
:data:`LAYOUTS` (the paths of the frames, their image keys, the angles and, for Data Exchange,
separate flats and darks), chosen automatically when the file holds that layout's frames and
angles (:func:`detect_layout`), or given path by path (``--data-path``, ``--image-key-path``,
``--angles-path``, ``--angles-units``), which also override a detected layout's paths. Each row is
a ``--format`` of its own (:mod:`nanoct.io.readers.layouts`).

Image keys follow NXtomo (0 projection, 1 flat, 2 dark, 3 invalid and -1 alignment left out);
without a key every frame is a projection. Angles are read in the unit given by
``--angles-units``, else the dataset's ``units`` attribute, else the layout's unit (degrees).
Every path is read through :class:`~nanoct.io.h5tree.H5Tree`: external links and virtual data
sets resolve only below the scan's folder (and folders the user allows).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from ..core.errors import NanoctError
from .angles import ANGLE_UNITS, in_radians
from .h5tree import H5Tree
from .nxtomo import nxtomo_entries, split_by_key
from .rawscan import RawScan, check_angles

__all__ = ["LAYOUTS", "H5Layout", "custom_layout", "detect_layout", "read_layout"]


@dataclass(frozen=True)
class H5Layout:
    """Where one HDF5 layout keeps a scan.

    Attributes
    ----------
    name : str
        The ``--format`` value.
    title : str
        Who writes it.
    data : str
        Frames ``(F, R, L)``.
    image_key : str, optional
        One NXtomo image key per frame (none: every frame of ``data`` is a projection).
    angles : str, optional
        One angle per frame (per projection without ``image_key``).
    angle_units : str
        Unit of the angles when the dataset has no ``units`` attribute.
    flats, darks : str, optional
        Separate flat and dark frames (Data Exchange).
    """

    name: str
    title: str
    data: str
    image_key: str | None = None
    angles: str | None = None
    angle_units: str = "degree"
    flats: str | None = None
    darks: str | None = None


LAYOUTS = {
    layout.name: layout
    for layout in (
        H5Layout(
            "diamond",
            "Diamond scan NeXus (GDA; K11/DIAD paths)",
            "/entry/imaging/data",
            image_key="/entry/instrument/imaging/image_key",
            angles="/entry/imaging_sum/gts_theta_value",
        ),
        H5Layout(
            "diamond-nxtomo",
            "Diamond NXtomo subentry (I12, I13)",
            "/entry1/tomo_entry/data/data",
            image_key="/entry1/tomo_entry/instrument/detector/image_key",
            angles="/entry1/tomo_entry/data/rotation_angle",
        ),
        H5Layout(
            "dxchange",
            "Data Exchange (APS, TomoPy)",
            "/exchange/data",
            angles="/exchange/theta",
            flats="/exchange/data_white",
            darks="/exchange/data_dark",
        ),
    )
}


def detect_layout(tree: H5Tree) -> str | None:
    """``"nxtomo"``, the name of the first :data:`LAYOUTS` row whose frames the file holds, or None."""
    if nxtomo_entries(tree):
        return "nxtomo"
    for layout in LAYOUTS.values():
        if tree.has(layout.data):
            return layout.name
    return None


def read_layout(
    tree: H5Tree,
    layout: H5Layout,
    window: Callable[..., tuple[slice, slice]],
    *,
    units: str | None = None,
    need_angles: bool = True,
) -> RawScan:
    """Read a scan laid out as ``layout`` (paths absolute in the file).

    Parameters
    ----------
    tree : H5Tree
        The open file.
    layout : H5Layout
    window : callable
        ``window((R, L)) -> (row slice, column slice)``: the part of the detector read from disk.
    units : {"deg", "rad"}, optional
        The angles' unit as the user states it (overrides the file's; no span check then).
    need_angles : bool
        False when the angles come from elsewhere (``--angles``): the scan gets placeholder
        angles ``0, 1, ...`` radians, replaced by the caller.

    Raises
    ------
    NanoctError
        Missing datasets, wrong shapes, counts that differ, unknown keys, a refused link.
    """
    path = tree.path
    shape = tree.dataset(layout.data).shape
    if len(shape) != 3:
        raise NanoctError(f"{path}:{layout.data} has shape {shape}; expected (frames, rows, columns)")
    region = (slice(None), *window(shape[1:]))
    data = tree.read(layout.data, region)[0].astype(np.float32, copy=False)
    keys = np.zeros(data.shape[0], int) if layout.image_key is None else tree.read(layout.image_key)[0]
    if need_angles and (layout.angles is None or not tree.has(layout.angles)):
        where = "" if layout.angles is None else f" (no {layout.angles})"
        raise NanoctError(f"{path}: no angles{where}; pass --angles-path DATASET or --angles FILE")
    if need_angles:
        raw, stored = tree.read(layout.angles)
    else:
        raw, stored = np.zeros(np.asarray(keys).size), None
    raw = np.asarray(raw, dtype=np.float64).ravel()
    proj, raw_proj, flats, darks, notes = split_by_key(data, keys, raw, where=str(path), keys_name=layout.image_key)
    for name, frames in (("flats", layout.flats), ("darks", layout.darks)):
        if frames is not None and tree.has(frames):
            extra = _frames(tree, frames, name, shape, region)
            if name == "flats":
                flats = extra if flats is None else np.concatenate([flats, extra])
            else:
                darks = extra if darks is None else np.concatenate([darks, extra])
    unit = units or stored or layout.angle_units
    where = f"{path}:{layout.angles}"
    angles = in_radians(raw_proj, unit, where) if need_angles else np.arange(proj.shape[0], dtype=np.float64)
    if need_angles and units is None:
        degrees = bool(np.isclose(in_radians(np.array(1.0), unit, where), np.pi / 180))
        check_angles(angles, degrees=degrees, where=where, fix="pass --angles-units or --angles FILE")
    source = {
        "file": str(path),
        "format": layout.name,
        "data": layout.data,
        "image_key": layout.image_key,
        "angles": layout.angles,
        "angle_units": unit if need_angles else None,
        "detector_shape": list(shape[1:]),
        "notes": notes,
    }
    return RawScan(proj, angles, flats=flats, darks=darks, source=source)


def _frames(tree: H5Tree, name: str, what: str, shape: tuple[int, ...], region: tuple[slice, ...]) -> np.ndarray:
    """Separate flat or dark frames, checked against the projections' detector size."""
    found = tree.dataset(name).shape
    if len(found) == 2:
        found, region = (1, *found), region[1:]
    if found[1:] != shape[1:]:
        raise NanoctError(
            f"{tree.path}: {what} have shape {found} ({name}), but one projection is {shape[1:]} "
            f"(rows, columns); give {what} of the same detector size"
        )
    frames = tree.read(name, region)[0].astype(np.float32, copy=False)
    return frames[None] if frames.ndim == 2 else frames


def custom_layout(
    base: H5Layout | None, data: str | None, image_key: str | None, angles: str | None, units: str | None
) -> H5Layout:
    """``base`` (or an empty layout) with the paths the user gave on the command line.

    Raises
    ------
    NanoctError
        No frames path at all, or an unknown ``--angles-units``.
    """
    if units is not None and units not in ANGLE_UNITS:
        raise NanoctError(f"--angles-units {units!r}: use deg or rad")
    if base is None and data is None:
        raise NanoctError("give --data-path DATASET (the frames) for an HDF5 file of no known layout")
    layout = base or H5Layout("hdf5", "given paths", data)  # type: ignore[arg-type]
    changes = {"data": data, "image_key": image_key, "angles": angles}
    layout = replace(layout, **{k: v for k, v in changes.items() if v is not None})
    return replace(layout, name="hdf5") if any(changes.values()) else layout
