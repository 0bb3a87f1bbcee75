"""FoVolNet (Bauer, Wu, Ma 2022), static: the foveated-rendering RecNN as the IML paper uses it
(recurrent connections removed, only the W-Net kept).

W-Net = two U-shaped networks (after Thomas et al.'s QW-Net, which FoVolNet builds on):

1. **Feature extraction**: a U-Net on the partially rendered image (PR-Image = decompacted C-Image,
   zeros off the pattern) plus the sampling mask as a 4th channel -> ``features`` channels at full
   resolution.
2. **Filtering**: a light U-shaped path. Going down, stride-2 convs carry the features to ``levels``
   scales; at each scale a head predicts a per-pixel ``k x k`` filter kernel (softmax over the
   ``k^2`` taps: non-negative, sums to 1) and, except at the coarsest scale, a blend weight. The
   kernels filter the image pyramid of the PR-Image; going up, the reconstruction is built
   coarse-to-fine: ``out_l = (1 - a_l) * K_l(I_l) + a_l * up(out_{l+1})``.
3. **Hybrid direct prediction** (FoVolNet "combines direct and kernel prediction"): a 1x1 head on the
   features predicts RGB and a weight ``b``; ``out = (1 - b) * out_0 + b * direct``
   (``direct=False`` gives the pure kernel-prediction output).

Image pyramid. ``I_0`` is the PR-Image, ``W_0`` the mask; coarser levels are mask-weighted averages
``I_{l+1} = pool(I_l W_l) / pool(W_l)`` (0 where no sample falls), ``W_{l+1} = pool(W_l)``, so the
coarse levels are dense even where the pattern is sparse (the periphery of a foveal pattern).
Every kernel output is a convex combination of pyramid values, so the kernel path cannot blow up
(an empty mask gives exactly 0, not NaN). Softmax, kernel application and blending run in float32
with autocast off.

Output not clamped (as EnhanceNet; the caller clamps at inference if it wants).
"""
from __future__ import annotations

from typing import Optional

import torch
import torch.nn.functional as F
from torch import nn

from imls_lightning.base.errors import InputError
from imls_lightning.core.compaction import Decompaction
from imls_lightning.models.unet import UNet, make_norm

__all__ = ["FoVolNet", "apply_pixel_kernels", "masked_downsample"]


def _f32(x: torch.Tensor) -> torch.Tensor:
    return x if x.dtype in (torch.float32, torch.float64) else x.float()


def apply_pixel_kernels(image: torch.Tensor, kernels: torch.Tensor) -> torch.Tensor:
    """Filter each pixel with its own ``k x k`` kernel (replicate border).

    ``out[b, c, y, x] = sum_{i, j} kernels[b, i * k + j, y, x] * image[b, c, y + i - k//2, x + j - k//2]``

    Args:
        image: ``(B, C, H, W)``.
        kernels: ``(B, k*k, H, W)`` tap weights (raster order within the kernel), ``k`` odd.

    Returns:
        ``(B, C, H, W)``.

    Example:
        >>> img = torch.rand(1, 3, 6, 6)
        >>> delta = torch.zeros(1, 9, 6, 6); delta[:, 4] = 1  # centre tap
        >>> torch.equal(apply_pixel_kernels(img, delta), img)
        True
    """
    b, c, h, w = image.shape
    kk = kernels.shape[1]
    k = int(round(float(kk) ** 0.5))  # float(): under torch.jit.trace shapes are tensors
    if k * k != kk or k % 2 == 0 or tuple(kernels.shape[-2:]) != (h, w) or kernels.shape[0] != b:
        raise ValueError(
            f"kernels: expected (B, k*k, H, W) with odd k matching image {tuple(image.shape)}, got {tuple(kernels.shape)}"
        )
    r = k // 2
    padded = F.pad(image, (r, r, r, r), mode="replicate") if r else image
    patches = F.unfold(padded, k).view(b, c, kk, h, w)
    return (patches * kernels.unsqueeze(1)).sum(dim=2)


def masked_downsample(image: torch.Tensor, weight: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """One mask-weighted 2x2 pyramid step (ceil for odd sizes).

    Args:
        image: ``(B, C, H, W)``; weight: ``(B, 1, H, W)`` coverage in ``[0, 1]``.

    Returns:
        ``(pool(image * weight) / pool(weight), pool(weight))``, each ``(B, ., ceil(H/2), ceil(W/2))``;
        the image is 0 where the pooled weight is 0 (never NaN).
    """
    num = F.avg_pool2d(image * weight, 2, ceil_mode=True)
    den = F.avg_pool2d(weight, 2, ceil_mode=True)
    img = torch.where(den > 0, num / den.clamp_min(1e-12), torch.zeros_like(num))
    return img, den


class _Conv(nn.Sequential):
    def __init__(self, cin: int, cout: int, stride: int = 1, norm: str = "group"):
        super().__init__(
            nn.Conv2d(cin, cout, 3, stride=stride, padding=1, bias=norm == "none"),
            make_norm(norm, cout),
            nn.ReLU(inplace=True),
        )


class FoVolNet(nn.Module):
    """Static FoVolNet RecNN: ``forward(c_image (B, 3, n, n)) -> (B, 3, m, m)``.

    Args:
        pattern: a :class:`~imls_lightning.core.patterns.SamplingPattern` (any kind; foveal in the paper).
        features: feature channels out of the feature U-Net. Default 16.
        depth: feature U-Net resolution levels. Default 4 (needs ``m >= 2**(depth-1)``).
        base_channels: feature U-Net first-level channels. Default 16.
        filter_channels: channels of the filtering path. Default 16.
        levels: scales at which kernels are predicted. Default 3.
        kernel_size: odd side ``k`` of the predicted kernels. Default 5.
        direct: blend in a direct RGB prediction (FoVolNet's hybrid). Default True.
        norm: normalization in both paths (``"group"``, ``"batch"``, ``"none"``). Default ``"group"``.

    Defaults are modest so it trains on CPU at 64-128^2.

    Example:
        >>> from imls_lightning.core.patterns import SamplingPattern
        >>> pat = SamplingPattern("foveal", 16, 8, torch.randperm(256)[:50].sort().values)
        >>> net = FoVolNet(pat, features=8, depth=2, base_channels=4, filter_channels=4)
        >>> net(torch.rand(2, 3, 8, 8)).shape
        torch.Size([2, 3, 16, 16])
    """

    def __init__(
        self,
        pattern,
        features: int = 16,
        depth: int = 4,
        base_channels: int = 16,
        filter_channels: int = 16,
        levels: int = 3,
        kernel_size: int = 5,
        direct: bool = True,
        norm: str = "group",
    ):
        super().__init__()
        k = int(kernel_size)
        if k < 1 or k % 2 == 0:
            raise InputError(f"kernel_size={kernel_size}: expected an odd integer >= 1")
        if int(levels) < 1:
            raise InputError(f"levels={levels}: expected an integer >= 1")
        if int(features) < 1 or int(filter_channels) < 1:
            raise InputError(f"features={features}, filter_channels={filter_channels}: expected positive integers")
        self.fr_size, self.c_size = int(pattern.fr_size), int(pattern.c_size)
        if self.fr_size < 2 ** (int(depth) - 1):
            raise InputError(f"FoVolNet depth={depth}: fr_size={self.fr_size} is smaller than 2^(depth-1); use a smaller depth")
        self.kernel_size, self.levels, self.direct = k, int(levels), bool(direct)
        self.decompaction = Decompaction(pattern.indices, self.fr_size)
        mask = pattern.mask.to(torch.float32).view(1, 1, self.fr_size, self.fr_size)
        self.register_buffer("mask", mask, persistent=False)
        self.feature_net = UNet(4, int(features), depth=depth, base_channels=base_channels, norm=norm)
        fc = int(filter_channels)
        # level inputs: carried features + the level's image (3) and coverage (1)
        self.filter_in = nn.ModuleList()
        self.filter_down = nn.ModuleList()
        for lvl in range(self.levels):
            cin = (int(features) if lvl == 0 else fc) + 4
            if lvl > 0:
                self.filter_down.append(_Conv(fc, fc, stride=2, norm=norm))
            self.filter_in.append(_Conv(cin, fc, norm=norm))
        # per level: k*k kernel logits (+1 blend logit except at the coarsest level)
        self.heads = nn.ModuleList(
            nn.Conv2d(fc, k * k + (1 if lvl < self.levels - 1 else 0), 3, padding=1) for lvl in range(self.levels)
        )
        if self.direct:
            self.direct_head = nn.Conv2d(int(features), 4, 1)
            with torch.no_grad():  # start mostly on the kernel path (b = sigmoid(-2) ~ 0.12)
                self.direct_head.bias[3] = -2.0

    def forward(self, c_image: torch.Tensor) -> torch.Tensor:
        n = self.c_size
        if c_image.dim() != 4 or tuple(c_image.shape[1:]) != (3, n, n):
            raise ValueError(f"FoVolNet: expected a C-Image (B, 3, {n}, {n}), got {tuple(c_image.shape)}")
        return self.reconstruct(self.decompaction(c_image))

    def reconstruct(self, pr_image: torch.Tensor, mask: Optional[torch.Tensor] = None, return_aux: bool = False):
        """Reconstruct from a PR-Image ``(B, 3, m, m)`` and its mask (default: the pattern's).

        With ``return_aux=True`` returns ``(image, aux)``, ``aux`` a dict with ``kernels`` (list per
        level of ``(B, k*k, H_l, W_l)`` normalized kernels), ``blend`` (list of ``(B, 1, H_l, W_l)``)
        and ``direct_weight`` (``(B, 1, m, m)`` or ``None``).
        """
        b = pr_image.shape[0]
        m = self.fr_size
        if pr_image.dim() != 4 or tuple(pr_image.shape[1:]) != (3, m, m):
            raise ValueError(f"FoVolNet: expected a PR-Image (B, 3, {m}, {m}), got {tuple(pr_image.shape)}")
        w0 = self.mask if mask is None else mask.reshape(-1, 1, m, m)
        w0 = w0.to(pr_image.dtype).expand(b, 1, m, m)
        feats = self.feature_net(torch.cat([pr_image, w0], dim=1))
        d = self.direct_head(feats) if self.direct else None

        with torch.autocast(device_type=pr_image.device.type, enabled=False):
            imgs, wts = [_f32(pr_image)], [_f32(w0)]
            for _ in range(1, self.levels):
                i, w = masked_downsample(imgs[-1], wts[-1])
                imgs.append(i)
                wts.append(w)

        kernels, blends, filtered = [], [], []
        h = feats
        for lvl in range(self.levels):
            if lvl > 0:
                h = self.filter_down[lvl - 1](h)
            h = self.filter_in[lvl](torch.cat([h, imgs[lvl].to(h.dtype), wts[lvl].to(h.dtype)], dim=1))
            out = self.heads[lvl](h)
            with torch.autocast(device_type=pr_image.device.type, enabled=False):
                out = _f32(out)
                kk = self.kernel_size**2
                kern = torch.softmax(out[:, :kk], dim=1)
                kernels.append(kern)
                filtered.append(apply_pixel_kernels(imgs[lvl], kern))
                if lvl < self.levels - 1:
                    blends.append(torch.sigmoid(out[:, kk:]))

        with torch.autocast(device_type=pr_image.device.type, enabled=False):
            rec = filtered[-1]
            for lvl in reversed(range(self.levels - 1)):
                up = F.interpolate(rec, size=filtered[lvl].shape[-2:], mode="bilinear", align_corners=False)
                a = blends[lvl]
                rec = (1 - a) * filtered[lvl] + a * up
            direct_w = None
            if d is not None:
                d = _f32(d)
                direct_w = torch.sigmoid(d[:, 3:4])
                rec = (1 - direct_w) * rec + direct_w * d[:, :3]
        if return_aux:
            return rec, {"kernels": kernels, "blend": blends, "direct_weight": direct_w}
        return rec

    def extra_repr(self) -> str:
        return (
            f"c_size={self.c_size}, fr_size={self.fr_size}, levels={self.levels}, "
            f"kernel_size={self.kernel_size}, direct={self.direct}"
        )
