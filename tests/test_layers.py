"""Import directions between the subpackages: each layer imports only the layers below it."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "nanoct"

#: What each subpackage must never import (directly or lazily, inside a function).
FORBIDDEN = {
    "core": {"sim", "io", "recon", "motion", "workflows", "learn", "evaluation", "study", "cli", "preprocess"},
    "preprocess": {"recon", "motion", "workflows", "learn", "evaluation", "study", "cli"},
    "recon": {"motion", "workflows", "learn", "study", "cli"},
    "motion": {"workflows", "learn", "study", "cli"},
    "workflows": {"study", "cli"},
}


def _imported(path: Path) -> set[str]:
    """The nanoct subpackages a module imports, absolute or relative."""
    found = set()
    depth = len(path.relative_to(SRC).parts) - 1
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against the module's package
                if node.level > depth:
                    found.add((node.module or "").split(".")[0] or "nanoct")
                elif node.level == depth and depth == 1:
                    found.add(path.relative_to(SRC).parts[0])
            elif node.module and node.module.startswith("nanoct."):
                found.add(node.module.split(".")[1])
        elif isinstance(node, ast.Import):
            found |= {alias.name.split(".")[1] for alias in node.names if alias.name.startswith("nanoct.")}
    return found


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_layer_imports_only_below(package):
    bad = {
        str(path.relative_to(SRC)): sorted(_imported(path) & FORBIDDEN[package])
        for path in sorted((SRC / package).rglob("*.py"))
    }
    assert not {k: v for k, v in bad.items() if v}, bad
