"""A PNG contact sheet of a view/image cache: thumbnails of a sample of views with their row index
and split, to check at a glance what a cache holds (framing, transfer function, trajectory).

Example:
    >>> png = write_contact_sheet("cache/tiny-0123456789ab", num=24)    # doctest: +SKIP
    >>> png.name
    'contact_sheet.png'
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from imls_lightning.base.atomic import atomic_write
from imls_lightning.base.errors import InputError


def pick_views(splits: dict[str, np.ndarray], num: int, seed: int = 0) -> list[tuple[int, str]]:
    """Choose up to ``num`` rows: about half training, a quarter validation, a quarter test (the test
    rows evenly spaced along the trajectory, in path order). Returns ``[(row, split), ...]``."""
    if int(num) < 1:
        raise InputError(f"contact_sheet_views={num}: expected an integer >= 1")
    rng = np.random.default_rng(seed)
    sizes = {k: len(v) for k, v in splits.items()}
    want = {"test": num // 4, "val": num // 4}
    want = {k: min(v, sizes.get(k, 0)) for k, v in want.items()}
    want["train"] = min(num - want["test"] - want["val"], sizes.get("train", 0))
    left = num - sum(want.values())  # a split too small: give its share to the others
    for k in ("test", "val", "train"):
        extra = min(left, sizes.get(k, 0) - want[k])
        want[k] += extra
        left -= extra
    out: list[tuple[int, str]] = []
    for k in ("train", "val", "test"):
        idx = np.asarray(splits.get(k, []), np.int64)
        if want[k] == 0:
            continue
        if k == "test":
            sel = idx[np.linspace(0, len(idx) - 1, want[k]).round().astype(int)]
        else:
            sel = np.sort(rng.choice(idx, size=want[k], replace=False))
        out += [(int(i), k) for i in sel]
    return out


def write_contact_sheet(cache, out: str | Path | None = None, num: int = 24, thumb: int | None = None,
                        columns: int = 8, seed: int = 0) -> Path:
    """Write a contact sheet PNG of a cache.

    Args:
        cache: a cache directory or an open :class:`~data_gen.cache.ViewImageCache`.
        out: PNG path; default ``<cache>/contact_sheet.png``.
        num: number of thumbnails.
        thumb: thumbnail side in pixels; default: the image size, clamped to [96, 160].
        columns: thumbnails per row.
        seed: which training/validation views are picked.

    Returns:
        The PNG path.
    """
    from PIL import Image, ImageDraw

    from .cache import ViewImageCache

    c = cache if isinstance(cache, ViewImageCache) else ViewImageCache.open(cache, require_complete=False)
    picks = [(i, s) for i, s in pick_views(c.splits, num, seed) if c.done[i]]
    if not picks:
        raise InputError(f"cache {c.path}: no rendered views to show")
    m = c.resolution
    t = int(thumb) if thumb else int(np.clip(m, 96, 160))
    label_h = 14
    cols = max(1, min(int(columns), len(picks)))
    rows = (len(picks) + cols - 1) // cols
    sheet = Image.new("RGB", (cols * t, rows * (t + label_h)), (40, 40, 40))
    draw = ImageDraw.Draw(sheet)
    colours = {"train": (200, 200, 200), "val": (120, 200, 255), "test": (255, 190, 90)}
    for k, (i, split) in enumerate(picks):
        r, col = divmod(k, cols)
        img = Image.fromarray(np.asarray(c.images[i]))
        # nearest keeps tiny CI images crisp; downscaling large ones is smoothed
        img = img.resize((t, t), Image.NEAREST if t >= m else Image.BILINEAR)
        x, y = col * t, r * (t + label_h)
        sheet.paste(img, (x, y + label_h))
        draw.text((x + 3, y + 1), f"#{i} {split}", fill=colours.get(split, (255, 255, 255)))
    path = Path(out) if out else c.path / "contact_sheet.png"
    try:
        atomic_write(path, lambda f: sheet.save(f, format="PNG"))
    except OSError as err:
        raise InputError(f"contact_sheet={out}: cannot write {path} ({err.strerror or err})") from None
    return path


__all__ = ["write_contact_sheet", "pick_views"]
