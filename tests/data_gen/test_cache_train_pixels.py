"""C-Image-only caches (``train_pixels``): the training views ray-cast at a pattern's pixels only, the
validation and test views whole; what the IMS's own 1,500-view cache needs (issue 31, item 2)."""
from __future__ import annotations

import numpy as np
import pytest

from data_gen.cache import ViewImageCache, cache_path_for, render_cache
from data_gen.cache_keys import check_train_pixels
from imls_lightning.base.errors import InputError
from tests.data_gen.helpers import VTK
from tests.data_gen.helpers import cache_data as _data

NUMBA = {"name": "numba"}


def _every_other_pixel(m: int) -> np.ndarray:
    """The C-pixels of a 2x downsampling pattern of an ``m x m`` image (even rows and columns)."""
    ys, xs = np.meshgrid(np.arange(0, m, 2), np.arange(0, m, 2), indexing="ij")
    return (ys * m + xs).ravel().astype(np.int64)


@pytest.mark.parametrize("renderer, workers", [(NUMBA, 0), (VTK, 1)])
def test_train_rows_hold_only_the_pattern_pixels_exactly(tmp_path, tiny_scene, renderer, workers):
    pixels = _every_other_pixel(24)
    full = ViewImageCache.open(render_cache(tiny_scene, _data(tmp_path / "full", workers=workers), renderer, progress=False).path)
    rep = render_cache(tiny_scene, _data(tmp_path / "sparse", workers=workers), renderer, progress=False, train_pixels=pixels)
    c = ViewImageCache.open(rep.path)
    assert rep.path.name != full.path.name  # a key of its own: never mixed with whole frames
    np.testing.assert_array_equal(c.sparse_rows, c.splits["train"])
    assert c.manifest["settings"]["train_pixels"]["count"] == pixels.size
    off = np.ones(24 * 24, bool)
    off[pixels] = False
    for i in c.splits["train"]:
        flat, ref = c.images[i].reshape(-1, 3), full.images[i].reshape(-1, 3)
        np.testing.assert_array_equal(flat[pixels], ref[pixels])  # the same rays, the same colours
        assert not flat[off].any()  # and no other pixel cast
    for i in np.concatenate([c.splits["val"], c.splits["test"]]):
        np.testing.assert_array_equal(c.images[i], full.images[i])
    assert len(full.sparse_rows) == 0 and "train_pixels" not in full.manifest["settings"]


def test_train_pixels_resume_and_key(tmp_path, tiny_scene):
    pixels = _every_other_pixel(24)
    d = _data(tmp_path)
    first = render_cache(tiny_scene, d, NUMBA, progress=False, train_pixels=pixels)
    again = render_cache(tiny_scene, d, NUMBA, progress=False, train_pixels=pixels)
    assert again.path == first.path and again.rendered == 0 and again.already_done == 16
    assert cache_path_for(tiny_scene, d, NUMBA, train_pixels=pixels) == first.path
    assert cache_path_for(tiny_scene, d, NUMBA) != first.path
    assert cache_path_for(tiny_scene, d, NUMBA, train_pixels=pixels[1:]) != first.path


@pytest.mark.parametrize("pixels", [[3, 1], [0, 576], [-1, 2], np.zeros((2, 2), np.int64), [0.5, 1.5], []])
def test_train_pixels_exception_bad_indices(tmp_path, tiny_scene, pixels):
    with pytest.raises(InputError, match=r"^train_pixels: expected strictly ascending flat pixel indices in \[0, 576\)"):
        render_cache(tiny_scene, _data(tmp_path), NUMBA, progress=False, train_pixels=pixels)
    assert not (tmp_path / "cache").exists() or not any((tmp_path / "cache").iterdir())  # nothing written


def test_check_train_pixels_passes_none_and_returns_int64():
    assert check_train_pixels(None, 4) is None
    out = check_train_pixels(np.array([1, 5], np.int32), 4)
    assert out.dtype == np.int64 and out.tolist() == [1, 5]
