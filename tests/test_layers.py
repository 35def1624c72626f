"""Import directions between the subpackages: each layer imports only the layers below it.

The layers, from the ground up (:data:`ORDER`); the order is the one the code has, with no import
running back up: ``preprocess`` and ``io`` need only ``core``; the solvers (``recon``) read and write
through ``io``; ``sim`` (matched sets reconstruct the scan) and ``motion`` (its estimators run FBP
and Dremel) stand on ``recon``; ``evaluation`` (metrics, intervals) needs none of the workflows;
``workflows`` joins reading, corrections, motion, solvers and the intervals' export; ``learn``
calibrates its networks with ``evaluation``; ``study`` runs everything. No subpackage imports a
top-level module (:data:`TOP`: the package's ``__init__``, the names it gathers, the array API, the
CLI): those stand above every layer. Inside a layer, no modules import each other in a circle.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "nanoct"

#: The subpackages from the ground up: each may import those before it, never one after it.
ORDER = ("core", "preprocess", "io", "recon", "sim", "motion", "evaluation", "workflows", "learn", "study")
#: Top-level modules no subpackage imports; ``nanoct`` is the package's own ``__init__`` (``from .. import x``).
TOP = {"nanoct", "names", "api", "cli", "__main__"}
#: What each subpackage must never import (directly, lazily inside a function, or as a ``"nanoct.x.y:attr"``
#: registry target).
FORBIDDEN = {package: set(ORDER[i + 1 :]) | TOP for i, package in enumerate(ORDER)}

_TARGET = re.compile(r"^nanoct\.(\w+)(?:\.\w+)*:\w+$")


def _top_name(name: str) -> str:
    """What ``from nanoct import name`` takes: a subpackage or top-level module by its name, else the package
    itself (``nanoct``: a name its ``__init__`` defines)."""
    return name if (SRC / name).is_dir() or (SRC / f"{name}.py").is_file() else "nanoct"


def _imported(path: Path, module: tuple[str, ...] | None = None) -> set[str]:
    """The parts of nanoct a module imports (subpackages, top-level modules, ``nanoct`` for the package's
    ``__init__``), absolute or relative, anywhere in the file. ``module``: the module's dotted name below
    ``nanoct`` as parts (default: from ``path`` below ``src/nanoct``)."""
    parts = module or path.relative_to(SRC).with_suffix("").parts
    package = ("nanoct", *parts[:-1])  # the package a relative import starts from (an __init__'s own)
    found: set[str] = set()

    def add(target: tuple[str, ...], names: list[str]) -> None:
        if target[:1] != ("nanoct",):
            return
        found.update([target[1]] if len(target) > 1 else [_top_name(n) for n in names])

    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            names = [alias.name for alias in node.names]
            if node.level:
                if node.level > len(package):
                    continue
                base = package[: len(package) - node.level + 1]
                add((*base, *(node.module.split(".") if node.module else ())), names)
            elif node.module:
                add(tuple(node.module.split(".")), names)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                add(tuple(alias.name.split(".")), [])
                if alias.name == "nanoct":
                    found.add("nanoct")
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            target = _TARGET.match(node.value)
            if target:
                found.add(target.group(1))
    return found


def _violations(package: str) -> dict[str, list[str]]:
    bad = {
        str(path.relative_to(SRC)): sorted(_imported(path) & FORBIDDEN[package])
        for path in sorted((SRC / package).rglob("*.py"))
    }
    return {k: v for k, v in bad.items() if v}


def _module_name(path: Path, root: Path) -> str:
    parts = ("nanoct", *path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _module_imports(path: Path, me: str, modules: set[str]) -> set[str]:
    """The modules of nanoct that one module imports anywhere in it (``from pkg import sub``: the submodule)."""
    package = me if path.name == "__init__.py" else me.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            base = package.split(".")[: package.count(".") + 2 - node.level] if node.level else []
            target = ".".join([*base, *(node.module.split(".") if node.module else [])])
            subs = {f"{target}.{alias.name}" for alias in node.names} & modules
            found |= subs | ({target} & modules if len(subs) < len(node.names) else set())
        elif isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names} & modules
    return found - {me}


def _circles(root: Path) -> list[list[str]]:
    """The groups of modules that import each other in a loop (strongly connected, Tarjan)."""
    modules = {_module_name(p, root): p for p in sorted(root.rglob("*.py"))}
    graph = {m: _module_imports(p, m, set(modules)) for m, p in modules.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    circles = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while not group or group[-1] != v:
                group.append(stack.pop())
            if len(group) > 1:
                circles.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return circles


def test_every_subpackage_has_a_layer():
    """Every subpackage is a layer, but the command-line package (on top, with the other top-level modules)."""
    assert {p.name for p in SRC.iterdir() if (p / "__init__.py").is_file()} - TOP == set(ORDER)


@pytest.mark.parametrize("package", ORDER)
def test_layer_imports_only_below(package):
    assert not _violations(package)


def test_the_checker_finds_imports_that_run_back_up(tmp_path):
    """Every way of importing upwards is caught: relative, absolute, lazy, the package itself, a registry target."""
    bad = tmp_path / "bad.py"
    bad.write_text(
        "from ..recon.batch import reconstruct_dataset\n"
        "from .. import __version__\n"
        "TARGET = 'nanoct.sim.matched:plan_matched'\n\n\n"
        "def f():\n"
        "    from ..names import stack_name\n"
        "    from nanoct import learn\n"
        "    import nanoct.cli\n"
        "    import nanoct\n"
    )
    assert _imported(bad, ("io", "bad")) & FORBIDDEN["io"] == {"recon", "nanoct", "sim", "names", "learn", "cli"}
    good = tmp_path / "good.py"
    good.write_text("from . import rawscan\nfrom .rawscan import RawScan\nfrom ..core.errors import NanoctError\n")
    assert _imported(good, ("io", "good")) == {"io", "core"}
    init = tmp_path / "__init__.py"  # a package's __init__ imports relative to itself
    init.write_text("from .base import Reader\nfrom ...core.errors import NanoctError\nfrom ... import names\n")
    assert _imported(init, ("io", "readers", "__init__")) == {"io", "core", "names"}


def test_no_modules_import_each_other_in_a_circle():
    assert _circles(SRC) == []


def test_the_circle_finder_finds_one(tmp_path):
    root = tmp_path / "nanoct"
    (root / "sim").mkdir(parents=True)
    for name, text in {
        "__init__": "",
        "sim/__init__": "",
        "sim/a": "from .b import x\n",
        "sim/b": "def f():\n    from . import a\n",
    }.items():
        (root / f"{name}.py").write_text(text)
    (root / "sim" / "c.py").write_text("from .a import y\n")
    assert _circles(root) == [["nanoct.sim.a", "nanoct.sim.b"]]
