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
      reconstructions/<name>, uncertainty/<name>, progress/<name>: see :mod:`nanoct.io.store_recon`

A measured scan imported with ``nanoct import`` (:func:`create_scan`) has ``attrs["nanoct"]["scan"]``
(where it came from, how it was corrected) instead of ``simulation``, one sample per detector
row (slice), all in the test split, and only ``sinograms``, ``split`` and ``done``: there is no
ground truth, true motion or eta.

Float arrays are created with a NaN fill value (store format 2), so a chunk file that is lost
reads as NaN and is reported instead of passing as zeros; a chunk that cannot be decoded is
reported too (:mod:`nanoct.io.chunks`). Re-running the command that wrote a damaged sample
rewrites it, and ``nanoct info DIR --check`` lists damaged samples. On open, the attributes
(n, geometry) are checked against the arrays' shapes.

Every chunk is written atomically by Zarr's local store, and a sample's ``done`` flag (or
``progress`` flag) is written last, so a run killed at any moment leaves no sample that
claims to be complete but is not; re-running the same command fills in the rest. A kill
in the middle of a chunk write leaves Zarr's temporary ``<chunk>.<hex>.partial`` next to it;
the rerun removes those of the arrays it writes (:func:`nanoct.io.chunks.remove_partial_writes`).
"""

from __future__ import annotations

import json
import os
import shutil
import uuid
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zarr

from ..core.errors import StoreError
from ..core.geometry import Geometry
from ..core.version import __version__
from .chunks import find_damaged, read_flags, read_samples, remove_partial_writes
from .fileio import cached_by_file
from .lock import pid_alive
from .store_recon import RECONSTRUCT_REMEDY, ReconstructionArrays

__all__ = [
    "SPLITS",
    "DataStore",
    "Sample",
    "comparable_description",
    "create_scan",
    "data_set_description",
    "ood_brief",
    "open_cached",
    "split_assignment",
]

SPLITS = {"train": 0, "val": 1, "test": 2}
FORMAT = 2  # 1: fill value 0 (a lost chunk read as zeros); 2: NaN fill for float arrays
_DATA_ARRAYS = ("phantoms", "sinograms", "sinograms_eta", "motion", "eta")
_SCAN_ARRAYS = ("sinograms",)  # an imported scan: measured data only
_REGENERATE = "delete it and generate it again"


@dataclass
class Sample:
    """One sample (all arrays float32); an imported scan has only the sinogram (the rest None)."""

    phantom: np.ndarray | None
    sinogram: np.ndarray
    sinogram_eta: np.ndarray | None
    motion: np.ndarray | None
    eta: np.ndarray | None


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


def _data_arrays(meta: dict[str, Any]) -> tuple[str, ...]:
    return _SCAN_ARRAYS if "scan" in meta else _DATA_ARRAYS


def _shapes(meta: dict[str, Any], geometry: Geometry) -> dict[str, tuple[int, ...]]:
    n, size, (k, det) = int(meta["n"]), geometry.n, geometry.sino_shape
    shapes = {
        "phantoms": (n, size, size),
        "sinograms": (n, k, det),
        "sinograms_eta": (n, k, det),
        "motion": (n, k, 3),
        "eta": (n, k),
    }
    return {name: shapes[name] for name in _data_arrays(meta)} | {"done": (n,), "split": (n,)}


def _build_group(path: Path, meta: dict[str, Any], geometry: Geometry, split: np.ndarray) -> None:
    """Create the group's arrays in a temporary sibling and rename it to ``path`` (atomic creation)."""
    _remove_stale_creations(path)
    tmp = path.parent / f".{path.name}.creating-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    n = int(meta["n"])
    try:
        group = zarr.open_group(str(tmp), mode="w")
        group.attrs["nanoct"] = meta
        for name, shape in _shapes(meta, geometry).items():
            dtype, fill = {"done": ("bool", False), "split": ("int8", -1)}.get(name, ("float32", np.nan))
            chunks = (n,) if name == "split" else (1, *shape[1:])
            group.create_array(name, shape=shape, chunks=chunks, dtype=dtype, fill_value=fill)
        group["split"][:] = split  # type: ignore[index]
        if path.exists():
            path.rmdir()  # an empty directory the user created
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def comparable_description(meta: dict[str, Any]) -> dict[str, Any]:
    """What makes a simulated data set the same one again: its description without the package version and
    the path of the scan a ``generate --like`` set was matched to (the scan's measurements stay compared)."""
    out = {k: v for k, v in meta.items() if k != "version"}
    like = (out.get("simulation") or {}).get("like")
    if isinstance(like, dict):
        out["simulation"] = {**out["simulation"], "like": {k: v for k, v in like.items() if k != "store"}}
    return out


def data_set_description(
    geometry: Geometry, n: int, seed: int, simulation: dict[str, Any], split_fractions: tuple[float, float, float]
) -> dict[str, Any]:
    """The description :meth:`DataStore.create` records for a simulated data set, as JSON reads it back
    (compare two with :func:`comparable_description`).

    Parameters
    ----------
    geometry : Geometry
        The data set's geometry.
    n, seed : int
        Number of samples and data-set seed.
    simulation : dict
        The simulation record.
    split_fractions : tuple of float
        Train, validation and test fractions.

    Returns
    -------
    dict
        ``format``, ``version``, ``geometry``, ``n``, ``seed``, ``simulation``, ``split_fractions``.
    """
    return _json_roundtrip(
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


def _check_target(path: Path) -> bool:
    """Whether ``path`` already holds a data set; StoreError if it is a file or another non-empty folder."""
    if path.exists() and not path.is_dir():
        raise StoreError(f"--out {path} is a file, not a directory; choose another --out")
    if path.exists() and not (path / "zarr.json").is_file() and any(path.iterdir()):
        raise StoreError(f"{path} exists and is not a nanoct data set; choose another --out or remove it")
    return (path / "zarr.json").is_file()


def _parse_meta(path: Path, meta: Any) -> tuple[Geometry, int, int]:
    """Geometry, n and seed of a store's attributes, or a StoreError saying what is wrong."""
    if not isinstance(meta, dict) or meta.get("format") not in (1, FORMAT):
        raise StoreError(
            f"{path} is a Zarr group but not a nanoct data set (format {FORMAT}); generate one with 'nanoct generate'"
        )
    if meta["format"] != FORMAT:
        raise StoreError(
            f"{path} was written by an older nanoct (store format {meta['format']}), in which a lost chunk reads "
            f"as zeros and cannot be detected; generate it again into a new directory (format {FORMAT})"
        )
    try:
        geometry = Geometry.from_dict(meta["geometry"])
        n, seed = int(meta["n"]), int(meta["seed"])
    except (KeyError, TypeError, ValueError) as exc:
        raise StoreError(f"the attributes of the data set at {path} are damaged ({exc}); {_REGENERATE}") from exc
    return geometry, n, seed


def _remove_stale_creations(path: Path) -> None:
    """Remove ``.NAME.creating-<pid>-<hex>`` directories of killed creations (their process is gone)."""
    for tmp in path.parent.glob(f".{path.name}.creating-*"):
        pid = tmp.name.rsplit(".creating-", 1)[1].split("-")[0]
        alive = pid.isdigit() and int(pid) != os.getpid() and pid_alive(int(pid))
        if tmp.is_dir() and not alive:
            shutil.rmtree(tmp, ignore_errors=True)


class DataStore:
    """A nanoct data set on disk.

    Use :meth:`create` to make (or re-open, when the description matches) a data set and
    :meth:`open` to open an existing one. The reconstruction arrays live in
    :attr:`recons` (:class:`~nanoct.io.store_recon.ReconstructionArrays`); the
    ``*reconstruction*`` methods here forward to it.
    """

    def __init__(self, path: Path, group: zarr.Group) -> None:
        self.path = Path(path)
        self._group = group
        self.meta: dict[str, Any] = group.attrs.get("nanoct")  # type: ignore[assignment]
        self.geometry, self.n, self.seed = _parse_meta(self.path, self.meta)
        self.recons = ReconstructionArrays(group, self.path, self.n, self.geometry.image_shape, self.geometry.n_angles)

    # ------------------------------------------------------------------ opening
    @classmethod
    def open(cls, path: str | os.PathLike[str], mode: str = "r") -> DataStore:
        """Open an existing data set (``mode`` "r" or "r+").

        Raises
        ------
        StoreError
            If ``path`` does not exist or is not a readable nanoct data set, or if its
            attributes (n, geometry) disagree with the shapes of its arrays.
        """
        path = Path(path)
        if not (path / "zarr.json").is_file():
            raise StoreError(
                f"no nanoct data set at {path} (missing {path / 'zarr.json'}); create one with 'nanoct generate'"
            )
        try:
            group = zarr.open_group(str(path), mode=mode)
        except Exception as exc:  # damaged metadata
            raise StoreError(f"the data set at {path} is damaged ({exc}); {_REGENERATE}") from exc
        store = cls(path, group)
        _check_metadata(store)
        _check_arrays(store)
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

        The group is built in a temporary sibling ``.NAME.creating-<pid>-<hex>`` and renamed
        into place, so an interrupted creation leaves no half-made data set; the next creation
        removes such siblings whose process is gone. Re-opening is resuming: the temporary chunk
        files of a killed earlier run are removed and damaged samples are marked for rewriting
        (:meth:`repair_samples`).

        Raises
        ------
        StoreError
            If ``path`` exists and is not the same data set (other geometry, size, seed or
            simulation parameters), or is not a nanoct data set at all.
        """
        path = Path(path)
        meta = data_set_description(geometry, n, seed, simulation, split_fractions)
        if _check_target(path):
            existing = cls.open(path, mode="r+")
            mine, theirs = comparable_description(meta), comparable_description(existing.meta)
            if mine != theirs:
                diff = sorted(k for k in mine.keys() | theirs.keys() if mine.get(k) != theirs.get(k))
                raise StoreError(
                    f"{path} holds a different data set (differs in: {', '.join(diff)}); "
                    "use another --out, or repeat the original command to resume it"
                )
            existing.repair_samples()
            return existing
        _build_group(path, meta, geometry, split_assignment(n, seed, split_fractions))
        return cls.open(path, mode="r+")

    # ------------------------------------------------------------------ samples
    def _array(self, name: str) -> zarr.Array:
        return self._group[name]  # type: ignore[return-value]

    @property
    def split(self) -> np.ndarray:
        """Split label per sample (0 train, 1 val, 2 test)."""
        return self._array("split")[:]

    @property
    def sample_nbytes(self) -> int:
        """Uncompressed bytes of one sample's data arrays (an upper bound of what writing one takes)."""
        arrays = [self._array(name) for name in _data_arrays(self.meta)]
        return sum(a.dtype.itemsize * int(np.prod(a.shape[1:])) for a in arrays)

    @property
    def done(self) -> np.ndarray:
        """Boolean mask of completely written samples."""
        return read_flags(self._group, "done", np.arange(self.n))

    def indices(self, split: str = "all") -> np.ndarray:
        """Sample indices of a split (``train``, ``val``, ``test`` or ``all``)."""
        if split == "all":
            return np.arange(self.n)
        if split not in SPLITS:
            raise ValueError(f"split {split!r} is unknown; use one of train, val, test, all")
        return np.flatnonzero(self.split == SPLITS[split])

    def remove_partial_writes(self, keys: Iterable[str]) -> list[Path]:
        """Delete temporary chunk files of killed writes under ``keys``; see :mod:`nanoct.io.chunks`."""
        return remove_partial_writes(self.path, keys)

    def damaged_samples(self, full: bool = True) -> np.ndarray:
        """Samples flagged done with a missing chunk file in any data array, or (``full``) one that cannot be read.

        ``full`` reads every such chunk; without it only the chunk files' names are looked up.
        """
        return find_damaged(self._group, self.path, _data_arrays(self.meta), np.flatnonzero(self.done), full)

    def complete_scan(self, sinograms: np.ndarray) -> np.ndarray:
        """Write the slices of an imported scan that an interrupted import left unwritten or that are damaged.

        Parameters
        ----------
        sinograms : ndarray of shape (S, K, L)
            The import's sinograms, as :func:`create_scan` was given them.

        Returns
        -------
        ndarray of int
            The slices written (empty when the data set was complete and intact).

        Raises
        ------
        StoreError
            If it is not an imported scan of that shape, or a slice written before differs from this import's
            (another file, or the file changed): nothing is written.
        """
        if not self.is_scan or np.shape(sinograms) != self._array("sinograms").shape:
            raise StoreError(f"{self.path} is not the imported scan of these sinograms; import into a new --out")
        self.remove_partial_writes(("sinograms", "done"))
        bad = np.union1d(np.flatnonzero(~self.done), self.damaged_samples(full=True)).astype(int)
        array = _check_kept_slices(self, sinograms, np.setdiff1d(np.arange(self.n), bad))
        for index in bad.tolist():  # one chunk per slice: a write replaces an unreadable chunk file whole
            array[index] = np.asarray(sinograms[index], dtype=np.float32)
        if bad.size:
            self._array("done").set_coordinate_selection(bad, True)
        return bad

    def repair_samples(self) -> np.ndarray:
        """Clear temporaries of killed writes and the ``done`` flags of samples whose chunk files are lost."""
        self.remove_partial_writes((*_data_arrays(self.meta), "done"))
        bad = self.damaged_samples(full=False)
        if bad.size:
            self._array("done").set_coordinate_selection(bad, False)
        return bad

    def write_sample(self, index: int, sample: Sample) -> None:
        """Write sample ``index``; its ``done`` flag is set last."""
        for name, value in zip(_DATA_ARRAYS, self._fields(sample)):
            self._array(name)[index] = value
        self._array("done")[index] = True

    @staticmethod
    def _fields(sample: Sample) -> tuple[np.ndarray, ...]:
        return sample.phantom, sample.sinogram, sample.sinogram_eta, sample.motion, sample.eta

    def _read_done(self, name: str, idx: np.ndarray) -> np.ndarray:
        array, what = self._array(name), f"'{name}' of {self.path}"
        return read_samples(array, idx, what=what, repair=self.writer, folder=self.path / name)

    @property
    def writer(self) -> str:
        """The command that writes (and rewrites) the data set's samples: ``nanoct import`` or ``nanoct generate``."""
        return "nanoct import" if self.is_scan else "nanoct generate"

    def read_sample(self, index: int) -> Sample:
        """Read sample ``index``.

        Raises
        ------
        StoreError
            If the sample is not written yet, or a chunk is missing or cannot be read.
        """
        if not 0 <= index < self.n:
            raise IndexError(f"sample index {index} is out of range 0..{self.n - 1}")
        idx = np.array([index])
        if not read_flags(self._group, "done", idx)[0]:
            raise StoreError(
                f"sample {index} of {self.path} is not written yet; run '{self.writer}' again with the same "
                "arguments to finish it"
            )
        names = _data_arrays(self.meta)
        return Sample(*(self._read_done(name, idx)[0] if name in names else None for name in _DATA_ARRAYS))

    @property
    def is_scan(self) -> bool:
        """Whether the data set is an imported measured scan (no ground truth, motion or eta)."""
        return "scan" in self.meta

    def read_phantoms(self, indices: Iterable[int]) -> np.ndarray:
        """Ground-truth phantoms of the given samples, shape (len(indices), N, N).

        Raises
        ------
        StoreError
            For an imported scan (it has no ground truth) or samples not generated yet.
        """
        if self.is_scan:
            raise StoreError(
                f"{self.path} is an imported scan without ground truth; PSNR/SSIM need a simulated data set "
                "('nanoct generate') — look at the images with 'nanoct export' instead"
            )
        return self.read_array("phantoms", indices)

    def read_array(self, name: str, indices: Iterable[int]) -> np.ndarray:
        """One data array (``sinograms``, ``eta``, ...) of the given samples, in one checked read.

        Raises
        ------
        StoreError
            If the data set has no such array (an imported scan has only ``sinograms``), or a
            requested sample is not generated yet or damaged.
        """
        if name not in _data_arrays(self.meta):
            raise StoreError(f"{self.path} has no '{name}' array; it has {', '.join(_data_arrays(self.meta))}")
        idx = np.asarray(list(indices), dtype=int)
        if not read_flags(self._group, "done", idx).all():
            raise StoreError(
                f"some requested samples of {self.path} are not written yet; run '{self.writer}' again with the "
                "same arguments to finish it"
            )
        return self._read_done(name, idx)

    # ------------------------------------------------------------------ reconstructions (see store_recon)
    def reconstruction_names(self) -> list[str]:
        """Names of the reconstruction image arrays present (``<name>_shifts`` excluded)."""
        return self.recons.names()

    def prepare_reconstruction(
        self,
        name: str,
        params: dict[str, Any],
        shifts: bool = False,
        uncertainty: bool = False,
        remedy: str = RECONSTRUCT_REMEDY,
    ) -> None:
        """Create ``reconstructions/<name>`` (and its progress flags) if missing.

        ``shifts`` adds ``reconstructions/<name>_shifts`` (n, K) for estimated motion,
        ``uncertainty`` adds ``uncertainty/<name>`` (n, N, N) for a pixel-wise std. When it
        exists with the same parameters, this is resuming: temporaries of a killed run are
        removed and samples whose chunks are missing or damaged are marked for rewriting.
        ``remedy`` is what a refusal tells the user to do (default: ``nanoct reconstruct``'s).

        Raises
        ------
        StoreError
            If it exists with other parameters (use another name or delete it).
        NanoctError
            If ``name`` is not a valid name (:func:`nanoct.io.store_recon.check_name`).
        """
        self.recons.prepare(name, params, shifts=shifts, uncertainty=uncertainty, remedy=remedy)

    def delete_reconstruction(self, name: str) -> None:
        """Remove ``reconstructions/<name>`` with its shifts, uncertainty and progress flags."""
        self.recons.delete(name)

    def reconstruction_done(self, name: str, indices: Iterable[int] | None = None) -> np.ndarray:
        """Which samples (all, or only ``indices``, reading just their flags) have ``name`` written."""
        return self.recons.done(name, indices)

    def invalidate_reconstruction(self, name: str, indices: Iterable[int]) -> None:
        """Mark samples of ``name`` as not written, so that the next run of its command redoes them."""
        self.recons.invalidate(name, indices)

    def write_reconstruction(
        self, name: str, index: int, image: np.ndarray, shifts: np.ndarray | None = None, std: np.ndarray | None = None
    ) -> None:
        """Write one reconstruction (with estimated shifts or std); the progress flag is set last."""
        self.recons.write(name, index, image, shifts=shifts, std=std)

    def read_reconstruction(self, name: str, indices: Iterable[int] | None = None) -> np.ndarray:
        """Read reconstructions ``name`` for the given samples (all by default).

        Raises
        ------
        StoreError
            If the reconstruction is absent, incomplete or damaged for the requested samples.
        """
        return self.recons.read(name, indices)

    def read_shifts(self, name: str, indices: Iterable[int] | None = None) -> np.ndarray:
        """Estimated per-view shifts (len(indices), K) of reconstruction ``name`` (e.g. ``dremel``)."""
        return self.recons.read_shifts(name, indices)

    def has_uncertainty(self, name: str) -> bool:
        """Whether reconstruction ``name`` comes with a pixel-wise std (``uncertainty/<name>``)."""
        return self.recons.has_uncertainty(name)

    def read_uncertainty(self, name: str, indices: Iterable[int]) -> np.ndarray:
        """Pixel-wise std of reconstruction ``name`` for the given (completed) samples."""
        return self.recons.read_uncertainty(name, indices)

    def reconstruction_params(self, name: str) -> dict[str, Any]:
        """Parameters stored with reconstruction ``name``."""
        return self.recons.params(name)

    def reconstruction_note(self, name: str, key: str) -> Any:
        """A note recorded with reconstruction ``name`` (None if absent)."""
        return self.recons.note(name, key)

    def set_reconstruction_note(self, name: str, key: str, value: Any) -> None:
        """Record a JSON value under ``key`` with reconstruction ``name``."""
        self.recons.set_note(name, key, value)

    # ------------------------------------------------------------------ summary
    def verify(self) -> dict[str, list[int]]:
        """Read every written sample and reconstruction; ``{array: damaged indices}`` for those with damage.

        The key ``"samples"`` holds damaged data samples, ``"reconstructions/<name>"`` damaged
        samples of a reconstruction (image, shifts or std).
        """
        found = {"samples": self.damaged_samples().tolist()}
        found.update({f"reconstructions/{k}": self.recons.damaged(k).tolist() for k in self.reconstruction_names()})
        return {k: v for k, v in found.items() if v}

    def info(self) -> dict[str, Any]:
        """Summary: sizes, splits, geometry, completeness and reconstructions present."""
        split = self.split
        done = self.done
        recons = {}
        for name in self.reconstruction_names():
            flags = self.reconstruction_done(name)
            recons[name] = {"done": int(flags.sum()), "params": self.reconstruction_params(name)}
            recons[name] |= ood_brief(self.reconstruction_note(name, "ood"))
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
            "scan": self.meta.get("scan"),
            "version": self.meta.get("version"),
            "reconstructions": recons,
        }


def ood_brief(note: dict[str, Any] | None) -> dict[str, Any]:
    """What :meth:`DataStore.info` shows of a prediction's out-of-distribution note.

    Parameters
    ----------
    note : dict or None
        The note ``ood`` of a prediction (:func:`nanoct.learn.predict.ood_check`), None where it has none.

    Returns
    -------
    dict
        ``{"ood": {"checks", "checked", "flagged", "unchecked"}}``: the checks made (``std``, ``scan``,
        ``footprint``), the number of images checked, those flagged and those the footprint check left out;
        ``{}`` without a note.
    """
    if not note:
        return {}
    footprint = note.get("footprint") or {}
    checks = [c for c in ("std", "scan") if c in note] + (["footprint"] if footprint else [])
    unchecked = sorted(int(k) for k in footprint.get("unchecked", {}))
    brief = {"checks": checks, "checked": len(note.get("p_values", {})), "flagged": list(note.get("flagged", []))}
    return {"ood": brief | {"unchecked": unchecked}}


#: Groups whose members are one result each (a reconstruction, its std or its progress flags).
_RESULT_GROUPS = ("reconstructions", "uncertainty", "progress")


def _check_metadata(store: DataStore) -> None:
    """Raise StoreError naming the first metadata file (``zarr.json``) of the store's arrays and groups, two
    levels deep, that cannot be read as JSON (emptied, truncated, overwritten), with what to do about it.

    zarr would otherwise fail only when the array is used, with the bare decoder message.
    """
    remedy = "delete it and import the scan again ('nanoct import')" if store.is_scan else _REGENERATE
    damaged = f"the data set at {store.path} is damaged; {remedy}"

    def read(meta: Path, what: str) -> dict[str, Any]:
        try:
            data = json.loads(meta.read_bytes())
        except (OSError, ValueError) as exc:
            raise StoreError(f"{meta} is damaged ({type(exc).__name__}: {exc}); {what}") from exc
        return data if isinstance(data, dict) else {}

    def members(folder: Path) -> list[Path]:
        return sorted(p for p in folder.iterdir() if (p / "zarr.json").is_file())

    for child in members(store.path):
        if read(child / "zarr.json", damaged).get("node_type") != "group":
            continue
        for sub in members(child):
            what = damaged
            if child.name in _RESULT_GROUPS:
                what = (
                    f"delete the folders '{sub.name}' in {', '.join(_RESULT_GROUPS)} of {store.path} and run the "
                    f"command that made '{sub.name}' again"
                )
            read(sub / "zarr.json", what)


def _check_arrays(store: DataStore) -> None:
    """Raise StoreError if a data array is missing, its shape disagrees with the attributes, or the split is damaged.

    The reconstruction arrays are checked when they are used (:class:`~nanoct.io.store_recon.ReconstructionArrays`).
    """
    for name, shape in _shapes(store.meta, store.geometry).items():
        try:
            actual = tuple(store._group[name].shape)  # type: ignore[union-attr]
        except KeyError:
            raise StoreError(
                f"the data set at {store.path} is damaged: array '{name}' is missing; {_REGENERATE}"
            ) from None
        if actual != shape:
            raise StoreError(
                f"the data set at {store.path} is inconsistent: '{name}' has shape {actual} but its attributes "
                f"(n={store.n}, image {store.geometry.n}, sinogram {store.geometry.sino_shape}) say {shape}; "
                f"the attributes were edited by hand: restore them, or {_REGENERATE}"
            )
    try:
        split = store._array("split")[:]
    except Exception as exc:
        raise StoreError(f"the split of {store.path} cannot be read ({exc}); {_REGENERATE}") from exc
    if not np.isin(split, list(SPLITS.values())).all():
        raise StoreError(f"the split of {store.path} is damaged (labels outside 0, 1, 2); {_REGENERATE}")


@cached_by_file("zarr.json", maxsize=8)
def open_cached(path: str) -> DataStore:
    """One writable handle per store and process, for tasks that each write one sample; a store made again
    at the same path (its ``zarr.json`` rewritten) gets a new handle."""
    return DataStore.open(path, mode="r+")


def _check_kept_slices(store: DataStore, sinograms: np.ndarray, kept: np.ndarray) -> Any:
    """The sinograms array of ``store``, once every slice in ``kept`` equals the import's (float32 rounding).

    Raises
    ------
    StoreError
        For the first slice that differs: the data set was imported from another file, or the file changed.
    """
    array = store._array("sinograms")
    for index in kept.tolist():
        new = np.asarray(sinograms[index], dtype=np.float32)
        scale = float(np.abs(new).max(initial=0.0))
        if not np.allclose(array[index], new, rtol=1e-5, atol=1e-6 * scale):
            raise StoreError(
                f"{store.path} holds an import whose slice {index} differs from this import's (another file under "
                "the same options, or the file changed since); import into a new --out (or delete it first)"
            )
    return array


def create_scan(
    path: str | os.PathLike[str], geometry: Geometry, sinograms: np.ndarray, scan: dict[str, Any]
) -> DataStore:
    """Create a data set holding measured sinograms, one sample per slice, all in the test split.

    Parameters
    ----------
    path : path
        New store directory (an empty or missing folder).
    geometry : Geometry
        The scan's geometry (explicit angles, rotation-axis offset).
    sinograms : ndarray of shape (S, K, L)
        Line integrals of S slices.
    scan : dict
        Where the data came from and how they were corrected (JSON-able); stored as
        ``attrs["nanoct"]["scan"]``.

    Raises
    ------
    StoreError
        If ``path`` already holds a data set (import into a new folder), is a file, or the
        sinograms do not match the geometry or are not finite.
    """
    path = Path(path)
    if _check_target(path):
        raise StoreError(f"{path} already holds a data set; import into a new --out (or delete it first)")
    stack = np.asarray(sinograms, dtype=np.float32)
    if stack.ndim != 3 or stack.shape[1:] != geometry.sino_shape or stack.shape[0] == 0:
        raise StoreError(
            f"sinograms have shape {stack.shape}; expected (slices, {geometry.n_angles}, {geometry.n_det})"
        )
    if not np.isfinite(stack).all():
        raise StoreError("the sinograms contain NaN or infinite values; nothing was written")
    n = stack.shape[0]
    meta = _json_roundtrip(
        {"format": FORMAT, "version": __version__, "geometry": geometry.to_dict(), "n": n, "seed": 0, "scan": scan}
    )
    _build_group(path, meta, geometry, np.full(n, SPLITS["test"], dtype=np.int8))
    store = DataStore.open(path, mode="r+")
    store._array("sinograms")[:] = stack
    store._array("done")[:] = True
    return store
