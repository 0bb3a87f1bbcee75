"""Views and the perspective camera model shared by every renderer.

A *view* is 9 floats ``(eye_xyz, lookAt_xyz, up_xyz)`` in the normalized space (OpenGL
convention). The camera is a perspective pinhole with vertical view angle ``view_angle`` (degrees,
as VTK's ``vtkCamera.SetViewAngle``) and square images. Image pixels are addressed in raster order
with row 0 at the *top*: flat index ``p = row * width + col``.
"""
from __future__ import annotations

import numpy as np

from imls_lightning.base.errors import InputError
from imls_lightning.base.validate import check_integer

VIEW_FIELDS = ("eye_x", "eye_y", "eye_z", "lookat_x", "lookat_y", "lookat_z", "up_x", "up_y", "up_z")


def validate_view(view, *, name: str = "view") -> np.ndarray:
    """Check a view and return it as a float64 array of shape ``(9,)``.

    Raises:
        InputError: wrong shape, non-finite numbers, eye == lookAt, or up parallel to the view
            direction.

    Example:
        >>> validate_view([0, 0, 3, 0, 0, 0, 0, 1, 0]).shape
        (9,)
    """
    v = np.asarray(view, dtype=np.float64)
    if v.shape != (9,):
        raise InputError(f"{name}: expected 9 floats (eye_xyz, lookAt_xyz, up_xyz), got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise InputError(f"{name}: contains non-finite numbers {v.tolist()}")
    eye, look, up = v[0:3], v[3:6], v[6:9]
    d = look - eye
    dn = np.linalg.norm(d)
    if dn < 1e-9:
        raise InputError(f"{name}: eye == lookAt ({eye.tolist()}): the view direction is undefined")
    un = np.linalg.norm(up)
    if un < 1e-9:
        raise InputError(f"{name}: up vector is zero")
    if np.linalg.norm(np.cross(d / dn, up / un)) < 1e-6:
        raise InputError(f"{name}: up {up.tolist()} is parallel to the view direction {(d / dn).tolist()}")
    return v


def view_tensor(views, device=None):
    """Views as the networks' input: the one home of view -> tensor.

    Args:
        views: one view, 9 numbers ``(eye_xyz, lookAt_xyz, up_xyz)`` (shape ``(9,)``), or a batch of
            them, shape ``(B, 9)``: a list, a numpy array (the cache's read-only memory maps too) or a
            tensor. Not validated (:func:`validate_view` checks one view's geometry).
        device: where the tensor goes; ``None``: the CPU for an array, a tensor's own device for a tensor.

    Returns:
        A float32 tensor of shape ``(B, 9)`` (``(1, 9)`` for one view), rounded from float64 to float32
        as numpy and torch both round (to nearest). An array is copied (torch warns on read-only
        memory); a tensor already float32 on ``device`` comes back as itself (reshaped for one view).

    Raises:
        InputError: the shape is neither ``(9,)`` nor ``(B, 9)``.

    Example:
        >>> view_tensor([0, 0, 3.5, 0, 0, 0, 0, 1, 0]).shape
        torch.Size([1, 9])
    """
    import torch  # deferred: the ray casters do not need torch

    if isinstance(views, torch.Tensor):
        v = views.to(device=device if device is not None else views.device, dtype=torch.float32)
    else:
        v = torch.from_numpy(np.array(views, np.float32))
        v = v if device is None else v.to(device)
    if v.dim() == 1:
        v = v[None]
    if v.dim() != 2 or v.shape[1] != 9:
        raise InputError(f"views: expected one view (9,) or a batch (B, 9) of (eye, lookAt, up), got shape {tuple(v.shape)}")
    return v


def camera_basis(view) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Return ``(eye, forward, right, up)``: unit vectors of the camera frame (right-handed,
    ``right = forward x up``, ``up`` re-orthogonalized as VTK's ``OrthogonalizeViewUp`` does)."""
    v = validate_view(view)
    eye, look, up = v[0:3], v[3:6], v[6:9]
    f = look - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    return eye, f, r, u


def pixel_rays(view, resolution: int, view_angle: float, pixels: np.ndarray | None = None):
    """Primary rays through pixel centres.

    Args:
        view: 9 floats.
        resolution: image side ``m`` (square images).
        view_angle: vertical field of view in degrees.
        pixels: flat raster indices ``(K,)`` (row 0 at the top); ``None`` means all ``m*m``.

    Returns:
        ``(origin, directions)``: origin ``(3,)`` float64 and unit directions ``(K, 3)`` float64.
    """
    if int(resolution) <= 0:
        raise InputError(f"resolution={resolution}: expected a positive integer")
    if not (0.0 < float(view_angle) < 180.0):
        raise InputError(f"view_angle={view_angle}: expected degrees in (0, 180)")
    m = int(resolution)
    eye, f, r, u = camera_basis(view)
    if pixels is None:
        pixels = np.arange(m * m, dtype=np.int64)
    pixels = np.asarray(pixels, dtype=np.int64)
    row, col = np.divmod(pixels, m)
    t = np.tan(np.deg2rad(float(view_angle)) / 2.0)
    x = (2.0 * (col + 0.5) / m - 1.0) * t
    y = (1.0 - 2.0 * (row + 0.5) / m) * t
    d = f[None, :] + x[:, None] * r[None, :] + y[:, None] * u[None, :]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return eye, d


def ray_box_hits(origin: np.ndarray, dirs: np.ndarray, bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Slab test: entry/exit distances ``(t0, t1)`` of rays against an axis-aligned box.

    ``bounds`` is ``[[xmin, xmax], [ymin, ymax], [zmin, zmax]]``; a ray misses when ``t1 <= t0``.
    ``t0`` is clamped at 0 (the camera may sit inside the box).
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / dirs
        ta = (bounds[:, 0][None, :] - origin[None, :]) * inv
        tb = (bounds[:, 1][None, :] - origin[None, :]) * inv
    tmin = np.nan_to_num(np.minimum(ta, tb), nan=-np.inf)
    tmax = np.nan_to_num(np.maximum(ta, tb), nan=np.inf)
    t0 = np.maximum(tmin.max(axis=1), 0.0)
    t1 = tmax.min(axis=1)
    return t0, t1


def render_request(view, resolution, pixels=None) -> tuple[np.ndarray, int, np.ndarray | None]:
    """The validated arguments of a renderer's ``render`` / ``render_pixels`` call, checked alike
    by every renderer: ``(view (9,) float64, m, pixels int64 (K,) or None)``.

    Raises:
        InputError: a bad view (:func:`validate_view`), a resolution that is not a positive
            integer, or bad pixel indices (:func:`validate_pixels`).

    Example:
        >>> v, m, pix = render_request([0, 0, 3, 0, 0, 0, 0, 1, 0], 4, [0, 15])
        >>> m, pix.tolist()
        (4, [0, 15])
    """
    v = validate_view(view)
    m = check_integer(resolution, "resolution", 1, strict=True, what="a positive integer")
    return v, m, None if pixels is None else validate_pixels(pixels, m)


def validate_pixels(pixels, resolution: int, *, name: str = "pixels") -> np.ndarray:
    """Check flat raster pixel indices of an ``m x m`` image and return them as int64 ``(K,)``.

    Any integer dtype is accepted; the order is kept and duplicates are allowed.

    Raises:
        InputError: not one-dimensional, not integers (floats and booleans are refused: use
            ``np.flatnonzero(mask.ravel())`` for a boolean mask), or outside ``[0, m*m)``.

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
