"""The on-disk data set: one Zarr v3 group per data set, one chunk per sample.

Layout (n samples, image N x N, sinogram K x L)::

    DIR/                         group; attrs["nanoct"] = geometry, simulation, seed, n, version
      phantoms        (n, N, N)  float32   ground truth x
      sinograms       (n, K, L)  float32   measured data y (perturbed object, exact motion)
      sinograms_eta   (n, K, L)  float32   model data y_eta = A x (unperturbed object)
      motion          (n, K, 3)  float32   true motion (t1 px, t2 px, theta deg) per view
      eta             (n, K)     float32   per-view model error max_l |y - y_eta|
      split           (n,)       int8      0 = train, 1 = val, 2 = test
      done            (n,)       bool      sample i is completely written
      reconstructions/<name>  (n, N, N) float32, attrs["params"]: parameters used
      reconstructions/<name>_shifts (n, K) float32: estimated motion of methods that have one
      uncertainty/<name>      (n, N, N) float32: pixel-wise std of sampling post-processors
      progress/<name>         (n,) bool: which samples of reconstructions/<name> are written

Every chunk is written atomically by Zarr's local store, and a sample's ``done`` flag (or
``progress`` flag) is written last, so a run killed at any moment leaves no sample that
claims to be complete but is not; re-running the same command fills in the rest. A kill
in the middle of a chunk write leaves Zarr's temporary ``<chunk>.<hex>.partial`` next to it;
the rerun removes those of the arrays it writes (:meth:`DataStore.remove_partial_writes`).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import uuid
from collections.abc import Iterable
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import zarr

from . import __version__
from .errors import StoreError
from .geometry import Geometry

__all__ = ["SPLITS", "DataStore", "Sample", "open_cached", "split_assignment"]

SPLITS = {"train": 0, "val": 1, "test": 2}
FORMAT = 1
_SAMPLE_ARRAYS = ("phantoms", "sinograms", "sinograms_eta", "motion", "eta", "done")
# Zarr's LocalStore writes a chunk to path.with_suffix(".<uuid4 hex>.partial"), then renames it
_PARTIAL = re.compile(r"\.[0-9a-f]{32}\.partial$")


@dataclass
class Sample:
    """One simulated sample (all arrays float32)."""

    phantom: np.ndarray
    sinogram: np.ndarray
    sinogram_eta: np.ndarray
    motion: np.ndarray
    eta: np.ndarray


def split_assignment(n: int, seed: int, fractions: tuple[float, float, float] = (0.95, 0.04, 0.01)) -> np.ndarray:
    """Assign n samples to train/val/test (0/1/2) in the given proportions.

    The paper's 95/4/1 split of 32,095 samples gives 30,490 / 1,284 / 321. Validation and test
    get at least one sample each when n >= 3; which samples go where is a permutation drawn
    from ``seed`` alone.
    """
    if n <= 0:
        raise ValueError(f"n={n} must be positive")
    f = np.asarray(fractions, dtype=float)
    if f.shape != (3,) or (f < 0).any() or not np.isclose(f.sum(), 1.0):
        raise ValueError(f"split fractions {fractions} must be three non-negative numbers summing to 1")
    n_test = int(round(f[2] * n))
    n_val = int(round(f[1] * n))
    if n >= 3:
        n_test, n_val = max(n_test, 1 if f[2] > 0 else 0), max(n_val, 1 if f[1] > 0 else 0)
    labels = np.zeros(n, dtype=np.int8)
    labels[n - n_test :] = 2
    labels[n - n_test - n_val : n - n_test] = 1
    perm = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(2**31 - 1,))).permutation(n)
    return labels[perm]


def _json_roundtrip(value: Any) -> Any:
    return json.loads(json.dumps(value))


class DataStore:
    """A nanoct data set on disk.

    Use :meth:`create` to make (or re-open, when the description matches) a data set and
    :meth:`open` to open an existing one.
    """

    def __init__(self, path: Path, group: zarr.Group) -> None:
        self.path = Path(path)
        self._group = group
        meta = group.attrs.get("nanoct")
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise StoreError(
                f"{path} is a Zarr group but not a nanoct data set (format {FORMAT}); generate one "
                "with 'nanoct generate'"
            )
        self.meta: dict[str, Any] = meta
        self.geometry = Geometry.from_dict(meta["geometry"])
        self.n: int = int(meta["n"])
        self.seed: int = int(meta["seed"])

    # ------------------------------------------------------------------ opening
    @classmethod
    def open(cls, path: str | os.PathLike[str], mode: str = "r") -> DataStore:
        """Open an existing data set (``mode`` "r" or "r+").

        Raises
        ------
        StoreError
            If ``path`` does not exist or is not a readable nanoct data set.
        """
        path = Path(path)
        if not (path / "zarr.json").is_file():
            raise StoreError(
                f"no nanoct data set at {path} (missing {path / 'zarr.json'}); create one with 'nanoct generate'"
            )
        try:
            group = zarr.open_group(str(path), mode=mode)
        except Exception as exc:  # damaged metadata
            raise StoreError(f"the data set at {path} is damaged ({exc}); delete it and generate it again") from exc
        store = cls(path, group)
        for name in ("phantoms", "sinograms", "sinograms_eta", "motion", "eta", "split", "done"):
            if name not in group:
                raise StoreError(
                    f"the data set at {path} is damaged: array '{name}' is missing; delete it and generate it again"
                )
        return store

    @classmethod
    def create(
        cls,
        path: str | os.PathLike[str],
        geometry: Geometry,
        n: int,
        seed: int,
        simulation: dict[str, Any],
        split_fractions: tuple[float, float, float] = (0.95, 0.04, 0.01),
    ) -> DataStore:
        """Create a data set at ``path``, or re-open it if it holds the same description.

        The group is built in a temporary sibling directory and renamed into place, so an
        interrupted creation leaves nothing behind. Re-opening is resuming: the temporary
        chunk files of a killed earlier run are removed (:meth:`remove_partial_writes`).

        Raises
        ------
        StoreError
            If ``path`` exists and is not the same data set (other geometry, size, seed or
            simulation parameters), or is not a nanoct data set at all.
        """
        path = Path(path)
        meta = _json_roundtrip(
            {
                "format": FORMAT,
                "version": __version__,
                "geometry": geometry.to_dict(),
                "n": int(n),
                "seed": int(seed),
                "simulation": simulation,
                "split_fractions": list(split_fractions),
            }
        )
        if path.exists():
            if not (path / "zarr.json").is_file() and any(path.iterdir()):
                raise StoreError(f"{path} exists and is not a nanoct data set; choose another --out or remove it")
            if (path / "zarr.json").is_file():
                existing = cls.open(path, mode="r+")
                mine = {k: v for k, v in meta.items() if k != "version"}
                theirs = {k: v for k, v in existing.meta.items() if k != "version"}
                if mine != theirs:
                    diff = sorted(k for k in mine if mine.get(k) != theirs.get(k))
                    raise StoreError(
                        f"{path} holds a different data set (differs in: {', '.join(diff)}); "
                        "use another --out, or repeat the original command to resume it"
                    )
                existing.remove_partial_writes(_SAMPLE_ARRAYS)
                return existing
        n_angles, n_det = geometry.sino_shape
        size = geometry.n
        tmp = path.parent / f".{path.name}.creating-{uuid.uuid4().hex[:8]}"
        try:
            group = zarr.open_group(str(tmp), mode="w")
            group.attrs["nanoct"] = meta
            specs = {
                "phantoms": ((n, size, size), "float32"),
                "sinograms": ((n, n_angles, n_det), "float32"),
                "sinograms_eta": ((n, n_angles, n_det), "float32"),
                "motion": ((n, n_angles, 3), "float32"),
                "eta": ((n, n_angles), "float32"),
                "done": ((n,), "bool"),
            }
            for name in _SAMPLE_ARRAYS:
                shape, dtype = specs[name]
                group.create_array(name, shape=shape, chunks=(1, *shape[1:]), dtype=dtype, fill_value=0)
            split = group.create_array("split", shape=(n,), chunks=(n,), dtype="int8", fill_value=0)
            split[:] = split_assignment(n, seed, split_fractions)
            if path.exists():
                path.rmdir()  # an empty directory the user created
            os.replace(tmp, path)
        finally:
            if tmp.exists():
                shutil.rmtree(tmp, ignore_errors=True)
        return cls.open(path, mode="r+")

    # ------------------------------------------------------------------ samples
    def _array(self, name: str) -> zarr.Array:
        return self._group[name]  # type: ignore[return-value]

    def _flags(self, key: str, idx: np.ndarray) -> np.ndarray:
        """Completion flags of the given samples only (reads just their chunks)."""
        if key not in self._group:
            return np.zeros(len(idx), dtype=bool)
        if len(idx) == 0:
            return np.zeros(0, dtype=bool)
        return np.asarray(self._group[key].get_coordinate_selection(idx), dtype=bool)

    @property
    def split(self) -> np.ndarray:
        """Split label per sample (0 train, 1 val, 2 test)."""
        return self._array("split")[:]

    @property
    def done(self) -> np.ndarray:
        """Boolean mask of completely written samples."""
        return np.asarray(self._array("done")[:], dtype=bool)

    def indices(self, split: str = "all") -> np.ndarray:
        """Sample indices of a split (``train``, ``val``, ``test`` or ``all``)."""
        if split == "all":
            return np.arange(self.n)
        if split not in SPLITS:
            raise ValueError(f"split {split!r} is unknown; use one of train, val, test, all")
        return np.flatnonzero(self.split == SPLITS[split])

    def remove_partial_writes(self, keys: Iterable[str]) -> list[Path]:
        """Delete the temporary chunk files that a killed write left under the arrays ``keys``.

        Call it only from the process that is about to (re)write these arrays, before it fans
        out: a write in progress elsewhere in the same arrays would lose its temporary.

        Parameters
        ----------
        keys : iterable of str
            Array paths in the group, e.g. ``"phantoms"`` or ``"reconstructions/fbp"``.

        Returns
        -------
        list of Path
            The files removed.
        """
        removed = []
        for key in keys:
            root = self.path / key
            if root.is_dir():
                for p in root.rglob("*.partial"):
                    if _PARTIAL.search(p.name) and p.is_file():
                        p.unlink(missing_ok=True)
                        removed.append(p)
        return removed

    def write_sample(self, index: int, sample: Sample) -> None:
        """Write sample ``index``; its ``done`` flag is set last."""
        self._array("phantoms")[index] = sample.phantom
        self._array("sinograms")[index] = sample.sinogram
        self._array("sinograms_eta")[index] = sample.sinogram_eta
        self._array("motion")[index] = sample.motion
        self._array("eta")[index] = sample.eta
        self._array("done")[index] = True

    def read_sample(self, index: int) -> Sample:
        """Read sample ``index``.

        Raises
        ------
        StoreError
            If the sample is not written yet or a chunk cannot be read.
        """
        if not 0 <= index < self.n:
            raise IndexError(f"sample index {index} is out of range 0..{self.n - 1}")
        if not self._array("done")[index]:
            raise StoreError(
                f"sample {index} of {self.path} is not generated yet; run 'nanoct generate' again to finish it"
            )
        try:
            return Sample(
                phantom=self._array("phantoms")[index],
                sinogram=self._array("sinograms")[index],
                sinogram_eta=self._array("sinograms_eta")[index],
                motion=self._array("motion")[index],
                eta=self._array("eta")[index],
            )
        except Exception as exc:
            raise StoreError(f"sample {index} of {self.path} cannot be read ({exc}); the store is damaged") from exc

    def read_phantoms(self, indices: Iterable[int]) -> np.ndarray:
        """Ground-truth phantoms of the given samples, shape (len(indices), N, N)."""
        idx = np.asarray(list(indices), dtype=int)
        if not self._flags("done", idx).all():
            raise StoreError(
                f"some requested samples of {self.path} are not generated yet; run 'nanoct generate' again"
            )
        return self._array("phantoms").get_orthogonal_selection((idx, slice(None), slice(None)))

    # ------------------------------------------------------------------ reconstructions
    def reconstruction_names(self) -> list[str]:
        """Names of the reconstruction image arrays present (``<name>_shifts`` excluded)."""
        if "reconstructions" not in self._group:
            return []
        group = self._group["reconstructions"]
        return sorted(k for k in group.array_keys() if group[k].ndim == 3)

    def prepare_reconstruction(
        self, name: str, params: dict[str, Any], shifts: bool = False, uncertainty: bool = False
    ) -> None:
        """Create ``reconstructions/<name>`` (and its progress flags) if missing.

        ``shifts`` adds ``reconstructions/<name>_shifts`` (n, K) for estimated motion,
        ``uncertainty`` adds ``uncertainty/<name>`` (n, N, N) for a pixel-wise std.

        Raises
        ------
        StoreError
            If it exists with other parameters (use another name or delete it).
        """
        params = _json_roundtrip(params)
        key = f"reconstructions/{name}"
        if key in self._group:
            old = self._group[key].attrs.get("params")
            if old != params:
                raise StoreError(
                    f"{key} in {self.path} was made with other parameters ({old}); "
                    f"delete it (nanoct reconstruct ... --overwrite) or choose other parameters"
                )
            self.remove_partial_writes(self._reconstruction_keys(name))  # resuming: clear a killed run's temporaries
            return
        size = self.geometry.n
        self._group.create_array(
            f"progress/{name}", shape=(self.n,), chunks=(1,), dtype="bool", fill_value=False, overwrite=True
        )
        if shifts:
            self._group.create_array(
                f"reconstructions/{name}_shifts",
                shape=(self.n, self.geometry.n_angles),
                chunks=(1, self.geometry.n_angles),
                dtype="float32",
                fill_value=0,
                overwrite=True,
            )
        if uncertainty:
            self._group.create_array(
                f"uncertainty/{name}",
                shape=(self.n, size, size),
                chunks=(1, size, size),
                dtype="float32",
                fill_value=0,
                overwrite=True,
            )
        arr = self._group.create_array(
            key, shape=(self.n, size, size), chunks=(1, size, size), dtype="float32", fill_value=0, overwrite=True
        )
        arr.attrs["params"] = params  # written last: marks the reconstruction as set up

    def delete_reconstruction(self, name: str) -> None:
        """Remove ``reconstructions/<name>`` with its shifts, uncertainty and progress flags."""
        for key in self._reconstruction_keys(name):
            if key in self._group:
                del self._group[key]

    @staticmethod
    def _reconstruction_keys(name: str) -> tuple[str, ...]:
        return (f"reconstructions/{name}", f"reconstructions/{name}_shifts", f"uncertainty/{name}", f"progress/{name}")

    def reconstruction_done(self, name: str, indices: Iterable[int] | None = None) -> np.ndarray:
        """Which samples (all, or only ``indices``, reading just their flags) have ``name`` written."""
        if indices is not None:
            return self._flags(f"progress/{name}", np.asarray(list(indices), dtype=int))
        key = f"progress/{name}"
        if key not in self._group:
            return np.zeros(self.n, dtype=bool)
        return np.asarray(self._group[key][:], dtype=bool)

    def write_reconstruction(
        self, name: str, index: int, image: np.ndarray, shifts: np.ndarray | None = None, std: np.ndarray | None = None
    ) -> None:
        """Write one reconstruction (with estimated shifts or std); the progress flag is set last."""
        self._group[f"reconstructions/{name}"][index] = image
        if shifts is not None:
            self._group[f"reconstructions/{name}_shifts"][index] = shifts
        if std is not None:
            self._group[f"uncertainty/{name}"][index] = std
        self._group[f"progress/{name}"][index] = True

    def read_reconstruction(self, name: str, indices: Iterable[int] | None = None) -> np.ndarray:
        """Read reconstructions ``name`` for the given samples (all by default).

        Raises
        ------
        StoreError
            If the reconstruction is absent or incomplete for the requested samples.
        """
        if f"reconstructions/{name}" not in self._group:
            raise StoreError(
                f"{self.path} has no reconstruction '{name}'; present: {self.reconstruction_names() or 'none'}"
            )
        idx = np.arange(self.n) if indices is None else np.asarray(list(indices), dtype=int)
        missing = idx[~self._flags(f"progress/{name}", idx)]
        if missing.size:
            raise StoreError(
                f"reconstruction '{name}' is missing {missing.size} requested sample(s) (e.g. "
                f"{missing[:5].tolist()}); run 'nanoct reconstruct' again"
            )
        if idx.size == 0:
            return np.zeros((0, *self.geometry.image_shape), np.float32)
        return self._group[f"reconstructions/{name}"].get_orthogonal_selection((idx, slice(None), slice(None)))

    def has_uncertainty(self, name: str) -> bool:
        """Whether reconstruction ``name`` comes with a pixel-wise std (``uncertainty/<name>``)."""
        return f"uncertainty/{name}" in self._group

    def read_uncertainty(self, name: str, indices: Iterable[int]) -> np.ndarray:
        """Pixel-wise std of reconstruction ``name`` for the given (completed) samples."""
        if not self.has_uncertainty(name):
            raise StoreError(f"reconstruction '{name}' in {self.path} has no uncertainty map")
        idx = np.asarray(list(indices), dtype=int)
        missing = idx[~self._flags(f"progress/{name}", idx)]
        if missing.size:
            raise StoreError(
                f"uncertainty of '{name}' is missing {missing.size} requested sample(s); run 'nanoct predict' again"
            )
        return self._group[f"uncertainty/{name}"].get_orthogonal_selection((idx, slice(None), slice(None)))

    def reconstruction_params(self, name: str) -> dict[str, Any]:
        """Parameters stored with reconstruction ``name``."""
        return dict(self._group[f"reconstructions/{name}"].attrs.get("params", {}))

    # ------------------------------------------------------------------ summary
    def info(self) -> dict[str, Any]:
        """Summary: sizes, splits, geometry, completeness and reconstructions present."""
        split = self.split
        done = self.done
        recons = {}
        for name in self.reconstruction_names():
            flags = self.reconstruction_done(name)
            recons[name] = {"done": int(flags.sum()), "params": self.reconstruction_params(name)}
        return {
            "path": str(self.path),
            "n": self.n,
            "done": int(done.sum()),
            "complete": bool(done.all()),
            "splits": {s: int((split == v).sum()) for s, v in SPLITS.items()},
            "seed": self.seed,
            "geometry": self.geometry.to_dict(),
            "image_shape": list(self.geometry.image_shape),
            "sinogram_shape": list(self.geometry.sino_shape),
            "simulation": self.meta.get("simulation", {}),
            "version": self.meta.get("version"),
            "reconstructions": recons,
        }


@lru_cache(maxsize=8)
def open_cached(path: str) -> DataStore:
    """One writable handle per store and process, for tasks that each write one sample."""
    return DataStore.open(path, mode="r+")
