"""CiUNet and CiUNetRes: conditional invertible U-Net with a (non-invertible) UNet conditioner.

Architecture (paper, "Architecture specifications"; details of ``jleuschn/cinn_for_imaging``'s
``iunet.py``), with L = ``n_scales`` resolutions (level l has size H/2^l)::

    x (1, H, W) -> ActNorm
    pre-block:  down -> (4, H/2) -> conditional coupling [UNet dec_1] (-> ActNorm) -> up -> (1, H)
    encoder, l = 1 .. L-1:
        down: channels x4 -> c_l = 2^(l+1) channels at level l  (4, 8, 16, 32 for L = 5)
        blocks_per_scale x conditional coupling [UNet decoder feature of level l] (-> ActNorm)
        l < L-1: split, half the channels are forwarded to the decoder (skip connection)
    decoder, l = L-2 .. 1:
        up: channels /4;  concat [upsampled, skip of level l]  -> c_l channels
        blocks_per_scale x conditional coupling [UNet encoder feature of level l] (-> ActNorm)
    up -> (1, H, W) -> reshaped (flattened) into z

down/up are the learned orthogonal (Haar-initialised) invertible resamplings; couplings are
additive (NICE) with zero-initialised last subnet layers. The conditioner is the project's UNet
(:class:`nanoct.learn.unet.UNet`, the paper's post-processing UNet, trained jointly); its
features are connected in reversed order: UNet decoder features (the bottleneck at the coarsest
level) condition the encoder couplings, UNet encoder features the decoder couplings. The coarsest
level has 32 channels at L = 5, as in the paper.
"""

from __future__ import annotations

from collections.abc import Sequence

import FrEIA.framework as Ff
import FrEIA.modules as Fm
import torch
from torch import nn

from nanoct.core.validation import check_bool, check_int, check_int_list
from nanoct.learn.flow import ConditionalFlow
from nanoct.learn.invertible import (
    ActNorm,
    OrthogonalDownsampling,
    OrthogonalUpsampling,
    coupling_block,
    preserve_numpy_rng,
    scale_head,
)
from nanoct.learn.unet import PAPER_CHANNELS, UNet

__all__ = ["CiUNet", "CiUNetRes"]


class CiUNet(ConditionalFlow):
    """Conditional invertible U-Net (CiUNet) for post-processing, name ``"ciunet"``.

    Keyword arguments (paper-faithful defaults):

    n_scales: 5
        Resolutions of the invertible U-Net (paper: 5); the image is padded to a multiple of
        2^(n_scales-1) (255 -> 256). The coarsest level has 2^n_scales channels (32 at 5).
    blocks_per_scale: 2
        Conditional couplings per encoder/decoder level (reference: one conditioned and one
        further coupling per level).
    pre_blocks: 1
        Couplings in the pre-block (paper: one).
    cond_channels: (32, 32, 64, 64, 128)
        Channels of the conditioning UNet per scale (the paper's UNet); one entry per scale.
    cond_norm: True
        BatchNorm in the conditioning UNet (as in the paper's UNet).
    hidden_ratio: 1.0
        Coupling subnet width as a multiple of its input channels (half the flow channels +
        the condition channels); subnets are conv3x3 - LeakyReLU - conv3x3 - LeakyReLU -
        conv3x3 (zero-initialised).
    kernel_size: 3
        Kernel size of the coupling subnets.
    actnorm: True
        ActNorm after every coupling (the input ActNorm of the pre-block is always there).
        Additive couplings and orthogonal resampling are volume preserving: ActNorm is the
        only learned scaling of the flow.
    target_noise: 0.005
        Std of the Gaussian noise added to the target in ``loss`` during training.
    target_noise_scale: "absolute"
        ``"absolute"`` (``target_noise`` is the std) or ``"range"`` (the std is ``target_noise``
        times each target image's max - min; for sets whose images differ widely in contrast,
        such as ``generate --like`` sets of a scan).
    orthogonal_map: "cayley"
        Parametrisation of the orthogonal resampling kernels.
    coupling: "additive"
        ``"additive"`` (NICE, the paper's) or ``"affine"`` (GLOW, soft-clamped log-scales,
        :class:`~nanoct.learn.invertible.ConditionalAffineCoupling`) for every coupling.
    clamp: 2.0
        Bound of the affine couplings' log-scales (unused for additive couplings).
    conditional_scale: False
        A pixel-wise conditional affine layer
        (:class:`~nanoct.learn.invertible.ConditionalScale`, log-scale and location from a head
        on the UNet's full-resolution decoder features) after the input ActNorm: ``"location"``
        (``(v - mu) * exp(s)``, the tiny study's), ``"shift"`` or ``True`` (``v * exp(s) + t``,
        the shift form), ``False`` / ``"none"`` (the paper's architecture).
    """

    name = "ciunet"
    residual = False

    def __init__(
        self,
        n_scales: int = 5,
        blocks_per_scale: int = 2,
        pre_blocks: int = 1,
        cond_channels: Sequence[int] = PAPER_CHANNELS,
        cond_norm: bool = True,
        hidden_ratio: float = 1.0,
        kernel_size: int = 3,
        actnorm: bool = True,
        target_noise: float = 0.005,
        target_noise_scale: str = "absolute",
        orthogonal_map: str = "cayley",
        coupling: str = "additive",
        clamp: float = 2.0,
        conditional_scale: bool | str = False,
        location_weight: float = 0.0,
    ) -> None:
        n_scales = check_int(n_scales, "n_scales", 2)
        cond_channels = check_int_list(cond_channels, "cond_channels", 1)
        if len(cond_channels) != n_scales:
            raise ValueError(f"cond_channels needs n_scales = {n_scales} positive entries, got {cond_channels}")
        check_int(blocks_per_scale, "blocks_per_scale", 1)
        check_int(pre_blocks, "pre_blocks", 0)
        if check_int(kernel_size, "kernel_size", 1) not in (1, 3, 5):
            raise ValueError(f"kernel_size must be 1, 3 or 5, got {kernel_size}")
        coupling_block(str(coupling), float(clamp))  # checks the kind
        super().__init__(
            n_scales=n_scales,
            blocks_per_scale=int(blocks_per_scale),
            pre_blocks=int(pre_blocks),
            cond_channels=cond_channels,
            cond_norm=check_bool(cond_norm, "cond_norm"),
            hidden_ratio=float(hidden_ratio),
            kernel_size=int(kernel_size),
            actnorm=check_bool(actnorm, "actnorm"),
            target_noise=float(target_noise),
            target_noise_scale=str(target_noise_scale),
            orthogonal_map=str(orthogonal_map),
            coupling=str(coupling),
            clamp=float(clamp),
            conditional_scale=conditional_scale,
            location_weight=float(location_weight),
        )
        self.multiple = 2 ** (n_scales - 1)
        self.cond_net = UNet(
            1, 1, channels=cond_channels, use_sigmoid=False, use_norm=self.hparams["cond_norm"], pad_mode="reflect"
        )
        # the UNet's 1x1 output layer is not used for conditioning: drop it, so that no
        # parameter goes without a gradient (DistributedDataParallel requires that)
        self.cond_net.outc = nn.Identity()
        self.scale_head = scale_head(cond_channels[0]) if self.conditional_form else None
        with preserve_numpy_rng():
            self.flow = self._build(self.multiple, self.multiple)

    def _build(self, h: int, w: int) -> Ff.GraphINN:
        hp = self.hparams
        n, cch = hp["n_scales"], hp["cond_channels"]
        block, extra = coupling_block(hp["coupling"], hp["clamp"])
        coupling_args = {"kernel_size": hp["kernel_size"], "hidden_ratio": hp["hidden_ratio"], **extra}
        res = {"orthogonal_map": hp["orthogonal_map"]}
        # conditions: UNet decoder features at levels 1..L-1 (L-1: bottleneck), encoder features 1..L-2
        cond_dec = {l: Ff.ConditionNode(cch[l], h >> l, w >> l, name=f"cond_dec_{l}") for l in range(1, n)}
        cond_enc = {l: Ff.ConditionNode(cch[l], h >> l, w >> l, name=f"cond_enc_{l}") for l in range(1, n - 1)}
        nodes: list[Ff.Node] = [Ff.InputNode(1, h, w, name="input")]

        def couplings(count: int, cond: Ff.ConditionNode, tag: str) -> None:
            for k in range(count):
                nodes.append(Ff.Node(nodes[-1], block, coupling_args, conditions=cond, name=f"coupling_{tag}_{k}"))
                if hp["actnorm"]:
                    nodes.append(Ff.Node(nodes[-1], ActNorm, {}, name=f"actnorm_{tag}_{k}"))

        nodes.append(Ff.Node(nodes[-1], ActNorm, {}, name="actnorm_in"))
        cond_full = self._append_conditional_scale(nodes, h, w)
        nodes.append(Ff.Node(nodes[-1], OrthogonalDownsampling, res, name="pre_down"))
        couplings(hp["pre_blocks"], cond_dec[1], "pre")
        nodes.append(Ff.Node(nodes[-1], OrthogonalUpsampling, res, name="pre_up"))

        skips: dict[int, tuple[Ff.Node, int]] = {}
        for l in range(1, n):
            nodes.append(Ff.Node(nodes[-1], OrthogonalDownsampling, res, name=f"down_{l}"))
            couplings(hp["blocks_per_scale"], cond_dec[l], f"enc{l}")
            if l < n - 1:
                split = Ff.Node(nodes[-1], Fm.Split, {"n_sections": 2, "dim": 0}, name=f"split_{l}")
                nodes.append(split)
                skips[l] = split.out1  # the next node takes split.out0
        for l in range(n - 2, 0, -1):
            nodes.append(Ff.Node(nodes[-1], OrthogonalUpsampling, res, name=f"up_{l}"))
            # [upsampled, skip] restores the channel order of the encoder's split, so that with
            # identity couplings and Haar resampling the whole U-Net is the identity at init
            nodes.append(Ff.Node([(nodes[-1], 0), skips[l]], Fm.Concat, {"dim": 0}, name=f"concat_{l}"))
            couplings(hp["blocks_per_scale"], cond_enc[l], f"dec{l}")
        nodes.append(Ff.Node(nodes[-1], OrthogonalUpsampling, res, name="up_0"))
        nodes.append(Ff.OutputNode(nodes[-1], name="output"))
        return Ff.GraphINN(nodes + cond_full + list(cond_dec.values()) + list(cond_enc.values()))

    def _conditions(self, x_tilde_padded: torch.Tensor) -> list[torch.Tensor]:
        n = self.hparams["n_scales"]
        _, enc, dec = self.cond_net.forward_features(x_tilde_padded)
        full = [] if self.scale_head is None else [self.scale_head(dec[0])]
        return full + [dec[l] for l in range(1, n)] + [enc[l] for l in range(1, n - 1)]

    def _flow_forward(self, vp: torch.Tensor, conds: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        out, log_jac = self.flow(vp, c=conds, jac=True)
        return out.reshape(out.shape[0], -1), log_jac

    def _flow_inverse(self, z: torch.Tensor, conds: list[torch.Tensor], size: tuple[int, int]) -> torch.Tensor:
        v, _ = self.flow(z.reshape(z.shape[0], 1, *size), c=conds, rev=True, jac=False)
        return v


class CiUNetRes(CiUNet):
    """Residual CiUNet, name ``"ciunet-res"``: the flow models ``dx = x_tilde - x``; the
    reconstruction is ``x_tilde - mean(dx samples)`` and the std is that of the dx samples.
    Same keyword arguments as :class:`CiUNet`."""

    name = "ciunet-res"
    residual = True
