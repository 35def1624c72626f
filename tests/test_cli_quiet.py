"""Every command takes -q/--quiet; the ones without progress bars then print nothing but errors."""

from __future__ import annotations

import typer.main

from nanoct.cli import app, run


def test_every_command_has_quiet():
    commands = typer.main.get_command(app).commands
    lacking = [name for name, command in commands.items() if "-q" not in [o for p in command.params for o in p.opts]]
    assert not lacking, lacking


def test_quiet_info_methods_and_show(tiny_store, tmp_path, capsys):
    assert run(["info", str(tiny_store.path), "-q"]) == 0
    assert capsys.readouterr().out == ""
    assert run(["info", str(tiny_store.path), "--check", "-q"]) == 0
    assert capsys.readouterr().out == ""
    assert run(["methods", "-q"]) == 0
    names = capsys.readouterr().out.split()
    assert "dremel" in names and "fbp" in names and all(":" not in n for n in names)
    assert run(["show", str(tiny_store.path), "--out", str(tmp_path / "s.png"), "-q"]) == 0
    assert capsys.readouterr().out == "" and (tmp_path / "s.png").is_file()
