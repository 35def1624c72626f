"""What every scan reader is: the contract of :mod:`nanoct.io.readers`, and what a read is asked for.

A :class:`Reader` declares its format's ``--format`` name, who writes it, its file extensions, how
it recognises a file (:meth:`Reader.recognises`) and the reading options it takes beyond the
common ones; :meth:`Reader.read` reads a file into the :class:`~nanoct.io.rawscan.RawScan` every
reader returns, given a :class:`ReadRequest` (the part of the detector, the angles from outside
the file, flat and dark files, the :class:`ReaderOptions`). What a reader cannot read, it refuses
with one :class:`~nanoct.core.errors.NanoctError` naming the file and what to do.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..rawscan import RawScan, detector_window

__all__ = ["Reader", "ReadRequest", "ReaderOptions"]


@dataclass(frozen=True)
class ReaderOptions:
    """How to read a file beyond its format: HDF5 dataset paths, angle units, tilt axis, links.

    Attributes
    ----------
    data_path, image_key_path, angles_path : str, optional
        HDF5 datasets of the frames, their NXtomo image keys and the angles (``--data-path``
        ...): they override a known layout's paths, or describe a file of no known layout.
    angle_units : {"deg", "rad"}, optional
        Unit of the angles, as the user states it (overrides the file's ``units`` attribute
        and ``--radians``; the check that the span fits the unit is then skipped).
    tilt_axis : {"columns", "rows"}
        MRC tilt series: along which image direction the tilt axis runs (:mod:`nanoct.io.readers.mrc`).
    allow : tuple of str
        Folders outside the scan's own that external links and virtual data sets may read.
    angles_select : (int, int), optional
        Use only the values ``[FIRST, STOP)`` of the angles file (0-based), e.g. the
        projections' lines of a file that also lists the flats' and darks' angles.
    """

    data_path: str | None = None
    image_key_path: str | None = None
    angles_path: str | None = None
    angle_units: str | None = None
    tilt_axis: str = "columns"
    allow: tuple[str, ...] = ()
    angles_select: tuple[int, int] | None = None

    @property
    def has_paths(self) -> bool:
        """Whether any HDF5 dataset path was given."""
        return any((self.data_path, self.image_key_path, self.angles_path))


@dataclass(frozen=True)
class ReadRequest:
    """What :func:`~nanoct.io.scanio.read_scan` asks a reader for, its options resolved and checked.

    Attributes
    ----------
    window : callable
        ``window((R, L)) -> (row slice, column slice)``: the part of the detector to read
        (:func:`~nanoct.io.rawscan.detector_window`; it refuses a selection the detector does not hold).
    angles : ndarray, callable or None
        The view angles given from outside the file (``--angles``, radians), or for ``FIRST:STOP`` a
        function of the number of views; None: the file's own.
    flats, darks : path, optional
        Separate flat and dark field files (only for readers that take them).
    entry : str, optional
        The NXtomo entry to read.
    options : ReaderOptions
    """

    window: Callable[[tuple[int, ...]], tuple[slice, slice]] = field(
        default_factory=lambda: detector_window(None, None)
    )
    angles: np.ndarray | Callable[[int], np.ndarray] | None = None
    flats: Any = None
    darks: Any = None
    entry: str | None = None
    options: ReaderOptions = field(default_factory=ReaderOptions)


class Reader(ABC):
    """One scan format: its name, its files, how it knows one, and how it reads one.

    Attributes
    ----------
    name : str
        The ``--format`` value.
    title : str
        What the format is and who writes it (``--help``, the docs' table of formats).
    extensions : tuple of str
        File name extensions it reads, lower case with the dot.
    recognised_by : str
        How :meth:`recognises` tells its files, in words (the docs' table).
    rank : int
        Where it stands among the readers: detection asks them, and messages list them, in this order
        (ties by name). A format whose files are also another's (an NXtomo file is HDF5 too) comes first.
    takes : frozenset of str
        The reading options it takes beyond ``--angles``, ``--rows``, ``--crop`` and the angle units:
        ``"flats"``, ``"darks"`` (separate files), ``"entry"``, ``"data_path"`` (HDF5 dataset paths),
        ``"allow"`` (folders its links may read), ``"tilt_axis"``, ``"angles_select"`` (on an angles file
        the format finds itself); :func:`~nanoct.io.scanio.read_scan` refuses the others.
    follows_links : bool
        Its files can link to other files, which it reads only below the scan's folder (and the
        ``--allow-outside`` folders); a link elsewhere is refused.
    """

    name: str
    title: str
    extensions: tuple[str, ...]
    recognised_by: str
    rank: int
    takes: frozenset[str] = frozenset()
    follows_links: bool = False

    def recognises(self, path: Path, allow: tuple[str, ...] = ()) -> bool:
        """Whether ``path`` (which exists) is a file of this format: by default, a file of its extensions.

        ``allow``: folders outside the scan's own that a recognising look into the file may follow links to.
        """
        return not path.is_dir() and path.suffix.lower() in self.extensions

    def unrecognised(self, path: Path) -> str | None:
        """Why ``path``, which no reader recognised, is refused, where this reader can say (None: it cannot)."""
        return None

    @abstractmethod
    def read(self, path: Path, request: ReadRequest) -> RawScan:
        """Read the scan at ``path`` as ``request`` asks.

        Returns
        -------
        RawScan
            Projections, flats and darks of the requested rows and columns, the angles (radians;
            placeholders where ``request.angles`` replaces them), ``source`` with the file, the format,
            ``detector_shape`` (the full detector ``[R, L]``), a pixel size where the file has one
            (``raw_pixel_size_m``) and what else the file tells.

        Raises
        ------
        NanoctError
            A missing, truncated or damaged file, a refused link, missing angles: one line naming the
            file and what to do.
        """

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r}>"
