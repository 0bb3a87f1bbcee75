"""imls_lightning.base.images: uint8 conversion, error map and image grid against direct computations."""
from __future__ import annotations

import numpy as np
import torch
from PIL import Image

from imls_lightning.base.images import error_map, image_grid, save_image, to_uint8


def test_to_uint8_against_direct_rounding():
    x = torch.tensor([[[0.0, 0.5], [1.0, 2.0]]])  # (1, 2, 2): grey, clipped above 1
    out = to_uint8(x)
    assert out.shape == (2, 2, 3) and out.dtype == np.uint8
    assert out[..., 0].tolist() == [[0, 128], [255, 255]] and (out[..., 0] == out[..., 2]).all()
    rgb = torch.rand(3, 4, 5)
    np.testing.assert_array_equal(to_uint8(rgb), (rgb.permute(1, 2, 0).numpy() * 255 + 0.5).astype(np.uint8))
    assert to_uint8(torch.tensor([[float("nan")]]))[0, 0].tolist() == [0, 0, 0]


def test_error_map_against_direct_formula():
    pred, target = torch.rand(3, 6, 6), torch.rand(3, 6, 6)
    e = ((pred - target).abs().mean(0) * 4).clamp(0, 1)
    m = error_map(pred, target)
    assert m.shape == (3, 6, 6)
    torch.testing.assert_close(m[0], (3 * e).clamp(0, 1))
    torch.testing.assert_close(m[2], (3 * e - 2).clamp(0, 1))
    assert error_map(pred, pred).abs().sum() == 0


def test_image_grid_size_and_tiles():
    red = torch.zeros(3, 4, 4)
    red[0] = 1
    g = image_grid([[red, None], [None, torch.ones(1, 2, 2)]], tile=8, pad=2)
    assert g.size == (2 + 2 * (8 + 2), 2 + 2 * (8 + 2))
    arr = np.asarray(g)
    assert arr[2, 2].tolist() == [255, 0, 0]  # first tile: red, scaled
    assert arr[2 + 10, 2 + 10].tolist() == [255, 255, 255]  # last tile: white
    assert arr[2, 2 + 10].tolist() == [24, 24, 24]  # empty cell: background
    titled = image_grid([[red]], col_titles=["a"], row_titles=["r"], tile=8, pad=2)
    assert titled.size == (56 + 12, 16 + 12)


def test_save_image_round_trip(tmp_path):
    g = image_grid([[torch.rand(3, 4, 4)]], tile=8)
    p = save_image(g, tmp_path / "x" / "g.png")
    assert p.is_file() and np.array_equal(np.asarray(Image.open(p).convert("RGB")), np.asarray(g))
