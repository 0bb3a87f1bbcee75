"""imls_lightning.base.atomic: atomic writes (temporary sibling, fsync, rename) leave the old file or the new one."""
from __future__ import annotations

import json

import numpy as np
import pytest

from imls_lightning.base.atomic import atomic_json, atomic_npy, atomic_write, atomic_write_text


def test_atomic_write_text_and_json_contents(tmp_path):
    p = atomic_write_text(tmp_path / "sub" / "a.txt", "x\ny\n")
    assert p == tmp_path / "sub" / "a.txt" and p.read_bytes() == b"x\ny\n"
    obj = {"b": 1, "a": [1.5, "s"], "p": tmp_path}
    q = atomic_json(tmp_path / "a.json", obj)
    assert q.read_text() == json.dumps(obj, indent=1, sort_keys=True, default=str) + "\n"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a.json", "sub"]  # no temporary file left


def test_atomic_npy_round_trip(tmp_path):
    arr = np.arange(12, dtype=np.int16).reshape(3, 4)
    p = atomic_npy(tmp_path / "a.npy", arr)
    back = np.load(p, allow_pickle=False)
    assert back.dtype == arr.dtype and np.array_equal(back, arr)


def test_failed_write_keeps_the_old_file_and_removes_the_temporary(tmp_path):
    p = atomic_write_text(tmp_path / "a.txt", "old")

    def fail(f):
        f.write(b"half")
        raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        atomic_write(p, fail)
    assert p.read_text() == "old" and sorted(x.name for x in tmp_path.iterdir()) == ["a.txt"]
    with pytest.raises(RuntimeError):
        atomic_write(tmp_path / "b.txt", fail, unique=True)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a.txt"]


def test_replace_overwrites(tmp_path):
    atomic_write_text(tmp_path / "a.txt", "one")
    atomic_write_text(tmp_path / "a.txt", "two", unique=True)
    assert (tmp_path / "a.txt").read_text() == "two"
