"""NXtomo files as ESRF's ``nxtomo`` library (and other NeXus writers) lay them out (``--format nxtomo``:
:mod:`nanoct.io.readers.nxtomo`).

The NXtomo application definition lets the ``NXentry`` have any name (``nxtomo`` writes
``entry0000``); an entry is recognised by its ``NX_class`` attribute ``NXentry`` and its
``definition`` ``NXtomo``. Files without these attributes are read from the usual paths
(``entry/instrument/detector/data``, ``entry1/...``). Within an entry:

* frames: ``instrument/detector/data`` (or ``data/data``), shape ``(frames, rows, columns)``;
* frame kinds: ``instrument/detector/image_key_control`` where present (it keeps the
  alignment frames, -1, that ``image_key`` marks as projections), else ``image_key``:
  0 projection, 1 flat, 2 dark, 3 invalid and -1 alignment (both left out);
* angles: ``sample/rotation_angle`` in the unit of its ``units`` attribute (any angle unit
  pint understands: ``degree``, ``deg``, ``rad`` ...; degrees when it has none, as NXtomo
  defines);
* pixel size: ``sample/x_pixel_size`` (the effective pixel at the sample, written by
  ``nxtomo``), else ``instrument/detector/x_pixel_size`` (and ``y_``), any length unit,
  metres when it has none.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from .h5tree import H5Tree, text

__all__ = ["NXtomoFrames", "nxtomo_entries", "read_nxtomo", "split_by_key", "to_unit"]

KEY_PROJECTION, KEY_FLAT, KEY_DARK, KEY_INVALID, KEY_ALIGNMENT = 0, 1, 2, 3, -1

# relative paths inside an entry (first found is used)
_DATA = ("instrument/detector/data", "data/data")
_KEYS = ("instrument/detector/image_key_control", "instrument/detector/image_key", "data/image_key")
_ANGLES = ("sample/rotation_angle", "data/rotation_angle")
_PIXEL = ("sample/{}_pixel_size", "instrument/detector/{}_pixel_size")
_LEGACY_ENTRIES = ("entry", "entry1")


@dataclass(frozen=True)
class NXtomoFrames:
    """The frames of one NXtomo entry sorted by kind.

    Attributes
    ----------
    projections : ndarray of shape (K, R, L)
    angles : ndarray of shape (K,)
        Radians.
    flats, darks : ndarray of shape (F, R, L) or None
    source : dict
        Entry, dataset paths, angle units, notes on the frames left out and, if the file gives
        it, the pixel size ``raw_pixel_size_m`` (metres, ``[x, y]``) and where it was read.
    """

    projections: np.ndarray
    angles: np.ndarray
    flats: np.ndarray | None
    darks: np.ndarray | None
    source: dict[str, Any] = field(default_factory=dict)


def nxtomo_entries(tree: H5Tree) -> list[str]:
    """Names of the top-level NXtomo entries of an open HDF5 file.

    An entry is a group with ``NX_class`` ``NXentry`` whose ``definition`` (a dataset or an
    attribute) is ``NXtomo``. A file without such attributes gives the legacy entry names
    (``entry``, ``entry1``) that hold detector data.

    Parameters
    ----------
    tree : H5Tree

    Returns
    -------
    list of str
        Entry names in file order (empty if the file has no NXtomo data).
    """
    import h5py

    found = []
    for name in tree.keys():
        if tree.file.get(name, getlink=True).__class__ is not h5py.HardLink:
            continue  # an entry is a group of the file itself
        if tree.attr(name, "NX_class") != "NXentry":
            continue
        ds = tree.get(f"{name}/definition")
        definition = text(ds[()]) if isinstance(ds, h5py.Dataset) else tree.attr(name, "definition")
        if definition.strip() == "NXtomo":
            found.append(name)
    if found:
        return found
    return [e for e in _LEGACY_ENTRIES if tree.has(e) and any(tree.has(f"{e}/{p}") for p in _DATA)]


def to_unit(value: Any, units: str | None, target: str, *, default: str, where: str) -> np.ndarray:
    """``value`` given in ``units`` (``default`` when None or empty) converted to ``target``, float64.

    Parameters
    ----------
    value : array_like
    units : str or None
        A unit pint understands (``"degree"``, ``"rad"``, ``"m"``, ``"um"``, ``"micrometer"`` ...).
    target, default : str
    where : str
        The dataset, for the error message.

    Raises
    ------
    NanoctError
        For a unit pint does not know or one of another dimension (a length for an angle).
    """
    import pint

    registry = pint.get_application_registry()
    text = (units or "").strip() or default
    try:
        # compare root units: angles are dimensionless in pint, as counts are, but their root is the radian
        factor, root = registry.get_root_units(text)
        wanted = registry.get_root_units(target)
    except (pint.errors.PintError, AttributeError, TypeError, ValueError, AssertionError) as exc:
        raise NanoctError(f"{where} has units {text!r}, which pint does not know ({exc})") from None
    if root != wanted[1]:
        raise NanoctError(f"{where} has units {text!r} ({root}), which is not a unit of {target}")
    return np.asarray(value, dtype=np.float64) * float(factor / wanted[0])


def _pixel_size(tree: H5Tree, entry: str) -> tuple[list[float] | None, str | None]:
    for pattern in _PIXEL:
        names = [f"{entry}/{pattern.format(axis)}" for axis in ("x", "y")]
        if tree.has(names[0]):
            sizes = []
            for name in names:
                if not tree.has(name):
                    sizes.append(sizes[0])  # a square pixel when only x is given
                    continue
                value, units = tree.read(name)
                sizes.append(float(to_unit(value, units, "m", default="m", where=f"{tree.path}:{name}").ravel()[0]))
            if all(np.isfinite(s) and s > 0 for s in sizes):
                return sizes, names[0]
    return None, None


def split_by_key(
    data: np.ndarray, keys: np.ndarray, angles: np.ndarray, *, where: str, keys_name: str | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None, list[str]]:
    """Frames sorted by their NXtomo image key: projections with their angles, flats, darks.

    Parameters
    ----------
    data : ndarray of shape (F, R, L)
        Every frame.
    keys : ndarray of shape (F,), int
        0 projection, 1 flat, 2 dark, 3 invalid, -1 alignment (invalid and alignment frames
        are left out).
    angles : ndarray of shape (F,)
        One angle per frame (any unit).
    where, keys_name : str
        The file and the key dataset, for messages.

    Returns
    -------
    projections, angles, flats, darks, notes
        ``flats`` / ``darks`` are None where the file has none; ``notes`` name the frames left out.

    Raises
    ------
    NanoctError
        Counts that differ, unknown keys, no projection.
    """
    keys, angles = np.asarray(keys).astype(int).ravel(), np.asarray(angles).ravel()
    if keys.size != data.shape[0] or angles.size != data.shape[0]:
        raise NanoctError(
            f"{where}: {data.shape[0]} detector frames but {keys.size} image keys and {angles.size} angles; "
            "give one key and one angle per frame (is the file complete?)"
        )
    known = (KEY_PROJECTION, KEY_FLAT, KEY_DARK, KEY_INVALID, KEY_ALIGNMENT)
    unknown = sorted(set(np.unique(keys).tolist()) - set(known))
    if unknown:
        raise NanoctError(
            f"{where}:{keys_name} has image key(s) {unknown}; NXtomo knows 0 projection, 1 flat, 2 dark, "
            "3 invalid, -1 alignment"
        )
    proj = keys == KEY_PROJECTION
    if not proj.any():
        raise NanoctError(f"{where}: no projection frames (image key 0)")
    notes = [
        f"left out {n} {kind} frame(s) (image key {key})"
        for kind, key in (("invalid", KEY_INVALID), ("alignment", KEY_ALIGNMENT))
        if (n := int((keys == key).sum()))
    ]
    flats = data[keys == KEY_FLAT] if (keys == KEY_FLAT).any() else None
    darks = data[keys == KEY_DARK] if (keys == KEY_DARK).any() else None
    return data[proj], angles[proj], flats, darks, notes


def _entry(tree: H5Tree, entry: str | None) -> str:
    entries = nxtomo_entries(tree)
    if entry is None:
        if not entries:
            raise NanoctError(
                f"{tree.path}: no NXtomo entry (no group with NX_class=NXentry and definition=NXtomo, "
                f"nor {', '.join(e + '/' + _DATA[0] for e in _LEGACY_ENTRIES)})"
            )
        if len(entries) > 1:
            listed = ", ".join(entries)
            raise NanoctError(f"{tree.path} has {len(entries)} NXtomo entries ({listed}); choose one with --entry NAME")
        return entries[0]
    if entry not in entries:
        listed = ", ".join(entries) or "none"
        raise NanoctError(f"--entry {entry!r}: no such NXtomo entry in {tree.path} (present: {listed})")
    return entry


def read_nxtomo(
    tree: H5Tree, entry: str | None = None, window: Callable[..., tuple[slice, slice]] | None = None
) -> NXtomoFrames:
    """Read the frames, keys, angles and pixel size of one NXtomo entry of an open file.

    Parameters
    ----------
    tree : H5Tree
        The open file.
    entry : str, optional
        Entry name; needed when the file has several NXtomo entries.
    window : callable, optional
        ``window((R, L)) -> (row slice, column slice)``: the part of the detector to read
        (default all); only that part is read from disk.

    Raises
    ------
    NanoctError
        No or several entries (without ``entry``), an unknown entry, missing datasets, a
        frame count that differs between data, keys and angles, unknown image keys, angle
        units that are not angles; each message names the file and what to do.
    """
    path = tree.path
    entry = _entry(tree, entry)
    data_name = next((f"{entry}/{p}" for p in _DATA if tree.has(f"{entry}/{p}")), None)
    if data_name is None:
        raise NanoctError(f"{path}: entry {entry} has no detector data ({', '.join(_DATA)})")
    angles_name = next((f"{entry}/{p}" for p in _ANGLES if tree.has(f"{entry}/{p}")), None)
    if angles_name is None:
        raise NanoctError(f"{path}: entry {entry} has no rotation angles ({', '.join(_ANGLES)}); pass --angles FILE")
    keys_name = next((f"{entry}/{p}" for p in _KEYS if tree.has(f"{entry}/{p}")), None)
    shape = tree.dataset(data_name).shape
    if len(shape) != 3:
        raise NanoctError(f"{path}:{data_name} has shape {shape}; expected (frames, rows, columns)")
    region = (slice(None), *window(shape[1:])) if window is not None else ()
    data = tree.read(data_name, region)[0].astype(np.float32, copy=False)
    raw_angles, angle_units = tree.read(angles_name)
    keys = tree.read(keys_name)[0] if keys_name is not None else np.zeros(data.shape[0], int)
    proj, raw, flats, darks, notes = split_by_key(data, keys, raw_angles, where=str(path), keys_name=keys_name)
    angles = to_unit(raw, angle_units, "radian", default="degree", where=f"{path}:{angles_name}")
    pixel, pixel_name = _pixel_size(tree, entry)
    source = {
        "entry": entry,
        "data": data_name,
        "image_key": keys_name,
        "angle_units": angle_units or "degree (none given)",
        "detector_shape": list(shape[1:]),
        "notes": notes,
    }
    if pixel is not None:
        source.update(raw_pixel_size_m=pixel, pixel_size_from=pixel_name)
    return NXtomoFrames(proj, angles, flats=flats, darks=darks, source=source)
