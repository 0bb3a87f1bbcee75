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
