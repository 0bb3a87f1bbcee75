"""Stand-in sampling patterns shared by the RecNN models' test modules."""
from __future__ import annotations

import torch

from imls_lightning.core.patterns import SamplingPattern


def grid_pattern(n: int, factor: int, offset: int = 0) -> SamplingPattern:
    """Downsampling stand-in: pixel (offset + f i, offset + f j) of each f x f block."""
    m = n * factor
    ii = torch.arange(n)
    idx = ((offset + factor * ii)[:, None] * m + (offset + factor * ii)[None, :]).reshape(-1)
    return SamplingPattern("downsample", m, n, idx)


def random_pattern(m: int, n: int, k: int, seed: int = 0) -> SamplingPattern:
    """Foveal-like stand-in: k random pixels in raster order."""
    g = torch.Generator().manual_seed(seed)
    return SamplingPattern("foveal", m, n, torch.randperm(m * m, generator=g)[:k].sort().values)


# ---- the IMS thresholding as written before IMSMaskHead (frozen references: the head must not change a mask)
def reference_lift_to_share(pim_norm: torch.Tensor, mean, valid: torch.Tensor | None = None):
    """``core.importance.lift_to_share`` as it was solved image by image before it was vectorized."""
    import math

    b = pim_norm.shape[0]
    u = torch.as_tensor(mean, dtype=torch.float64).reshape(-1).cpu()
    u = (u.expand(b) if u.numel() == 1 else u).clamp(0.0, 1.0)
    x = pim_norm.detach().to(torch.float64).clamp_min(0.0)
    if valid is not None:
        v = valid.to(dtype=torch.bool)
        while v.dim() < 4:
            v = v.unsqueeze(0)
        v = v.expand(b, 1, x.shape[2], x.shape[3])
    mult, floor = torch.ones(b, dtype=torch.float64), torch.zeros(b, dtype=torch.float64)
    for i in range(b):
        vals = x[i][v[i]] if valid is not None else x[i].reshape(-1)
        n, target = vals.numel(), float(u[i]) * vals.numel()
        if n == 0 or float(vals.clamp(max=1.0).sum()) >= target:
            continue
        pos = vals[vals > 0]
        if target >= pos.numel():
            mult[i] = math.inf
            floor[i] = min(max((target - pos.numel()) / max(n - pos.numel(), 1), 0.0), 1.0)
            continue
        xs, _ = torch.sort(pos, descending=True)
        rest = xs.flip(0).cumsum(0).flip(0)
        at_saturation = torch.arange(xs.numel(), dtype=torch.float64) + rest / xs
        j = min(int(torch.searchsorted(at_saturation, torch.tensor([target], dtype=torch.float64))), xs.numel() - 1)
        mult[i] = max((target - j) / float(rest[j]), 1.0)
    return mult.view(b, 1, 1, 1), floor.view(b, 1, 1, 1)


def reference_lifted_mask(x: torch.Tensor, m: torch.Tensor, f: torch.Tensor, P: torch.Tensor) -> torch.Tensor:
    scaled = torch.where(torch.isinf(m), (x > 0).to(x.dtype), x * m.to(x.dtype).nan_to_num(posinf=1.0))
    f = f.to(x.dtype)
    return (scaled > P) | (scaled >= 1.0) | (f > P) | (f >= 1.0)


def reference_ims_mask(g: torch.Tensor, P: torch.Tensor, valid: torch.Tensor, target: str, mean=None,
                       trained_mean: float = 0.1, lower: float = 0.0, lift: bool = False) -> torch.Tensor:
    """``IMSTask.output_to_im`` / ``tasks.ims.scaled_pim_im`` as they were before the mask head."""
    g = g.float()
    if mean is None:
        im = g > 0 if target == "im" else ((g + 1.0) * 0.5 > P) | (g >= 1.0)
        return im & valid
    ut = torch.as_tensor(mean, dtype=torch.float32).reshape(-1, 1, 1, 1)
    scale = (ut - lower) / torch.tensor(trained_mean - lower, dtype=torch.float32)
    pim = (g + 1.0) * 0.5
    pim_u = pim * scale if lower == 0.0 else (pim - lower) * scale + lower
    saturated = (g >= 1.0) & (scale >= 1.0)
    im = (pim_u > P) | saturated
    if lift:
        x = torch.where(saturated, pim_u.clamp_min(1.0), pim_u)
        m, f = reference_lift_to_share(x, ut.flatten(), valid)
        above = scale > 1.0
        m = torch.where(above, m, torch.ones_like(m))
        f = torch.where(above, f, torch.zeros_like(f))
        im = im | reference_lifted_mask(x, m, f, P)
    return im & valid
