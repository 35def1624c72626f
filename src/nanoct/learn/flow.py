"""The shared base of the conditional invertible networks (CiNN, CiUNet and their residual variants).

:class:`ConditionalFlow` holds the likelihood, sampling and checkpoint logic; the subclasses only
build their FrEIA graphs and conditioners (:mod:`nanoct.learn.cinn`, :mod:`nanoct.learn.ciunet`).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import FrEIA.framework as Ff
import numpy as np
import torch

from nanoct.learn.base import VALUE_SCALES, PostProcessor, image_range
from nanoct.learn.invertible import (
    ConditionalScale,
    RunningMoments,
    crop,
    finish_actnorm_init,
    gaussian_nll_bpd,
    pad_to_multiple,
    scale_form,
)

__all__ = [
    "TARGET_NOISE_SCALES",
    "CheckpointMismatchError",
    "ConditionalFlow",
    "parametrize_cached",
    "target_noise_std",
]

#: What ``target_noise`` is a fraction of: ``"absolute"`` (a std in the images' units, the
#: paper's data) or ``"range"`` (each target image's max - min, so faint and bright images get
#: noise of the same relative size, as a data set of scan patches of very different contrast needs).
TARGET_NOISE_SCALES = VALUE_SCALES


def _jsonable(value: Any) -> Any:
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    return value


def _location_weight(hparams: dict[str, Any], form: str | None) -> float:
    """The checked ``location_weight`` of a flow's ``hparams`` (0 if absent)."""
    weight = float(hparams.get("location_weight", 0.0))
    if not weight >= 0:
        raise ValueError(f"location_weight must be >= 0, got {weight}")
    if weight > 0 and form != "location":
        raise ValueError(
            f"location_weight = {weight} needs conditional_scale='location' (the layer whose location it "
            f"trains), got conditional_scale={hparams.get('conditional_scale', False)!r}"
        )
    return weight


def _target_noise(hparams: dict[str, Any]) -> tuple[float, str]:
    """The checked ``target_noise`` and ``target_noise_scale`` of a flow's ``hparams`` (0, absolute if absent).

    The paper's ``"absolute"`` is taken out of ``hparams``: it is recorded only when another is
    chosen, so that the runs recorded before the option existed resume.
    """
    noise = float(hparams.get("target_noise", 0.0))
    if noise < 0:
        raise ValueError(f"target_noise must be >= 0, got {noise}")
    scale = str(hparams.get("target_noise_scale", "absolute"))
    if scale not in TARGET_NOISE_SCALES:
        raise ValueError(f"target_noise_scale must be one of {', '.join(TARGET_NOISE_SCALES)}, got {scale!r}")
    if scale == "absolute":
        hparams.pop("target_noise_scale", None)
    return noise, scale


def target_noise_std(x: torch.Tensor, target_noise: float, scale: str) -> float | torch.Tensor:
    """Std of the noise a flow adds to the target images ``x`` (B, 1, H, W) in training.

    Parameters
    ----------
    x : torch.Tensor
        Target images.
    target_noise : float
        The flow's ``target_noise``.
    scale : {"absolute", "range"}
        The flow's ``target_noise_scale`` (:data:`TARGET_NOISE_SCALES`).

    Returns
    -------
    float or torch.Tensor
        ``target_noise`` itself (``"absolute"``), or ``target_noise`` times each image's
        max - min (``"range"``; a (B, 1, 1, 1) tensor, at least ``target_noise * 1e-6`` so that a
        constant image keeps a non-degenerate density).
    """
    if scale == "absolute":
        return target_noise
    return target_noise * image_range(x)


class CheckpointMismatchError(ValueError, RuntimeError):
    """A state dict of another architecture or size (a ``ValueError``; also a ``RuntimeError``,
    what ``torch.nn.Module.load_state_dict`` raises, so existing handlers keep working)."""


class ConditionalFlow(PostProcessor):
    """Shared likelihood, sampling and checkpoint logic of CiNN/CiUNet and their residual variants.

    Subclasses build their FrEIA graph(s) and a conditioning network, set ``self.multiple`` (the
    padded size must be a multiple of it) and implement :meth:`_conditions`,
    :meth:`_flow_forward` (padded image -> flat latent of the same size, log|det J|) and
    :meth:`_flow_inverse`. Graphs are built once for the smallest valid size and run at any
    multiple of it: all their layers are size-agnostic (convolutional couplings, resampling,
    channel splits/permutations, the ActNorm above); anything size-dependent (flattening) is
    done outside the graph.

    Conventions:

    * The invertible path sees ``v = x`` (``residual = False``) or ``v = x_tilde - x``
      (``residual = True``, the paper's "Res" variants).
    * Padding: ``v`` is padded at the bottom/right with zeros to a multiple of ``self.multiple``
      (for phantoms and residuals 0 is the natural background value), the condition
      ``x_tilde`` by reflection. Padded pixels are ordinary flow dimensions: in training mode
      they receive the same target noise as the image, so their density is non-degenerate;
      samples are cropped back, so only the marginal over the real pixels is used.
    * ``loss`` is the NLL in bits per dimension over all Hp*Wp flow dimensions (padding
      included; 0.8% of them at 255 -> 256), without the +8 offset of 8-bit dequantisation.
    """

    has_uncertainty = True

    residual: bool = False
    multiple: int = 1

    def __init__(self, **hparams: Any) -> None:
        super().__init__(**{k: _jsonable(v) for k, v in hparams.items()})
        self.target_noise, self.target_noise_scale = _target_noise(self.hparams)
        #: Form of the pixel-wise conditional scale (None: none), from ``conditional_scale``.
        self.conditional_form = scale_form(self.hparams.get("conditional_scale", False))
        self.location_weight = _location_weight(self.hparams, self.conditional_form)

    def _append_conditional_scale(self, nodes: list[Ff.Node], h: int, w: int) -> list[Ff.ConditionNode]:
        """Append the :class:`ConditionalScale` node to ``nodes`` if the network has one.

        Returns its condition node (the head's (2, h, w) map; empty list without the layer).
        """
        if self.conditional_form is None:
            return []
        cond = Ff.ConditionNode(2, h, w, name="cond_full")
        kwargs = {"form": self.conditional_form}
        nodes.append(Ff.Node(nodes[-1], ConditionalScale, kwargs, conditions=cond, name="scale_in"))
        return [cond]

    # -- to implement -------------------------------------------------------------------------
    def _conditions(self, x_tilde_padded: torch.Tensor) -> list[torch.Tensor]:
        """Condition tensors in the order of the graph's condition nodes."""
        raise NotImplementedError

    def _flow_forward(self, vp: torch.Tensor, conds: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """Padded (B, 1, Hp, Wp) -> (z (B, Hp*Wp), log|det J| (B,))."""
        raise NotImplementedError

    def _flow_inverse(self, z: torch.Tensor, conds: list[torch.Tensor], size: tuple[int, int]) -> torch.Tensor:
        """z (B, Hp*Wp) -> padded (B, 1, Hp, Wp), where size = (Hp, Wp)."""
        raise NotImplementedError

    # -- input checks ---------------------------------------------------------------------------
    def _check_condition(self, x_tilde: torch.Tensor) -> None:
        if not torch.is_tensor(x_tilde) or x_tilde.dim() != 4 or x_tilde.shape[1] != 1:
            shape = tuple(x_tilde.shape) if torch.is_tensor(x_tilde) else type(x_tilde).__name__
            raise ValueError(f"{self.name}: the condition x_tilde must be a (batch, 1, H, W) tensor, got {shape}")
        if x_tilde.shape[0] < 1 or x_tilde.shape[-1] < 1 or x_tilde.shape[-2] < 1:
            raise ValueError(f"{self.name}: empty condition of shape {tuple(x_tilde.shape)}")

    def _check_pair(self, v: torch.Tensor, x_tilde: torch.Tensor, what: str = "x") -> None:
        self._check_condition(x_tilde)
        if not torch.is_tensor(v) or tuple(v.shape) != tuple(x_tilde.shape):
            shape = tuple(v.shape) if torch.is_tensor(v) else type(v).__name__
            raise ValueError(
                f"{self.name}: {what} has shape {shape} but the condition x_tilde has shape "
                f"{tuple(x_tilde.shape)}; they must be equal"
            )

    def padded_size(self, h: int, w: int) -> tuple[int, int]:
        m = self.multiple
        return h + (-h) % m, w + (-w) % m

    def latent_dim(self, h: int, w: int) -> int:
        """Length of z for an H x W image (= the padded pixel count)."""
        hp, wp = self.padded_size(h, w)
        return hp * wp

    def condition(self, x_tilde: torch.Tensor) -> list[torch.Tensor]:
        """Run the conditioning network on (padded) ``x_tilde``; reusable across many samples."""
        self._check_condition(x_tilde)
        return self._conditions(pad_to_multiple(x_tilde, self.multiple, mode="reflect"))

    # -- the flow -------------------------------------------------------------------------------
    def forward(self, v: torch.Tensor, x_tilde: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Density direction: ``v`` (B, 1, H, W) given ``x_tilde`` -> (z (B, D), log|det dz/dv| (B,)).

        ``v`` is the target ``x`` (``residual = False``) or the residual ``x_tilde - x``.
        """
        self._check_pair(v, x_tilde, "v")
        conds = self.condition(x_tilde)
        return self._flow_forward(pad_to_multiple(v, self.multiple, value=0.0), conds)

    def _inverse_with(self, z: torch.Tensor, conds: list[torch.Tensor], size: tuple[int, int]) -> torch.Tensor:
        finish_actnorm_init(self)
        v = self._flow_inverse(z, conds, self.padded_size(*size))
        return crop(v, size)

    def inverse(self, z: torch.Tensor, x_tilde: torch.Tensor) -> torch.Tensor:
        """Generative direction: latent ``z`` (B, D) given ``x_tilde`` -> ``v`` (B, 1, H, W)."""
        self._check_condition(x_tilde)
        b, _, h, w = x_tilde.shape
        d = self.latent_dim(h, w)
        if not torch.is_tensor(z) or z.dim() != 2 or tuple(z.shape) != (b, d):
            shape = tuple(z.shape) if torch.is_tensor(z) else type(z).__name__
            raise ValueError(
                f"{self.name}: z must have shape ({b}, {d}) for a condition of shape "
                f"{tuple(x_tilde.shape)}, got {shape}"
            )
        return self._inverse_with(z, self.condition(x_tilde), (h, w))

    # -- PostProcessor ----------------------------------------------------------------------------
    def _target(self, x_tilde: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        return x_tilde - x if self.residual else x

    def loss(self, x_tilde: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, dict[str, float]]:
        """Mean NLL of ``x`` given ``x_tilde`` in bits/dim (the training and validation loss), plus
        ``location_weight`` times the MSE of :meth:`location` against the noise-free target.

        In training mode Gaussian noise of std :func:`target_noise_std` is added to the target
        first (to all pixels, padded ones included); in eval mode the loss is deterministic.
        """
        self._check_pair(x, x_tilde, "x")
        v_clean = self._target(x_tilde, x) if self.location_weight else None
        noisy = self.training and self.target_noise > 0
        sigma = target_noise_std(x, self.target_noise, self.target_noise_scale) if noisy else 0.0
        if noisy:
            x = x + sigma * torch.randn_like(x)
        v = self._target(x_tilde, x)
        conds = self.condition(x_tilde)
        vp = pad_to_multiple(v, self.multiple, value=0.0)
        if noisy and vp.shape != v.shape:
            # the padded pixels get the same noise as the image, so their density is not degenerate
            noise = sigma * torch.randn_like(vp)
            noise[..., : v.shape[-2], : v.shape[-1]] = 0.0
            vp = vp + noise
        z, log_jac = self._flow_forward(vp, conds)
        nll = gaussian_nll_bpd(z, log_jac).mean()
        d = z.shape[1]
        logs = {
            "nll_bpd": float(nll.detach()),
            "z_sq_mean": float(z.detach().pow(2).mean()),
            "logdet_per_dim": float(log_jac.detach().mean() / d),
        }
        if self.location_weight == 0:
            return nll, logs
        location_mse = (self.location(conds, tuple(v.shape[-2:])).float() - v_clean).pow(2).mean()
        logs["location_mse"] = float(location_mse.detach())
        return nll + self.location_weight * location_mse, logs

    def location(self, conds: list[torch.Tensor], size: tuple[int, int]) -> torch.Tensor:
        """The conditional scale's pixel-wise location ``mu`` in the units of ``v``, (B, 1, H, W).

        The layer sits after the input ActNorm, so its ``mu`` (in that layer's units) goes back
        through the ActNorm's inverse. Only for ``conditional_scale="location"``.
        """
        if self.conditional_form != "location":
            raise ValueError(f"{self.name}: only the 'location' conditional scale has a location")
        modules = {n.name: n.module for n in self.flow.node_list}
        mu = crop(modules["scale_in"].split(conds[0])[1], size)
        return modules["actnorm_in"].reverse(mu) if "actnorm_in" in modules else mu

    @torch.no_grad()
    def data_init(self, x_tilde: torch.Tensor, x: torch.Tensor) -> None:
        """Initialise the ActNorm layers from one batch (call before wrapping in DDP so that all
        ranks start from the same parameters; otherwise the first ``loss`` call does it)."""
        self._check_pair(x, x_tilde, "x")
        self.forward(self._target(x_tilde, x), x_tilde)

    def _sample_rows(
        self,
        x_tilde: torch.Tensor,
        n_samples: int,
        chunk: int,
        generator: torch.Generator | None,
        antithetic: bool = False,
    ) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        """Yield (image index per row, v samples) in passes of at most ``chunk`` rows.

        Row ``r`` is sample ``m = r % n_samples`` of image ``r // n_samples``. With
        ``antithetic`` the latent of every odd ``m`` is the negated latent of ``m - 1`` (the
        draws are made as without it, so the even samples are the same in both modes).
        """
        b, _, h, w = x_tilde.shape
        d = self.latent_dim(h, w)
        conds = self.condition(x_tilde)
        total = b * n_samples
        previous: torch.Tensor | None = None
        for r0 in range(0, total, chunk):
            rows = torch.arange(r0, min(r0 + chunk, total))
            img = torch.div(rows, n_samples, rounding_mode="floor").to(x_tilde.device)
            z = torch.randn(
                len(rows),
                d,
                generator=generator,
                dtype=x_tilde.dtype,
                device="cpu" if generator is None else generator.device,
            )
            if antithetic:
                for j in torch.nonzero(rows % n_samples % 2 == 1).flatten().tolist():
                    z[j] = -(z[j - 1] if j > 0 else previous)
                previous = z[-1].clone()
            cs = [c.index_select(0, img) for c in conds]
            yield img, self._inverse_with(z.to(x_tilde.device), cs, (h, w))

    @staticmethod
    def _generator(generator: torch.Generator | None, seed: int | None) -> torch.Generator | None:
        if generator is None and seed is not None:
            generator = torch.Generator().manual_seed(int(seed))
        return generator

    @staticmethod
    def _check_sampling_args(n_samples: Any, chunk: Any) -> None:
        for label, val in (("n_samples", n_samples), ("chunk", chunk)):
            if isinstance(val, bool) or not isinstance(val, (int, np.integer)) or val <= 0:
                raise ValueError(f"{label} must be a positive integer, got {val!r}")

    @torch.no_grad()
    def sample(
        self,
        x_tilde: torch.Tensor,
        n_samples: int = 1,
        chunk: int = 32,
        generator: torch.Generator | None = None,
        seed: int | None = None,
    ) -> torch.Tensor:
        """``n_samples`` reconstructions per input, (B, n_samples, 1, H, W): ``G^-1(z)`` (or
        ``x_tilde - G^-1(z)`` for the residual variants) with independent z ~ N(0, I) (for
        antithetic pairs use :meth:`reconstruct`)."""
        self._check_condition(x_tilde)
        self._check_sampling_args(n_samples, chunk)
        generator = self._generator(generator, seed)
        b, _, h, w = x_tilde.shape
        out = torch.empty(b * n_samples, 1, h, w, dtype=x_tilde.dtype, device=x_tilde.device)
        pos = 0
        with parametrize_cached():
            for img, v in self._sample_rows(x_tilde, n_samples, chunk, generator):
                out[pos : pos + len(img)] = x_tilde[img] - v if self.residual else v
                pos += len(img)
        return out.view(b, n_samples, 1, h, w)

    @torch.no_grad()
    def reconstruct(
        self,
        x_tilde: torch.Tensor,
        n_samples: int = 100,
        chunk: int = 32,
        generator: torch.Generator | None = None,
        seed: int | None = None,
        antithetic: bool = False,
        **kwargs: Any,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Mean and pixel-wise standard deviation over ``n_samples`` latent samples per input.

        ``x_reco = 1/M sum_m G^-1(z_m)`` and ``sigma = (1/M sum_m (G^-1(z_m) - x_reco)^2)^(1/2)``;
        for the residual variants ``x_reco = x_tilde - 1/M sum_m dx_m`` and ``sigma`` = the std of
        the residual samples (paper eqs. for CiNN(Res)). At most ``chunk`` latent samples (over
        all images of the batch) go through the network at once; moments are accumulated in
        float64, so memory does not grow with ``n_samples``. The latent draws come from
        ``generator`` if given, else from a generator seeded with ``seed`` if given, else from
        torch's global RNG.

        With ``antithetic`` the samples come in pairs ``G^-1(z), G^-1(-z)`` (antithetic
        variates; an odd ``n_samples`` leaves the last sample unpaired). Every sample still has
        the model's distribution, so mean and std estimate the same quantities; the part of
        ``G^-1`` that is odd in z (all of it for an affine map) cancels in the mean, which
        removes most of the Monte-Carlo error of the mean of a near-affine flow at no cost.
        """
        if kwargs:
            raise TypeError(f"{self.name}.reconstruct got unexpected arguments {sorted(kwargs)}")
        self._check_condition(x_tilde)
        self._check_sampling_args(n_samples, chunk)
        generator = self._generator(generator, seed)
        b, _, h, w = x_tilde.shape
        moments = RunningMoments(b, (1, h, w), device=x_tilde.device)
        with parametrize_cached():
            for img, v in self._sample_rows(x_tilde, n_samples, chunk, generator, bool(antithetic)):
                moments.update(v, img)
        mean_v, std = moments.result()
        mean_v, std = mean_v.to(x_tilde.dtype), std.to(x_tilde.dtype)
        mean = x_tilde - mean_v if self.residual else mean_v
        return mean, std

    # -- checkpoints ------------------------------------------------------------------------------
    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        try:
            return super().load_state_dict(state_dict, strict=strict, assign=assign)
        except RuntimeError as e:
            if isinstance(e, CheckpointMismatchError):
                raise
            raise CheckpointMismatchError(
                f"{self.name} with {self.hparams}: the state dict does not match this architecture/size "
                f"(build the model with the checkpoint's name and hparams): {e}"
            ) from e


@contextmanager
def parametrize_cached() -> Iterator[None]:
    """Cache the orthogonal matrices during sampling (they are recomputed on every call otherwise)."""
    from torch.nn.utils import parametrize

    with parametrize.cached():
        yield
