"""The README: its notebook example runs as written (on a small Data Exchange file it makes), its
quick start and command table name what exists, it stays a short guide, and the product text
states what the product does, not the history of how it got there."""

from __future__ import annotations

import re
from pathlib import Path

import h5py
import numpy as np
import typer.main

from nanoct.cli import app
from nanoct.core.geometry import PRESETS, Geometry
from nanoct.core.operators import RayTransform
from nanoct.study.config import STUDY_PRESETS

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
INSTALL = (
    "python3 -m venv .venv && .venv/bin/pip install -q torch==2.13.0 && "
    '.venv/bin/pip install -q -c constraints.txt -e ".[test]"'
)
#: Words that tell the project's history instead of its state (git log keeps the history).
HISTORY = re.compile(r"\b(round (one|two|three|four|five|six|seven|eight|nine|ten|\d+)|issues? \d+|session)\b", re.I)


def _example() -> str:
    text = README.read_text()
    section = text[text.index("## Your own scan") :]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_notebook_example_runs(tmp_path, monkeypatch):
    g = Geometry.from_angles(np.linspace(0, np.pi, 40, endpoint=False), 41, 41)
    x = np.zeros(g.image_shape, np.float32)
    x[12:28, 15:30] = 0.05
    line = np.stack([RayTransform(g).forward(x)] * 2, axis=1)  # (views, 2 rows, columns)
    with h5py.File(tmp_path / "scan.h5", "w") as f:
        f["exchange/data"] = 1000 * np.exp(-line)
        f["exchange/data_white"] = np.full((2, 2, 41), 1000.0)
        f["exchange/data_dark"] = np.zeros((2, 2, 41))
        f["exchange/theta"] = np.rad2deg(g.angles)
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(_example(), "README example", "exec"), namespace)
    assert namespace["image"].shape == (41, 41)
    assert namespace["shifts"].shape == (40,)


def _section(title: str) -> str:
    text = README.read_text()
    start = text.index(f"## {title}\n")
    end = text.find("\n## ", start + 1)
    return text[start : end if end >= 0 else None]


def test_quick_start_is_two_commands_on_a_fresh_machine():
    commands = re.findall(r"```bash\n(.*?)\n```", _section("Quick start"), re.S)
    assert len(commands) == 2
    assert all(c.startswith(INSTALL + " && ") for c in commands)
    run, tests = (c.removeprefix(INSTALL + " && ") for c in commands)
    assert run == ".venv/bin/nanoct reproduce --preset tiny-quick"
    assert "tiny-quick" in STUDY_PRESETS and "tiny-parallel" in PRESETS  # the first run and the reference
    assert tests == ".venv/bin/python -m pytest -q"


def test_command_table_names_every_command():
    table = _section("Commands")
    listed = set(re.findall(r"^\| `nanoct ([\w-]+)", table, re.M))
    assert listed == set(typer.main.get_command(app).commands)


def test_readme_is_a_short_guide():
    assert len(README.read_text().encode()) <= 8 * 1024


def test_product_text_has_no_history_words():
    files = [README, *(ROOT / "docs").rglob("*.md"), *(ROOT / "src").rglob("*.py")]
    files += [*(ROOT / "benchmarks").rglob("*.py"), *(ROOT / "benchmarks").rglob("*.md")]
    hits = [
        f"{path.relative_to(ROOT)}:{i}: {line.strip()}"
        for path in files
        for i, line in enumerate(path.read_text().splitlines(), 1)
        if HISTORY.search(line)
    ]
    assert not hits, "state what the product does and what was measured, not when:\n" + "\n".join(hits)
