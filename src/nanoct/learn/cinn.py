"""CiNN and CiNNRes: multi-scale conditional invertible network with a ResNet conditioner.

Architecture (paper, "Architecture specifications"; details of ``jleuschn/cinn_for_imaging``)::

    x (1, H, W) -> [ActNorm] -> down_0 -> (4, H/2, W/2)
    for s = 0 .. n_scales-2:
        blocks_per_scale x (conditional NICE coupling [cond_s] -> [ActNorm] -> PermuteRandom)
        down_{s+1}: channels x4, spatial /2;  split: half the channels -> latent
    flatten the rest (2^(n_scales+1) channels at H/2^n_scales; 128 channels at n_scales = 6)
    split off fc_dim values (a "small part"): fc_blocks x (PermuteRandom -> NICE fc coupling
    [global condition] -> [ActNorm]);  the remainder -> latent
    z = concat(all latent parts, fc part)          (length H*W)

``down`` is the learned orthogonal (Haar-initialised) invertible downsampling. The conditioner
is a ResNet on ``x_tilde`` (jointly trained): a stem at full resolution, then per scale a
stride-2 convolution and a residual block giving ``cond_channels[s]`` feature maps at
H/2^(s+1), and a global head (average pool + MLP) giving a ``fc_cond_dim`` vector for the
fully-connected couplings.

Additive couplings and orthogonal resampling are volume preserving, so the ActNorm layers
(``actnorm=True``, default) are the only source of a non-zero log-determinant: without them the
model cannot scale its latent to the conditional spread of the target, and the pixel-wise std
from sampling would not be calibrated.
"""

from __future__ import annotations

from collections.abc import Sequence

import FrEIA.framework as Ff
import FrEIA.modules as Fm
import numpy as np
import torch
from torch import nn

from nanoct.core.validation import check_bool, check_int, check_int_list
from nanoct.learn.flow import ConditionalFlow
from nanoct.learn.invertible import (
    ActNorm,
    OrthogonalDownsampling,
    coupling_block,
    preserve_numpy_rng,
    scale_head,
)

__all__ = ["CiNN", "CiNNRes", "ResNetConditioner"]


class _ResBlock(nn.Module):
    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__()
        self.body = nn.Sequential(
            nn.Conv2d(c_in, c_out, 3, padding=1), nn.LeakyReLU(), nn.Conv2d(c_out, c_out, 3, padding=1)
        )
        self.skip = nn.Identity() if c_in == c_out else nn.Conv2d(c_in, c_out, 1)
        self.act = nn.LeakyReLU()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(self.body(x) + self.skip(x))


class ResNetConditioner(nn.Module):
    """ResNet feature pyramid: ``forward(x)`` returns ``[f_0, ..., f_{L-1}, g]`` with f_s of
    shape (B, channels[s], H/2^(s+1), W/2^(s+1)) and the global vector g (B, fc_dim)."""

    def __init__(self, channels: Sequence[int], width: int = 16, fc_dim: int = 128) -> None:
        super().__init__()
        self.stem = nn.Sequential(nn.Conv2d(1, width, 3, padding=1), nn.LeakyReLU(), _ResBlock(width, width))
        levels, prev = [], width
        for ch in channels:
            levels.append(nn.Sequential(nn.Conv2d(prev, ch, 3, stride=2, padding=1), nn.LeakyReLU(), _ResBlock(ch, ch)))
            prev = ch
        self.levels = nn.ModuleList(levels)
        self.global_head = nn.Sequential(
            nn.AdaptiveAvgPool2d(1), nn.Flatten(), nn.Linear(prev, fc_dim), nn.LeakyReLU(), nn.Linear(fc_dim, fc_dim)
        )

    def forward(self, x: torch.Tensor, with_stem: bool = False) -> list[torch.Tensor]:
        """The pyramid; with ``with_stem`` the full-resolution stem features come first."""
        h = self.stem(x)
        out = [h] if with_stem else []
        for level in self.levels:
            h = level(h)
            out.append(h)
        out.append(self.global_head(h))
        return out


class CiNN(ConditionalFlow):
    """Conditional invertible network (CiNN) for post-processing, name ``"cinn"``.

    Keyword arguments (paper-faithful defaults; the paper fixes the scale count, the channel
    growth and the coarsest 128 channels, the rest follows ``cinn_for_imaging``'s defaults):

    n_scales: 6
        Number of learned 2x downsamplings (paper: 6 scales at N = 255, padded to 256). The
        image is padded to a multiple of 2^n_scales; the coarsest scale has 2^(n_scales+1)
        channels (128 at 6).
    blocks_per_scale: 6
        Conditional coupling blocks per scale (each: NICE coupling, ActNorm, random channel
        permutation); subnets alternate 1x1 and 3x3 convolutions.
    fc_dim: 128
        Size of the "small part" of the coarsest signal that goes through the final
        fully-connected couplings (capped at what is available).
    fc_blocks: 4
        Permutation + fully-connected coupling pairs at the end (paper: "random permutation and
        a conditional coupling block"; reference: 4).
    cond_channels: (4, 16, 32, 64, 64)
        Conditioner feature channels per coupling scale (one entry per scale 0..n_scales-2, or
        one int for all).
    cond_width: 16
        Width of the conditioner stem at full resolution.
    fc_cond_dim: 128
        Size of the global condition vector of the fully-connected couplings.
    hidden_ratio: 2.0
        Coupling subnet width as a multiple of its input channels (input + condition).
    actnorm: True
        ActNorm at the input and after every coupling (see module docstring).
    target_noise: 0.005
        Std of the Gaussian noise added to the target in ``loss`` during training.
    target_noise_scale: "absolute"
        ``"absolute"`` (``target_noise`` is the std) or ``"range"`` (the std is ``target_noise``
        times each target image's max - min; for sets whose images differ widely in contrast,
        such as ``generate --like`` sets of a scan).
    orthogonal_map: "cayley"
        Parametrisation of the orthogonal resampling kernels.
    seed: 0
        Seed of the fixed random permutations.
    coupling: "additive"
        ``"additive"`` (NICE, the paper's) or ``"affine"`` (GLOW, soft-clamped log-scales,
        :class:`~nanoct.learn.invertible.ConditionalAffineCoupling`) for every coupling.
    clamp: 2.0
        Bound of the affine couplings' log-scales (unused for additive couplings).
    conditional_scale: False
        A pixel-wise conditional affine layer
        (:class:`~nanoct.learn.invertible.ConditionalScale`, log-scale and location from a head
        on the conditioner's full-resolution stem features) after the input ActNorm: ``"location"``
        (``(v - mu) * exp(s)``, the tiny study's), ``"shift"`` or ``True`` (``v * exp(s) + t``,
        the shift form), ``False`` / ``"none"`` (the paper's architecture).
    """

    name = "cinn"
    residual = False

    def __init__(
        self,
        n_scales: int = 6,
        blocks_per_scale: int = 6,
        fc_dim: int = 128,
        fc_blocks: int = 4,
        cond_channels: int | Sequence[int] = (4, 16, 32, 64, 64),
        cond_width: int = 16,
        fc_cond_dim: int = 128,
        hidden_ratio: float = 2.0,
        actnorm: bool = True,
        target_noise: float = 0.005,
        target_noise_scale: str = "absolute",
        orthogonal_map: str = "cayley",
        seed: int = 0,
        coupling: str = "additive",
        clamp: float = 2.0,
        conditional_scale: bool | str = False,
        location_weight: float = 0.0,
    ) -> None:
        n_sections = check_int(n_scales, "n_scales", 1) - 1
        if isinstance(cond_channels, (int, np.integer)):
            cond_channels = [cond_channels] * n_sections
        empty = isinstance(cond_channels, (list, tuple)) and not cond_channels  # n_scales = 1: no sections
        cond_channels = [] if empty else check_int_list(cond_channels, "cond_channels", 1)
        if len(cond_channels) != n_sections:
            raise ValueError(f"cond_channels needs n_scales - 1 = {n_sections} entries, got {len(cond_channels)}")
        for label, val, lo in (
            ("blocks_per_scale", blocks_per_scale, 0),
            ("fc_dim", fc_dim, 2),
            ("fc_blocks", fc_blocks, 0),
            ("cond_width", cond_width, 1),
            ("fc_cond_dim", fc_cond_dim, 1),
            ("seed", seed, 0),
        ):
            check_int(val, label, lo)
        coupling_block(str(coupling), float(clamp))  # checks the kind
        super().__init__(
            n_scales=int(n_scales),
            blocks_per_scale=int(blocks_per_scale),
            fc_dim=int(fc_dim),
            fc_blocks=int(fc_blocks),
            cond_channels=cond_channels,
            cond_width=int(cond_width),
            fc_cond_dim=int(fc_cond_dim),
            hidden_ratio=float(hidden_ratio),
            actnorm=check_bool(actnorm, "actnorm"),
            target_noise=float(target_noise),
            target_noise_scale=str(target_noise_scale),
            orthogonal_map=str(orthogonal_map),
            seed=int(seed),
            coupling=str(coupling),
            clamp=float(clamp),
            conditional_scale=conditional_scale,
            location_weight=float(location_weight),
        )
        self.multiple = 2 ** int(n_scales)
        coarse_channels = 2 ** (int(n_scales) + 1)
        if int(fc_dim) > coarse_channels:
            raise ValueError(
                f"fc_dim must be <= {coarse_channels} (the coarsest signal of the smallest image, "
                f"2^(n_scales+1) values), got {fc_dim}"
            )
        self.cond_net = ResNetConditioner(cond_channels, int(cond_width), int(fc_cond_dim))
        self.scale_head = scale_head(int(cond_width)) if self.conditional_form else None
        # FrEIA needs concrete sizes to build a graph; the convolutional graph is built for the
        # smallest valid size and runs at any multiple of it (its layers are size-agnostic), and
        # the fully-connected graph has the fixed size fc_dim. Flattening, the split of the
        # coarsest signal and the assembly of z happen outside the graphs.
        with preserve_numpy_rng():
            self.flow = self._build_conv(self.multiple, self.multiple)
            self.flow_fc = self._build_fc()

    def _build_conv(self, h: int, w: int) -> Ff.GraphINN:
        hp = self.hparams
        n, ratio, seed = hp["n_scales"], hp["hidden_ratio"], hp["seed"]
        block, extra = coupling_block(hp["coupling"], hp["clamp"])
        conds = [
            Ff.ConditionNode(c, h // 2 ** (s + 1), w // 2 ** (s + 1), name=f"cond_{s}")
            for s, c in enumerate(hp["cond_channels"])
        ]
        nodes: list[Ff.Node] = [Ff.InputNode(1, h, w, name="input")]
        if hp["actnorm"]:
            nodes.append(Ff.Node(nodes[-1], ActNorm, {}, name="actnorm_in"))
        cond_full = self._append_conditional_scale(nodes, h, w)
        nodes.append(
            Ff.Node(nodes[-1], OrthogonalDownsampling, {"orthogonal_map": hp["orthogonal_map"]}, name="down_0")
        )
        outs: list[Ff.Node] = []
        for s in range(n - 1):
            for k in range(hp["blocks_per_scale"]):
                nodes.append(
                    Ff.Node(
                        nodes[-1],
                        block,
                        {"kernel_size": 1 if k % 2 == 0 else 3, "hidden_ratio": ratio, **extra},
                        conditions=conds[s],
                        name=f"coupling_{s}_{k}",
                    )
                )
                if hp["actnorm"]:
                    nodes.append(Ff.Node(nodes[-1], ActNorm, {}, name=f"actnorm_{s}_{k}"))
                nodes.append(
                    Ff.Node(
                        nodes[-1], Fm.PermuteRandom, {"seed": seed * 100_003 + 1000 * s + k}, name=f"permute_{s}_{k}"
                    )
                )
            nodes.append(
                Ff.Node(
                    nodes[-1], OrthogonalDownsampling, {"orthogonal_map": hp["orthogonal_map"]}, name=f"down_{s + 1}"
                )
            )
            nodes.append(Ff.Node(nodes[-1], Fm.Split, {"n_sections": 2, "dim": 0}, name=f"split_{s + 1}"))
            outs.append(Ff.OutputNode(nodes[-1].out1, name=f"z_{s + 1}"))
        outs.append(Ff.OutputNode(nodes[-1].out0 if n > 1 else nodes[-1], name="z_coarse"))
        return Ff.GraphINN(nodes + outs + cond_full + conds, force_tuple_output=True)

    def _build_fc(self) -> Ff.GraphINN | None:
        hp = self.hparams
        if hp["fc_blocks"] == 0:
            return None
        block, extra = coupling_block(hp["coupling"], hp["clamp"])
        cond_fc = Ff.ConditionNode(hp["fc_cond_dim"], name="cond_fc")
        nodes: list[Ff.Node] = [Ff.InputNode(hp["fc_dim"], name="fc_in")]
        for k in range(hp["fc_blocks"]):
            nodes.append(
                Ff.Node(
                    nodes[-1], Fm.PermuteRandom, {"seed": hp["seed"] * 100_003 + 99_000 + k}, name=f"permute_fc_{k}"
                )
            )
            nodes.append(
                Ff.Node(
                    nodes[-1],
                    block,
                    {"hidden_ratio": hp["hidden_ratio"], **extra},
                    conditions=cond_fc,
                    name=f"coupling_fc_{k}",
                )
            )
            if hp["actnorm"]:
                nodes.append(Ff.Node(nodes[-1], ActNorm, {}, name=f"actnorm_fc_{k}"))
        out = Ff.OutputNode(nodes[-1], name="fc_out")
        return Ff.GraphINN(nodes + [out, cond_fc])

    def _conditions(self, x_tilde_padded: torch.Tensor) -> list[torch.Tensor]:
        conds = self.cond_net(x_tilde_padded, with_stem=self.scale_head is not None)
        if self.scale_head is not None:
            conds[0] = self.scale_head(conds[0])
        return conds

    def _latent_shapes(self, size: tuple[int, int]) -> list[tuple[int, int, int]]:
        """Shapes of the conv graph's outputs (split-off parts, then the coarsest signal)."""
        h, w = size
        shapes = [(2 ** (s + 3), h // 2 ** (s + 2), w // 2 ** (s + 2)) for s in range(self.hparams["n_scales"] - 1)]
        n = self.hparams["n_scales"]
        shapes.append((2 ** (n + 1), h // 2**n, w // 2**n))
        return shapes

    def _flow_forward(self, vp: torch.Tensor, conds: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        b = vp.shape[0]
        outs, log_jac = self.flow(vp, c=conds[:-1], jac=True)
        parts = [o.reshape(b, -1) for o in outs[:-1]]
        coarse = outs[-1].reshape(b, -1)
        fc = self.hparams["fc_dim"]
        if self.flow_fc is not None:
            head, lj = self.flow_fc(coarse[:, :fc], c=conds[-1:], jac=True)
            log_jac = log_jac + lj
        else:
            head = coarse[:, :fc]
        return torch.cat(parts + [coarse[:, fc:], head], dim=1), log_jac

    def _flow_inverse(self, z: torch.Tensor, conds: list[torch.Tensor], size: tuple[int, int]) -> torch.Tensor:
        b = z.shape[0]
        shapes = self._latent_shapes(size)
        sizes = [c * h * w for c, h, w in shapes]
        fc = self.hparams["fc_dim"]
        pieces = list(torch.split(z, sizes[:-1] + [sizes[-1] - fc, fc], dim=1))
        head = pieces.pop()
        if self.flow_fc is not None:
            head, _ = self.flow_fc(head, c=conds[-1:], rev=True, jac=False)
        coarse = torch.cat([head, pieces.pop()], dim=1)
        outs = [p.reshape(b, *shape) for p, shape in zip(pieces + [coarse], shapes)]
        (vp,), _ = self.flow(tuple(outs), c=conds[:-1], rev=True, jac=False)
        return vp


class CiNNRes(CiNN):
    """Residual CiNN, name ``"cinn-res"``: the flow models ``dx = x_tilde - x``; the
    reconstruction is ``x_tilde - mean(dx samples)`` and the std is that of the dx samples.
    Same keyword arguments as :class:`CiNN`."""

    name = "cinn-res"
    residual = True
