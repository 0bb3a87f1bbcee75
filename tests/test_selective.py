"""Selective rendering through either renderer: pixel validation, masks, both routes agree.

No timing is asserted here: performance is measured by ``scripts/bench_selective.py``.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from data_gen.errors import InputError
from data_gen.selective import SelectiveRenderer, mask_to_pixels, render_selected, validate_pixels

VIEW = [2.5, 1.0, 1.2, 0.1, 0.0, 0.0, 0.0, 0.0, 1.0]


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 10.0 * math.log10(255.0 ** 2 / max(mse, 1e-12))


@pytest.fixture(scope="module")
def renderers(blob_scene):
    from data_gen.render_numba import NumbaRenderer
    from data_gen.render_vtk import VTKRenderer

    return {"numba": NumbaRenderer(blob_scene), "vtk": VTKRenderer(blob_scene)}


# ---- pixel sets ------------------------------------------------------------------------------------
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


def test_mask_to_pixels():
    mask = np.zeros((3, 3), bool)
    mask[0, 2] = mask[2, 1] = True
    assert mask_to_pixels(mask).tolist() == [2, 7]
    with pytest.raises(InputError, match="boolean"):
        mask_to_pixels(mask.astype(np.uint8))
    with pytest.raises(InputError, match="square"):
        mask_to_pixels(np.zeros((2, 3), bool))


# ---- both routes ------------------------------------------------------------------------------------
@pytest.mark.parametrize("route", ["numba", "vtk"])
def test_render_selected_mask_equals_full_frame(renderers, route):
    r = renderers[route]
    m = 40
    full = r.render(VIEW, m)
    mask = np.zeros((m, m), bool)
    mask[8:30:3, 5:35:2] = True
    frame = np.zeros((m, m, 3), np.uint8)
    colours = render_selected(r, VIEW, m, mask, out=frame)
    assert colours.shape == (int(mask.sum()), 3)
    err = np.abs(colours.astype(int) - full[mask])
    if route == "numba":
        assert err.max() == 0  # every ray is independent: bit-identical
    else:
        assert err.max() <= 1 and psnr(colours, full[mask]) >= 40.0
    assert np.array_equal(frame[mask], colours) and (frame[~mask] == 0).all()


def test_routes_agree(renderers):
    """Both routes cast the same rays of the same scene model (numba vs VTK: >= 45 dB, see
    tests/test_render_numba.py for the threshold)."""
    m = 48
    pix = np.random.default_rng(7).choice(m * m, 500, replace=False)
    a = SelectiveRenderer(renderers["vtk"])(VIEW, m, pix)
    sel = SelectiveRenderer(renderers["numba"])
    b = sel(VIEW, m, pix)
    assert psnr(a, b) >= 45.0
    assert sel.seconds >= sel.render_seconds > 0.0


@pytest.mark.parametrize("route", ["numba", "vtk"])
def test_empty_pixel_set_renders_nothing(renderers, route):
    sel = SelectiveRenderer(renderers[route])
    out = sel(VIEW, 64, np.zeros(0, np.int64))
    assert out.shape == (0, 3) and out.dtype == np.uint8
    assert sel.render_seconds == 0.0  # the renderer was never invoked
    out = sel(VIEW, 64, np.zeros((64, 64), bool))
    assert out.shape == (0, 3)


def test_exception_selective_inputs(renderers):
    with pytest.raises(InputError, match="render_pixels"):
        SelectiveRenderer(object())
    with pytest.raises(InputError, match="mask must have shape"):
        render_selected(renderers["numba"], VIEW, 8, np.zeros((4, 4), bool))
    with pytest.raises(InputError, match="out"):
        render_selected(renderers["numba"], VIEW, 8, np.array([1]), out=np.zeros((8, 8, 3), np.float32))
