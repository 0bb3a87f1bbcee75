"""imls_lightning.render.camera: pixel-set validation; view_tensor, the one view -> network input."""
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


# --- view_tensor: the one view -> network input ------------------------------------------------------------------


def _direct_view_tensor(views):
    """The conversion written out by hand: float64 numbers rounded to float32 one by one, one view as a batch of one."""
    import struct

    import torch

    rows = np.atleast_2d(np.asarray(views, np.float64))
    return torch.tensor([[struct.unpack("f", struct.pack("f", float(x)))[0] for x in row] for row in rows], dtype=torch.float32)


@pytest.mark.parametrize("views", [
    [0, 0, 3.5, 0, 0, 0, 0, 1, 0],                                   # one view, a list
    np.array([0.1, -2.3, 3.3333333333, 0, 0.01, 0, 0, 1, 0]),       # one view, float64
    np.random.default_rng(0).normal(size=(5, 9)),                    # a batch, float64
    np.random.default_rng(1).normal(size=(3, 9)).astype(np.float32),  # a batch, float32
])
def test_view_tensor_matches_a_direct_conversion(views):
    import torch

    from imls_lightning.render.camera import view_tensor

    got = view_tensor(views)
    want = _direct_view_tensor(views)
    assert got.dtype == torch.float32 and got.shape == want.shape and got.shape[1] == 9
    assert torch.equal(got, want)
    # a tensor gives the same numbers as the array it came from, on its own device
    again = view_tensor(torch.as_tensor(np.asarray(views, np.float64)))
    assert torch.equal(again, want) and again.device == want.device
    assert view_tensor(views, "cpu").device.type == "cpu"


def test_view_tensor_copies_read_only_arrays_and_rejects_other_shapes(tmp_path):
    import torch

    from imls_lightning.render.camera import view_tensor

    path = tmp_path / "views.npy"
    np.save(path, np.arange(18, dtype=np.float32).reshape(2, 9))
    mm = np.load(path, mmap_mode="r")  # read-only, as the cache's views
    t = view_tensor(mm[0])
    t += 1  # a copy: the file is not touched
    assert float(mm[0, 0]) == 0.0 and torch.equal(view_tensor(mm), torch.arange(18.0).reshape(2, 9))
    for bad in ([1, 2, 3], np.zeros((2, 8)), np.zeros((1, 2, 9))):
        with pytest.raises(InputError, match="expected one view"):
            view_tensor(bad)
