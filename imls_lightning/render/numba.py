"""The project's own compiled ray caster (numba): full frames and arbitrary pixel subsets.

:class:`NumbaRenderer` implements the scene model of the renderer of record
(:class:`~imls_lightning.render.vtk.VTKRenderer`, VTK's ``vtkFixedPointVolumeRayCastMapper``) so that the
cache and the selective renderer of a run can use it interchangeably with VTK. Every ray is
independent, so ``render_pixels(view, m, pixels)`` is *exactly* ``render(view, m)`` at those pixels
and its cost is linear in the number of pixels.

Scene model (the conventions of VTK's fixed-point mapper, read from its source):

* **Rays** through pixel centres (:func:`imls_lightning.render.camera.pixel_rays`). Rays that miss the volume's
  box ``[origin, origin + (dims - 1) * spacing]`` get the background and are never marched.
* **Samples** every ``scene.sample_distance`` along the ray (normalized units, resolved by
  :func:`imls_lightning.render.scene.resolve_sample_distance`: ``auto`` is half a voxel), on a grid anchored
  at the near clipping plane that VTK's ``vtkRenderer::ResetCameraClippingRange`` gives for the
  volume's box (:func:`clipping_range`; :class:`~imls_lightning.render.vtk.VTKRenderer` sets the same
  planes). As VTK does, the ray is clipped to the box inset by 0.01 voxel, the segment is shortened
  by 0.1% at each end, and the first sample is the first grid point strictly after its start.
* **Scalars**: trilinear interpolation of the raw volume in its native dtype, normalized on the fly
  with ``volume.value_range`` (no float copy of the volume is ever made). ``interpolation="tricubic"`` (no VTK
  counterpart) takes the cubic B-spline instead and shades each sample from its gradient (:class:`NumbaRenderer`).
* **Transfer function**: a 4096-entry lookup table over [0, 1], linearly interpolated, with the
  opacity corrected for the sample distance, ``1 - (1 - a) ** (sample_distance /
  opacity_unit_distance)``.
* **Shading** (VTK's ``vtkEncodedGradientShader`` with the renderer's headlight and two-sided
  lighting): per-voxel normals from central differences of the raw field (divided by the voxel
  spacing); at each of a sample's 8 cell corners ``D = ambient + diffuse * |n . v|`` and
  ``S = specular * |n . v| ** power`` (``v`` the view direction; a zero gradient gives ``D =
  ambient, S = 0``); ``D`` and ``S`` are interpolated trilinearly and the sample's premultiplied
  colour is ``(D * rgb + S) * alpha``. Gradients are computed only at samples whose opacity is > 0.
* **Compositing** front to back; a ray stops once its remaining transparency drops below
  ``255 / 32767`` (VTK's fixed-point early termination); the background is composited behind.
* **Empty-space skipping**: a min/max grid over 8^3-voxel bricks marks the bricks in which the
  transfer function is exactly transparent, and a Chebyshev distance transform over the bricks
  (:func:`skip_distance`) lets a ray jump over a whole block of them to the next sample on the same
  grid, so skipping never changes a pixel. Precomputed once per renderer: a few kB.

Agreement with VTK (measured by a script removed after its result was committed,
``git show 97cc83f:scripts/bench_selective.py``): 52-56 dB PSNR on ``ct_head``, mean
absolute error ~0.25/255; the residue is VTK's 15-bit fixed-point arithmetic (its roundings are
biased up) and its quantized normals, plus a handful of pixels on the box's silhouette that VTK's
row bounds skip.

Example:
    >>> r = NumbaRenderer(scene)                                         # doctest: +SKIP
    >>> img = r.render([0, 0, 3, 0, 0, 0, 0, 1, 0], 128)                 # (128, 128, 3) uint8
    >>> r.render_pixels([0, 0, 3, 0, 0, 0, 0, 1, 0], 128, np.array([0, 8256]))   # (2, 3) uint8
"""
from __future__ import annotations

import math
import time

import numba
import numpy as np
from numba import njit, prange

from imls_lightning.base.errors import InputError
from imls_lightning.base.validate import check_integer

from .camera import camera_basis, render_request
from .scene import Scene

#: entries of the transfer-function lookup table over normalized scalars [0, 1]
LUT_SIZE = 4096
#: edge of the empty-space-skipping bricks, in voxels (cells): 2 ** BRICK_SHIFT
BRICK_SHIFT = 3
BRICK = 1 << BRICK_SHIFT
#: VTK fixed point: a ray ends once its remaining transparency is below 0xff / 0x7fff
TERMINATION = 255.0 / 32767.0
#: pixels per work item handed to a thread (dynamic scheduling balances rays of unequal cost)
CHUNK = 64


# ------------------------------------------------------------------------------------------------
# camera helpers shared with the VTK selective route
# ------------------------------------------------------------------------------------------------
def clipping_range(view, bounds: np.ndarray, view_angle: float, near_tolerance: float = 0.001) -> tuple[float, float]:
    """Near/far clipping distances that ``vtkRenderer::ResetCameraClippingRange(bounds)`` sets.

    VTK starts its rays at the near plane and places samples every ``sample_distance`` from
    there, so the numba caster needs the same near plane to put its samples where VTK does.

    Args:
        view: 9 floats.
        bounds: ``(3, 2)`` box ``[[xmin, xmax], [ymin, ymax], [zmin, zmax]]``.
        view_angle: vertical view angle in degrees.
        near_tolerance: VTK's ``NearClippingPlaneTolerance`` (0.001 for a 24-bit depth buffer).

    Returns:
        ``(near, far)`` distances along the view direction.
    """
    eye, f, _, _ = camera_basis(view)
    b = np.asarray(bounds, np.float64)
    corners = np.array([[b[0, i], b[1, j], b[2, k]] for k in (0, 1) for j in (0, 1) for i in (0, 1)])
    dist = (corners - eye) @ f
    r0, r1 = float(dist.min()), float(dist.max())
    min_gap = 0.2 * math.tan(math.radians(float(view_angle)) / 2.0) * r1
    if r1 - r0 < min_gap:
        g = min_gap - r1 + r0
        r1 += g / 2.0
        r0 -= g / 2.0
    r0 = max(r0, 0.0)
    expansion = 0.5  # vtkRenderer's default ClippingRangeExpansion
    r0 = 0.99 * r0 - (r1 - r0) * expansion
    r1 = 1.01 * r1 + (r1 - r0) * expansion  # VTK uses the already-updated near here
    if r0 >= r1:
        r0 = 0.01 * r1
    if r0 < near_tolerance * r1:
        r0 = near_tolerance * r1
    return r0, r1


@njit(cache=True)
def _ray_dir(p, m, fwd, right, up, tan_half):
    """Unit direction through the centre of flat pixel ``p`` (same formula as ``pixel_rays``)."""
    row = p // m
    col = p - row * m
    x = (2.0 * (col + 0.5) / m - 1.0) * tan_half
    y = (1.0 - 2.0 * (row + 0.5) / m) * tan_half
    dx = fwd[0] + x * right[0] + y * up[0]
    dy = fwd[1] + x * right[1] + y * up[1]
    dz = fwd[2] + x * right[2] + y * up[2]
    n = math.sqrt(dx * dx + dy * dy + dz * dz)
    return dx / n, dy / n, dz / n


@njit(cache=True)
def _slab(ex, ey, ez, dx, dy, dz, bmin, bmax):
    """Entry/exit distances of a ray against an axis-aligned box (``t1 <= t0``: miss)."""
    t0 = -np.inf
    t1 = np.inf
    e = (ex, ey, ez)
    d = (dx, dy, dz)
    for a in range(3):
        if d[a] != 0.0:
            ta = (bmin[a] - e[a]) / d[a]
            tb = (bmax[a] - e[a]) / d[a]
            if ta > tb:
                ta, tb = tb, ta
            if ta > t0:
                t0 = ta
            if tb < t1:
                t1 = tb
        elif e[a] < bmin[a] or e[a] > bmax[a]:
            return 1.0, 0.0
    return t0, t1


@njit(parallel=True, cache=True)
def _hit_mask(pixels, m, eye, fwd, right, up, tan_half, near, far, bmin, bmax, out):
    """``out[i] = 1`` where the ray of ``pixels[i]`` crosses the box between near and far planes."""
    for i in prange(pixels.shape[0]):
        dx, dy, dz = _ray_dir(pixels[i], m, fwd, right, up, tan_half)
        cosa = dx * fwd[0] + dy * fwd[1] + dz * fwd[2]
        t0, t1 = _slab(eye[0], eye[1], eye[2], dx, dy, dz, bmin, bmax)
        t0 = max(t0, near / cosa, 0.0)
        t1 = min(t1, far / cosa)
        out[i] = 1 if t1 > t0 else 0


def ray_hit_mask(view, resolution: int, view_angle: float, bounds: np.ndarray,
                 clip: tuple[float, float] | None = None, pixels: np.ndarray | None = None) -> np.ndarray:
    """Boolean ``(K,)`` (or ``(m*m,)``): which pixels' rays cross ``bounds`` between the planes.

    A superset of the rays a renderer marches (no 0.01-voxel inset): used to find the pixels the
    VTK selective route must block.
    """
    m = int(resolution)
    eye, f, r, u = camera_basis(view)
    if clip is None:
        clip = clipping_range(view, bounds, view_angle)
    pix = np.arange(m * m, dtype=np.int64) if pixels is None else np.asarray(pixels, np.int64)
    out = np.empty(pix.shape[0], np.uint8)
    b = np.asarray(bounds, np.float64)
    _hit_mask(pix, m, eye, f, r, u, math.tan(math.radians(view_angle) / 2.0), float(clip[0]), float(clip[1]),
              np.ascontiguousarray(b[:, 0]), np.ascontiguousarray(b[:, 1]), out)
    return out.view(bool)


# ------------------------------------------------------------------------------------------------
# empty-space skipping
# ------------------------------------------------------------------------------------------------
@njit(parallel=True, cache=True)
def _brick_minmax(flat, nx, ny, nz, bs, halo, out_min, out_max):
    """Raw min/max over each brick's voxels ``[b*bs - halo, b*bs + bs + halo]`` (inclusive: its cells' corners, and
    ``halo`` voxels more on each side for a filter wider than a cell), clipped to the volume."""
    nbz, nby, nbx = out_min.shape
    for bz in prange(nbz):
        z0 = max(bz * bs - halo, 0)
        z1 = min(bz * bs + bs + halo, nz - 1)
        for by in range(nby):
            y0 = max(by * bs - halo, 0)
            y1 = min(by * bs + bs + halo, ny - 1)
            for bx in range(nbx):
                x0 = max(bx * bs - halo, 0)
                x1 = min(bx * bs + bs + halo, nx - 1)
                lo = np.inf
                hi = -np.inf
                for z in range(z0, z1 + 1):
                    for y in range(y0, y1 + 1):
                        base = (z * ny + y) * nx
                        for x in range(x0, x1 + 1):
                            v = float(flat[base + x])
                            if v < lo:
                                lo = v
                            if v > hi:
                                hi = v
                out_min[bz, by, bx] = lo
                out_max[bz, by, bx] = hi


def skip_distance(transparent: np.ndarray, cap: int = 64) -> np.ndarray:
    """Chebyshev distance (in bricks) from each brick to the nearest non-transparent one.

    ``0`` marks bricks that must be sampled; a brick at distance ``d`` sits in a
    ``(2d - 1)^3`` block of transparent bricks, which a ray crosses in one jump. Bricks outside
    the grid count as transparent (rays never sample there). ``uint8``, capped at ``cap``.
    """
    opaque = transparent == 0
    dist = np.where(opaque, 0, cap).astype(np.uint8)
    reach = opaque.copy()
    for d in range(1, cap):
        if reach.all():
            break
        grown = reach.copy()  # 3x3x3 dilation (Chebyshev radius 1) by shifted maxima
        for ax in range(3):
            g = grown.copy()
            sl_lo = [slice(None)] * 3
            sl_hi = [slice(None)] * 3
            sl_lo[ax] = slice(1, None)
            sl_hi[ax] = slice(None, -1)
            g[tuple(sl_lo)] |= grown[tuple(sl_hi)]
            g[tuple(sl_hi)] |= grown[tuple(sl_lo)]
            grown = g
        dist[grown & ~reach] = d
        reach = grown
    return dist


def transparent_bricks(bmin: np.ndarray, bmax: np.ndarray, value_range, alpha_table: np.ndarray) -> np.ndarray:
    """``uint8`` grid: 1 where every scalar a brick can interpolate has exactly zero opacity.

    Trilinear interpolation stays within the min/max of a cell's corners (the tricubic B-spline within that of the
    4^3 voxels around the cell: the bricks' ranges then take one voxel more on each side), and the lookup table is
    interpolated linearly between entries, so a brick whose normalized range covers only
    zero-opacity entries can only produce transparent samples: skipping it is exact.
    """
    lo_v, hi_v = value_range
    n = alpha_table.shape[0]
    s_lo = np.clip((bmin - lo_v) / (hi_v - lo_v), 0.0, 1.0) * (n - 1)
    s_hi = np.clip((bmax - lo_v) / (hi_v - lo_v), 0.0, 1.0) * (n - 1)
    i0 = np.floor(s_lo).astype(np.int64)
    i1 = np.minimum(np.ceil(s_hi).astype(np.int64), n - 1)
    nonzero = np.concatenate([[0], np.cumsum(alpha_table > 0)])  # prefix count of opaque entries
    return ((nonzero[i1 + 1] - nonzero[i0]) == 0).astype(np.uint8)


# ------------------------------------------------------------------------------------------------
# the ray caster
# ------------------------------------------------------------------------------------------------
@njit(cache=True)
def _power(c, p):
    """``c ** p``; by repeated squaring for integer powers up to 128 (the usual case: 10, 20, ...)."""
    ip = int(p)
    if ip == p and 0 < ip <= 128:
        r = 1.0
        b = c
        while ip:
            if ip & 1:
                r *= b
            b *= b
            ip >>= 1
        return r
    return math.pow(c, p)


@njit(cache=True)
def _shade_from_grad(gx, gy, gz, zero_tol, vx, vy, vz, ka, kd, ks, spow):
    """VTK shading-table entry ``(D, S)`` for a (spacing-scaled) voxel gradient."""
    t = math.sqrt(gx * gx + gy * gy + gz * gz)
    if t <= zero_tol:
        return ka, 0.0
    c = abs(gx * vx + gy * vy + gz * vz) / t
    d = ka
    s = 0.0
    if c > 0.0:
        d += kd * c
        if c > 0.001:
            s = ks * _power(c, spow)
    return d, s


@njit(cache=True)
def _cell_corners(flat, base, nx, plane):
    """The 8 voxel values of the cell whose lowest corner is flat index ``base`` (``nx``: the x row's length,
    ``plane``: a z slice's), as floats in the order ``v000, v100, v010, v110, v001, v101, v011, v111`` (``vXYZ``)."""
    return (float(flat[base]), float(flat[base + 1]), float(flat[base + nx]), float(flat[base + nx + 1]),
            float(flat[base + plane]), float(flat[base + plane + 1]), float(flat[base + plane + nx]),
            float(flat[base + plane + nx + 1]))


@njit(cache=True)
def _cell_shade_interior(flat, base, nx, plane, gsx, gsy, gsz, zero_tol, vx, vy, vz, ka, kd, ks, spow):
    """``(D, S)`` of the 8 corners of the cell at flat index ``base`` (no corner on a face).

    The 8 central differences need 32 distinct voxels: the cell and its one-voxel extension
    along each axis; each is read once.
    """
    c000, c100, c010, c110, c001, c101, c011, c111 = _cell_corners(flat, base, nx, plane)
    # x - 1 and x + 2 neighbours of the four x-rows of the cell
    xm00 = float(flat[base - 1])
    xp00 = float(flat[base + 2])
    xm10 = float(flat[base + nx - 1])
    xp10 = float(flat[base + nx + 2])
    xm01 = float(flat[base + plane - 1])
    xp01 = float(flat[base + plane + 2])
    xm11 = float(flat[base + plane + nx - 1])
    xp11 = float(flat[base + plane + nx + 2])
    # y - 1 and y + 2 neighbours
    ym00 = float(flat[base - nx])
    yp00 = float(flat[base + 2 * nx])
    ym10 = float(flat[base - nx + 1])
    yp10 = float(flat[base + 2 * nx + 1])
    ym01 = float(flat[base + plane - nx])
    yp01 = float(flat[base + plane + 2 * nx])
    ym11 = float(flat[base + plane - nx + 1])
    yp11 = float(flat[base + plane + 2 * nx + 1])
    # z - 1 and z + 2 neighbours
    zm00 = float(flat[base - plane])
    zp00 = float(flat[base + 2 * plane])
    zm10 = float(flat[base - plane + 1])
    zp10 = float(flat[base + 2 * plane + 1])
    zm01 = float(flat[base - plane + nx])
    zp01 = float(flat[base + 2 * plane + nx])
    zm11 = float(flat[base - plane + nx + 1])
    zp11 = float(flat[base + 2 * plane + nx + 1])
    # VTK's normal: v[x-1] - v[x+1] per axis, divided by the spacing
    d0, s0 = _shade_from_grad((xm00 - c100) * gsx, (ym00 - c010) * gsy, (zm00 - c001) * gsz, zero_tol, vx, vy, vz, ka, kd, ks, spow)
    d1, s1 = _shade_from_grad((c000 - xp00) * gsx, (ym10 - c110) * gsy, (zm10 - c101) * gsz, zero_tol, vx, vy, vz, ka, kd, ks, spow)
    d2, s2 = _shade_from_grad((xm10 - c110) * gsx, (c000 - yp00) * gsy, (zm01 - c011) * gsz, zero_tol, vx, vy, vz, ka, kd, ks, spow)
    d3, s3 = _shade_from_grad((c010 - xp10) * gsx, (c100 - yp10) * gsy, (zm11 - c111) * gsz, zero_tol, vx, vy, vz, ka, kd, ks, spow)
    d4, s4 = _shade_from_grad((xm01 - c101) * gsx, (ym01 - c011) * gsy, (c000 - zp00) * gsz, zero_tol, vx, vy, vz, ka, kd, ks, spow)
    d5, s5 = _shade_from_grad((c001 - xp01) * gsx, (ym11 - c111) * gsy, (c100 - zp10) * gsz, zero_tol, vx, vy, vz, ka, kd, ks, spow)
    d6, s6 = _shade_from_grad((xm11 - c111) * gsx, (c001 - yp01) * gsy, (c010 - zp01) * gsz, zero_tol, vx, vy, vz, ka, kd, ks, spow)
    d7, s7 = _shade_from_grad((c011 - xp11) * gsx, (c101 - yp11) * gsy, (c110 - zp11) * gsz, zero_tol, vx, vy, vz, ka, kd, ks, spow)
    return d0, d1, d2, d3, d4, d5, d6, d7, s0, s1, s2, s3, s4, s5, s6, s7


@njit(cache=True)
def _central_difference(flat, i, stride, at, n, edge2):
    """VTK's ``v[i - stride] - v[i + stride]`` along one axis at flat voxel index ``i`` (``stride``: the axis's step in
    ``flat``; ``at``: the voxel's index on the axis, ``n``: the axis's length); at a face the one-sided difference,
    doubled with ``edge2``."""
    if at == 0:
        g = float(flat[i]) - float(flat[i + stride])
        if edge2:
            g *= 2.0
    elif at == n - 1:
        g = float(flat[i - stride]) - float(flat[i])
        if edge2:
            g *= 2.0
    else:
        g = float(flat[i - stride]) - float(flat[i + stride])
    return g


@njit(cache=True)
def _corner_shade(flat, x, y, z, nx, ny, nz, gsx, gsy, gsz, edge2, zero_tol, vx, vy, vz, ka, kd, ks, spow):
    """VTK shading-table entry ``(D, S)`` for the normal of voxel ``(x, y, z)``.

    The normal is VTK's ``v[x-1] - v[x+1]`` per axis (minus the gradient) divided by the spacing;
    at the volume's faces VTK clamps the index (8/16-bit integer data) or takes a one-sided
    difference doubled (other types, ``edge2``). Two-sided headlight: the cosine is ``|n . v|``.
    """
    i = (z * ny + y) * nx + x
    gx = _central_difference(flat, i, 1, x, nx, edge2)
    gy = _central_difference(flat, i, nx, y, ny, edge2)
    gz = _central_difference(flat, i, nx * ny, z, nz, edge2)
    return _shade_from_grad(gx * gsx, gy * gsy, gz * gsz, zero_tol, vx, vy, vz, ka, kd, ks, spow)


# ------------------------------------------------------------------------------------------------
# tricubic interpolation (renderer.interpolation=tricubic)
# ------------------------------------------------------------------------------------------------
#: the interpolations of the ray caster's scalar samples (``renderer.interpolation``), the default first
INTERPOLATIONS = ("trilinear", "tricubic")


@njit(cache=True)
def _bspline_weights(f):
    """Cubic B-spline weights of the taps at ``i - 1, i, i + 1, i + 2`` for a sample at ``i + f``."""
    g = 1.0 - f
    f2 = f * f
    f3 = f2 * f
    return g * g * g / 6.0, (3.0 * f3 - 6.0 * f2 + 4.0) / 6.0, (-3.0 * f3 + 3.0 * f2 + 3.0 * f + 1.0) / 6.0, f3 / 6.0


@njit(cache=True)
def _bspline_slopes(f):
    """Derivatives of :func:`_bspline_weights` with respect to ``f`` (the taps' weights in a derivative)."""
    g = 1.0 - f
    return -0.5 * g * g, 1.5 * f * f - 2.0 * f, -1.5 * f * f + f + 0.5, 0.5 * f * f


@njit(cache=True)
def _taps(i, n, stride):
    """Flat offsets of the taps ``i - 1 .. i + 2`` along one axis, clamped to the volume (``[0, n - 1]``) as the
    trilinear path clamps its sample position: the field continues its faces' values outward."""
    return max(i - 1, 0) * stride, i * stride, min(i + 1, n - 1) * stride, min(i + 2, n - 1) * stride


@njit(cache=True)
def _row(flat, base, xt, wx):
    """One x row of 4 taps, weighted."""
    return (wx[0] * float(flat[base + xt[0]]) + wx[1] * float(flat[base + xt[1]])
            + wx[2] * float(flat[base + xt[2]]) + wx[3] * float(flat[base + xt[3]]))


@njit(cache=True)
def _bspline_sum(flat, xt, yt, zt, wx, wy, wz):
    """The separable sum over the 4^3 taps (flat offsets ``xt, yt, zt`` per axis) with per-axis weights."""
    acc = 0.0
    for k in range(4):
        zb = zt[k]
        acc += wz[k] * (wy[0] * _row(flat, zb + yt[0], xt, wx) + wy[1] * _row(flat, zb + yt[1], xt, wx)
                        + wy[2] * _row(flat, zb + yt[2], xt, wx) + wy[3] * _row(flat, zb + yt[3], xt, wx))
    return acc


@njit(cache=True)
def _cell_taps(nx, ny, nz, ix, iy, iz):
    """Per-axis flat tap offsets around cell ``(ix, iy, iz)``."""
    return _taps(ix, nx, 1), _taps(iy, ny, nx), _taps(iz, nz, nx * ny)


@njit(cache=True)
def _cell_of(u, n):
    """Cell index and fraction of a voxel coordinate ``u`` in ``[0, n - 1]`` (the last cell takes ``u = n - 1``)."""
    i = min(int(u), n - 2)
    return i, u - i


@njit(cache=True)
def tricubic_sample(flat, nx, ny, nz, ux, uy, uz):
    """The cubic B-spline field of the raw scalars at voxel coordinates ``(ux, uy, uz)`` (each in ``[0, n - 1]``).

    ``flat``: the ``(nz, ny, nx)`` volume raveled. The approximating B-spline (no prefilter): a C2 field, a
    convex combination of the 4^3 voxels around the sample (so it stays within their range), which reproduces
    constant and linear data exactly and smooths the rest slightly (a voxel's own value is
    ``(v[i-1] + 4 v[i] + v[i+1]) / 6`` per axis).
    """
    ix, fx = _cell_of(ux, nx)
    iy, fy = _cell_of(uy, ny)
    iz, fz = _cell_of(uz, nz)
    xt, yt, zt = _cell_taps(nx, ny, nz, ix, iy, iz)
    return _bspline_sum(flat, xt, yt, zt, _bspline_weights(fx), _bspline_weights(fy), _bspline_weights(fz))


@njit(cache=True)
def tricubic_gradient(flat, nx, ny, nz, ux, uy, uz):
    """The exact gradient ``(d/dux, d/duy, d/duz)`` of :func:`tricubic_sample`'s field (per voxel, not per spacing)."""
    ix, fx = _cell_of(ux, nx)
    iy, fy = _cell_of(uy, ny)
    iz, fz = _cell_of(uz, nz)
    xt, yt, zt = _cell_taps(nx, ny, nz, ix, iy, iz)
    return _bspline_gradient(flat, xt, yt, zt, fx, fy, fz)


@njit(cache=True)
def _bspline_gradient(flat, xt, yt, zt, fx, fy, fz):
    """Gradient of the B-spline at fractions ``(fx, fy, fz)`` of the cell whose taps are ``xt, yt, zt``: the same
    64 voxels, weighted by the slopes along one axis and the weights along the others."""
    wx = _bspline_weights(fx)
    wy = _bspline_weights(fy)
    wz = _bspline_weights(fz)
    return (_bspline_sum(flat, xt, yt, zt, _bspline_slopes(fx), wy, wz),
            _bspline_sum(flat, xt, yt, zt, wx, _bspline_slopes(fy), wz),
            _bspline_sum(flat, xt, yt, zt, wx, wy, _bspline_slopes(fz)))


@njit(parallel=True, cache=True)
def _cast(flat, nx, ny, nz, pixels, m, eye, fwd, right, up, tan_half, near, far,
          origin, spacing, sample_distance, lut, vmin, inv_range, int_index, dmin, tricubic,
          shade, ka, kd, ks, spow, edge2, zero_tol,
          bricks, bg, out, marched):
    """Cast the rays of ``pixels`` (flat raster indices of an ``m x m`` image) into ``out (K, 3)``.

    ``marched[i]`` is 0 for rays that miss the volume's box (background), else 1 + the samples the ray
    interpolated: the ray's cost in the unit that dominates it (a skipped brick costs one step, not a sample).
    ``tricubic``: ``None`` for trilinear (a None-typed argument lets numba prune the tricubic branches at compile
    time: the trilinear kernel is the one before the option, and as fast), ``True`` to sample the cubic B-spline field and shade each sample from its gradient (:func:`tricubic_sample`)
    instead of the trilinear scalars and the corners' shading.
    """
    nlut = lut.shape[0]
    # VTK clips rays against the voxel-centre box inset by 0.01 voxel on every face
    dims = (nx, ny, nz)
    bmin = np.empty(3)
    bmax = np.empty(3)
    for a in range(3):
        bmin[a] = origin[a] + 0.01 * spacing[a]
        bmax[a] = origin[a] + (dims[a] - 1 - 0.01) * spacing[a]
    isx = 1.0 / spacing[0]
    isy = 1.0 / spacing[1]
    isz = 1.0 / spacing[2]
    # per-axis gradient scale: VTK divides the differences by the (relative) spacing
    gsx = 1.0 / spacing[0]
    gsy = 1.0 / spacing[1]
    gsz = 1.0 / spacing[2]
    plane = nx * ny
    for i in prange(pixels.shape[0]):
        dx, dy, dz = _ray_dir(pixels[i], m, fwd, right, up, tan_half)
        cosa = dx * fwd[0] + dy * fwd[1] + dz * fwd[2]
        t_near = near / cosa
        t0, t1 = _slab(eye[0], eye[1], eye[2], dx, dy, dz, bmin, bmax)
        t0 = max(t0, t_near, 0.0)
        t1 = min(t1, far / cosa)
        # ... and then pulls both ends in by 0.1% of the segment
        seg = t1 - t0
        t0 += 0.001 * seg
        t1 -= 0.001 * seg
        if not (t1 > t0):
            marched[i] = 0
            for c in range(3):
                out[i, c] = np.uint8(math.floor(bg[c] * 255.0 + 0.5))
            continue
        samples = 0  # counted in a register: an array write per sample would sit in the innermost loop
        # samples sit on the grid t_near + k * sample_distance (VTK anchors them at the near plane)
        k = math.floor((t0 - t_near) / sample_distance) + 1
        acc_r = 0.0
        acc_g = 0.0
        acc_b = 0.0
        rem = 1.0
        cx = -1
        cy = -1
        cz = -1
        d0 = d1 = d2 = d3 = d4 = d5 = d6 = d7 = 0.0
        s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = 0.0
        w000 = w100 = w010 = w110 = w001 = w101 = w011 = w111 = 0.0  # trilinear weights (tricubic: unused)
        xt = yt = zt = (0, 0, 0, 0)  # tricubic taps (trilinear: unused)
        # the ray in voxel coordinates: u(t) = o + t * v
        ox = (eye[0] - origin[0]) * isx
        oy = (eye[1] - origin[1]) * isy
        oz = (eye[2] - origin[2]) * isz
        vx = dx * isx
        vy = dy * isy
        vz = dz * isz
        while True:
            t = t_near + k * sample_distance
            if t > t1:
                break
            ux = ox + t * vx
            uy = oy + t * vy
            uz = oz + t * vz
            ux = min(max(ux, 0.0), nx - 1.0)
            uy = min(max(uy, 0.0), ny - 1.0)
            uz = min(max(uz, 0.0), nz - 1.0)
            ix = min(int(ux), nx - 2)
            iy = min(int(uy), ny - 2)
            iz = min(int(uz), nz - 2)
            bx = ix >> BRICK_SHIFT  # a compile-time shift, not an integer division
            by = iy >> BRICK_SHIFT
            bz = iz >> BRICK_SHIFT
            dist = bricks[bz, by, bx]
            if dist:
                # every brick within Chebyshev distance dist - 1 is exactly transparent: jump to
                # the first grid sample past that block of bricks
                rr = dist - 1
                hx0 = origin[0] + max(bx - rr, 0) * BRICK * spacing[0]
                hx1 = origin[0] + min((bx + rr + 1) * BRICK, nx - 1) * spacing[0]
                hy0 = origin[1] + max(by - rr, 0) * BRICK * spacing[1]
                hy1 = origin[1] + min((by + rr + 1) * BRICK, ny - 1) * spacing[1]
                hz0 = origin[2] + max(bz - rr, 0) * BRICK * spacing[2]
                hz1 = origin[2] + min((bz + rr + 1) * BRICK, nz - 1) * spacing[2]
                texit = np.inf
                if dx > 0.0:
                    texit = min(texit, (hx1 - eye[0]) / dx)
                elif dx < 0.0:
                    texit = min(texit, (hx0 - eye[0]) / dx)
                if dy > 0.0:
                    texit = min(texit, (hy1 - eye[1]) / dy)
                elif dy < 0.0:
                    texit = min(texit, (hy0 - eye[1]) / dy)
                if dz > 0.0:
                    texit = min(texit, (hz1 - eye[2]) / dz)
                elif dz < 0.0:
                    texit = min(texit, (hz0 - eye[2]) / dz)
                kn = math.floor((texit - t_near) / sample_distance) + 1
                k = kn if kn > k else k + 1
                continue
            k += 1
            samples += 1
            fx = ux - ix
            fy = uy - iy
            fz = uz - iz
            base = iz * plane + iy * nx + ix
            if tricubic is not None:
                # no VTK counterpart, so no fixed-point rounding of integer data either: the smooth value
                xt, yt, zt = _cell_taps(nx, ny, nz, ix, iy, iz)
                v = _bspline_sum(flat, xt, yt, zt, _bspline_weights(fx), _bspline_weights(fy), _bspline_weights(fz))
            else:
                v000, v100, v010, v110, v001, v101, v011, v111 = _cell_corners(flat, base, nx, plane)
                gx_ = 1.0 - fx
                gy_ = 1.0 - fy
                gz_ = 1.0 - fz
                w000 = gx_ * gy_ * gz_
                w100 = fx * gy_ * gz_
                w010 = gx_ * fy * gz_
                w110 = fx * fy * gz_
                w001 = gx_ * gy_ * fz
                w101 = fx * gy_ * fz
                w011 = gx_ * fy * fz
                w111 = fx * fy * fz
                v = (v000 * w000 + v100 * w100 + v010 * w010 + v110 * w110
                     + v001 * w001 + v101 * w101 + v011 * w011 + v111 * w111)
                if int_index:
                    # VTK indexes its tables of small-range integer data by the interpolated value
                    # in 15-bit fixed point, rounded up (its weights sum to 32765/32768)
                    v = dmin + math.floor(((v - dmin) * 32765.0 + 32767.0) / 32768.0)
            s = (v - vmin) * inv_range
            s = min(max(s, 0.0), 1.0) * (nlut - 1)
            j = min(int(s), nlut - 2)
            w = s - j
            a = lut[j, 3] + w * (lut[j + 1, 3] - lut[j, 3])
            if a <= 0.0:
                continue
            r = lut[j, 0] + w * (lut[j + 1, 0] - lut[j, 0])
            g = lut[j, 1] + w * (lut[j + 1, 1] - lut[j, 1])
            b = lut[j, 2] + w * (lut[j + 1, 2] - lut[j, 2])
            if shade:
                if tricubic is not None:
                    # the exact gradient of the B-spline field at the sample, from the same 64 voxels, in VTK's
                    # normal convention (v[x-1] - v[x+1] per axis, about -2 x the derivative, over the spacing)
                    gx, gy, gz = _bspline_gradient(flat, xt, yt, zt, fx, fy, fz)
                    dd, ss = _shade_from_grad(-2.0 * gx * gsx, -2.0 * gy * gsy, -2.0 * gz * gsz, zero_tol,
                                              fwd[0], fwd[1], fwd[2], ka, kd, ks, spow)
                else:
                    if ix != cx or iy != cy or iz != cz:
                        # the shading of the 8 corner normals, reused while the ray stays in this cell
                        cx = ix
                        cy = iy
                        cz = iz
                        if 0 < ix < nx - 2 and 0 < iy < ny - 2 and 0 < iz < nz - 2:
                            (d0, d1, d2, d3, d4, d5, d6, d7, s0, s1, s2, s3, s4, s5, s6, s7) = _cell_shade_interior(
                                flat, base, nx, plane, gsx, gsy, gsz, zero_tol, fwd[0], fwd[1], fwd[2], ka, kd, ks, spow)
                        else:
                            d0, s0 = _corner_shade(flat, ix, iy, iz, nx, ny, nz, gsx, gsy, gsz, edge2, zero_tol, fwd[0], fwd[1], fwd[2], ka, kd, ks, spow)
                            d1, s1 = _corner_shade(flat, ix + 1, iy, iz, nx, ny, nz, gsx, gsy, gsz, edge2, zero_tol, fwd[0], fwd[1], fwd[2], ka, kd, ks, spow)
                            d2, s2 = _corner_shade(flat, ix, iy + 1, iz, nx, ny, nz, gsx, gsy, gsz, edge2, zero_tol, fwd[0], fwd[1], fwd[2], ka, kd, ks, spow)
                            d3, s3 = _corner_shade(flat, ix + 1, iy + 1, iz, nx, ny, nz, gsx, gsy, gsz, edge2, zero_tol, fwd[0], fwd[1], fwd[2], ka, kd, ks, spow)
                            d4, s4 = _corner_shade(flat, ix, iy, iz + 1, nx, ny, nz, gsx, gsy, gsz, edge2, zero_tol, fwd[0], fwd[1], fwd[2], ka, kd, ks, spow)
                            d5, s5 = _corner_shade(flat, ix + 1, iy, iz + 1, nx, ny, nz, gsx, gsy, gsz, edge2, zero_tol, fwd[0], fwd[1], fwd[2], ka, kd, ks, spow)
                            d6, s6 = _corner_shade(flat, ix, iy + 1, iz + 1, nx, ny, nz, gsx, gsy, gsz, edge2, zero_tol, fwd[0], fwd[1], fwd[2], ka, kd, ks, spow)
                            d7, s7 = _corner_shade(flat, ix + 1, iy + 1, iz + 1, nx, ny, nz, gsx, gsy, gsz, edge2, zero_tol, fwd[0], fwd[1], fwd[2], ka, kd, ks, spow)
                    dd = (d0 * w000 + d1 * w100 + d2 * w010 + d3 * w110
                          + d4 * w001 + d5 * w101 + d6 * w011 + d7 * w111)
                    ss = (s0 * w000 + s1 * w100 + s2 * w010 + s3 * w110
                          + s4 * w001 + s5 * w101 + s6 * w011 + s7 * w111)
                r = dd * r + ss
                g = dd * g + ss
                b = dd * b + ss
            wgt = a * rem
            acc_r += r * wgt
            acc_g += g * wgt
            acc_b += b * wgt
            rem *= 1.0 - a
            if rem < TERMINATION:
                break
        marched[i] = 1 + samples
        # premultiplied colour over the background (VTK clamps the colour to 1 first)
        out[i, 0] = np.uint8(math.floor(min(min(acc_r, 1.0) + rem * bg[0], 1.0) * 255.0 + 0.5))
        out[i, 1] = np.uint8(math.floor(min(min(acc_g, 1.0) + rem * bg[1], 1.0) * 255.0 + 0.5))
        out[i, 2] = np.uint8(math.floor(min(min(acc_b, 1.0) + rem * bg[2], 1.0) * 255.0 + 0.5))


# ------------------------------------------------------------------------------------------------
# the renderer object
# ------------------------------------------------------------------------------------------------
def check_interpolation(interpolation) -> str:
    """``renderer.interpolation`` validated: one of :data:`INTERPOLATIONS`."""
    if not (isinstance(interpolation, str) and interpolation in INTERPOLATIONS):
        raise InputError(f"renderer.interpolation={interpolation!r}: expected one of {', '.join(INTERPOLATIONS)} "
                         "(renderer=numba; renderer=vtk interpolates trilinearly only)")
    return interpolation


def transfer_lut(scene: Scene, size: int = LUT_SIZE) -> np.ndarray:
    """``(size, 4)`` float64 table over normalized scalars: colour and *sample* opacity.

    The opacity is corrected for the sample distance (VTK corrects entries above 1e-4 only).
    """
    tf = scene.transfer_function
    x = np.linspace(0.0, 1.0, size)
    a = tf.alpha(x)
    factor = float(scene.sample_distance) / float(scene.opacity_unit_distance)
    a = np.where(a > 1e-4, 1.0 - np.power(np.clip(1.0 - a, 0.0, 1.0), factor), a)
    return np.ascontiguousarray(np.concatenate([tf.rgb(x), a[:, None]], axis=1), dtype=np.float64)


class NumbaRenderer:
    """Compiled CPU ray caster with VTK's scene model; casts any subset of a frame's rays.

    Args:
        scene: what to render.
        threads: CPU threads (``0``: all of numba's threads, i.e. every core).
        warmup: compile (or load from numba's on-disk cache) in the constructor, so that no
            render call pays for compilation.
        skip_empty: jump over bricks the transfer function makes exactly transparent (default). False marches
            every sample inside the volume's box, as a ray caster without empty-space skipping does (the paper's
            regime, where a background ray inside the box costs as much as an object ray, or more): the same
            pixels, other costs.
        interpolation: ``"trilinear"`` (default; VTK's) or ``"tricubic"``: the cubic B-spline filter evaluated
            directly over the 4^3 voxels around each sample (:func:`tricubic_sample`), shaded per sample from the
            spline's exact gradient. The direct 64-tap form rather than Sigg & Hadwiger's 8 trilinear fetches
            (GPU Gems 2, ch. 20): that trick saves work only where a texture unit filters for free; on a CPU each
            fetch is 8 reads and 7 lerps anyway, and the direct form gets the gradient from the same 64 voxels with
            the weights' derivatives. The lighting is the trilinear path's (VTK's headlight, two-sided, the same
            normal convention and zero tolerance), evaluated at the sample rather than interpolated from the cell
            corners' central differences (those would bring back the trilinear facets). Clamped at the volume's
            faces like the trilinear path; small-range integer data are not rounded to VTK's fixed-point table
            index (VTK has no tricubic mode to match). A smoother, slightly blurred picture (the approximating
            spline, no prefilter) at about 2.5 times the cost per object sample (docs/GUIDE.md).

    Attributes:
        last_render_seconds: wall time of the last compiled ray-casting call.
        last_rays_marched: rays of the last call that reached the volume's box (the others got
            the background without being marched).
        last_ray_samples: ``(K,)`` int32, per pixel of the last call in order: 0 for a ray that missed the box,
            else 1 + the samples it interpolated (its cost with skipping and early termination; the
            cost-aware masks of :mod:`imls_lightning.estimate.pixel_cost` read it).

    Example:
        >>> r = NumbaRenderer(scene)                                    # doctest: +SKIP
        >>> view = [0, 0, 3, 0, 0, 0, 0, 1, 0]
        >>> full = r.render(view, 64)                                   # (64, 64, 3) uint8
        >>> px = np.array([0, 2080, 4095])
        >>> (r.render_pixels(view, 64, px) == full.reshape(-1, 3)[px]).all()
        True
    """

    name = "numba"

    def __init__(self, scene: Scene, threads: int = 0, warmup: bool = True, skip_empty: bool = True,
                 interpolation: str = "trilinear"):
        self.scene = scene
        if not isinstance(skip_empty, bool):
            raise InputError(f"renderer.skip_empty={skip_empty!r}: expected true or false (empty-space skipping)")
        self.skip_empty = skip_empty
        self.interpolation = check_interpolation(interpolation)
        self.threads = check_integer(threads, "renderer.threads", 0, what="an integer >= 0 (0 = all cores)")
        vol = scene.volume
        data = vol.data
        if not (isinstance(data, np.ndarray) and data.flags.c_contiguous):
            data = np.ascontiguousarray(data)
        # a plain, read-only ndarray view of the (possibly memory-mapped) raw scalars: never a
        # float copy; always read-only so that numba compiles one kernel per dtype, not two
        self._flat = data.reshape(-1).view(np.ndarray)
        self._flat.flags.writeable = False
        if self._flat.dtype.kind not in "iuf" or self._flat.dtype.itemsize > 8 or self._flat.dtype == np.float16:
            raise InputError(f"volume '{vol.name}': dtype {self._flat.dtype} is not supported by renderer=numba "
                             "(expected an 8-64 bit integer, float32 or float64)")
        if not self._flat.dtype.isnative:
            raise InputError(f"volume '{vol.name}': non-native byte order {self._flat.dtype.str} (the readers convert it)")
        self._nx, self._ny, self._nz = (int(d) for d in vol.dims)
        self._origin = np.asarray(vol.origin, np.float64)
        self._spacing = np.asarray(vol.normalized_spacing, np.float64)
        self._bounds = np.stack([self._origin, self._origin + (np.asarray(vol.dims) - 1) * self._spacing], axis=1)
        lo, hi = vol.value_range
        self._vmin = float(lo)
        self._inv_range = 1.0 / float(hi - lo)
        self._lut = transfer_lut(scene)
        sh = scene.shading
        self._shade = bool(sh.enabled)
        self._ka, self._kd, self._ks, self._spow = (float(sh.ambient), float(sh.diffuse),
                                                    float(sh.specular), float(sh.specular_power))
        # VTK's gradient code: 8/16-bit integers clamp at the faces; other types use one-sided
        # differences doubled and treat gradients below 1e-5 of the data range as zero
        self._edge2 = self._flat.dtype not in (np.uint8, np.int8, np.uint16, np.int16)
        self._zero_tol = 1e-5 * float(hi - lo) if self._edge2 else 0.0
        self._bg = np.asarray(scene.background, np.float64)
        self._bricks = self._build_bricks()
        self._all_pixels: dict[int, np.ndarray] = {}
        self.last_render_seconds = 0.0
        self.last_rays_marched = 0
        self.last_ray_samples = np.zeros(0, np.int32)
        self.warmup_seconds = 0.0
        if warmup:
            t0 = time.perf_counter()
            self.render_pixels([0.0, 0.0, 4.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0], 8, np.array([27], np.int64))
            self.warmup_seconds = time.perf_counter() - t0

    def _build_bricks(self) -> np.ndarray:
        nx, ny, nz = self._nx, self._ny, self._nz
        shape = (-(-(nz - 1) // BRICK), -(-(ny - 1) // BRICK), -(-(nx - 1) // BRICK))
        bmin = np.empty(shape, np.float64)
        bmax = np.empty(shape, np.float64)
        # the B-spline reads one voxel beyond the cell on each side
        _brick_minmax(self._flat, nx, ny, nz, BRICK, 1 if self.interpolation == "tricubic" else 0, bmin, bmax)
        # VTK's tables for integer data spanning < 32768 values hold one entry per integer from
        # the data minimum; other data are scaled to 32768 entries (fine enough to ignore)
        self._dmin = float(bmin.min())
        self._int_index = self._flat.dtype.kind in "iu" and float(bmax.max()) - self._dmin <= 32767.0
        # the fixed-point rounding can move an integer sample by one unit: widen the brick ranges
        pad = 1.0 if self._int_index else 0.0
        self._transparent = transparent_bricks(bmin - pad, bmax + pad, self.scene.volume.value_range, self._lut[:, 3])
        if not self.skip_empty:  # distance 0 everywhere: every brick is sampled
            return np.zeros(self._transparent.shape, np.uint8)
        return skip_distance(self._transparent)

    @property
    def transparent_brick_fraction(self) -> float:
        """Share of the 8^3 bricks skipped as exactly transparent under the transfer function."""
        return float(self._transparent.mean())

    def clipping_range(self, view) -> tuple[float, float]:
        """The near/far planes VTK would use for this view (see :func:`clipping_range`)."""
        return clipping_range(view, self._bounds, self.scene.view_angle)

    def _run(self, view, m: int, pixels: np.ndarray) -> np.ndarray:
        eye, f, r, u = camera_basis(view)
        near, far = self.clipping_range(view)
        out = np.empty((pixels.shape[0], 3), np.uint8)
        marched = np.empty(pixels.shape[0], np.int32)
        old_threads = numba.get_num_threads()
        n = min(self.threads, numba.config.NUMBA_NUM_THREADS) if self.threads else numba.config.NUMBA_NUM_THREADS
        numba.set_num_threads(n)
        old_chunk = numba.set_parallel_chunksize(CHUNK)
        try:
            t0 = time.perf_counter()
            _cast(self._flat, self._nx, self._ny, self._nz, pixels, m, eye, f, r, u,
                  math.tan(math.radians(float(self.scene.view_angle)) / 2.0), near, far,
                  self._origin, self._spacing, float(self.scene.sample_distance), self._lut,
                  self._vmin, self._inv_range, self._int_index, self._dmin,
                  True if self.interpolation == "tricubic" else None, self._shade, self._ka, self._kd, self._ks, self._spow,
                  self._edge2, self._zero_tol, self._bricks, self._bg, out, marched)
            self.last_render_seconds = time.perf_counter() - t0
        finally:
            numba.set_parallel_chunksize(old_chunk)
            numba.set_num_threads(old_threads)
        self.last_rays_marched = int(np.count_nonzero(marched))
        self.last_ray_samples = marched
        return out

    def render(self, view, resolution: int) -> np.ndarray:
        """Full frame ``(m, m, 3)`` uint8, row 0 at the top."""
        _, m, _ = render_request(view, resolution)
        pix = self._all_pixels.get(m)
        if pix is None:
            pix = self._all_pixels.setdefault(m, np.arange(m * m, dtype=np.int64))
        return self._run(view, m, pix).reshape(m, m, 3)

    def render_pixels(self, view, resolution: int, pixels) -> np.ndarray:
        """Colours ``(K, 3)`` uint8 of the flat raster indices ``pixels`` (int, ``(K,)``), in order.

        Only those rays are cast; the result equals ``render(view, resolution)`` at those pixels
        exactly. An empty ``pixels`` returns ``(0, 3)`` at once.
        """
        _, m, pix = render_request(view, resolution, pixels)
        if pix.shape[0] == 0:
            self.last_render_seconds = 0.0
            self.last_rays_marched = 0
            self.last_ray_samples = np.zeros(0, np.int32)
            return np.zeros((0, 3), np.uint8)
        return self._run(view, m, pix)

    def close(self) -> None:  # same interface as VTKRenderer
        pass


__all__ = ["NumbaRenderer", "INTERPOLATIONS", "check_interpolation", "tricubic_sample", "tricubic_gradient", "clipping_range", "ray_hit_mask", "transfer_lut",
           "transparent_bricks", "skip_distance", "LUT_SIZE", "BRICK", "TERMINATION"]
