"""Selective rendering: ray-cast only the given pixels of a view, with any renderer.

Both renderers implement ``render_pixels(view, resolution, pixels) -> (K, 3) uint8``:

* :class:`~data_gen.render_numba.NumbaRenderer` casts exactly the requested rays (its cost is linear
  in their number, and its colours equal its full frame bit for bit);
* :class:`~data_gen.render_vtk.VTKRenderer` renders the frame with opaque geometry in front of the
  volume over every *other* pixel whose ray would reach the volume (one quad per horizontal run of
  such pixels, covering exactly their centres); with the fixed-point mapper's intersecting-geometry
  mixing on, those rays end before their first sample, so only the requested rays (and background
  rays, which cost nothing) are cast. Its colours equal its full frame (read from the mapper's
  ray-cast image), but it keeps a fixed cost (geometry, depth-buffer capture, one ray set-up per
  pixel): on ``ct_head`` at 512^2, 10% of the pixels cost 33-42% of a frame.

Measured (``scripts/bench_selective.py``, ct_head, 2 cores): the numba route costs 13-17% of its
full frame for 10% of the pixels and 53-58% for 50% (random pixels; pixels clustered on image
detail cost more per ray: 16% and 71-75%), an empty set ~25 us. It is the default selective route.

Rays that cannot reach the volume's box are never marched by either route.

:func:`render_selected` / :class:`SelectiveRenderer` are the one entry point the pipeline uses; they
also accept an ``(m, m)`` boolean mask instead of indices and can scatter the colours into a frame.

Example:
    >>> sel = SelectiveRenderer(renderer)                                     # doctest: +SKIP
    >>> colours = sel(view, 512, important_indices)                           # (K, 3) uint8
    >>> sel.seconds                                                           # time of the cast
"""
from __future__ import annotations

import time

import numpy as np

from .errors import InputError


def validate_pixels(pixels, resolution: int, *, name: str = "pixels") -> np.ndarray:
    """Check flat raster pixel indices of an ``m x m`` image and return them as int64 ``(K,)``.

    Any integer dtype is accepted; the order is kept and duplicates are allowed.

    Raises:
        InputError: not one-dimensional, not integers (floats and booleans are refused: use
            :func:`mask_to_pixels` for masks), or outside ``[0, m*m)``.

    Example:
        >>> validate_pixels(np.array([0, 5, 15], np.int32), 4).dtype
        dtype('int64')
    """
    m = int(resolution)
    a = np.asarray(pixels)
    if a.ndim != 1:
        raise InputError(f"{name}: expected a 1-D array of flat pixel indices (row * {m} + col), got shape {a.shape}")
    if a.size == 0:
        return np.zeros(0, np.int64)
    if a.dtype == bool or not np.issubdtype(a.dtype, np.integer):
        raise InputError(f"{name}: expected integer flat pixel indices, got dtype {a.dtype}")
    lo, hi = int(a.min()), int(a.max())
    if lo < 0 or hi >= m * m:
        raise InputError(f"{name}: indices must lie in [0, {m * m}) for a {m}x{m} image, got min {lo} max {hi}")
    return np.ascontiguousarray(a, dtype=np.int64)


def mask_to_pixels(mask) -> np.ndarray:
    """``(m, m)`` boolean mask -> ascending flat raster indices ``(K,)`` int64."""
    mk = np.asarray(mask)
    if mk.ndim != 2 or mk.shape[0] != mk.shape[1]:
        raise InputError(f"mask: expected a square (m, m) mask, got shape {mk.shape}")
    if mk.dtype != bool:
        raise InputError(f"mask: expected a boolean mask, got dtype {mk.dtype}")
    return np.flatnonzero(mk.reshape(-1)).astype(np.int64)


def render_selected(renderer, view, resolution: int, pixels, *, out: np.ndarray | None = None) -> np.ndarray:
    """Ray-cast only ``pixels`` of ``view`` with ``renderer`` (any renderer with ``render_pixels``).

    Args:
        renderer: a :class:`~data_gen.render_numba.NumbaRenderer` or
            :class:`~data_gen.render_vtk.VTKRenderer` (anything with ``render_pixels``).
        view: 9 floats.
        resolution: image side ``m``.
        pixels: flat raster indices ``(K,)`` (any integer dtype) or an ``(m, m)`` boolean mask.
        out: optional ``(m, m, 3)`` uint8 frame; the colours are also written into it.

    Returns:
        ``(K, 3)`` uint8 colours in the order of ``pixels`` (ascending raster order for a mask).
    """
    m = int(resolution)
    p = np.asarray(pixels)
    if p.ndim == 2:
        if p.shape != (m, m):
            raise InputError(f"pixels: a mask must have shape ({m}, {m}), got {p.shape}")
        p = mask_to_pixels(p)
    colours = renderer.render_pixels(view, m, p)
    if out is not None:
        if out.shape != (m, m, 3) or out.dtype != np.uint8:
            raise InputError(f"out: expected a ({m}, {m}, 3) uint8 frame, got {out.shape} {out.dtype}")
        out.reshape(-1, 3)[validate_pixels(p, m)] = colours
    return colours


class SelectiveRenderer:
    """Callable wrapper: ``sel(view, m, pixels) -> (K, 3) uint8`` plus the time it took.

    Args:
        renderer: any renderer with ``render_pixels`` (see :func:`render_selected`).

    Attributes:
        seconds: wall time of the last call (validation, casting and gathering).
        render_seconds: the renderer's own ``last_render_seconds`` of the last call.
    """

    def __init__(self, renderer):
        if not hasattr(renderer, "render_pixels"):
            raise InputError(f"renderer {type(renderer).__name__}: has no render_pixels(view, resolution, pixels)")
        self.renderer = renderer
        self.seconds = 0.0
        self.render_seconds = 0.0

    def __call__(self, view, resolution: int, pixels, *, out: np.ndarray | None = None) -> np.ndarray:
        t0 = time.perf_counter()
        colours = render_selected(self.renderer, view, resolution, pixels, out=out)
        self.seconds = time.perf_counter() - t0
        self.render_seconds = float(getattr(self.renderer, "last_render_seconds", self.seconds))
        return colours


__all__ = ["validate_pixels", "mask_to_pixels", "render_selected", "SelectiveRenderer"]
