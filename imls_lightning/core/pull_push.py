"""Pull-push inpainting: the classical, untrained fill of a sparse image (LAS "fast inpainting").

The one home of the formula. LAS inpaints its samples with it before its reconstruction network;
the IML refine decoder (:class:`imls_lightning.models.iml.RefineDecoder`) starts from it; and every
report uses it alone as the untrained baseline a learned decoder has to beat.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..core.compaction import compact, decompact

__all__ = ["pull_push_inpaint", "PullPushInpaint", "fill_c_image", "in_layout_of"]

# Below this pyramid mass a pixel counts as empty in pull-push (LAS: exactly 0). Keeps 1/N finite.
_PP_EPS = 1e-12




def _pull(m: torch.Tensor, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    oh, ow = m.shape[-2] // 2, m.shape[-1] // 2
    if m.shape[-2] == 2 * oh and m.shape[-1] == 2 * ow:  # even sides: the windows are the 2x2 blocks
        mass, wsum, m_low = F.avg_pool2d(m, 2), F.avg_pool2d(m * d, 2), F.max_pool2d(m, 2)
    else:  # adaptive pooling windows = LAS start/end_index (floor(i H / oH) .. ceil((i+1) H / oH))
        mass = F.adaptive_avg_pool2d(m, (oh, ow))
        wsum = F.adaptive_avg_pool2d(m * d, (oh, ow))
        m_low = F.adaptive_max_pool2d(m, (oh, ow))
    ok = mass > _PP_EPS
    d_low = torch.where(ok, wsum / torch.where(ok, mass, torch.ones_like(mass)), torch.zeros_like(wsum))
    return m_low, d_low


def _upsample_axis(x: torch.Tensor, n: int, dim: int) -> torch.Tensor:
    """The push's bilinear taps along one axis (``dim`` = -2 rows, -1 columns): fine pixel i = 3/4 of coarse pixel
    i // 2 + 1/4 of its neighbour on i's side (i even: before, odd: after), zero beyond the edge; the axis goes
    from k to n = 2 k or 2 k + 1 pixels (an odd n's last pixel has its own coarse pixel past the edge)."""
    k = x.shape[dim]
    pad = (1, 1 + n - 2 * k) if dim == -1 else (0, 0, 1, 1 + n - 2 * k)
    padded = F.pad(x, pad)
    length = padded.shape[dim] - 2
    own = 0.75 * padded.narrow(dim, 1, length)
    before, after = own.add(padded.narrow(dim, 0, length), alpha=0.25), own.add(padded.narrow(dim, 2, length), alpha=0.25)
    # (..., L, 2) or (..., L, 2, W): each coarse pixel's two fine pixels side by side, then one axis of 2 L
    return torch.stack([before, after], dim).flatten(dim - 1, dim).narrow(dim, 0, n)


def _upsample(x: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """The push's (9/16, 3/16, 3/16, 1/16) taps, zero outside: separable, rows then columns."""
    return _upsample_axis(_upsample_axis(x, h, -2), w, -1)


def _push(m, d, m_low, d_low, top: bool = False):
    h, w = m.shape[-2:]
    # one pass over [m', m' d']: N and D; W, the taps inside the image, is separable (1 inside, less at the edges)
    nd = _upsample(torch.cat([m_low, m_low * d_low], 1), h, w)
    N, D = nd[:, :1], nd[:, 1:]
    ok = N > _PP_EPS
    fill = torch.where(ok, D / torch.where(ok, N, torch.ones_like(N)), torch.zeros_like(D))
    d_out = torch.lerp(fill, d, m)  # m d + (1 - m) fill, exact at m = 0 and 1: a sample comes back unchanged
    if top:  # the finest level returns the data only
        return m, d_out
    W = _upsample_axis(m_low.new_ones(m_low.shape[-2], 1), h, -2) * _upsample_axis(m_low.new_ones(1, m_low.shape[-1]), w, -1)
    m_out = m + (1 - m) * (N / W)  # W >= 9/16 or 3/16 > 0 always (one coarse tap is inside)
    return m_out, d_out


def _pull_push(m, d, top: bool = False):
    if m.shape[-2] <= 1 or m.shape[-1] <= 1:
        return m, d
    m_low, d_low = _pull(m, d)
    m_low, d_low = _pull_push(m_low, d_low)
    return _push(m, d, m_low, d_low, top)


def pull_push_inpaint(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Fill the unsampled pixels of a sparse image by a pull-push pyramid (LAS "fast inpainting").

    Differentiable w.r.t. ``values`` and ``mask`` (fractional masks allowed: the soft sampling mask
    of training). Pull: halve the image, ``m' = max(m)``, ``d' = sum(m d) / sum(m)`` over each
    window; recurse down to a side of 1; push: each fine pixel blends its own value with the
    bilinear (9/16, 3/16, 3/16, 1/16) mask-weighted average of the 4 nearest coarse pixels,
    ``d_out = m d + (1 - m) D / N``. With a 0/1 mask, sampled pixels are returned unchanged. Works
    for any ``H, W`` (not only powers of two). Runs in float32 (float64 kept) with autocast off.

    Args:
        values: ``(B, C, H, W)`` sample values (anything where the mask is 0).
        mask: ``(B, 1, H, W)`` or ``(B, H, W)`` in [0, 1] (bool allowed).

    Returns:
        ``(B, C, H, W)`` inpainted image, dtype of ``values`` (float32 for reduced precision).
        An all-zero mask gives all zeros.

    Example:
        >>> v = torch.zeros(1, 1, 4, 4); v[0, 0, 0, 0] = 2.0
        >>> m = (v > 0).float()
        >>> pull_push_inpaint(v, m).unique().tolist()
        [2.0]
    """
    if values.dim() != 4:
        raise ValueError(f"values: expected (B, C, H, W), got {tuple(values.shape)}")
    if mask.dim() == 3:
        mask = mask.unsqueeze(1)
    if mask.dim() != 4 or mask.shape[1] != 1 or mask.shape[0] != values.shape[0] or mask.shape[-2:] != values.shape[-2:]:
        raise ValueError(f"mask: expected (B, 1, H, W) matching values {tuple(values.shape)}, got {tuple(mask.shape)}")
    dt = torch.float64 if values.dtype == torch.float64 else torch.float32
    with torch.autocast(device_type=values.device.type, enabled=False):
        return _pull_push(mask.to(dt), values.to(dt), top=True)[1]


def fill_c_image(values: torch.Tensor, mask: torch.Tensor, pattern=None) -> torch.Tensor:
    """Pull-push fill of a C-Image's unsampled pixels, where the pixels' neighbours are their neighbours
    in the image.

    A downsampling pattern's C-Image is a regular grid of the FR-Image, so it is filled as it is. A foveal
    pattern's C-Image packs scattered FR pixels in raster order (:func:`~imls_lightning.core.compaction.compact`):
    its rows are runs of FR rows and its columns are not neighbours at all. Its samples are scattered back to
    their FR positions, filled there and gathered again, so the untrained baseline fills from the pixels
    around each hole in the picture, not from its neighbours in memory.

    Args:
        values: ``(B, C, n, n)`` C-Image values (anything where the mask is 0).
        mask: ``(B, 1, n, n)`` or ``(B, n, n)`` in [0, 1] (bool allowed).
        pattern: the :class:`~imls_lightning.core.patterns.SamplingPattern` of the C-Image; ``None`` or a
            grid pattern: the plain :func:`pull_push_inpaint`.

    Returns:
        ``(B, C, n, n)``, the sampled pixels unchanged (0/1 mask); float32 for reduced precision.

    Example:
        >>> from imls_lightning.core.patterns import foveal_pattern
        >>> p = foveal_pattern(16, 6, None)
        >>> v = torch.rand(1, 3, 6, 6); m = (torch.rand(1, 1, 6, 6) > 0.5).float()
        >>> out = fill_c_image(v, m, p)
        >>> out.shape, bool(torch.equal(out * m, v * m))
        (torch.Size([1, 3, 6, 6]), True)
    """
    if pattern is None or pattern.kind != "foveal":
        return pull_push_inpaint(values, mask)
    if mask.dim() == 3:
        mask = mask.unsqueeze(1)
    m = mask.to(values.dtype)
    idx = pattern.indices.to(values.device)  # pull_push_inpaint picks the working precision, as for a grid
    filled = pull_push_inpaint(decompact(values * m, idx, pattern.fr_size), decompact(m, idx, pattern.fr_size))
    return compact(filled, idx, pattern.c_size)


def in_layout_of(x: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """``x`` in ``like``'s memory layout: channels-last where ``like`` is channels-last and not also plain contiguous
    (a ``(B, C, n, n)`` view of ``(B, n, n, C)`` memory), else ``x`` as it is. The pull-push fill returns plain
    contiguous memory; a network given a channels-last C-Image runs up to 1.7x faster on the CPU (EnhanceNet at
    256^2: 22 against 39 ms), so a fill in a method's path keeps the layout the method built.

    Example:
        >>> c = torch.rand(1, 8, 8, 3).permute(0, 3, 1, 2)        # channels-last, as a rendered C-Image is built
        >>> in_layout_of(c.contiguous(), c).is_contiguous(memory_format=torch.channels_last)
        True
    """
    if like.dim() == 4 and like.is_contiguous(memory_format=torch.channels_last) and not like.is_contiguous():
        return x.contiguous(memory_format=torch.channels_last)
    return x


class PullPushInpaint(nn.Module):
    """:func:`pull_push_inpaint` as a layer: ``forward(values, mask)``."""

    def forward(self, values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return pull_push_inpaint(values, mask)
