"""Deterministic procedural volumes, so that the main job needs no data file.

Generators of distinct character (:data:`PROCEDURAL_GENERATORS`):

* ``tiny`` (32^3): three Gaussian blobs and a tilted torus; cheap, for CI, with clear structure.
* ``marschner_lobb`` (64^3): the Marschner-Lobb test signal (fM = 6, alpha = 0.25) on [-1, 1]^3;
  seed 0 is the classic signal, other seeds rotate it randomly about the centre.
* ``mixing_layer`` (96^3): a Rayleigh-Taylor-like mixing layer filling the box: heavy fluid
  (density 3) over light fluid (density 1), the interface displaced by multi-scale random 2D
  Fourier modes, and 3D turbulent modes (amplitude ~ k^-0.8) inside the mixing zone.
* ``flame`` (64 x 64 x 96): a compact candle-like plume along +z with turbulent wrinkles that
  grow with height, a bright reaction front around a hot core, and empty space around it.

Four more of the paper's regime (512^3 by default, detail at the scale of a voxel, so that at 512^2
a bilinear upsampling of a 256^2 render loses clearly; stream them with ``scene.volume.stream_to``),
with widths of thin structures given in voxels of the volume generated:

* ``rayleigh_taylor``: heavy over light fluid, a sharp interface folded into bubbles and spikes down
  to ~13 voxels.
* ``flame_sheets``: a flame whose two reaction sheets are ~2.5 voxels thick, folded at several scales.
* ``seed_shell``: a CT-like seed (beechnut-like): pitted, wrinkled shell, septa, fibres, porous tissue.
* ``rt_plumes``: a Rayleigh-Taylor layer late in its growth, for a whole-box framing: capped spikes of heavy fluid
  and round-headed bubbles of light fluid, down to ~5 voxels thick, leaning with a smooth flow.

Their detail is coherent: folds at several scales of one surface, never a random-phase band finer than
the folds, which no network could infer from a half-resolution render.

Every generator is a function ``fn(dims_xyz, seed, z0, z1) -> float32 (z1 - z0, Y, X)`` that can
evaluate any z-slab of the volume on its own: its random parameters come from ``seed`` alone, so a
slab is bit-identical to the same slab of the whole volume. That is what lets
:func:`write_procedural_raw` stream paper-scale volumes (e.g. 1024^3) to disk slab by slab.

Field coordinates follow the normalized space of :class:`~imls_lightning.render.volume.Volume` with unit
spacing: voxels are centred, the longest axis spans [-1, 1], the others keep their aspect.

Example:
    >>> v = make_procedural("tiny", seed=3)
    >>> v.dims, v.data.dtype.name, v.source
    ((32, 32, 32), 'float32', 'procedural:tiny?size=32,32,32&seed=3')
"""
from __future__ import annotations

import concurrent.futures
import multiprocessing
import os
import re
import sys
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from imls_lightning.base.atomic import atomic_write
from imls_lightning.base.errors import InputError
from imls_lightning.base.orphans import exit_when_orphaned
from imls_lightning.render.volume import Volume

F32 = np.float32


# ---------------------------------------------------------------------------------------------
# building blocks
# ---------------------------------------------------------------------------------------------
def grid_axes(dims: tuple[int, int, int], z0: int = 0, z1: int | None = None):
    """1D voxel-centre coordinates ``x (X,), y (Y,), z (z1-z0,)`` and half extents ``(ex, ey, ez)``.

    Unit spacing scaled so the longest axis spans [-1, 1].

    Example:
        >>> x, y, z, e = grid_axes((5, 3, 3))
        >>> x.tolist(), e.tolist()
        ([-1.0, -0.5, 0.0, 0.5, 1.0], [1.0, 0.5, 0.5])
    """
    X, Y, Z = (int(d) for d in dims)
    z1 = Z if z1 is None else z1
    h = 2.0 / (max(X, Y, Z) - 1)
    x = ((np.arange(X) - (X - 1) / 2.0) * h).astype(F32)
    y = ((np.arange(Y) - (Y - 1) / 2.0) * h).astype(F32)
    z = ((np.arange(z0, z1) - (Z - 1) / 2.0) * h).astype(F32)
    return x, y, z, np.array([(X - 1) * h / 2, (Y - 1) * h / 2, (Z - 1) * h / 2])


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random 3x3 rotation matrix (QR of a Gaussian matrix, det +1)."""
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def fourier_modes(rng: np.random.Generator, n: int, kmin: float, kmax: float, slope: float, ndim: int = 3):
    """``n`` random plane waves: wave vectors ``(n, ndim)`` with log-uniform magnitudes in
    ``[kmin, kmax]`` and random directions, amplitudes ``~ |k|^-slope`` scaled so that the sum has
    unit RMS, and random phases ``(n,)``."""
    k = np.exp(rng.uniform(np.log(kmin), np.log(kmax), n))
    d = rng.standard_normal((n, ndim))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    amp = k ** (-slope)
    amp /= np.sqrt(np.sum(amp**2) / 2.0)  # a sum of cosines with random phases has RMS sqrt(sum a^2 / 2)
    phase = rng.uniform(0.0, 2 * np.pi, n)
    return (d * k[:, None]).astype(F32), amp.astype(F32), phase.astype(F32)


def eval_modes(modes, x: np.ndarray, y: np.ndarray, z: np.ndarray | None = None) -> np.ndarray:
    """Sum of plane waves on the grid ``(Z, Y, X)`` (or ``(Y, X)`` for 2D modes), float32.

    Vectorized per mode over the whole slab; adding the three 1D products in a fixed order keeps a
    slab bit-identical to the same rows of the whole volume.
    """
    kv, amp, phase = modes
    shape = (len(y), len(x)) if z is None else (len(z), len(y), len(x))
    out = np.zeros(shape, F32)
    tmp = np.empty(shape, F32)
    for i in range(len(amp)):
        if z is None:
            np.add((kv[i, 1] * y + phase[i])[:, None], (kv[i, 0] * x)[None, :], out=tmp)
        else:
            np.add((kv[i, 2] * z + phase[i])[:, None, None], (kv[i, 1] * y)[None, :, None], out=tmp)
            tmp += (kv[i, 0] * x)[None, None, :]
        np.cos(tmp, out=tmp)
        tmp *= amp[i]
        out += tmp
    return out


def _sigmoid(t: np.ndarray) -> np.ndarray:
    # tanh form: no overflow warnings for large |t|
    return (F32(0.5) * (F32(1.0) + np.tanh(F32(0.5) * t))).astype(F32, copy=False)


def _rng(name: str, seed: int) -> np.random.Generator:
    # a per-generator salt so that two generators with the same seed do not share random numbers
    return np.random.default_rng([zlib.crc32(name.encode()), int(seed)])


# ---------------------------------------------------------------------------------------------
# generators: fn(dims_xyz, seed, z0, z1) -> float32 (z1 - z0, Y, X)
# ---------------------------------------------------------------------------------------------
def tiny(dims, seed: int, z0: int, z1: int) -> np.ndarray:
    """Three Gaussian blobs + a randomly tilted torus; values about 0..1.5."""
    rng = _rng("tiny", seed)
    x, y, z, e = grid_axes(dims, z0, z1)
    Z, Y, X = z[:, None, None], y[None, :, None], x[None, None, :]
    out = np.zeros((len(z), len(y), len(x)), F32)
    for _ in range(3):
        c = rng.uniform(-0.45, 0.45, 3) * e
        s = rng.uniform(0.12, 0.25)
        w = rng.uniform(0.6, 1.0)
        out += F32(w) * np.exp(-((X - c[0]) ** 2 + (Y - c[1]) ** 2 + (Z - c[2]) ** 2) / F32(2 * s * s))
    R = random_rotation(rng).astype(F32)
    px = R[0, 0] * X + R[0, 1] * Y + R[0, 2] * Z
    py = R[1, 0] * X + R[1, 1] * Y + R[1, 2] * Z
    pz = R[2, 0] * X + R[2, 1] * Y + R[2, 2] * Z
    ring = (np.sqrt(px * px + py * py) - F32(0.6) * F32(e.min())) ** 2 + pz * pz
    out += F32(0.8) * np.exp(-ring / F32(2 * 0.08**2))
    return out.astype(F32, copy=False)


def marschner_lobb(dims, seed: int, z0: int, z1: int, f_m: float = 6.0, alpha: float = 0.25) -> np.ndarray:
    """Marschner & Lobb (1994): ``(1 - sin(pi z / 2) + alpha (1 + rho_r(r))) / (2 (1 + alpha))``,
    ``rho_r(r) = cos(2 pi f_M cos(pi r / 2))``, ``r = sqrt(x^2 + y^2)``; values in [0, 1].

    Seed 0 is the classic signal; other seeds evaluate it in a randomly rotated frame.
    """
    x, y, z, _ = grid_axes(dims, z0, z1)
    Z, Y, X = z[:, None, None], y[None, :, None], x[None, None, :]
    if int(seed) != 0:
        R = random_rotation(_rng("marschner_lobb", seed)).astype(F32)
        X, Y, Z = (R[0, 0] * X + R[0, 1] * Y + R[0, 2] * Z, R[1, 0] * X + R[1, 1] * Y + R[1, 2] * Z,
                   R[2, 0] * X + R[2, 1] * Y + R[2, 2] * Z)
    r = np.sqrt(X * X + Y * Y)
    rho_r = np.cos(F32(2 * np.pi * f_m) * np.cos(F32(np.pi / 2) * r))
    out = (F32(1.0) - np.sin(F32(np.pi / 2) * Z) + F32(alpha) * (F32(1.0) + rho_r)) / F32(2 * (1 + alpha))
    return np.broadcast_to(out, (len(z), len(y), len(x))).astype(F32)


def mixing_layer(dims, seed: int, z0: int, z1: int) -> np.ndarray:
    """Rayleigh-Taylor-like density: heavy (3) on top (+z) of light (1), a wide turbulent mixing zone.

    The interface height ``h(x, y)`` is a sum of 24 random 2D modes (RMS 0.2, amplitude ~ 1/k);
    inside a Gaussian envelope around it (half width 0.5) 40 random 3D modes (k = 2 pi .. 14 pi,
    amplitude ~ k^-0.8, stretched 2x along z) displace the level set into bubbles and spikes, and 16 finer modes add the
    texture of partially mixed fluid.
    """
    rng = _rng("mixing_layer", seed)
    interface = fourier_modes(rng, 24, 1.5 * np.pi, 12 * np.pi, 1.0, ndim=2)
    turbulence = fourier_modes(rng, 40, 2 * np.pi, 14 * np.pi, 0.8)
    turbulence[0][:, 2] *= 0.5  # stretched along gravity: rising bubbles and falling spikes
    fine = fourier_modes(rng, 16, 10 * np.pi, 18 * np.pi, 0.5)
    x, y, z, _ = grid_axes(dims, z0, z1)
    h = F32(0.2) * eval_modes(interface, x, y)[None]  # (1, Y, X)
    zz = z[:, None, None]
    env = np.exp(-(((zz - F32(0.5) * h) / F32(0.5)) ** 2)).astype(F32)
    phi = zz - h - F32(0.4) * env * eval_modes(turbulence, x, y, z)
    rho = F32(1.0) + F32(2.0) * _sigmoid(phi / F32(0.05))
    rho += F32(0.1) * env * eval_modes(fine, x, y, z)
    return rho.astype(F32, copy=False)


def flame(dims, seed: int, z0: int, z1: int) -> np.ndarray:
    """A compact flame along +z: a slim plume (hot core + bright reaction front) from a base near
    the bottom to a flickering tip, wrinkled by 32 random 3D modes whose amplitude grows with
    height; ~0 everywhere around it."""
    rng = _rng("flame", seed)
    wrinkles = fourier_modes(rng, 32, 3 * np.pi, 16 * np.pi, 0.7)
    wobble = rng.uniform(0, 2 * np.pi, 4).astype(F32)
    x, y, z, e = grid_axes(dims, z0, z1)
    zb, zt = -0.85 * e[2], 0.65 * e[2]  # base and tip of the flame
    r0 = 0.4 * min(e[0], e[1])  # widest radius of the unwrinkled flame
    zz = z[:, None, None]
    s = (zz - F32(zb)) / F32(zt - zb)  # 0 at the base, 1 at the tip
    n = eval_modes(wrinkles, x, y, z)
    # the axis sways a little with height
    xc = F32(0.05) * np.sin(F32(4.0) * zz + wobble[0]) + F32(0.02) * np.sin(F32(11.0) * zz + wobble[1])
    yc = F32(0.05) * np.sin(F32(3.0) * zz + wobble[2]) + F32(0.02) * np.sin(F32(13.0) * zz + wobble[3])
    r = np.sqrt((x[None, None, :] - xc) ** 2 + (y[None, :, None] - yc) ** 2)
    sc = np.clip(s, 0.0, 1.0)
    # candle profile s^0.6 (1 - s)^1.2: narrow base, bulge low (r0 at s = 1/3), long taper to the tip
    radius = F32(r0 / ((1 / 3) ** 0.6 * (2 / 3) ** 1.2)) * sc ** F32(0.6) * (F32(1.0) - sc) ** F32(1.2)
    # wrinkles displace the front outward/inward, more and more towards the tip (tongues, pockets)
    d = r - radius - (F32(0.01) + F32(0.07) * sc) * n
    core = _sigmoid(-d / F32(0.02))
    front = np.exp(-((d / F32(0.03)) ** 2))
    # fade in above the base, flicker out around the tip (the tip height varies with the noise)
    gate = np.clip(F32(10.0) * s, 0.0, 1.0) * _sigmoid((F32(1.0) - s + F32(0.06) * n) / F32(0.04))
    # brightest near the base; pockets that flicker above the tip cool off before the box's top
    heat = (F32(1.0) - F32(0.5) * sc) * np.clip((F32(e[2]) - zz) / F32(0.25), 0.0, 1.0)
    return (gate * heat * (F32(0.5) * core + F32(0.6) * front)).astype(F32, copy=False)


def _by_slabs(body: Callable[[int, int], np.ndarray], dims, z0: int, z1: int, rows: int = 16) -> np.ndarray:
    """Evaluate ``body(a, b) -> (b - a, Y, X)`` over rows of ``rows`` z-slices (cache-sized
    temporaries for paper-size volumes); every operation is elementwise, so any split of
    ``[z0, z1)`` gives the same bits."""
    out = np.empty((z1 - z0, int(dims[1]), int(dims[0])), F32)
    for a in range(z0, z1, rows):
        b = min(z1, a + rows)
        out[a - z0:b - z0] = body(a, b)
    return out


def _voxel(dims) -> float:
    """One voxel in normalized units (the longest axis spans [-1, 1])."""
    return 2.0 / (max(int(d) for d in dims) - 1)


def rayleigh_taylor(dims, seed: int, z0: int, z1: int, *, interface_voxels: float = 2.5) -> np.ndarray:
    """Paper-regime Rayleigh-Taylor mixing layer: heavy fluid (3) on top (+z) of light fluid (1)
    with a sharp interface (a sigmoid ``interface_voxels`` wide) folded into bubbles and spikes.

    The level set ``z - h(x, y) - 0.3 env n``: ``h`` is 64 2D modes (RMS 0.06); inside a Gaussian
    envelope (half width 0.55) ``n`` is 48 3D modes (k = 2 pi .. 40 pi, amplitude ~ 1/k, stretched
    along z) that fold the interface into bubbles and spikes down to ~13 voxels at 512^3. Every scale
    is a fold of the one interface, coherent across scales: no random-phase band finer than the
    folds (a first version wrinkled the interfaces with 24 modes down to ~6 voxels, a texture no
    network can infer from a half-resolution render; BENCHMARKS.md, "The paper's regime").
    """
    rng = _rng("rayleigh_taylor", seed)
    vox = _voxel(dims)
    interface = fourier_modes(rng, 64, 1.0 * np.pi, 40 * np.pi, 1.6, ndim=2)
    bubbles = fourier_modes(rng, 48, 2 * np.pi, 40 * np.pi, 1.0)
    bubbles[0][:, 2] *= 0.6  # stretched along gravity
    x, y, _, _ = grid_axes(dims)
    h = F32(0.06) * eval_modes(interface, x, y)[None]
    w = F32(interface_voxels * vox)

    def body(a: int, b: int) -> np.ndarray:
        z = grid_axes(dims, a, b)[2]
        zz = z[:, None, None]
        env = np.exp(-(((zz - h) / F32(0.55)) ** 2)).astype(F32)
        phi = zz - h - env * (F32(0.3) * eval_modes(bubbles, x, y, z))
        return F32(1.0) + F32(2.0) * _sigmoid(phi / w)

    return _by_slabs(body, dims, z0, z1)


def flame_sheets(dims, seed: int, z0: int, z1: int, *, sheet_voxels: float = 3.0) -> np.ndarray:
    """Paper-regime flame: two thin reaction sheets (Gaussian profile ``sheet_voxels`` wide) on a
    candle-shaped front folded at several scales, empty space around it; values 0 .. ~1.

    The front ``d = r - radius(z) - a(z) n - b(z) f`` (``n``: 24 3D modes k = 3 pi .. 24 pi,
    stretched along z; ``f``: 24 folds k = 6 pi .. 48 pi, amplitude ~ 1/k, down to ~11 voxels at
    512^3, up to 0.13 deep near the tip; both grow towards the tip: coherent folds, crumpled into
    overhangs, no random-phase band finer than them); the outer sheet lies on ``d = 0``, an inner one
    (inner cone, 0.7 as bright) at a depth 0.05 .. 0.1 shifted by 12 independent modes, so the two
    sheets fold, approach and pinch off on their own. Sheets are ``sheet_voxels`` wide so that the
    preset's opaque surface ramps over about 2 voxels: sharper, the shading normals turn at every voxel
    face (a speckle no network can infer); translucent, the trilinear field draws a moire.
    """
    rng = _rng("flame_sheets", seed)
    vox = _voxel(dims)
    big = fourier_modes(rng, 24, 3 * np.pi, 24 * np.pi, 1.0)
    big[0][:, 2] *= 0.5  # tongues stretched along the flow
    folds = fourier_modes(rng, 24, 6 * np.pi, 48 * np.pi, 1.0)
    mid = fourier_modes(rng, 12, 8 * np.pi, 30 * np.pi, 0.8)
    wobble = rng.uniform(0, 2 * np.pi, 4).astype(F32)
    x, y, _, e = grid_axes(dims)
    zb, zt = -0.88 * e[2], 0.72 * e[2]  # base and tip
    r0 = 0.56 * min(e[0], e[1])
    w = F32(sheet_voxels * vox)
    X, Y = x[None, None, :], y[None, :, None]

    def body(a: int, b: int) -> np.ndarray:
        z = grid_axes(dims, a, b)[2]
        zz = z[:, None, None]
        s = (zz - F32(zb)) / F32(zt - zb)
        sc = np.clip(s, 0.0, 1.0)
        xc = F32(0.05) * np.sin(F32(4.0) * zz + wobble[0]) + F32(0.02) * np.sin(F32(11.0) * zz + wobble[1])
        yc = F32(0.05) * np.sin(F32(3.0) * zz + wobble[2]) + F32(0.02) * np.sin(F32(13.0) * zz + wobble[3])
        r = np.sqrt((X - xc) ** 2 + (Y - yc) ** 2)
        radius = F32(r0 / ((1 / 3) ** 0.6 * (2 / 3) ** 1.2)) * sc ** F32(0.6) * (F32(1.0) - sc) ** F32(1.2)
        nb = eval_modes(big, x, y, z)
        d = r - radius - (F32(0.01) + F32(0.10) * sc) * nb
        d -= (F32(0.01) + F32(0.12) * sc) * eval_modes(folds, x, y, z)
        d2 = d + F32(0.05) + F32(0.05) * sc + F32(0.03) * eval_modes(mid, x, y, z)
        sheets = np.maximum(np.exp(-((d / w) ** 2)), F32(0.7) * np.exp(-((d2 / w) ** 2)))
        gate = np.clip(F32(10.0) * s, 0.0, 1.0) * _sigmoid((F32(1.0) - s + F32(0.06) * nb) / F32(0.04))
        heat = (F32(1.0) - F32(0.4) * sc) * np.clip((F32(e[2]) - zz) / F32(0.25), 0.0, 1.0)
        return (gate * heat * sheets).astype(F32, copy=False)

    return _by_slabs(body, dims, z0, z1)


def _cell_hash(i: np.ndarray, j: np.ndarray, salt: int) -> np.ndarray:
    """A uniform number in [0, 1) per integer cell ``(i, j)`` (float arrays of whole numbers): integer
    arithmetic only, so every machine draws the same jitter (a ``sin`` hash rounds differently per CPU)."""
    h = (i.astype(np.int64) * 73856093) ^ (j.astype(np.int64) * 19349663) ^ (salt * 83492791)
    h = (h ^ (h >> 13)) * 1274126177
    return ((h ^ (h >> 16)) & 0xFFFF).astype(F32) / F32(65536.0)


def seed_shell(dims, seed: int, z0: int, z1: int, *, edge_voxels: float = 2.5, spine_edge_voxels: float = 1.5,
               cell_voxels: float = 16.0, spine_radius_voxels: float = 3.0, spine_length_voxels: float = 36.0) -> np.ndarray:
    """Paper-regime CT-like specimen (a beechnut's spiny husk): a wrinkled shell 6 voxels thick
    (density ~0.6 at its core after its soft edges) around a three-ridged, slightly twisted nut,
    covered in about 1000 tapering spines (density ~0.85 on their axes) that lean and curl towards the
    apex; air (0) around it.

    The surface ``rho0(z) (1 + 0.13 cos 3 theta) + 0.02 l + 0.01 w`` (``l``: 12 3D modes
    k = 2.5 pi .. 10 pi; ``w``: 24 folds k = 12 pi .. 40 pi). One spine per cell of a lattice on
    (height, angle) ``cell_voxels`` apart, jittered, ``spine_radius_voxels`` thick at the base and
    0.6-1.4 x ``spine_length_voxels`` long. Each spine is a line across many pixels, the structure a
    C-Image gives a RecNN to complete. Shell edges are ``edge_voxels`` wide: with 1-voxel edges (the
    first design's pits and grooves) the shading normals turned at every voxel face, a speckle at
    about a pixel per voxel that no network can infer (BENCHMARKS.md, "The paper's regime").
    """
    rng = _rng("seed_shell", seed)
    vox = _voxel(dims)
    lumps = fourier_modes(rng, 12, 2.5 * np.pi, 10 * np.pi, 1.0)
    wrinkles = fourier_modes(rng, 24, 12 * np.pi, 40 * np.pi, 1.0)
    twist0 = rng.uniform(0, 2 * np.pi)
    x, y, _, e = grid_axes(dims)
    zb, zt = -0.82 * e[2], 0.80 * e[2]  # blunt base, pointed apex
    rm = 0.40 * min(e[0], e[1])
    thick, edge, sedge = F32(6.0 * vox), F32(edge_voxels * vox), F32(spine_edge_voxels * vox)
    cell, r0, length = F32(cell_voxels * vox), F32(spine_radius_voxels * vox), F32(spine_length_voxels * vox)
    X, Y = x[None, None, :], y[None, :, None]
    two_pi = F32(2 * np.pi)

    def rho0_of(zz: np.ndarray) -> np.ndarray:  # the nut's mean radius at height zz
        t = np.clip((zz - F32(zb)) / F32(zt - zb), 0.0, 1.0)
        return F32(rm) * np.maximum(np.sin(F32(np.pi) * t ** F32(0.75)), F32(0.0)) ** F32(0.6)

    def body(a: int, b: int) -> np.ndarray:
        z = grid_axes(dims, a, b)[2]
        zz = z[:, None, None]
        rho = np.sqrt(X * X + Y * Y)
        angle = np.arctan2(Y, X)
        th = angle - (F32(twist0) + F32(0.8) * zz)  # the three ridges twist a little
        surf = (rho0_of(zz) * (F32(1.0) + F32(0.13) * np.cos(F32(3.0) * th))
                + F32(0.02) * eval_modes(lumps, x, y, z) + F32(0.01) * eval_modes(wrinkles, x, y, z))
        d = rho - surf  # < 0 inside
        ends = _sigmoid((zz - F32(zb)) / edge) * _sigmoid((F32(zt) - zz) / edge)
        shell = _sigmoid((d + thick) / edge) * _sigmoid(-d / edge) * ends
        # spines: at height h above the shell a spine's axis has moved up (lean + curl) and round, so the
        # point's base coordinates (zp, tp) pick its cell, and the distance to that cell's axis its profile
        h = np.maximum(d, F32(0.0))
        zp = zz - (F32(0.3) * h + F32(3.0) * h * h)
        row = np.floor((zp - F32(zb)) / cell)
        z_row = F32(zb) + (row + F32(0.5)) * cell
        per_row = np.maximum(np.round(two_pi * np.maximum(rho0_of(z_row), F32(1e-3)) / cell), F32(3.0))
        tp = np.mod(angle - F32(0.6 / rm) * h, two_pi)
        col = np.floor(tp * per_row / two_pi)
        zc = z_row + (_cell_hash(row, col, 1) - F32(0.5)) * F32(0.3) * cell
        tc = (col + F32(0.5) + (_cell_hash(row, col, 2) - F32(0.5)) * F32(0.3)) * two_pi / per_row
        dt = np.mod(tp - tc + F32(np.pi), two_pi) - F32(np.pi)
        lateral = np.sqrt((zp - zc) ** 2 + (surf * dt) ** 2)
        spine_len = length * (F32(0.6) + F32(0.8) * _cell_hash(row, col, 3))
        radius = r0 * np.clip(F32(1.0) - h / spine_len, 0.0, 1.0) ** F32(0.7)
        rooted = _sigmoid((rho0_of(z_row) - F32(0.25 * rm)) / F32(4 * vox))  # none on the thin ends
        spine = _sigmoid((radius - lateral) / sedge) * _sigmoid((d + thick) / edge) * rooted * (radius > 0)
        return np.maximum(shell, spine).astype(F32, copy=False)

    return _by_slabs(body, dims, z0, z1)


def plume_lattice(X: np.ndarray, Y: np.ndarray, depth: np.ndarray, lean, *, cell: float, salt: int, radius: tuple,
                  length: tuple, cap: tuple, presence: float) -> np.ndarray:
    """Signed distance (normalized units, < 0 inside) to a lattice of plumes rooted at ``depth`` 0: one per square
    cell ``cell`` wide in (x, y), jittered, present with probability ``presence``, reaching a depth drawn in
    ``length`` = (lo, hi), tapering from ``radius`` = (root, tip) and ending in an ellipsoidal cap ``cap`` =
    (radius, half height). ``lean`` = (lx, ly, cx, cy), fields broadcastable to ``depth``: at depth d a plume's
    axis has moved by ``l d + c d^2``, so the point's root position picks its cell (as :func:`seed_shell`'s spines).
    A cap wider than ``cell / 2`` less the jitter would be cut at its cell's edge.

    Example:
        >>> z = np.linspace(-0.5, 0.5, 5, dtype=F32)[:, None, None]
        >>> X, Y = np.zeros((1, 1, 1), F32), np.zeros((1, 1, 1), F32)
        >>> d = plume_lattice(X, Y, z, (F32(0),) * 4, cell=0.5, salt=1, radius=(0.05, 0.05), length=(0.3, 0.3),
        ...                   cap=(0.08, 0.04), presence=1.0)
        >>> d.shape, bool(d[0, 0, 0] > 0)   # above the roots (depth < 0) the stem ends nowhere: not inside
        ((5, 1, 1), False)
    """
    lx, ly, cx, cy = lean
    dd = np.maximum(depth, F32(0.0))
    xp = X - dd * (lx + cx * dd)
    yp = Y - dd * (ly + cy * dd)
    cell = F32(cell)
    i = np.floor((xp + F32(1.0)) / cell)
    j = np.floor((yp + F32(1.0)) / cell)
    xc = F32(-1.0) + (i + F32(0.5) + F32(0.3) * (_cell_hash(i, j, salt) - F32(0.5))) * cell
    yc = F32(-1.0) + (j + F32(0.5) + F32(0.3) * (_cell_hash(i, j, salt + 1) - F32(0.5))) * cell
    reach = F32(length[0]) + F32(length[1] - length[0]) * _cell_hash(i, j, salt + 2)
    lateral = np.sqrt((xp - xc) ** 2 + (yp - yc) ** 2)
    t = np.clip(depth / reach, 0.0, 1.0)
    stem = np.maximum(lateral - (F32(radius[0]) + F32(radius[1] - radius[0]) * t), np.maximum(depth - reach, -depth))
    cr, ch = F32(cap[0]), F32(cap[1])
    head = (np.sqrt((lateral / cr) ** 2 + ((depth - reach) / ch) ** 2) - F32(1.0)) * min(cr, ch)
    return np.where(_cell_hash(i, j, salt + 3) < F32(presence), np.minimum(stem, head), F32(1.0)).astype(F32, copy=False)


RT_PLUMES = {
    # (cell, (root, tip) radius, (lo, hi) length, (radius, half height) cap, presence), in voxels
    "spikes": (40, (5.0, 2.5), (40, 150), (6.0, 3.0), 0.8),
    "fine_spikes": (18, (3.2, 2.4), (12, 60), (4.2, 2.4), 0.35),
    "bubbles": (40, (7.0, 10.0), (30, 120), (13.0, 11.0), 0.8),
    "lean": 0.12, "curl": 0.3,
}


def rt_plumes(dims, seed: int, z0: int, z1: int, *, edge_voxels: float = 1.5) -> np.ndarray:
    """Paper-regime Rayleigh-Taylor mixing layer late in its growth, for a whole-box framing: heavy fluid (3) on top
    of light (1), the interface ``z = h(x, y)`` (32 2D modes, RMS 0.05) folded by 24 3D modes (k = 6 pi .. 30 pi,
    0.03 deep near it), from which hang two lattices of spikes of heavy fluid (32 voxels apart, 5 -> 2.5 voxels thick,
    40-150 deep; 13 apart, 2.6 -> 1.8 thick, 12-60 deep) with mushroom caps, and into which rise bubbles of light
    fluid (40 apart, 7 -> 10 thick, round heads). Every plume leans and curls with the flow (smooth 2D fields).

    The detail at the pixel scale is the spikes: lines across many pixels, a few voxels thick, that a C-Image shows
    in part and a RecNN can complete (:func:`seed_shell`'s spines are the same kind of structure). The edges are a
    sigmoid ``edge_voxels`` wide.
    """
    rng = _rng("rt_plumes", seed)
    v = _voxel(dims)
    interface = fourier_modes(rng, 32, 1.0 * np.pi, 10 * np.pi, 1.6, ndim=2)
    folds = fourier_modes(rng, 24, 6 * np.pi, 30 * np.pi, 1.0)
    flow = [fourier_modes(rng, 8, 1.0 * np.pi, 2.5 * np.pi, 1.0, ndim=2) for _ in range(4)]
    x, y, _, _ = grid_axes(dims)
    X, Y = x[None, None, :], y[None, :, None]
    h = F32(0.05) * eval_modes(interface, x, y)[None]
    scale = (RT_PLUMES["lean"],) * 2 + (RT_PLUMES["curl"],) * 2
    lean = tuple(F32(s) * eval_modes(m, x, y)[None] for s, m in zip(scale, flow))
    rising = tuple(-f for f in lean)
    w = F32(edge_voxels * v)

    def lattice(depth, flow_, name, salt):
        cell, radius, length, cap, presence = RT_PLUMES[name]
        return plume_lattice(X, Y, depth, flow_, cell=cell * v, salt=salt, radius=tuple(r * v for r in radius),
                             length=tuple(s * v for s in length), cap=tuple(c * v for c in cap), presence=presence)

    def body(a: int, b: int) -> np.ndarray:
        z = grid_axes(dims, a, b)[2]
        depth = h - z[:, None, None]  # below the interface: < 0 is heavy fluid
        near = np.exp(-((depth / F32(0.3)) ** 2)).astype(F32)
        phi = depth + F32(0.03) * near * eval_modes(folds, x, y, z)
        phi = np.minimum(phi, lattice(depth, lean, "spikes", 10))
        phi = np.minimum(phi, lattice(depth, lean, "fine_spikes", 20))
        phi = np.maximum(phi, -lattice(-depth, rising, "bubbles", 30))
        return F32(1.0) + F32(2.0) * _sigmoid(-phi / w)

    return _by_slabs(body, dims, z0, z1)


@dataclass(frozen=True)
class ProceduralGenerator:
    """A registered generator: ``fn(dims_xyz, seed, z0, z1) -> float32 (z1 - z0, Y, X)``."""

    name: str
    fn: Callable[..., np.ndarray]
    default_size: tuple[int, int, int]
    description: str


#: name -> generator; ``make_procedural`` and ``scene.volume.generator`` use these names
PROCEDURAL_GENERATORS: dict[str, ProceduralGenerator] = {
    g.name: g
    for g in [
        ProceduralGenerator("tiny", tiny, (32, 32, 32), "three Gaussian blobs and a tilted torus (CI)"),
        ProceduralGenerator("marschner_lobb", marschner_lobb, (64, 64, 64), "Marschner-Lobb test signal, fM=6, alpha=0.25"),
        ProceduralGenerator("mixing_layer", mixing_layer, (96, 96, 96), "Rayleigh-Taylor-like turbulent mixing layer filling the box"),
        ProceduralGenerator("flame", flame, (64, 64, 96), "compact flame-like plume with turbulent wrinkles, empty around"),
        ProceduralGenerator("rayleigh_taylor", rayleigh_taylor, (512, 512, 512),
                            "paper-size Rayleigh-Taylor mixing layer, sharp folded interfaces down to a few voxels"),
        ProceduralGenerator("flame_sheets", flame_sheets, (512, 512, 512),
                            "paper-size flame: thin reaction sheets wrinkled at several scales, empty around"),
        ProceduralGenerator("seed_shell", seed_shell, (512, 512, 512),
                            "paper-size CT-like specimen: a beechnut's wrinkled husk covered in ~1000 curled spines"),
        ProceduralGenerator("rt_plumes", rt_plumes, (512, 512, 512),
                            "paper-size Rayleigh-Taylor layer late in its growth: capped spikes and bubbles, thin to a few voxels"),
    ]
}


# ---------------------------------------------------------------------------------------------
# public API
# ---------------------------------------------------------------------------------------------
def _generator(name) -> ProceduralGenerator:
    if str(name) not in PROCEDURAL_GENERATORS:
        raise InputError(f"scene.volume.generator={name!r}: unknown generator, expected one of {', '.join(PROCEDURAL_GENERATORS)}")
    return PROCEDURAL_GENERATORS[str(name)]


def _size(size, default: tuple[int, int, int], what: str = "scene.volume.size") -> tuple[int, int, int]:
    if size is None:
        return default
    try:
        vals = [size] * 3 if np.ndim(size) == 0 else list(size)
        ok = len(vals) == 3 and all(float(v) == int(v) and int(v) >= 2 for v in vals)
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise InputError(f"{what}={size!r}: expected an integer >= 2 or three of them [x, y, z]")
    return (int(vals[0]), int(vals[1]), int(vals[2]))


def _seed(seed) -> int:
    try:
        ok = float(seed) == int(seed) and int(seed) >= 0
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise InputError(f"scene.volume.seed={seed!r}: expected a non-negative integer")
    return int(seed)


def procedural_spec(generator: str, size=None, seed=0) -> tuple[str, tuple[int, int, int], int]:
    """Checked ``(generator, (x, y, z), seed)``: the generator's default size where ``size`` is None.

    Example:
        >>> procedural_spec("flame", None, 2)
        ('flame', (64, 64, 96), 2)
    """
    g = _generator(generator)
    return g.name, _size(size, g.default_size), _seed(seed)


def procedural_source(generator: str, dims, seed: int) -> str:
    """The regeneration string, e.g. ``procedural:mixing_layer?size=64,64,64&seed=0``."""
    return f"procedural:{generator}?size={','.join(str(int(d)) for d in dims)}&seed={int(seed)}"


_SOURCE = re.compile(r"^procedural:(?P<gen>\w+)\?size=(?P<x>\d+),(?P<y>\d+),(?P<z>\d+)&seed=(?P<seed>\d+)$")


def parse_procedural_source(source: str) -> tuple[str, tuple[int, int, int], int]:
    """Inverse of :func:`procedural_source`: ``(generator, (x, y, z), seed)``.

    Example:
        >>> parse_procedural_source("procedural:flame?size=64,64,96&seed=2")
        ('flame', (64, 64, 96), 2)
    """
    m = _SOURCE.match(str(source).strip())
    if m is None:
        raise InputError(f"source={source!r}: expected procedural:<generator>?size=x,y,z&seed=n")
    return m["gen"], (int(m["x"]), int(m["y"]), int(m["z"])), int(m["seed"])


def make_procedural(generator: str, size=None, seed: int = 0) -> Volume:
    """Generate a procedural volume in memory.

    Args:
        generator: a name in :data:`PROCEDURAL_GENERATORS`.
        size: ``int`` (cube) or ``(x, y, z)``; ``None`` -> the generator's default size.
        seed: non-negative integer; the same seed gives the same volume bit for bit.

    Returns:
        Volume with ``data`` float32 ``(Z, Y, X)``, spacing ``(1, 1, 1)``, value range = (min, max),
        ``source`` = :func:`procedural_source` string.

    Example:
        >>> v = make_procedural("marschner_lobb", 41)
        >>> v.data.shape, round(v.value_range[1], 2)
        ((41, 41, 41), 1.0)
    """
    g = _generator(generator)
    dims = _size(size, g.default_size)
    seed = _seed(seed)
    data = g.fn(dims, seed, 0, dims[2])
    info = {"generator": g.name, "size_xyz": list(dims), "seed": seed, "description": g.description}
    source = procedural_source(g.name, dims, seed)
    return Volume(data, (1.0, 1.0, 1.0), (float(data.min()), float(data.max())), g.name, source, info)


def from_source(source: str) -> Volume:
    """Regenerate a procedural volume from its ``source`` string (as recorded in a manifest)."""
    gen, dims, seed = parse_procedural_source(source)
    return make_procedural(gen, dims, seed)


def raw_name(generator: str, dims, seed: int = 0) -> str:
    """The file name :func:`write_procedural_raw` gives a volume in a directory.

    Seed 0 keeps the plain Open SciVis name (``flame_1408x1080x1100_float32.raw``, what
    ``experiment=large_flame`` expects); other seeds are part of the name, so two seeds never share
    a file.

    Example:
        >>> raw_name("flame", (64, 64, 96)), raw_name("flame", 32, seed=3)
        ('flame_64x64x96_float32.raw', 'flame-seed3_32x32x32_float32.raw')
    """
    g = _generator(generator)
    dims = _size(dims, g.default_size, "dims")
    stem = g.name if _seed(seed) == 0 else f"{g.name}-seed{int(seed)}"
    return f"{stem}_{dims[0]}x{dims[1]}x{dims[2]}_float32.raw"


def _probe_slices(nz: int) -> list[int]:
    # first, middle and last z-slice: a changed generator, seed or a torn file shows in one of them
    return sorted({0, nz // 2, nz - 1})


def raw_matches(generator: str, dims, path: str | os.PathLike, seed: int = 0) -> bool:
    """Whether ``path`` holds this procedural volume: right size, and its first, middle and last
    z-slices equal the generator's bit for bit (a slab is bit-identical to the whole volume's rows).

    Costs three z-slices of generation, so a reused file is checked by content, not by its name.
    """
    g = _generator(generator)
    dims = _size(dims, g.default_size, "dims")
    path = Path(path)
    nbytes = dims[0] * dims[1] * dims[2] * 4
    if not path.is_file() or path.stat().st_size != nbytes:
        return False
    data = np.memmap(path, dtype="<f4", mode="r", shape=(dims[2], dims[1], dims[0]))
    try:
        return all(np.array_equal(data[z:z + 1], g.fn(dims, _seed(seed), z, z + 1)) for z in _probe_slices(dims[2]))
    finally:
        del data


def _write_slab(name: str, dims, seed: int, z0: int, z1: int, path: str) -> int:
    """Worker: evaluate one z-slab and write it at its offset of the (pre-sized) file."""
    slab = np.ascontiguousarray(PROCEDURAL_GENERATORS[name].fn(dims, seed, z0, z1), dtype="<f4")
    fd = os.open(path, os.O_WRONLY)
    try:
        view = memoryview(slab).cast("B")
        offset, done = z0 * dims[0] * dims[1] * 4, 0
        while done < len(view):
            done += os.pwrite(fd, view[done:], offset + done)
    finally:
        os.close(fd)
    return z1 - z0


def _workers(workers) -> int:
    try:
        w = int(workers)
        if w < 0 or isinstance(workers, bool) or float(workers) != w:
            raise ValueError
    except (TypeError, ValueError):
        raise InputError(f"workers={workers!r}: expected an integer >= 0 (0 = one per core)") from None
    return w or (os.cpu_count() or 1)


def write_procedural_raw(generator: str, dims, path: str | os.PathLike, seed: int = 0, chunk_z: int = 32,
                         overwrite: bool = False, workers: int = 1, progress: bool = False) -> Path:
    """Stream a procedural volume slab by slab into an Open SciVis ``.raw`` file (float32, LE).

    Never holds more than ``chunk_z`` slices per worker in memory, so paper-scale volumes (1024^3 =
    4 GiB) can be made on a small machine. The file is written under a temporary name and renamed
    when complete (atomic): an existing file with the final name is always whole. It is reused only
    when its content checks out (:func:`raw_matches`); a file that does not (another generator
    version, a torn copy) is regenerated, and the one line saying so goes to stderr.

    Args:
        generator: a name in :data:`PROCEDURAL_GENERATORS`.
        dims: ``(x, y, z)`` or an int.
        path: a directory (the file is named :func:`raw_name` in it) or the ``.raw`` file itself,
            whose name must follow the convention with these dims.
        seed: as in :func:`make_procedural` (same seed, same voxels).
        chunk_z: z-slices per slab.
        workers: processes evaluating slabs in parallel (0 = one per core); each writes its slab
            at its own offset of the file.
        progress: a tqdm bar over the slabs.

    Returns:
        The path of the ``.raw`` file; load it with ``load_volume({"path": ...})``.

    Example:
        >>> p = write_procedural_raw("mixing_layer", 1024, "/data", seed=0)   # doctest: +SKIP
        >>> p.name                                                             # doctest: +SKIP
        'mixing_layer_1024x1024x1024_float32.raw'
    """
    g = _generator(generator)
    dims = _size(dims, g.default_size, "dims")
    seed = _seed(seed)
    workers = _workers(workers)
    try:
        chunk_z = int(chunk_z)
        if chunk_z < 1:
            raise ValueError
    except (TypeError, ValueError):
        raise InputError(f"chunk_z={chunk_z!r}: expected a positive integer") from None
    path = Path(path).expanduser()
    fname = raw_name(g.name, dims, seed)
    if path.is_dir():
        path = path / fname
    else:
        m = re.match(r"^.+_(\d+)x(\d+)x(\d+)_float32\.raw$", path.name)
        if m is None or tuple(int(v) for v in m.groups()) != dims:
            raise InputError(f"path={path}: expected a directory or a file named like {fname} (name_XxYxZ_float32.raw with these dims)")
        if not path.parent.is_dir():
            raise InputError(f"path={path}: directory {path.parent} does not exist")
    nbytes = dims[0] * dims[1] * dims[2] * 4
    if path.is_file() and not overwrite:
        if raw_matches(g.name, dims, path, seed):
            return path
        print(f"{path}: not the volume procedural:{g.name} seed {seed} describes (size or content differ); regenerating it",
              file=sys.stderr)
    slabs = [(z0, min(dims[2], z0 + chunk_z)) for z0 in range(0, dims[2], chunk_z)]
    bar = _progress(len(slabs), f"{fname}", progress)

    def write(fh) -> None:
        if workers == 1 or len(slabs) == 1:
            for z0, z1 in slabs:
                fh.write(np.ascontiguousarray(g.fn(dims, seed, z0, z1), dtype="<f4").tobytes())
                bar.update(1)
            return
        fh.truncate(nbytes)
        fh.flush()
        # spawn, not fork: the parent may hold numba/torch thread pools that a fork would copy mid-state
        ctx = multiprocessing.get_context("spawn")
        # a worker exits when this process dies (killed mid-volume, it would otherwise idle on its pipe for ever)
        with concurrent.futures.ProcessPoolExecutor(min(workers, len(slabs)), mp_context=ctx, initializer=exit_when_orphaned,
                                                    initargs=(os.getpid(),)) as pool:
            jobs = [pool.submit(_write_slab, g.name, dims, seed, z0, z1, fh.name) for z0, z1 in slabs]
            for job in concurrent.futures.as_completed(jobs):
                job.result()
                bar.update(1)

    try:
        atomic_write(path, write, unique=True)
    except PermissionError as err:
        raise InputError(f"path={path}: cannot write ({err.strerror})") from None
    finally:
        bar.close()
    return path


def _progress(total: int, desc: str, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="slab", disable=not enabled, leave=False)
