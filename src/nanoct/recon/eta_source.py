"""Where a method that needs the model error eta (RESESOP) gets it in a batch run: the ``eta`` parameter.

``eta`` (the CLI's ``--eta``) is one of

``"true"`` (default of a simulated data set)
    The store's own eta (only a simulation has it).
``"estimate:residual"`` or ``"estimate:residual=NAME"`` (default of an imported scan: ``dremel``)
    Per sample from a first reconstruction ``reconstructions/NAME`` (default ``dremel``):
    :func:`nanoct.recon.eta.eta_from_residual` (scale 1, on measured data its default 0.5);
    ``--eta-scale`` scales it like any eta. On measured data (:func:`carries_motion`), when the
    first reconstruction has a motion (Dremel's), RESESOP runs after that motion, as ``nanoct
    stack --method resesop`` does: its model carries the motion (``resesop(..., shifts=)``) and
    eta is the residual left after it (:meth:`EtaPlan.motion`). A simulation keeps the paper's
    unperturbed model and the residual before the motion.
``"estimate:reference=PATH"``
    The per-view median of the eta of a simulated reference store of the same geometry
    (:func:`nanoct.recon.eta.eta_from_reference`), the same for every sample.

:class:`EtaSourceParams` checks the syntax with the method's parameters; :func:`plan_eta` checks
what depends on the store (the first reconstruction exists, the reference store matches) before
anything is written, and computes what is shared by all samples.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import NanoctError
from ..core.geometry import Geometry
from ..io.store import DataStore
from ..io.store_recon import check_name
from .eta import eta_from_reference, eta_from_residual
from .measured import looks_measured
from .names import reconstruct_command
from .params import MethodParams
from .registry import methods_with_motion

__all__ = ["EtaPlan", "EtaSourceParams", "carries_motion", "plan_eta"]

_SYNTAX = "use true, estimate:residual[=RECONSTRUCTION] or estimate:reference=STORE"


def _normalise(eta: Any) -> str:
    text = str(eta).strip()
    kind, _, arg = text.partition("=")
    if text == "true":
        return "true"
    if kind == "estimate:residual":
        try:
            check_name(arg or "dremel")
        except NanoctError as exc:
            raise ValueError(f"eta={eta!r}: the first reconstruction's name is not valid; {_SYNTAX}") from exc
        return f"estimate:residual={arg or 'dremel'}"
    if kind == "estimate:reference" and arg:
        return f"estimate:reference={Path(arg).resolve()}"
    raise ValueError(f"eta={eta!r} is unknown; {_SYNTAX}")


@dataclass(frozen=True)
class EtaSourceParams(MethodParams):
    """Batch parameters of a method that uses eta (used by the batch runner, not the solver).

    Parameters
    ----------
    eta : str, default "true"
        Where eta comes from: ``true`` (the store's), ``estimate:residual[=RECONSTRUCTION]`` (from a
        first reconstruction, default dremel) or ``estimate:reference=STORE`` (a simulated store's);
        normalised (the first reconstruction named, a reference path made absolute).
    """

    eta: str = "true"

    def __post_init__(self) -> None:
        self._set("eta", _normalise(self.eta))


@dataclass(frozen=True)
class EtaPlan:
    """How each sample of a batch gets its eta.

    Attributes
    ----------
    kind : {"true", "residual", "reference"}
    first : str or None
        The first reconstruction of the residual estimator.
    reference : ndarray of shape (K,) or None
        The reference estimate, the same for every sample.
    """

    kind: str
    first: str | None = None
    reference: np.ndarray | None = None

    def motion(self, store: Any, index: int) -> np.ndarray | None:
        """The motion of the first reconstruction of sample ``index`` (Dremel's shifts), or None.

        None unless the residual estimator's first reconstruction was made by a method that
        estimates motion (:func:`~nanoct.recon.registry.methods_with_motion`).
        """
        if self.kind != "residual":
            return None
        if store.reconstruction_params(self.first).get("method") not in methods_with_motion():
            return None
        return store.read_shifts(self.first, [index])[0].astype(np.float64)

    def eta(self, store: Any, index: int, sample: Any, shifts: Any = None) -> np.ndarray:
        """The (unscaled) eta of sample ``index`` of ``store`` (``sample`` its data).

        ``shifts``: the motion RESESOP's model carries (:meth:`motion`); the residual estimate
        is then taken after it (:func:`~nanoct.recon.eta.eta_from_residual`'s ``shifts``).
        """
        if self.kind == "true":
            return sample.eta
        if self.kind == "reference":
            return self.reference  # type: ignore[return-value]
        first = store.read_reconstruction(self.first, [index])[0]
        return eta_from_residual(store.geometry, sample.sinogram, first, shifts=shifts)


def carries_motion(sinogram: Any, measured: str = "auto") -> bool:
    """Whether a batch run treats ``sinogram`` as measured data: RESESOP after the first reconstruction's motion.

    The methods' own rule (:mod:`~nanoct.recon.measured`): ``measured`` ``"on"`` or
    ``"extend"``, or ``"auto"`` where :func:`~nanoct.recon.measured.looks_measured` (an open
    beam not at zero, or an object cut by the detector edges), the rule ``nanoct stack`` uses
    per slice; a simulation keeps the unperturbed model and a held joint motion.
    """
    return measured in ("on", "extend") or (measured == "auto" and looks_measured(np.asarray(sinogram)))


def _reference_eta(path: str, geometry: Geometry) -> np.ndarray:
    ref = DataStore.open(path)
    if ref.geometry != geometry:
        raise NanoctError(
            f"--eta estimate:reference={path}: the reference store has another geometry ({ref.geometry.kind}, "
            f"{ref.geometry.n_angles} views, {ref.geometry.n_det} detector pixels, image {ref.geometry.n}); "
            "simulate one with the data set's preset (nanoct generate --preset ...)"
        )
    if ref.is_scan:
        raise NanoctError(f"--eta estimate:reference={path} is an imported scan without eta; use a simulated store")
    done = np.flatnonzero(ref.done)
    if done.size == 0:
        raise NanoctError(f"--eta estimate:reference={path} has no generated samples; finish 'nanoct generate' first")
    return eta_from_reference(ref.read_array("eta", done))


def plan_eta(store: Any, eta: str, indices: np.ndarray) -> EtaPlan:
    """Check the eta source ``eta`` (normalised) for the samples ``indices`` of ``store``; prepare it.

    Raises
    ------
    NanoctError
        The store has no eta (an imported scan) and ``eta`` is ``true``; the first
        reconstruction is missing or incomplete (the message gives the command that makes it);
        the reference store is missing, of another geometry or without eta.
    """
    kind, _, arg = eta.partition("=")
    if kind == "true":
        if store.is_scan:
            raise NanoctError(
                f"{store.path} is an imported scan: it has no true eta; estimate it with --eta estimate:residual "
                "(after --method dremel) or --eta estimate:reference=STORE (a simulated store of the same geometry)"
            )
        return EtaPlan("true")
    if kind == "estimate:reference":
        return EtaPlan("reference", reference=_reference_eta(arg, store.geometry))
    if arg not in store.reconstruction_names() or not store.reconstruction_done(arg, indices).all():
        raise NanoctError(
            f"--eta estimate:residual needs the first reconstruction '{arg}' of every sample to reconstruct; "
            f"make it first: {reconstruct_command(store.path, arg)}"
        )
    return EtaPlan("residual", first=arg)
