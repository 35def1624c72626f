"""Names of results and settings: the one place their grammar is built and parsed.

Every array of reconstructions in a store has a name; predictions of a network have a name
built from their input's. The grammar::

    reconstruction   <method>[_est-<source>[-<first>]][_eta<scale>]
                     fbp, dremel, resesop_eta0.8, resesop_est-residual, resesop_est-reference_eta1.2
    stack            <method>_stack  (``nanoct stack``: one motion and axis for all slices)
                     fbp_stack, dremel_stack
    prediction       <input>+<model>[@<train input>][%seed<S>]
                     dremel+unet, fbp+cinn-res@resesop (trained on resesop, applied to fbp),
                     resesop+unet%seed1 (training seed 1; seed 0 has no suffix)
    scaling run      <input>+<model>%n<K>x<steps>[%seed<S>]
                     dremel+unet%n640x640%seed1 (data-scaling study: first K training images)
    setting          parallel | fan | unperturbed  (the paper's tables: geometry kind and motion)

The ``_est-...`` and ``_eta<scale>`` parts belong to methods that use the model error eta
(:attr:`nanoct.recon.registry.MethodSpec.needs_eta`); :func:`reconstruction_name` gives the
default name of a batch run and :func:`reconstruct_command` the command that makes a name.

The names of predictions and settings need no method and live in :mod:`nanoct.core.names` (the store
itself tells predictions apart); those that a method and its parameters give, in
:mod:`nanoct.recon.names`. This module gathers both for the command line and for users; the
subpackages import each name from its home.
"""

from __future__ import annotations

from .core.names import (
    SETTINGS,
    ResultName,
    is_prediction,
    parse_name,
    prediction_name,
    scaling_name,
    seed_name,
    setting_key,
    strip_seed,
)
from .recon.names import eta_label, predict_command, reconstruct_command, reconstruction_name, stack_name

__all__ = [
    "SETTINGS",
    "ResultName",
    "eta_label",
    "is_prediction",
    "parse_name",
    "predict_command",
    "prediction_name",
    "reconstruct_command",
    "reconstruction_name",
    "scaling_name",
    "seed_name",
    "setting_key",
    "stack_name",
    "strip_seed",
]
