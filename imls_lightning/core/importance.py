"""Importance normalization and rejection sampling of the IML network (paper, "Importance Mask
Learning Network": Normalization, Rejection Sampling).

The encoder's preliminary importance mask PIM (``>= 0``, from a softplus) is rescaled per image so
that its mean is the prescribed *mean value* ``u``:

    PIM'_ij = l + PIM_ij (u - l) / (mean(PIM) + delta)

and thresholded against the fixed plastic rank pattern ``P`` (values in ``(0, 1]``):

    hard (inference):  IM_ij = [PIM'_ij > P_ij]                 one bit per pixel
    soft (training):   IM_ij = sigmoid(alpha (PIM'_ij - P_ij))   differentiable

Numerics. Both steps run in float32 with autocast disabled, whatever the input dtype (float64 stays
float64, for ``gradcheck``): under bf16 autocast the 8-bit mantissa would quantize ``P`` and
``PIM'`` to ~0.4 % and move the mask. ``torch.sigmoid`` saturates to exactly 0/1 without
overflow, so ``alpha = 1e4`` is safe, and with ``l = 0`` the largest possible ``PIM'`` is
``u * N`` (all importance on one of ``N`` pixels), so ``alpha (PIM' - P)`` stays far from the
float32 range. An all-zero PIM has mean 0; ``delta`` then keeps the division finite and gives
``PIM' = l`` (no important pixels for ``l = 0``), gradients stay finite. Note the same holds,
smoothly, for any PIM whose mean is comparable to or below ``delta`` (1e-7): such a PIM is treated as
"no importance" rather than being rescaled to the mean ``u``.
"""
from __future__ import annotations

import math
from typing import Any, Optional

import torch
from torch import nn

from imls_lightning.base.errors import InputError
from imls_lightning.base.validate import check_number

__all__ = [
    "check_mean",
    "check_alpha",
    "check_ipr",
    "delegated",
    "normalize_importance",
    "check_sharpness",
    "check_sharpnesses",
    "sharpen_importance",
    "SharpenImportance",
    "lift_to_share",
    "lifted_mask",
    "LiftToShare",
    "check_object_floor",
    "object_fraction",
    "floored_mean",
    "soft_rejection_sample",
    "hard_rejection_sample",
    "ImportanceNormalization",
    "RejectionSampling",
]

MEAN_RANGE = (0.01, 1.0)


def check_mean(mean: float, name: str = "mean") -> float:
    """Validate the prescribed mean value ``u`` (paper: a number in ``[0.01, 1]``)."""
    return check_number(mean, name, MEAN_RANGE[0], MEAN_RANGE[1])


def check_alpha(alpha: float, name: str = "alpha") -> float:
    """Validate the sigmoid steepness ``alpha`` (positive and finite)."""
    return check_number(alpha, name, 0, lo_open=True, what="a positive finite number")


def check_ipr(ipr: float, name: str = "ipr") -> float:
    """Validate a target share of sampled pixels (IPR): a number in ``(0, 1]``.

    Example:
        >>> check_ipr("0.25")
        0.25
    """
    return check_number(ipr, name, 0.0, 1.0, lo_open=True, what="a number in (0, 1]")


def _check_lower_delta(mean: float, lower: float, delta: float) -> tuple[float, float]:
    lower, delta = float(lower), float(delta)
    if not (0.0 <= lower < mean):
        raise InputError(f"lower={lower}: expected 0 <= lower < mean ({mean})")
    if not (delta > 0 and math.isfinite(delta)):
        raise InputError(f"delta={delta}: expected a small positive number (default 1e-7)")
    return lower, delta


def _f32(x: torch.Tensor) -> torch.Tensor:
    """float32 for reduced precision inputs, float64 kept (gradcheck), other dtypes -> float32."""
    return x if x.dtype in (torch.float32, torch.float64) else x.float()


def _valid_4d(valid: torch.Tensor, device, dtype) -> torch.Tensor:
    """An ``(H, W)`` / ``(1, 1, H, W)`` / ``(B, 1, H, W)`` pixel mask as a 4-D tensor of ``dtype`` on ``device``."""
    v = valid.to(device=device, dtype=dtype)
    while v.dim() < 4:
        v = v.unsqueeze(0)
    return v


def _valid_mean(x: torch.Tensor, v: torch.Tensor | None) -> torch.Tensor:
    """``(B, 1, 1, 1)``: each image's mean over all pixels (``v=None``) or over the pixels of the 4-D mask ``v``;
    the count is clamped at 1, so an all-invalid image has mean 0, not NaN."""
    if v is None:
        return x.mean(dim=(1, 2, 3), keepdim=True)
    count = v.expand(x.shape[0], 1, x.shape[2], x.shape[3]).sum(dim=(1, 2, 3), keepdim=True).clamp_min(1.0) * x.shape[1]
    return (x * v).sum(dim=(1, 2, 3), keepdim=True) / count


def normalize_importance(
    pim: torch.Tensor,
    mean: float,
    lower: float = 0.0,
    delta: float = 1e-7,
    valid: Optional[torch.Tensor] = None,
) -> torch.Tensor:
    """Normalize the preliminary importance mask to the prescribed mean value, per image.

    ``PIM' = l + PIM (u - l) / (mean(PIM) + delta)``, the mean taken per image over all pixels, or
    over the valid C-Image pixels only when ``valid`` is given (the zero padding past the pattern's
    ``K`` pixels must not dilute the mean: it is never rendered). ``PIM'`` is computed everywhere;
    the caller masks the padding out of the IM.

    Args:
        pim: ``(B, C, H, W)`` non-negative PIM (usually ``C = 1``), any float dtype.
        mean: the mean value ``u`` in ``[0.01, 1]``.
        lower: lower bound ``l`` in ``[0, u)`` (paper: 0).
        delta: ``> 0``, guards the division (paper: 1e-7).
        valid: optional ``(H, W)``, ``(1, 1, H, W)`` or ``(B, 1, H, W)`` bool/0-1 mask of the pixels
            that enter the mean.

    Returns:
        ``(B, C, H, W)`` PIM' in float32 (float64 if ``pim`` is float64), computed with autocast off.

    Example:
        >>> pim = torch.tensor([[[[1.0, 3.0]]]])
        >>> normalize_importance(pim, 0.5, delta=1e-12).tolist()
        [[[[0.25, 0.75]]]]
    """
    u = check_mean(mean)
    lower, delta = _check_lower_delta(u, lower, delta)
    if pim.dim() != 4:
        raise ValueError(f"pim: expected a (B, C, H, W) tensor, got shape {tuple(pim.shape)}")
    with torch.autocast(device_type=pim.device.type, enabled=False):
        x = _f32(pim)
        # an all-invalid image has mean 0 -> PIM' = l, not NaN
        mu = _valid_mean(x, None if valid is None else _valid_4d(valid, x.device, x.dtype))
        return lower + x * ((u - lower) / (mu + delta))


SHARPNESS_RANGE = (1.0, 8.0)


def check_sharpness(sharpness: float, name: str = "sharpness") -> float:
    """Validate a mask sharpness ``gamma`` in ``[1, 8]`` (1: the paper's mask).

    Below 1 the power's gradient at 0 is infinite, and flattening the mask bought nothing where it was
    measured (flame_whole: at 0.7 the same gap cost more pixels); above 8 it is a step function.

    Example:
        >>> check_sharpness("2")
        2.0
    """
    return check_number(sharpness, name, SHARPNESS_RANGE[0], SHARPNESS_RANGE[1], what="a number in [1, 8] (1: the paper's mask)")


def check_sharpnesses(values: Any, name: str = "sharpness") -> list[float]:
    """Validate a number or a list of mask sharpnesses (:func:`check_sharpness` each): sorted, without repeats.

    Example:
        >>> check_sharpnesses([2, 1, 2.0]), check_sharpnesses(3)
        ([1.0, 2.0], [3.0])
    """
    items = list(values) if isinstance(values, (list, tuple)) else [values]
    if not items:
        raise InputError(f"{name}={values}: expected a number or a list of numbers in [1, 8] (1: the paper's mask)")
    return sorted({check_sharpness(x, name) for x in items})


def sharpen_importance(pim: torch.Tensor, sharpness: float, valid: Optional[torch.Tensor] = None,
                       delta: float = 1e-7) -> torch.Tensor:
    """Sharpen a normalized importance per image, keeping its mean: ``S = R^gamma mean(PIM') / (mean(R^gamma) + delta)``
    with ``R = PIM' / max(PIM')`` (the same as ``PIM'^gamma mean(PIM') / mean(PIM'^gamma)``, without its underflow).

    At the same mean the pixels it ranks high gain density and its low, flat floor (the background an IMS
    spreads a little density over) loses it, so a mask dithered from ``S`` spends fewer pixels where the
    importance is low. The means are over all pixels, or over ``valid`` ones only (the C-Image's pattern
    pixels, as :func:`normalize_importance`). ``gamma = 1`` returns ``pim`` unchanged (the same tensor).

    Args:
        pim: ``(B, C, H, W)`` non-negative importance (negative values count as 0), any float dtype.
        sharpness: ``gamma`` in ``[1, 8]`` (:func:`check_sharpness`).
        valid: optional ``(H, W)``, ``(1, 1, H, W)`` or ``(B, 1, H, W)`` mask of the pixels in the means.
        delta: ``> 0``, guards the division (an all-zero image stays zero); ``mean(R^gamma) >= 1 / N`` otherwise.

    Returns:
        ``(B, C, H, W)`` in float32 (float64 for float64 input), computed with autocast off.

    Example:
        >>> pim = torch.tensor([[[[0.2, 0.2, 0.6, 1.0]]]])
        >>> sharpen_importance(pim, 2.0, delta=0.0).tolist()   # the same mean, 0.5, the high values higher
        [[[[0.0555555559694767, 0.0555555559694767, 0.5, 1.3888888359069824]]]]
    """
    gamma = check_sharpness(sharpness)
    if pim.dim() != 4:
        raise ValueError(f"pim: expected a (B, C, H, W) tensor, got shape {tuple(pim.shape)}")
    if gamma == 1.0:
        return pim
    with torch.autocast(device_type=pim.device.type, enabled=False):
        x = _f32(pim).clamp_min(0.0)
        v = None if valid is None else _valid_4d(valid, x.device, x.dtype)
        # the power of x / max(x), not of x: a faint image (all PIM' ~ 0.01) at gamma = 8 would underflow to 0
        # and lose its mean to delta; relative to its maximum the largest term is 1 and the mean is kept
        top = (x if v is None else x * v).amax(dim=(1, 2, 3), keepdim=True)
        s = (x / top.clamp_min(torch.finfo(x.dtype).tiny)) ** gamma
        return s * (_valid_mean(x, v) / (_valid_mean(s, v) + delta))


class SharpenImportance(nn.Module):
    """:func:`sharpen_importance` as a module with its ``sharpness`` bound.

    Example:
        >>> SharpenImportance(3.0)(torch.ones(1, 1, 4, 4)).shape
        torch.Size([1, 1, 4, 4])
    """

    def __init__(self, sharpness: float = 1.0):
        super().__init__()
        self.sharpness = check_sharpness(sharpness)

    def forward(self, pim: torch.Tensor, valid: Optional[torch.Tensor] = None) -> torch.Tensor:
        return sharpen_importance(pim, self.sharpness, valid)

    def extra_repr(self) -> str:
        return f"sharpness={self.sharpness}"


def check_object_floor(margin: Any, tau: Any = 0.2, name: str = "object_floor") -> tuple[float, float]:
    """Validate an object floor: ``(margin, tau)`` with ``margin`` in ``[0, 1]`` and ``tau`` in ``(0, 1)``.

    Example:
        >>> check_object_floor("0.1", 0.2)
        (0.1, 0.2)
    """
    m = check_number(margin, f"{name}.margin", 0.0, 1.0, what="a share of the C-Image in [0, 1]")
    t = check_number(tau, f"{name}.tau", 0.0, 1.0, lo_open=True, hi_open=True,
                     what="an importance in (0, 1) above which a pixel counts as the object")
    return m, t


def object_fraction(pim: torch.Tensor, valid: torch.Tensor, tau: float = 0.2) -> torch.Tensor:
    """The share of each image's ``valid`` pixels whose importance exceeds ``tau``: ``(B,)`` float32.

    What an IMS's PIM' (from the view alone) says of the object a view shows: on the paper-regime scenes its
    background sits near 0.02 and its object well above 0.2. A mask whose share falls near this fraction leaves
    holes in the object (seed_whole's failing views, BENCHMARKS.md), so :func:`floored_mean` keeps a margin above it.

    Args:
        pim: ``(B, 1, H, W)`` importance in ``[0, 1]``.
        valid: ``(H, W)`` (or broadcastable 4-D) bool, the pattern's C-pixels; an image with none gets 0.
        tau: the importance above which a pixel counts as the object.

    Example:
        >>> pim = torch.tensor([[[[0.9, 0.0], [0.5, 0.1]]]])
        >>> object_fraction(pim, torch.ones(2, 2, dtype=torch.bool)).tolist()
        [0.5]
        >>> object_fraction(pim, torch.tensor([[True, False], [False, False]])).tolist()
        [1.0]
    """
    with torch.autocast(device_type=pim.device.type, enabled=False):
        v = _valid_4d(valid, pim.device, torch.float32)
        hit = (pim.float() > float(tau)).float() * v
        count = v.expand_as(hit).sum(dim=(1, 2, 3)).clamp_min(1.0)
        return hit.sum(dim=(1, 2, 3)) / count


def floored_mean(mean: torch.Tensor, fraction: torch.Tensor, margin: "float | torch.Tensor") -> torch.Tensor:
    """Each view's mean value raised to its object's fraction plus ``margin`` where that is larger, at most 1:
    ``max(u, min(1, f + margin))``, ``(B,)``. ``margin``: one number, or ``(B,)``, one per view (a floor per band of
    camera distance, :class:`~imls_lightning.models.ims.DistanceMeans`); a negative margin of -1 is no floor for
    that view (``f - 1 <= 0``).

    Example:
        >>> floored_mean(torch.tensor([0.3, 0.6]), torch.tensor([0.35, 0.35]), 0.1).tolist()
        [0.44999998807907104, 0.6000000238418579]
        >>> floored_mean(torch.tensor([0.3, 0.3]), torch.tensor([0.35, 0.35]), torch.tensor([0.1, -1.0])).tolist()
        [0.44999998807907104, 0.30000001192092896]
    """
    m = margin.to(device=fraction.device, dtype=torch.float32) if torch.is_tensor(margin) else float(margin)
    return torch.maximum(mean.float(), (fraction.float() + m).clamp(max=1.0))


def lift_to_share(
    pim_norm: torch.Tensor,
    mean: torch.Tensor | float,
    valid: Optional[torch.Tensor] = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per image, the multiplier ``m >= 1`` and floor ``f`` that make a normalized importance sample a
    share ``u`` of the pixels (the IMS's masks at mean values above the trained one).

    Against the rank pattern ``P`` (uniform in ``(0, 1]``) a pixel of importance ``x`` is sampled with
    probability ``min(x, 1)``. Once pixels saturate above 1 the share falls short of the mean ``u``, and
    a pixel at 0 is never sampled at any ``u`` (an IMS trained at ``u = 0.2`` reaches 66 % of C at
    ``u = 1`` on ct_head). This lifts ``PIM'`` in two steps, so that the expected share is ``u``:

    1. scale first: the smallest ``m >= 1`` with ``mean(min(m PIM', 1)) = u``. ``m PIM' > P`` is the
       same family of masks as the paper's rescale, only reaching the share ``u`` (the importance
       ranking is kept);
    2. only when every pixel with ``PIM' > 0`` is taken (``m = inf``): the floor ``f`` in ``[0, 1]`` on
       the pixels at 0, a blue-noise share ``f > P`` of them. ``u = 1`` samples every pixel.

    ``m = 1, f = 0`` (no change) when ``mean(min(PIM', 1)) >= u`` already. Solved exactly from the
    sorted values: with the ``k`` largest saturated the share is ``(k + m R_k) / N``, ``R_k`` the sum
    of the others.

    Tensor operations only, on ``pim_norm``'s device, all images at once: ``torch.jit.trace`` and the
    ONNX exporter record it (the exported IMS mask, :mod:`imls_lightning.inference.export`). Only a ``valid`` that
    differs between images is solved image by image.

    Args:
        pim_norm: ``(B, 1, H, W)`` normalized importance PIM' (``>= 0``).
        mean: the share to reach per image: a number or a ``(B,)`` tensor in ``[0, 1]``.
        valid: optional ``(H, W)`` / ``(1, 1, H, W)`` / ``(B, 1, H, W)`` mask of the pixels that count
            (the pattern's ``K`` pixels of a compacted C-Image).

    Returns:
        ``(m, f)``, each ``(B, 1, 1, 1)`` float64 (``m`` may be ``inf``); not differentiable (thresholds).
        The mask is ``(m PIM' > P) | (f > P)``, with ``m PIM'`` read as ``PIM' > 0`` where ``m = inf``
        (:func:`lifted_mask`).

    Example:
        >>> pim = torch.tensor([[[[0.0, 0.1, 0.3, 2.0]]]])   # mean(min(PIM', 1)) = 0.35
        >>> [v.item() for v in lift_to_share(pim, 0.35)]      # reached already
        [1.0, 0.0]
        >>> [round(v.item(), 6) for v in lift_to_share(pim, 0.5)]   # scale 0.1 and 0.3 by 2.5
        [2.5, 0.0]
        >>> [v.item() for v in lift_to_share(pim, 0.875)]    # all three taken, the zero lifted to 0.5
        [inf, 0.5]
    """
    if pim_norm.dim() != 4:
        raise ValueError(f"pim_norm: expected a (B, C, H, W) tensor, got shape {tuple(pim_norm.shape)}")
    b = pim_norm.shape[0]
    x = pim_norm.detach().to(torch.float64).clamp_min(0.0)
    u = torch.as_tensor(mean, dtype=torch.float64).reshape(-1)
    if u.numel() != 1 and u.numel() != b:
        raise ValueError(f"mean: expected a number or {b} mean values, got {u.numel()}")
    if not torch.jit.is_tracing():  # a traced mean is the constant it was checked as
        for v in u.tolist():
            if not (0.0 <= v <= 1.0 + 1e-6):  # a float32 1.0 passes
                check_number(v, "mean", 0.0, 1.0)
    u = u.to(x.device).clamp(0.0, 1.0).expand(b)
    flat = x.flatten(1)
    if valid is None:
        return _lift_rows(flat, u)
    v = _valid_4d(valid, x.device, torch.bool)
    if v.shape[0] == 1:  # one set of pixels for every image: gathered once, solved at once
        index = torch.nonzero(v.flatten()).flatten()
        return _lift_rows(flat.index_select(1, index), u)
    v = v.expand(b, 1, x.shape[2], x.shape[3]).flatten(1)
    parts = [_lift_rows(flat[i][v[i]][None], u[i:i + 1]) for i in range(b)]
    return torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts])


def _lift_rows(vals: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`lift_to_share` of the rows of ``vals`` ``(B, N)`` float64 (the counted pixels of each
    image) at the shares ``u`` ``(B,)``: ``(m, f)`` ``(B, 1, 1, 1)``."""
    b, n = vals.shape
    one = torch.ones(b, dtype=torch.float64, device=vals.device)
    if not torch.jit.is_tracing() and n == 0:  # no pixel counts: nothing to reach (a traced n is never 0)
        return one.view(b, 1, 1, 1), torch.zeros_like(one).view(b, 1, 1, 1)
    target = u * n
    reached = vals.clamp(max=1.0).sum(1) >= target           # the rescale reaches u by itself
    npos = (vals > 0).sum(1).to(torch.float64)
    take_all = ~reached & (target >= npos)                     # every pixel with importance, then the floor
    floor = ((target - npos) / (n - npos).clamp_min(1.0)).clamp(0.0, 1.0)
    xs = vals.sort(1, descending=True).values                  # zeros last: they add nothing below
    rest = xs.flip(1).cumsum(1).flip(1)                        # rest[:, k] = sum of xs[:, k:]
    ranks = torch.arange(n, dtype=torch.float64, device=vals.device)
    # share * N when xs[k] reaches 1; non-decreasing over the pixels with importance, inf past them
    at_saturation = torch.where(xs > 0, ranks + rest / xs, torch.full_like(xs, math.inf))
    j = torch.minimum((at_saturation < target[:, None]).sum(1), (npos.long() - 1).clamp_min(0))
    mult = ((target - j.to(torch.float64)) / rest.gather(1, j[:, None])[:, 0]).clamp_min(1.0)
    mult = torch.where(take_all, torch.full_like(mult, math.inf), torch.where(reached, one, mult))
    floor = torch.where(take_all, floor, torch.zeros_like(floor))
    return mult.view(b, 1, 1, 1), floor.view(b, 1, 1, 1)


def lifted_mask(pim_norm: torch.Tensor, mult: torch.Tensor, floor: torch.Tensor, P: torch.Tensor) -> torch.Tensor:
    """The hard mask ``(m PIM' > P) | (f > P)`` of :func:`lift_to_share`'s ``(m, f)``; a value reaching 1
    is always sampled (``P`` reaches 1), and ``m = inf`` takes every pixel with ``PIM' > 0``.

    Example:
        >>> pim = torch.tensor([[[[0.0, 0.1, 0.3, 2.0]]]])
        >>> m, f = lift_to_share(pim, 0.875)
        >>> lifted_mask(pim, m, f, torch.tensor([[0.4, 0.9, 0.9, 0.9]])).tolist()
        [[[[True, True, True, True]]]]
    """
    with torch.autocast(device_type=pim_norm.device.type, enabled=False):
        x = _f32(pim_norm)
        P = _p_like(P, x)
        m, f = mult.to(device=x.device, dtype=x.dtype), floor.to(device=x.device, dtype=x.dtype)
        # m = inf takes every pixel with importance (x * inf would be NaN at x = 0)
        inf = torch.isinf(m)
        scaled = torch.where(inf, (x > 0).to(x.dtype), x * torch.where(inf, torch.ones_like(m), m))
        return (scaled > P) | (scaled >= 1.0) | (f > P) | (f >= 1.0)


def _p_like(P: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    P = P.to(device=x.device, dtype=x.dtype)
    while P.dim() < 4:
        P = P.unsqueeze(0)
    return P


def soft_rejection_sample(pim_norm: torch.Tensor, P: torch.Tensor, alpha: float) -> torch.Tensor:
    """Differentiable rejection sampling ``IM = sigmoid(alpha (PIM' - P))`` (training).

    Args:
        pim_norm: ``(B, 1, H, W)`` normalized importance PIM'.
        P: ``(H, W)`` (or broadcastable to ``pim_norm``) rank pattern, values in ``(0, 1]``.
        alpha: steepness, ``> 0`` (LAS uses 50).

    Returns:
        ``(B, 1, H, W)`` soft mask in ``[0, 1]``, float32 (float64 for float64 input), autocast off.

    Example:
        >>> soft_rejection_sample(torch.tensor([[[[0.5]]]]), torch.tensor([[0.5]]), 50.0).item()
        0.5
    """
    a = check_alpha(alpha)
    with torch.autocast(device_type=pim_norm.device.type, enabled=False):
        x = _f32(pim_norm)
        # torch.sigmoid is saturating-stable: exp never overflows, the result is exactly 0/1 far out
        return torch.sigmoid(a * (x - _p_like(P, x)))


def hard_rejection_sample(pim_norm: torch.Tensor, P: torch.Tensor) -> torch.Tensor:
    """Rejection sampling ``IM = [PIM' > P]`` (inference): one bit per pixel.

    Args:
        pim_norm: ``(B, 1, H, W)`` normalized importance PIM'.
        P: ``(H, W)`` (or broadcastable) rank pattern.

    Returns:
        ``(B, 1, H, W)`` bool mask (not differentiable). Ties (``PIM' == P``) are *not* important.

    Example:
        >>> hard_rejection_sample(torch.tensor([[[[0.2, 0.7]]]]), torch.tensor([[0.5, 0.5]])).tolist()
        [[[[False, True]]]]
    """
    with torch.autocast(device_type=pim_norm.device.type, enabled=False):
        x = _f32(pim_norm)
        return x > _p_like(P, x)


class ImportanceNormalization(nn.Module):
    """:func:`normalize_importance` as a layer at its ``mean`` (validated; changed after construction, or given to
    one call: ``forward(pim, valid, mean=u)``, e.g. a training step at a drawn mean value).

    Example:
        >>> norm = ImportanceNormalization(mean=0.1)
        >>> [round(v, 4) for v in norm(torch.rand(2, 1, 8, 8)).mean(dim=(1, 2, 3)).tolist()]
        [0.1, 0.1]
    """

    def __init__(self, mean: float = 0.1, lower: float = 0.0, delta: float = 1e-7):
        super().__init__()
        self._mean = check_mean(mean)
        self.lower, self.delta = _check_lower_delta(self._mean, lower, delta)

    @property
    def mean(self) -> float:
        return self._mean

    @mean.setter
    def mean(self, value: float) -> None:
        self._mean = self.checked(value)

    def checked(self, mean: float) -> float:
        """``mean`` validated as a mean value of this layer (in ``[0.01, 1]``, above its ``lower``)."""
        u = check_mean(mean)
        _check_lower_delta(u, self.lower, self.delta)
        return u

    def forward(self, pim: torch.Tensor, valid: Optional[torch.Tensor] = None, mean: Optional[float] = None) -> torch.Tensor:
        u = self._mean if mean is None else self.checked(mean)
        return normalize_importance(pim, u, self.lower, self.delta, valid)

    def extra_repr(self) -> str:
        return f"mean={self._mean}, lower={self.lower}, delta={self.delta}"


def delegated(sub: str, name: str, settable: bool = False) -> property:
    """A property that reads (and, when ``settable``, writes) ``self.<sub>.<name>``: a network shows
    the settings of its normalization / sampling layer (e.g. ``net.mean``) without keeping a copy,
    and every change goes through that layer's validation.

    Example:
        >>> class Net(nn.Module):
        ...     mean = delegated("normalization", "mean", settable=True)
        ...     def __init__(self):
        ...         super().__init__()
        ...         self.normalization = ImportanceNormalization(mean=0.1)
        >>> net = Net(); net.mean = 0.2; net.normalization.mean
        0.2
    """
    def get(self):
        return getattr(getattr(self, sub), name)

    def put(self, value) -> None:
        setattr(getattr(self, sub), name, value)

    return property(get, put if settable else None, doc=f"``{sub}.{name}``" + (" (settable, validated)" if settable else ""))


class RejectionSampling(nn.Module):
    """Rejection sampling against a fixed rank pattern ``P`` (stored as a persistent buffer, so a
    checkpoint carries the ``P`` it was trained with).

    ``forward(pim_norm, hard=None)``: ``hard=None`` means soft in training mode, hard in eval mode;
    both return a float32 ``(B, 1, H, W)`` mask (hard: exactly 0/1) so it can multiply an image.

    Example:
        >>> rs = RejectionSampling(torch.full((4, 4), 0.5), alpha=50.0).eval()
        >>> rs(torch.ones(1, 1, 4, 4)).sum().item()
        16.0
    """

    def __init__(self, P: torch.Tensor, alpha: float = 50.0):
        super().__init__()
        P = torch.as_tensor(P, dtype=torch.float32)
        if P.dim() != 2:
            raise InputError(f"P: expected an (n, n) rank pattern, got shape {tuple(P.shape)}")
        if not bool(torch.isfinite(P).all()) or float(P.min()) < 0 or float(P.max()) > 1:
            raise InputError("P: expected finite values in [0, 1] (the plastic rank pattern is in (0, 1])")
        self.register_buffer("P", P.clone())
        self._alpha = check_alpha(alpha)

    @property
    def alpha(self) -> float:
        return self._alpha

    @alpha.setter
    def alpha(self, value: float) -> None:
        self._alpha = check_alpha(value)

    def forward(self, pim_norm: torch.Tensor, hard: Optional[bool] = None) -> torch.Tensor:
        if hard is None:
            hard = not self.training
        P = self.window(pim_norm.shape[-2], pim_norm.shape[-1])
        if hard:
            m = hard_rejection_sample(pim_norm, P)
            return m.to(torch.float64 if pim_norm.dtype == torch.float64 else torch.float32)
        return soft_rejection_sample(pim_norm, P, self._alpha)

    def window(self, h: int, w: int) -> torch.Tensor:
        """``P`` for an ``h x w`` input: ``P`` itself, or its top-left window for a training crop (a
        window of the low-discrepancy rank pattern is itself well spread)."""
        H, W = self.P.shape
        if (h, w) == (H, W):
            return self.P
        if h > H or w > W:
            raise ValueError(f"RejectionSampling: input {h}x{w} is larger than the rank pattern P {H}x{W}")
        return self.P[:h, :w]

    def extra_repr(self) -> str:
        return f"size={tuple(self.P.shape)}, alpha={self._alpha}"


class LiftToShare(nn.Module):
    """:func:`lift_to_share` then :func:`lifted_mask` as a layer: the hard IM ``(B, 1, H, W)`` (bool) that
    samples a share ``mean`` of each image's (valid) pixels, keeping the importance ranking.

    Example:
        >>> lift = LiftToShare()
        >>> pim = torch.tensor([[[[0.0, 0.1, 0.3, 2.0]]]])
        >>> lift(pim, 0.875, torch.tensor([[0.4, 0.9, 0.9, 0.9]])).tolist()
        [[[[True, True, True, True]]]]
    """

    def forward(self, pim_norm: torch.Tensor, mean: torch.Tensor | float, P: torch.Tensor,
                valid: Optional[torch.Tensor] = None) -> torch.Tensor:
        return lifted_mask(pim_norm, *lift_to_share(pim_norm, mean, valid), P)
