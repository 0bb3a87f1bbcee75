"""Sharded cache rendering (``data.shard=I/N``): disjoint subsets, concurrent processes, one cache."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from filelock import FileLock

from data_gen.cache import LOG, ViewImageCache, parse_shard, read_log, render_cache
from imls_lightning.base.errors import InputError

ROOT = Path(__file__).resolve().parents[2]
NUMBA = {"name": "numba", "threads": 1}


def _data(cache_dir, **kw):
    d = {"num_views": 14, "test_views": 6, "resolution": 24, "workers": 0, "seed": 0, "fsync": False,
         "cache_dir": str(cache_dir)}
    d.update(kw)
    return d


def _cli(cache_dir: Path, shard: str | None) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "data_gen", "scene=tiny", "data=tiny", "data.resolution=48", "renderer=numba",
           "renderer.threads=1", f"data.cache_dir={cache_dir}", "data.fsync=false", "progress=false"]
    if shard is not None:
        cmd.append(f"data.shard={shard}")
    env = dict(os.environ, NUMBA_NUM_THREADS="1")
    return subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait(p: subprocess.Popen) -> str:
    out, err = p.communicate(timeout=300)
    assert p.returncode == 0, err[-3000:]
    return out.strip().splitlines()[-1]


def test_parse_shard():
    assert parse_shard(None) is None and parse_shard("null") is None
    assert parse_shard("0/1") == (0, 1) and parse_shard(" 3 / 4 ") == (3, 4) and parse_shard([1, 2]) == (1, 2)
    for bad in ("2/2", "-1/2", "1/0", "1", "a/b", "1/2/3", 5):
        with pytest.raises(InputError, match="data.shard"):
            parse_shard(bad)


def test_two_concurrent_shard_processes_make_the_single_process_cache(tmp_path):
    """Shards 0/2 and 1/2 in two processes at once, and one process alone: same directory name
    (the shard is not hashed), same views, same pixels, every view logged once, by its own shard."""
    procs = [_cli(tmp_path / "sharded", s) for s in ("0/2", "1/2")]
    single = _cli(tmp_path / "single", None)
    paths = [Path(_wait(p)) for p in procs]
    ref_path = Path(_wait(single))
    assert paths[0] == paths[1] and paths[0].name == ref_path.name

    got, ref = ViewImageCache.open(paths[0]), ViewImageCache.open(ref_path)  # both complete
    n = len(ref)
    assert n == 36 and got.complete
    np.testing.assert_array_equal(got.views, ref.views)
    np.testing.assert_array_equal(np.asarray(got.images), np.asarray(ref.images))
    np.testing.assert_array_equal(got.crc, ref.crc)
    assert got.verify().size == 0 and np.all(np.isfinite(got.render_seconds))
    assert {k: v.tolist() for k, v in got.splits.items()} == {k: v.tolist() for k, v in ref.splits.items()}
    # each shard rendered exactly its interleaved subset, into its own log; the main log is empty
    assert (paths[0] / LOG).read_bytes() == b""
    for i in range(2):
        done, _, _ = read_log(paths[0] / f"done-shard-{i}-of-2.log", n)
        np.testing.assert_array_equal(np.flatnonzero(done), np.arange(i, n, 2))
    manifest = json.loads((paths[0] / "manifest.json").read_text())
    assert manifest["complete"] == n and sorted(r["shard"] for r in manifest["runs"]) == ["0/2", "1/2"]
    assert manifest["settings"] == ref.manifest["settings"]


def test_shard_locks_are_independent_and_a_plain_run_completes_the_rest(tmp_path, tiny_scene):
    d = _data(tmp_path)
    first = render_cache(tiny_scene, {**d, "shard": "0/3"}, NUMBA, progress=False)
    path = first.path
    assert first.rendered == 7 and first.shard == (0, 3) and "shard 0/3" in first.summary()
    with pytest.raises(InputError, match="only 7 of 20 views are rendered"):
        ViewImageCache.open(path)
    # another process holds shard 1's lock: shard 2 is not held up by it, shard 1 waits for it
    held = FileLock(str(path / ".lock-shard-1-of-3"))
    held.acquire()
    try:
        assert render_cache(tiny_scene, {**d, "shard": "2/3"}, NUMBA, progress=False).rendered == 6
        result = {}
        t = threading.Thread(target=lambda: result.update(r=render_cache(tiny_scene, {**d, "shard": "1/3"}, NUMBA, progress=False)))
        t.start()
        t.join(timeout=1.5)
        assert t.is_alive() and "r" not in result  # waiting on the held shard lock
    finally:
        held.release()
    t.join(timeout=60)
    assert result["r"].rendered == 7
    # everything is done: a plain run renders nothing; a shard run again renders nothing
    assert render_cache(tiny_scene, d, NUMBA, progress=False).rendered == 0
    again = render_cache(tiny_scene, {**d, "shard": "1/3"}, NUMBA, progress=False)
    assert again.rendered == 0 and "nothing left" in again.summary()
    # a plain run after one shard renders exactly the missing views
    other = _data(tmp_path / "b")
    render_cache(tiny_scene, {**other, "shard": "1/2"}, NUMBA, progress=False)
    rest = render_cache(tiny_scene, other, NUMBA, progress=False)
    assert rest.rendered == 10 and rest.already_done == 10
    c = ViewImageCache.open(rest.path)
    ref = ViewImageCache.open(path)
    np.testing.assert_array_equal(np.asarray(c.images), np.asarray(ref.images))


def test_cli_bad_shard_is_one_line_error(tmp_path):
    p = _cli(tmp_path, "2/2")
    out, err = p.communicate(timeout=120)
    assert p.returncode == 2 and "Traceback" not in err
    assert [ln for ln in err.splitlines() if ln.startswith("error:")] == ["error: data.shard='2/2': expected I/N with 0 <= I < N"]
