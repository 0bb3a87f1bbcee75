"""EnhanceNet (Sajjadi, Schölkopf, Hirsch 2017): the super-resolution RecNN.

Architecture as in its paper (the generator of EnhanceNet-PAT): 3x3 conv + ReLU, residual blocks
(default 10 x 64 channels, each conv-ReLU-conv plus identity), nearest-neighbour upsampling + 3x3 conv
+ ReLU per step, 3x3 conv + ReLU, 3x3 conv to RGB, and that residual is **added to a bicubic
upsample of the input**. The paper's 4x is two x2 steps; here any integer factor works: one step per
prime factor (x4 = x2, x2; x3 = x3; x6 = x2, x3).

Input. The downsampling pattern's C-Image *is* the low-resolution image (compaction of a regular grid
in raster order), so EnhanceNet reads the C-Image directly; the pattern only fixes the factor
``m / n`` and the grid offset. The bicubic skip is sampled at the true positions of the pattern's
pixels: FR pixel ``r`` sits at low-res coordinate ``(r - offset) / factor`` (for the centred offset
``(factor - 1) / 2`` this is exactly ``F.interpolate(mode="bicubic", align_corners=False)``; a grid
that takes the top-left pixel of each block is shifted accordingly instead of by half a pixel).

Output. Not clamped: clamping in training would zero the gradient of saturated pixels; clamping to
``[0, 1]`` at inference is the caller's choice.
"""
from __future__ import annotations

from typing import Optional, Sequence

import torch
import torch.nn.functional as F
from torch import nn

from imls_lightning.base.errors import InputError

__all__ = ["EnhanceNet", "bicubic_matrix", "bicubic_upsample", "regular_grid", "prime_factors"]

_A = -0.75  # PyTorch's / OpenCV's bicubic convolution constant


def prime_factors(n: int) -> list[int]:
    """Prime factors in ascending order, e.g. ``12 -> [2, 2, 3]``; ``1 -> []``."""
    out, p = [], 2
    while n > 1:
        while n % p == 0:
            out.append(p)
            n //= p
        p += 1
    return out


def _cubic(t: torch.Tensor) -> torch.Tensor:
    t = t.abs()
    near = ((_A + 2) * t - (_A + 3)) * t * t + 1
    far = ((_A * t - 5 * _A) * t + 8 * _A) * t - 4 * _A
    return torch.where(t <= 1, near, torch.where(t < 2, far, torch.zeros_like(t)))


def bicubic_matrix(n: int, m: int, factor: int, offset: Optional[float] = None, dtype=torch.float32) -> torch.Tensor:
    """1D bicubic interpolation matrix ``(m, n)``: low-res samples -> high-res pixels.

    High-res pixel ``r`` is interpolated at low-res coordinate ``(r - offset) / factor`` with the
    cubic convolution kernel (``a = -0.75``) and taps clamped to ``[0, n - 1]`` (replicate border),
    exactly PyTorch's ``bicubic`` scheme. ``offset=None`` is the centred grid ``(factor - 1) / 2``.
    """
    off = (factor - 1) / 2 if offset is None else float(offset)
    r = torch.arange(m, dtype=torch.float64)
    X = (r - off) / factor
    i0 = torch.floor(X)
    t = X - i0
    W = torch.zeros(m, n, dtype=torch.float64)
    rows = torch.arange(m)
    for k in range(-1, 3):
        idx = (i0 + k).clamp(0, n - 1).long()
        W.index_put_((rows, idx), _cubic(t - k), accumulate=True)
    return W.to(dtype)


def bicubic_upsample(
    x: torch.Tensor, factor: int, offset: Optional[Sequence[float]] = None, size: Optional[int] = None
) -> torch.Tensor:
    """Bicubic upsampling by an integer factor with a given grid offset (separable matrices).

    Args:
        x: ``(B, C, n, n)`` low-res image.
        factor: integer ``>= 1``.
        offset: ``(oy, ox)`` position of low-res sample 0 in high-res pixels; ``None`` = centred
            (then equal to ``F.interpolate(x, scale_factor=factor, mode="bicubic")``).
        size: output side ``m`` (default ``n * factor``).

    Returns:
        ``(B, C, m, m)``, computed in float32 (float64 kept) with autocast off.

    Example:
        >>> x = torch.rand(1, 3, 5, 5)
        >>> torch.allclose(bicubic_upsample(x, 2), F.interpolate(x, scale_factor=2, mode="bicubic"), atol=1e-6)
        True
    """
    n = x.shape[-1]
    m = n * factor if size is None else int(size)
    oy, ox = (None, None) if offset is None else offset
    with torch.autocast(device_type=x.device.type, enabled=False):
        xf = x if x.dtype in (torch.float32, torch.float64) else x.float()
        Wy = bicubic_matrix(x.shape[-2], m, factor, oy, xf.dtype).to(xf.device)
        Wx = bicubic_matrix(n, m, factor, ox, xf.dtype).to(xf.device)
        return Wy @ xf @ Wx.T


def regular_grid(pattern) -> tuple[int, int, int]:
    """``(factor, oy, ox)`` if the pattern is a full regular grid ``(oy + f i, ox + f j)`` covering the
    whole ``n x n`` C-Image (a downsampling pattern), else :class:`InputError`."""
    m, n = int(pattern.fr_size), int(pattern.c_size)
    kind = getattr(pattern, "kind", "?")
    if m % n or pattern.count != n * n:
        raise InputError(
            f"EnhanceNet needs a downsampling pattern (regular grid, fr_size a multiple of c_size, n*n pixels); "
            f"got pattern kind={kind!r} fr_size={m} c_size={n} with {pattern.count} pixels"
        )
    f = m // n
    idx = pattern.indices.cpu()
    oy, ox = int(idx[0]) // m, int(idx[0]) % m
    ii = torch.arange(n)
    expected = ((oy + f * ii)[:, None] * m + (ox + f * ii)[None, :]).reshape(-1)
    if oy >= f or ox >= f or not torch.equal(idx, expected):
        raise InputError(f"EnhanceNet needs a downsampling pattern (regular grid); pattern kind={kind!r} is not one")
    return f, oy, ox


class _ResBlock(nn.Module):
    def __init__(self, ch: int):
        super().__init__()
        self.conv1 = nn.Conv2d(ch, ch, 3, padding=1)
        self.conv2 = nn.Conv2d(ch, ch, 3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.conv2(F.relu(self.conv1(x)))


class EnhanceNet(nn.Module):
    """EnhanceNet RecNN: ``forward(c_image (B, 3, n, n)) -> (B, 3, m, m)``, ``m = n * factor``.

    Args:
        pattern: a :class:`~imls_lightning.core.patterns.SamplingPattern` that is a regular grid
            (``kind="downsample"``; ``"full"`` with ``m == n`` gives factor 1).
        channels: feature channels. Default 64 (paper).
        blocks: residual blocks. Default 10 (paper).

    Attributes:
        factor, offset ``(oy, ox)``, fr_size ``m``, c_size ``n``.

    The last conv starts at 0.1 x its default init, so an untrained net is close to bicubic.

    Example:
        >>> from imls_lightning.core.patterns import SamplingPattern
        >>> idx = (2 * torch.arange(4)[:, None] * 8 + 2 * torch.arange(4)[None, :]).reshape(-1)
        >>> net = EnhanceNet(SamplingPattern("downsample", 8, 4, idx), channels=8, blocks=1)
        >>> net(torch.rand(1, 3, 4, 4)).shape
        torch.Size([1, 3, 8, 8])
    """

    def __init__(self, pattern, channels: int = 64, blocks: int = 10):
        super().__init__()
        if int(channels) < 1 or int(blocks) < 0:
            raise InputError(f"EnhanceNet channels={channels}, blocks={blocks}: expected channels >= 1, blocks >= 0")
        f, oy, ox = regular_grid(pattern)
        self.factor, self.offset = f, (oy, ox)
        self.fr_size, self.c_size = int(pattern.fr_size), int(pattern.c_size)
        ch = int(channels)
        self.conv_in = nn.Conv2d(3, ch, 3, padding=1)
        self.blocks = nn.Sequential(*[_ResBlock(ch) for _ in range(int(blocks))])
        self.ups = nn.ModuleList(nn.Conv2d(ch, ch, 3, padding=1) for _ in prime_factors(f))
        self.up_factors = prime_factors(f)
        self.conv_mid = nn.Conv2d(ch, ch, 3, padding=1)
        self.conv_out = nn.Conv2d(ch, 3, 3, padding=1)
        with torch.no_grad():
            self.conv_out.weight.mul_(0.1)
            self.conv_out.bias.zero_()
        self.register_buffer("Wy", bicubic_matrix(self.c_size, self.fr_size, f, oy), persistent=False)
        self.register_buffer("Wx", bicubic_matrix(self.c_size, self.fr_size, f, ox), persistent=False)
        self._crop_matrices: dict[tuple, tuple[torch.Tensor, torch.Tensor]] = {}  # data.crop sizes

    def _matrices(self, h: int, w: int, device) -> tuple[torch.Tensor, torch.Tensor]:
        """The bicubic matrices for an ``h x w`` C-Image: the buffers at ``n x n``; for a training crop
        (same factor and offset, aligned to the grid) built on the fly."""
        n, f = self.c_size, self.factor
        if (h, w) == (n, n):
            return self.Wy, self.Wx
        key = (h, w, str(device))
        cached = self._crop_matrices.get(key)
        if cached is None:  # built once per crop size, not on every training step
            oy, ox = self.offset
            cached = (bicubic_matrix(h, h * f, f, oy).to(device), bicubic_matrix(w, w * f, f, ox).to(device))
            self._crop_matrices[key] = cached
        return cached

    def bicubic(self, c_image: torch.Tensor) -> torch.Tensor:
        """The bicubic skip alone: ``(B, 3, h, w) -> (B, 3, f h, f w)`` (float32, autocast off)."""
        Wy, Wx = self._matrices(c_image.shape[-2], c_image.shape[-1], c_image.device)
        with torch.autocast(device_type=c_image.device.type, enabled=False):
            x = c_image if c_image.dtype in (torch.float32, torch.float64) else c_image.float()
            return Wy.to(x.dtype) @ x @ Wx.to(x.dtype).T

    def residual(self, c_image: torch.Tensor) -> torch.Tensor:
        """The learned residual path: ``(B, 3, n, n) -> (B, 3, m, m)``."""
        h = F.relu(self.conv_in(c_image))
        h = self.blocks(h)
        for p, conv in zip(self.up_factors, self.ups):
            h = F.relu(conv(F.interpolate(h, scale_factor=p, mode="nearest")))
        h = F.relu(self.conv_mid(h))
        return self.conv_out(h)

    def forward(self, c_image: torch.Tensor) -> torch.Tensor:
        """``(B, 3, n, n) -> (B, 3, m, m)``; fully convolutional, so a grid-aligned crop ``(B, 3, h, w)``
        of a C-Image gives the matching ``(B, 3, f h, f w)`` crop of the FR-Image (patch training)."""
        n = self.c_size
        if c_image.dim() != 4 or c_image.shape[1] != 3 or c_image.shape[-1] < 1 or c_image.shape[-2] < 1:
            raise ValueError(f"EnhanceNet: expected a C-Image (B, 3, {n}, {n}) or a crop (B, 3, h, w), got {tuple(c_image.shape)}")
        return self.residual(c_image) + self.bicubic(c_image)

    def extra_repr(self) -> str:
        return f"factor={self.factor}, offset={self.offset}, c_size={self.c_size}, fr_size={self.fr_size}"
