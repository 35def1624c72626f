"""Measured-scan commands: ``import`` a scan file into a data set, and ``stack`` (one motion and axis for a
whole stack, then every slice) on a data set or a scan file (imported first, or streamed block by block).

Both read a scan file with the same options (:class:`~nanoct.cli.options.ScanReading`,
:class:`~nanoct.cli.options.ScanCorrections`), declared once.
"""

from __future__ import annotations

import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import typer

from ..core.errors import NanoctError
from .flags import flag_groups, given, option
from .options import QUIET, QUIET_OUTPUT, SCHEDULER, WORKERS, Execution, ScanCorrections, ScanReading
from .parsing import check_name, parse_center, parse_eta, parse_ints, parse_model
from .summary import echo_import, slab_summary, stack_summary


@dataclass(frozen=True)
class ImportSettings:
    """``import``: the detector binning, the axis, the image size and what bad values to accept."""

    binning: int = option(
        1, "--binning", help="Average this many detector columns (and rows); a remainder is left out, with a note."
    )
    center_offset: str = option(
        "0",
        "--center-offset",
        help="Rotation axis minus the raw detector centre, in raw pixels (TomoPy center - (L-1)/2), or auto "
        "(every estimator: opposite views, find_center_vo, centroids, each scored by held-out views; see "
        "docs/consistency.md). The default 0 "
        "takes the axis at the detector centre ('nanoct stack' estimates it by default).",
    )
    size: int | None = option(
        None, "--size", help="Image size N (default: detector columns after crop/binning; at most 4 times them)."
    )
    tolerance: float = option(
        1e-3,
        "--tolerance",
        help="Largest fraction of non-positive flat/dark-corrected values (dead pixels), filled from their row.",
    )
    drop_bad_views: bool = option(
        False, "--drop-bad-views", help="Leave out projections (and flats/darks) holding NaN or infinite values."
    )

    def keywords(self) -> dict[str, Any]:
        """These settings as keywords of :func:`~nanoct.workflows.importscan.import_scan`."""
        return {
            "binning": self.binning, "center_offset": parse_center(self.center_offset), "size": self.size,
            "tolerance": self.tolerance, "drop_bad": self.drop_bad_views,
        }  # fmt: skip


@flag_groups(place={"entry": "tolerance"})  # --entry after --tolerance, where 'import' lists it
def import_(
    *,
    src: Path = typer.Argument(..., help="Scan: HDF5/NeXus (.h5/.nxs), .tif stack or folder, .npy, or MRC (.mrc/.st)."),
    out: Path = typer.Option(..., "--out", "-o", help="New data-set directory."),
    reading: ScanReading,
    settings: ImportSettings,
    corrections: ScanCorrections,
    quiet: bool = QUIET_OUTPUT,
) -> None:
    """Import a measured parallel-beam scan: one sample per detector row, all sharing one motion.

    Flat/dark correction and -log, slice selection, cropping and binning; the view angles come
    from the file (NXtomo rotation_angle in its units, other HDF5 layouts in theirs, Data
    Exchange theta: degrees, IMOD .rawtlt/.tlt next to an MRC stack) or --angles, the pixel size
    from NXtomo or the MRC header. An HDF5 file of a known layout (NXtomo, Diamond's scan NeXus,
    Data Exchange) is read without options; any other with --data-path (and --image-key-path,
    --angles-path). External links and virtual datasets are followed only below the file's
    folder (and --allow-outside folders). Corrections (off by default, recorded with the data
    set): outliers, the open beam from air, Paganin phase retrieval, stripe removal. The data
    set has no ground truth: reconstruct it (Dremel estimates one shift per view for the whole
    stack), post-process it with a network trained on data simulated with its geometry, and
    export the images.
    """
    if reading.line_integrals and given(settings, ["tolerance"]):
        raise NanoctError(
            f"--tolerance {settings.tolerance:g}: for the flat/dark correction, which --line-integrals skips"
        )
    store = import_scan_file(src, out, reading, corrections, **settings.keywords())
    if not quiet:
        echo_import(store)


def import_scan_file(src: Path, out: Path, reading: ScanReading, corrections: ScanCorrections, **settings: Any) -> Any:
    """:func:`~nanoct.workflows.importscan.import_scan` with the reading and correction options that
    ``import`` and ``stack`` share; ``settings``: the import's other keywords (binning, axis, ...), which only
    ``import`` offers."""
    from ..workflows.importscan import import_scan

    row_range = reading.row_range()
    corrections.check_needs()
    fixes = corrections.corrections()
    return import_scan(
        src, out, **reading.read_settings(), rows=None if row_range is None else slice(*row_range),
        crop=reading.crop_range(), corrections=fixes, **settings,
    )  # fmt: skip


@dataclass(frozen=True)
class StackTarget:
    """``stack`` given a scan file: where it goes (a new data set, or a Zarr group streamed into)."""

    store_dir: Path | None = option(None, "--store", help="With a scan file: the new data set to import into.")
    out: Path | None = option(
        None, "--out", "-o", help="With a scan file: stream it block by block into this Zarr group (bounded memory)."
    )
    block: int | None = option(None, "--block", help="With --out: detector rows per block (default 16).")


#: ``--dremel-binning``'s default (the coarse Dremel estimate binned 8x).
DREMEL_BINNING = 8


@dataclass(frozen=True)
class StackSettings:
    """``stack``: how the motion and axis are estimated and each slice reconstructed, and the output's name."""

    method: str = option(
        "fbp", "--method", "-m", help="Each slice: fbp | gridrec (FBP in Fourier space) | dremel (fixed) | resesop."
    )
    eta: str = option(
        "auto",
        "--eta",
        help="resesop: uncertainty level per view: auto (half the FBP's largest residual) | NUMBER | FILE.npy (K,).",
    )
    center_offset: str = option(
        "auto",
        "--center-offset",
        help="Axis offset in detector pixels, or auto. The default auto estimates it with the motion ('nanoct "
        "import' defaults to 0, the detector centre); on a data set in its detector pixels (binned where it was "
        "imported with --binning).",
    )
    motion_slices: str = option("auto", "--motion-slices", help="auto (up to 4) | all | 0,5,9")
    dremel_binning: int = option(
        DREMEL_BINNING,
        "--dremel-binning",
        help="Binning of the coarse Dremel estimate (used with --refine, or where autofocus is rejected); not "
        "the detector binning of 'nanoct import --binning'.",
    )
    binning: int | None = option(
        None, "--binning", hidden=True, help="Former spelling of --dremel-binning (deprecated)."
    )
    coarse_iter: int = option(8, "--coarse-iter", help="Dremel iterations on the binned data (0: none).")
    refine: str = option(
        "auto",
        "--refine",
        help="Dremel + projection matching with these binnings, e.g. 2,2,1, air seen or not (auto: the views' "
        "centroids where air is seen, else autofocus + matching; see docs).",
    )
    model: str | None = option(None, "--model", help="DEGREE,HARMONICS: use a smooth model of the motion.")
    name: str | None = option(None, "--name", help="Output name (default METHOD_stack).", callback=check_name)
    overwrite: bool = option(False, "--overwrite", help="Replace an existing result of that name.")

    def coarse_binning(self) -> int:
        """The binning of the coarse Dremel estimate: ``--dremel-binning``, or its former spelling ``--binning``."""
        if self.binning is None:
            return self.dremel_binning
        if given(self, ["dremel_binning"]):
            raise NanoctError("--binning: the former spelling of --dremel-binning; give --dremel-binning only")
        return self.binning

    def refine_binnings(self) -> tuple[int, ...] | None:
        """``--refine``: None for auto, else the binnings of the refinement steps."""
        return None if self.refine == "auto" else parse_ints(self.refine, "--refine")


@dataclass(frozen=True)
class StackRequest:
    """Every option of one ``nanoct stack`` run, by group."""

    target: StackTarget
    settings: StackSettings
    reading: ScanReading
    corrections: ScanCorrections
    run: Execution


@flag_groups()
def stack(
    *,
    source: Path = typer.Argument(
        ..., help="Data-set store, or a scan file: streamed into --out, or imported into --store first."
    ),
    target: StackTarget,
    settings: StackSettings,
    reading: ScanReading,
    corrections: ScanCorrections,
    workers: int = WORKERS,
    scheduler: str | None = SCHEDULER,
    quiet: bool = QUIET,
) -> None:
    """Whole measured stack: one motion and rotation axis (coarse to fine), then every slice (resumable).

    Given a scan file and --out, streams it block by block of detector rows (memory bounded by a
    block, resumable by block; docs/commands.md). Given a scan file and --store, imports it first
    with the reading and correction options of 'nanoct import' (--format, --angles, --data-path,
    --open-beam, --stripes ...; the axis is then estimated here, not at import).
    The estimated motion is checked against no correction, the axis alone and a smooth model by
    how well half of the views predict the other half, and dropped where it fits worse beyond the
    noise (docs/consistency.md). Ends with a summary: the axis and how it was found, the range of
    the motion, that check, where the slices are, and the slices whose Dremel refinement ran away
    (they keep the stack's motion).
    """
    from ..io.store import DataStore
    from ..workflows.stack import reconstruct_stack

    request = StackRequest(target, settings, reading, corrections, Execution(workers, scheduler, not quiet))
    found = _stack_source(source, request)
    if found is None:  # streamed into --out
        return
    written = reconstruct_stack(
        found, method=settings.method, center=parse_center(settings.center_offset),
        motion_slices=settings.motion_slices, binning=settings.coarse_binning(), coarse_iter=settings.coarse_iter,
        model=parse_model(settings.model), eta=parse_eta(settings.eta), refine=settings.refine_binnings(),
        name=settings.name, overwrite=settings.overwrite, workers=workers, scheduler=scheduler, progress=not quiet,
    )  # fmt: skip
    store = DataStore.open(found)
    typer.echo(stack_summary(store, written, settings, store.recons.motion_info(written) or {}))


def _stack_source(source: Path, request: StackRequest) -> Path | None:
    """The data set ``nanoct stack`` works on: ``source``, or the scan file imported into ``--store``.

    A scan file with ``--out`` is streamed here instead (its summary printed; ``None`` returned).
    An option that does not apply to ``source`` is refused.
    """
    target, settings = request.target, request.settings
    if settings.eta != "auto" and settings.method != "resesop":
        raise NanoctError(f"--eta {settings.eta}: RESESOP's uncertainty level, used only with --method resesop")
    if (source / "zarr.json").is_file():
        scan_only = given(target)
        if scan_only:
            raise NanoctError(
                f"{', '.join(scan_only)}: for a scan file (--out streams it, --block sets its blocks, --store imports "
                f"it); {source} is a data set (drop {'them' if len(scan_only) > 1 else 'it'})"
            )
        _refuse_reading(source, request)
        return source
    if target.out is not None and target.store_dir is None:
        typer.echo(_stream_stack(source, target.out, request))
        return None
    if not source.exists():
        raise NanoctError(
            f"{source} does not exist; give a data set (nanoct import), or a scan file or folder with --out OUT.zarr "
            "or --store NEW_DIR"
        )
    if target.store_dir is None or target.out is not None:
        raise NanoctError(
            f"{source} is not a data set: stream the scan file with --out OUT.zarr (memory bounded by a block, "
            "resumable), or import it first with --store NEW_DIR (not both)"
        )
    if target.block is not None:
        raise NanoctError("--block goes with --out (streaming); a data set made with --store runs slice by slice")
    return import_scan_file(source, target.store_dir, request.reading, request.corrections).path


def _refuse_reading(directory: Path, request: StackRequest) -> None:
    """Refuse the reading and correction options given to ``nanoct stack`` on the data set ``directory``: they
    apply when a scan file is read, so the message gives the import that applies them."""
    from ..io.store import DataStore

    found = given(request.reading) | given(request.corrections)
    if not found:
        return
    try:
        scan = DataStore.open(directory).meta.get("scan") or {}
    except (NanoctError, OSError, KeyError, ValueError):  # the stack itself then says what is wrong
        scan = {"file": "SCAN"}
    names = ", ".join(found)
    if not scan:
        raise NanoctError(f"{names}: reading and correction options are for a scan file; {directory} is simulated")
    words = ["nanoct", "import", str(scan.get("file") or "SCAN"), "--out", "NEW_DIR"]
    for flag, value in found.items():
        values = value if isinstance(value, list) else [value]  # a repeatable option: once per value
        words += [flag] if value is True else [w for v in values for w in (flag, str(v))]
    raise NanoctError(
        f"{names}: reading and correction options apply when importing; the data set {directory} is already "
        f"imported: use {shlex.join(words)} (or give stack the scan file with --store NEW_DIR or --out OUT.zarr)"
    )


def _stream_stack(src: Path, out: Path, request: StackRequest) -> str:
    """``nanoct stack SCAN --out OUT.zarr``: the scan streamed block by block (``reconstruct_scan``)."""
    from ..workflows.slabs import reconstruct_scan
    from ..workflows.stack import fbp_engine

    settings, reading, run = request.settings, request.reading, request.run
    unused = given(reading, ["crop"]) | given(request.corrections) | given(settings, ["name", "eta"])
    if unused:
        raise NanoctError(
            f"{', '.join(unused)}: not applied when streaming with --out; import with --store NEW_DIR instead"
        )
    if settings.method not in ("fbp", "gridrec"):
        raise NanoctError(f"--method {settings.method!r}: streaming with --out runs fbp or gridrec (Fourier space)")
    if fbp_engine("auto") != "gridrec":
        raise NanoctError("streaming with --out needs finufft (pip install finufft); or import with --store NEW_DIR")
    center = parse_center(settings.center_offset)
    motion_rows: Any = settings.motion_slices
    if motion_rows not in ("auto", "all"):
        motion_rows = list(parse_ints(motion_rows, "--motion-slices", low=0))
    elif motion_rows == "all":
        raise NanoctError("--motion-slices all: give auto or the rows to use, e.g. 0,50,100, when streaming")
    read, block = reading.read_settings(), request.target.block
    written = reconstruct_scan(
        src, out, rows=reading.row_range(), motion_rows=motion_rows,
        center=None if center == "auto" else float(center), block=16 if block is None else block,
        read={k: v for k, v in read.items() if v is not None},
        motion={"binning": settings.coarse_binning(), "coarse_iter": settings.coarse_iter,
                "model": parse_model(settings.model), "refine": settings.refine_binnings()},
        overwrite=settings.overwrite, workers=run.workers, scheduler=run.scheduler, progress=run.progress,
    )  # fmt: skip
    return slab_summary(written, settings)
