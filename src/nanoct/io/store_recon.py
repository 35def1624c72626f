"""The reconstruction arrays of a data set: images, estimated shifts, uncertainty, progress flags.

For a reconstruction ``<name>`` of a store with n samples, image N x N and K views::

    reconstructions/<name>          (n, N, N) float32, attrs["params"]: parameters used
    reconstructions/<name>_shifts   (n, K)    float32: estimated motion (methods that have one)
        attrs["shared_shifts"] of reconstructions/<name>: (K,) the one motion of a stack (when shared)
    uncertainty/<name>              (n, N, N) float32: pixel-wise std (sampling post-processors)
    progress/<name>                 (n,)      bool: which samples are written (set last)

Float arrays are filled with NaN, so a sample whose chunk is lost is reported, never read as
an image (:mod:`nanoct.io.chunks`). :class:`~nanoct.io.store.DataStore` holds one
:class:`ReconstructionArrays` and forwards its reconstruction methods to it.
"""

from __future__ import annotations

import json
import re
import uuid
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import zarr

from ..core.errors import NanoctError, StoreError
from ..core.names import is_prediction
from .chunks import find_damaged, read_flags, read_samples, remove_partial_writes

__all__ = ["ReconstructionArrays", "check_name"]

_NAME = re.compile(r"[\w.+@%-]+")  # letters and digits (any script), _ . + @ % - (nanoct.names' grammar)


def check_name(name: str) -> str:
    """Return ``name`` if it can name a reconstruction, else raise :class:`NanoctError`.

    A name is one path component of the store that a shell passes as it is: letters, digits,
    ``_``, ``-``, ``+``, ``@``, ``%`` and ``.`` (no spaces, path separators or control characters), not
    empty, no leading dot (hidden and ``..``), and not ending in ``_shifts`` (the suffix of the
    estimated-shift arrays).
    """
    if not isinstance(name, str) or not _NAME.fullmatch(name) or name.startswith("."):
        raise NanoctError(
            f"--name {name!r} is not a valid reconstruction name: use letters, digits, '_', '-', '+', '@', '%' or '.' "
            "(no spaces or path separators, not empty, no leading dot)"
        )
    if name.endswith("_shifts"):
        raise NanoctError(f"--name {name!r} must not end in '_shifts' (reserved for estimated motion)")
    return name


def differing_keys(old: Any, new: Any, prefix: str = "", depth: int | None = 2) -> list[str]:
    """The keys (dotted, ``depth`` levels deep at most; None: to the leaves) in which two parameter records differ,
    e.g. ``tiling.overlap``; ``[prefix]`` (or ``["params"]``) where they are not both dicts, or are dicts that
    differ deeper."""
    if not (isinstance(old, dict) and isinstance(new, dict)) or (depth is not None and prefix.count(".") >= depth - 1):
        return [prefix or "params"] if old != new else []
    out: list[str] = []
    for key in sorted(old.keys() | new.keys(), key=str):
        out += differing_keys(old.get(key), new.get(key), f"{prefix}.{key}" if prefix else str(key), depth)
    return out


#: What a refusal of a reconstruction made with other parameters tells the user to do, unless its command says.
RECONSTRUCT_REMEDY = "delete it (nanoct reconstruct ... --overwrite) or choose other parameters"


def _dotted(record: dict[str, Any], key: str) -> Any:
    """The value at a dotted key (``calibration.store``) of a parameter record, None where there is none."""
    for part in key.split("."):
        record = record.get(part) if isinstance(record, dict) else None
    return record


def same_content(old: dict[str, Any], new: dict[str, Any], place: str, keys: tuple[str, ...]) -> bool:
    """Whether the file or folder at top-level key ``place`` holds the same content in both records: the hash
    recorded under the first of ``keys`` found in ``old`` equals ``new``'s under ``keys[0]``, or, for a record
    without one (made before it was kept), the place is the same (:func:`moved_params`' identities)."""
    recorded = next((v for v in (_dotted(old, k) for k in keys) if v is not None), None)
    return recorded == _dotted(new, keys[0]) if recorded is not None else old.get(place) == new.get(place)


def moved_params(
    old: dict[str, Any], new: dict[str, Any], identities: dict[str, tuple[str, ...]], ignored: tuple[str, ...] = ()
) -> bool:
    """Whether two parameter records of a result differ only in where its inputs lie.

    Parameters
    ----------
    old, new : dict
        The stored parameters and those of this run (as JSON reads them back).
    identities : dict
        Top-level keys naming a file or folder, each with the keys (dotted) of the SHA-256 of its content:
        the first is this run's, the others are where an older record kept it. The place may differ where the
        recorded hash equals this run's, or, for a record without one (made before it was kept), where the
        place is the same.
    ignored : tuple of str
        Dotted keys of other places, recorded and not compared (e.g. ``calibration.store``).

    Returns
    -------
    bool
        True where the records differ, and only so.
    """
    if old == new:
        return False
    dropped = {*identities, *(keys[0] for keys in identities.values())}

    def placeless(record: dict[str, Any]) -> dict[str, Any]:
        kept = {k: v for k, v in record.items() if k not in dropped}
        for key in ignored:
            outer, _, inner = key.partition(".")
            if isinstance(kept.get(outer), dict):
                kept[outer] = {k: v for k, v in kept[outer].items() if k != inner}
        return kept

    if placeless(old) != placeless(new):
        return False
    return all(same_content(old, new, place, keys) for place, keys in identities.items())


def _keys(name: str) -> tuple[str, ...]:
    return (f"reconstructions/{name}", f"reconstructions/{name}_shifts", f"uncertainty/{name}", f"progress/{name}")


class ReconstructionArrays:
    """The reconstruction arrays of one open store.

    Parameters
    ----------
    group : zarr.Group
        The store's root group.
    path : Path
        The store directory (for messages and partial-write clean-up).
    n : int
        Number of samples.
    image_shape, n_angles :
        Shape of an image and number of views, for new arrays and shape checks.
    """

    def __init__(self, group: zarr.Group, path: Path, n: int, image_shape: tuple[int, int], n_angles: int) -> None:
        self._group = group
        self.path = path
        self.n = n
        self.image_shape = image_shape
        self.n_angles = n_angles

    def names(self) -> list[str]:
        """Names of the reconstruction image arrays present (``<name>_shifts`` excluded)."""
        if "reconstructions" not in self._group:
            return []
        with warnings.catch_warnings():
            # another process writing the group's metadata leaves Zarr's zarr.<hex>.partial for a moment,
            # which Zarr's listing reports as an unknown object: not ours to show
            warnings.filterwarnings("ignore", message=r"Object at .*\.partial is not recognized")
            keys = list(self._group["reconstructions"].array_keys())  # type: ignore[union-attr]
        return sorted(k for k in keys if not k.endswith("_shifts"))  # names never end in _shifts (check_name)

    def _array(self, key: str) -> zarr.Array:
        """``group[key]``, refused when its shape disagrees with the store's n, N and K."""
        array = self._group[key]
        if key.startswith("progress/"):
            shape: tuple[int, ...] = (self.n,)
        else:
            shape = (self.n, self.n_angles) if key.endswith("_shifts") else (self.n, *self.image_shape)
        if tuple(array.shape) != shape:  # type: ignore[union-attr]
            raise StoreError(
                f"{key} in {self.path} has shape {tuple(array.shape)}, the data set says {shape}; its "  # type: ignore[union-attr]
                "attributes were edited or the arrays replaced: delete the reconstruction or generate the data "
                "set again"
            )
        return array  # type: ignore[return-value]

    def _new(self, key: str, shape: tuple[int, ...], dtype: str, fill: Any) -> zarr.Array:
        return self._group.create_array(
            key, shape=shape, chunks=(1, *shape[1:]), dtype=dtype, fill_value=fill, overwrite=True
        )

    def prepare(
        self,
        name: str,
        params: dict[str, Any],
        shifts: bool = False,
        uncertainty: bool = False,
        remedy: str = RECONSTRUCT_REMEDY,
    ) -> None:
        """Create the arrays of ``name`` if missing, else resume; see :meth:`DataStore.prepare_reconstruction`."""
        check_name(name)
        params = json.loads(json.dumps(params))
        key = f"reconstructions/{name}"
        if key in self._group:
            old = self._group[key].attrs.get("params")
            if old != params and not self.done(name).any():
                # a run refused or interrupted before its first sample holds no result (its motion, if
                # estimated, belongs to the old parameters): a rerun with other parameters replaces it
                self.delete(name)
                return self.prepare(name, params, shifts, uncertainty, remedy)
            if old != params:
                raise StoreError(
                    f"{key} in {self.path} was made with other parameters (differs in: "
                    f"{', '.join(differing_keys(old, params))}); {remedy}"
                )
            self.repair(name)
            return
        self._new(f"progress/{name}", (self.n,), "bool", False)
        if shifts:
            self._new(f"reconstructions/{name}_shifts", (self.n, self.n_angles), "float32", np.nan)
        if uncertainty:
            self._new(f"uncertainty/{name}", (self.n, *self.image_shape), "float32", np.nan)
        arr = self._new(key, (self.n, *self.image_shape), "float32", np.nan)
        # one metadata write; "params" marks the reconstruction as set up, "created" tells this array
        # from an earlier one of the same name (a prediction made from it records it)
        arr.attrs.update({"created": uuid.uuid4().hex, "params": params})

    def damaged(self, name: str, full: bool = True) -> np.ndarray:
        """Samples flagged written whose image, shifts or std chunk file is lost, or (``full``) unreadable.

        ``full`` reads every such chunk; without it only the chunk files' names are looked up.
        """
        return find_damaged(self._group, self.path, _keys(name)[:3], np.flatnonzero(self.done(name)), full)

    def repair(self, name: str) -> np.ndarray:
        """Clear the progress flags of samples of ``name`` whose chunk files are lost, so that a rerun rewrites them."""
        remove_partial_writes(self.path, _keys(name))  # resuming: clear a killed run's temporaries
        bad = self.damaged(name, full=False)
        self.invalidate(name, bad)
        return bad

    def invalidate(self, name: str, indices: Iterable[int]) -> None:
        """Mark samples of ``name`` as not written (the next run of its command redoes them)."""
        idx = np.asarray(list(indices), dtype=int)
        if idx.size:
            self._group[f"progress/{name}"].set_coordinate_selection(idx, False)  # type: ignore[union-attr]

    def delete(self, name: str) -> None:
        """Remove ``reconstructions/<name>`` with its shifts, uncertainty and progress flags."""
        check_name(name)
        for key in _keys(name):
            if key in self._group:
                del self._group[key]

    def done(self, name: str, indices: Iterable[int] | None = None) -> np.ndarray:
        """Which samples (all, or only ``indices``, reading just their flags) have ``name`` written."""
        idx = np.arange(self.n) if indices is None else np.asarray(list(indices), dtype=int)
        return read_flags(self._group, f"progress/{name}", idx)

    def write(
        self,
        name: str,
        index: int,
        image: np.ndarray,
        shifts: np.ndarray | None = None,
        std: np.ndarray | None = None,
        done: bool = True,
    ) -> None:
        """Write one reconstruction (with estimated shifts or std); the progress flag is set last (``done=False``:
        left to :meth:`mark_done`, for a caller that records something about the sample first)."""
        try:
            self._array(f"reconstructions/{name}")[index] = image
            if shifts is not None:
                self._array(f"reconstructions/{name}_shifts")[index] = shifts
            if std is not None:
                self._array(f"uncertainty/{name}")[index] = std
            if done:
                self._array(f"progress/{name}")[index] = True
        except KeyError as exc:
            raise StoreError(
                f"reconstructions/{name} in {self.path} was deleted while this run was writing it (by another "
                "run with --overwrite?); run the command again when that run has finished"
            ) from exc

    def mark_done(self, name: str, index: int) -> None:
        """Set the progress flag of one sample of ``name`` written with ``done=False``."""
        self._array(f"progress/{name}")[index] = True

    def _read(self, key: str, name: str, indices: Iterable[int] | None, repair: str) -> np.ndarray:
        if f"reconstructions/{name}" not in self._group:
            raise StoreError(f"{self.path} has no reconstruction '{name}'; present: {self.names() or 'none'}")
        if key not in self._group:
            raise StoreError(f"reconstruction '{name}' in {self.path} has no {key.split('/')[0]} array")
        idx = np.arange(self.n) if indices is None else np.asarray(list(indices), dtype=int)
        missing = idx[~self.done(name, idx)]
        if missing.size:
            raise StoreError(
                f"reconstruction '{name}' is missing {missing.size} requested sample(s) (e.g. "
                f"{missing[:5].tolist()}); run '{repair}' again"
            )
        array = self._array(key)
        return read_samples(array, idx, what=f"{key} of {self.path}", repair=repair, folder=self.path / key)

    def _repair_command(self, name: str) -> str:
        return "nanoct predict" if is_prediction(name) else "nanoct reconstruct"

    def read(self, name: str, indices: Iterable[int] | None = None) -> np.ndarray:
        """Images of ``name`` for the given samples (all by default); see :meth:`DataStore.read_reconstruction`."""
        return self._read(f"reconstructions/{name}", name, indices, self._repair_command(name))

    def read_shifts(self, name: str, indices: Iterable[int] | None = None) -> np.ndarray:
        """Estimated per-view shifts (n_samples, K) of ``name`` for the given samples (all by default)."""
        return self._read(f"reconstructions/{name}_shifts", name, indices, self._repair_command(name))

    def has_uncertainty(self, name: str) -> bool:
        """Whether reconstruction ``name`` comes with a pixel-wise std (``uncertainty/<name>``)."""
        return f"uncertainty/{name}" in self._group

    def read_uncertainty(self, name: str, indices: Iterable[int]) -> np.ndarray:
        """Pixel-wise std of reconstruction ``name`` for the given (completed) samples."""
        return self._read(f"uncertainty/{name}", name, indices, self._repair_command(name))

    def fingerprint(self, name: str) -> dict[str, Any]:
        """What identifies the array ``name``: its parameters and the id made when it was created.

        A reconstruction deleted and made again (``--overwrite``) gets a new id even with the
        same parameters, so results derived from it can tell that their input changed.
        """
        attrs = self._group[f"reconstructions/{name}"].attrs
        return {"params": attrs.get("params"), "created": attrs.get("created")}

    def shared_shifts(self, name: str) -> np.ndarray | None:
        """The one motion (K,) estimated for all slices of ``name`` (None: per-sample motion or not estimated yet)."""
        values = self._group[f"reconstructions/{name}"].attrs.get("shared_shifts")
        return None if values is None else np.asarray(values, dtype=np.float32)

    def set_shared_shifts(self, name: str, shifts: np.ndarray) -> None:
        """Record the motion shared by all slices of ``name`` (an attribute; each slice's shifts row gets it too)."""
        values = np.asarray(shifts, dtype=np.float32)
        if values.shape != (self.n_angles,) or not np.isfinite(values).all():
            raise StoreError(f"shared shifts of '{name}' must be {self.n_angles} finite values")
        self._group[f"reconstructions/{name}"].attrs["shared_shifts"] = [float(v) for v in values]

    def motion_info(self, name: str) -> dict[str, Any] | None:
        """What was recorded with the motion of ``name`` (axis offset, ...; None: nothing yet)."""
        info = self._group[f"reconstructions/{name}"].attrs.get("motion_info")
        return None if info is None else dict(info)

    def set_motion_info(self, name: str, info: dict[str, Any]) -> None:
        """Record JSON-able facts about the motion of ``name`` (one attribute)."""
        self._group[f"reconstructions/{name}"].attrs["motion_info"] = json.loads(json.dumps(info))

    def note(self, name: str, key: str) -> Any:
        """A note recorded with reconstruction ``name`` (:meth:`set_note`; None if absent)."""
        return self._group[f"reconstructions/{name}"].attrs.get(f"note_{key}")

    def set_note(self, name: str, key: str, value: Any) -> None:
        """Record a JSON value under ``key`` with reconstruction ``name`` (e.g. predict's out-of-distribution flags)."""
        self._group[f"reconstructions/{name}"].attrs[f"note_{key}"] = json.loads(json.dumps(value))

    def params(self, name: str) -> dict[str, Any]:
        """Parameters stored with reconstruction ``name``."""
        return dict(self._group[f"reconstructions/{name}"].attrs.get("params", {}))

    def set_params(self, name: str, params: dict[str, Any]) -> None:
        """Replace the parameters stored with reconstruction ``name`` (its samples and creation id are kept):
        for parameters that record where its inputs lie, after they moved."""
        self._group[f"reconstructions/{name}"].attrs["params"] = json.loads(json.dumps(params))

    def relocate(
        self, name: str, params: dict[str, Any], identities: dict[str, tuple[str, ...]], ignored: tuple[str, ...] = ()
    ) -> bool:
        """Record ``params`` with the kept reconstruction ``name`` where they differ from its parameters only in
        where its inputs lie (:func:`moved_params`), so that it resumes; whether it did."""
        if f"reconstructions/{name}" not in self._group:
            return False
        new = json.loads(json.dumps(params))
        if not moved_params(self.params(name), new, identities, ignored):
            return False
        self.set_params(name, new)
        return True
