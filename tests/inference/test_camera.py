"""imls_lightning.inference.camera: the orbit camera both viewers use."""
from __future__ import annotations

import numpy as np
import pytest

from imls_lightning.base.errors import InputError
from imls_lightning.inference.camera import MAX_ELEVATION, frame_psnr, orbit_view, turned, zoomed


def test_turned_wraps_azimuth_and_clamps_elevation():
    assert turned(170.0, 80.0, 20.0, 20.0) == (-170.0, MAX_ELEVATION)
    assert turned(-179.0, -85.0, -2.0, -10.0) == (179.0, -MAX_ELEVATION)


def test_zoomed_steps_by_ten_percent_within_the_range():
    assert zoomed(3.0, 1, (2.5, 4.0)) == pytest.approx(2.7)
    assert zoomed(3.0, 10, (2.5, 4.0)) == 2.5 and zoomed(3.0, -10, (2.5, 4.0)) == 4.0


def test_orbit_view_eye_at_distance_and_up_orthogonal():
    v = orbit_view(35.0, 25.0, 3.2)
    eye, look, up = v[:3], v[3:6], v[6:]
    assert np.linalg.norm(eye - look) == pytest.approx(3.2)
    assert abs(np.dot(up, (look - eye) / 3.2)) < 1e-9 and np.linalg.norm(up) == pytest.approx(1.0)


def test_frame_psnr_against_a_direct_formula():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (8, 8, 3), dtype=np.uint8)
    b = np.clip(a.astype(int) + rng.integers(-3, 4, a.shape), 0, 255).astype(np.uint8)
    mse = np.mean((a.astype(float) - b.astype(float)) ** 2)
    assert frame_psnr(a, b) == pytest.approx(10 * np.log10(255.0**2 / mse), abs=1e-4)


def test_exception_orbit_view_bad_angles():
    with pytest.raises(InputError, match="^elevation=90"):
        orbit_view(0.0, 90.0, 3.0)
    with pytest.raises(InputError, match="^distance=0"):
        orbit_view(0.0, 0.0, 0.0)
