"""The orbit camera both viewers use: a view from angles, turning, zooming, and the frame PSNR.

One home for the camera math of the desktop viewer (:mod:`imls_lightning.viewer`) and the browser
viewer (:mod:`imls_lightning.web`).
"""
from __future__ import annotations

import math

import numpy as np
import torch

from imls_lightning.render.camera import validate_view
from imls_lightning.base.errors import InputError, finite_number
from data_gen.views import orthogonal_up, unit_vectors

MAX_ELEVATION = 89.0           # degrees; at 90 the +z up vector would be parallel to the view
ZOOM_STEP = 0.9                # distance factor per scroll step (in)
DEFAULT_DISTANCE_RANGE = (2.5, 4.0)


def orbit_view(azimuth: float, elevation: float, distance: float, lookat=(0.0, 0.0, 0.0)) -> np.ndarray:
    """The view of a camera orbiting ``lookat``: 9 floats ``(eye, lookAt, up)``.

    Args:
        azimuth: degrees around the z axis, from +x towards +y (any finite number).
        elevation: degrees above the xy plane, in ``[-89, 89]``.
        distance: eye to ``lookat`` (> 0).
        lookat: the point looked at (the volume centre is the origin).

    Returns:
        ``(9,)`` float64, validated; ``up`` is +z made orthogonal to the view direction (unit).

    Raises:
        InputError: non-finite angles, elevation outside +-89 degrees, or distance <= 0.

    Example:
        >>> np.round(orbit_view(0, 0, 3.0), 6).tolist()
        [3.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
    """
    az, el, r = (finite_number(v, k, "a finite number") for v, k in ((azimuth, "azimuth"), (elevation, "elevation"), (distance, "distance")))
    if abs(el) > MAX_ELEVATION:
        raise InputError(f"elevation={elevation}: expected degrees in [-{MAX_ELEVATION:g}, {MAX_ELEVATION:g}] (the up vector is +z)")
    if r <= 0:
        raise InputError(f"distance={distance}: expected a positive camera distance")
    a, e = math.radians(az), math.radians(el)
    look = np.asarray(lookat, dtype=np.float64).reshape(3)
    eye = look + r * np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
    # the same up convention as the test trajectory (data_gen.views): +z, Gram-Schmidt against the view direction
    fwd = unit_vectors((look - eye)[None])
    up = orthogonal_up(fwd, np.array([[0.0, 0.0, 1.0]]))[0]
    return validate_view(np.concatenate([eye, look, up]))


def frame_psnr(image: np.ndarray, truth: np.ndarray) -> float:
    """PSNR in dB of two ``(m, m, 3)`` uint8 images (100 dB when identical), as the evaluation scores it."""
    from ..core.metrics import psnr

    p = torch.from_numpy(np.array(image)).permute(2, 0, 1)[None].float()
    t = torch.from_numpy(np.array(truth)).permute(2, 0, 1)[None].float()
    return float(psnr(p, t, data_range=255.0))


def turned(azimuth: float, elevation: float, d_azimuth: float, d_elevation: float) -> tuple[float, float]:
    """The angles after turning by ``(d_azimuth, d_elevation)`` degrees: azimuth wrapped to
    ``[-180, 180)``, elevation clamped to +-89.

    Example:
        >>> turned(170.0, 80.0, 20.0, 20.0)
        (-170.0, 89.0)
    """
    az = (float(azimuth) + float(d_azimuth) + 180.0) % 360.0 - 180.0
    return az, float(np.clip(float(elevation) + float(d_elevation), -MAX_ELEVATION, MAX_ELEVATION))


def zoomed(distance: float, steps: float, distance_range: tuple[float, float]) -> float:
    """The distance after ``steps`` scroll steps (positive: in): times ``0.9 ** steps``, clamped to
    ``distance_range``.

    Example:
        >>> round(zoomed(3.0, 1, (2.5, 4.0)), 6), zoomed(3.0, -10, (2.5, 4.0))
        (2.7, 4.0)
    """
    lo, hi = distance_range
    return float(np.clip(float(distance) * ZOOM_STEP ** float(steps), lo, hi))


class OrbitCamera:
    """The camera of a viewer, as a mixin: the class sets ``azimuth``, ``elevation``, ``distance``
    (degrees, degrees, normalized units), ``home`` (the start triple) and ``distance_range``."""

    azimuth: float
    elevation: float
    distance: float
    home: tuple[float, float, float]
    distance_range: tuple[float, float]

    def view(self) -> np.ndarray:
        """The current view, 9 floats ``(eye, lookAt, up)``."""
        return orbit_view(self.azimuth, self.elevation, self.distance)

    def orbit(self, d_azimuth: float, d_elevation: float) -> None:
        """Turn the camera (degrees); elevation is clamped to +-89, azimuth wrapped to [-180, 180)."""
        self.azimuth, self.elevation = turned(self.azimuth, self.elevation, d_azimuth, d_elevation)

    def zoom(self, steps: float) -> None:
        """Scroll ``steps`` (positive: in): distance times ``0.9 ** steps``, clamped to the scene's range."""
        self.distance = zoomed(self.distance, steps, self.distance_range)

    def reset(self) -> None:
        """Back to the start camera."""
        self.azimuth, self.elevation, self.distance = self.home
