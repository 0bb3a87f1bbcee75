"""The Importance Mask Learning network (paper, "Importance Mask Learning Network").

    C-Image --encoder U-Net (3->1) + softplus--> PIM --normalization (mean u)--> PIM'
            --rejection sampling vs P (soft in training, hard at inference)--> IM  (0 on padding)
    (C-Image, IM) --decoder--> reconstructed C-Image

Two decoders (``decoder=``):

* ``"refine"`` (default), :class:`RefineDecoder`: the untrained pull-push fill of the sampled
  pixels, plus a U-Net's correction from ``[fill, IM]``; sampled pixels pass through unchanged. It
  starts at the classical fill's quality, can only learn upward from it, and never degrades a pixel
  it was given (IM = 1 everywhere gives the C-Image back exactly).
* ``"plain"``, :class:`PlainDecoder`: the paper's drawing, a U-Net on ``IM * C-Image`` alone. It
  has to learn the fill from scratch and corrupts the pixels it was given; kept for the ablation
  and for checkpoints written before the refine decoder.

Two importance sources (``importance=``): ``"learned"`` (the encoder above) and ``"uniform"`` (no
encoder: PIM' = u everywhere, so the IM is the blue-noise plastic mask ``u > P`` of share ``u``):
the untrained mask baseline, trained with its own decoder.

:class:`IMLRecNN` puts the decoder in front of any RecNN (EnhanceNet, FoVolNet): the paper's
end-to-end model, and, with a standalone-trained IML, its "off-the-shelf RecNN" case.

Precision. The encoder and decoder may run under autocast; softplus, normalization and rejection
sampling always run in float32 (see :mod:`imls_lightning.core.importance`), so ``pim``, ``pim_norm``,
``im`` and ``pr_c_image`` are float32, and ``c_recon`` is the decoder's dtype (bf16 under bf16
autocast: compute losses in float32).
"""
from __future__ import annotations

from typing import NamedTuple, Optional

import torch
import torch.nn.functional as F
from torch import nn

from imls_lightning.base.errors import InputError
from imls_lightning.core.importance import ImportanceNormalization, RejectionSampling, delegated
from imls_lightning.core.operating_point import POINT_DECODERS
from imls_lightning.core.pull_push import fill_c_image, in_layout_of, pull_push_inpaint
from imls_lightning.models.unet import UNet

__all__ = ["IMLOutput", "IMLNet", "IMLRecNN", "RefineDecoder", "PlainDecoder", "FillDecoder", "build_decoder", "decoder_at",
           "ipr", "c_share", "DECODERS", "IMPORTANCE_SOURCES"]

DECODERS = ("refine", "plain")
IMPORTANCE_SOURCES = ("learned", "uniform")


def _mask_like(mask: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    if mask.dim() == 3:
        mask = mask.unsqueeze(1)
    if mask.dim() != 4 or mask.shape[1] != 1 or mask.shape[0] != values.shape[0] or mask.shape[-2:] != values.shape[-2:]:
        raise ValueError(f"mask: expected (B, 1, H, W) matching values {tuple(values.shape)}, got {tuple(mask.shape)}")
    return mask.to(values.dtype if values.is_floating_point() else torch.float32)


class FillDecoder(nn.Module):
    """The untrained baseline decoder: pull-push fill of the sampled pixels (no parameters); with a
    foveal ``pattern``, at their FR positions (:func:`~imls_lightning.core.pull_push.fill_c_image`).

    ``forward(values (B, 3, n, n), mask (B, 1, n, n)) -> (B, 3, n, n)``; ``values`` only matter
    where ``mask > 0`` (pass the C-Image or the PR-C-Image alike); sampled pixels are kept.

    Example:
        >>> v = torch.zeros(1, 3, 4, 4); v[:, :, 0, 0] = 1.0
        >>> FillDecoder()(v, (v[:, :1] > 0).float()).mean().item()
        1.0
    """

    def __init__(self, pattern=None):
        super().__init__()
        self.pattern = pattern  # a foveal pattern's C-Image is filled at the samples' FR positions (fill_c_image)

    def forward(self, values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        # in the layout the values came in, so the RecNN after it runs as fast as on a rendered C-Image
        return in_layout_of(fill_c_image(values, _mask_like(mask, values), self.pattern), values)


class RefineDecoder(nn.Module):
    """Fill-and-refine decoder: ``out = m v + (1 - m) (fill + U([fill, m]))``, ``fill`` = pull-push of
    the samples ``(v, m)``.

    The U-Net learns only the correction to the classical fill (the scene's prior: where nothing is,
    edges, colour bleeding into empty space); the sampled pixels pass through unchanged, so a full
    mask returns the input exactly (the invariant "the decoder never degrades a pixel it was given").
    With a soft mask (training) the blend is differentiable in ``m``: every pixel's gradient says
    how much sampling it would pay.

    Args:
        depth, base_channels, max_channels, norm: the U-Net's size (see :class:`UNet`).
        fill_pattern: a foveal :class:`~imls_lightning.core.patterns.SamplingPattern`: the fill runs at the
            samples' FR positions (:func:`~imls_lightning.core.pull_push.fill_c_image`), so the correction starts
            from the fair fill (on ct_head's FoVolNet pair 28-33 dB, the C-Image layout's 15-22 dB). ``None`` (and
            on a grid pattern, where both are the same): the fill runs in the C-Image's layout, as the runs trained
            before it did (``model.fill=c``).

    Shapes: ``forward(values (B, 3, n, n), mask (B, 1, n, n) in [0, 1]) -> (B, 3, n, n)``.

    Example:
        >>> dec = RefineDecoder(depth=2, base_channels=4)
        >>> c = torch.rand(1, 3, 8, 8)
        >>> torch.equal(dec(c, torch.ones(1, 1, 8, 8)), c)
        True
    """

    def __init__(self, depth: int = 5, base_channels: int = 32, max_channels: int = 512, norm: str = "group",
                 fill_pattern=None):
        super().__init__()
        self.fill_pattern = fill_pattern
        self.net = UNet(4, 3, depth=depth, base_channels=base_channels, max_channels=max_channels, norm=norm)
        # zero correction at initialization: training starts exactly at the classical fill
        nn.init.zeros_(self.net.head.weight)
        nn.init.zeros_(self.net.head.bias)

    def forward(self, values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        m = _mask_like(mask, values)
        fill = fill_c_image(values, m, self.fill_pattern)
        refined = fill + self.net(torch.cat([fill, m.to(fill.dtype)], 1)).to(fill.dtype)
        return m * values.to(fill.dtype) + (1 - m) * refined


class PlainDecoder(UNet):
    """The paper's decoder: a U-Net on the PR-C-Image ``m * v`` alone (3 -> 3 channels).

    A :class:`UNet` itself, so checkpoints written before the refine decoder load unchanged.

    Shapes: ``forward(values (B, 3, n, n), mask (B, 1, n, n)) -> (B, 3, n, n)``.
    """

    def __init__(self, depth: int = 5, base_channels: int = 32, max_channels: int = 512, norm: str = "group"):
        super().__init__(3, 3, depth=depth, base_channels=base_channels, max_channels=max_channels, norm=norm)

    def forward(self, values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return super().forward(_mask_like(mask, values) * values)


def build_decoder(kind: str, depth: int = 5, base_channels: int = 32, max_channels: int = 512, norm: str = "group",
                  fill_pattern=None) -> nn.Module:
    """``"refine"`` -> :class:`RefineDecoder`, ``"plain"`` -> :class:`PlainDecoder`, ``"fill"`` -> :class:`FillDecoder`;
    ``fill_pattern``: where the fill runs (:class:`RefineDecoder`; the plain U-Net has no fill)."""
    if kind == "refine":
        return RefineDecoder(depth, base_channels, max_channels, norm, fill_pattern=fill_pattern)
    if kind == "plain":
        return PlainDecoder(depth, base_channels, max_channels, norm)
    if kind == "fill":
        return FillDecoder(fill_pattern)
    raise InputError(f"decoder={kind!r}: expected one of {list(DECODERS) + ['fill']}")


def decoder_at(kind: str, trained: nn.Module, pattern=None) -> nn.Module:
    """The decoder an operating point runs (its ``decoder``,
    :data:`~imls_lightning.core.operating_point.POINT_DECODERS`): ``"trained"``, the IMS's own ``trained`` decoder;
    ``"fill"``, the untrained pull-push fill of the same pixels (:class:`FillDecoder`, at ``pattern``'s positions).

    Example:
        >>> isinstance(decoder_at("fill", nn.Identity()), FillDecoder), type(decoder_at("trained", nn.Identity())).__name__
        (True, 'Identity')
    """
    if kind not in POINT_DECODERS:
        raise InputError(f"decoder={kind!r}: expected one of {list(POINT_DECODERS)}")
    return FillDecoder(pattern) if kind == "fill" else trained


class IMLOutput(NamedTuple):
    """Everything :meth:`IMLNet.forward` computes, each ``(B, C, n, n)``.

    Attributes:
        pim: ``(B, 1, n, n)`` preliminary importance (softplus output, ``>= 0``).
        pim_norm: ``(B, 1, n, n)`` PIM' (normalized to the mean value).
        im: ``(B, 1, n, n)`` importance mask: soft in ``[0, 1]`` or hard in ``{0, 1}``; 0 on padding.
        pr_c_image: ``(B, 3, n, n)`` ``im * c_image``.
        c_recon: ``(B, 3, n, n)`` the decoder's C-Image.
    """

    pim: torch.Tensor
    pim_norm: torch.Tensor
    im: torch.Tensor
    pr_c_image: torch.Tensor
    c_recon: torch.Tensor


def ipr(im: torch.Tensor, fr_size: int) -> torch.Tensor:
    """Important-pixel ratio per image: important pixels / FR-Image pixels ``m * m``.

    A pixel is important when ``im > 0.5`` (exact for hard masks; for a soft mask it counts the
    pixels that the hard mask would most likely keep).

    Args:
        im: ``(B, 1, n, n)`` (or ``(B, n, n)``) importance mask.
        fr_size: FR-Image side ``m``.

    Returns:
        ``(B,)`` float32.

    Example:
        >>> ipr(torch.ones(1, 1, 2, 2), fr_size=4).tolist()
        [0.25]
    """
    return (im > 0.5).flatten(1).sum(1).float() / float(int(fr_size) ** 2)


def c_share(im: torch.Tensor, valid: Optional[torch.Tensor] = None) -> torch.Tensor:
    """Share of the valid C-Image pixels that are important, per image: ``(B,)`` float32.

    Args:
        im: ``(B, 1, n, n)`` importance mask (important where ``> 0.5``).
        valid: ``(n, n)`` bool mask of the pattern's pixels (``None``: all ``n*n``).

    Example:
        >>> valid = torch.tensor([[True, True], [True, False]])
        >>> c_share(torch.tensor([[[[1.0, 0.0], [1.0, 0.0]]]]), valid).mul(3).tolist()
        [2.0]
    """
    imp = im > 0.5
    if valid is None:
        return imp.flatten(1).float().mean(1)
    v = valid.to(device=im.device, dtype=torch.bool).reshape(1, -1)
    return (imp.flatten(1) & v).sum(1).float() / v.sum().clamp_min(1).float()


class IMLNet(nn.Module):
    """IML network. ``forward(c_image (B, 3, n, n), hard=None) -> IMLOutput``.

    Args:
        c_size: C-Image side ``n``.
        P: ``(n, n)`` rank pattern in ``(0, 1]`` (the plastic pattern; stored as a buffer).
        mean: mean value ``u`` in ``[0.01, 1]``. Default 0.1.
        alpha: sigmoid steepness of soft rejection sampling, ``> 0``. Default 50 (LAS).
        depth: U-Net resolution levels of encoder and decoder. Default 5 (paper).
        base_channels: U-Net first-level channels. Default 32.
        lower: lower bound ``l`` of the normalization. Default 0 (paper).
        delta: normalization guard. Default 1e-7 (paper).
        valid: optional ``(n, n)`` bool, True on the pattern's C-Image pixels (``pattern.valid``);
            the PIM mean is taken over them and the IM is forced to 0 elsewhere. ``None``: all valid.
        max_channels, norm: passed to :class:`~imls_lightning.models.unet.UNet`.
        decoder: ``"refine"`` (default) or ``"plain"`` (see the module docstring).
        importance: ``"learned"`` (default, the encoder) or ``"uniform"`` (no encoder: the blue-noise
            mask ``u > P``; always hard).
        straight_through: in training, sample the hard mask and pass the soft mask's gradient
            (``hard + soft - soft.detach()``), so the decoder trains on exactly the masks it gets at
            inference. Default False (the paper's soft mask).
        fill_pattern: a foveal pattern: the refine decoder fills at the samples' FR positions
            (:class:`RefineDecoder`). Default ``None``: in the C-Image's layout.

    ``hard=None`` means soft rejection sampling in training mode and hard in eval mode.

    Attributes:
        encoder (``None`` for uniform importance), decoder: the two networks (attach ``decoder`` to
        any RecNN, see :class:`IMLRecNN`); normalization (:class:`ImportanceNormalization`),
        sampling (:class:`RejectionSampling`).

    Example:
        >>> net = IMLNet(16, torch.rand(16, 16), depth=3, base_channels=4).eval()
        >>> out = net(torch.rand(2, 3, 16, 16))
        >>> out.im.shape, out.c_recon.shape
        (torch.Size([2, 1, 16, 16]), torch.Size([2, 3, 16, 16]))
    """

    def __init__(
        self,
        c_size: int,
        P: torch.Tensor,
        mean: float = 0.1,
        alpha: float = 50.0,
        depth: int = 5,
        base_channels: int = 32,
        lower: float = 0.0,
        delta: float = 1e-7,
        valid: Optional[torch.Tensor] = None,
        max_channels: int = 512,
        norm: str = "group",
        decoder: str = "refine",
        importance: str = "learned",
        straight_through: bool = False,
        fill_pattern=None,
    ):
        super().__init__()
        n = int(c_size)
        if n < 1:
            raise InputError(f"c_size={c_size}: expected a positive integer")
        if decoder not in DECODERS:
            raise InputError(f"decoder={decoder!r}: expected one of {list(DECODERS)}")
        if importance not in IMPORTANCE_SOURCES:
            raise InputError(f"importance={importance!r}: expected one of {list(IMPORTANCE_SOURCES)}")
        self.c_size = n
        P = torch.as_tensor(P, dtype=torch.float32)
        if tuple(P.shape) != (n, n):
            raise InputError(f"P: expected an ({n}, {n}) rank pattern for c_size={n}, got shape {tuple(P.shape)}")
        self.decoder_kind, self.importance_source = decoder, importance
        self.straight_through = bool(straight_through)
        self.encoder = (UNet(3, 1, depth=depth, base_channels=base_channels, max_channels=max_channels, norm=norm)
                        if importance == "learned" else None)
        self.decoder = build_decoder(decoder, depth, base_channels, max_channels, norm, fill_pattern=fill_pattern)
        self.normalization = ImportanceNormalization(mean, lower, delta)
        self.sampling = RejectionSampling(P, alpha)
        if valid is None:
            v = torch.ones(n, n)
        else:
            v = torch.as_tensor(valid)
            if tuple(v.shape) != (n, n):
                raise InputError(f"valid: expected an ({n}, {n}) mask for c_size={n}, got shape {tuple(v.shape)}")
        self.register_buffer("valid", v.to(torch.float32).view(1, 1, n, n), persistent=False)
        self._all_valid = valid is None or bool(v.all())

    mean = delegated("normalization", "mean", settable=True)
    alpha = delegated("sampling", "alpha", settable=True)

    def _check(self, c_image: torch.Tensor) -> None:
        n = self.c_size
        if c_image.dim() == 4 and tuple(c_image.shape[1:]) == (3, n, n):
            return
        # a training crop (data.crop): only where every C-pixel is a pattern pixel (no padding to place)
        crop = c_image.dim() == 4 and c_image.shape[1] == 3 and 1 <= c_image.shape[-2] <= n and 1 <= c_image.shape[-1] <= n
        if not (crop and self._all_valid):
            raise ValueError(f"IMLNet: expected a C-Image (B, 3, {n}, {n})"
                             f"{' or a crop (B, 3, h, w), h, w <= ' + str(n) if self._all_valid else ''}, got {tuple(c_image.shape)}")

    def encode(self, c_image: torch.Tensor, mean: Optional[float] = None) -> tuple[torch.Tensor, torch.Tensor]:
        """``(pim, pim_norm)``, each ``(B, 1, n, n)`` float32; normalized to ``mean`` (``None``: the net's own)."""
        self._check(c_image)
        if self.encoder is None:  # uniform importance: PIM' = u on every valid pixel
            pim = torch.ones_like(c_image[:, :1], dtype=torch.float64 if c_image.dtype == torch.float64 else torch.float32)
        else:
            logits = self.encoder(c_image)
            with torch.autocast(device_type=c_image.device.type, enabled=False):
                x = logits if logits.dtype in (torch.float32, torch.float64) else logits.float()
                pim = F.softplus(x)
        pim_norm = self.normalization(pim, None if self._all_valid else self.valid, mean=mean)
        return pim, pim_norm

    def sample(self, pim_norm: torch.Tensor, hard: Optional[bool] = None) -> torch.Tensor:
        """IM from PIM' (soft/hard as :class:`RejectionSampling`), forced to 0 on C-Image padding.

        Uniform importance is always hard; ``straight_through`` makes a soft request return the hard
        mask with the soft mask's gradient.
        """
        if hard is None:
            hard = not self.training
        if self.encoder is None:
            hard = True
        if not hard and self.straight_through:
            soft = self.sampling(pim_norm, False)
            im = self.sampling(pim_norm, True) + (soft - soft.detach())  # exactly the hard values
        else:
            im = self.sampling(pim_norm, hard)
        return im if self._all_valid else im * self.valid.to(im.dtype)

    def importance(self, c_image: torch.Tensor, hard: bool = True, mean: Optional[float] = None) -> torch.Tensor:
        """The IM alone: ``(B, 1, n, n)`` float32 (``{0, 1}`` when ``hard``; use ``.bool()`` for bits), at the mean value
        ``mean`` (``None``: the net's own)."""
        return self.sample(self.encode(c_image, mean)[1], hard)

    def decode(self, pr_c_image: torch.Tensor, im: torch.Tensor) -> torch.Tensor:
        """Rebuild the C-Image ``(B, 3, n, n)`` from the rendered pixels ``pr_c_image`` (``(B, 3, n, n)``,
        anything where ``im`` is 0) and the mask ``im`` ``(B, 1, n, n)``."""
        self._check(pr_c_image)
        return self.decoder(pr_c_image, im)

    def forward(self, c_image: torch.Tensor, hard: Optional[bool] = None, mean: Optional[float] = None) -> IMLOutput:
        """The IML on a C-Image; ``mean``: normalize to this mean value ``u`` for this call (``None``: the net's own)."""
        pim, pim_norm = self.encode(c_image, mean)
        im = self.sample(pim_norm, hard)
        pr_c = im * c_image.to(im.dtype)
        return IMLOutput(pim, pim_norm, im, pr_c, self.decoder(c_image.to(im.dtype), im))

    def extra_repr(self) -> str:
        return f"c_size={self.c_size}, all_valid={self._all_valid}, decoder={self.decoder_kind}, importance={self.importance_source}"


class IMLRecNN(nn.Module):
    """IML decoder (and encoder) in front of a RecNN: C-Image -> FR-Image.

    Args:
        iml: an :class:`IMLNet` (standalone- or end-to-end-trained).
        recnn: any RecNN with ``forward(c_image (B, 3, n, n)) -> (B, 3, m, m)`` and the same ``n``.

    Methods:
        ``forward(c_image, hard=None)``: IM from the C-Image (IML + RecNN, the upper bound) -> FR-Image.
        ``from_im(c_image, im)``: a given IM (e.g. from IMS) selects the pixels -> FR-Image.
        ``from_pr_c_image(pr_c_image, im)``: already selectively rendered C-Image and its mask -> FR-Image (IML/S).

    Example:
        >>> from imls_lightning.core.patterns import SamplingPattern
        >>> from imls_lightning.models.fovolnet import FoVolNet
        >>> pat = SamplingPattern("foveal", 16, 8, torch.randperm(256)[:64].sort().values)
        >>> iml = IMLNet(8, torch.rand(8, 8), depth=2, base_channels=4)
        >>> rec = FoVolNet(pat, features=4, depth=2, base_channels=4, filter_channels=4, levels=2)
        >>> IMLRecNN(iml, rec).from_im(torch.rand(1, 3, 8, 8), torch.ones(1, 1, 8, 8)).shape
        torch.Size([1, 3, 16, 16])
    """

    def __init__(self, iml: IMLNet, recnn: nn.Module):
        super().__init__()
        rc = getattr(recnn, "c_size", iml.c_size)
        if int(rc) != iml.c_size:
            raise InputError(f"IML c_size={iml.c_size} does not match the RecNN's c_size={rc}")
        self.iml, self.recnn = iml, recnn

    def from_pr_c_image(self, pr_c_image: torch.Tensor, im: torch.Tensor) -> torch.Tensor:
        return self.recnn(self.iml.decode(pr_c_image, im))

    def from_im(self, c_image: torch.Tensor, im: torch.Tensor) -> torch.Tensor:
        im = im.to(torch.float32 if c_image.dtype != torch.float64 else c_image.dtype)
        return self.from_pr_c_image(im * c_image.to(im.dtype), im)

    def forward(self, c_image: torch.Tensor, hard: Optional[bool] = None) -> torch.Tensor:
        return self.recnn(self.iml(c_image, hard).c_recon)
