"""The :class:`Volume`: raw scalars plus the geometry that places them in the normalized space.

Space convention (``DESIGN.md``): the volume is centred at the origin and scaled so its longest
physical axis spans [-1, 1]; anisotropic spacing keeps its aspect. Scalars are normalized to [0, 1]
through a recorded ``(vmin, vmax)`` (optionally percentile-clipped when the volume is loaded).

The raw array is never rescaled in memory: large files stay memory-mapped in their native dtype,
and renderers map normalized transfer-function positions back to raw values with
:meth:`Volume.to_raw` (or normalize samples on the fly with :meth:`Volume.normalize`).
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from imls_lightning.base.errors import InputError


@dataclass
class Volume:
    """A 3D scalar field on a regular grid.

    Args:
        data: raw scalars, shape ``(Z, Y, X)`` (C order, x fastest, as the Open SciVis ``.raw``
            convention), native dtype; may be a ``np.memmap``.
        spacing: physical voxel spacing ``(sx, sy, sz)``, all positive.
        value_range: ``(vmin, vmax)`` that maps to [0, 1]; ``vmax > vmin``.
        name: short name used in cache directory names and reports.
        source: where the data came from (a file path or ``procedural:<kind>?size=..&seed=..``).
        info: free-form provenance recorded in the cache manifest (percentiles used, header, ...).

    Example:
        >>> v = Volume(np.zeros((2, 3, 5), np.float32), (1.0, 1.0, 1.0), (0.0, 1.0), "z", "test")
        >>> v.dims, v.half_extent.tolist()
        ((5, 3, 2), [1.0, 0.5, 0.25])
    """

    data: np.ndarray
    spacing: tuple[float, float, float]
    value_range: tuple[float, float]
    name: str
    source: str
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.data.ndim != 3:
            raise InputError(f"volume '{self.name}': expected a 3D array (Z, Y, X), got shape {self.data.shape}")
        if min(self.data.shape) < 2:
            raise InputError(f"volume '{self.name}': every axis needs at least 2 voxels, got shape (Z, Y, X)={self.data.shape}")
        sp = tuple(float(s) for s in self.spacing)
        if len(sp) != 3 or not all(np.isfinite(s) and s > 0 for s in sp):
            raise InputError(f"volume '{self.name}': spacing must be three positive numbers (sx, sy, sz), got {self.spacing}")
        self.spacing = sp  # type: ignore[assignment]
        lo, hi = (float(v) for v in self.value_range)
        if not (np.isfinite(lo) and np.isfinite(hi)) or hi <= lo:
            raise InputError(
                f"volume '{self.name}' is constant (value range {lo}..{hi}): nothing to render"
            )
        self.value_range = (lo, hi)

    # ---- geometry ---------------------------------------------------------------------------
    @property
    def dims(self) -> tuple[int, int, int]:
        """Grid size as ``(X, Y, Z)`` (VTK order)."""
        z, y, x = self.data.shape
        return (int(x), int(y), int(z))

    @property
    def physical_size(self) -> np.ndarray:
        """Distance between the first and last voxel centre per axis ``(x, y, z)``."""
        return (np.asarray(self.dims, np.float64) - 1.0) * np.asarray(self.spacing, np.float64)

    @property
    def scale(self) -> float:
        """Physical units -> normalized units (longest axis spans 2)."""
        return 2.0 / float(self.physical_size.max())

    @property
    def half_extent(self) -> np.ndarray:
        """Normalized half size ``(ex, ey, ez)``; the volume occupies ``[-e, e]``; max is 1."""
        return self.physical_size * self.scale / 2.0

    @property
    def normalized_spacing(self) -> np.ndarray:
        """Voxel spacing in normalized units ``(x, y, z)``."""
        return np.asarray(self.spacing, np.float64) * self.scale

    @property
    def origin(self) -> np.ndarray:
        """Normalized position of voxel (0, 0, 0), i.e. ``-half_extent``."""
        return -self.half_extent

    @property
    def bounds(self) -> np.ndarray:
        """Axis-aligned box ``[[xmin, xmax], [ymin, ymax], [zmin, zmax]]`` in normalized units."""
        e = self.half_extent
        return np.stack([-e, e], axis=1)

    # ---- scalars ----------------------------------------------------------------------------
    def normalize(self, values: np.ndarray) -> np.ndarray:
        """Raw -> [0, 1] (clipped), float32."""
        lo, hi = self.value_range
        out = (np.asarray(values, np.float32) - np.float32(lo)) / np.float32(hi - lo)
        return np.clip(out, 0.0, 1.0)

    def to_raw(self, x: np.ndarray | float) -> np.ndarray | float:
        """Normalized [0, 1] position -> raw scalar value (for building renderer lookup tables)."""
        lo, hi = self.value_range
        return lo + np.asarray(x, np.float64) * (hi - lo) if np.ndim(x) else lo + float(x) * (hi - lo)

    # ---- identity ---------------------------------------------------------------------------
    def fingerprint(self) -> str:
        """A short hash of everything about the volume that changes rendered pixels.

        Hashes shape, dtype, spacing, value range and a strided sample of the voxels (all voxels
        for small volumes) so that huge memory-mapped files are not read whole.
        """
        h = hashlib.sha256()
        h.update(repr((self.data.shape, str(self.data.dtype), self.spacing, self.value_range)).encode())
        flat = self.data.reshape(-1)
        step = max(1, flat.size // 4_000_000)
        h.update(np.ascontiguousarray(flat[::step]).tobytes())
        return h.hexdigest()[:16]

    def describe(self) -> dict[str, Any]:
        """Plain-data summary for manifests and logs."""
        return {
            "name": self.name,
            "source": self.source,
            "dims_xyz": list(self.dims),
            "dtype": str(self.data.dtype),
            "spacing_xyz": list(self.spacing),
            "value_range": list(self.value_range),
            "half_extent_xyz": [float(v) for v in self.half_extent],
            "fingerprint": self.fingerprint(),
            **({"info": self.info} if self.info else {}),
        }
