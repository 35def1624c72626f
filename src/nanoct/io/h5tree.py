"""HDF5 files as untrusted input: objects read by path, links followed only into allowed folders.

A scan's HDF5 file may hold external links (Diamond's NeXus files keep the frames in other
files) and virtual data sets (``nxtomo`` links the acquisition files); a link may also name
``/etc/passwd`` or ``../../x``. :class:`H5Tree` walks a path one link at a time and follows
soft links and external links itself (HDF5's own search, which also looks in the current
directory, is never used): the file an external link or a virtual data set's source names is
resolved relative to the folder of the file that holds the link, and read only when it lies
below one of the allowed folders (the scan's own folder, and those the user allows with
``--allow-outside``). Anything else, a missing target, and a file HDF5 cannot open are refused
with one line naming the link and the file.
"""

from __future__ import annotations

import contextlib
import os
import posixpath
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import NanoctError

__all__ = ["H5Tree", "open_h5", "text"]

_MAX_HOPS = 32  # soft and external links followed for one path (a loop ends here)


def text(value: Any) -> str:
    """An HDF5 attribute or scalar (bytes, numpy scalar, 1-element array) as a str."""
    if isinstance(value, bytes):
        return value.decode(errors="replace")
    if isinstance(value, np.ndarray) and value.size == 1:
        return text(value.item())
    return str(value)


def open_h5(path: Path) -> Any:
    """``h5py.File(path, "r")``; a file that is not (complete) HDF5 raises :class:`NanoctError`."""
    import h5py

    try:
        return h5py.File(path, "r")
    except (OSError, ValueError) as exc:
        raise NanoctError(f"cannot open {path} as HDF5 ({exc}); is it a complete .h5/.nxs file?") from None


def _inside(path: Path, roots: Iterable[Path]) -> bool:
    return any(path == root or root in path.parents for root in roots)


class H5Tree:
    """An HDF5 file opened for reading, its links followed only into allowed folders.

    Parameters
    ----------
    path : path
        The file.
    allow : sequence of path
        More folders whose files external links and virtual data sets may name (the file's own
        folder is always allowed).

    Notes
    -----
    Use as a context manager: the linked files it opens are closed with it.
    """

    def __init__(self, path: str | os.PathLike[str], allow: Iterable[str | os.PathLike[str]] = ()) -> None:
        self.path = Path(path)
        self.roots = [self.path.resolve().parent, *(Path(a).resolve() for a in allow)]
        self._stack = contextlib.ExitStack()
        self._files: dict[Path, Any] = {}
        self.file = self._open(self.path.resolve())

    def __enter__(self) -> H5Tree:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the file and every linked file opened through it."""
        self._stack.close()

    def _open(self, path: Path) -> Any:
        if path not in self._files:
            self._files[path] = self._stack.enter_context(open_h5(path))
        return self._files[path]

    def _target(self, name: str, holder: Path, what: str) -> Path:
        """The file a link in ``holder`` names, checked: below an allowed folder, and present."""
        named = Path(name)
        target = (named if named.is_absolute() else holder.parent / named).resolve()
        if not _inside(target, self.roots):
            raise NanoctError(
                f"{self.path}: {what} points to {name} ({target}), outside the scan's folder {self.roots[0]}; "
                "refused (pass --allow-outside FOLDER if you trust it)"
            )
        if not target.is_file():
            raise NanoctError(f"{self.path}: {what} points to {name}, which is missing ({target}); copy it there")
        return target

    def get(self, name: str) -> Any:
        """The group or dataset at ``name`` (absolute in the file), or None where nothing is.

        Raises
        ------
        NanoctError
            A link outside the allowed folders, to a missing file, a link loop, or a virtual
            data set whose sources are outside or missing.
        """
        import h5py

        node, hops = self.file, 0
        parts = [p for p in name.split("/") if p]
        while parts:
            part = parts.pop(0)
            try:
                link = node.get(part, getlink=True) if isinstance(node, h5py.Group) else None
            except (OSError, KeyError, RuntimeError, ValueError) as exc:
                raise NanoctError(f"{self.path}: cannot read {name} ({exc}); the file may be damaged") from None
            if link is None:
                return None
            if isinstance(link, h5py.HardLink):
                node = node[part]
                continue
            hops += 1
            if hops > _MAX_HOPS:
                raise NanoctError(f"{self.path}: {name} goes through more than {_MAX_HOPS} links (a loop?)")
            if isinstance(link, h5py.SoftLink):
                target = link.path if link.path.startswith("/") else posixpath.join(node.name, link.path)
                node, parts = node.file, [p for p in target.split("/") if p] + parts
            elif isinstance(link, h5py.ExternalLink):
                holder = Path(node.file.filename).resolve()
                file = self._open(self._target(link.filename, holder, f"the external link {node.name}/{part}"))
                node, parts = file, [p for p in link.path.split("/") if p] + parts
            else:
                raise NanoctError(f"{self.path}: {name} is a link of an unknown kind; refused")
        if isinstance(node, h5py.Dataset) and node.is_virtual:
            self._check_virtual(node, name)
        return node

    def _check_virtual(self, ds: Any, name: str) -> None:
        holder = Path(ds.file.filename).resolve()
        for source in {s.file_name for s in ds.virtual_sources()}:
            if source == ".":
                continue
            candidates = [Path(source) if Path(source).is_absolute() else holder.parent / source]
            prefix = os.environ.get("HDF5_VDS_PREFIX")
            if prefix:
                candidates.append(Path(prefix) / source)
            found = [c.resolve() for c in candidates if c.is_file()]
            what = f"the virtual dataset {name}"
            if not found:
                raise NanoctError(
                    f"{self.path}:{name} is a virtual dataset whose source file {source} is missing "
                    f"(looked next to {holder.name}); copy it with the file, or convert it with the data included"
                )
            for path in found:
                if not _inside(path, self.roots):
                    raise NanoctError(
                        f"{self.path}: {what} reads {source} ({path}), outside the scan's folder {self.roots[0]}; "
                        "refused (pass --allow-outside FOLDER if you trust it)"
                    )

    def has(self, name: str) -> bool:
        """Whether ``name`` exists (following links as :meth:`get` does; a refused link raises)."""
        return self.get(name) is not None

    def dataset(self, name: str) -> Any:
        """The dataset at ``name``; :class:`NanoctError` when it is missing or a group."""
        import h5py

        node = self.get(name)
        if not isinstance(node, h5py.Dataset):
            what = "missing" if node is None else "a group, not a dataset"
            raise NanoctError(f"{self.path}: {name} is {what}; check the dataset path")
        return node

    def read(self, name: str, region: tuple[slice, ...] = ()) -> tuple[np.ndarray, str | None]:
        """Dataset ``name`` (only ``region`` of it, if given) and its ``units`` attribute (None without).

        Raises
        ------
        NanoctError
            A missing dataset, a refused link, or a dataset that cannot be read (truncated).
        """
        ds = self.dataset(name)
        try:
            data = np.asarray(ds[region] if region else ds[()])
            units = text(ds.attrs["units"]) if "units" in ds.attrs else None
        except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
            raise NanoctError(
                f"{self.path}: cannot read {name} ({exc}); the file may be truncated or still being written - "
                "copy it again"
            ) from None
        return data, units

    def attr(self, name: str, key: str, default: Any = "") -> str:
        """Attribute ``key`` of the object at ``name`` as text (``default`` when either is missing)."""
        node = self.get(name)
        if node is None or key not in node.attrs:
            return default
        return text(node.attrs[key])

    def keys(self, name: str = "/") -> list[str]:
        """Names of the members of the group at ``name`` (empty for a dataset or nothing)."""
        import h5py

        node = self.get(name)
        return list(node.keys()) if isinstance(node, h5py.Group) else []
