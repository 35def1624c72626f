"""A catalogue of bad inputs and damaged stores run through the CLI.

Each case must end with exit status 2, exactly one ``error:`` line, no traceback, nothing new
left on disk, and (for damaged data) no result printed as if it were valid. The stores are
built once per module and copied for every case.
"""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
import uuid
from pathlib import Path

import numpy as np
import pytest

from nanoct.cli import run
from nanoct.cli.entry import expected_error
from nanoct.core.geometry import get_preset
from nanoct.io.store import DataStore
from nanoct.learn.train import TrainConfig, train
from nanoct.recon.batch import reconstruct_dataset
from nanoct.sim.generate import generate_dataset

SMALL = {"channels": [4, 4, 8, 8, 16]}


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """par: tiny-parallel, 6 samples, fbp; fan: tiny-fan, 3 samples, fbp; run: a UNet trained on par/fbp."""
    root = tmp_path_factory.mktemp("catalogue")
    fractions = (0.5, 0.25, 0.25)
    generate_dataset(root / "par", get_preset("tiny-parallel"), 6, workers=0, progress=False, split_fractions=fractions)
    generate_dataset(root / "fan", get_preset("tiny-fan"), 4, workers=0, progress=False, split_fractions=fractions)
    for d in ("par", "fan"):
        reconstruct_dataset(root / d, "fbp", workers=0, progress=False)
    train(
        root / "par",
        root / "run",
        TrainConfig("unet", "fbp", epochs=1, batch_size=2, model_kwargs=SMALL),
        progress=False,
    )
    (root / "afile").write_text("not a directory")
    return root


@pytest.fixture
def work(base, tmp_path):
    """A fresh copy of the module's stores and run for one case."""
    for name in ("par", "fan", "run"):
        shutil.copytree(base / name, tmp_path / name)
    shutil.copy(base / "afile", tmp_path / "afile")
    return tmp_path


def _listing(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")}


def _chunk(store: Path, array: str, index: int) -> Path:
    """The chunk file of sample ``index`` of a per-sample array (Zarr v3 default key encoding)."""
    ndim = len(json.loads((store / array / "zarr.json").read_text())["shape"])
    return (
        store / array / "c" / str(index) / Path(*["0"] * (ndim - 1)) if ndim > 1 else store / array / "c" / str(index)
    )


def _cli(capsys, args: list[str]) -> tuple[int, str, str]:
    code = run([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def _check_error(code: int, out: str, err: str, expect: str) -> None:
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, (code, out, err)
    assert [line for line in lines if line.startswith("error:")] == lines[-1:], err
    assert len([line for line in lines if line.startswith("error:")]) == 1, err
    assert "Traceback" not in out + err, err
    assert expect.lower() in err.lower(), err


BAD_ARGS = {
    "out is a file": (["generate", "-p", "tiny-parallel", "--n", 2, "--out", "{w}/afile"], "is a file"),
    "n zero": (["generate", "-p", "tiny-parallel", "--n", 0, "--out", "{w}/new"], "--n 0"),
    "n negative": (["generate", "-p", "tiny-parallel", "--n", -3, "--out", "{w}/new"], "--n -3"),
    "n absurd": (["generate", "-p", "tiny-parallel", "--n", 10**15, "--out", "{w}/new"], "memory"),
    "max shift negative": (
        ["generate", "-p", "tiny-parallel", "--n", 2, "--out", "{w}/new", "--max-shift", -1],
        "--max-shift",
    ),
    "max shift nan": (
        ["generate", "-p", "tiny-parallel", "--n", 2, "--out", "{w}/new", "--max-shift", "nan"],
        "--max-shift",
    ),
    "noise nan": (
        ["generate", "-p", "tiny-parallel", "--n", 2, "--out", "{w}/new", "--noise-std", "nan"],
        "--noise-std",
    ),
    "oversample zero": (
        ["generate", "-p", "tiny-parallel", "--n", 2, "--out", "{w}/new", "--oversample", 0],
        "--oversample",
    ),
    "fractions two": (
        ["generate", "-p", "tiny-parallel", "--n", 2, "--out", "{w}/new", "--split-fractions", "0.5,0.5"],
        "--split-fractions",
    ),
    "fractions sum": (
        ["generate", "-p", "tiny-parallel", "--n", 2, "--out", "{w}/new", "--split-fractions", "0.5,0.5,0.5"],
        "--split-fractions",
    ),
    "unknown preset": (["generate", "-p", "huge-cone", "--n", 2, "--out", "{w}/new"], "huge-cone"),
    "negative seed": (["generate", "-p", "tiny-parallel", "--n", 2, "--out", "{w}/new", "--seed", -1], "--seed"),
    "negative workers": (["generate", "-p", "tiny-parallel", "--n", 2, "--out", "{w}/new", "-w", -1], "--workers"),
    "other data set": (["generate", "-p", "tiny-parallel", "--n", 7, "--out", "{w}/par", "-w", 0], "different"),
    "out is another dir": (["generate", "-p", "tiny-parallel", "--n", 2, "--out", "{w}/run", "-w", 0], "not a nanoct"),
    "name with slash": (["reconstruct", "{w}/par", "-m", "fbp", "--name", "sub/fbp", "-w", 0], "--name"),
    "name with dot": (["reconstruct", "{w}/par", "-m", "fbp", "--name", ".hidden", "-w", 0], "--name"),
    "name dotdot": (["reconstruct", "{w}/par", "-m", "fbp", "--name", "../phantoms", "-w", 0], "--name"),
    "name empty": (["reconstruct", "{w}/par", "-m", "fbp", "--name", "", "-w", 0], "--name"),
    "name backslash": (["reconstruct", "{w}/par", "-m", "fbp", "--name", "a\\b", "-w", 0], "--name"),
    "name with space": (["reconstruct", "{w}/par", "-m", "fbp", "--name", "fbp new", "-w", 0], "no spaces"),
    "name shifts": (["reconstruct", "{w}/par", "-m", "fbp", "--name", "x_shifts", "-w", 0], "_shifts"),
    "unknown method": (["reconstruct", "{w}/par", "-m", "sart", "-w", 0], "sart"),
    "unknown split": (["reconstruct", "{w}/par", "-m", "fbp", "--split", "holdout", "-w", 0], "holdout"),
    "eta scale without resesop": (["reconstruct", "{w}/par", "-m", "fbp", "--eta-scale", 2, "-w", 0], "--eta-scale"),
    "no store": (["reconstruct", "{w}/missing", "-m", "fbp", "-w", 0], "no nanoct data set"),
    "store is a file": (["info", "{w}/afile"], "no nanoct data set"),
    "info on a run dir": (["info", "{w}/run"], "no nanoct data set"),
    "show index": (["show", "{w}/par", "--index", 99, "--out", "{w}/x.png"], "--index 99"),
    "evaluate split": (["evaluate", "{w}/par", "--split", "holdout"], "holdout"),
    "evaluate out is a file": (["evaluate", "{w}/par", "--out", "{w}/afile"], "afile"),
    "train device": (["train", "{w}/par", "-i", "fbp", "--device", "gpu0", "--out", "{w}/r2"], "--device"),
    "train missing input": (["train", "{w}/par", "-i", "dremel", "--out", "{w}/r2", "--epochs", 1], "dremel"),
    "predict device": (["predict", "{w}/par", "--run", "{w}/run", "--device", "gpu0"], "--device"),
    "predict missing run": (["predict", "{w}/par", "--run", "{w}/norun"], "norun"),
    "predict samples": (["predict", "{w}/par", "--run", "{w}/run", "-M", 0], "--samples"),
    "predict name slash": (["predict", "{w}/par", "--run", "{w}/run", "--name", "a/b"], "--name 'a/b'"),
    "predict name empty": (["predict", "{w}/par", "--run", "{w}/run", "--name", ""], "--name ''"),
    "predict levels empty item": (["predict", "{w}/par", "--run", "{w}/run", "--levels", "0.9,,0.95"], "--levels"),
    "predict tile too large": (["predict", "{w}/par", "--run", "{w}/run", "--tile", 500], "--tile 500 is larger"),
    "train lr inf": (["train", "{w}/par", "-i", "fbp", "--out", "{w}/r2", "--lr", "inf"], "lr (inf)"),
    "train param typo": (
        ["train", "{w}/par", "-i", "fbp", "--out", "{w}/r2", "--param", "chanels=[4,4,8,8,16]"],
        "no parameter chanels; its parameters are",
    ),
    "stack missing path": (["stack", "{w}/scna", "-w", 0], "scna does not exist"),
    "train negative seed": (["train", "{w}/par", "-i", "fbp", "--out", "{w}/r2", "--seed", -5], "--seed -5"),
    "predict other geometry": (["predict", "{w}/fan", "--run", "{w}/run", "--device", "cpu"], "geometry"),
    "predict calibrate-on": (
        ["predict", "{w}/par", "--run", "{w}/run", "--calibrate-on", "{w}/nothere"],
        "--calibrate-on",
    ),
    "reproduce n zero": (["reproduce", "--n", 0, "--out", "{w}/study", "--models", "none", "-q"], "--n 0"),
    "reproduce preset": (["reproduce", "-p", "huge-cone", "--out", "{w}/study", "-q"], "huge-cone"),
    "scaling sizes": (["scaling", "--sizes", "160,x", "--out", "{w}/scaling", "-q"], "--sizes"),
    "scaling seeds": (["scaling", "--seeds", "3,2", "--out", "{w}/scaling", "-q"], "same length"),
    "scaling steps": (["scaling", "--steps", 0, "--out", "{w}/scaling", "-q"], "steps 0"),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", list(BAD_ARGS))
def test_bad_arguments(work, capsys, case):
    args, expect = BAD_ARGS[case]
    before = _listing(work)
    code, out, err = _cli(capsys, [str(a).replace("{w}", str(work)) for a in args])
    _check_error(code, out, err, expect)
    assert _listing(work) == before, sorted(_listing(work) ^ before)


# usage errors that click (vendored by typer as typer._click since 0.29) raises before a command runs
USAGE = {
    "unknown option": (["reconstruct", "{w}", "--bogus"], "no such option: --bogus"),
    "misspelt option": (["reconstruct", "{w}", "--metod", "fbp"], "--method"),
    "unknown command": (["frobnicate"], "no such command 'frobnicate'"),
    "misspelt command": (["genrate"], "did you mean 'generate'"),
    "missing argument": (["reconstruct"], "missing argument 'directory'"),
    "missing option": (["reconstruct", "{w}"], "missing option '--method'"),
    "missing option value": (["train", "{w}", "-i", "fbp", "--precision"], "requires an argument"),
    "bad integer": (["generate", "--n", "abc", "-p", "tiny-parallel", "-o", "{w}/new"], "'--n'"),
    "bad float": (["train", "{w}", "-i", "fbp", "--lr", "fast"], "'--lr'"),
    "flag with a value": (["info", "{w}", "--json=3"], "does not take a value"),
    "extra argument": (["info", "{w}", "{w}"], "unexpected extra argument"),
    "unknown top-level option": (["--bogus"], "no such option: --bogus"),
}


@pytest.mark.parametrize("case", list(USAGE))
def test_usage_errors(tmp_path, capsys, case):
    args, expect = USAGE[case]
    code, out, err = _cli(capsys, [a.replace("{w}", str(tmp_path)) for a in args])
    _check_error(code, out, err, expect)
    assert out == "" and list(tmp_path.iterdir()) == []


def test_version(capsys):
    from nanoct import __version__

    assert _cli(capsys, ["--version"]) == (0, f"nanoct {__version__}\n", "")


def test_no_arguments_print_the_help(capsys):
    code, out, err = _cli(capsys, [])
    assert code == 2 and "Usage: nanoct" in out + err and "Traceback" not in out + err


def test_help_shows_no_type_after_flags(capsys):
    code, out, _ = _cli(capsys, ["reconstruct", "--help"])
    assert code == 0 and "-q, --quiet" in out and "--overwrite " in out
    assert "<bool>" not in out


def _delete(path: Path) -> None:
    path.unlink()


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[:7])


def _edit_meta(store: Path, change) -> None:
    meta = json.loads((store / "zarr.json").read_text())
    change(meta["attributes"]["nanoct"])
    (store / "zarr.json").write_text(json.dumps(meta))


def _test_index(store: Path) -> int:
    return int(DataStore.open(store).indices("test")[0])


DAMAGE = {
    "phantom chunk deleted": (lambda s: _delete(_chunk(s, "phantoms", _test_index(s))), ["evaluate"], "phantoms"),
    "phantom chunk truncated": (lambda s: _truncate(_chunk(s, "phantoms", _test_index(s))), ["evaluate"], "unreadable"),
    "recon chunk deleted": (
        lambda s: _delete(_chunk(s, "reconstructions/fbp", _test_index(s))),
        ["evaluate"],
        "nanoct reconstruct",
    ),
    "recon chunk garbled": (
        lambda s: _chunk(s, "reconstructions/fbp", _test_index(s)).write_bytes(b"\x00" * 64),
        ["evaluate"],
        "reconstructions/fbp",
    ),
    "sinogram chunk deleted (show)": (lambda s: _delete(_chunk(s, "sinograms", 0)), ["show", "--out", "x.png"], "sino"),
    "eta chunk deleted (check)": (lambda s: _delete(_chunk(s, "eta", 1)), ["info", "--check"], "samples: 1"),
    "recon chunk deleted (check)": (
        lambda s: _delete(_chunk(s, "reconstructions/fbp", 2)),
        ["info", "--check"],
        "reconstructions/fbp",
    ),
    "n edited": (lambda s: _edit_meta(s, lambda m: m.update(n=8)), ["info"], "edited"),
    "geometry N edited": (lambda s: _edit_meta(s, lambda m: m["geometry"].update(n=127)), ["info"], "edited"),
    "geometry garbled": (lambda s: _edit_meta(s, lambda m: m.update(geometry="x")), ["info"], "damaged"),
    "old format": (lambda s: _edit_meta(s, lambda m: m.update(format=1)), ["info"], "older nanoct"),
    "root metadata garbled": (lambda s: (s / "zarr.json").write_text("{"), ["info"], "damaged"),
    "array missing": (lambda s: shutil.rmtree(s / "sinograms"), ["info"], "'sinograms' is missing"),
    "split chunk deleted": (lambda s: _delete(s / "split" / "c" / "0"), ["info"], "split"),
    "progress chunk garbled": (lambda s: (s / "progress" / "fbp" / "c" / "0").write_bytes(b"xx"), ["info"], "flags"),
}


@pytest.mark.parametrize("case", list(DAMAGE))
def test_damaged_store(work, capsys, case):
    damage, command, expect = DAMAGE[case]
    store = work / "par"
    damage(store)
    before = _listing(work)
    args = [command[0], store, *(str(work / a) if a.endswith(".png") else a for a in command[1:])]
    code, out, err = _cli(capsys, args)
    _check_error(code, out, err, expect)
    if command[0] != "info":  # info prints the summary it could read; nothing else prints a result
        assert out == "", out
    assert _listing(work) == before, sorted(_listing(work) ^ before)


def test_check_lists_damage_and_rerun_repairs(work, capsys):
    store = work / "par"
    code, out, _ = _cli(capsys, ["info", store, "--check"])
    assert code == 0 and "no damaged samples" in out
    fbp = DataStore.open(store).read_reconstruction("fbp")
    sino = _chunk(store, "sinograms", 1)
    good = sino.read_bytes()
    sino.unlink()
    _truncate(_chunk(store, "reconstructions/fbp", 4))
    code, out, err = _cli(capsys, ["info", store, "--check", "--json"])
    assert code == 2 and json.loads(out)["damaged"] == {"samples": [1], "reconstructions/fbp": [4]}
    code, _, err = _cli(capsys, ["show", store, "--index", 1, "--out", work / "x.png"])
    assert code == 2 and "run 'nanoct generate' again" in err
    code, _, err = _cli(capsys, ["evaluate", store, "--split", "all"])  # names the undecodable chunk file
    garbled = _chunk(store, "reconstructions/fbp", 4)
    assert code == 2 and f"delete {garbled} and run 'nanoct reconstruct' again" in err
    garbled.unlink()
    code, _, _ = _cli(
        capsys,
        [
            "generate",
            "-p",
            "tiny-parallel",
            "--n",
            6,
            "--out",
            store,
            "-w",
            0,
            "-q",
            "--split-fractions",
            "0.5,0.25,0.25",
        ],
    )
    assert code == 0 and sino.read_bytes() == good  # the same bytes again
    code, _, _ = _cli(capsys, ["reconstruct", store, "-m", "fbp", "-w", 0, "-q"])
    assert code == 0
    np.testing.assert_array_equal(DataStore.open(store).read_reconstruction("fbp"), fbp)
    code, out, _ = _cli(capsys, ["info", store, "--check"])
    assert code == 0 and "no damaged samples" in out


def test_prediction_follows_its_input(work, capsys):
    store, run_dir = work / "par", work / "run"
    assert _cli(capsys, ["predict", store, "--run", run_dir, "--device", "cpu", "-q"])[0] == 0
    made_from = DataStore.open(store).reconstruction_params("fbp+unet")
    assert made_from["geometry"] == get_preset("tiny-parallel").to_dict() | made_from["geometry"]
    assert made_from["input_fingerprint"]["params"] == {"method": "fbp"}
    args = ["reconstruct", store, "-m", "fbp", "--overwrite", "-w", 0, "-q"]
    assert _cli(capsys, args)[0] == 0
    assert _cli(capsys, ["predict", store, "--run", run_dir, "--device", "cpu", "-q"])[0] == 0
    s = DataStore.open(store)
    assert s.reconstruction_params("fbp+unet")["input_fingerprint"] == s.recons.fingerprint("fbp")
    assert s.reconstruction_params("fbp+unet")["input_fingerprint"] != made_from["input_fingerprint"]


def test_train_after_divergence_accepts_a_corrected_rerun(work, capsys):
    # a run that diverged in its first epoch leaves config.json (with its --lr) but no last.pt
    (work / "r2").mkdir()
    config = json.loads((work / "run" / "config.json").read_text())
    (work / "r2" / "config.json").write_text(json.dumps(config | {"lr": 1e30}))
    args = ["train", work / "par", "-i", "fbp", "--out", work / "r2", "--epochs", 1, "--batch-size", 2, "-q"]
    args += ["--param", "channels=[4,4,8,8,16]", "--device", "cpu", "--lr", "1e-3"]
    assert _cli(capsys, args)[0] == 0
    assert json.loads((work / "r2" / "config.json").read_text())["lr"] == 1e-3


def test_os_errors_name_the_file():
    assert expected_error(PermissionError(13, "Permission denied", "/data/x")) == (
        "Permission denied: /data/x; check its permissions, or write somewhere else"
    )
    assert "No space" in expected_error(OSError(28, "No space left on device", "/d"))
    assert expected_error(RuntimeError("a bug")) is None


def test_bug_shows_traceback(monkeypatch, capsys):
    import nanoct.io.store

    def broken(*a, **k):
        raise RuntimeError("boom")

    monkeypatch.setattr(nanoct.io.store.DataStore, "open", broken)
    code, _, err = _cli(capsys, ["info", "anything"])
    assert code == 1 and "Traceback" in err and "report" in err


def _fail_chunk_writes(monkeypatch, code: int, after: int, under: str) -> None:
    """Zarr chunk writes below ``under`` fail half-way after ``after`` chunks were written, leaving the partial file."""
    import zarr.storage._local as local

    real, calls = local._put, []

    def put(path, value, exclusive=False):
        if under in Path(path).parts and "c" in Path(path).parts and len(calls) >= after:
            data = bytes(value.as_buffer_like())
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            Path(path).with_suffix(f".{uuid.uuid4().hex}.partial").write_bytes(data[: len(data) // 2])  # zarr's name
            raise OSError(code, os.strerror(code), str(path))
        if "c" in Path(path).parts:
            calls.append(path)
        return real(path, value, exclusive=exclusive)

    monkeypatch.setattr(local, "_put", put)


@pytest.mark.slow
@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EIO])
def test_write_failing_half_way_then_rerun(work, capsys, monkeypatch, code):
    store = work / "par"
    args = ["reconstruct", store, "-m", "fbp", "--name", "again", "-w", 0, "-q"]
    with monkeypatch.context() as m:
        _fail_chunk_writes(m, code, after=3, under="again")
        code_, out, err = _cli(capsys, args)
    expect = {errno.ENOSPC: "no space left on the device of", errno.EIO: "check the disk"}[code]
    _check_error(code_, out, err, expect)
    assert str(store) in err
    if code == errno.ENOSPC:
        assert re.search(r"\(\d+\.\d [KMG]iB free, about \d+\.\d [KMG]iB more needed\)", err), err
    assert _cli(capsys, ["info", store, "--check"])[0] == 0  # readable, nothing damaged
    s = DataStore.open(store)
    assert 0 < s.reconstruction_done("again").sum() < s.n
    assert _cli(capsys, args)[0] == 0  # the rerun completes ...
    np.testing.assert_array_equal(DataStore.open(store).read_reconstruction("again"), s.read_reconstruction("fbp"))
    assert not list(store.rglob("*.partial"))  # ... and clears the partial file


@pytest.mark.slow
def test_checkpoint_write_failing_then_rerun(work, capsys, monkeypatch):
    import nanoct.io.fileio as fileio

    real = fileio.os.replace

    def full_disk(src, dst):  # the last step of writing last.pt fails
        if Path(dst).name == "last.pt":
            raise OSError(errno.ENOSPC, "No space left on device", str(src))
        return real(src, dst)

    args = ["train", work / "par", "-i", "fbp", "--out", work / "r2", "--epochs", 2, "--batch-size", 2, "-q"]
    args += ["--param", "channels=[4,4,8,8,16]", "--device", "cpu"]
    with monkeypatch.context() as m:
        m.setattr(fileio.os, "replace", full_disk)
        code, out, err = _cli(capsys, args)
    _check_error(code, out, err, f"no space left on the device of {work / 'r2' / 'last.pt'}")
    assert "more needed" in err and not (work / "r2" / "last.pt").exists()
    assert not [p for p in (work / "r2").iterdir() if ".tmp-" in p.name]
    assert _cli(capsys, args)[0] == 0
    assert len((work / "r2" / "log.csv").read_text().splitlines()) == 3  # header and two epochs


def test_main_prints_warnings_as_lines_and_ends_at_once_after_ctrl_c(monkeypatch, capsys):
    """On the command line a warning is one ``warning:`` line (no source location, flags as typed); after Ctrl-C
    the process ends with os._exit(130), not through the interpreter's teardown of running threads."""
    import warnings

    import nanoct.cli.entry as cli

    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)  # main replaces it: restored afterwards

    def warns() -> int:
        warnings.warn("2 of 40 images look\n   out of distribution; try max_shift=1", UserWarning, stacklevel=1)
        return 0

    monkeypatch.setattr(cli, "run", warns)
    with pytest.raises(SystemExit) as stop:
        cli.main()
    assert stop.value.code == 0
    assert capsys.readouterr().err == "warning: 2 of 40 images look out of distribution; try --max-shift 1\n"
    monkeypatch.setattr(cli, "run", lambda: (warnings.warn("lr=0.1 is old", DeprecationWarning, stacklevel=1), 0)[1])
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        with pytest.raises(SystemExit):
            cli.main()
    assert capsys.readouterr().err == "warning: DeprecationWarning: lr=0.1 is old\n"  # another library's: as it is
    ended: list[int] = []
    monkeypatch.setattr(cli, "run", lambda: 130)
    monkeypatch.setattr(cli.os, "_exit", lambda code: ended.append(code))
    with pytest.raises(SystemExit):  # the stub returns, so main goes on to sys.exit
        cli.main()
    assert ended == [130]
