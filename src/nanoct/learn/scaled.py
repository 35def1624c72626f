"""Per-image intensity normalisation around any post-processing network.

Measured scans hold slices whose intensities differ by two orders of magnitude (a bright
section of a sample and a faint one of the same stack), and a training set matched to a scan
(``nanoct generate --like``) mixes phantoms of those scales. A network trained on such data in
absolute units sees the faint images only as a small term of its loss. :class:`ImageScaled`
divides each input ``x_tilde`` and its target by a scale taken from the input alone,

    s = 2 * (99th percentile of |x_tilde|),  floored at 1e-6,

trains and runs the wrapped network on ``(x_tilde / s, x / s)``, and multiplies its mean and std
back by ``s``. The wrapped model is then equivariant to the intensity scale of its input. For a
likelihood-trained (flow) network the loss is the negative log-likelihood of ``x / s``, which
differs from that of ``x`` by ``H * W * log s``, a term that does not depend on the network's
parameters: the gradients are those of the likelihood of ``x``. For an MSE-trained network the
loss is ``MSE / s**2``: every image counts in its own units. The factor 2 keeps the targets of a
sigmoid-output UNet inside (0, 1).

Choose it at training time with ``nanoct train ... --param normalize=image``; the checkpoint
records it and :func:`nanoct.learn.models.build_model` rebuilds it. A tiled prediction takes the
scale from the whole image (:func:`image_scale` on it) and passes it to every tile, so the
tiles of one image share one scale.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from .base import PostProcessor

__all__ = ["SCALE_FACTOR", "SCALE_FLOOR", "SCALE_QUANTILE", "ImageScaled", "image_scale"]

SCALE_QUANTILE = 0.99
SCALE_FACTOR = 2.0
SCALE_FLOOR = 1e-6


def image_scale(x_tilde: torch.Tensor | np.ndarray) -> torch.Tensor:
    """The scale ``s`` of each image of a batch (B, 1, H, W), shape (B, 1, 1, 1) (see the module docstring).

    A single image (H, W) as a numpy array gives a (1, 1, 1, 1) tensor.
    """
    x = torch.as_tensor(np.asarray(x_tilde, np.float32)[None, None]) if isinstance(x_tilde, np.ndarray) else x_tilde
    q = torch.quantile(x.detach().abs().reshape(x.shape[0], -1).float(), SCALE_QUANTILE, dim=1)
    return (SCALE_FACTOR * q).clamp_min(SCALE_FLOOR).view(-1, 1, 1, 1)


class ImageScaled(PostProcessor):
    """A post-processor run on intensity-normalised images (see the module docstring).

    Parameters
    ----------
    inner : PostProcessor
        The network that sees the normalised images; its registry name, ``has_uncertainty`` and
        hyperparameters are this model's, with ``normalize="image"`` added.
    """

    def __init__(self, inner: PostProcessor) -> None:
        super().__init__(**inner.hparams, normalize="image")
        self.inner = inner
        self.name = inner.name
        self.has_uncertainty = inner.has_uncertainty

    def loss(self, x_tilde: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, dict[str, float]]:
        """The wrapped network's loss on ``(x_tilde / s, x / s)``."""
        s = image_scale(x_tilde).to(x_tilde.dtype)
        return self.inner.loss(x_tilde / s, x / s)

    @torch.no_grad()
    def data_init(self, x_tilde: torch.Tensor, x: torch.Tensor) -> None:
        """The wrapped network's data-dependent initialisation on normalised images (if it has one)."""
        if hasattr(self.inner, "data_init"):
            s = image_scale(x_tilde).to(x_tilde.dtype)
            self.inner.data_init(x_tilde / s, x / s)

    @torch.no_grad()
    def reconstruct(
        self, x_tilde: torch.Tensor, *, scale: float | None = None, **kwargs: Any
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Mean (and std) of the wrapped network on ``x_tilde / s``, times ``s``.

        Parameters
        ----------
        x_tilde : tensor (B, 1, H, W)
        scale : float, optional
            Use this scale for every image of the batch (a tile of a larger image gets the
            whole image's); default: each image's own :func:`image_scale`.
        **kwargs
            Passed to the wrapped network's ``reconstruct`` (``n_samples``, ``seed``, ...).
        """
        if scale is None:
            s = image_scale(x_tilde).to(x_tilde.device, x_tilde.dtype)
        else:
            s = torch.full((x_tilde.shape[0], 1, 1, 1), float(scale), dtype=x_tilde.dtype, device=x_tilde.device)
        mean, std = self.inner.reconstruct(x_tilde / s, **kwargs)
        return mean * s, None if std is None else std * s
