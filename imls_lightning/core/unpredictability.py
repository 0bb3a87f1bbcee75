"""Where a C-Image's pixels are unpredictable from their neighbours: an importance nothing learned.

Each C-pixel's *unpredictability* is the error of filling it (by the product's untrained pull-push fill) from
the other half of a blue-noise split of the pixels (:func:`unpredictability`): a pixel on a smooth surface is
predicted by its neighbours, a pixel on an edge, a fold or a spine is not. A two-pass sampler knows it only at
the pixels it ray-cast first (:func:`base_unpredictability`). :func:`importance_mask` makes the product's kind of
hard mask from it at any share of the pattern (normalized to the mean, lifted where the rescale falls short,
thresholded against the plastic rank pattern), with a floor that keeps every region sampled;
:func:`two_pass_mask` adds such a mask to a first pass.

Used by the before-training estimate (:mod:`imls_lightning.estimate.needed_share`: the share a scene needs) and by
the classical two-pass sampler (:class:`imls_lightning.inference.two_pass.TwoPassFill`), the simplest alternative
the IMS has to beat.

Example:
    >>> from imls_lightning.core.patterns import downsample_pattern
    >>> p = downsample_pattern(16, 2)
    >>> c = torch.zeros(1, 3, 8, 8); c[..., 4:] = 1.0            # one vertical edge
    >>> score = unpredictability(c, p)
    >>> bool(score[0, 0, :, 3:5].sum() > 0), float(score[0, 0, :, :2].sum())   # only the edge is unpredictable
    (True, 0.0)
    >>> importance_mask(score, 0.25, p, floor=0.25).float().mean().item()      # a quarter of the pixels, edge first
    0.25
"""
from __future__ import annotations

import torch

from imls_lightning.base.errors import InputError
from imls_lightning.base.validate import check_number

from .pull_push import fill_c_image
from .importance import lift_to_share, lifted_mask, normalize_importance, sharpen_importance
from .patterns import SamplingPattern, plastic_rank_pattern
from .rank_patterns import blue_noise


def cross_fill_error(c: torch.Tensor, half: torch.Tensor, other: torch.Tensor, pattern: SamplingPattern) -> torch.Tensor:
    """``(B, 1, n, n)``: on ``other`` the error of filling ``c`` ``(B, 3, n, n)`` from ``half``, on ``half`` the error of
    filling it from ``other`` (absolute, summed over the channels), 0 elsewhere; ``half``, ``other``: ``(n, n)`` bool."""
    b, n = c.shape[0], c.shape[-1]
    score = torch.zeros(b, 1, n, n, dtype=torch.float32, device=c.device)
    for known, unknown in ((half, other), (other, half)):
        m = known[None, None].to(device=c.device, dtype=torch.float32).expand(b, 1, n, n)
        err = (fill_c_image(c.float() * m, m, pattern) - c.float()).abs().sum(1, keepdim=True)
        score = torch.where(unknown[None, None].to(c.device), err, score)
    return score


def unpredictability(c: torch.Tensor, pattern: SamplingPattern, seed: int = 0) -> torch.Tensor:
    """Each C-pixel's error when filled from the other half of a blue-noise split: ``(B, 3, n, n)`` ->
    ``(B, 1, n, n)``, the absolute error summed over the channels.

    The pixels of the half ``H`` (blue noise below 0.5) are filled from the others and the others from
    ``H`` (:func:`~imls_lightning.core.pull_push.fill_c_image`, the product's untrained fill), so every
    pixel is scored by how well its neighbours predict it. Pixels past the pattern's ``K`` score 0.
    """
    n = pattern.c_size
    if c.dim() != 4 or c.shape[-2:] != (n, n):
        raise ValueError(f"c: expected a (B, 3, {n}, {n}) C-Image, got {tuple(c.shape)}")
    valid = pattern.valid.to(c.device)
    half = (blue_noise(n, seed) < 0.5).to(c.device) & valid
    return cross_fill_error(c, half, ~half & valid, pattern)


def first_pass(pattern: SamplingPattern, base: float, seed: int = 0) -> torch.Tensor:
    """``(n, n)`` bool: a two-pass sampler's first pass, the blue-noise ``base`` share of the pattern's pixels."""
    if not 0.0 < float(base) < 1.0:
        raise InputError(f"base={base}: expected the share of a first pass in (0, 1)")
    return (blue_noise(pattern.c_size, seed) < float(base)) & pattern.valid


def base_unpredictability(c: torch.Tensor, pattern: SamplingPattern, base: float, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`unpredictability` as a two-pass renderer could know it: from a blue-noise ``base`` share of the
    C-Image only. The base pixels are scored against each other (the halves of their own blue-noise split) and
    their scores are spread to the other pixels by the same fill. Returns ``(score (B, 1, n, n), base mask
    (n, n) bool)``: what a classical adaptive sampler would render first, and where it would add pixels next.
    """
    n = pattern.c_size
    valid = pattern.valid.to(c.device)
    ranks = blue_noise(n, seed).to(c.device)
    first = first_pass(pattern, base, seed).to(c.device)
    half = first & (ranks < float(base) / 2)   # the base's own blue-noise halves: blue noise below b/2 and the rest
    other = first & ~half
    err = cross_fill_error(c, half, other, pattern)
    m = first[None, None].float().expand(c.shape[0], 1, n, n)
    return fill_c_image(err * m, m, pattern) * valid, first


def importance_mask(score: torch.Tensor, share: float, pattern: SamplingPattern, floor: float = 0.0,
                    among: torch.Tensor | None = None, sharpness: float = 1.0) -> torch.Tensor:
    """The product's hard mask of ``share`` of the pattern from an importance ``(B, 1, n, n)``: normalized to
    the mean ``share``, lifted where the rescale falls short, thresholded against the plastic rank pattern;
    ``(B, 1, n, n)`` bool, the pattern's pixels only.

    ``floor``: importance added everywhere, relative to the mean importance (a pixel of no importance is
    sampled at about ``floor / (1 + floor)`` of the mean density). A fill cannot rebuild a region none of
    whose pixels is kept, however predictable the region is from its own pixels: the trained IMS keeps such a
    floor on the background (ct_head's at 0.24 of the object's density).

    ``among``: ``(n, n)`` bool, the pixels the mask may choose (default: the pattern's); ``share`` is of those.

    ``sharpness``: ``gamma`` in ``[1, 8]``, the floored importance sharpened as the IMS's mask head sharpens its
    PIM' (:func:`~imls_lightning.core.importance.sharpen_importance`) before the rescale: 1 leaves it as it is.
    """
    s = check_number(share, "share", 0.0, 1.0, lo_open=True, what="a share of the C-Image in (0, 1]")
    f = check_number(floor, "floor", 0.0, what="a number >= 0 (importance relative to the mean)")
    valid = pattern.valid.to(score.device)
    if among is not None:
        valid = valid & among.to(device=score.device, dtype=torch.bool)
    P = plastic_rank_pattern(pattern.c_size).to(score.device)
    if f > 0:
        mean = (score * valid).sum(dim=(1, 2, 3), keepdim=True) / valid.sum().clamp_min(1)
        score = score + f * mean.clamp_min(1e-12)  # a flat image: the floor alone, sampled evenly
    score = sharpen_importance(score, sharpness, valid=valid)
    pim = normalize_importance(score, max(s, 0.01), valid=valid)
    mult, lift = lift_to_share(pim, s, valid=valid)
    return lifted_mask(pim, mult, lift, P) & valid


def two_pass_mask(score: torch.Tensor, first: torch.Tensor, share: float, pattern: SamplingPattern,
                  floor: float = 0.0) -> torch.Tensor:
    """A two-pass sampler's pixels in all: the first pass ``first`` ``(n, n)`` bool and, among the others, the
    :func:`importance_mask` of ``score`` ``(B, 1, n, n)`` that brings the total to ``share`` of the pattern;
    ``(B, 1, n, n)`` bool. A share at or below the first pass's keeps the first pass alone."""
    first = first.to(device=score.device, dtype=torch.bool)
    b = float(first.sum()) / max(pattern.count, 1)
    if float(share) <= b or b >= 1.0:
        return first[None, None].expand(score.shape[0], 1, *first.shape).clone()
    rest = min((float(share) - b) / (1.0 - b), 1.0)
    return importance_mask(score, rest, pattern, floor, among=~first) | first


__all__ = ["first_pass", "cross_fill_error", "unpredictability", "base_unpredictability", "importance_mask", "two_pass_mask"]
