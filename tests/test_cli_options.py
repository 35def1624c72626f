"""Every option of ``nanoct import`` and ``nanoct stack`` is used or refused.

The options are read from the commands themselves (``nanoct.cli.app``), so a new option that is
missing from :data:`IMPORT` or :data:`STACK` fails :func:`test_every_option_is_classified`. Each
entry says what giving the option does, on a tiny scan (8 rows x 32 columns x 24 views) written
here: it ``CHANGES`` the result (exit status 0 and another data set, output, printed text or
progress than without it), it is ``REFUSED`` (exit status 2, one ``error:`` line naming what is
wrong, nothing written), it is ``REQUIRED`` (without it the command is refused), or it is a
``NOOP`` by design (with the reason). ``stack`` is walked three ways: on a data set made by
``import`` (``dataset``), on a scan file imported first (``store``: ``--store NEW``) and on a scan
file streamed (``stream``: ``--out OUT.zarr``).
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest
import typer

from nanoct.cli import app, run
from nanoct.io.store import DataStore
from scan_cases import analytic_projections, known_motion

K, R, L = 24, 8, 32
CHANGES, REFUSED, REQUIRED, NOOP = "changes", "refused", "required", "no-op"


@dataclass(frozen=True)
class Case:
    """An option tried on ``scan`` (a key of :data:`SCANS`): the command with ``base`` and then ``args`` added.

    ``message``: for ``REFUSED`` a text of the error line, for ``NOOP`` why. ``prepare``: arguments of a
    first run into the same output, made before both (e.g. another result that ``--overwrite`` replaces).
    For ``REQUIRED``, ``args`` is the whole command line without the option ({t}: the test's folder).
    """

    expect: str
    args: tuple[str, ...] = ()
    scan: str = "nxs"
    base: tuple[str, ...] = ()
    message: str = ""
    prepare: tuple[str, ...] | None = None


#: The scans, as the command line gives them ({s}: the folder they are written to).
FLATS = ("--flats", "{s}/flats.npy")
DARKS = ("--darks", "{s}/darks.npy")
SCANS = {
    "nxs": ("{s}/scan.nxs",),  # NXtomo with flats and darks, a shift per view, a zinger
    "npy": ("{s}/scan.npy", "--angles", "{s}/angles.txt"),  # the same as .npy, degrees in a text file
    "npy-26": ("{s}/scan.npy", "--angles", "{s}/angles26.txt", *FLATS, *DARKS),  # 2 lines more than views
    "npy-rad": ("{s}/scan.npy", "--angles", "{s}/angles_rad.txt", *FLATS, *DARKS),  # the angles in radians
    "nan": ("{s}/nan.npy", "--angles", "{s}/angles.txt", *FLATS, *DARKS),  # a view with a NaN
    "dead": ("{s}/dead.npy", "--angles", "{s}/angles.txt", *FLATS, *DARKS),  # a pixel reading 0
    "wide": ("{s}/wide.npy", "--angles", "0:180"),  # transmissions of an object wider than the detector
    "lines": ("{s}/lines.npy", "--angles", "{s}/angles.txt"),  # the line integrals of scan.npy
    "mrc": ("{s}/tilt.mrc", "--line-integrals"),  # a tilt series (+-57.5 degrees) with its .rawtlt
    "linked": ("{s}/linked/scan.nxs",),  # NXtomo whose frames are an external link out of its folder
}
DATA = "/entry/instrument/detector/data"
KEYS = "/entry/instrument/detector/image_key"
ANGLES = "/entry/sample/rotation_angle"
AIR = ("--air-columns", "0:3,29:32")
PAGANIN = ("--delta-beta", "100", "--energy-kev", "20", "--distance-m", "0.5", "--pixel-size-m", "1e-6")

IMPORT = {
    "SRC": Case(REQUIRED, ("import", "--out", "{t}/data")),
    "--out": Case(REQUIRED, ("import", "{s}/scan.nxs")),
    "--format": Case(REFUSED, ("--format", "dxchange"), message="exchange"),
    "--angles": Case(CHANGES, ("--angles", "0:360")),
    "--angles-select": Case(CHANGES, ("--angles-select", "2:26"), scan="npy-26"),
    "--radians": Case(CHANGES, ("--radians",), scan="npy-rad"),
    "--angles-units": Case(CHANGES, ("--angles-units", "rad")),
    "--data-path": Case(CHANGES, ("--data-path", DATA), base=("--image-key-path", KEYS, "--angles-path", ANGLES)),
    "--image-key-path": Case(CHANGES, ("--image-key-path", KEYS), base=("--data-path", DATA, "--angles-path", ANGLES)),
    "--angles-path": Case(CHANGES, ("--angles-path", ANGLES), base=("--data-path", DATA, "--image-key-path", KEYS)),
    "--allow-outside": Case(CHANGES, ("--allow-outside", "{s}"), scan="linked"),
    # one row and the axis given: stack on the series read the other way (32 rows, no air) takes a minute
    "--tilt-axis": Case(CHANGES, ("--tilt-axis", "rows"), scan="mrc", base=("--rows", "0:1", "--center-offset", "0")),
    "--flats": Case(CHANGES, FLATS, scan="npy", base=DARKS),
    "--darks": Case(CHANGES, DARKS, scan="npy", base=FLATS),
    "--line-integrals": Case(CHANGES, ("--line-integrals",), scan="lines"),  # refused as transmissions
    "--rows": Case(CHANGES, ("--rows", "2:5")),
    "--crop": Case(CHANGES, ("--crop", "2,30")),
    "--binning": Case(CHANGES, ("--binning", "2")),
    "--center-offset": Case(CHANGES, ("--center-offset", "0.5")),
    "--size": Case(CHANGES, ("--size", "40")),
    "--tolerance": Case(REFUSED, ("--tolerance", "0"), scan="dead", message="tolerance 0.00%"),
    "--entry": Case(REFUSED, ("--entry", "other"), message="other"),
    "--drop-bad-views": Case(CHANGES, ("--drop-bad-views",), scan="nan"),
    "--outliers": Case(CHANGES, ("--outliers", "3")),
    "--outlier-size": Case(CHANGES, ("--outlier-size", "5"), base=("--outliers", "3")),
    "--outlier-kind": Case(CHANGES, ("--outlier-kind", "dark"), base=("--outliers", "3")),
    "--open-beam": Case(CHANGES, ("--open-beam",)),
    "--air-columns": Case(CHANGES, AIR, base=("--open-beam",)),  # instead of the air found
    "--open-beam-degree": Case(CHANGES, ("--open-beam-degree", "0"), base=("--open-beam",)),
    # a later value of an option replaces the earlier one: each Paganin value changed in a whole set
    "--delta-beta": Case(CHANGES, ("--delta-beta", "10"), base=PAGANIN),
    "--energy-kev": Case(CHANGES, ("--energy-kev", "40"), base=PAGANIN),
    "--distance-m": Case(CHANGES, ("--distance-m", "2"), base=PAGANIN),
    "--pixel-size-m": Case(CHANGES, ("--pixel-size-m", "3e-6"), base=PAGANIN),
    "--stripes": Case(CHANGES, ("--stripes", "sorting")),
    "--stripe-params": Case(CHANGES, ("--stripe-params", "size=5"), base=("--stripes", "sorting")),
    "--quiet": Case(CHANGES, ("-q",)),
}

#: A reading or correction option of ``stack``: as for ``import`` on a scan file (``store``, ``stream``),
#: refused on a data set; ``READ_NOT_STREAMED`` is refused when streaming too.
READ, READ_NOT_STREAMED = "read", "read, not streamed"
READ_OPTIONS = (
    "--format", "--angles", "--angles-select", "--radians", "--angles-units", "--data-path", "--image-key-path",
    "--angles-path", "--allow-outside", "--tilt-axis", "--flats", "--darks", "--line-integrals", "--rows", "--entry",
)  # fmt: skip
NOT_STREAMED_OPTIONS = (
    "--crop", "--outliers", "--outlier-size", "--outlier-kind", "--open-beam", "--air-columns", "--open-beam-degree",
    "--delta-beta", "--energy-kev", "--distance-m", "--pixel-size-m", "--stripes", "--stripe-params",
)  # fmt: skip
#: ``--refine auto`` runs the autofocus on the wide scan (about 20 s): each is tried from ``--refine 2,1``.
REFINED = {"scan": "wide", "base": ("--refine", "2,1")}
NO_CLUSTER = "where the work runs (local processes or a Dask scheduler), not what it computes"
STACK: dict[str, Any] = {
    "SOURCE": Case(REQUIRED, ("stack", "--store", "{t}/new")),
    "--store": {
        "dataset": Case(REFUSED, ("--store", "{t}/new"), message="--store: for a scan file"),
        "store": Case(REQUIRED, ("stack", "{s}/scan.nxs")),
        "stream": Case(REFUSED, ("--store", "{t}/new"), message="not both"),
    },
    "--out": {
        "dataset": Case(REFUSED, ("--out", "{t}/new.zarr"), message="--out: for a scan file"),
        "store": Case(REFUSED, ("--out", "{t}/new.zarr"), message="not both"),
        "stream": Case(REQUIRED, ("stack", "{s}/scan.nxs")),
    },
    "--block": {
        "dataset": Case(REFUSED, ("--block", "4"), message="--block: for a scan file"),
        "store": Case(REFUSED, ("--block", "4"), message="--block goes with --out"),
        "stream": Case(CHANGES, ("--block", "4")),
    },
    "--method": {
        "dataset": Case(CHANGES, ("--method", "dremel")),
        "store": Case(CHANGES, ("--method", "dremel")),
        "stream": Case(REFUSED, ("--method", "dremel"), message="streaming with --out runs fbp or gridrec"),
    },
    "--eta": {
        "dataset": Case(CHANGES, ("--eta", "0.01"), base=("--method", "resesop")),
        "store": Case(CHANGES, ("--eta", "0.01"), base=("--method", "resesop")),
        "stream": Case(REFUSED, ("--eta", "0.01"), message="RESESOP's uncertainty level"),
    },
    "--center-offset": Case(CHANGES, ("--center-offset", "0.5")),
    "--motion-slices": Case(CHANGES, ("--motion-slices", "0,1")),
    "--dremel-binning": Case(CHANGES, ("--dremel-binning", "2"), **REFINED),
    "--binning": Case(CHANGES, ("--binning", "2"), **REFINED),  # the former spelling of --dremel-binning (hidden)
    "--coarse-iter": Case(CHANGES, ("--coarse-iter", "2"), **REFINED),
    "--refine": Case(CHANGES, ("--refine", "1"), **REFINED),
    "--model": Case(CHANGES, ("--model", "2,1")),
    "--name": {
        "dataset": Case(CHANGES, ("--name", "other")),
        "store": Case(CHANGES, ("--name", "other")),
        "stream": Case(REFUSED, ("--name", "other"), message="not applied when streaming"),
    },
    "--overwrite": Case(CHANGES, ("--overwrite",), prepare=("--center-offset", "0.5")),
    **dict.fromkeys(READ_OPTIONS, READ),
    **dict.fromkeys(NOT_STREAMED_OPTIONS, READ_NOT_STREAMED),
    "--workers": Case(NOOP, message=NO_CLUSTER),
    "--scheduler": Case(NOOP, message=NO_CLUSTER),
    "--quiet": Case(CHANGES, ("-q",)),  # no progress bars
}
#: ``store`` runs the import of ``import`` and then the stack of ``dataset``: the slowest third of the walk
MODES = ("dataset", pytest.param("store", marks=pytest.mark.slow), "stream")


def _options(command: str) -> list[str]:
    """The parameters of a command as the user writes them: each option's long flag, an argument's NAME."""
    click_command = typer.main.get_command(app).commands[command]  # type: ignore[attr-defined]
    names = []
    for param in click_command.params:
        flags = [o for o in param.opts if o.startswith("--")] if param.param_type_name == "option" else []
        names.append(flags[0] if flags else param.name.upper())
    return names


def _stack_case(option: str, mode: str) -> Case:
    """What :data:`STACK` says of ``option`` in ``mode``."""
    entry = STACK[option]
    if isinstance(entry, Case):
        return entry
    if isinstance(entry, dict):
        return entry[mode]
    imported = IMPORT[option]
    if mode == "dataset":  # refused whatever the scan: the data set is already imported
        return Case(REFUSED, imported.args, message="options apply when importing")
    if mode == "stream" and entry == READ_NOT_STREAMED:  # alone: the base may hold another one
        return replace(imported, expect=REFUSED, base=(), message="not applied when streaming")
    return imported


def test_every_option_is_classified():
    assert sorted(_options("import")) == sorted(IMPORT)
    assert sorted(_options("stack")) == sorted(STACK)
    for option, entry in STACK.items():
        assert entry not in (READ, READ_NOT_STREAMED) or option in IMPORT, option


def _discs(phi: np.ndarray, shifts: np.ndarray) -> np.ndarray:
    """``(K, R, L)`` line integrals of three discs (each row its own densities), moved by ``shifts``: air beside
    them in every view."""
    x = np.arange(L) - (L - 1) / 2
    lines = np.zeros((K, R, L))
    for i, (a, b, radius, density) in enumerate([(0.0, 0.0, 9.0, 0.05), (4.0, -3.0, 3.0, 0.1), (-3.0, 4.0, 2.0, 0.15)]):
        centre = a * np.cos(phi) + b * np.sin(phi) + shifts  # (K,)
        chord = 2 * np.sqrt(np.clip(radius**2 - (x[None, :] - centre[:, None]) ** 2, 0, None))  # (K, L)
        lines += density * (1 + 0.1 * i * np.arange(R))[None, :, None] * chord[:, None, :]
    return lines


def _write_scans(folder: Path) -> None:
    """The files of :data:`SCANS`."""
    phi = np.arange(K) * np.pi / K
    shifts, _ = known_motion(phi, seed=1)
    lines = _discs(phi, shifts)
    noise = np.random.default_rng(0).normal(0, 3, lines.shape)  # measured data are noisy (air is found so)
    proj = (20 + 980 * np.exp(-lines) + noise).astype(np.float32)
    proj[5, 3, 10] = 3000.0  # a zinger
    flats, darks = np.full((2, R, L), 1000, np.float32), np.full((2, R, L), 20, np.float32)
    np.save(folder / "scan.npy", proj)
    dead = proj.copy()
    dead[7, 2, 20] = 0.0  # a dead pixel: below the dark
    np.save(folder / "dead.npy", dead)
    np.save(folder / "flats.npy", flats)
    np.save(folder / "darks.npy", darks)
    bad = proj.copy()
    bad[4, 0, 0] = np.nan
    np.save(folder / "nan.npy", bad)
    deg = np.rad2deg(phi)
    np.save(folder / "lines.npy", lines.astype(np.float32))
    np.savetxt(folder / "angles.txt", deg)
    np.savetxt(folder / "angles26.txt", np.r_[0.0, 0.0, deg])
    np.savetxt(folder / "angles_rad.txt", phi)
    frames = np.concatenate([darks[:1], flats[:1], proj])
    with h5py.File(folder / "frames.h5", "w") as f:
        f["data"] = frames
    (folder / "linked").mkdir()
    for path, data in ((folder / "scan.nxs", frames), (folder / "linked" / "scan.nxs", None)):
        with h5py.File(path, "w") as f:
            f[DATA] = data if data is not None else h5py.ExternalLink("../frames.h5", "/data")
            f[KEYS] = np.r_[2, 1, np.zeros(K, int)]
            f[ANGLES] = np.r_[0.0, 0.0, deg]
    x = np.arange(L) - (L - 1) / 2  # an elliptic slab 80 px long: no air in any view, its mass varies
    s2 = (40 * np.cos(phi)) ** 2 + (12 * np.sin(phi)) ** 2
    chord = 2 * 40 * 12 * np.sqrt(np.clip(s2[:, None] - x[None, :] ** 2, 0, None)) / s2[:, None]
    wide = analytic_projections(phi, L, R, center=0.0) + 0.01 * chord[:, None, :]
    np.save(folder / "wide.npy", np.exp(-wide).astype(np.float32))
    import mrcfile

    with mrcfile.new(folder / "tilt.mrc") as mrc:
        mrc.set_data(lines.astype(np.float32))
    np.savetxt(folder / "tilt.rawtlt", np.linspace(-57.5, 57.5, K))


@pytest.fixture(scope="module")
def scans(tmp_path_factory) -> Path:
    """The scans of :data:`SCANS`, and data sets imported from the ``nxs`` and ``wide`` ones (``<scan>.ds``)."""
    folder = tmp_path_factory.mktemp("scans")
    _write_scans(folder)
    for scan in ("nxs", "wide"):
        argv = [a.replace("{s}", str(folder)) for a in SCANS[scan]]
        assert run(["import", argv[0], "--out", str(folder / f"{scan}.ds"), "-q", *argv[1:]]) == 0
    return folder


def _argv(mode: str, case: Case, scans: Path, out: Path, extra: tuple[str, ...]) -> list[str]:
    """The command line of ``case`` in ``mode`` (``import`` or a stack mode) writing to ``out``."""
    scan = list(SCANS[case.scan])
    if mode == "import":
        argv = ["import", scan[0], "--out", f"{out}/data", *scan[1:]]
    elif mode == "dataset":
        if not (out / "ds").exists():
            shutil.copytree(scans / f"{case.scan}.ds", out / "ds")
        argv = ["stack", f"{out}/ds", "-w", "0"]
    else:
        where = ["--store", f"{out}/store"] if mode == "store" else ["--out", f"{out}/slices.zarr"]
        argv = ["stack", scan[0], *where, *scan[1:], "-w", "0"]
    return [a.replace("{s}", str(scans)).replace("{t}", str(out)) for a in (*argv, *case.base, *extra)]


def _contents(out: Path) -> dict[str, Any]:
    """What a run left under ``out``: data sets (sinograms, geometry, scan record, reconstructions and their
    motion) and streamed slices (images and attributes)."""
    import zarr

    found: dict[str, Any] = {}
    for name in ("data", "ds", "store"):
        if (out / name / "zarr.json").is_file():
            store = DataStore.open(out / name)
            found[name] = {"sinograms": store.read_array("sinograms", range(store.n)), "geometry": store.geometry,
                           "scan": json.dumps(store.meta.get("scan"), sort_keys=True)}  # fmt: skip
            for recon in store.reconstruction_names():
                found[name][recon] = (store.read_reconstruction(recon), store.recons.shared_shifts(recon),
                                      json.dumps(store.recons.motion_info(recon), sort_keys=True))  # fmt: skip
    if (out / "slices.zarr").exists():
        group = zarr.open_group(str(out / "slices.zarr"), mode="r")
        found["slices"] = (group["slices"][:], json.dumps(dict(group.attrs), sort_keys=True))
    return found


def _outcome(argv: list[str], out: Path, capsys) -> dict[str, Any]:
    """Exit status, what was printed (paths under ``out`` as ``OUT``), whether progress was shown, what was written."""
    code = run(argv)
    captured = capsys.readouterr()
    err = captured.err.replace(str(out), "OUT")
    return {
        "code": code,
        "stdout": captured.out.replace(str(out), "OUT"),
        "lines": [line for line in err.splitlines() if line.startswith(("error:", "warning:", "note:"))],
        "progress": "%|" in err,
        "written": _contents(out) if code == 0 else None,
        "err": err,
    }


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (tuple, list)) and isinstance(b, (tuple, list)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.shape(a) == np.shape(b) and np.allclose(a, b, rtol=1e-6, atol=1e-9, equal_nan=True)
    return a == b


_BASES: dict[tuple, dict[str, Any]] = {}  # the outcome without the option, per mode, scan and base arguments


def _refusal(result: dict[str, Any]) -> str:
    """The one ``error:`` line of a refused run (exit status 2, no traceback, the error line last)."""
    lines = [line for line in result["err"].splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error:")]
    assert result["code"] == 2 and errors == lines[-1:] and "Traceback" not in result["err"], result["err"]
    return errors[0]


def _base(mode: str, case: Case, scans: Path, folder: Path, capsys) -> dict[str, Any]:
    """The outcome of ``case`` without its option (made once per mode, scan and base arguments)."""
    folder.mkdir()
    if case.prepare is not None:
        assert run(_argv(mode, case, scans, folder, case.prepare)) == 0
        return _outcome(_argv(mode, case, scans, folder, ()), folder, capsys)
    key = (mode, case.scan, case.base)
    if key not in _BASES:
        _BASES[key] = _outcome(_argv(mode, case, scans, folder, ()), folder, capsys)
    return _BASES[key]


def _check(mode: str, option: str, case: Case, scans: Path, tmp_path: Path, capsys) -> None:
    """Run ``case`` in ``mode`` (``import`` or a stack mode) and check what :data:`IMPORT` / :data:`STACK` say."""
    if case.expect == NOOP:
        assert case.message, f"{option}: a no-op needs its reason"
        return
    if case.expect == REQUIRED:
        argv = [a.replace("{s}", str(scans)).replace("{t}", str(tmp_path)) for a in case.args]
        _refusal(_outcome(argv, tmp_path, capsys))
        assert list(tmp_path.iterdir()) == [], f"{option}: a refusal wrote files"
        return
    base = _base(mode, case, scans, tmp_path / "base", capsys)
    out = tmp_path / "with"
    out.mkdir()
    if case.prepare is not None:
        assert run(_argv(mode, case, scans, out, case.prepare)) == 0
    argv = _argv(mode, case, scans, out, case.args)
    before = sorted(out.rglob("*"))
    result = _outcome(argv, out, capsys)
    if case.expect == CHANGES:
        assert result["code"] == 0, (option, result["err"])
        drop = {"err"}  # progress bars and timings: compared as "progress" and the lines
        assert not _same(
            {k: v for k, v in result.items() if k not in drop}, {k: v for k, v in base.items() if k not in drop}
        ), f"{option} {case.args} changed nothing ({mode})"
        return
    assert base["code"] == 0, (option, "refused without the option too", base["err"])
    assert case.message in _refusal(result), (option, result["err"])
    assert sorted(out.rglob("*")) == before, f"{option}: a refusal wrote files"


@pytest.mark.parametrize("option", list(IMPORT))
def test_import_option(option, scans, tmp_path, capsys):
    _check("import", option, IMPORT[option], scans, tmp_path, capsys)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("option", list(STACK))
def test_stack_option(option, mode, scans, tmp_path, capsys):
    if mode == "stream":
        pytest.importorskip("finufft")  # streaming runs gridrec
    _check(mode, option, _stack_case(option, mode), scans, tmp_path, capsys)


def _one_error(argv: list[str], scans: Path, tmp_path: Path, capsys) -> str:
    """The error line of a refused command ({s}: the scans, {t}: ``tmp_path``), checked: exit status 2, one
    ``error:`` line, nothing written."""
    before = sorted(tmp_path.rglob("*"))
    line = _refusal(
        _outcome([a.replace("{s}", str(scans)).replace("{t}", str(tmp_path)) for a in argv], tmp_path, capsys)
    )
    assert sorted(tmp_path.rglob("*")) == before, "a refusal wrote files"
    return line


NXS_INTO = {
    "import": ["import", "{s}/scan.nxs", "--out", "{t}/new"],
    "store": ["stack", "{s}/scan.nxs", "--store", "{t}/new", "-w", "0"],
    "stream": ["stack", "{s}/scan.nxs", "--out", "{t}/new.zarr", "-w", "0"],
}


@pytest.mark.parametrize(
    ("into", "value", "line"),
    [
        ("import", ["--rows", "5000:5001"], "--rows 5000:5001: the scan has 8 detector rows (0:8)"),
        ("store", ["--rows", "5000:5001"], "--rows 5000:5001: the scan has 8 detector rows (0:8)"),
        ("stream", ["--rows", "5000:5001"], "--rows 5000:5001: the scan has 8 detector rows (0:8)"),
        ("stream", ["--rows", "3:9"], "--rows 3:9: the scan has 8 detector rows (0:8)"),
        ("import", ["--crop", "0,500"], "--crop 0,500: the scan has 32 detector columns (0,32)"),
        ("store", ["--crop", "30,33"], "--crop 30,33: the scan has 32 detector columns (0,32)"),
        (
            "import",
            ["--open-beam", "--air-columns", "0:3,30:40"],
            "--air-columns 30:40: the detector has 32 columns (0:32)",
        ),
        (
            "import",
            ["--crop", "2,30", "--open-beam", "--air-columns", "0:3,27:29"],
            "--air-columns 27:29: the detector read",
        ),
        (
            "stream",
            ["--motion-slices", "0,9"],
            "--motion-slices 0,9: rows of the selection, counted from its first; it has 8",
        ),
    ],
)
def test_a_selection_outside_the_scan_names_the_flag_the_value_and_the_range(
    scans, tmp_path, capsys, into, value, line
):
    """Refused with one line once the file's shape is read, by import and by both ways stack reads a scan file."""
    assert _one_error([*NXS_INTO[into], *value], scans, tmp_path, capsys).startswith(f"error: {line}")


def test_angles_select_beyond_the_angles_file(scans, tmp_path, capsys):
    argv = ["import", *SCANS["npy"], *FLATS, *DARKS, "--out", "{t}/new", "--angles-select", "0:99"]
    line = _one_error(argv, scans, tmp_path, capsys)
    assert line == f"error: --angles-select 0:99: the angles file {scans}/angles.txt has 24 values (0:24)"


def test_reading_options_on_a_data_set_name_the_import_that_applies_them(scans, tmp_path, capsys):
    """One line: the flags (in the order of the command's options), and the import command with their values."""
    shutil.copytree(scans / "nxs.ds", tmp_path / "ds")
    argv = ["stack", "{t}/ds", "--rows", "5000:5001", "--open-beam", "--allow-outside", "/a", "--allow-outside", "/b"]
    assert _one_error(argv, scans, tmp_path, capsys) == (  # paths under tmp_path read OUT
        "error: --allow-outside, --rows, --open-beam: reading and correction options apply when importing; the data "
        f"set OUT/ds is already imported: use nanoct import {scans}/scan.nxs --out NEW_DIR --allow-outside /a "
        "--allow-outside /b --rows 5000:5001 --open-beam (or give stack the scan file with --store NEW_DIR or --out "
        "OUT.zarr)"
    )


#: Options the file or the other options leave unused: each refused (the walk above gives each once alone).
UNUSED = {
    "flats of an HDF5 scan": (["import", "{s}/scan.nxs", *FLATS], "--flats: for TIFF and .npy scans"),
    "flats with line integrals": (
        ["import", *SCANS["lines"], *FLATS, "--line-integrals"],
        "--flats: --line-integrals takes no flat/dark",
    ),
    "tilt axis of a .npy": (["import", *SCANS["npy"], *FLATS, "--tilt-axis", "rows"], "--tilt-axis rows: for MRC"),
    "links of a .npy": (["import", *SCANS["npy"], *FLATS, "--allow-outside", "{s}"], "--allow-outside: for HDF5"),
    "select without a file": (["import", "{s}/scan.nxs", "--angles-select", "0:9"], "no --angles is given"),
    "select of evenly spaced": (["import", "{s}/scan.nxs", "--angles", "0:180", "--angles-select", "0:9"], "evenly"),
    "radians without a file": (["import", "{s}/scan.nxs", "--radians"], "--radians: the unit of an --angles text"),
    "radians and units": (["import", *SCANS["npy-rad"], "--radians", "--angles-units", "rad"], "give one"),
    "outlier size alone": (["import", "{s}/scan.nxs", "--outlier-size", "5"], "used only with --outliers"),
    "outlier kind alone": (["stack", "{s}/scan.nxs", "--store", "{t}/s", "--outlier-kind", "dark"], "--outliers"),
    "degree alone": (["import", "{s}/scan.nxs", "--open-beam-degree", "1"], "used only with --open-beam"),
    "tolerance of line integrals": (
        ["import", *SCANS["lines"], "--line-integrals", "--tolerance", "0.01"],
        "--tolerance 0.01: for the flat/dark",
    ),
    "eta without resesop": (["stack", "{s}/nxs.ds", "--eta", "0.1"], "used only with --method resesop"),
    "store for a data set": (["stack", "{s}/nxs.ds", "--store", "{t}/s"], "--store: for a scan file"),
    "a correction when streaming": (
        ["stack", "{s}/scan.nxs", "--out", "{t}/o.zarr", "--open-beam-degree", "1"],
        "--open-beam-degree: not applied",
    ),
}


@pytest.mark.parametrize("case", list(UNUSED))
def test_an_option_left_unused_is_refused(scans, tmp_path, capsys, case):
    args, message = UNUSED[case]
    argv = [*args, "--out", "{t}/new"] if args[0] == "import" else [*args, "-w", "0"]
    assert message in _one_error(argv, scans, tmp_path, capsys)
