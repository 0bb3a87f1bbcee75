"""Rank patterns: per-pixel orders in which a sampler takes the pixels of an image.

* :func:`blue_noise` - void-and-cluster blue-noise ranks (Ulichney 1993), procedural and seeded:
  thresholded against a modulation surface it makes the foveal pattern of
  :mod:`imls_lightning.core.patterns`.
* :func:`plastic_rank_pattern` - the LAS rank map P (R2 / plastic sequence, rank of first visit).

Both are computed once per size (and seed) and cached in memory, read-only.
"""
from __future__ import annotations

import functools
import math

import numba
import numpy as np
import torch

from imls_lightning.base.validate import check_integer

__all__ = ["blue_noise", "blue_noise_ranks", "plastic_rank_pattern", "PLASTIC_G"]

# --------------------------------------------------------------------------------------------
# blue noise: void-and-cluster (Ulichney 1993) with a compiled, toroidal, incremental energy
# --------------------------------------------------------------------------------------------

_VAC_SIGMA = 1.5  # Ulichney's Gaussian std (pixels)
_VAC_RADIUS = 6  # kernel support 4 sigma: the cut-off tail is < 4e-4 of the peak
_VAC_TILE = 16  # tiles keep per-tile extrema so a step costs O(r^2 + tiles), not O(N)
_VAC_DENSITY = 0.1  # density of the initial binary pattern (Ulichney's suggestion)
_VAC_JITTER = 1e-9  # seeded tie-breaker far below any real energy difference


@numba.njit(cache=True)
def _vac_flip(energy, pattern, p, w, h, kern, r, sign):
    # add (sign=+1) or remove (sign=-1) the wrapped Gaussian of pixel p; toroidal like the tile
    y = p // w
    x = p - y * w
    for dy in range(-r, r + 1):
        row = ((y + dy) % h) * w
        for dx in range(-r, r + 1):
            energy[row + (x + dx) % w] += sign * kern[dy + r, dx + r]
    pattern[p] = 1 if sign > 0 else 0


@numba.njit(cache=True)
def _vac_tile(energy, pattern, w, h, t_size, ntc, t, want, val, idx):
    # want=1: max energy among ones (tightest cluster); want=0: min energy among zeros (largest void)
    ty = t // ntc
    tx = t - ty * ntc
    y1 = min((ty + 1) * t_size, h)
    x1 = min((tx + 1) * t_size, w)
    best = -np.inf if want == 1 else np.inf
    bi = -1
    for y in range(ty * t_size, y1):
        for x in range(tx * t_size, x1):
            p = y * w + x
            if pattern[p] == want:
                e = energy[p]
                if (want == 1 and e > best) or (want == 0 and e < best):
                    best = e
                    bi = p
    val[t] = best
    idx[t] = bi


@numba.njit(cache=True)
def _vac_row(val, idx, ntc, ty, want, rval, ridx):
    # best of one row of tiles: a two-level max/min so a global query costs O(rows), not O(tiles)
    best = -np.inf if want == 1 else np.inf
    bi = -1
    for t in range(ty * ntc, (ty + 1) * ntc):
        if idx[t] >= 0 and ((want == 1 and val[t] > best) or (want == 0 and val[t] < best)):
            best = val[t]
            bi = idx[t]
    rval[ty] = best
    ridx[ty] = bi


@numba.njit(cache=True)
def _vac_best(rval, ridx, want):
    best = -np.inf if want == 1 else np.inf
    bi = -1
    for ty in range(rval.shape[0]):
        if ridx[ty] >= 0 and ((want == 1 and rval[ty] > best) or (want == 0 and rval[ty] < best)):
            best = rval[ty]
            bi = ridx[ty]
    return bi


@numba.njit(cache=True)
def _vac_distinct(c, r, size, t_size, n_tiles, out):
    # distinct tile coordinates covered by [c - r, c + r] on a ring of `size` pixels
    cnt = 0
    for d in range(-r, r + 1):
        t = ((c + d) % size) // t_size
        seen = False
        for j in range(cnt):
            if out[j] == t:
                seen = True
                break
        if not seen:
            out[cnt] = t
            cnt += 1
    return cnt


@numba.njit(cache=True)
def _vac_refresh(energy, pattern, p, w, h, r, t_size, ntr, ntc, rows, cols, want, val, idx, rval, ridx):
    # recompute the tiles the flipped pixel's kernel window touched, then their tile rows
    y = p // w
    x = p - y * w
    nr = _vac_distinct(y, r, h, t_size, ntr, rows)
    nc = _vac_distinct(x, r, w, t_size, ntc, cols)
    for i in range(nr):
        for j in range(nc):
            _vac_tile(energy, pattern, w, h, t_size, ntc, rows[i] * ntc + cols[j], want, val, idx)
        _vac_row(val, idx, ntc, rows[i], want, rval, ridx)


@numba.njit(cache=True)
def _vac_init_stats(energy, pattern, w, h, t_size, ntr, ntc, want, val, idx, rval, ridx):
    for t in range(ntr * ntc):
        _vac_tile(energy, pattern, w, h, t_size, ntc, t, want, val, idx)
    for ty in range(ntr):
        _vac_row(val, idx, ntc, ty, want, rval, ridx)


@numba.njit(cache=True)
def _vac_ranks(h, w, initial, jitter, kern, r, t_size):
    n_pix = h * w
    ntr = (h + t_size - 1) // t_size
    ntc = (w + t_size - 1) // t_size
    nt = ntr * ntc
    rows = np.empty(2 * r + 1, np.int64)
    cols = np.empty(2 * r + 1, np.int64)
    v1 = np.empty(nt)
    i1 = np.empty(nt, np.int64)
    v0 = np.empty(nt)
    i0 = np.empty(nt, np.int64)
    rv1 = np.empty(ntr)
    ri1 = np.empty(ntr, np.int64)
    rv0 = np.empty(ntr)
    ri0 = np.empty(ntr, np.int64)

    energy = jitter.copy()
    pattern = np.zeros(n_pix, np.uint8)
    n_ones = 0
    for p in range(n_pix):
        if initial[p]:
            _vac_flip(energy, pattern, p, w, h, kern, r, 1.0)
            n_ones += 1

    # 1. relax the initial pattern: move the tightest cluster into the largest void until stable
    if 0 < n_ones < n_pix:
        _vac_init_stats(energy, pattern, w, h, t_size, ntr, ntc, 1, v1, i1, rv1, ri1)
        _vac_init_stats(energy, pattern, w, h, t_size, ntr, ntc, 0, v0, i0, rv0, ri0)
        for _ in range(4 * n_ones + 64):
            c = _vac_best(rv1, ri1, 1)
            _vac_flip(energy, pattern, c, w, h, kern, r, -1.0)
            _vac_refresh(energy, pattern, c, w, h, r, t_size, ntr, ntc, rows, cols, 1, v1, i1, rv1, ri1)
            _vac_refresh(energy, pattern, c, w, h, r, t_size, ntr, ntc, rows, cols, 0, v0, i0, rv0, ri0)
            v = _vac_best(rv0, ri0, 0)
            _vac_flip(energy, pattern, v, w, h, kern, r, 1.0)
            _vac_refresh(energy, pattern, v, w, h, r, t_size, ntr, ntc, rows, cols, 1, v1, i1, rv1, ri1)
            _vac_refresh(energy, pattern, v, w, h, r, t_size, ntr, ntc, rows, cols, 0, v0, i0, rv0, ri0)
            if v == c:
                break
    proto_pattern = pattern.copy()
    proto_energy = energy.copy()
    rank = np.empty(n_pix, np.int64)

    # 2. ranks below the prototype: remove tightest clusters one by one
    _vac_init_stats(energy, pattern, w, h, t_size, ntr, ntc, 1, v1, i1, rv1, ri1)
    for k in range(n_ones - 1, -1, -1):
        c = _vac_best(rv1, ri1, 1)
        rank[c] = k
        _vac_flip(energy, pattern, c, w, h, kern, r, -1.0)
        _vac_refresh(energy, pattern, c, w, h, r, t_size, ntr, ntc, rows, cols, 1, v1, i1, rv1, ri1)

    # 3. ranks above: fill the largest void one by one. Past half density Ulichney switches to
    # "tightest cluster of zeros"; with a linear filter that is argmax(sum(kernel) - E) over the
    # zeros = argmin E over the zeros, i.e. the same step, so one loop covers both phases.
    pattern = proto_pattern
    energy = proto_energy
    _vac_init_stats(energy, pattern, w, h, t_size, ntr, ntc, 0, v0, i0, rv0, ri0)
    for k in range(n_ones, n_pix):
        v = _vac_best(rv0, ri0, 0)
        rank[v] = k
        _vac_flip(energy, pattern, v, w, h, kern, r, 1.0)
        _vac_refresh(energy, pattern, v, w, h, r, t_size, ntr, ntc, rows, cols, 0, v0, i0, rv0, ri0)
    return rank


@functools.lru_cache(maxsize=16)
def blue_noise_ranks(h: int, w: int, seed: int) -> np.ndarray:
    """The integer ranks behind :func:`blue_noise`: ``(h, w)`` int64, each of ``0 .. h*w-1`` once.

    Cached per ``(h, w, seed)`` and read-only (callers must not, and cannot, write into it); the
    arguments are not checked (:func:`blue_noise` checks them).
    """
    rng = np.random.default_rng(np.random.SeedSequence([seed, h, w]))
    n_pix = h * w
    n_init = min(n_pix, max(1, int(round(_VAC_DENSITY * n_pix))))
    initial = np.zeros(n_pix, np.uint8)
    initial[rng.choice(n_pix, size=n_init, replace=False)] = 1
    jitter = rng.random(n_pix) * _VAC_JITTER
    d = np.arange(-_VAC_RADIUS, _VAC_RADIUS + 1, dtype=np.float64)
    kern = np.exp(-(d[:, None] ** 2 + d[None, :] ** 2) / (2.0 * _VAC_SIGMA**2))
    rank = _vac_ranks(h, w, initial, jitter, kern, _VAC_RADIUS, _VAC_TILE)
    rank = rank.reshape(h, w)
    rank.setflags(write=False)
    return rank


def blue_noise(size: int | tuple[int, int], seed: int = 0) -> torch.Tensor:
    """Blue-noise threshold map by void-and-cluster (Ulichney 1993), procedural and deterministic.

    Every pixel gets a distinct rank ``0 .. N-1`` (``N = H*W``); ``map < t`` keeps
    ``ceil(t*N)`` pixels that are evenly spread at every density, with little low-frequency
    energy. The Gaussian energy (std 1.5 px, support 13x13) wraps around the borders (toroidal),
    so the tile repeats seamlessly. It is updated incrementally in compiled code: each step costs
    O(kernel + tiles) instead of a full O(N log N) FFT filtering, and a 512^2 map takes about a
    second. Results are cached in memory per ``(size, seed)``.

    Args:
        size: ``n`` for ``n x n`` or ``(H, W)``.
        seed: seed of the initial random pattern (and of a 1e-9 tie-breaking jitter).

    Returns:
        ``(H, W)`` float64 ranks normalized to ``[0, 1)``: ``rank / N``, each value exactly once.

    Example:
        >>> bn = blue_noise(16, seed=3)
        >>> bn.shape, float(bn.min()), bool((bn < 0.25).sum() == 64)
        (torch.Size([16, 16]), 0.0, True)
    """
    h, w = (size, size) if isinstance(size, (int, np.integer)) else tuple(size)
    h = check_integer(h, "blue_noise size", 1, strict=True)
    w = check_integer(w, "blue_noise size", 1, strict=True)
    seed = check_integer(seed, "pattern.seed", 0, strict=True)
    ranks = blue_noise_ranks(h, w, seed)
    return torch.from_numpy(ranks.astype(np.float64) / float(h * w))


# --------------------------------------------------------------------------------------------
# plastic (R2) rank pattern P of LAS
# --------------------------------------------------------------------------------------------


def _plastic_constant() -> float:
    # real root of x^3 = x + 1 by Newton's method, as LAS computes it (1.32471795724474...)
    x = 1.0
    for _ in range(20):
        x = x - (x**3 - x - 1.0) / (3.0 * x**2 - 1.0)
    return x


PLASTIC_G = _plastic_constant()


@functools.lru_cache(maxsize=8)
def _plastic_ranks(h: int, w: int) -> np.ndarray:
    a1 = 1.0 / PLASTIC_G
    a2 = math.pow(1.0 / PLASTIC_G, 2)
    n_pix = h * w
    rank = np.zeros(n_pix, np.int64)
    filled = 0
    start = 1  # LAS's sample(i) uses (i + 1): the first point is k = 1
    chunk = max(4096, 2 * n_pix)  # the sequence covers all pixels after ~2 N points
    while filled < n_pix:
        k = np.arange(start, start + chunk, dtype=np.float64)
        x = np.mod(0.5 + a1 * k, 1.0)
        y = np.mod(0.5 + a2 * k, 1.0)
        flat = np.floor(h * y).astype(np.int64) * w + np.floor(w * x).astype(np.int64)
        pix, first = np.unique(flat, return_index=True)  # first visit of each pixel in this chunk
        new = rank[pix] == 0
        pix = pix[new][np.argsort(first[new], kind="stable")]
        rank[pix] = filled + 1 + np.arange(pix.size)
        filled += pix.size
        start += chunk
    rank = rank.reshape(h, w)
    rank.setflags(write=False)
    return rank


def plastic_rank_pattern(size: int | tuple[int, int]) -> torch.Tensor:
    """The LAS rank pattern P: R2 (plastic) sequence, rank of first visit.

    Point ``k = 1, 2, ...`` of the sequence is ``(x, y) = frac(0.5 + k * (1/g, 1/g^2))`` with the
    plastic constant ``g`` (real root of ``x^3 = x + 1``, ``1.3247179572447...``; DESIGN's
    ``1.32471795724`` is this constant to 11 decimals, LAS solves for it in double precision, as we
    do). It falls on pixel ``(col, row) = (floor(x * W), floor(y * H))``; ``P = rank of the first
    visit / (W * H)``. The sequence continues until every pixel was visited (about ``2 W H`` points).

    Checked against LAS's public code (shamanDevel/AdaptiveSampling, ``network/sampling/plastic.py``):
    ``alpha_j = (1/g)^(j+1)`` with g from Newton's method; the first point uses index 1
    (``sample(i)`` evaluates ``(i + 1) * alpha``); ranks start at 1, so ``P`` is in ``(0, 1]``.
    LAS's ``fill_image((W, H))`` indexes its array as ``[floor(W x), floor(H y)]``, i.e. the first
    sequence component runs along array axis 0 (rows when the map is read as an image); here, as
    DESIGN states, ``x`` runs along the columns, so for square sizes ``P`` equals the transpose
    of LAS's stored map. Both are the same low-discrepancy order; only the orientation differs.

    Vectorized in chunks with numpy (a 512^2 map takes ~0.1 s) and cached per size.

    Args:
        size: ``n`` for ``n x n`` or ``(H, W)``.

    Returns:
        ``(H, W)`` float32 in ``(0, 1]``, each value ``k / (W*H)``, ``k = 1..W*H``, exactly once.

    Example:
        >>> p = plastic_rank_pattern(4)
        >>> sorted((p * 16).round().int().flatten().tolist()) == list(range(1, 17))
        True
    """
    h, w = (size, size) if isinstance(size, (int, np.integer)) else tuple(size)
    h = check_integer(h, "plastic pattern size", 1, strict=True)
    w = check_integer(w, "plastic pattern size", 1, strict=True)
    ranks = _plastic_ranks(h, w)
    return torch.from_numpy((ranks.astype(np.float64) / float(h * w)).astype(np.float32))
