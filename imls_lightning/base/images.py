"""Pictures: uint8 conversion, error maps and image grids of tensors (PIL), for training logs and the viewers.
They know nothing of the method, so every layer may show them."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from PIL import Image, ImageDraw

from .atomic import atomic_write

_TILE_BG = (24, 24, 24)


def to_uint8(img: torch.Tensor | np.ndarray) -> np.ndarray:
    """``(C, H, W)`` or ``(H, W)`` in [0, 1] (1 or 3 channels) -> ``(H, W, 3)`` uint8."""
    t = torch.as_tensor(img).detach().float().cpu()
    if t.dim() == 2:
        t = t[None]
    if t.shape[0] == 1:
        t = t.expand(3, -1, -1)
    t = torch.nan_to_num(t, nan=0.0).clamp(0, 1)
    return (t[:3].permute(1, 2, 0).numpy() * 255.0 + 0.5).astype(np.uint8)


def error_map(pred: torch.Tensor, target: torch.Tensor, scale: float = 4.0) -> torch.Tensor:
    """``(3, H, W)`` heat map of the absolute error (mean over channels), amplified by ``scale``."""
    e = (pred.float() - target.float()).abs().mean(0).mul(scale).clamp(0, 1)
    # black -> red -> yellow -> white
    r = (e * 3).clamp(0, 1)
    g = (e * 3 - 1).clamp(0, 1)
    b = (e * 3 - 2).clamp(0, 1)
    return torch.stack([r, g, b])


def image_grid(
    rows: Sequence[Sequence[torch.Tensor | np.ndarray | None]],
    col_titles: Sequence[str] | None = None,
    row_titles: Sequence[str] | None = None,
    tile: int = 128,
    pad: int = 4,
) -> Image.Image:
    """Lay out images in a grid, each scaled (nearest neighbour) to ``tile x tile``.

    Args:
        rows: ``rows[r][c]`` is a ``(C, H, W)`` tensor in [0, 1] (or ``(H, W, 3)`` uint8 array),
            or ``None`` for an empty cell.
        col_titles / row_titles: optional labels drawn above columns / left of rows.

    Example:
        >>> g = image_grid([[torch.rand(3, 8, 8), torch.rand(1, 4, 4)]], col_titles=["a", "b"], tile=16)
        >>> g.size
        (44, 40)
    """
    n_rows = len(rows)
    n_cols = max((len(r) for r in rows), default=0)
    top = 16 if col_titles else 0
    left = 56 if row_titles else 0
    w = left + n_cols * (tile + pad) + pad
    h = top + n_rows * (tile + pad) + pad
    canvas = Image.new("RGB", (w, h), _TILE_BG)
    draw = ImageDraw.Draw(canvas)
    for c, title in enumerate(col_titles or []):
        draw.text((left + pad + c * (tile + pad), 2), str(title)[: max(4, tile // 6)], fill=(230, 230, 230))
    for r, row in enumerate(rows):
        if row_titles and r < len(row_titles):
            draw.text((2, top + pad + r * (tile + pad) + tile // 2 - 6), str(row_titles[r])[:9], fill=(230, 230, 230))
        for c, img in enumerate(row):
            if img is None:
                continue
            arr = img if isinstance(img, np.ndarray) and img.dtype == np.uint8 and img.ndim == 3 else to_uint8(img)
            pil = Image.fromarray(arr).resize((tile, tile), Image.NEAREST)
            canvas.paste(pil, (left + pad + c * (tile + pad), top + pad + r * (tile + pad)))
    return canvas


def save_image(img: Image.Image, path: str | Path) -> Path:
    """Save atomically (temp file + rename) and return the path."""
    return atomic_write(path, lambda f: img.save(f, format="PNG"))
