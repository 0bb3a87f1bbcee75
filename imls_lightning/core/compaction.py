"""Differentiable compaction and decompaction (the paper's C and D = C^-1 matrices).

Compaction gathers the pixels of a sampling pattern from an FR/PR-Image in raster order into an
``n x n`` C-Image (zero padded past the pattern's ``K`` pixels); decompaction scatters them back.
Both are index gathers/scatters: no dense ``m^2 x n^2`` matrix is ever built, and autograd gives
the exact transposed map for the backward pass.

In the paper's notation (images as row vectors), ``C-Image = PR-Image x C`` with the ``m^2 x n^2``
selection matrix ``C[indices[k], k] = 1``, and ``PR-Image = C-Image x D``. ``C`` is a partial
permutation, so its inverse is its transpose: ``D = C^T`` (the Moore-Penrose inverse when the
C-Image is padded, ``K < n^2``, and ``C`` is not square-invertible).
"""
from __future__ import annotations

import torch
from torch import nn

from imls_lightning.base.errors import InputError

__all__ = ["compact", "decompact", "Compaction", "Decompaction"]


def _check_indices(indices: torch.Tensor, c_size: int) -> int:
    if not isinstance(indices, torch.Tensor) or indices.dtype != torch.long or indices.dim() != 1:
        got = f"{indices.dtype} {tuple(indices.shape)}" if isinstance(indices, torch.Tensor) else type(indices).__name__
        raise ValueError(f"indices: expected a 1D int64 tensor of raster indices, got {got}")
    k = indices.numel()
    if k > c_size * c_size:
        raise InputError(
            f"sampling pattern has {k} pixels, more than the C-Image holds ({c_size}x{c_size}={c_size * c_size}); "
            "raise pattern.c_size or sparsen the pattern"
        )
    return k


def _check_image(x: torch.Tensor, name: str, size: int | None) -> int:
    """Shape check for ``(*, s, s)``; returns ``s``. ``size=None`` accepts any square size."""
    if not isinstance(x, torch.Tensor):
        raise ValueError(f"{name}: expected a torch.Tensor, got {type(x).__name__}")
    s = "m" if size is None else size
    if x.dim() < 2 or x.shape[-1] != x.shape[-2] or (size is not None and x.shape[-1] != size):
        raise ValueError(f"{name}: expected a tensor of shape (B, C, {s}, {s}) (any leading dims), got {tuple(x.shape)}")
    return int(x.shape[-1])


def compact(image: torch.Tensor, indices: torch.Tensor, c_size: int, fr_size: int | None = None) -> torch.Tensor:
    """Gather pattern pixels into the C-Image.

    Args:
        image: ``(B, C, m, m)`` FR- or PR-Image (any leading dims, any dtype).
        indices: ``(K,)`` int64 flat raster indices into ``m*m``, ascending, ``K <= c_size**2``.
        c_size: C-Image side ``n``.
        fr_size: if given, ``image`` must be ``m = fr_size`` wide (a clear error instead of an
            out-of-range gather when an image of the wrong resolution comes in).

    Returns:
        ``(B, C, n, n)``: pixel ``k`` of the C-Image (raster order) is ``image.flat[indices[k]]``;
        pixels ``k >= K`` are 0.

    Example:
        >>> x = torch.arange(16.).view(1, 1, 4, 4)
        >>> compact(x, torch.tensor([0, 2, 8, 10]), 2)[0, 0].tolist()
        [[0.0, 2.0], [8.0, 10.0]]
    """
    m = _check_image(image, "image", fr_size)
    k = _check_indices(indices, c_size)
    # the last index is the largest (ascending); checking it is free for CPU indices
    if k and indices.device.type == "cpu" and int(indices[-1]) >= m * m:
        raise ValueError(f"image: pattern indices reach {int(indices[-1])}, beyond a {m}x{m} image; wrong resolution?")
    lead = image.shape[:-2]
    flat = image.reshape(*lead, m * m)
    # gather, not index_select: on the CPU index_select along the last dimension runs element by element
    # (2.3 ms against 0.08 ms for a 512^2 foveal pattern's 3 channels)
    gathered = flat.gather(-1, indices.to(flat.device).expand(*lead, k))
    if k < c_size * c_size:  # zero padding past the pattern (cat keeps any dtype, bool included)
        gathered = torch.cat([gathered, gathered.new_zeros(*lead, c_size * c_size - k)], dim=-1)
    return gathered.reshape(*lead, c_size, c_size)


def decompact(c_image: torch.Tensor, indices: torch.Tensor, fr_size: int, c_size: int | None = None) -> torch.Tensor:
    """Scatter C-Image pixels back to their pattern positions; everything else is 0.

    Args:
        c_image: ``(B, C, n, n)`` (any leading dims, any dtype); padding pixels are ignored.
        indices: ``(K,)`` as in :func:`compact`.
        fr_size: FR-Image side ``m``.
        c_size: if given, ``c_image`` must be ``n = c_size`` wide.

    Returns:
        ``(B, C, m, m)`` PR-Image.

    Example:
        >>> c = torch.tensor([[[[1., 2.], [3., 4.]]]])
        >>> decompact(c, torch.tensor([0, 2, 8, 10]), 4)[0, 0, 0].tolist()
        [1.0, 0.0, 2.0, 0.0]
    """
    n = _check_image(c_image, "c_image", c_size)
    k = _check_indices(indices, n)
    if k and indices.device.type == "cpu" and int(indices[-1]) >= fr_size * fr_size:
        raise ValueError(f"indices: reach {int(indices[-1])}, beyond a {fr_size}x{fr_size} FR-Image")
    lead = c_image.shape[:-2]
    src = c_image.reshape(*lead, n * n)[..., :k]
    out = src.new_zeros(*lead, fr_size * fr_size)
    out = out.index_copy(-1, indices.to(out.device), src)  # out of place: autograd gathers back
    return out.reshape(*lead, fr_size, fr_size)


class Compaction(nn.Module):
    """:func:`compact` with the pattern's indices stored as a (non-persistent) buffer.

    Example:
        >>> from imls_lightning.core.patterns import downsample_pattern
        >>> layer = Compaction.from_pattern(downsample_pattern(8, 2))
        >>> layer(torch.rand(2, 3, 8, 8)).shape
        torch.Size([2, 3, 4, 4])
    """

    def __init__(self, indices: torch.Tensor, c_size: int, fr_size: int | None = None):
        super().__init__()
        self.register_buffer("indices", torch.as_tensor(indices, dtype=torch.long), persistent=False)
        self.c_size = int(c_size)
        self.fr_size = None if fr_size is None else int(fr_size)
        _check_indices(self.indices, self.c_size)

    @classmethod
    def from_pattern(cls, pattern) -> "Compaction":
        """From a :class:`~imls_lightning.core.patterns.SamplingPattern` (checks the input resolution)."""
        return cls(pattern.indices, pattern.c_size, pattern.fr_size)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return compact(image, self.indices, self.c_size, self.fr_size)

    def extra_repr(self) -> str:
        return f"K={self.indices.numel()}, c_size={self.c_size}, fr_size={self.fr_size}"


class Decompaction(nn.Module):
    """:func:`decompact` with the pattern's indices stored as a (non-persistent) buffer.

    Example:
        >>> from imls_lightning.core.patterns import downsample_pattern
        >>> layer = Decompaction.from_pattern(downsample_pattern(8, 2))
        >>> layer(torch.rand(2, 3, 4, 4)).shape
        torch.Size([2, 3, 8, 8])
    """

    def __init__(self, indices: torch.Tensor, fr_size: int, c_size: int | None = None):
        super().__init__()
        self.register_buffer("indices", torch.as_tensor(indices, dtype=torch.long), persistent=False)
        self.fr_size = int(fr_size)
        self.c_size = None if c_size is None else int(c_size)
        if self.c_size is not None:
            _check_indices(self.indices, self.c_size)

    @classmethod
    def from_pattern(cls, pattern) -> "Decompaction":
        """From a :class:`~imls_lightning.core.patterns.SamplingPattern` (checks the input resolution)."""
        return cls(pattern.indices, pattern.fr_size, pattern.c_size)

    def forward(self, c_image: torch.Tensor) -> torch.Tensor:
        return decompact(c_image, self.indices, self.fr_size, self.c_size)

    def extra_repr(self) -> str:
        return f"K={self.indices.numel()}, fr_size={self.fr_size}, c_size={self.c_size}"
