"""The layout rules: no function over 80 lines of code and no class over 200 in src/ (docstrings not counted),
and no module of the command-line interface (src/nanoct/cli/) over 400 lines."""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "nanoct"
MAX_FUNCTION, MAX_CLASS = 80, 200
#: The command-line interface is a package of small modules, one per group of commands.
MAX_CLI_MODULE = 400


def _docstring_lines(node: ast.AST) -> set[int]:
    lines: set[int] = set()
    for sub in ast.walk(node):
        body = getattr(sub, "body", None)
        if isinstance(sub, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and body:
            first = body[0]
            if (
                isinstance(first, ast.Expr)
                and isinstance(first.value, ast.Constant)
                and isinstance(first.value.value, str)
            ):
                lines |= set(range(first.lineno, first.end_lineno + 1))
    return lines


def code_lines(source: list[str], node: ast.AST) -> int:
    """Lines of ``node`` that are neither blank, comments nor docstrings."""
    lines = set(range(node.lineno, node.end_lineno + 1)) - _docstring_lines(node)
    return sum(1 for i in lines if source[i - 1].strip() and not source[i - 1].lstrip().startswith("#"))


def _oversized() -> list[str]:
    found = []
    for path in sorted(SRC.rglob("*.py")):
        text = path.read_text()
        source = text.split("\n")
        for node in ast.walk(ast.parse(text)):
            limit = MAX_CLASS if isinstance(node, ast.ClassDef) else MAX_FUNCTION
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                n = code_lines(source, node)
                if n > limit:
                    found.append(f"{path.relative_to(SRC)}:{node.lineno} {node.name}: {n} lines (limit {limit})")
    return found


def test_no_oversized_function_or_class():
    assert _oversized() == []


def test_the_command_line_interface_is_a_package_of_small_modules():
    assert not (SRC / "cli.py").exists()
    lines = {path.name: len(path.read_text().splitlines()) for path in sorted((SRC / "cli").glob("*.py"))}
    assert {"__init__.py", "entry.py", "options.py"} <= set(lines)
    assert {name: n for name, n in lines.items() if n > MAX_CLI_MODULE} == {}


def test_the_counter_counts_code_only():
    text = 'def f():\n    """Doc\n    string."""\n    # comment\n\n    return 1\n'
    (node,) = ast.parse(text).body
    assert code_lines(text.split("\n"), node) == 2


def test_the_rule_catches_a_long_function():
    text = "def f():\n" + "".join(f"    x{i} = {i}\n" for i in range(MAX_FUNCTION + 1))
    (node,) = ast.parse(text).body
    assert code_lines(text.split("\n"), node) == MAX_FUNCTION + 2
