"""Groups of options declared once, as a frozen dataclass whose fields are typer options.

A command takes a group as one typed parameter (``reading: ScanReading``); :func:`flag_groups`
shows typer the group's fields as the command's own options, in the group's place, and builds
the dataclass from their values before the command runs. :func:`given` lists the options of a
group that were given a value other than their default, as the flags a user typed.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable, Iterable
from dataclasses import Field, field, fields, is_dataclass
from typing import Any, TypeVar, get_type_hints

import typer

F = TypeVar("F", bound=Callable[..., Any])


def option(default: Any, *param_decls: str, **kwargs: Any) -> Any:
    """A dataclass field that is a typer option: ``option(default, "--flag", help=...)`` as ``typer.Option``.

    The field's default is the option's; the option itself is kept in the field's metadata, for
    :func:`flag_groups` and :func:`given`.
    """
    info = typer.Option(default, *param_decls, **kwargs)
    if isinstance(default, list):  # a repeatable option: a fresh list per instance
        return field(default_factory=lambda: list(default), metadata={"option": info})
    return field(default=default, metadata={"option": info})


def _is_group(annotation: Any) -> bool:
    return isinstance(annotation, type) and is_dataclass(annotation)


def _option_of(item: Field[Any]) -> Any:
    return item.metadata["option"]


def long_flag(group: Any, name: str) -> str:
    """The long flag (``--open-beam``) of the field ``name`` of an options group (class or instance)."""
    item = next(f for f in fields(group) if f.name == name)
    return next(d for d in _option_of(item).param_decls if d.startswith("--"))


def given(group: Any, names: Iterable[str] | None = None) -> dict[str, Any]:
    """The options of ``group`` (all, or those named, in their order there) whose value is not their default,
    as ``{flag: value}``; a repeatable option's value as a list."""
    chosen = None if names is None else list(names)
    found = {}
    items = {f.name: f for f in fields(group)}
    for name in chosen if chosen is not None else list(items):
        value, default = getattr(group, name), _option_of(items[name]).default
        if isinstance(default, list):
            value = list(value)
        if value != default:
            found[long_flag(group, name)] = value
    return found


def flag_groups(place: dict[str, str] | None = None) -> Callable[[F], F]:
    """Decorate a command whose parameters include options groups (dataclasses of :func:`option` fields).

    Typer sees each group's fields as options of the command, in the group's place among its
    parameters; the command receives the group built from their values. ``place`` moves an option
    (by its parameter name) to just after another one, where a command has always listed it there.
    """

    def decorate(command: F) -> F:
        hints = get_type_hints(command)
        groups: dict[str, type] = {}
        params: list[inspect.Parameter] = []
        for param in inspect.signature(command).parameters.values():
            annotation = hints.get(param.name, param.annotation)
            if not _is_group(annotation):
                params.append(param.replace(kind=inspect.Parameter.KEYWORD_ONLY, annotation=annotation))
                continue
            groups[param.name] = annotation
            types = get_type_hints(annotation)
            params += [
                inspect.Parameter(
                    f.name, inspect.Parameter.KEYWORD_ONLY, default=_option_of(f), annotation=types[f.name]
                )
                for f in fields(annotation)
            ]
        for name, after in (place or {}).items():
            moved = next(p for p in params if p.name == name)
            params.remove(moved)
            params.insert(next(i for i, p in enumerate(params) if p.name == after) + 1, moved)

        @functools.wraps(command)
        def run(**values: Any) -> Any:
            for name, group in groups.items():
                values[name] = group(**{f.name: values.pop(f.name) for f in fields(group)})
            return command(**values)

        run.__signature__ = inspect.Signature(params, return_annotation=None)  # type: ignore[attr-defined]
        run.__annotations__ = {p.name: p.annotation for p in params} | {"return": None}
        return run  # type: ignore[return-value]

    return decorate


__all__ = ["flag_groups", "given", "long_flag", "option"]
