"""The Importance Mask Learning network (paper, "Importance Mask Learning Network").

    C-Image --encoder U-Net (3->1) + softplus--> PIM --normalization (mean u)--> PIM'
            --rejection sampling vs P (soft in training, hard at inference)--> IM  (0 on padding)
    PR-C-Image = IM * C-Image --decoder U-Net (3->3)--> reconstructed C-Image

:class:`IMLRecNN` puts the decoder in front of any RecNN (EnhanceNet, FoVolNet): the paper's
end-to-end model, and, with a standalone-trained IML, its "off-the-shelf RecNN" case.

Precision. The encoder and decoder may run under autocast; softplus, normalization and rejection
sampling always run in float32 (see :mod:`imls_lightning.importance`), so ``pim``, ``pim_norm``,
``im`` and ``pr_c_image`` are float32, and ``c_recon`` is the decoder's dtype (bf16 under bf16
autocast: compute losses in float32).
"""
from __future__ import annotations

from typing import NamedTuple, Optional

import torch
import torch.nn.functional as F
from torch import nn

from data_gen.errors import InputError
from imls_lightning.importance import ImportanceNormalization, RejectionSampling
from imls_lightning.models.unet import UNet

__all__ = ["IMLOutput", "IMLNet", "IMLRecNN", "ipr", "c_share"]


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

    ``hard=None`` means soft rejection sampling in training mode and hard in eval mode.

    Attributes:
        encoder, decoder: the two U-Nets (attach ``decoder`` to any RecNN, see :class:`IMLRecNN`).
        normalization (:class:`ImportanceNormalization`), sampling (:class:`RejectionSampling`).

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
    ):
        super().__init__()
        n = int(c_size)
        if n < 1:
            raise InputError(f"c_size={c_size}: expected a positive integer")
        self.c_size = n
        P = torch.as_tensor(P, dtype=torch.float32)
        if tuple(P.shape) != (n, n):
            raise InputError(f"P: expected an ({n}, {n}) rank pattern for c_size={n}, got shape {tuple(P.shape)}")
        self.encoder = UNet(3, 1, depth=depth, base_channels=base_channels, max_channels=max_channels, norm=norm)
        self.decoder = UNet(3, 3, depth=depth, base_channels=base_channels, max_channels=max_channels, norm=norm)
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

    @property
    def mean(self) -> float:
        return self.normalization.mean

    @mean.setter
    def mean(self, value: float) -> None:
        self.normalization.mean = value

    @property
    def alpha(self) -> float:
        return self.sampling.alpha

    @alpha.setter
    def alpha(self, value: float) -> None:
        self.sampling.alpha = value

    def _check(self, c_image: torch.Tensor) -> None:
        n = self.c_size
        if c_image.dim() != 4 or tuple(c_image.shape[1:]) != (3, n, n):
            raise ValueError(f"IMLNet: expected a C-Image (B, 3, {n}, {n}), got {tuple(c_image.shape)}")

    def encode(self, c_image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(pim, pim_norm)``, each ``(B, 1, n, n)`` float32."""
        self._check(c_image)
        logits = self.encoder(c_image)
        with torch.autocast(device_type=c_image.device.type, enabled=False):
            x = logits if logits.dtype in (torch.float32, torch.float64) else logits.float()
            pim = F.softplus(x)
        pim_norm = self.normalization(pim, None if self._all_valid else self.valid)
        return pim, pim_norm

    def sample(self, pim_norm: torch.Tensor, hard: Optional[bool] = None) -> torch.Tensor:
        """IM from PIM' (soft/hard as :class:`RejectionSampling`), forced to 0 on C-Image padding."""
        im = self.sampling(pim_norm, hard)
        return im if self._all_valid else im * self.valid.to(im.dtype)

    def importance(self, c_image: torch.Tensor, hard: bool = True) -> torch.Tensor:
        """The IM alone: ``(B, 1, n, n)`` float32 (``{0, 1}`` when ``hard``; use ``.bool()`` for bits)."""
        return self.sample(self.encode(c_image)[1], hard)

    def decode(self, pr_c_image: torch.Tensor) -> torch.Tensor:
        """Inpaint a PR-C-Image ``(B, 3, n, n)`` into the C-Image ``(B, 3, n, n)``."""
        self._check(pr_c_image)
        return self.decoder(pr_c_image)

    def forward(self, c_image: torch.Tensor, hard: Optional[bool] = None) -> IMLOutput:
        pim, pim_norm = self.encode(c_image)
        im = self.sample(pim_norm, hard)
        pr_c = im * c_image.to(im.dtype)
        return IMLOutput(pim, pim_norm, im, pr_c, self.decoder(pr_c))

    def extra_repr(self) -> str:
        return f"c_size={self.c_size}, all_valid={self._all_valid}"


class IMLRecNN(nn.Module):
    """IML decoder (and encoder) in front of a RecNN: C-Image -> FR-Image.

    Args:
        iml: an :class:`IMLNet` (standalone- or end-to-end-trained).
        recnn: any RecNN with ``forward(c_image (B, 3, n, n)) -> (B, 3, m, m)`` and the same ``n``.

    Methods:
        ``forward(c_image, hard=None)``: IM from the C-Image (IML + RecNN, the upper bound) -> FR-Image.
        ``from_im(c_image, im)``: a given IM (e.g. from IMS) selects the pixels -> FR-Image.
        ``from_pr_c_image(pr_c_image)``: already selectively rendered C-Image -> FR-Image (IML/S).

    Example:
        >>> from imls_lightning.patterns import SamplingPattern
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

    def from_pr_c_image(self, pr_c_image: torch.Tensor) -> torch.Tensor:
        return self.recnn(self.iml.decode(pr_c_image))

    def from_im(self, c_image: torch.Tensor, im: torch.Tensor) -> torch.Tensor:
        im = im.to(torch.float32 if c_image.dtype != torch.float64 else c_image.dtype)
        return self.from_pr_c_image(im * c_image.to(im.dtype))

    def forward(self, c_image: torch.Tensor, hard: Optional[bool] = None) -> torch.Tensor:
        return self.recnn(self.iml(c_image, hard).c_recon)
