"""Registry of reconstruction methods: the one place that lists them, and the one dispatch.

Each method is one :class:`MethodSpec`: the import paths of its solver and of its parameter
class (both imported only when used, so reading the registry costs nothing), whether it needs
the per-view model error ``eta``, whether it estimates motion, the parameters only a batch run
has, and a one-line help. Every caller (the array API, the batch runner, the CLI and the
conformance tests) checks parameters with :meth:`MethodSpec.check` and runs a method with
:meth:`MethodSpec.run`. To add a method, write its module (a solver following the contract of
:mod:`nanoct.recon` and a :class:`~nanoct.recon.params.MethodParams` subclass) and add one
entry (``docs/adding_a_method.md``)::

    "sart": MethodSpec("sart", "nanoct.recon.sart:sart", "nanoct.recon.sart:SartParams", "SART"),

Result names (``resesop_eta0.8``) and the commands that make them are in :mod:`nanoct.recon.names`.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ..core.errors import NanoctError
from ..core.geometry import Geometry

if TYPE_CHECKING:  # the registry imports no solver module: reading it costs nothing
    from .params import MethodParams
    from .result import ReconResult

__all__ = [
    "METHODS",
    "MethodSpec",
    "check_method_params",
    "method_help",
    "method_spec",
    "methods_with_eta",
    "methods_with_motion",
]


def _load(target: str) -> Any:
    module, _, attr = target.partition(":")
    return getattr(importlib.import_module(module), attr)


def _flag(param: str) -> str:
    return {"eta_scale": "--eta-scale", "eta": "--eta"}.get(param, f"--param {param}")


@dataclass(frozen=True)
class MethodSpec:
    """A reconstruction method: where it lives and how the tools treat it.

    Attributes
    ----------
    name : str
        The method's name (``--method``).
    target : str
        ``"module:function"`` of the solver ``f(op, sino[, eta], **params) -> ReconResult``.
    params : str
        ``"module:Class"`` of its :class:`~nanoct.recon.params.MethodParams` (the parameters a
        user may set).
    help : str
        One line for the CLI.
    needs_eta : bool
        The solver takes the per-view model error ``eta`` as third argument (scaled by the
        ``eta_scale`` parameter, the CLI's ``--eta-scale``).
    estimates_motion : bool
        The result carries per-view shifts (stored as ``reconstructions/<name>_shifts``).
    batch_params : str, optional
        ``"module:Class"`` of the parameters the batch runner uses itself and does not pass to
        the solver (where eta or a shared motion comes from).
    parallel_only : bool
        The method handles parallel-beam geometries only.
    """

    name: str
    target: str
    params: str
    help: str
    needs_eta: bool = False
    estimates_motion: bool = False
    batch_params: str | None = None
    parallel_only: bool = False

    def solver(self) -> Any:
        """The solver function (imported on first use)."""
        return _load(self.target)

    def params_class(self) -> type[MethodParams]:
        """The parameter class (imported on first use)."""
        return _load(self.params)

    def parameter_names(self) -> tuple[str, ...]:
        """The parameters a user may set: the solver's, then the batch runner's."""
        return self.solver_parameter_names() + self.batch_parameter_names()

    def solver_parameter_names(self) -> tuple[str, ...]:
        """The parameters passed to the solver."""
        return self.params_class().names()

    def batch_parameter_names(self) -> tuple[str, ...]:
        """The parameters the batch runner uses itself (not passed to the solver)."""
        return () if self.batch_params is None else _load(self.batch_params).names()

    def parameter_help(self) -> dict[str, str]:
        """``name -> one line`` for every parameter (from the parameter classes' docstrings)."""
        helps = dict(self.params_class().help())
        if self.batch_params is not None:
            helps.update(_load(self.batch_params).help())
        return helps

    def check(self, params: dict[str, Any], geometry: Geometry) -> dict[str, Any]:
        """Check the user parameters for ``geometry`` before any work is done.

        Returns
        -------
        dict
            The parameters with defaults filled in and values normalised.

        Raises
        ------
        NanoctError
            For an unknown parameter name or a bad value; the message names the CLI flag
            (``--param NAME`` or ``--eta-scale``) and the accepted names or values.
        """
        accepted = self.parameter_names()
        unknown = sorted(set(params) - set(accepted))
        if unknown:
            raise NanoctError(
                f"{', '.join(_flag(u) for u in unknown)}: not a parameter of --method {self.name}; "
                f"accepted: {', '.join(accepted)}"
            )
        batch = set(self.batch_parameter_names())
        try:
            checked = self.params_class().check(geometry, **{k: v for k, v in params.items() if k not in batch})
            if self.batch_params is not None:
                batch_values = {k: v for k, v in params.items() if k in batch}
                checked.update(_load(self.batch_params).check(geometry, **batch_values))
            return checked
        except (TypeError, ValueError) as exc:
            name = str(exc).partition("=")[0]
            flag = _flag(name) if name in accepted else "a parameter"
            raise NanoctError(f"{flag} of --method {self.name}: {exc}") from exc

    def check_eta(self, eta: Any) -> None:
        """Raise ``ValueError`` unless ``eta`` is given exactly when the method needs it."""
        if self.needs_eta and eta is None:
            raise ValueError(f"{self.name} needs the per-view model error eta=; estimate it with nanoct.recon.eta")
        if not self.needs_eta and eta is not None:
            raise ValueError(f"{self.name} takes no eta")

    def run(self, op: Any, sinogram: Any, eta: Any = None, **params: Any) -> ReconResult:
        """Run the method: ``solver(op, sinogram[, eta], **params)``.

        ``params`` are the solver's parameters and its other keyword arguments (``x0``,
        ``callback``, ``matrix``, ``shifts0``, RESESOP's ``shifts``); batch parameters do not go here.

        Raises
        ------
        ValueError
            If ``eta`` is missing for a method that needs it, or given to one that does not.
        """
        self.check_eta(eta)
        data = (sinogram, eta) if self.needs_eta else (sinogram,)
        return self.solver()(op, *data, **params)


def _spec(name: str, module: str, params: str, help: str, **flags: Any) -> MethodSpec:
    return MethodSpec(name, f"nanoct.recon.{module}:{name}", f"nanoct.recon.{module}:{params}", help, **flags)


#: Registered methods, in the order the CLI lists them.
METHODS: dict[str, MethodSpec] = {
    spec.name: spec
    for spec in (
        _spec("fbp", "fbp", "FbpParams", "filtered back projection (direct)"),
        _spec(
            "gridrec",
            "gridrec",
            "GridrecParams",
            "FBP in Fourier space, non-uniform FFT (parallel beam)",
            parallel_only=True,
        ),
        _spec("kaczmarz", "kaczmarz", "KaczmarzParams", "Kaczmarz (ART) sweeps"),
        _spec(
            "dremel",
            "dremel",
            "DremelParams",
            "Kaczmarz with per-view shift estimation (Algorithm 1)",
            estimates_motion=True,
            batch_params="nanoct.recon.shared:SharedMotionParams",
        ),
        _spec(
            "resesop",
            "resesop",
            "ResesopParams",
            "RESESOP-Kaczmarz with model error eta (Algorithm 2)",
            needs_eta=True,
            batch_params="nanoct.recon.eta_source:EtaSourceParams",
        ),
    )
}


def methods_with_eta() -> tuple[str, ...]:
    """Names of the methods that take the model error eta (and ``--eta-scale``)."""
    return tuple(name for name, spec in METHODS.items() if spec.needs_eta)


def methods_with_motion() -> tuple[str, ...]:
    """Names of the methods that estimate per-view motion (their results carry shifts)."""
    return tuple(name for name, spec in METHODS.items() if spec.estimates_motion)


def method_help() -> str:
    """One line per method, ``name: help``, for the CLI."""
    return "; ".join(f"{name}: {spec.help}" for name, spec in METHODS.items())


def method_spec(method: str) -> MethodSpec:
    """The registry entry of ``method``.

    Raises
    ------
    NanoctError
        If no method of that name is registered; the message lists the registered ones.
    """
    if method not in METHODS:
        raise NanoctError(f"--method {method!r} is unknown; use one of {', '.join(METHODS)}")
    return METHODS[method]


def check_method_params(method: str, params: dict[str, Any], geometry: Geometry) -> dict[str, Any]:
    """Check the user parameters of ``method`` for ``geometry`` (:meth:`MethodSpec.check`)."""
    return method_spec(method).check(params, geometry)
