"""A method's user parameters, declared once: a frozen dataclass that checks itself.

Each reconstruction method declares the parameters a user may set as one frozen dataclass
(a subclass of :class:`MethodParams`): field names, types and defaults, and a numpydoc
``Parameters`` section in its docstring. Everything else comes from it:

* constructing it checks and normalises every value (a ``ValueError`` names the parameter,
  ``name=value``, and what is accepted); :meth:`MethodParams.resolve` fills in what depends
  on the geometry (e.g. the default relaxation) and returns the values the solver uses;
* :meth:`MethodParams.check` is what the solver, the registry and the batch runner call;
* :meth:`MethodParams.names` and :meth:`MethodParams.help` give the registry's parameter lists
  and the CLI's ``nanoct methods`` text.

A solver then takes its parameters as keyword arguments (``dremel(op, sino, n_iter=8)``)
and starts with ``p = DremelParams.check(op, **params)``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, fields
from typing import Any

from ..core.geometry import Geometry
from ..core.operators import RayTransform

__all__ = ["MethodParams", "resolve_geometry"]


def resolve_geometry(op: Geometry | RayTransform) -> Geometry:
    """Accept a :class:`Geometry` or an unperturbed :class:`RayTransform` with ``oversample=1``."""
    if isinstance(op, Geometry):
        return op
    if isinstance(op, RayTransform):
        if op.motion is not None:
            raise ValueError(
                "the reconstruction methods use the unperturbed (inexact) operator; "
                "pass a RayTransform without motion, or its geometry"
            )
        if op.oversample != 1:
            raise ValueError("pass a RayTransform with oversample=1 (the reconstruction grid)")
        return op.geometry
    raise ValueError(f"expected a Geometry or RayTransform, got {type(op).__name__}")


_ENTRY = re.compile(r"^    (\w+) : (.*)$")


@dataclass(frozen=True)
class MethodParams:
    """Base of the parameter classes; a subclass's fields are its method's parameters."""

    def _set(self, name: str, value: Any) -> None:
        """Store a normalised value (the dataclass is frozen)."""
        object.__setattr__(self, name, value)

    def resolve(self, geometry: Geometry) -> dict[str, Any]:
        """The values the solver uses for ``geometry`` (here: the fields as they are)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The parameters a user may set, in declaration order."""
        return tuple(f.name for f in fields(cls))

    @classmethod
    def check(cls, op: Geometry | RayTransform, **values: Any) -> dict[str, Any]:
        """Check ``values`` for the geometry of ``op``; return every parameter, normalised.

        Raises
        ------
        TypeError
            For a name that is not a parameter of this method.
        ValueError
            For a bad value (the message starts with ``name=value``).
        """
        unknown = sorted(set(values) - set(cls.names()))
        if unknown:
            raise TypeError(f"unexpected parameter(s) {', '.join(unknown)}; accepted: {', '.join(cls.names())}")
        geometry = resolve_geometry(op)
        return cls(**values).resolve(geometry)

    @classmethod
    def help(cls) -> dict[str, str]:
        """``name -> the first sentence of its description`` (plain text) from the class docstring."""
        entries: dict[str, list[str]] = {}
        current: list[str] | None = None
        for line in (cls.__doc__ or "").splitlines():
            match = _ENTRY.match(line)
            if match:
                current = entries.setdefault(match.group(1), [])
            elif current is not None and line.startswith("        "):
                current.append(line.strip())
            elif line.strip():
                current = None
        out = {}
        for name in cls.names():
            text = _plain(" ".join(entries.get(name, [])))
            out[name] = _SENTENCE.split(text, maxsplit=1)[0].rstrip(".") or "(undocumented)"
        return out


_SENTENCE = re.compile(r"(?<=[a-z0-9)\]\"'])\.\s+(?=[A-Z(\"])")


def _plain(text: str) -> str:
    """rST to plain text: ``:func:`~a.b.c``` -> ``c``, ````x```` -> ``x``."""
    text = re.sub(r":\w+:`~?(?:[\w.]+\.)?([\w]+)`", r"\1", text)
    return text.replace("``", "")
