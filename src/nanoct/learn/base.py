"""The interface every post-processing network implements, so one trainer serves them all.

A post-processor maps a first reconstruction ``x_tilde`` (batch, 1, H, W) to an estimate of
the ground truth ``x``. Networks that model the whole conditional distribution p(x | x_tilde)
also return a pixel-wise standard deviation.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

__all__ = ["VALUE_SCALES", "PostProcessor", "image_range"]

#: What a training quantity in the images' units is measured against: ``"absolute"`` (the units
#: themselves, the paper's) or ``"range"`` (each target image's max - min, :func:`image_range`, so
#: faint and bright images count alike: scan slices whose contrast differs by orders of magnitude).
VALUE_SCALES = ("absolute", "range")


def image_range(x: torch.Tensor) -> torch.Tensor:
    """Each image's max - min of a batch ``x`` (B, 1, H, W), detached, as a (B, 1, 1, 1) tensor of at least
    1e-6 (so that a constant image does not divide by zero)."""
    spread = x.detach().amax(dim=(1, 2, 3), keepdim=True) - x.detach().amin(dim=(1, 2, 3), keepdim=True)
    return spread.clamp_min(1e-6)


class PostProcessor(nn.Module):
    """Base class of post-processing networks.

    Subclasses set ``name`` (the registry name, e.g. ``"unet"``), store the keyword arguments
    they were built with in ``self.hparams`` (a JSON-compatible dict, so a checkpoint can
    rebuild and validate the architecture), and implement :meth:`loss` and
    :meth:`reconstruct`. Inputs of any size H, W are accepted: networks that need multiples of
    2^scales pad internally and crop their outputs back.
    """

    name: str = ""
    #: True for networks whose :meth:`reconstruct` returns a pixel-wise std (sampling models).
    has_uncertainty: bool = False

    def __init__(self, **hparams: Any) -> None:
        super().__init__()
        self.hparams: dict[str, Any] = dict(hparams)

    def loss(self, x_tilde: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, dict[str, float]]:
        """Training loss of a batch and named scalars to log (e.g. ``{"mse": ...}``)."""
        raise NotImplementedError

    @torch.no_grad()
    def reconstruct(self, x_tilde: torch.Tensor, **kwargs: Any) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Estimate ``x`` from ``x_tilde``: returns (mean, std), std None for point estimators."""
        raise NotImplementedError
