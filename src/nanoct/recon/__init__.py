"""Reconstruction methods: FBP, Kaczmarz, Dremel, RESESOP-Kaczmarz.

The methods are listed in one place, :data:`nanoct.recon.registry.METHODS`; the batch runner,
the CLI and the study read it.

The solver contract
-------------------
Every method is a plain function ``method(op, sino, [eta,] *, **params) -> ReconResult``:

* ``op``: a :class:`~nanoct.geometry.Geometry` or an unperturbed
  :class:`~nanoct.operators.RayTransform` with ``oversample=1`` (the inexact model);
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
* Each method's module has ``check_params(op, **params)`` with the same keyword names and
  defaults as the solver's tunable parameters; it raises ``ValueError`` naming the parameter
  and its accepted values, and returns the normalised values the solver records. The solver
  calls it first, so bad values fail before any work; the batch runner calls it before it
  writes anything. Parameters that only a batch run has (``eta``: where eta comes from;
  Dremel's ``motion_slices``, ``shifts_from``) are checked by the registry's ``batch_checker``
  (:mod:`nanoct.recon.eta_source`, :mod:`nanoct.recon.shared`) and never reach the solver.

Choices where the paper is ambiguous, with the measurements behind the defaults, are in
``docs/choices.md``.
"""

from .result import STOP_REASONS, ReconResult

__all__ = ["STOP_REASONS", "ReconResult"]
