"""The ``nanoct`` command: the typer app with its commands in the order the help lists them, and the entry
point, the one error boundary of the command line (an expected failure is one ``error:`` line)."""

from __future__ import annotations

import errno
import os
import re
import sys
import traceback
import warnings
from typing import Any

import typer

from .. import __version__
from ..core.errors import NanoctError
from ..io.fileio import free_space
from . import data, learn, recon, scan, study

app = typer.Typer(
    help="nanoct: CT reconstruction with inexact (motion-perturbed) forward operators.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    # plain help: flags read "-q, --quiet" (rich help shows "<bool>" after every flag in typer 0.29)
    rich_markup_mode=None,
)

# the exceptions module of the click that the installed typer uses: click itself up to typer 0.28,
# typer._click (vendored) from 0.29 on
_CLICK = sys.modules[typer.BadParameter.__module__]


def _show_version(value: bool) -> None:
    if value:
        typer.echo(f"nanoct {__version__}")
        raise typer.Exit()


@app.callback()
def _options(
    version: bool = typer.Option(
        False, "--version", help="Print the version and exit.", callback=_show_version, is_eager=True
    ),
) -> None:
    """nanoct: CT reconstruction with inexact (motion-perturbed) forward operators."""


#: The commands, in the order of the help's list.
COMMANDS = {
    "generate": data.generate,
    "reconstruct": recon.reconstruct,
    "methods": recon.methods,
    "train": learn.train,
    "predict": learn.predict,
    "info": data.info,
    "show": data.show,
    "evaluate": study.evaluate,
    "reproduce": study.reproduce,
    "shift-test": study.shift_test,
    "scaling": study.scaling,
    "import": scan.import_,
    "stack": scan.stack,
    "export": data.export,
}
for _name, _command in COMMANDS.items():
    app.command(_name)(_command)

# internal parameter names that appear in library messages -> the flag a user typed
_FLAGS = {"max_shift": "--max-shift", "noise_std": "--noise-std", "oversample": "--oversample", "workers": "--workers"}


def _as_flags(message: str) -> str:
    """Rewrite ``max_shift=-1`` in a library message as ``--max-shift -1``."""
    return re.sub(r"\b(" + "|".join(_FLAGS) + r")=", lambda m: _FLAGS[m.group(1)] + " ", message)


def expected_error(exc: BaseException) -> str | None:
    """The one-line message for an expected failure, or None for a bug."""
    if isinstance(exc, (NanoctError, ValueError)):
        return str(exc)
    if isinstance(exc, MemoryError):
        return (
            "not enough memory for this request; ask for less at once (a smaller --n, preset, --size, --tile, "
            "--samples or --batch-size, or fewer rows), or run it on a machine with more memory"
        )
    if isinstance(exc, OSError):
        where = " ".join(str(f) for f in (exc.filename, exc.filename2) if f)
        reason = exc.strerror or errno.errorcode.get(exc.errno or 0) or str(exc)
        denied = "check its permissions, or write somewhere else"
        again = "run the same command again (it resumes where it stopped)"
        free = free_space(exc.filename) if exc.filename else None
        free_text = "" if free is None else f" ({free / 2**20:.1f} MiB free)"
        hints = {
            errno.EACCES: denied,
            errno.EPERM: denied,
            errno.EROFS: denied,
            errno.ENOSPC: f"free some disk space{free_text} and {again}",
            errno.EIO: f"the device reported a read or write error: check the disk, then {again}",
        }
        hint = hints.get(exc.errno or 0, "check the path")
        return f"{reason}: {where or '?'}; {hint}"
    return None


def _usage_message(exc: Exception) -> str:
    """One line for a click usage error: its message (with typer's hint) and where the help is."""
    message = " ".join(exc.format_message().split())  # type: ignore[attr-defined]
    ctx = getattr(exc, "ctx", None)
    return f"{message.rstrip('.')} (see '{ctx.command_path} --help')" if ctx is not None else message


def run(argv: list[str] | None = None) -> int:
    """Run the CLI on ``argv`` (default ``sys.argv[1:]``) and return the exit status.

    Every expected failure (a usage error such as an unknown option or a value of the wrong
    type, a :class:`NanoctError`, bad numbers, a file-system error, not enough memory)
    becomes one ``error:`` line and status 2; Ctrl-C prints how to resume and
    gives 130; anything else is a bug: its traceback is printed with a request to report it
    (status 1).
    """
    try:
        # typer turns Ctrl-C into exit status 130, returned (not raised) without standalone mode
        code = app(args=argv, prog_name="nanoct", standalone_mode=False)
    except (KeyboardInterrupt, typer.Abort):
        code = 130
    except typer.Exit as exc:
        code = exc.exit_code
    except _CLICK.ClickException as exc:  # usage errors: unknown option or command, missing or bad value
        if type(exc).__name__ == "NoArgsIsHelpError":  # 'nanoct' alone: the help text
            exc.show()
            return 2
        typer.secho(f"error: {_usage_message(exc)}", fg=typer.colors.RED, err=True)
        return 2
    except Exception as exc:  # the one error boundary of the CLI
        message = expected_error(exc)
        if message is None:
            traceback.print_exc()
            typer.secho(
                "this is a bug in nanoct; please report it with the command and the traceback above",
                fg=typer.colors.RED,
                err=True,
            )
            return 1
        typer.secho(f"error: {_as_flags(' '.join(message.split()))}", fg=typer.colors.RED, err=True)
        return 2
    if code == 130:
        typer.secho("interrupted; run the same command again to resume", fg=typer.colors.YELLOW, err=True)
    return code if isinstance(code, int) else 0


def _show_warning(message: Warning | str, category: type[Warning], *args: Any, **kwargs: Any) -> None:
    """A warning on the command line: one ``warning:`` line, without Python's source location; nanoct's own
    with its parameters written as flags, another library's with its category."""
    text = " ".join(str(message).split())
    own = category is UserWarning or category.__module__.startswith("nanoct")  # nanoct warns with these
    line = _as_flags(text) if own else f"{category.__name__}: {text}"
    typer.secho(f"warning: {line}", fg=typer.colors.YELLOW, err=True)


def main() -> None:
    """Entry point: :func:`run` on the command line, exit with its status.

    Warnings print as ``warning:`` lines. After Ctrl-C the process ends at once (``os._exit``), as
    a kill would, which every command survives: the teardown of background threads still running
    (the stores' I/O loop, torch's workers) could otherwise abort it (status 134) after the resume
    hint was printed.
    """
    warnings.showwarning = _show_warning
    code = run()
    if code == 130:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(130)
    sys.exit(code)
