"""Reconstruction methods: FBP, Kaczmarz, Dremel, RESESOP-Kaczmarz.

The methods are listed in one place, :data:`nanoct.recon.registry.METHODS`; the array API, the
batch runner, the CLI and the study read it and run a method through
:meth:`~nanoct.recon.registry.MethodSpec.run`.

The solver contract
-------------------
Every method is a plain function ``method(op, sino, [eta,] *, **params) -> ReconResult``:

* ``op``: a :class:`~nanoct.core.geometry.Geometry` or an unperturbed
  :class:`~nanoct.core.operators.RayTransform` with ``oversample=1`` (the inexact model);
  ``sino``: the (K, L) sinogram, finite; methods that use the model error
  (``MethodSpec.needs_eta``) take ``eta`` of shape (K,) or (K, L) third.
* The same names for the same things: ``n_iter`` (number of sweeps; the limit for methods with
  a stop rule), ``relaxation`` (``None``: :func:`~nanoct.recon.rowaction.auto_relaxation`),
  ``order`` (view order), ``nonneg`` (keep ``x >= 0``), ``seed`` (random view order),
  ``residual`` (``"exact"`` or ``"running"`` history), ``x0`` (start image, default zeros),
  ``callback`` and ``matrix`` (a precomputed system matrix). A direct method (FBP) takes none
  of the iteration arguments.
* ``callback(iteration, x, motion)`` is called after each iteration with the 0-based
  iteration, the current (N, N) image (a view; do not modify) and the current motion estimate
  (methods that estimate motion) or ``None``; returning True stops the method.
* The result is a :class:`ReconResult`: ``image`` (N, N) float32; ``residuals`` one per
  iteration; ``stop_reason`` one of :data:`STOP_REASONS` (``"direct"``, ``"max_iter"``,
  ``"discrepancy"``, ``"callback"``); ``motion`` or None; ``params`` every parameter used,
  with ``"method"``.
* Each method's module declares its tunable parameters once, as a frozen dataclass
  (:class:`~nanoct.recon.params.MethodParams`: names, types, defaults, a numpydoc docstring);
  constructing it raises ``ValueError`` naming the parameter and its accepted values, and
  ``Params.check(op, **params)`` returns the normalised values the solver records. The solver
  calls it first, so bad values fail before any work; the batch runner calls it (through
  :meth:`~nanoct.recon.registry.MethodSpec.check`) before it writes anything. Parameters that
  only a batch run has (``eta``: where eta comes from; Dremel's ``motion_slices``,
  ``shifts_from``) are the registry entry's ``batch_params``
  (:mod:`nanoct.recon.eta_source`, :mod:`nanoct.recon.shared`) and never reach the solver.

Choices where the paper is ambiguous, with the measurements behind the defaults, are in
``docs/choices.md``.
"""

from .result import STOP_REASONS, ReconResult

__all__ = ["STOP_REASONS", "ReconResult"]
