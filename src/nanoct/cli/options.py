"""Options several commands share, declared once: single options (``WORKERS``, ``QUIET`` ...) and the groups
of ``import`` and ``stack`` (:class:`ScanReading`: how to read a scan file; :class:`ScanCorrections`: the
corrections of its projections), which those commands take as one typed value each
(:func:`~nanoct.cli.flags.flag_groups`); :class:`Execution` carries where the work runs."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import typer

from ..core.errors import NanoctError
from ..io.readers import READERS
from .flags import given, long_flag, option
from .parsing import parse_ints, parse_range

WORKERS = typer.Option(2, "--workers", "-w", help="Local Dask worker processes (0: run in this process).")
SCHEDULER = typer.Option(None, "--scheduler", help="Address of a running Dask scheduler (instead of a local cluster).")
QUIET = typer.Option(False, "--quiet", "-q", help="No progress bars.")
QUIET_OUTPUT = typer.Option(False, "--quiet", "-q", help="Print nothing but errors.")


@dataclass(frozen=True)
class Execution:
    """Where a command's work runs (``--workers`` local processes or a ``--scheduler``) and whether it shows
    progress bars (not ``--quiet``)."""

    workers: int
    scheduler: str | None
    progress: bool


@dataclass(frozen=True)
class ScanReading:
    """How to read a scan file (``import``, and ``stack`` given a scan file; refused by ``stack`` on a data set)."""

    fmt: str | None = option(
        None,
        "--format",
        help=f"{' | '.join(READERS)} (default: from the file).",
    )
    angles: str | None = option(
        None,
        "--angles",
        help="Angles: text file, one per view (IMOD .tlt/.rawtlt too), FILE.h5:/dataset, or FIRST:STOP (evenly "
        "spaced, STOP excluded).",
    )
    angles_select: str | None = option(
        None, "--angles-select", help="Use only the values FIRST:STOP (0-based, STOP excluded) of the --angles file."
    )
    radians: bool = option(False, "--radians", help="The --angles text file is in radians (default degrees).")
    angles_units: str | None = option(
        None,
        "--angles-units",
        help="deg | rad: the unit of the angles, overriding the file's units attribute and the check that the "
        "values look like that unit (--radians keeps the check): for scans that fail it, e.g. more than two "
        "turns in radians.",
    )
    data_path: str | None = option(None, "--data-path", help="HDF5: dataset of the frames (frames, rows, columns).")
    image_key_path: str | None = option(
        None, "--image-key-path", help="HDF5: dataset of the NXtomo image keys (0 proj, 1 flat, 2 dark)."
    )
    angles_path: str | None = option(None, "--angles-path", help="HDF5: dataset of the angles (one per frame).")
    allow_outside: list[Path] = option(
        [], "--allow-outside", help="HDF5: a folder outside the scan's own that links may read (repeatable)."
    )
    tilt_axis: str = option("columns", "--tilt-axis", help="MRC: the tilt axis runs along the image columns | rows.")
    flats: Path | None = option(None, "--flats", help="Flat fields (TIFF or .npy) for TIFF and .npy scans.")
    darks: Path | None = option(None, "--darks", help="Dark fields (TIFF or .npy) for TIFF and .npy scans.")
    line_integrals: bool = option(
        False, "--line-integrals", help="The data are already -log normalised (no flat/dark correction)."
    )
    rows: str | None = option(None, "--rows", help="Detector rows (slices) FIRST:STOP (default all).")
    crop: str | None = option(None, "--crop", help="Detector columns FIRST,STOP to keep.")
    entry: str | None = option(None, "--entry", help="NXtomo entry to read (when the file has several).")

    def row_range(self) -> tuple[int, int] | None:
        """``--rows FIRST:STOP``, checked."""
        return parse_range(self.rows, "--rows", ":")

    def crop_range(self) -> tuple[int, int] | None:
        """``--crop FIRST,STOP``, checked."""
        return parse_range(self.crop, "--crop", ",")

    def read_settings(self) -> dict[str, Any]:
        """The keywords of :func:`~nanoct.io.scanio.read_scan` these options give, other than the rows and columns."""
        from ..io.scanio import ReaderOptions

        if self.angles_units is not None and self.angles_units not in ("deg", "rad"):
            raise NanoctError(f"--angles-units {self.angles_units!r}: use deg or rad")
        if self.tilt_axis not in ("columns", "rows"):
            raise NanoctError(f"--tilt-axis {self.tilt_axis!r}: use columns (IMOD's, vertical) or rows (horizontal)")
        options = ReaderOptions(
            self.data_path, self.image_key_path, self.angles_path, self.angles_units, self.tilt_axis,
            tuple(str(a) for a in self.allow_outside), parse_range(self.angles_select, "--angles-select", ":"),
        )  # fmt: skip
        return {
            "fmt": self.fmt, "angles_file": self.angles, "degrees": not self.radians, "flats": self.flats,
            "darks": self.darks, "is_line_integral": self.line_integrals, "entry": self.entry, "options": options,
        }  # fmt: skip


@dataclass(frozen=True)
class ScanCorrections:
    """Corrections of measured projections (``nanoct.preprocess``, docs/corrections.md), all off by default."""

    outliers: float | None = option(
        None, "--outliers", help="Replace outliers (zingers) beyond this many robust noise units (e.g. 5)."
    )
    outlier_size: int = option(3, "--outlier-size", help="Median window of the outlier filter (odd).")
    outlier_kind: str = option("both", "--outlier-kind", help="Outliers to replace: both | bright | dark.")
    open_beam: bool = option(
        False, "--open-beam", help="Divide each view by its open beam fitted to air (beam decay, flat mismatch)."
    )
    air_columns: str | None = option(
        None, "--air-columns", help="With --open-beam: columns seeing only air, FIRST:STOP[,FIRST:STOP]."
    )
    open_beam_degree: str = option("auto", "--open-beam-degree", help="Open-beam surface per view: auto | 0 | 1 | 2.")
    delta_beta: float | None = option(
        None, "--delta-beta", help="Paganin phase retrieval: delta/beta (needs the next three)."
    )
    energy_kev: float | None = option(None, "--energy-kev", help="Paganin: photon energy in keV.")
    distance_m: float | None = option(None, "--distance-m", help="Paganin: propagation distance in metres.")
    pixel_size_m: float | None = option(None, "--pixel-size-m", help="Paganin: detector pixel size in metres.")
    stripes: str | None = option(
        None, "--stripes", help="Ring/stripe removal (algotom): all | sorting | filtering | fitting."
    )
    stripe_params: str | None = option(
        None, "--stripe-params", help="Stripe method parameters by algotom's names, e.g. snr=3,la_size=51."
    )

    #: Options that set how another one works, with the one each needs (given alone, nothing would use them).
    NEEDS = {"outlier_size": "outliers", "outlier_kind": "outliers", "open_beam_degree": "open_beam"}

    def check_needs(self) -> None:
        """Refuse an option given without the one it sets how it works (``--outlier-size`` without ``--outliers``)."""
        for name, needed in self.NEEDS.items():
            alone = given(self, [name])
            if alone and not given(self, [needed]):
                flag, other = next(iter(alone)), long_flag(self, needed)
                raise NanoctError(f"{flag} {alone[flag]}: used only with {other} (add {other}, or drop {flag})")

    def corrections(self) -> Any:
        """The :class:`~nanoct.preprocess.pipeline.Corrections` these options ask for (None: none)."""
        from ..preprocess import Corrections, parse_columns, parse_stripe_params

        degree: int | str = (
            self.open_beam_degree
            if self.open_beam_degree == "auto"
            else parse_ints(self.open_beam_degree, "--open-beam-degree", low=0)[0]
        )
        corrections = Corrections(
            outliers=self.outliers, outlier_size=self.outlier_size, outlier_kind=self.outlier_kind,
            open_beam=self.open_beam, air_columns=None if self.air_columns is None else parse_columns(self.air_columns),
            open_beam_degree=degree, delta_beta=self.delta_beta, energy_kev=self.energy_kev,
            distance_m=self.distance_m, pixel_size_m=self.pixel_size_m, stripes=self.stripes,
            stripe_params={} if self.stripe_params is None else parse_stripe_params(self.stripe_params),
        )  # fmt: skip
        return None if corrections == Corrections() else corrections
