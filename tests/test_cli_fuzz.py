"""Property-based fuzzing of the command line: random flag sets and values for every command.

For any argument list, ``nanoct`` must either accept it or end with exit status 2, exactly one
``error:`` line, no traceback and nothing new on disk. Values are drawn from what users get
wrong: wrong types, negative, NaN, infinite, huge, empty, unicode, paths that are files, missing
or read-only, and unknown flags. The expensive stages (simulation and reconstruction fan-out,
training, prediction, the study, the figure) are replaced by a marker: reaching one means the arguments
were accepted, and the work itself is tested elsewhere.

The number of examples is ``NANOCT_FUZZ_EXAMPLES`` (default 200, the CI bound), e.g.
``NANOCT_FUZZ_EXAMPLES=2000 pytest tests/test_cli_fuzz.py``.
"""

from __future__ import annotations

import contextlib
import io
import os
import shutil
import tempfile
import typing
from pathlib import Path

import pytest
import typer
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from nanoct.cli import app, run
from nanoct.core.geometry import get_preset
from nanoct.recon.batch import reconstruct_dataset
from nanoct.sim.generate import generate_dataset

EXAMPLES = int(os.environ.get("NANOCT_FUZZ_EXAMPLES", "200"))
COMMANDS = typer.main.get_command(app).commands  # type: ignore[attr-defined]

PATHS = ["{w}/store", "{w}/afile", "{w}/missing", "{w}/missing/deeper", "{w}/ro", "{w}/ro/new", "{w}/ünï cødé 😀",
         "{w}/new", "{w}/new.png", "{w}/out.tif", "{w}/shifts.txt", "{w}/store/phantoms", "", "/dev/null"]  # fmt: skip
NUMBERS = ["0", "1", "2", "-1", "-0", "3.5", "-2.5", "nan", "-nan", "inf", "-inf", "1e308", "1e-320",
           "99999999999999999999", str(2**63), "0x10", "1_000"]  # fmt: skip
WORDS = ["", " ", "abc", "ünï", "😀", "\t", "a=b", "=", "relaxation=0.2", "channels=[4,4]", "x=nan", "fbp", "dremel",
         "resesop", "sart", "tiny-parallel", "tiny-fan", "huge-cone", "tiny", "test", "all", "holdout", "unet",
         "cinn", "bogus", "best", "last", "cpu", "cuda:99", "gpu0", "fp32", "bf16", "cosine", "0.5,0.3,0.2",
         "1,0,0", "0.5,0.5", "none", "npy", "tiff", "1:2", "2:1", "0,4", "--", "-q"]  # fmt: skip
# values that are right for a parameter, so that some examples get past the checks
GOOD = {"preset": "tiny-parallel", "n": "2", "out": "{w}/new", "directory": "{w}/store", "method": "fbp",
        "split": "all", "input_name": "fbp", "name": "fbp", "index": "0", "seed": "0", "workers": "0",
        "epochs": "1", "model": "unet", "device": "cpu", "models": "none", "scale": "tiny",
        "src": "{w}/afile"}  # fmt: skip
UNKNOWN = ["--bogus", "-Z", "--n-samples", "--quite", "---", "--=", "--help=no"]


class _Reached(BaseException):
    """Raised by the stand-ins of the expensive stages: the arguments were accepted."""


def _reached(*args, **kwargs):
    raise _Reached


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A workspace: a tiny store with an FBP reconstruction, a file, a read-only and a unicode directory."""
    root = tmp_path_factory.mktemp("fuzz")
    generate_dataset(root / "store", get_preset("tiny-parallel"), 2, workers=0, progress=False)
    reconstruct_dataset(root / "store", "fbp", workers=0, progress=False)
    (root / "afile").write_text("not a directory")
    (root / "ünï cødé 😀").mkdir()
    (root / "ro").mkdir()
    return root


@pytest.fixture
def stand_ins(monkeypatch):
    import nanoct.evaluation.figures
    import nanoct.learn.predict
    import nanoct.learn.train
    import nanoct.recon.batch
    import nanoct.sim.generate
    import nanoct.study.runner

    for module, name in [
        (nanoct.evaluation.figures, "show_sample"),
        (nanoct.sim.generate, "run_tasks"),
        (nanoct.recon.batch, "run_tasks"),
        (nanoct.learn.train, "train"),
        (nanoct.learn.predict, "predict"),
        (nanoct.study.runner, "reproduce_study"),
        (nanoct.study.runner, "reproduce_scale"),
    ]:
        monkeypatch.setattr(module, name, _reached)


def _value(command: str, param) -> st.SearchStrategy[str]:
    if "Path" in str(typing.get_type_hints(COMMANDS[command].callback).get(param.name)):
        return st.sampled_from(PATHS) | st.sampled_from(WORDS)
    return st.sampled_from(NUMBERS) | st.sampled_from(WORDS) | st.sampled_from(PATHS) | st.text(max_size=8)


@st.composite
def argvs(draw) -> list[str]:
    """A command and a random set of its options (flags, values, positional arguments) and unknown flags."""
    name = draw(st.sampled_from(sorted(COMMANDS)))
    args: list[str] = [name]
    for param in COMMANDS[name].params:
        good = GOOD.get(param.name)
        value = st.sampled_from([good]) if good is not None and draw(st.integers(0, 2)) else _value(name, param)
        if param.param_type_name == "argument":
            if draw(st.integers(0, 9)):
                args.append(draw(value))
        elif param.name != "help" and draw(st.integers(0, 9)) < (9 if param.required else 3):
            flag = draw(st.sampled_from(param.opts + param.secondary_opts))
            args += [flag] if param.is_flag else [flag, draw(value)]
    if draw(st.integers(0, 5)) == 0:
        args.insert(draw(st.integers(1, len(args))), draw(st.sampled_from(UNKNOWN)))
    if draw(st.integers(0, 9)) == 0:
        args.pop(draw(st.integers(0, len(args) - 1)))  # a value or flag lost
    return args


def _listing(root: Path) -> dict[str, int]:
    return {str(p.relative_to(root)): p.stat().st_size for p in root.rglob("*")}


@pytest.mark.timeout(max(600, EXAMPLES))  # about 0.1-0.5 s an example
@settings(
    max_examples=EXAMPLES,
    deadline=None,
    database=None,
    derandomize="NANOCT_FUZZ_EXAMPLES" not in os.environ,  # CI: the same examples every run
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(argv=argvs())
def test_random_arguments(base, stand_ins, argv):
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp) / "w"
        shutil.copytree(base, work)
        (work / "ro").chmod(0o555)
        args = [a.replace("{w}", str(work)) for a in argv]
        before = _listing(work)
        label = args[0] if args and args[0] in COMMANDS else "(no command)"
        out, err = io.StringIO(), io.StringIO()
        try:
            # relative paths (a word such as "cpu" taken for a directory) land in the workspace
            with contextlib.chdir(work), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                code = run(args)
        except _Reached:
            event(f"{label}: reached the work")
            return
        finally:
            (work / "ro").chmod(0o755)
        event(f"{label}: exit {code}")
        text = out.getvalue() + err.getvalue()
        assert "Traceback" not in text and code != 1, (args, text)
        assert code in (0, 2), (args, code, text)
        if code == 2 and args:  # (no arguments at all: the help text, status 2)
            lines = [line for line in err.getvalue().splitlines() if line.strip()]
            assert len(lines) == 1 and lines[0].startswith("error: "), (args, err.getvalue())
            assert _listing(work) == before, (args, sorted(set(_listing(work)) ^ set(before)))
