"""The (view, full-resolution image) cache: hashed, atomic, resumable, rendered in parallel.

One directory per hash of everything that changes the pixels, ``<data.cache_dir>/<scene>-<hash12>``
(or exactly ``data.cache_path``); the scene part holds the *resolved* sample distance, in normalized
units and in voxels, so ``sample_distance: auto`` keys by the step it means::

    manifest.json        settings (hashed part + provenance), counts, runs, the resolved sample
                         distance (normalized and in voxels); written last, atomically
    views.npy            (N, 9) float32: train+val views (rows 0..V-1), then the test trajectory
    splits.json          {"train": [...], "val": [...], "test": [...]} row indices
    images.npy           (N, m, m, 3) uint8, created sparse with ``np.lib.format.open_memmap`` and
                         written in place, one view at a time
                         (with ``train_pixels``, the training rows hold only those pixels, the rest
                         black: a C-Image-only cache for a model that needs no FR-Image, the IMS;
                         ``manifest["settings"]["train_pixels"]`` and :attr:`ViewImageCache.sparse_rows`)
    done.log             append-only completion log, one line per finished view:
                         ``<index> <crc32 of its pixels> <render seconds> <crc32 of the line>``
    render_seconds.npy   (N,) float32 copy of the log's render seconds (NaN: not rendered yet)
    .lock                file lock: one rendering run per cache at a time (sharded runs hold it only
                         while they create/check the files and update the manifest)
    .imls-cache          marker: this tool created the directory (written first, before any other file)
    done-shard-I-of-N.log, .lock-shard-I-of-N
                         a sharded run's own completion log and lock (``data.shard=I/N``, below)

Crash safety. A view counts as done only when its log line is intact. The line is appended (and
fsync'd) by the parent process only after the worker has written the view's pixels and flushed
them to disk (``fdatasync``), so after a crash or ``kill -9`` at any moment every logged view has its
pixels, and a view whose pixels were half-written has no (intact) line and is rendered again. The
metadata files are written to a temporary name and renamed (atomic), the manifest last: a
directory without a manifest but with the tool's marker is an unfinished initialisation and is redone
from scratch.

Trust. The tool writes only into a directory it created (one with its ``manifest.json`` or its
``.imls-cache`` marker) or an empty one; any other existing directory is refused in one line, before
anything (not even a lock file) is written into it. Every view's pixels are checked against the
CRC-32 logged when they were written, each time a cache is opened or rendered (a CRC-32 costs about
0.4 ms per 512x512 view, over 1000x less than rendering it: ``scripts/measure_pixel_check.py``, removed after its result
was committed: ``git show 97cc83f:scripts/measure_pixel_check.py``): a rendering run
re-renders the views that fail, with a one-line warning; :meth:`ViewImageCache.open` refuses them in
one line. A truncated ``images.npy`` is extended (the views whose pixels were lost fail their check
and are re-rendered) and a truncated or deleted ``views.npy`` / ``splits.json`` is rewritten from the
settings (which hash them), each with a one-line warning. A complete cache in a directory this
process cannot write (a read-only mount) is opened without any write.

Sharding (``data.shard=I/N``, not part of the hash). N processes, on one machine or on N nodes that
share the cache directory, each render the disjoint subset ``{views j : j mod N == I}`` (interleaved,
so near and far views spread evenly) concurrently. The first to arrive creates the files under
``.lock``; rendering then runs outside it, each shard under its own ``.lock-shard-I-of-N`` (a second
process given the same shard waits instead of duplicating work), pixels written in place into
disjoint rows of ``images.npy``, completions logged to the shard's own append-only log (one
writer per file, so no interleaved lines even on network filesystems). Every reader merges
``done.log`` with the shard logs. Each shard takes ``.lock`` again only to refresh the manifest.
The cache is complete when every shard has finished; a run without ``data.shard`` completes
whatever is still missing.

Modules. This one runs a cache's life cycle (trust, initialisation, repair, locks, rendering what is
missing) and re-exports the public names of the others, so ``data_gen.cache`` is the one import:
:mod:`data_gen.cache_keys` (file names, ``data`` settings, planned views, the settings hash),
:mod:`data_gen.cache_log` (completion log, pixel writes and checksums), :mod:`data_gen.cache_workers`
(render processes) and :mod:`data_gen.cache_reader` (:class:`ViewImageCache`).

Example:
    >>> path = ensure_cache(scene, {"num_views": 24, "resolution": 32, "test_views": 12,
    ...                             "cache_dir": "cache"}, {"name": "vtk"})   # doctest: +SKIP
    >>> c = ViewImageCache.open(path)                                        # doctest: +SKIP
    >>> c.views.shape, c.images.shape, {k: len(v) for k, v in c.splits.items()}  # doctest: +SKIP
    ((36, 9), (36, 32, 32, 3), {'train': 22, 'val': 2, 'test': 12})
"""
from __future__ import annotations

import datetime as _dt
import json
import os
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from imls_lightning.base.atomic import atomic_json, atomic_npy
from imls_lightning.base.errors import InputError
from imls_lightning.base.validate import check_mapping
from imls_lightning.render import make_renderer, render_image, renderer_pixel_settings, renderer_version
from imls_lightning.render.scene import Scene, voxel_size

from .cache_keys import (
    DATA_DEFAULTS,
    FORMAT_VERSION,
    IMAGES,
    LOCK,
    LOG,
    MANIFEST,
    MARKER,
    OWN_FILES,
    SECONDS,
    SHARD_LOGS,
    SPLITS,
    VIEWS,
    cache_path_for,
    cache_settings,
    check_train_pixels,
    data_settings,
    is_own_file,
    json_default,
    jsonable,
    parse_shard,
    plan_views,
    safe_name,
    settings_hash,
    shard_log_name,
)
from .cache_log import CompletionLog, bad_views, read_log, read_logs, remember_checked, write_view
from .cache_reader import ViewImageCache
from .cache_workers import run_workers


def _atomic_json(path: Path, obj: Any) -> None:
    atomic_json(path, obj, default=json_default)


# ---------------------------------------------------------------------------------------------
# the cache
# ---------------------------------------------------------------------------------------------
@dataclass
class CacheReport:
    """What one :func:`render_cache` call did."""

    path: Path
    total: int
    already_done: int
    rendered: int
    workers: int
    threads: int
    wall_seconds: float = 0.0
    render_seconds: float = 0.0  # sum of the renderer's own render-call times in this run
    startup_seconds: float = 0.0  # until the last worker had built its renderer (process start, imports, scene)
    shard: tuple[int, int] | None = None  # (I, N) of a sharded run

    @property
    def outside_render_share(self) -> float:
        """Share of the workers' wall time not spent inside the render call (0 when nothing ran)."""
        if self.rendered == 0 or self.wall_seconds <= 0:
            return 0.0
        return max(0.0, 1.0 - self.render_seconds / (max(1, self.workers) * self.wall_seconds))

    def summary(self) -> str:
        if self.shard is not None:
            head = f"shard {self.shard[0]}/{self.shard[1]}: "
            if self.rendered == 0:
                return f"{head}nothing left to render in this shard: {self.path}"
        else:
            head = ""
            if self.rendered == 0:
                return f"cache complete ({self.total} views), nothing to render: {self.path}"
        return head + (
            f"rendered {self.rendered} views ({self.already_done} were done) with {self.workers or 1} process(es) "
            f"x {self.threads} thread(s) in {self.wall_seconds:.1f} s: {self.render_seconds / self.rendered:.4f} s "
            f"render call per view, {self.wall_seconds / self.rendered:.4f} s wall per view, "
            f"{100 * self.outside_render_share:.1f}% of the time outside the render call"
            + (f" (worker start-up {self.startup_seconds:.1f} s)" if self.startup_seconds else "")
        )


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def _settings_diff(a: Any, b: Any, prefix: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out: list[str] = []
        for k in sorted(set(a) | set(b)):
            out += _settings_diff(a.get(k), b.get(k), f"{prefix}.{k}" if prefix else str(k))
        return out
    return [] if a == b else [prefix or "(all)"]


def _what(path: Path, user_dir: bool) -> str:
    return f"data.cache_path={path}" if user_dir else f"data.cache_dir={path.parent}"


def _check_ours(path: Path, user_dir: bool) -> None:
    """Refuse (one line, writing nothing) an existing directory the tool did not create: one with
    neither a manifest nor the tool's marker that is not empty."""
    if not path.exists():
        return
    if not path.is_dir():
        raise InputError(f"{_what(path, user_dir)}: {path} is a file, expected a directory")
    if (path / MANIFEST).is_file() or (path / MARKER).is_file():
        return
    try:
        names = sorted(p.name for p in path.iterdir())
    except OSError as err:
        raise InputError(f"{_what(path, user_dir)}: cannot list {path} ({err.strerror or err})") from None
    if names:
        raise InputError(
            f"{_what(path, user_dir)}: {path} is not a cache made by this tool (no {MANIFEST} or {MARKER}) and not empty "
            f"(holds {', '.join(names[:3])}{', ...' if len(names) > 3 else ''}); choose an empty or new directory"
        )


def _prepare_dir(path: Path, user_dir: bool) -> bool:
    """Create the cache directory and the tool's marker in it (first of its files); returns whether
    the directory was created now. One-line errors."""
    existed = path.is_dir()
    try:
        path.mkdir(parents=True, exist_ok=True)
        if not (path / MANIFEST).is_file() and not (path / MARKER).is_file():
            (path / MARKER).write_bytes(b"made by imls-lightning (data_gen.cache); safe to delete with the directory\n")
        probe = path / f".write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as err:
        if not existed and path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        raise InputError(f"{_what(path, user_dir)}: not writable ({err.strerror or type(err).__name__})") from None
    return not existed


def _remove_own_files(path: Path, everything: bool = False) -> None:
    """Delete the cache's files (``everything``: also its lock and marker)."""
    for name in OWN_FILES:
        if name in (LOCK, MARKER) and not everything:
            continue
        for p in (path / name, path / (name + ".tmp")):
            try:
                p.unlink()
            except FileNotFoundError:
                pass
    for p in path.glob(SHARD_LOGS):  # logs of a cache that no longer exists
        p.unlink(missing_ok=True)


def _initialise(path: Path, settings, manifest, views, splits, m: int, user_dir: bool) -> None:
    """Write a fresh cache's files, the manifest last (the directory is locked)."""
    foreign = [p.name for p in path.iterdir() if not is_own_file(p.name) and not p.name.endswith(".tmp")
               and not p.name.startswith(".write-test-")]
    if foreign:
        what = f"data.cache_path={path}" if user_dir else f"cache directory {path}"
        raise InputError(f"{what}: not a cache (no {MANIFEST}) and not empty (holds {', '.join(sorted(foreign)[:3])}); choose an empty or new directory")
    _remove_own_files(path)  # leftovers of an initialisation that was interrupted
    atomic_npy(path / VIEWS, views)
    _atomic_json(path / SPLITS, {k: v.tolist() for k, v in splits.items()})
    tmp = path / (IMAGES + ".tmp")
    # a sparse file: only the header is written now; each view's pixels land in place later
    mm = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.uint8, shape=(len(views), m, m, 3))
    del mm
    with open(tmp, "rb+") as f:
        os.fsync(f.fileno())
    os.replace(tmp, path / IMAGES)
    (path / LOG).write_bytes(b"")
    atomic_npy(path / SECONDS, np.full(len(views), np.nan, np.float32))
    _atomic_json(path / MANIFEST, manifest)


def _npy_data_offset(path: Path) -> int:
    with open(path, "rb") as f:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            np.lib.format.read_array_header_1_0(f)
        else:
            np.lib.format.read_array_header_2_0(f)
        return f.tell()


def _dir_writable(path: Path) -> bool:
    return os.access(path, os.W_OK | os.X_OK)


def _read_manifest(path: Path, settings) -> dict:
    """The manifest of ``path``, checked to belong to ``settings``; one-line errors."""
    try:
        manifest = json.loads((path / MANIFEST).read_text())
    except (OSError, ValueError):
        raise InputError(f"cache directory {path}: {MANIFEST} is unreadable; delete the directory to re-render it") from None
    if not isinstance(manifest, dict) or manifest.get("settings") != settings:
        diff = _settings_diff(manifest.get("settings") if isinstance(manifest, dict) else None, settings)
        raise InputError(
            f"cache directory {path}: its {MANIFEST} belongs to other settings (differs in {', '.join(diff[:4])}"
            f"{', ...' if len(diff) > 4 else ''}); use another data.cache_dir / data.cache_path or delete it"
        )
    return manifest


def _warn(message: str) -> None:
    print("warning: " + " ".join(str(message).split()), file=sys.stderr, flush=True)


def _load_npy(path: Path) -> np.ndarray | None:
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError):
        return None


def _images_header(path: Path) -> tuple[tuple, np.dtype, int] | None:
    """``(shape, dtype, data offset)`` of an ``.npy`` file's header, or None when unreadable."""
    try:
        with open(path, "rb") as f:
            version = np.lib.format.read_magic(f)
            read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, fortran, dtype = read(f)
            return (tuple(shape), np.dtype(dtype), f.tell()) if not fortran else None
    except (OSError, ValueError, EOFError):
        return None


def _repair_metadata(path: Path, views: np.ndarray, splits: dict[str, np.ndarray], m: int) -> None:
    """Repair, under the cache lock, what the settings (whose hash covers the views and splits)
    determine: a missing or truncated ``views.npy`` / ``splits.json`` is rewritten; a truncated
    ``images.npy`` is extended to its full size (the views whose pixels were cut off then fail their
    checksums and are re-rendered) and one with a broken header is made anew. One-line warnings."""
    stored = _load_npy(path / VIEWS)
    if stored is None or stored.shape != views.shape or not np.array_equal(stored, views):
        _warn(f"cache {path}: {VIEWS} is missing, truncated or changed; rewriting it from the settings")
        atomic_npy(path / VIEWS, views)
    want = {k: v.tolist() for k, v in splits.items()}
    try:
        ok = json.loads((path / SPLITS).read_text()) == want
    except (OSError, ValueError):
        ok = False
    if not ok:
        _warn(f"cache {path}: {SPLITS} is missing, truncated or changed; rewriting it from the settings")
        _atomic_json(path / SPLITS, want)
    shape = (len(views), m, m, 3)
    head = _images_header(path / IMAGES)
    if head is None or head[0] != shape or head[1] != np.dtype(np.uint8):
        _warn(f"cache {path}: {IMAGES} is missing or its header is damaged; every view is checked and re-rendered as needed")
        tmp = path / (IMAGES + ".tmp")
        mm = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.uint8, shape=shape)
        del mm
        os.replace(tmp, path / IMAGES)
        return
    full = head[2] + int(np.prod(shape))
    size = (path / IMAGES).stat().st_size
    if size < full:
        _warn(f"cache {path}: {IMAGES} is truncated ({size} of {full} bytes); the views cut off are re-rendered")
        os.truncate(path / IMAGES, full)  # sparse: the lost views read as zeros and fail their checksums


def _read_only_report(path: Path, settings, n: int) -> CacheReport:
    """A complete cache this process cannot write: checked, then used as it is (no file is written)."""
    _read_manifest(path, settings)
    c = ViewImageCache.open(path)  # one-line error when incomplete or damaged (it cannot be repaired here)
    return CacheReport(path, n, int(c.done.sum()), 0, 0, 0)


def render_cache(scene: Scene, data_cfg, renderer_cfg=None, progress: bool = True, train_pixels=None) -> CacheReport:
    """Render whatever is missing from the cache of ``(scene, data, renderer)``; see the module doc.

    Args:
        scene: the scene.
        data_cfg: the ``data`` node (see :data:`DATA_DEFAULTS`).
        renderer_cfg: the ``renderer`` node (``name``, ``mapper``, ``threads``).
        progress: show a tqdm progress bar on stderr.
        train_pixels: ``None``, or the flat raster indices ``(K,)`` of the only pixels the training
            views are rendered at (a pattern's C-pixels; every other pixel of those rows stays black).
            Validation and test views are always whole frames. Part of the cache key
            (:func:`~data_gen.cache_keys.check_train_pixels`).

    Returns:
        A :class:`CacheReport` (its ``path`` is the cache directory).

    Raises:
        InputError: bad settings, degenerate views, an unwritable cache directory, a directory whose
            manifest belongs to other settings, too little free disk space.
    """
    from filelock import FileLock

    d = data_settings(data_cfg)
    rcfg = check_mapping(renderer_cfg, "renderer") if renderer_cfg is not None else {"name": "vtk"}
    renderer_pixel_settings(rcfg)  # validates the renderer name before anything touches the disk
    m = d["resolution"]
    views, splits = plan_views(scene, d)
    pixels = check_train_pixels(train_pixels, m)
    settings = cache_settings(scene, d, rcfg, views, splits, train_pixels=pixels)
    key = settings_hash(settings)
    user_dir = bool(d.get("cache_path"))
    path = Path(str(d["cache_path"])).expanduser() if user_dir else Path(str(d["cache_dir"])).expanduser() / f"{safe_name(scene.name)}-{key}"
    path = path.absolute()
    n = len(views)
    _check_ours(path, user_dir)
    if (path / MANIFEST).is_file() and not _dir_writable(path):
        # a finished cache on a read-only mount: read, never write (not even a lock)
        return _read_only_report(path, settings, n)
    was_empty = path.is_dir() and not any(path.iterdir())
    created = _prepare_dir(path, user_dir)
    lock = FileLock(str(path / LOCK))
    _acquire(lock, path, f"waiting for another run that is rendering {path} ...")
    try:
        try:
            mpath = path / MANIFEST
            if mpath.is_file():
                manifest = _read_manifest(path, settings)
                _repair_metadata(path, views, splits, m)
            else:
                manifest = {
                    "format_version": FORMAT_VERSION,
                    "hash": key,
                    "settings": settings,
                    "scene": jsonable(scene.pixel_settings()),
                    "scene_config": jsonable(scene.config) if scene.config is not None else None,
                    "renderer": jsonable({**rcfg, "pixel_settings": renderer_pixel_settings(rcfg), "version": renderer_version(rcfg)}),
                    "resolution": m,
                    "view_angle": float(scene.view_angle),
                    # the resolved ray step (scene.sample_distance: auto = half a voxel), in both units
                    "sample_distance": {"normalized": float(scene.sample_distance), "voxels": scene.sample_distance_voxels,
                                        "voxel_size_normalized": voxel_size(scene.volume)},
                    "data": jsonable({k: d[k] for k in ("num_views", "test_views", "val_fraction", "seed", "lookat_jitter", "test_trajectory")}),
                    "counts": {"train": len(splits["train"]), "val": len(splits["val"]), "test": len(splits["test"]), "total": n},
                    "files": {"views": VIEWS, "splits": SPLITS, "images": IMAGES, "log": LOG, "render_seconds": SECONDS},
                    "view_fields": ["eye_x", "eye_y", "eye_z", "lookat_x", "lookat_y", "lookat_z", "up_x", "up_y", "up_z"],
                    "created": _now(),
                    "complete": 0,
                    "runs": [],
                }
                _initialise(path, settings, manifest, views, splits, m, user_dir)
        except BaseException:
            if created:  # nothing of ours may stay behind half-made
                lock.release()
                shutil.rmtree(path, ignore_errors=True)
            elif was_empty and not (path / MANIFEST).is_file():  # a user's empty directory: empty again
                lock.release()
                _remove_own_files(path, everything=True)
            raise
        sparse = np.zeros(n, bool)
        if pixels is not None:
            sparse[splits["train"]] = True
        if d["shard"] is None:
            return _render_missing(scene, d, rcfg, path, manifest, views, progress, pixels=pixels, sparse=sparse)
    finally:
        if lock.is_locked:
            lock.release()
    # sharded: render outside the cache lock, under the shard's own lock
    i, k = d["shard"]
    shard_lock = FileLock(str(path / f".lock-shard-{i}-of-{k}"))
    _acquire(shard_lock, path, f"waiting for another run that is rendering shard {i}/{k} of {path} ...")
    try:
        return _render_missing(scene, d, rcfg, path, None, views, progress, cache_lock=lock, pixels=pixels, sparse=sparse)
    finally:
        shard_lock.release()


def _acquire(lock, path: Path, waiting: str) -> None:
    """Take a FileLock, saying once on stderr when it has to wait; one-line error if it cannot."""
    from filelock import Timeout

    try:
        try:
            lock.acquire(timeout=0)
        except Timeout:
            print(waiting, file=sys.stderr, flush=True)
            lock.acquire()
    except OSError as err:
        raise InputError(f"data.cache_dir={path.parent}: cannot lock {lock.lock_file} ({err.strerror or err})") from None


def _render_missing(scene, d, rcfg, path: Path, manifest, views, progress, cache_lock=None, pixels=None,
                    sparse=None) -> CacheReport:
    """Render the views not logged yet (of ``d["shard"]`` only, when set: then ``manifest`` is None
    and ``cache_lock`` is the cache's lock, taken again to update the manifest); rows ``i`` with
    ``sparse[i]`` only at ``pixels``."""
    n, m = len(views), d["resolution"]
    sparse = np.zeros(n, bool) if sparse is None else sparse
    shard = d.get("shard")
    done, crc, _ = read_logs(path, n)
    # never trust logged pixels unchecked: a view changed after it was written is rendered again
    mine = np.flatnonzero(done) if shard is None else np.flatnonzero(done & (np.arange(n) % shard[1] == shard[0]))
    bad = bad_views(np.load(path / IMAGES, mmap_mode="r", allow_pickle=False), mine, crc)
    if len(bad):
        _warn(f"cache {path}: {len(bad)} view(s) whose pixels do not match their checksums (rows "
              f"{', '.join(map(str, bad[:5]))}{', ...' if len(bad) > 5 else ''}); re-rendering them")
        done[bad] = False
    todo = np.flatnonzero(~done)
    if shard is not None:
        todo = todo[todo % shard[1] == shard[0]]
    workers = min(d["workers"], len(todo)) if d["workers"] > 0 else 0
    threads = int(rcfg.get("threads") or 0) or max(1, _cores() // max(1, workers))
    report = CacheReport(path, n, int(done.sum()), 0, workers, threads, shard=shard)

    def finish(run):
        if shard is None:
            _finish(path, manifest, n, run)
            return
        with cache_lock:  # other shards update the manifest too: read it afresh under the lock
            _finish(path, json.loads((path / MANIFEST).read_text()), n, None if run is None else {**run, "shard": f"{shard[0]}/{shard[1]}"})

    if len(todo) == 0:
        finish(None)
        if shard is None:
            remember_checked(path)
        return report
    need = len(todo) * m * m * 3
    free = shutil.disk_usage(path).free
    if need > free:
        raise InputError(f"data.cache_dir={path.parent}: {need / 2**30:.2f} GiB needed for {len(todo)} images, only {free / 2**30:.2f} GiB free")

    from tqdm import tqdm

    own = np.arange(n) if shard is None else np.arange(shard[0], n, shard[1])
    bar = tqdm(total=len(own), initial=int(done[own].sum()), unit="view", disable=not progress, file=sys.stderr,
               desc=f"render {scene.name} {m}x{m}" + (f" shard {shard[0]}/{shard[1]}" if shard else ""),
               dynamic_ncols=True, smoothing=0.05)
    log = CompletionLog(path / (LOG if shard is None else shard_log_name(shard)), d["fsync"])
    offset = _npy_data_offset(path / IMAGES)
    t0 = time.perf_counter()
    started = _now()
    try:
        if workers == 0:
            renderer = make_renderer(scene, rcfg, threads=threads)
            report.startup_seconds = time.perf_counter() - t0
            fd = os.open(path / IMAGES, os.O_WRONLY)
            try:
                for i in todo:
                    img = render_image(renderer, views[i], m, pixels if sparse[i] else None)
                    crc = write_view(fd, img, int(i), offset, d["fsync"])
                    log.append(int(i), crc, renderer.last_render_seconds)
                    report.rendered += 1
                    report.render_seconds += renderer.last_render_seconds
                    bar.update(1)
            finally:
                os.close(fd)
                if hasattr(renderer, "close"):
                    renderer.close()
        else:
            run_workers(scene, rcfg, threads, path / IMAGES, offset, m, views, todo, workers, d["fsync"], log, bar, report,
                        pixels=pixels, sparse=sparse)
    finally:
        report.wall_seconds = time.perf_counter() - t0
        log.close()
        bar.close()
        finish({
            "started": started, "finished": _now(), "rendered": report.rendered, "workers": workers,
            "threads": threads, "wall_seconds": round(report.wall_seconds, 4),
            "render_seconds": round(report.render_seconds, 4),
            "outside_render_share": round(report.outside_render_share, 4),
            "startup_seconds": round(report.startup_seconds, 4),
        })
    if shard is None:
        remember_checked(path)  # every logged view was checked or written (and checksummed) just now
    return report


def _finish(path: Path, manifest: dict, n: int, run: dict | None) -> None:
    """Refresh render_seconds.npy and the manifest's progress from the log (atomically)."""
    done, _, sec = read_logs(path, n)
    k = int(done.sum())
    if run is None and manifest.get("complete") == k and (path / SECONDS).is_file():
        return  # nothing changed: leave the files alone
    atomic_npy(path / SECONDS, sec)
    manifest["complete"] = k
    manifest["updated"] = _now()
    if run is not None:
        manifest.setdefault("runs", []).append(run)
    _atomic_json(path / MANIFEST, manifest)


def ensure_cache(scene: Scene, data_cfg, renderer_cfg=None, progress: bool = True, train_pixels=None) -> Path:
    """Render what is missing and return the cache directory (see :func:`render_cache`)."""
    return render_cache(scene, data_cfg, renderer_cfg, progress=progress, train_pixels=train_pixels).path

__all__ = [
    "ensure_cache", "render_cache", "ViewImageCache", "CacheReport", "cache_path_for", "cache_settings",
    "data_settings", "parse_shard", "plan_views", "read_log", "read_logs", "bad_views", "DATA_DEFAULTS",
    "FORMAT_VERSION", "LOG", "MANIFEST", "VIEWS", "SPLITS", "IMAGES", "SECONDS", "LOCK", "MARKER",
]
