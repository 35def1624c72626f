"""Every `nanoct ...` command in the code blocks of README.md and docs/*.md runs, on small data.

The code blocks of each document are run in order, as a shell would run them, in a fresh folder
(one per document), with the command-line entry point in this process. What the test changes,
so that a command written for a cluster or a paper-scale run finishes in seconds, is listed in
:data:`REWRITES` (and docs/commands.md, "The documented commands are tested"):

* workers: a command that fans out over local Dask workers runs in this process (``--workers 0``);
* shell: ``A=x B=y`` and ``export A=x`` set variables, ``$A`` is replaced, a ``for`` loop runs
  its body for each value of its variable (the first value only where the body trains or
  predicts: one network per pass), ``torchrun ... -m nanoct`` and
  ``.venv/bin/nanoct`` are ``nanoct``, commands joined by ``&&`` are split, other programs
  (pip, dask, python) are skipped;
* absolute paths (``/data/par``, ``/tmp/eta``) lie inside the document's folder;
* placeholder files: ``scan.nxs`` is an NXtomo file written here (112 detector rows, 63
  columns, 60 views of a phantom, flats and darks); a ``predict --run RUN`` whose run does not
  exist gets a small ciunet-res run (3 scales) trained here for one epoch on images of 16 samples
  (reconstructed by the command's ``--input`` where that names a method, else resesop)
  simulated with the geometry of the data set it is applied to (``predict`` refuses a run of
  another geometry) and calibrated by a prediction on that simulated set;
* sizes: ``generate`` uses the tiny preset of the same beam and at most 50 samples (the
  fewest that leave one test sample), 8 for a set nothing trains on (``--split-fractions 0,...``),
  ``--epochs`` is 1, ``--scheduler ADDRESS`` becomes
  ``--workers 0``, and a whole study (``reproduce`` or ``scaling`` without ``--plan``, 45
  minutes at tiny scale) is run with ``--plan``.

A command that fails is reported with its document, line and output; all of a document's
failures are listed together.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import h5py
import numpy as np
import pytest

from nanoct.cli import run
from nanoct.recon.registry import METHODS

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
REWRITES = (
    (r"--scheduler \S+", "--workers 0", "no Dask cluster in a test"),
    (r"(generate .*--preset\s+)(paper|small)-", r"\1tiny-", "tiny images"),
    (r"--epochs \d+", "--epochs 1", "one epoch"),
)
MAX_SAMPLES = 50
#: The commands that fan out over local Dask workers (``--workers``, default 2): run in this process instead.
FANNING_OUT = ("generate", "reconstruct", "reproduce", "scaling", "shift-test", "stack")
#: At most this many samples for a set nothing trains on (``--split-fractions 0,...``: test or calibration pairs).
MAX_UNTRAINED_SAMPLES = 8


SHELL_BLOCKS = ("", "bash", "sh", "shell", "console")


def code_blocks(path: Path) -> list[tuple[int, str]]:
    """The fenced shell code blocks (no language, bash, sh ...) of a Markdown file with the line each starts on."""
    blocks, current, start, language = [], None, 0, ""
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if line.lstrip().startswith("```"):
            if current is None:
                current, start, language = [], number + 1, line.strip()[3:].strip().lower()
            else:
                if language in SHELL_BLOCKS:
                    blocks.append((start, "\n".join(current)))
                current = None
        elif current is not None:
            current.append(line)
    return blocks


def _as_nanoct(words: list[str]) -> list[str] | None:
    """The argument list of a ``nanoct`` command (torchrun and .venv/bin/ prefixes dropped), else None."""
    if (
        words
        and words[0] == "torchrun"
        and "-m" in words
        and words[words.index("-m") + 1 : words.index("-m") + 2] == ["nanoct"]
    ):
        return words[words.index("-m") + 2 :]
    if words and (words[0] == "nanoct" or words[0].endswith("/nanoct")):
        return words[1:]
    return None


def _expand(text: str, env: dict[str, str]) -> str:
    return re.sub(r"\$(\w+)|\$\{(\w+)\}", lambda m: env.get(m.group(1) or m.group(2), m.group(0)), text)


def _parse(lines: list[tuple[int, str]]) -> list:
    """Lines of a shell block as a tree: ``(line, text)`` items and ``("for", variable, values, body)`` loops."""
    tree: list = []
    stack = [tree]
    for number, raw in lines:
        line = raw.split(" #", 1)[0].strip()
        if not line or line.startswith("#"):
            continue
        loop = re.match(r"for (\w+) in (.+?);\s*do$", line)
        if loop:
            body: list = []
            stack[-1].append(("for", loop.group(1), loop.group(2), body))
            stack.append(body)
        elif line == "done":
            stack.pop()
        else:
            stack[-1].append((number, line))
    return tree


def _heavy(tree: list) -> bool:
    """Whether a loop body trains or predicts (one network per pass)."""
    for item in tree:
        if item[0] == "for":
            if _heavy(item[3]):
                return True
        elif re.search(r"\bnanoct (train|predict)\b", item[1]):
            return True
    return False


def _run_tree(tree: list, env: dict[str, str], found: list) -> None:
    for item in tree:
        if item[0] == "for":
            values = _expand(item[2], env).split()
            for value in values[:1] if _heavy(item[3]) else values:
                env[item[1]] = value
                _run_tree(item[3], env, found)
            continue
        number, line = item
        assignment = re.fullmatch(r"(?:export )?((?:\w+=\S+\s*)+)", line)
        if assignment:
            env.update(dict(entry.split("=", 1) for entry in assignment.group(1).split()))
            continue
        for part in line.split("&&"):
            try:
                words = shlex.split(_expand(part, env))
            except ValueError:  # prose or output in a block without a language, not a command
                if _as_nanoct(part.split()) is not None:
                    raise
                continue
            argv = _as_nanoct(words)
            if argv is not None:
                found.append((number, argv))


def commands(path: Path) -> list[tuple[int, list[str]]]:
    """The nanoct commands of a document, in order, with their line, after the shell rules above."""
    found: list = []
    env: dict[str, str] = {}
    for start, block in code_blocks(path):
        lines = [(start + i, text) for i, text in enumerate(block.replace("\\\n", " ").splitlines())]
        _run_tree(_parse(lines), env, found)
    return found


def _rewrite(argv: list[str], root: Path) -> list[str]:
    text = " ".join(shlex.quote(a) for a in argv)
    for pattern, replacement, _ in REWRITES:
        text = re.sub(pattern, replacement, text)
    words = shlex.split(text)
    if words[0] == "generate" and "--n" in words:
        i = words.index("--n") + 1
        fractions = words[words.index("--split-fractions") + 1] if "--split-fractions" in words else "1"
        untrained = float(fractions.split(",")[0]) == 0
        words[i] = str(min(int(words[i]), MAX_UNTRAINED_SAMPLES if untrained else MAX_SAMPLES))
    if words[0] in FANNING_OUT and not any(w in ("--workers", "-w") or w.startswith("--workers=") for w in words):
        words += ["--workers", "0"]  # a Dask cluster's start costs more than the command's work at these sizes
    if words[0] in ("reproduce", "scaling") and "--plan" not in words:
        words.append("--plan")
    # absolute paths (alone or after "=") inside the document's folder; the vendored real scans from the repository
    words = [re.sub(r"(^|=)/(?!/)", lambda m: f"{m.group(1)}{root}/", w) if "/" in w else w for w in words]
    return [str(ROOT / w) if w.startswith("tests/data/") else w for w in words]


def _write_scan_nxs(path: Path) -> None:
    """An NXtomo file: 60 views of a phantom on 112 detector rows x 63 columns, with flats and darks."""
    from nanoct.sim.analytic import ellipse_sinogram, stack_phantom

    phi = np.linspace(0, np.pi, 60, endpoint=False)
    slices = stack_phantom(63, 4, seed=1)
    sino = np.stack([ellipse_sinogram(slices[r * 4 // 112], phi, 63) for r in range(112)], axis=1)  # (K, R, L)
    sino *= 1.0 / max(float(sino.max()), 1e-6)
    flat, dark = 1000.0, 20.0
    frames = np.concatenate(
        [np.full((2, 112, 63), dark), np.full((2, 112, 63), flat), dark + (flat - dark) * np.exp(-sino)]
    )
    with h5py.File(path, "w") as f:
        f["entry/instrument/detector/data"] = frames.astype(np.uint16)
        f["entry/instrument/detector/image_key"] = np.r_[2, 2, 1, 1, np.zeros(60, int)]
        f["entry/sample/rotation_angle"] = np.r_[0, 0, 0, 0, np.rad2deg(phi)]


def _train_run(run_dir: Path, data: Path, method: str = "resesop") -> None:
    """A placeholder run: a small ciunet-res trained one epoch on ``method`` images simulated with ``data``'s geometry.

    ``predict`` refuses a run trained on another geometry, and an imported scan has no ground
    truth to train on: the network is trained on a simulated data set of the same geometry.
    """
    from nanoct.io.store import DataStore
    from nanoct.sim.generate import generate_dataset

    sim = run_dir.parent / f"simulated_{run_dir.name}"
    geometry = DataStore.open(data).geometry
    generate_dataset(sim, geometry, 16, split_fractions=(0.75, 0.125, 0.125), workers=0, progress=False)
    assert run(["reconstruct", str(sim), "--method", method, "-w", "0", "-q"]) == 0
    argv = ["train", str(sim), "--model", "ciunet-res", "--input", method, "--epochs", "1", "-q", "--out"]
    small = ["--param", "n_scales=3", "--param", "blocks_per_scale=1", "--param", "cond_channels=[4,4,4]"]
    assert run([*argv, str(run_dir), *small]) == 0
    # its std is calibrated on the validation split of the data it was trained on (an imported scan has none)
    assert run(["predict", str(sim), "--run", str(run_dir), "--input", method, "-q"]) == 0


PLACEHOLDERS = {"scan.nxs": _write_scan_nxs}


def _prepare(document: Path, folder: Path) -> None:
    text = document.read_text()
    for name, write in PLACEHOLDERS.items():
        if name in text:
            write(folder / name)


WITH_COMMANDS = [d for d in DOCUMENTS if commands(d)]


def test_the_documents_hold_the_commands_this_test_runs():
    names = {d.name for d in WITH_COMMANDS}
    assert {"README.md", "commands.md", "measured_data.md", "runbook.md"} <= names, names
    assert sum(len(commands(d)) for d in WITH_COMMANDS) >= 35
    loop = [argv for _, argv in commands(ROOT / "docs" / "runbook.md") if argv[0] == "predict"]
    assert loop == [["predict", "runs/paper/parallel/data", "--run", "runs/paper/parallel/runs/unet-fbp",
                     "--input", "fbp", "--split", "test"]]  # fmt: skip


def test_the_rewrites_keep_a_command_and_shrink_its_size(tmp_path):
    argv = _rewrite(
        ["generate", "--preset", "paper-fan", "--n", "32095", "--out", "/data/x", "--scheduler", "tcp://H:1"], tmp_path
    )
    assert argv == ["generate", "--preset", "tiny-fan", "--n", "50", "--out", f"{tmp_path}/data/x", "--workers", "0"]
    assert _rewrite(["generate", "--n", "24", "--split-fractions", "0,0,1", "--out", "t"], tmp_path)[2] == "8"
    assert _rewrite(["generate", "--n", "24", "--split-fractions", "0.5,0,0.5", "--out", "t"], tmp_path)[2] == "24"
    assert _rewrite(["reconstruct", "d", "--method", "fbp"], tmp_path)[-2:] == ["--workers", "0"]
    assert _rewrite(["stack", "d", "-w", "1"], tmp_path) == ["stack", "d", "-w", "1"]
    assert _rewrite(["reproduce", "--scale", "paper"], tmp_path)[-1] == "--plan"
    assert _rewrite(["reconstruct", "d", "--eta", "estimate:reference=/tmp/r"], tmp_path)[3] == (
        f"estimate:reference={tmp_path}/tmp/r"
    )


@pytest.mark.slow
@pytest.mark.parametrize("document", WITH_COMMANDS, ids=[d.name for d in WITH_COMMANDS])
def test_every_documented_command_runs(document, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    _prepare(document, tmp_path)
    failed = []
    for line, argv in commands(document):
        command = _rewrite(argv, tmp_path)
        if command[0] == "predict" and not Path(command[command.index("--run") + 1]).exists():
            method = command[command.index("--input") + 1] if "--input" in command else "resesop"
            method = method if method in METHODS else "resesop"  # e.g. resesop_est-residual: a result's name
            _train_run(Path(command[command.index("--run") + 1]), Path(command[1]), method)
        capsys.readouterr()
        status = run(command)
        output = capsys.readouterr()
        if status != 0:
            failed.append(f"{document.name}:{line}: nanoct {' '.join(command)} -> {status}\n{output.err[-600:]}")
    assert not failed, "\n".join(failed)
