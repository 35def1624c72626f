"""The paper's post-processing UNet (after dival's ``get_unet_model``) and its PostProcessor.

Architecture (defaults = the paper's): 5 scales with (32, 32, 64, 64, 128) channels; an input
block (3x3 conv, BatchNorm, LeakyReLU(0.2)); per lower scale a down block (stride-2 3x3 conv
and a 3x3 conv, each followed by BatchNorm and LeakyReLU); per up step bilinear upsampling
(``align_corners=True``) concatenated with a 1x1-conv skip branch of 4 channels, then two 3x3
convs; a 1x1 output conv and a sigmoid.

Images of any size are accepted: the input is padded (reflect by default) to the next
multiple of 2^(scales-1) -- 255 -> 256, 127 -> 128, 63 -> 64 -- and the output is cropped
back, so every scale halves exactly and the skip connections align.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..core.validation import check_bool, check_int, check_int_list
from .base import VALUE_SCALES, PostProcessor, image_range

__all__ = ["LOSS_SCALES", "UNet", "UNetPost", "check_skips", "padded_size"]

PAPER_CHANNELS = (32, 32, 64, 64, 128)


def padded_size(n: int, scales: int) -> int:
    """Smallest multiple of 2^(scales-1) that is >= n (the size the UNet works at)."""
    m = 2 ** (scales - 1)
    return -(-int(n) // m) * m


def _conv(in_ch: int, out_ch: int, stride: int, use_norm: bool) -> list[nn.Module]:
    layers: list[nn.Module] = [nn.Conv2d(in_ch, out_ch, 3, stride=stride, padding=1)]
    if use_norm:
        layers.append(nn.BatchNorm2d(out_ch))
    layers.append(nn.LeakyReLU(0.2, inplace=True))
    return layers


class _UpBlock(nn.Module):
    def __init__(self, in_ch: int, out_ch: int, skip_ch: int, use_norm: bool) -> None:
        super().__init__()
        self.use_skip = skip_ch > 0
        skip_ch = max(skip_ch, 1)  # dival keeps a zeroed channel when skips are off
        skip: list[nn.Module] = [nn.Conv2d(out_ch, skip_ch, 1)]
        if use_norm:
            skip.append(nn.BatchNorm2d(skip_ch))
        skip.append(nn.LeakyReLU(0.2, inplace=True))
        self.skip_conv = nn.Sequential(*skip)
        conv: list[nn.Module] = [nn.BatchNorm2d(in_ch + skip_ch)] if use_norm else []
        conv += _conv(in_ch + skip_ch, out_ch, 1, use_norm) + _conv(out_ch, out_ch, 1, use_norm)
        self.conv = nn.Sequential(*conv)

    def forward(self, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=True)
        s = self.skip_conv(skip)
        if not self.use_skip:
            s = s * 0
        return self.conv(torch.cat([x, s], dim=1))


def check_skips(skip_channels: Any) -> int | list[int]:
    """``skip_channels``: one count for every scale (an int) or one per scale (a list), each ``>= 0``.

    Raises
    ------
    ValueError
        For anything else; the message names it.
    """
    if isinstance(skip_channels, (int, np.integer)):
        return check_int(skip_channels, "skip_channels", 0)
    return check_int_list(skip_channels, "skip_channels", 0)


class UNet(nn.Module):
    """Plain UNet mapping (B, in_ch, H, W) to (B, out_ch, H, W).

    Parameters
    ----------
    in_ch, out_ch : int
        Input and output channels.
    channels : sequence of int
        Feature channels per scale, finest first; its length is the number of scales.
    skip_channels : int or sequence of int
        Channels of the 1x1 skip branch per scale (0 disables a skip connection).
    use_sigmoid : bool
        Apply a sigmoid to the output (images in [0, 1]).
    out_bias : float
        Initial bias of the output convolution (0: PyTorch's default initialisation). With the
        sigmoid, a negative value starts the output near the phantoms' zero background.
    use_norm : bool
        BatchNorm after every convolution.
    pad_mode : {"reflect", "replicate", "constant"}
        How the input is padded to a multiple of 2^(scales-1) (cropped back afterwards).
    """

    def __init__(
        self,
        in_ch: int = 1,
        out_ch: int = 1,
        channels: Sequence[int] = PAPER_CHANNELS,
        skip_channels: int | Sequence[int] = 4,
        use_sigmoid: bool = True,
        use_norm: bool = True,
        pad_mode: str = "reflect",
        out_bias: float = 0.0,
    ) -> None:
        super().__init__()
        channels = check_int_list(channels, "channels", 1)
        skips = check_skips(skip_channels)
        skips = [skips] * len(channels) if isinstance(skips, int) else skips
        if len(skips) != len(channels):
            raise ValueError(f"skip_channels {skips} must have one entry per scale ({len(channels)})")
        if pad_mode not in ("reflect", "replicate", "constant"):
            raise ValueError(f"pad_mode {pad_mode!r} must be reflect, replicate or constant")
        self.scales = len(channels)
        self.channels = channels
        self.use_sigmoid = use_sigmoid
        self.pad_mode = pad_mode
        self.inc = nn.Sequential(*_conv(in_ch, channels[0], 1, use_norm))
        self.down = nn.ModuleList(
            nn.Sequential(
                *_conv(channels[i - 1], channels[i], 2, use_norm), *_conv(channels[i], channels[i], 1, use_norm)
            )
            for i in range(1, self.scales)
        )
        # up[j] goes from scale (scales-1-j) to scale (scales-2-j)
        self.up = nn.ModuleList(
            _UpBlock(channels[i], channels[i - 1], skips[i - 1], use_norm) for i in range(self.scales - 1, 0, -1)
        )
        self.outc = nn.Conv2d(channels[0], out_ch, 1)
        if out_bias:
            nn.init.constant_(self.outc.bias, float(out_bias))

    # ------------------------------------------------------------------ padding
    def _pad(self, x: torch.Tensor) -> tuple[torch.Tensor, tuple[int, int, int, int]]:
        h, w = x.shape[-2:]
        ph, pw = padded_size(h, self.scales) - h, padded_size(w, self.scales) - w
        pad = (pw // 2, pw - pw // 2, ph // 2, ph - ph // 2)  # left, right, top, bottom
        if ph or pw:
            mode = self.pad_mode if min(h, w) > max(pad) else "replicate"  # reflect needs pad < size
            x = F.pad(x, pad, mode=mode)
        return x, pad

    @staticmethod
    def _crop(x: torch.Tensor, pad: tuple[int, int, int, int]) -> torch.Tensor:
        left, right, top, bottom = pad
        return x[..., top : x.shape[-2] - bottom, left : x.shape[-1] - right]

    # ------------------------------------------------------------------ forward
    def forward_features(self, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor], list[torch.Tensor]]:
        """Output and the feature maps of every scale.

        Returns
        -------
        out : Tensor
            (B, out_ch, H, W), cropped back to the input size.
        enc_feats : list of Tensor
            Encoder activations, ``enc_feats[i]`` at scale i: (B, channels[i], P/2^i, P/2^i)
            with P the padded size (:func:`padded_size`).
        dec_feats : list of Tensor
            Decoder activations indexed the same way: ``dec_feats[i]`` is the decoder output
            at scale i, ``dec_feats[-1]`` the bottleneck (= ``enc_feats[-1]``).
        """
        xp, pad = self._pad(x)
        enc = [self.inc(xp)]
        for block in self.down:
            enc.append(block(enc[-1]))
        h = enc[-1]
        dec = [h]
        for j, block in enumerate(self.up):
            h = block(h, enc[-2 - j])
            dec.append(h)
        out = self.outc(h)
        if self.use_sigmoid:
            out = torch.sigmoid(out)
        return self._crop(out, pad), enc, dec[::-1]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.forward_features(x)[0]


#: What the UNet's squared error is measured against: ``"absolute"`` (the images' units, the paper's
#: MSE) or ``"range"`` (each target image's max - min: the mean over the batch of each image's MSE
#: divided by its range squared, so a faint image weighs in training as a bright one does, as PSNR
#: weighs them; for a data set of scan slices whose contrast differs by orders of magnitude).
LOSS_SCALES = VALUE_SCALES


class UNetPost(PostProcessor):
    """UNet post-processing (``name = "unet"``): trained with the mean squared error.

    Keyword arguments are those of :class:`UNet` (minus in/out channels), ``loss_scale``
    (:data:`LOSS_SCALES`; recorded only when not the paper's ``"absolute"``, so that earlier runs
    resume) and ``residual``: the output is ``x_tilde - UNet(x_tilde)``, a correction of the input
    (as in FBPConvNet; not in the paper), with a linear output (``use_sigmoid`` defaults to False
    then) whose last convolution starts at zero, so training starts from the input itself
    (recorded only when True). The resolved values are stored in ``hparams``.
    """

    name = "unet"

    def __init__(
        self,
        channels: Sequence[int] = PAPER_CHANNELS,
        skip_channels: int | Sequence[int] = 4,
        use_sigmoid: bool | None = None,
        use_norm: bool = True,
        pad_mode: str = "reflect",
        out_bias: float = 0.0,
        loss_scale: str = "absolute",
        residual: bool = False,
    ) -> None:
        if loss_scale not in LOSS_SCALES:
            raise ValueError(f"loss_scale must be one of {', '.join(LOSS_SCALES)}, got {loss_scale!r}")
        residual = check_bool(residual, "residual")
        use_sigmoid = not residual if use_sigmoid is None else check_bool(use_sigmoid, "use_sigmoid")
        if residual and (use_sigmoid or out_bias):
            raise ValueError(
                "a residual UNet corrects its input with a linear output that starts at zero: "
                "leave out use_sigmoid=true and out_bias"
            )
        skips: Any = check_skips(skip_channels)
        super().__init__(
            channels=check_int_list(channels, "channels", 1),
            skip_channels=skips,
            use_sigmoid=use_sigmoid,
            use_norm=check_bool(use_norm, "use_norm"),
            pad_mode=str(pad_mode),
            out_bias=float(out_bias),
            **({} if loss_scale == "absolute" else {"loss_scale": str(loss_scale)}),
            **({"residual": True} if residual else {}),
        )
        self.loss_scale, self.residual = str(loss_scale), residual
        self.net = UNet(1, 1, **{k: v for k, v in self.hparams.items() if k not in ("loss_scale", "residual")})
        if residual:
            nn.init.zeros_(self.net.outc.weight)
            nn.init.zeros_(self.net.outc.bias)

    def forward(self, x_tilde: torch.Tensor) -> torch.Tensor:
        return x_tilde - self.net(x_tilde) if self.residual else self.net(x_tilde)

    def loss(self, x_tilde: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, dict[str, float]]:
        """Mean squared error over pixels and batch; with ``loss_scale="range"`` each image's MSE divided by
        its target's (max - min)^2 (at least 1e-12), averaged over the batch (logged as ``relative_mse``)."""
        out = self.forward(x_tilde)
        mse = F.mse_loss(out, x)
        if self.loss_scale == "absolute":
            return mse, {"mse": float(mse.detach())}
        out = out.float()
        relative = (((out - x) ** 2).mean(dim=(1, 2, 3)) / image_range(x).flatten() ** 2).mean()
        return relative, {"mse": float(mse.detach()), "relative_mse": float(relative.detach())}

    @torch.no_grad()
    def reconstruct(self, x_tilde: torch.Tensor, **kwargs: Any) -> tuple[torch.Tensor, None]:
        """UNet output (the caller sets eval mode); no uncertainty."""
        return self.forward(x_tilde), None
