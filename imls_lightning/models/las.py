"""LAS baseline: Learning Adaptive Sampling and Reconstruction (Weiss et al., TVCG 2020).

Pipeline (DVR, one frame): a low-resolution render ``(B, 3, h, h)`` -> :class:`LASImportanceNet`
(EnhanceNet-style residual blocks + upsampling, softplus) -> positive importance map at FR
resolution ``(B, 1, m, m)`` -> normalization to a prescribed mean ``u`` with a lower bound ``l``,
clamped to 1 -> rejection sampling against the plastic rank pattern ``P`` at FULL resolution (soft
sigmoid with steepness ``alpha`` in training, hard at inference) -> the sampled pixels (in training
``mask * FR ground truth``) -> differentiable pull-push inpainting of the sparse samples
(:func:`pull_push_inpaint`) -> :class:`LASReconstructionNet` on ``[inpainted samples, mask]`` ->
FR-Image ``(B, 3, m, m)``. Importance and reconstruction nets are trained end to end.

What the public code says (``shamanDevel/AdaptiveSampling``, commit 2d3014a; paths in that repo)
----------------------------------------------------------------------------------------------
- Driver: ``network/mainTrainingAdaptive.py`` (end-to-end "low-res -> importance -> sampling ->
  sparse reconstruction" training). DVR defaults: importance input = low-res RGBA (``--inputChannels
  color``; normal/depth optional), plus the previous frame's importance map flattened
  space-to-depth (temporal; zeros on the first frame). Reconstruction input = ``mask * RGBA``
  (optionally inpainted) + the sample mask channel + the warped previous output (4 channels,
  zeros without temporal consistency). Output RGBA, clamped to [0, 1] only for display/next frame.
  The low-res input is the area-downsampled FR crop unless a separately rendered low-res dataset is
  given (``network/dataset/adaptiveDatasetLoader.py``).
- Importance network: ``network/importance/networkMap.py`` (``NetworkImportanceMap``) wraps
  ``network/models/enhancenet.py`` (``EnhanceNet``) with ``reconType='direct'`` (no residual to the
  input), bilinear upsampling, ``--importanceLayers 5`` residual blocks (conv3x3-ReLU-conv3x3, skip
  add), 64 channels, no BN by default; preblock conv3x3+ReLU; post: per x2 ``Upsample(bilinear) ->
  conv3x3 -> ReLU``, then conv3x3+ReLU, conv3x3 -> 1 channel, then ``Softplus``
  (``--importanceOutputLayer softplus``). The input is zero-padded by ``--importanceBorder 8``
  low-res pixels and the output cropped by ``8 * upscale``. Upscale ``--importanceNetUpscale 4``,
  optionally followed by bilinear ``--importancePostUpscale`` (DVR stats script uses 8x in total,
  ``network/statistics/mainAdaptiveDvrStats.py``). Orthogonal init (ReLU gain) of the residual
  blocks' convs.
- Normalization: ``network/importance/importanceMap.py`` ``ImportanceMap.basic_normalize`` and
  ``network/importance/__init__.py`` ``PostProcess``: ``mean = max(min, mean)``;
  ``out = l + I * (u - l) / max(mean(I), 1e-7)`` per image, then ``clamp(max=1)``
  (``mainTrainingAdaptive.py``). Defaults ``--importanceMin 0.01``, ``--importanceMean 0.2``; the DVR
  evaluation uses ``l = 0.002`` and ``u`` in {0.02, 0.05, 0.1, 0.2} and *bisects u* so the hard mask
  hits the requested sample fraction (``USE_BINARY_SEARCH_ON_MEAN``, ``network/utils/binary_search.py``).
  A regularizer ``--lossHeatmapMean 0.1 * (0.5 - mean(I))^2`` on the raw map keeps it near the
  normalization's centre (``PostProcess.importanceCenter`` = 0.5 for 'basic').
- Sampling: ``mask = sigmoid(--sampleSharpness * (I - P))`` in training, default sharpness 50;
  ``mask = (I >= P)`` at test time (``hard_sample=True``). ``P`` is the plastic sequence rank map,
  ``network/sampling/plastic.py``: ``g`` solves ``g^3 = g + 1`` (1.32471795724), ``alpha_j =
  (1/g)^(j+1)``, ``z_i = (0.5 + alpha (i + 1)) mod 1``, rank of first visit / (W H), stored as a
  2048^2 map (``network/sampling/mainSamplingToHDF5.py``); training takes random crops of it with
  random flips/rot90 (``getSamplePatternCrops`` / ``cropSamplePattern`` in
  ``adaptiveDatasetLoader.py``).
- Inpainting before the network (``--reconInterpolateInput``): ``network/importance/
  fractionalInpainting.py`` -> CUDA ``renderer/inpainting_fast.cu`` ``fastInpaintFractional``: a
  pull-push pyramid. Pull (2x down, adaptive-pool windows): ``m_low = max(m)``, ``d_low =
  sum(m d) / sum(m)`` (0 if the sum is 0). Push (bilinear 9/16, 3/16, 3/16, 1/16 from the 4 nearest
  coarse pixels, inside the image only): ``W = sum w``, ``N = sum w m_low``, ``D = sum w m_low d_low``;
  ``m_out = m + (1 - m) N / W``, ``d_out = m d + (1 - m) D / N`` (0 if N = 0). Recursion stops at a
  side of 1. Inference uses the binary version ``fast_inpaint``, which equals the fractional one for
  0/1 masks. ``mainTrainingAdaptive.py`` calls it as ``fractionalInpaint(mask * x, mask)``.
- Reconstruction network: ``--reconModel EnhanceNet`` (default) = ``EnhanceNet`` with
  ``upscale_factor=1``, 10 residual blocks x 64 channels, and (its default ``recon_type``)
  *residual*: output = first C input channels (the (inpainted) samples) + network output.
  Alternative ``UNet`` (``network/models/unet.py``): ``--reconLayers 6`` levels, ``2**--reconFilters``
  = 64 first-level filters doubling per level, bilinear up + 1x1 conv, no BN, optional residual.
- Losses (``network/losses/lossnet.py``): configurable ``--losses`` list (l1, l2, dssim, lpips,
  perceptual with per-layer VGG weights, temporal l2, GAN); the DVR run names in
  ``mainAdaptiveDvrStats.py`` suggest perceptual 0.1 / LPIPS + temporal l2. ``--lossBorderPadding 16``
  zeroes a border before the loss. Plus the heatmap regularizer above.
- Training: one Adam over importance + reconstruction parameters (``lr 1e-4``, StepLR gamma 0.5
  every 500 epochs), end to end with soft sampling; optional ``--pretrainedImportance`` /
  ``--pretrainedReconstruction`` checkpoints and ``--importanceDontTrain`` (freeze importance).
  No mandatory pretraining stage.

Deliberate differences here (see ``docs/LAS.md``): RGB only (the cache has no alpha), single frames
(no temporal inputs or losses), the full FR frame instead of random crops, a fixed ``m x m`` plastic
pattern (randomly flipped/rotated per sample in training instead of random crops of a 2048^2 map),
the post-upscale (if any) applied before normalization (normalization is affine, so only the mean's
resolution changes), pull-push treats masses below 1e-12 as empty (avoids huge gradients), default
loss L1 + heatmap prior, and ``hard`` sampling uses the project's ``PIM' > P``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import torch
import torch.nn.functional as F
from torch import nn

from imls_lightning.base.errors import InputError
from imls_lightning.base.validate import check_integer
from imls_lightning.core.importance import (
    ImportanceNormalization,
    check_alpha,
    check_ipr,
    check_mean,
    delegated,
    hard_rejection_sample,
    normalize_importance,
    soft_rejection_sample,
)
from imls_lightning.core.pull_push import PullPushInpaint, pull_push_inpaint
from imls_lightning.core.smallest_within import bisect_monotone
from imls_lightning.models.unet import UNet
from imls_lightning.core.patterns import plastic_rank_pattern

__all__ = [
    "pull_push_inpaint",
    "PullPushInpaint",
    "LASImportanceNet",
    "LASReconstructionNet",
    "LASNet",
    "LASOutput",
    "las_loss",
    "downsample_low_res",
]

# --------------------------------------------------------------------------------------------
# networks
# --------------------------------------------------------------------------------------------


def _int_factors(k: int) -> list[int]:
    """2, 2, ..., then the odd rest: the upsampling stages of an integer factor ``k``."""
    out = []
    while k % 2 == 0 and k > 1:
        out.append(2)
        k //= 2
    if k > 1:
        out.append(k)
    return out


class _ResBlock(nn.Module):
    def __init__(self, c: int):
        super().__init__()
        self.body = nn.Sequential(nn.Conv2d(c, c, 3, padding=1), nn.ReLU(inplace=True), nn.Conv2d(c, c, 3, padding=1))

    def forward(self, x):
        return x + self.body(x)


class _EnhanceBody(nn.Module):
    """EnhanceNet trunk as LAS builds it: conv+ReLU, residual blocks, (bilinear up + conv + ReLU) per
    upsampling stage, conv+ReLU, conv -> ``out_channels``. No activation at the end."""

    def __init__(self, in_channels: int, out_channels: int, channels: int, blocks: int, upscale: int):
        super().__init__()
        self.pre = nn.Sequential(nn.Conv2d(in_channels, channels, 3, padding=1), nn.ReLU(inplace=True))
        self.blocks = nn.Sequential(*[_ResBlock(channels) for _ in range(blocks)])
        post = []
        for f in _int_factors(upscale):
            post += [nn.Upsample(scale_factor=f, mode="bilinear", align_corners=False),
                     nn.Conv2d(channels, channels, 3, padding=1), nn.ReLU(inplace=True)]
        post += [nn.Conv2d(channels, channels, 3, padding=1), nn.ReLU(inplace=True),
                 nn.Conv2d(channels, out_channels, 3, padding=1)]
        self.post = nn.Sequential(*post)
        # LAS: orthogonal init with ReLU gain for the residual blocks (keeps the deep skip path tame)
        for mod in self.blocks.modules():
            if isinstance(mod, nn.Conv2d):
                nn.init.orthogonal_(mod.weight, nn.init.calculate_gain("relu"))

    def forward(self, x):
        return self.post(self.blocks(self.pre(x)))


class LASImportanceNet(nn.Module):
    """Low-res render -> positive importance map at FR resolution (LAS ``NetworkImportanceMap``).

    Args:
        low_res: side ``h`` of the low-resolution input (LAS/paper: 64).
        fr_size: FR side ``m``; ``m / h`` must be an integer, ``= net upscale * post_upscale``.
        in_channels: 3 (RGB, here) or 4 (RGBA, LAS DVR).
        channels: trunk width (LAS 64).
        blocks: residual blocks (LAS 5).
        border: zero border (low-res pixels) around the input, cropped after (LAS 8).
        post_upscale: bilinear upsampling after the network (LAS ``--importancePostUpscale``, 1).

    Shapes:
        ``(B, in_channels, h, h) -> (B, 1, m, m)``, values ``> 0`` (softplus; may underflow to 0).

    Example:
        >>> net = LASImportanceNet(8, 32, channels=8, blocks=1, border=2)
        >>> net(torch.rand(2, 3, 8, 8)).shape
        torch.Size([2, 1, 32, 32])
    """

    def __init__(self, low_res: int = 64, fr_size: int = 512, in_channels: int = 3, channels: int = 64,
                 blocks: int = 5, border: int = 8, post_upscale: int = 1):
        super().__init__()
        self.low_res = check_integer(low_res, "low_res", 1)
        self.fr_size = check_integer(fr_size, "fr_size", 1)
        self.in_channels = check_integer(in_channels, "in_channels", 1)
        self.border = check_integer(border, "border", 0)
        self.post_upscale = check_integer(post_upscale, "post_upscale", 1)
        if self.fr_size % (self.low_res * self.post_upscale):
            raise InputError(
                f"fr_size={fr_size}: expected a multiple of low_res * post_upscale = {self.low_res * self.post_upscale}"
            )
        self.net_upscale = self.fr_size // (self.low_res * self.post_upscale)
        self.body = _EnhanceBody(self.in_channels, 1, check_integer(channels, "channels", 1),
                                 check_integer(blocks, "blocks", 0),
                                 self.net_upscale)

    def forward(self, low_res: torch.Tensor) -> torch.Tensor:
        if low_res.dim() != 4 or low_res.shape[1] != self.in_channels or tuple(low_res.shape[-2:]) != (self.low_res,) * 2:
            raise ValueError(
                f"low_res: expected (B, {self.in_channels}, {self.low_res}, {self.low_res}), got {tuple(low_res.shape)}"
            )
        b = self.border
        x = F.pad(low_res, (b, b, b, b)) if b else low_res
        y = self.body(x)
        if b:
            c = b * self.net_upscale
            y = y[..., c:-c, c:-c]
        if self.post_upscale > 1:
            y = F.interpolate(y, scale_factor=self.post_upscale, mode="bilinear", align_corners=False)
        return F.softplus(y)


class LASReconstructionNet(nn.Module):
    """Sparse FR samples + mask -> FR-Image (LAS reconstruction network, upscale 1).

    The samples are multiplied by the mask, optionally pull-push inpainted (LAS
    ``--reconInterpolateInput``), concatenated with the mask channel and fed to an EnhanceNet trunk
    (LAS default: 10 blocks x 64, output = input samples + network, i.e. residual) or a U-Net
    (``arch="unet"``; LAS: 6 levels, 64 first-level filters, bilinear up, no BN).

    Args:
        in_channels: image channels ``C`` (3 here).
        arch: ``"enhancenet"`` (default) or ``"unet"``.
        channels, blocks: EnhanceNet width and residual blocks.
        unet_depth, unet_channels, unet_max_channels: U-Net levels / first-level width / cap.
        inpaint: pull-push inpaint the samples before the network (default True).
        residual: add the (inpainted) samples to the network output (default True).

    Shapes:
        ``forward(samples (B, C, m, m), mask (B, 1, m, m) | (B, m, m)) -> (B, C, m, m)`` (not clamped).

    Example:
        >>> rec = LASReconstructionNet(channels=8, blocks=1)
        >>> rec(torch.rand(1, 3, 16, 16), torch.rand(1, 1, 16, 16) > 0.5).shape
        torch.Size([1, 3, 16, 16])
    """

    def __init__(self, in_channels: int = 3, arch: str = "enhancenet", channels: int = 64, blocks: int = 10,
                 unet_depth: int = 6, unet_channels: int = 64, unet_max_channels: int = 512,
                 inpaint: bool = True, residual: bool = True):
        super().__init__()
        self.in_channels = check_integer(in_channels, "in_channels", 1)
        self.arch = str(arch)
        self.inpaint = bool(inpaint)
        self.residual = bool(residual)
        if self.arch == "enhancenet":
            self.net = _EnhanceBody(self.in_channels + 1, self.in_channels, check_integer(channels, "channels", 1),
                                    check_integer(blocks, "blocks", 0), 1)
        elif self.arch == "unet":
            self.net = UNet(self.in_channels + 1, self.in_channels, depth=check_integer(unet_depth, "unet_depth", 1),
                            base_channels=check_integer(unet_channels, "unet_channels", 1),
                            max_channels=check_integer(unet_max_channels, "unet_max_channels", 1), norm="none")
        else:
            raise InputError(f"arch={arch!r}: expected 'enhancenet' or 'unet'")

    def prepare(self, samples: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """The network's image input: ``mask * samples``, pull-push inpainted if enabled. ``(B, C, m, m)``."""
        mask = _mask4(mask, samples)
        x = samples * mask.to(samples.dtype)
        if self.inpaint:
            x = pull_push_inpaint(x, mask)
        return x

    def forward_with_input(self, samples: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(prediction, network image input)``; see :meth:`forward`."""
        if samples.dim() != 4 or samples.shape[1] != self.in_channels:
            raise ValueError(f"samples: expected (B, {self.in_channels}, m, m), got {tuple(samples.shape)}")
        mask = _mask4(mask, samples)
        x = self.prepare(samples, mask)
        y = self.net(torch.cat([x, mask.to(x.dtype)], dim=1))
        return (y + x.to(y.dtype) if self.residual else y), x

    def forward(self, samples: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return self.forward_with_input(samples, mask)[0]


def _mask4(mask: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """``(m, m)``/``(B, m, m)``/``(B, 1, m, m)`` bool or float -> float ``(B, 1, m, m)``."""
    if mask.dim() == 2:
        mask = mask[None, None].expand(like.shape[0], 1, *mask.shape)
    elif mask.dim() == 3:
        mask = mask.unsqueeze(1)
    if mask.dim() != 4 or mask.shape[1] != 1 or mask.shape[-2:] != like.shape[-2:] or mask.shape[0] != like.shape[0]:
        raise ValueError(f"mask: expected (B, 1, H, W) matching {tuple(like.shape)}, got {tuple(mask.shape)}")
    if not mask.is_floating_point():
        mask = mask.to(torch.float32)
    return mask


# --------------------------------------------------------------------------------------------
# the composed baseline
# --------------------------------------------------------------------------------------------


@dataclass
class LASOutput:
    """Everything one :meth:`LASNet.run` produced.

    Attributes:
        fr_pred: ``(B, C, m, m)`` reconstruction (not clamped).
        mask: ``(B, 1, m, m)`` float sampling mask (soft in training, 0/1 when hard).
        importance: ``(B, 1, m, m)`` normalized importance ``min(l + I (u - l) / mean(I), 1)``, float32.
        raw_importance: ``(B, 1, m, m)`` the network's softplus output ``I`` (for the heatmap prior).
        network_input: ``(B, C, m, m)`` the (inpainted) samples the reconstruction net saw.
    """

    fr_pred: torch.Tensor
    mask: torch.Tensor
    importance: torch.Tensor
    raw_importance: torch.Tensor
    network_input: torch.Tensor

    @property
    def ipr(self) -> torch.Tensor:
        """``(B,)`` share of FR pixels sampled (mean of the mask)."""
        return self.mask.float().mean(dim=(1, 2, 3))


def downsample_low_res(fr_image: torch.Tensor, low_res: int) -> torch.Tensor:
    """Area-downsample FR-Images to the importance net's input (what LAS trains on without a
    separately rendered low-res set). ``(B, C, m, m) -> (B, C, low_res, low_res)``."""
    return F.interpolate(fr_image, size=(low_res, low_res), mode="area")


class LASNet(nn.Module):
    """LAS: importance net -> normalization -> plastic rejection sampling at FR -> reconstruction.

    Args:
        low_res, fr_size: sides ``h`` and ``m``.
        mean: prescribed mean value ``u`` in [0.01, 1] (LAS default 0.2).
        lower: lower bound ``l`` (LAS 0.002 in its DVR evaluation, 0.01 training default), ``< mean``.
        delta: guard of the normalization's division (1e-7).
        alpha: steepness of the soft sampling sigmoid (LAS ``--sampleSharpness`` 50).
        in_channels: image channels (3).
        importance_channels, importance_blocks, importance_border, post_upscale: see :class:`LASImportanceNet`.
        recon_arch, recon_channels, recon_blocks, unet_depth, unet_channels, inpaint, residual:
            see :class:`LASReconstructionNet`.
        pattern_augment: in training, flip/rotate ``P`` randomly per sample (LAS: random crops +
            flips/rot90 of a large pattern), so the nets cannot memorize one pattern.

    ``forward(low_res, fr_image, hard=None) -> (fr_pred, mask, importance)``; ``hard=None`` is soft in
    training mode and hard in eval mode. In both, the sampled image is ``mask * fr_image``.

    Example:
        >>> net = LASNet(8, 32, mean=0.2, importance_channels=8, importance_blocks=1, importance_border=2,
        ...              recon_channels=8, recon_blocks=1)
        >>> fr = torch.rand(2, 3, 32, 32)
        >>> pred, mask, imp = net(downsample_low_res(fr, 8), fr)
        >>> pred.shape, mask.shape
        (torch.Size([2, 3, 32, 32]), torch.Size([2, 1, 32, 32]))
    """

    def __init__(self, low_res: int = 64, fr_size: int = 512, mean: float = 0.2, lower: float = 0.002,
                 delta: float = 1e-7, alpha: float = 50.0, in_channels: int = 3,
                 importance_channels: int = 64, importance_blocks: int = 5, importance_border: int = 8,
                 post_upscale: int = 1, recon_arch: str = "enhancenet", recon_channels: int = 64,
                 recon_blocks: int = 10, unet_depth: int = 6, unet_channels: int = 64, inpaint: bool = True,
                 residual: bool = True, pattern_augment: bool = True):
        super().__init__()
        self.importance_net = LASImportanceNet(low_res, fr_size, in_channels, importance_channels,
                                               importance_blocks, importance_border, post_upscale)
        self.reconstruction_net = LASReconstructionNet(in_channels, recon_arch, recon_channels, recon_blocks,
                                                       unet_depth, unet_channels, inpaint=inpaint, residual=residual)
        self.low_res, self.fr_size = self.importance_net.low_res, self.importance_net.fr_size
        # u, l and delta, validated there (and u again on every change); holds no state
        self.normalization = ImportanceNormalization(mean, lower, delta)
        self.alpha = check_alpha(alpha)
        self.pattern_augment = bool(pattern_augment)
        P = torch.as_tensor(plastic_rank_pattern(self.fr_size), dtype=torch.float32)
        if tuple(P.shape) != (self.fr_size, self.fr_size):
            raise ValueError(f"plastic_rank_pattern({self.fr_size}) returned shape {tuple(P.shape)}")
        self.register_buffer("P", P)  # persistent: a checkpoint carries the P it was trained with

    mean = delegated("normalization", "mean", settable=True)
    lower = delegated("normalization", "lower")
    delta = delegated("normalization", "delta")

    # -- pieces ---------------------------------------------------------------------------------

    def normalize(self, raw: torch.Tensor, mean: Optional[float] = None) -> torch.Tensor:
        """``min(l + I (u - l) / (mean(I) + delta), 1)`` per image, float32. ``(B,1,m,m) -> (B,1,m,m)``."""
        u = self.mean if mean is None else check_mean(mean)
        # LAS clamps at 1: P <= 1, so anything above is "always sample" and only inflates the mean
        return normalize_importance(raw, u, self.lower, self.delta).clamp(max=1.0)

    def _pattern(self, batch: int, augment: bool) -> torch.Tensor:
        if not augment:
            return self.P
        variants = torch.stack([torch.rot90(p, k, (0, 1)) for p in (self.P, self.P.flip(1)) for k in range(4)])
        pick = torch.randint(0, 8, (batch,), device=self.P.device)
        return variants[pick].unsqueeze(1)  # (B, 1, m, m)

    def sample(self, importance: torch.Tensor, hard: bool) -> torch.Tensor:
        """Rejection sampling of the normalized importance against ``P``: ``(B,1,m,m)`` float mask."""
        if hard:
            return hard_rejection_sample(importance, self.P).to(importance.dtype)
        P = self._pattern(importance.shape[0], self.training and self.pattern_augment)
        return soft_rejection_sample(importance, P, self.alpha)

    def _check_low(self, low_res: torch.Tensor) -> None:
        c = self.importance_net.in_channels
        if low_res.dim() != 4 or low_res.shape[1] != c or tuple(low_res.shape[-2:]) != (self.low_res,) * 2:
            raise InputError(
                f"low_res: expected a (B, {c}, {self.low_res}, {self.low_res}) low-resolution render, "
                f"got {tuple(low_res.shape)}"
            )

    # -- training / evaluation ---------------------------------------------------------------

    def run(self, low_res: torch.Tensor, fr_image: torch.Tensor, hard: Optional[bool] = None,
            mean: Optional[float] = None) -> LASOutput:
        """The whole pipeline with every intermediate (see :class:`LASOutput`).

        Args:
            low_res: ``(B, C, h, h)`` low-res render in [0, 1].
            fr_image: ``(B, C, m, m)`` FR ground truth in [0, 1]; only ``mask * fr_image`` reaches the
                reconstruction (the soft mask in training, 0/1 when ``hard``).
            hard: ``None`` -> ``not self.training``.
            mean: override of ``u`` for this call.
        """
        self._check_low(low_res)
        c, m = self.importance_net.in_channels, self.fr_size
        if fr_image.dim() != 4 or tuple(fr_image.shape[1:]) != (c, m, m) or fr_image.shape[0] != low_res.shape[0]:
            raise InputError(
                f"fr_image: expected ({low_res.shape[0]}, {c}, {m}, {m}) matching low_res, got {tuple(fr_image.shape)}"
            )
        if hard is None:
            hard = not self.training
        raw = self.importance_net(low_res)
        importance = self.normalize(raw, mean)
        mask = self.sample(importance, bool(hard))
        fr_pred, net_in = self.reconstruction_net.forward_with_input(fr_image, mask)
        return LASOutput(fr_pred, mask, importance, raw, net_in)

    def forward(self, low_res: torch.Tensor, fr_image: torch.Tensor, hard: Optional[bool] = None):
        out = self.run(low_res, fr_image, hard)
        return out.fr_pred, out.mask, out.importance

    # -- inference (real selective rendering in between) ----------------------------------------

    @torch.no_grad()
    def importance_mask(self, low_res: torch.Tensor, mean: Optional[float] = None,
                        ipr: Optional[float] = None, steps: int = 30) -> torch.Tensor:
        """Which FR pixels to ray-cast: hard ``min(normalized importance, 1) > P``.

        Args:
            low_res: ``(B, C, h, h)`` or ``(C, h, h)`` low-res render.
            mean: ``u`` for this call (default: the trained one).
            ipr: if given, bisect ``u`` per image so that the share of sampled pixels is as close
                as possible to ``ipr`` (what LAS's evaluation does); ``mean`` is then ignored. If even
                ``u = 1`` samples fewer (a very peaked map, clamped at 1), the ``u = 1`` mask is used.
            steps: bisection steps.

        Returns:
            bool ``(B, m, m)`` (or ``(m, m)`` for an unbatched input).
        """
        squeeze = low_res.dim() == 3
        if squeeze:
            low_res = low_res.unsqueeze(0)
        self._check_low(low_res)
        raw = self.importance_net(low_res)
        if ipr is None:
            mask = hard_rejection_sample(self.normalize(raw, mean), self.P)
        else:
            mask = self._mask_for_ipr(raw, ipr, steps)
        mask = mask[:, 0]
        return mask[0] if squeeze else mask

    def _mask_for_ipr(self, raw: torch.Tensor, ipr: float, steps: int) -> torch.Tensor:
        return self.mask_at(raw, self.mean_for_ipr(raw, ipr, steps))

    def mask_at(self, raw: torch.Tensor, mean: torch.Tensor | float) -> torch.Tensor:
        """Hard mask ``(B, 1, m, m)`` bool of the importance net's output ``raw`` ``(B, 1, m, m)`` at
        mean ``u`` (a number or ``(B, 1, 1, 1)``).

        The normalization is affine in ``u``: ``l + (u - l) r`` with ``r = I / (mean(I) + delta)``,
        so one ``r`` serves every ``u`` (:meth:`mean_for_ipr` bisects over it).
        """
        return self._affine_mask(normalize_importance(raw, 1.0, 0.0, self.delta), mean)

    def _affine_mask(self, r: torch.Tensor, u: torch.Tensor | float) -> torch.Tensor:
        return hard_rejection_sample((self.lower + (u - self.lower) * r).clamp(max=1.0), self.P)

    def mean_for_ipr(self, raw: torch.Tensor, ipr: float, steps: int = 30) -> torch.Tensor:
        """Per-image mean ``u`` ``(B, 1, 1, 1)`` at which :meth:`mask_at` samples about ``ipr`` of
        the FR pixels (bisection in ``u``, :func:`~imls_lightning.core.smallest_within.bisect_monotone`; ``u = 1``
        where even that samples fewer).

        Args:
            raw: ``(B, 1, m, m)`` the importance net's output.
            ipr: target share of sampled FR pixels in ``(0, 1]``.
            steps: bisection steps.

        Example:
            >>> net = LASNet(8, 32, importance_channels=4, importance_blocks=1, importance_border=2,
            ...              recon_channels=4, recon_blocks=1)
            >>> net.mean_for_ipr(torch.rand(2, 1, 32, 32), 0.25).shape
            torch.Size([2, 1, 1, 1])
        """
        target = check_ipr(ipr)
        r = normalize_importance(raw, 1.0, 0.0, self.delta)
        lo = torch.full((raw.shape[0], 1, 1, 1), max(self.lower, 0.0), device=raw.device, dtype=r.dtype)

        def share(u: torch.Tensor) -> torch.Tensor:
            return self._affine_mask(r, u).float().mean(dim=(1, 2, 3), keepdim=True)

        return bisect_monotone(share, target, lo, torch.ones_like(lo), steps, scale="linear").hi

    @torch.no_grad()
    def reconstruct(self, samples: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """FR-Image from the really rendered samples.

        Args:
            samples: ``(B, C, m, m)`` (or ``(C, m, m)``) float in [0, 1], rendered colours at the mask's
                pixels (other pixels are ignored).
            mask: bool/0-1 ``(m, m)``, ``(B, m, m)`` or ``(B, 1, m, m)``.

        Returns:
            ``(B, C, m, m)`` (or ``(C, m, m)``) clamped to [0, 1].
        """
        squeeze = samples.dim() == 3
        if squeeze:
            samples = samples.unsqueeze(0)
            if mask.dim() == 2:
                mask = mask.unsqueeze(0)
        c, m = self.importance_net.in_channels, self.fr_size
        if samples.dim() != 4 or tuple(samples.shape[1:]) != (c, m, m):
            raise InputError(f"samples: expected (B, {c}, {m}, {m}), got {tuple(samples.shape)}")
        mask = _mask4(mask.to(samples.device), samples)
        out = self.reconstruction_net(samples, (mask > 0.5).to(samples.dtype))
        out = out.clamp(0.0, 1.0)
        return out[0] if squeeze else out


def las_loss(out: LASOutput, target: torch.Tensor, l1_weight: float = 1.0, mse_weight: float = 0.0,
             heatmap_weight: float = 0.1, heatmap_center: float = 0.5, border: int = 0):
    """LAS training loss: image terms + the heatmap prior ``w (c - mean(I))^2`` on the raw importance.

    Args:
        out: from :meth:`LASNet.run`.
        target: ``(B, C, m, m)`` FR ground truth.
        l1_weight, mse_weight: image terms (LAS chooses them per run via ``--losses``; a perceptual
            term can be added by the caller).
        heatmap_weight, heatmap_center: LAS ``--lossHeatmapMean`` 0.1 and centre 0.5.
        border: pixels excluded at each side from the image terms (LAS ``--lossBorderPadding``).

    Returns:
        ``(total, {"l1": ..., "mse": ..., "heatmap": ...})`` with scalar tensors (float32).
    """
    pred, tgt = out.fr_pred.float(), target.float()
    if border:
        pred, tgt = pred[..., border:-border, border:-border], tgt[..., border:-border, border:-border]
    terms = {
        "l1": F.l1_loss(pred, tgt),
        "mse": F.mse_loss(pred, tgt),
        "heatmap": (heatmap_center - out.raw_importance.float().mean()) ** 2,
    }
    total = l1_weight * terms["l1"] + mse_weight * terms["mse"] + heatmap_weight * terms["heatmap"]
    return total, terms
