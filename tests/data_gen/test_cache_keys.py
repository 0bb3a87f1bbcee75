"""Cache keys (:mod:`data_gen.cache_keys`): the ``data`` settings, file names and the settings hash.

Fast, nothing is rendered; the keys of real caches are exercised in ``tests/data_gen/test_cache.py``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from data_gen.cache_keys import (
    DATA_DEFAULTS,
    LOG,
    MANIFEST,
    data_settings,
    is_own_file,
    jsonable,
    safe_name,
    settings_hash,
    shard_log_name,
    views_digest,
)
from imls_lightning.base.errors import InputError


def test_data_settings_fill_defaults_and_canonical_types():
    d = data_settings(OmegaConf.create({"resolution": 64.0, "num_views": 10, "lookat_jitter": None, "shard": "1/2"}))
    assert d["resolution"] == 64 and isinstance(d["resolution"], int)
    assert d["lookat_jitter"] == DATA_DEFAULTS["lookat_jitter"]  # null takes the default
    assert d["shard"] == (1, 2) and d["test_views"] == DATA_DEFAULTS["test_views"]
    assert set(d) == set(DATA_DEFAULTS)


@pytest.mark.parametrize("kw, message", [
    ({"resolution": 0}, "data.resolution=0: expected an integer >= 1"),
    ({"num_views": 2.5}, "data.num_views=2.5: expected an integer >= 1"),
    ({"test_views": -1}, "data.test_views=-1: expected an integer >= 0"),
    ({"workers": True}, "data.workers=True: expected an integer >= 0"),
    ({"val_fraction": 1.0}, "data.val_fraction=1.0: expected a number in [0, 1)"),
    ({"lookat_jitter": "x"}, "data.lookat_jitter='x': expected a number >= 0 (normalized units)"),
    ({"cache_dir": " "}, "data.cache_dir: empty (expected a directory)"),
    ({"shard": "3/2"}, "data.shard='3/2': expected I/N with 0 <= I < N"),
])
def test_exception_data_settings_one_line(kw, message):
    with pytest.raises(InputError) as e:
        data_settings(kw)
    assert str(e.value) == message


def test_exception_data_not_a_mapping():
    assert data_settings(None) == data_settings({})
    with pytest.raises(InputError, match=r"^data: expected a mapping of settings, got list$"):
        data_settings([1])


def test_own_file_names_and_safe_names():
    assert is_own_file(MANIFEST) and is_own_file(LOG) and is_own_file(shard_log_name((0, 4)))
    assert is_own_file(".lock-shard-1-of-2") and not is_own_file("notes.txt")
    assert safe_name("CT head / v2") == "CT_head_v2" and safe_name("..") == "scene"


def test_hash_and_digest_are_stable_and_sensitive():
    s = jsonable({"b": np.int64(2), "a": [np.float32(0.5)], "p": Path("x")})
    assert s == {"a": [0.5], "b": 2, "p": "x"}
    assert settings_hash(s) == settings_hash(dict(reversed(list(s.items())))) and len(settings_hash(s)) == 12
    views = np.zeros((4, 9), np.float32)
    splits = {"train": np.array([0, 1]), "val": np.array([2]), "test": np.array([3])}
    d = views_digest(views, splits)
    assert d == views_digest(views.copy(), {k: v.copy() for k, v in splits.items()})
    assert d != views_digest(views, {**splits, "train": np.array([1, 0])})
