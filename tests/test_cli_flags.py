"""Options declared once: a group of options is a dataclass that a command takes as one typed value."""

from __future__ import annotations

from dataclasses import dataclass

import typer
import typer.main
from typer.testing import CliRunner

from nanoct.cli import app
from nanoct.cli.flags import flag_groups, given, option
from nanoct.cli.options import ScanCorrections, ScanReading


@dataclass(frozen=True)
class Pair:
    first: int = option(1, "--first", help="The first.")
    names: list[str] = option([], "--name", help="Repeatable.")
    last: str | None = option(None, "--last", help="The last.")


def test_a_group_is_options_in_its_place_and_reaches_the_command_built():
    seen = []

    @flag_groups(place={"last": "quiet"})
    def command(*, before: int = typer.Option(0, "--before"), pair: Pair, quiet: bool = typer.Option(False, "-q")):
        seen.append((before, pair, quiet))

    tool = typer.Typer()
    tool.command()(command)
    tool.command("other")(lambda: None)  # two commands: 'command' is a subcommand
    params = [p.name for p in typer.main.get_command(tool).commands["command"].params]  # type: ignore[attr-defined]
    assert params == ["before", "first", "names", "quiet", "last"]
    result = CliRunner().invoke(tool, ["command", "--first", "3", "--name", "a", "--name", "b", "--last", "z"])
    assert result.exit_code == 0, result.output
    assert seen == [(0, Pair(3, ["a", "b"], "z"), False)]
    assert given(seen[0][1]) == {"--first": 3, "--name": ["a", "b"], "--last": "z"}
    assert given(Pair(), ["first", "names"]) == {}


def test_import_and_stack_take_the_same_reading_and_correction_options():
    commands = typer.main.get_command(app).commands  # type: ignore[attr-defined]
    shared = [f.name for group in (ScanReading, ScanCorrections) for f in group.__dataclass_fields__.values()]
    for name in ("import", "stack"):
        options = {p.name: p for p in commands[name].params}
        assert set(shared) <= set(options), name
    for param in shared:
        a, b = (next(p for p in commands[c].params if p.name == param) for c in ("import", "stack"))
        assert (a.opts, a.default, a.help) == (b.opts, b.default, b.help), param
