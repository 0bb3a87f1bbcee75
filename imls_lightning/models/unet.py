"""A standard U-Net (Ronneberger et al. 2015): the IML encoder/decoder and FoVolNet's feature extractor.

``depth`` is the number of resolution levels, so ``depth - 1`` max-pool down-steps (the original
U-Net has depth 5: 64..1024 channels, 4 poolings; the paper's IML uses depth 5). Level ``i`` has
``min(base_channels * 2**i, max_channels)`` channels. Each level is two 3x3 conv + norm + ReLU;
going up is bilinear x2 (default; no checkerboard artefacts) or a 2x2 transposed conv, then skip
concatenation and the level's double conv; a 1x1 conv gives ``out_channels`` with no activation.

Sizes. An input of any ``H, W >= 2**(depth-1)`` works: it is padded (replicate, bottom/right) to a
multiple of ``2**(depth-1)`` and the output is cropped back to ``H x W``. Smaller inputs are refused
with an :class:`~imls_lightning.base.errors.InputError` (the bottom level would be empty); e.g. 16x16 is the
smallest input at depth 5 (bottom level 1x1).

Normalization. GroupNorm by default: it does not depend on the batch (IML trains and infers at batch
size 1, where BatchNorm's batch statistics are noise and its running statistics drift between train
and eval), it is well defined down to a 1x1 bottom level (statistics over a group of channels), and
it stays finite under bf16 autocast (the bf16 kernels accumulate the statistics in float32;
eps 1e-5 keeps constant inputs finite).
``norm="batch"`` and ``norm="none"`` are available.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from imls_lightning.base.errors import InputError

__all__ = ["UNet", "DoubleConv", "make_norm"]


def make_norm(kind: str, channels: int, groups: int = 8) -> nn.Module:
    """Normalization layer by name: ``"group"`` (GroupNorm, the largest group count ``<= groups``
    that divides ``channels``), ``"batch"`` (BatchNorm2d) or ``"none"``."""
    if kind == "group":
        g = max(d for d in range(1, min(groups, channels) + 1) if channels % d == 0)
        return nn.GroupNorm(g, channels)
    if kind == "batch":
        return nn.BatchNorm2d(channels)
    if kind == "none":
        return nn.Identity()
    raise InputError(f"norm={kind!r}: expected one of 'group', 'batch', 'none'")


class DoubleConv(nn.Sequential):
    """(3x3 conv -> norm -> ReLU) x 2; ``(B, in, H, W) -> (B, out, H, W)``."""

    def __init__(self, in_channels: int, out_channels: int, norm: str = "group", groups: int = 8):
        bias = norm == "none"
        super().__init__(
            nn.Conv2d(in_channels, out_channels, 3, padding=1, bias=bias),
            make_norm(norm, out_channels, groups),
            nn.ReLU(inplace=True),
            nn.Conv2d(out_channels, out_channels, 3, padding=1, bias=bias),
            make_norm(norm, out_channels, groups),
            nn.ReLU(inplace=True),
        )


class _Up(nn.Module):
    def __init__(self, low_channels: int, skip_channels: int, out_channels: int, up_mode: str, norm: str, groups: int):
        super().__init__()
        self.up_mode = up_mode
        if up_mode == "transpose":
            self.up = nn.ConvTranspose2d(low_channels, skip_channels, 2, stride=2)
            cat_channels = 2 * skip_channels
        else:
            self.up = None
            cat_channels = low_channels + skip_channels
        self.conv = DoubleConv(cat_channels, out_channels, norm, groups)

    def forward(self, low: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        if self.up is None:
            low = F.interpolate(low, size=skip.shape[-2:], mode="bilinear", align_corners=False)
        else:
            low = self.up(low)
        return self.conv(torch.cat([skip, low], dim=1))


class UNet(nn.Module):
    """U-Net ``(B, in_channels, H, W) -> (B, out_channels, H, W)``.

    Args:
        in_channels: input channels (IML encoder 3, decoder 3; FoVolNet 4).
        out_channels: output channels (IML encoder 1, decoder 3).
        depth: number of resolution levels, ``>= 1`` (``depth - 1`` down-steps). Default 5.
        base_channels: channels of the first level, doubled per level. Default 32.
        max_channels: cap on the channels of a level. Default 512.
        norm: ``"group"`` (default), ``"batch"`` or ``"none"``.
        up_mode: ``"bilinear"`` (default) or ``"transpose"``.
        groups: GroupNorm group count (upper bound). Default 8.

    Example:
        >>> net = UNet(3, 1, depth=3, base_channels=4)
        >>> net(torch.rand(1, 3, 20, 13)).shape
        torch.Size([1, 1, 20, 13])
    """

    def __init__(
        self,
        in_channels: int = 3,
        out_channels: int = 1,
        depth: int = 5,
        base_channels: int = 32,
        max_channels: int = 512,
        norm: str = "group",
        up_mode: str = "bilinear",
        groups: int = 8,
    ):
        super().__init__()
        if int(depth) < 1:
            raise InputError(f"depth={depth}: expected an integer >= 1 (number of U-Net resolution levels)")
        if int(base_channels) < 1 or int(max_channels) < 1:
            raise InputError(f"base_channels={base_channels}, max_channels={max_channels}: expected positive integers")
        if up_mode not in ("bilinear", "transpose"):
            raise InputError(f"up_mode={up_mode!r}: expected 'bilinear' or 'transpose'")
        make_norm(norm, 8, groups)  # validates the name early
        self.in_channels, self.out_channels, self.depth = int(in_channels), int(out_channels), int(depth)
        chans = [min(int(base_channels) * 2**i, int(max_channels)) for i in range(self.depth)]
        self.channels = chans
        self.inc = DoubleConv(self.in_channels, chans[0], norm, groups)
        self.downs = nn.ModuleList(DoubleConv(chans[i - 1], chans[i], norm, groups) for i in range(1, self.depth))
        self.ups = nn.ModuleList(
            _Up(chans[i + 1], chans[i], chans[i], up_mode, norm, groups) for i in reversed(range(self.depth - 1))
        )
        self.head = nn.Conv2d(chans[0], self.out_channels, 1)

    @property
    def multiple(self) -> int:
        """Side lengths are padded to a multiple of this (``2**(depth-1)``); also the smallest input."""
        return 2 ** (self.depth - 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.dim() != 4 or x.shape[1] != self.in_channels:
            raise ValueError(f"UNet: expected (B, {self.in_channels}, H, W), got {tuple(x.shape)}")
        h, w = x.shape[-2:]
        k = self.multiple
        if h < k or w < k:
            raise InputError(
                f"UNet depth={self.depth}: input {h}x{w} is smaller than 2^(depth-1)={k}; use a smaller depth or larger images"
            )
        ph, pw = (-h) % k, (-w) % k
        if ph or pw:
            x = F.pad(x, (0, pw, 0, ph), mode="replicate")
        feats = [self.inc(x)]
        for down in self.downs:
            feats.append(down(F.max_pool2d(feats[-1], 2)))
        y = feats.pop()
        for up in self.ups:
            y = up(y, feats.pop())
        y = self.head(y)
        return y[..., :h, :w] if (ph or pw) else y
