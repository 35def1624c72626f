"""NXtomo files as ESRF's ``nxtomo`` library (and other NeXus writers) lay them out.

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

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import NanoctError

__all__ = ["NXtomoFrames", "nxtomo_entries", "read_h5_dataset", "read_nxtomo", "to_unit"]

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


def _text(value: Any) -> str:
    if isinstance(value, bytes):
        return value.decode(errors="replace")
    if isinstance(value, np.ndarray) and value.size == 1:
        return _text(value.item())
    return str(value)


def nxtomo_entries(f: Any) -> list[str]:
    """Names of the top-level NXtomo entries of an open HDF5 file.

    An entry is a group with ``NX_class`` ``NXentry`` whose ``definition`` (a dataset or an
    attribute) is ``NXtomo``. A file without such attributes gives the legacy entry names
    (``entry``, ``entry1``) that hold detector data.

    Parameters
    ----------
    f : h5py.File

    Returns
    -------
    list of str
        Entry names in file order (empty if the file has no NXtomo data).
    """
    import h5py

    found = []
    for name in f:
        group = f.get(name, getlink=False)
        if not isinstance(group, h5py.Group) or _text(group.attrs.get("NX_class", "")) != "NXentry":
            continue
        definition = group["definition"][()] if "definition" in group else group.attrs.get("definition", "")
        if _text(definition).strip() == "NXtomo":
            found.append(name)
    if found:
        return found
    return [e for e in _LEGACY_ENTRIES if e in f and any(f"{e}/{p}" in f for p in _DATA)]


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


def read_h5_dataset(f: Any, path: Path, name: str, region: tuple[slice, ...] = ()) -> tuple[np.ndarray, str | None]:
    """Dataset ``name`` of an open HDF5 file (only ``region`` of it, if given) and its ``units`` attribute.

    ``units`` is None without one. Only the selected region is read from disk.

    A virtual dataset (how ``nxtomo`` links the frames of the acquisition files) whose source
    files are missing would read as its fill value (zeros): it is refused, naming the files.

    Raises
    ------
    NanoctError
        For a dataset that cannot be read (truncated file, broken link) or missing sources.
    """
    try:
        ds = f[name]
        if ds.is_virtual:
            missing = sorted({s.file_name for s in ds.virtual_sources() if not _source_exists(s.file_name, path)})
            if missing:
                raise NanoctError(
                    f"{path}:{name} is a virtual dataset whose source file(s) {', '.join(missing)} are missing "
                    f"(looked next to {path.name}); copy them with the file, or convert it with the data included"
                )
        return np.asarray(ds[region] if region else ds[()]), (_text(ds.attrs["units"]) if "units" in ds.attrs else None)
    except (OSError, KeyError, RuntimeError) as exc:
        raise NanoctError(
            f"{path}: cannot read {name} ({exc}); the file may be truncated or still being written - copy it again"
        ) from None


def _source_exists(name: str, path: Path) -> bool:
    """Whether a virtual dataset's source file is where HDF5 looks for it (the file itself: ``.``)."""
    if name == ".":
        return True
    prefix = os.environ.get("HDF5_VDS_PREFIX")
    candidates = [Path(name), path.parent / name] + ([Path(prefix) / name] if prefix else [])
    return any(c.is_file() for c in candidates)


def _pixel_size(f: Any, path: Path, entry: str) -> tuple[list[float] | None, str | None]:
    for pattern in _PIXEL:
        names = [f"{entry}/{pattern.format(axis)}" for axis in ("x", "y")]
        if names[0] in f:
            sizes = []
            for name in names:
                if name not in f:
                    sizes.append(sizes[0])  # a square pixel when only x is given
                    continue
                value, units = read_h5_dataset(f, path, name)
                sizes.append(float(to_unit(value, units, "m", default="m", where=f"{path}:{name}").ravel()[0]))
            if all(np.isfinite(s) and s > 0 for s in sizes):
                return sizes, names[0]
    return None, None


def read_nxtomo(
    path: Path, f: Any, entry: str | None = None, window: Callable[..., tuple[slice, slice]] | None = None
) -> NXtomoFrames:
    """Read the frames, keys, angles and pixel size of one NXtomo entry of an open file.

    Parameters
    ----------
    path : Path
        The file (for messages).
    f : h5py.File
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
    entries = nxtomo_entries(f)
    if entry is None:
        if not entries:
            raise NanoctError(
                f"{path}: no NXtomo entry (no group with NX_class=NXentry and definition=NXtomo, "
                f"nor {', '.join(e + '/' + _DATA[0] for e in _LEGACY_ENTRIES)})"
            )
        if len(entries) > 1:
            listed = ", ".join(entries)
            raise NanoctError(f"{path} has {len(entries)} NXtomo entries ({listed}); choose one with --entry NAME")
        entry = entries[0]
    elif entry not in entries:
        listed = ", ".join(entries) or "none"
        raise NanoctError(f"--entry {entry!r}: no such NXtomo entry in {path} (present: {listed})")
    data_name = next((f"{entry}/{p}" for p in _DATA if f"{entry}/{p}" in f), None)
    if data_name is None:
        raise NanoctError(f"{path}: entry {entry} has no detector data ({', '.join(_DATA)})")
    angles_name = next((f"{entry}/{p}" for p in _ANGLES if f"{entry}/{p}" in f), None)
    if angles_name is None:
        raise NanoctError(f"{path}: entry {entry} has no rotation angles ({', '.join(_ANGLES)}); pass --angles FILE")
    keys_name = next((f"{entry}/{p}" for p in _KEYS if f"{entry}/{p}" in f), None)
    shape = f[data_name].shape
    if len(shape) != 3:
        raise NanoctError(f"{path}:{data_name} has shape {shape}; expected (frames, rows, columns)")
    region = (slice(None), *window(shape[1:])) if window is not None else ()
    data = read_h5_dataset(f, path, data_name, region)[0].astype(np.float32, copy=False)
    raw_angles, angle_units = read_h5_dataset(f, path, angles_name)
    keys = np.zeros(data.shape[0], int)
    if keys_name is not None:
        keys = read_h5_dataset(f, path, keys_name)[0].astype(int).ravel()
    raw_angles = raw_angles.ravel()
    if keys.size != data.shape[0] or raw_angles.size != data.shape[0]:
        raise NanoctError(
            f"{path}: {data.shape[0]} detector frames but {keys.size} image keys and {raw_angles.size} angles; "
            "NXtomo lists one key and one angle per frame (is the file complete?)"
        )
    known = (KEY_PROJECTION, KEY_FLAT, KEY_DARK, KEY_INVALID, KEY_ALIGNMENT)
    unknown = sorted(set(np.unique(keys).tolist()) - set(known))
    if unknown:
        raise NanoctError(
            f"{path}:{keys_name} has image key(s) {unknown}; NXtomo knows 0 projection, 1 flat, 2 dark, "
            "3 invalid, -1 alignment"
        )
    proj = keys == KEY_PROJECTION
    if not proj.any():
        raise NanoctError(f"{path}: entry {entry} has no projection frames (image key 0)")
    angles = to_unit(raw_angles[proj], angle_units, "radian", default="degree", where=f"{path}:{angles_name}")
    pixel, pixel_name = _pixel_size(f, path, entry)
    source = {
        "entry": entry,
        "data": data_name,
        "image_key": keys_name,
        "angle_units": angle_units or "degree (none given)",
        "detector_shape": list(shape[1:]),
        "notes": [
            f"left out {n} {kind} frame(s) (image key {key})"
            for kind, key in (("invalid", KEY_INVALID), ("alignment", KEY_ALIGNMENT))
            if (n := int((keys == key).sum()))
        ],
    }
    if pixel is not None:
        source.update(raw_pixel_size_m=pixel, pixel_size_from=pixel_name)
    return NXtomoFrames(
        data[proj],
        angles,
        flats=data[keys == KEY_FLAT] if (keys == KEY_FLAT).any() else None,
        darks=data[keys == KEY_DARK] if (keys == KEY_DARK).any() else None,
        source=source,
    )
