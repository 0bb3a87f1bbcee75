"""data_gen.cache_reader: ViewImageCache, a cache opened for reading and checked."""
from __future__ import annotations

import os

import numpy as np
import pytest

from data_gen.cache import ViewImageCache, render_cache
from imls_lightning.base.errors import InputError
from tests.data_gen.helpers import VTK
from tests.data_gen.helpers import cache_data as _data


def test_verify_detects_silent_corruption(tmp_path, tiny_scene):
    path = render_cache(tiny_scene, _data(tmp_path), VTK, progress=False).path
    with open(path / "images.npy", "r+b") as f:
        f.seek(-10, os.SEEK_END)
        f.write(b"\x01" * 10)
    assert ViewImageCache.open(path, check_pixels=False).verify().tolist() == [15]


def test_changed_views_refused_on_open(tmp_path, tiny_scene):
    path = render_cache(tiny_scene, _data(tmp_path), VTK, progress=False).path
    v = np.load(path / "views.npy")
    v[0, 0] += 0.5
    np.save(path / "views.npy", v)
    with pytest.raises(InputError, match="changed after rendering"):
        ViewImageCache.open(path)


def test_exception_open_non_cache(tmp_path):
    with pytest.raises(InputError, match="not a view/image cache"):
        ViewImageCache.open(tmp_path)
