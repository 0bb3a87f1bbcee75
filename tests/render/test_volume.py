"""imls_lightning.render.volume: Volume geometry in the normalized space and scalar normalization, against direct
computations; invalid volumes are refused with one-line InputErrors."""
from __future__ import annotations

import numpy as np
import pytest

from imls_lightning.base.errors import InputError
from imls_lightning.render.volume import Volume


def _volume(shape=(4, 6, 11), spacing=(0.5, 1.0, 2.0), value_range=(10.0, 20.0), data=None) -> Volume:
    data = np.random.default_rng(0).uniform(0, 30, shape).astype(np.float32) if data is None else data
    return Volume(data, spacing, value_range, "v", "test")


def test_geometry_against_direct_computation():
    v = _volume()
    assert v.dims == (11, 6, 4)
    phys = np.array([(11 - 1) * 0.5, (6 - 1) * 1.0, (4 - 1) * 2.0])  # 5, 5, 6: z is the longest axis
    np.testing.assert_allclose(v.physical_size, phys)
    s = 2.0 / 6.0
    assert v.scale == pytest.approx(s)
    np.testing.assert_allclose(v.half_extent, phys * s / 2)
    assert v.half_extent.max() == pytest.approx(1.0)
    np.testing.assert_allclose(v.normalized_spacing, np.array([0.5, 1.0, 2.0]) * s)
    np.testing.assert_allclose(v.origin, -v.half_extent)
    np.testing.assert_allclose(v.bounds, np.stack([-v.half_extent, v.half_extent], 1))
    # the last voxel centre sits at the far corner
    np.testing.assert_allclose(v.origin + (np.array(v.dims) - 1) * v.normalized_spacing, v.half_extent)


def test_normalize_and_to_raw_are_inverse_inside_the_range():
    v = _volume()
    raw = np.array([5.0, 10.0, 12.5, 20.0, 25.0])
    np.testing.assert_allclose(v.normalize(raw), [0.0, 0.0, 0.25, 1.0, 1.0])
    assert v.normalize(raw).dtype == np.float32
    x = np.array([0.0, 0.25, 1.0])
    np.testing.assert_allclose(v.to_raw(x), [10.0, 12.5, 20.0])
    assert v.to_raw(0.5) == pytest.approx(15.0) and isinstance(v.to_raw(0.5), float)


def test_fingerprint_follows_pixels_changing_settings():
    d = np.random.default_rng(1).uniform(0, 1, (3, 4, 5)).astype(np.float32)
    a, b = _volume(data=d, value_range=(0, 1)), _volume(data=d.copy(), value_range=(0, 1))
    assert a.fingerprint() == b.fingerprint() and len(a.fingerprint()) == 16
    assert _volume(data=d, value_range=(0, 2)).fingerprint() != a.fingerprint()
    assert _volume(data=d, spacing=(1, 1, 1), value_range=(0, 1)).fingerprint() != a.fingerprint()
    d2 = d.copy()
    d2[0, 0, 0] += 0.5
    assert _volume(data=d2, value_range=(0, 1)).fingerprint() != a.fingerprint()
    desc = a.describe()
    assert desc["dims_xyz"] == [5, 4, 3] and desc["fingerprint"] == a.fingerprint() and desc["dtype"] == "float32"


@pytest.mark.parametrize("kw, needle", [
    ({"data": np.zeros((4, 4), np.float32)}, "3D"),
    ({"data": np.zeros((1, 4, 4), np.float32)}, "at least 2 voxels"),
    ({"spacing": (1.0, 0.0, 1.0)}, "spacing"),
    ({"spacing": (1.0, 1.0)}, "spacing"),
    ({"value_range": (1.0, 1.0)}, "constant"),
    ({"value_range": (0.0, float("nan"))}, "constant"),
])
def test_exception_invalid_volume(kw, needle):
    with pytest.raises(InputError, match=needle) as err:
        _volume(**kw)
    assert "\n" not in str(err.value)
