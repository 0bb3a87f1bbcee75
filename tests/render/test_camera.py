"""imls_lightning.render.camera: pixel-set validation."""
from __future__ import annotations

import numpy as np
import pytest

from imls_lightning.render.camera import validate_pixels
from imls_lightning.base.errors import InputError


# ---- pixel sets (imls_lightning.render.camera.validate_pixels) -------------------------------------------------
def test_validate_pixels_keeps_order_and_duplicates():
    out = validate_pixels(np.array([5, 0, 5, 15], np.uint16), 4)
    assert out.dtype == np.int64 and out.tolist() == [5, 0, 5, 15]
    assert validate_pixels([], 4).shape == (0,)


@pytest.mark.parametrize(
    "pixels, match",
    [
        (np.array([1.0]), "integer"),
        (np.array([True]), "integer"),
        (np.array([16]), r"\[0, 16\)"),
        (np.array([-1]), r"\[0, 16\)"),
        (np.zeros((1, 2), np.int64), "1-D"),
    ],
)
def test_exception_validate_pixels(pixels, match):
    with pytest.raises(InputError, match=match) as e:
        validate_pixels(pixels, 4)
    assert "\n" not in str(e.value)
