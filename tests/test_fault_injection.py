"""Fault injection: ``kill -9`` at several points of rendering and training, then run again.

Each rerun must resume (nothing lost: the result equals an uninterrupted run; nothing redone
twice: every view is logged exactly once, training restarts from the newest saved epoch), and render
workers whose parent was killed must exit. Slow (about 2 minutes on 2 cores): ``make test-all``.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import torch
from tests.data_gen.helpers import process_alive as _alive

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow

RENDER_KILLS = (1, 40, 120, 220)  # done.log lines at which the renderer is killed, one run after another
VIEWS, TEST_VIEWS, RES = 300, 20, 64


def _popen(args: list[str]) -> subprocess.Popen:
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1")
    return subprocess.Popen([sys.executable, "-m", *args], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)


def _log_indices(path: Path) -> list[int]:
    from data_gen.cache import LOG, read_log

    lines = [ln for ln in (path / LOG).read_bytes().split(b"\n") if ln]
    done, _, _ = read_log(path / LOG, VIEWS + TEST_VIEWS)
    return [int(ln.split(b" ")[0]) for ln in lines if len(ln.split(b" ")) == 4 and done[int(ln.split(b" ")[0])]]


def _wait_for(cond, timeout: float, proc: subprocess.Popen) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        if cond():
            return True
        time.sleep(0.005)
    return cond()


def _children(pid: int) -> list[int]:
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except FileNotFoundError:
        return []


def test_render_killed_at_many_points_resumes_without_loss_or_rework(tmp_path):
    from omegaconf import OmegaConf

    from data_gen.cache import ViewImageCache, read_log, render_cache
    from data_gen.scenes import build_scene

    cache_dir = tmp_path / "cache"
    args = ["data_gen", "scene=tiny", f"data.num_views={VIEWS}", f"data.test_views={TEST_VIEWS}", f"data.resolution={RES}",
            "data.workers=2", f"data.cache_dir={cache_dir}", "progress=false", "renderer=vtk"]
    path = None
    for kill_at in RENDER_KILLS:
        proc = _popen(args)
        try:
            def reached():
                nonlocal path
                found = list(cache_dir.glob("tiny-*/done.log"))
                if found:
                    path = found[0].parent
                    return len(_log_indices(path)) >= kill_at
                return False

            assert _wait_for(reached, 120, proc), "the render ended before the kill point"
            before = len(_log_indices(path))
            os.killpg(proc.pid, signal.SIGKILL)  # the parent and its render workers
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate(timeout=60)
        done, _, _ = read_log(path / "done.log", VIEWS + TEST_VIEWS)
        assert done.sum() >= before  # lines logged before the kill are kept
    # the parent alone killed right after its workers started: the orphans must exit
    proc = _popen(args)
    try:
        assert _wait_for(lambda: len(_children(proc.pid)) >= 2, 60, proc)
        workers = [c for c in _children(proc.pid)]
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.communicate(timeout=60)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and any(_alive(w) for w in workers):
        time.sleep(0.1)
    assert not any(_alive(w) for w in workers), "orphaned render workers still running"
    # the final run renders exactly what is missing
    done_before, _, _ = read_log(path / "done.log", VIEWS + TEST_VIEWS)
    p = subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    assert f"({int(done_before.sum())} were done)" in p.stderr or done_before.all(), p.stderr[-2000:]
    counts = Counter(_log_indices(path))
    assert sorted(counts) == list(range(VIEWS + TEST_VIEWS)) and max(counts.values()) == 1, "a view was rendered twice"
    scene = build_scene(OmegaConf.load(ROOT / "conf" / "scene" / "tiny.yaml"))
    ref = render_cache(scene, {"num_views": VIEWS, "test_views": TEST_VIEWS, "resolution": RES, "workers": 0,
                               "cache_path": str(tmp_path / "ref")}, {"name": "vtk"}, progress=False)
    np.testing.assert_array_equal(np.asarray(ViewImageCache.open(path).images), np.asarray(ViewImageCache.open(ref.path).images))


def test_training_killed_at_several_epochs_resumes_from_the_newest_saved_one(tmp_path):
    epochs = 5
    args = ["imls_lightning.train", "model=recnn", "recnn=enhancenet", "recnn.net.channels=4", "recnn.net.blocks=1",
            "scene=tiny", "data=tiny", "renderer=numba", f"trainer.max_epochs={epochs}", "model.patience=100",
            "logger=none", "test=false", "trainer.enable_progress_bar=false", f"paths.runs_dir={tmp_path / 'runs'}",
            f"data.cache_dir={tmp_path / 'cache'}"]
    kills = 0
    seen_epochs: list[int] = []
    for _ in range(2):  # killed after the first saved epoch, then after the next one
        proc = _popen(args)
        try:
            def saved_after():
                lasts = list((tmp_path / "runs").glob("*/checkpoints/last.ckpt"))
                if not lasts:
                    return False
                try:
                    e = int(torch.load(lasts[0], map_location="cpu", weights_only=True)["epoch"])
                except Exception:  # being written
                    return False
                return e > (seen_epochs[-1] if seen_epochs else -1)

            assert _wait_for(saved_after, 300, proc), proc.communicate()[1][-2000:] if proc.poll() is not None else "timeout"
            os.killpg(proc.pid, signal.SIGKILL)
            kills += 1
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
            out, err = proc.communicate(timeout=60)
        last = next((tmp_path / "runs").glob("*/checkpoints/last.ckpt"))
        from imls_lightning.base.config import checkpoint_problem

        if checkpoint_problem(last) is None:
            seen_epochs.append(int(torch.load(last, map_location="cpu", weights_only=True)["epoch"]))
        if seen_epochs and seen_epochs[-1] >= epochs - 1:
            break
    p = subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=600,
                       env=dict(os.environ, OMP_NUM_THREADS="1"))
    assert p.returncode == 0, p.stderr[-2000:]
    assert "resuming from" in p.stdout, p.stdout[-2000:]
    resumed = Path(p.stdout.split("resuming from", 1)[1].split()[0])
    assert resumed.name == "last.ckpt" or "warning:" in p.stderr
    import json

    run_dir = next((tmp_path / "runs").glob("recnn-*"))
    assert json.loads((run_dir / "result.json").read_text())["epochs"] == epochs
    assert kills >= 1


def test_orp_sweep_killed_after_its_first_iml_job_resumes_reusing_finished_runs(tmp_path):
    """kill -9 of an ORP sweep once its RecNN and first IML run have finished: the rerun reuses both
    (nothing trained twice) and finishes the search."""
    tiny = ["model=iml", "recnn=enhancenet", "hydra/sweeper=orp", "scene=tiny", "data=tiny", "renderer=numba",
            "trainer.max_epochs=1", "recnn.net.channels=4", "recnn.net.blocks=1", "model.depth=2", "model.base_channels=4",
            "test=false", "trainer.enable_progress_bar=false", "sweeper.latency_views=1", "sweeper.latency_repeats=2",
            "sweeper.k=1", "sweeper.max_rounds=2", "sweeper.epsilon_db=100", "logger=none",
            f"paths.runs_dir={tmp_path / 'runs'}", f"data.cache_dir={tmp_path / 'cache'}"]
    proc = _popen(["imls_lightning.train", "-m", *tiny])
    try:
        finished = lambda: len(list((tmp_path / "runs").glob("iml-*/result.json"))) >= 1  # noqa: E731
        assert _wait_for(finished, 400, proc), "the sweep ended before the kill point"
        os.killpg(proc.pid, signal.SIGKILL)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate(timeout=60)
    done_before = {p.parent.name for p in (tmp_path / "runs").glob("*/result.json")}
    assert any(n.startswith("recnn-") for n in done_before) and any(n.startswith("iml-") for n in done_before)
    p = subprocess.run([sys.executable, "-m", "imls_lightning.train", "-m", *tiny], cwd=ROOT, capture_output=True, text=True,
                       timeout=600, env=dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="2"))
    assert p.returncode == 0, p.stderr[-2000:]
    reused = {Path(ln.split("] ", 1)[1].split(" already finished")[0]).name for ln in p.stdout.splitlines()
              if "already finished" in ln}
    assert done_before <= reused, (done_before, reused)
    assert any(ln.startswith("[orp] ") and ln.endswith("orp.yaml") for ln in p.stdout.splitlines())
