"""A *scene*: volume + transfer function + shading + sampling + background + camera ranges.

Every renderer (VTK's and the project's own) takes a :class:`Scene`, so a scene is all that decides
the pixels besides the view and the resolution. Transfer-function positions are in *normalized*
scalar units [0, 1] (see :class:`imls_lightning.render.volume.Volume`). A scene is built from the
``scene`` config node by :func:`data_gen.scenes.build_scene`.

Sample distance (:func:`resolve_sample_distance`, the one home of the rule): ``sample_distance:
auto`` (the default) is half a voxel, where one *voxel* is the smallest voxel spacing
(:func:`voxel_size`). This follows VTK's ``LockSampleDistanceToInputSpacing`` (which reaches half the
*average* spacing for volumes of 1e6 voxels and more); the smallest spacing keeps anisotropic
volumes sampled at least twice per voxel along every axis. An explicit ``sample_distance`` is a
length in normalized units (the volume's longest physical axis spans [-1, 1]); ``sample_distance_voxels``
gives it in voxels instead. A :class:`Scene` always holds the resolved length in normalized units.

Opacity model (shared by all renderers): the opacity ``a`` read from the transfer function is the
opacity of a slab of thickness ``opacity_unit_distance`` (normalized units); a ray sample taken every
``sample_distance`` gets ``1 - (1 - a) ** (sample_distance / opacity_unit_distance)`` (VTK's
``ScalarOpacityUnitDistance``), so a finer sampling does not make the volume more opaque.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from imls_lightning.base.errors import InputError
from .volume import Volume


def _points(name: str, pts, width: int) -> np.ndarray:
    a = np.asarray(pts, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != width or len(a) < 2:
        raise InputError(f"{name}: expected at least 2 points of {width} numbers each, got {np.shape(pts)}")
    if not np.all(np.isfinite(a)) or a.min() < 0 or a.max() > 1:
        raise InputError(f"{name}: every number must lie in [0, 1] (scalar position and values)")
    if np.any(np.diff(a[:, 0]) < 0):
        raise InputError(f"{name}: scalar positions must be ascending, got {a[:, 0].tolist()}")
    return a


@dataclass
class TransferFunction:
    """Piecewise-linear colour and opacity over normalized scalars.

    Args:
        color: ``(K, 4)`` rows ``(x, r, g, b)``, all in [0, 1], ``x`` ascending.
        opacity: ``(L, 2)`` rows ``(x, a)``, all in [0, 1], ``x`` ascending.
    """

    color: np.ndarray
    opacity: np.ndarray

    def __post_init__(self) -> None:
        self.color = _points("transfer_function.color", self.color, 4)
        self.opacity = _points("transfer_function.opacity", self.opacity, 2)
        if float(self.opacity[:, 1].max()) <= 0.0:
            raise InputError("transfer_function.opacity: every opacity is 0, the volume would be invisible")

    def rgb(self, x: np.ndarray) -> np.ndarray:
        """Colour at normalized scalars ``x`` (any shape) -> ``x.shape + (3,)``; constant beyond the ends."""
        x = np.asarray(x, np.float64)
        return np.stack([np.interp(x, self.color[:, 0], self.color[:, c]) for c in (1, 2, 3)], axis=-1)

    def alpha(self, x: np.ndarray) -> np.ndarray:
        """Opacity (per ``opacity_unit_distance``) at normalized scalars ``x``."""
        return np.interp(np.asarray(x, np.float64), self.opacity[:, 0], self.opacity[:, 1])

    def table(self, size: int = 1024) -> np.ndarray:
        """Lookup table ``(size, 4)`` of ``(r, g, b, a)`` sampled uniformly over [0, 1]."""
        x = np.linspace(0.0, 1.0, size)
        return np.concatenate([self.rgb(x), self.alpha(x)[:, None]], axis=1).astype(np.float32)

    def to_dict(self) -> dict[str, Any]:
        return {"color": self.color.tolist(), "opacity": self.opacity.tolist()}


@dataclass
class Shading:
    """Phong shading with a headlight (light at the camera), as VTK's default light kit-less scene."""

    enabled: bool = True
    ambient: float = 0.2
    diffuse: float = 0.7
    specular: float = 0.2
    specular_power: float = 10.0

    def __post_init__(self) -> None:
        for k in ("ambient", "diffuse", "specular"):
            v = float(getattr(self, k))
            if not (0.0 <= v <= 1.0):
                raise InputError(f"scene.shading.{k}={v}: expected a number in [0, 1]")
        if not (float(self.specular_power) > 0):
            raise InputError(f"scene.shading.specular_power={self.specular_power}: expected a positive number")

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in ("enabled", "ambient", "diffuse", "specular", "specular_power")}


#: ``scene.sample_distance: auto``: half a voxel (after VTK's ``LockSampleDistanceToInputSpacing``)
AUTO_SAMPLE_DISTANCE_VOXELS = 0.5
#: the finest sample distance accepted, in voxels (50x finer than ``auto``: finer only costs time)
MIN_SAMPLE_DISTANCE_VOXELS = 0.01


def voxel_size(volume: Volume) -> float:
    """One *voxel*, the unit of ``scene.sample_distance_voxels``: the smallest voxel spacing of
    ``volume`` in normalized units (the longest physical axis spans [-1, 1]).

    Example:
        >>> v = Volume(np.zeros((3, 3, 5), np.float32), (1.0, 1.0, 0.5), (0.0, 1.0), "v", "test")
        >>> voxel_size(v)       # x spans 4 * 1.0 -> 2 normalized units: scale 0.5; min spacing 0.5
        0.25
    """
    return float(np.min(volume.normalized_spacing))


def _positive(key: str, value, expected: str) -> float | None:
    """``value`` as a positive finite float; None for ``None``/``auto``; InputError naming ``key``."""
    if value is None or (isinstance(value, str) and value.strip().lower() in ("auto", "none", "null", "")):
        return None
    v = math.nan
    if not isinstance(value, bool):
        try:
            v = float(value)
        except (TypeError, ValueError):
            pass
    if not (math.isfinite(v) and v > 0):
        raise InputError(f"{key}={value!r}: expected {expected}")
    return v


def resolve_sample_distance(volume: Volume, sample_distance="auto", sample_distance_voxels=None) -> float:
    """The ray-sampling step in normalized units, from the scene's settings.

    Args:
        volume: the scene's volume (its voxel size defines the unit voxel, :func:`voxel_size`).
        sample_distance: ``"auto"`` (or None): ``AUTO_SAMPLE_DISTANCE_VOXELS`` (half a voxel); a number:
            the step in normalized units (the volume's longest physical axis spans [-1, 1]).
        sample_distance_voxels: the step in voxels (needs ``sample_distance: auto``); None: unused.

    Returns:
        The step in normalized units (what the renderers march with).

    Raises:
        InputError: a value that is not ``auto`` or a positive number, both keys given, or a step
            finer than ``MIN_SAMPLE_DISTANCE_VOXELS`` (it would only cost time).

    Example:
        >>> v = Volume(np.zeros((3, 3, 5), np.float32), (1.0, 1.0, 0.5), (0.0, 1.0), "v", "test")
        >>> resolve_sample_distance(v), resolve_sample_distance(v, 0.02), resolve_sample_distance(v, "auto", 2)
        (0.125, 0.02, 0.5)
    """
    normalized = _positive("scene.sample_distance", sample_distance, "auto (half a voxel) or a positive number in normalized "
                           "units (the volume's longest axis spans [-1, 1]); for voxels use scene.sample_distance_voxels")
    voxels = _positive("scene.sample_distance_voxels", sample_distance_voxels,
                       "a positive number of voxels (of the smallest voxel spacing), or null")
    if normalized is not None and voxels is not None:
        raise InputError(f"scene.sample_distance={sample_distance!r} and scene.sample_distance_voxels={sample_distance_voxels!r}: "
                         "give only one (scene.sample_distance=auto with scene.sample_distance_voxels)")
    size = voxel_size(volume)
    key, value = ("scene.sample_distance", sample_distance) if normalized is not None else ("scene.sample_distance_voxels", sample_distance_voxels)
    if normalized is None:
        normalized = (AUTO_SAMPLE_DISTANCE_VOXELS if voxels is None else voxels) * size
    if normalized < MIN_SAMPLE_DISTANCE_VOXELS * size * (1 - 1e-9):
        raise InputError(f"{key}={value!r}: finer than {MIN_SAMPLE_DISTANCE_VOXELS} voxel ({MIN_SAMPLE_DISTANCE_VOXELS * size:.3g} "
                         f"normalized units for volume '{volume.name}'); auto is {AUTO_SAMPLE_DISTANCE_VOXELS} voxel")
    return float(normalized)


@dataclass
class Scene:
    """Everything that decides the pixels besides the view and the image resolution."""

    name: str
    volume: Volume
    transfer_function: TransferFunction
    shading: Shading = field(default_factory=Shading)
    # ``"auto"`` or a length in normalized units; always the resolved length (a float) once built
    sample_distance: float | str = "auto"
    opacity_unit_distance: float = 0.02   # normalized units
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    camera_distance: tuple[float, float] = (2.5, 4.0)
    view_angle: float = 30.0
    # the plain ``scene`` config node this scene was built from (``build_scene``), recorded in
    # cache manifests so any entry can be re-rendered; never hashed, never compared
    config: dict[str, Any] | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.sample_distance = resolve_sample_distance(self.volume, self.sample_distance)
        if isinstance(self.opacity_unit_distance, bool) or not _is_positive_number(self.opacity_unit_distance):
            raise InputError(f"scene.opacity_unit_distance={self.opacity_unit_distance!r}: expected a positive number in normalized units")
        self.opacity_unit_distance = float(self.opacity_unit_distance)
        bg = tuple(float(c) for c in self.background)
        if len(bg) != 3 or not all(0.0 <= c <= 1.0 for c in bg):
            raise InputError(f"scene.background={self.background}: expected three numbers in [0, 1]")
        self.background = bg  # type: ignore[assignment]
        lo, hi = (float(c) for c in self.camera_distance)
        if not (0 < lo <= hi):
            raise InputError(f"scene.camera_distance={self.camera_distance}: expected [min, max] with 0 < min <= max")
        self.camera_distance = (lo, hi)
        if not (0.0 < float(self.view_angle) < 180.0):
            raise InputError(f"scene.view_angle={self.view_angle}: expected degrees in (0, 180)")

    @property
    def sample_distance_voxels(self) -> float:
        """The sample distance in voxels (of the smallest voxel spacing, :func:`voxel_size`)."""
        return float(f"{self.sample_distance / voxel_size(self.volume):.12g}")

    def pixel_settings(self) -> dict[str, Any]:
        """Plain data of everything in the scene that changes pixels (hashed into cache keys)."""
        return {
            "name": self.name,
            "volume": self.volume.describe(),
            "transfer_function": self.transfer_function.to_dict(),
            "shading": self.shading.to_dict(),
            "sample_distance": float(self.sample_distance),            # normalized units
            "sample_distance_voxels": self.sample_distance_voxels,
            "opacity_unit_distance": float(self.opacity_unit_distance),
            "background": list(self.background),
            "camera_distance": list(self.camera_distance),
            "view_angle": float(self.view_angle),
        }


def _is_positive_number(v) -> bool:
    try:
        return math.isfinite(float(v)) and float(v) > 0
    except (TypeError, ValueError):
        return False

