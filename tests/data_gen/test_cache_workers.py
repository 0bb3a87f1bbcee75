"""data_gen.cache_workers: render worker processes (same pixels as in-process rendering; orphans exit)."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from data_gen.cache import ViewImageCache, render_cache
from tests.data_gen.helpers import VTK
from tests.data_gen.helpers import cache_data as _data
from tests.data_gen.helpers import process_alive as _alive

ROOT = Path(__file__).resolve().parents[2]


def test_parallel_workers_match_in_process(tmp_path, tiny_scene):
    a = render_cache(tiny_scene, _data(tmp_path, cache_path=str(tmp_path / "a")), VTK, progress=False)
    b = render_cache(tiny_scene, _data(tmp_path, cache_path=str(tmp_path / "b"), workers=2), VTK, progress=False)
    assert b.rendered == 16 and b.workers == 2
    np.testing.assert_array_equal(ViewImageCache.open(a.path).images, ViewImageCache.open(b.path).images)


def test_orphaned_worker_exits_when_its_parent_dies(tmp_path):
    """A render worker whose parent is SIGKILLed before its setup arrived must exit (issue 17, 7)."""
    code = (
        "import multiprocessing as mp, os, sys, time\n"
        "from data_gen.cache_workers import worker_main\n"
        "if __name__ == '__main__':\n"
        "    ctx = mp.get_context('spawn')\n"
        "    setup, tasks, results = ctx.Queue(), ctx.Queue(), ctx.Queue()\n"
        "    p = ctx.Process(target=worker_main, args=(setup, os.getpid(), tasks, results))\n"
        "    p.start()\n"
        "    print(p.pid, flush=True)\n"
        "    time.sleep(600)\n"
    )
    parent = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        worker = int(parent.stdout.readline())
        time.sleep(3)  # the worker is up and waiting for its setup
        assert _alive(worker)
    finally:
        parent.kill()
        parent.wait()
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and _alive(worker):
        time.sleep(0.1)
    assert not _alive(worker), "the orphaned worker still waits for its setup"
