"""Render processes of the cache: a scene shipped to spawned workers, which render the views they
pull from a queue and write their pixels in place; the parent logs each finished view.

A scene whose volume is a read-only memory map travels as a reference to its file (the workers map
the same file) rather than as a copy of the array.
"""
from __future__ import annotations

import copy
import os
import pickle
import queue
import time
from typing import Any

import numpy as np

from imls_lightning.base.errors import InputError
from imls_lightning.base.orphans import exit_when_orphaned
from imls_lightning.render import make_renderer, render_image
from imls_lightning.render.scene import Scene

from .cache_log import write_view

def _memmap_ref(a: np.ndarray) -> dict[str, Any] | None:
    """``(file, offset, dtype, shape)`` of a C-contiguous read-only view into a file mapping, or None."""
    if not isinstance(a, np.memmap) or getattr(a, "_mmap", None) is None or not a.flags.c_contiguous:
        return None
    fn = getattr(a, "filename", None)
    if not fn or not os.path.isfile(fn):
        return None
    try:
        import mmap

        base = np.frombuffer(a._mmap, np.uint8)
        start = int(a.offset) - int(a.offset) % mmap.ALLOCATIONGRANULARITY
        off = start + (a.ctypes.data - base.ctypes.data)
        del base
        check = np.memmap(fn, dtype=a.dtype, mode="r", offset=off, shape=a.shape)
        k = min(a.size, 4096)
        if not np.array_equal(np.asarray(check.reshape(-1)[:k]), np.asarray(a.reshape(-1)[:k]), equal_nan=True):
            return None
        return {"file": fn, "offset": off, "dtype": a.dtype.str, "shape": a.shape}
    except Exception:  # any doubt: ship the array itself
        return None


def _scene_payload(scene: Scene) -> bytes:
    ref = _memmap_ref(scene.volume.data)
    if ref is None:
        return pickle.dumps(("array", scene), protocol=pickle.HIGHEST_PROTOCOL)
    vol = copy.copy(scene.volume)
    vol.data = np.zeros((2, 2, 2), np.uint8)  # placeholder, replaced in the worker
    light = copy.copy(scene)
    light.volume = vol
    return pickle.dumps(("memmap", light, ref), protocol=pickle.HIGHEST_PROTOCOL)


def _scene_from_payload(payload: bytes) -> Scene:
    kind, scene, *rest = pickle.loads(payload)
    if kind == "memmap":
        ref = rest[0]
        scene.volume.data = np.memmap(ref["file"], dtype=np.dtype(ref["dtype"]), mode="r", offset=ref["offset"], shape=tuple(ref["shape"]))
    return scene


def _orphan_exit(*queues) -> None:
    """Let a worker whose parent died exit at once: without this its queues' feeder threads would
    wait at exit for a reader that is gone."""
    for q in queues:
        q.cancel_join_thread()


def worker_main(setup, parent_pid, tasks, results):
    """Render views taken from ``tasks`` until a ``None``; report ``("done", i, crc, seconds)``.

    The scene, the views and the settings arrive through the ``setup`` queue rather than as
    process arguments: multiprocessing writes arguments into a pipe that blocks for ever if the
    child dies before reading them all (a large volume would hang the parent).
    """
    exit_when_orphaned(parent_pid)
    try:
        while True:  # never block for ever: a parent killed before its setup reached us leaves nothing to wait for
            try:
                payload, renderer_cfg, threads, images_path, data_offset, resolution, views, fsync, pixels, sparse = setup.get(timeout=0.5)
                break
            except queue.Empty:
                if os.getppid() != parent_pid:
                    _orphan_exit(setup, tasks, results)
                    return
        scene = _scene_from_payload(payload)
        renderer = make_renderer(scene, renderer_cfg, threads=threads)
        fd = os.open(images_path, os.O_WRONLY)
        results.put(("ready", os.getpid()))
        try:
            while True:
                if os.getppid() != parent_pid:  # the parent was killed: stop, leave no orphan work
                    _orphan_exit(setup, tasks, results)
                    return
                try:
                    i = tasks.get(timeout=0.5)
                except queue.Empty:
                    continue
                if i is None:
                    return
                img = render_image(renderer, views[i], resolution, pixels if sparse[i] else None)
                crc = write_view(fd, img, i, data_offset, fsync)
                results.put(("done", int(i), crc, float(renderer.last_render_seconds)))
        finally:
            os.close(fd)
    except InputError as err:
        results.put(("error", str(err), True))
    except BaseException as err:  # reported to the parent, which raises it
        import traceback

        results.put(("error", f"render worker {os.getpid()} failed: {type(err).__name__}: {err}\n{traceback.format_exc()}", False))


def run_workers(scene, rcfg, threads, images_path, offset, m, views, todo, workers, fsync, log, bar, report,
                pixels=None, sparse=None):
    """Render rows ``todo`` of ``views`` in ``workers`` spawned processes of ``threads`` threads each
    (rows ``i`` with ``sparse[i]`` only at ``pixels``: :func:`~imls_lightning.render.render_image`).

    Each worker writes its views' pixels in place into ``images_path`` (data at ``offset``); this
    process logs every finished view to ``log`` (a :class:`~data_gen.cache_log.CompletionLog`),
    advances ``bar`` and adds to ``report`` (``rendered``, ``render_seconds``, ``startup_seconds``).

    Raises:
        InputError: a worker's one-line input error.
        RuntimeError: a worker failed otherwise, or died with views left (run again to resume).
    """
    import multiprocessing as mp

    ctx = mp.get_context("spawn")  # VTK and OpenGL state must not be forked
    setup, tasks, results = ctx.Queue(), ctx.Queue(), ctx.Queue()
    # dynamic load balancing: views near the volume cost more than far ones, so workers pull
    # the next index when they are free instead of owning a fixed share
    for i in todo:
        tasks.put(int(i))
    for _ in range(workers):
        tasks.put(None)
    if sparse is None:
        sparse = np.zeros(len(views), bool)
    payload = (_scene_payload(scene), rcfg, threads, str(images_path), offset, m, views, fsync, pixels, sparse)
    for _ in range(workers):
        setup.put(payload)
    procs = [ctx.Process(target=worker_main, args=(setup, os.getpid(), tasks, results), daemon=True) for _ in range(workers)]
    for p in procs:
        p.start()
    remaining = set(int(i) for i in todo)
    error: tuple[str, bool] | None = None
    t0 = time.perf_counter()
    try:
        while remaining:
            try:
                msg = results.get(timeout=1.0)
            except queue.Empty:
                if not any(p.is_alive() for p in procs):
                    # drain what arrived just before the last worker exited
                    try:
                        msg = results.get(timeout=1.0)
                    except queue.Empty:
                        break
                else:
                    continue
            if msg[0] == "ready":
                report.startup_seconds = max(report.startup_seconds, time.perf_counter() - t0)
            elif msg[0] == "done":
                _, i, crc, sec = msg
                log.append(i, crc, sec)
                remaining.discard(i)
                report.rendered += 1
                report.render_seconds += sec
                bar.update(1)
            elif msg[0] == "error":
                error = (msg[1], msg[2])
                break
    finally:
        if error is not None or remaining:
            for p in procs:
                if p.is_alive():
                    p.terminate()
        for p in procs:
            p.join(timeout=10)
            if p.is_alive():
                p.kill()
        for q in (setup, tasks, results):
            q.cancel_join_thread()
    if error is not None:
        if error[1]:
            raise InputError(error[0])
        raise RuntimeError(error[0])
    if remaining:
        codes = [p.exitcode for p in procs]
        raise RuntimeError(f"render workers exited (codes {codes}) with {len(remaining)} views not rendered; run again to resume")

__all__ = ["run_workers", "worker_main"]
