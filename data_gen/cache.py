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
0.4 ms per 512x512 view, over 1000x less than rendering it: ``scripts/measure_pixel_check.py``): a rendering run
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

Example:
    >>> path = ensure_cache(scene, {"num_views": 24, "resolution": 32, "test_views": 12,
    ...                             "cache_dir": "cache"}, {"name": "vtk"})   # doctest: +SKIP
    >>> c = ViewImageCache.open(path)                                        # doctest: +SKIP
    >>> c.views.shape, c.images.shape, {k: len(v) for k, v in c.splits.items()}  # doctest: +SKIP
    ((36, 9), (36, 32, 32, 3), {'train': 22, 'val': 2, 'test': 12})
"""
from __future__ import annotations

import copy
import datetime as _dt
import hashlib
import json
import os
import pickle
import queue
import re
import shutil
import sys
import time
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .atomic import atomic_json, atomic_npy, atomic_write, fsync_dir
from .errors import InputError
from .renderers import make_renderer, renderer_pixel_settings, renderer_version
from .scene import Scene, voxel_size
from .views import (
    exploration_trajectory,
    load_views_file,
    sample_training_views,
    split_train_val,
    validate_views,
)

FORMAT_VERSION = 1

MANIFEST, VIEWS, SPLITS, IMAGES, LOG, SECONDS, LOCK, MARKER = (
    "manifest.json", "views.npy", "splits.json", "images.npy", "done.log", "render_seconds.npy", ".lock",
    ".imls-cache",
)
# every file a cache directory may hold (temporary files are these names + ".tmp"), besides the
# per-shard logs and locks (_SHARD_FILE)
_OWN_FILES = (MANIFEST, VIEWS, SPLITS, IMAGES, LOG, SECONDS, LOCK, MARKER, "contact_sheet.png")
_SHARD_FILE = re.compile(r"^(done-shard-\d+-of-\d+\.log|\.lock-shard-\d+-of-\d+)$")


def _shard_log_name(shard: tuple[int, int]) -> str:
    return f"done-shard-{shard[0]}-of-{shard[1]}.log"


def _is_own(name: str) -> bool:
    return name in _OWN_FILES or _SHARD_FILE.match(name) is not None

#: the ``data`` node's keys this module reads, with their defaults (paper scale); other keys
#: (``batch_size``, ``loader_workers``, ...) belong to the DataModule and are ignored here
DATA_DEFAULTS: dict[str, Any] = {
    "num_views": 2000,        # train + val views (paper: 2000, split 9:1)
    "test_views": 120,        # length of the exploratory test trajectory (paper: 120)
    "val_fraction": 0.1,
    "seed": 0,
    "lookat_jitter": 0.1,     # radius of the look-at ball around the centre (normalized units)
    "test_trajectory": None,  # a user's own test views (.npy / text, rows of 9) instead of the synthetic path
    "resolution": 512,        # m: FR-Image side (paper: 512)
    "workers": 2,             # render processes (0: render in this process)
    "cache_dir": "cache",
    "cache_path": None,       # exact directory instead of <cache_dir>/<scene>-<hash>
    "fsync": True,            # flush every view to disk before logging it (power-loss safety)
    "shard": None,            # "I/N": render only views j with j mod N == I (not part of the hash)
}


# ---------------------------------------------------------------------------------------------
# settings
# ---------------------------------------------------------------------------------------------
def _plain(cfg, what: str = "data") -> dict[str, Any]:
    if cfg is None:
        return {}
    try:
        from omegaconf import DictConfig, OmegaConf

        if isinstance(cfg, DictConfig):
            return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]
    except ImportError:  # pragma: no cover
        pass
    if not isinstance(cfg, Mapping):
        raise InputError(f"{what}: expected a mapping of settings, got {type(cfg).__name__}")
    return dict(cfg)


def _int(name: str, value, minimum: int) -> int:
    ok = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
    if not ok and isinstance(value, float) and value.is_integer():
        ok, value = True, int(value)
    if not ok or int(value) < minimum:
        raise InputError(f"data.{name}={value}: expected an integer >= {minimum}")
    return int(value)


def data_settings(data_cfg) -> dict[str, Any]:
    """The ``data`` node with defaults filled in and every value checked.

    Raises:
        InputError: ``resolution <= 0``, ``num_views < 1``, a bad fraction, ...
    """
    raw = _plain(data_cfg)
    # a missing or null key takes the default (null is the default of the two optional paths)
    d = {k: v if raw.get(k) is None else raw[k] for k, v in DATA_DEFAULTS.items()}
    d["resolution"] = _int("resolution", d["resolution"], 1)
    d["num_views"] = _int("num_views", d["num_views"], 1)
    d["test_views"] = _int("test_views", d["test_views"], 0)
    d["workers"] = _int("workers", d["workers"], 0)
    d["seed"] = _int("seed", d["seed"], 0)
    try:
        d["val_fraction"] = float(d["val_fraction"])
        d["lookat_jitter"] = float(d["lookat_jitter"])
    except (TypeError, ValueError):
        raise InputError(f"data.val_fraction={d['val_fraction']} / data.lookat_jitter={d['lookat_jitter']}: expected numbers") from None
    if not (0.0 <= d["val_fraction"] < 1.0):
        raise InputError(f"data.val_fraction={d['val_fraction']}: expected a number in [0, 1)")
    if not (np.isfinite(d["lookat_jitter"]) and d["lookat_jitter"] >= 0):
        raise InputError(f"data.lookat_jitter={d['lookat_jitter']}: expected a number >= 0 (normalized units)")
    if not str(d["cache_dir"]).strip():
        raise InputError("data.cache_dir: empty (expected a directory)")
    d["fsync"] = bool(d["fsync"])
    d["shard"] = parse_shard(d["shard"])
    return d


def parse_shard(value) -> tuple[int, int] | None:
    """``data.shard``: ``None`` (everything), ``"I/N"`` or ``[I, N]`` with ``0 <= I < N`` -> ``(I, N)``.

    Example:
        >>> parse_shard("1/4"), parse_shard(None)
        ((1, 4), None)
    """
    if value is None or (isinstance(value, str) and value.strip().lower() in ("", "null", "none")):
        return None
    parts = value.split("/") if isinstance(value, str) else value
    try:
        i, k = (int(str(p).strip()) for p in parts)
    except (TypeError, ValueError):
        raise InputError(f"data.shard={value!r}: expected I/N, e.g. data.shard=0/4 (shard I of N, 0 <= I < N)") from None
    if not (k >= 1 and 0 <= i < k):
        raise InputError(f"data.shard={value!r}: expected I/N with 0 <= I < N")
    return i, k


def plan_views(scene: Scene, d: Mapping[str, Any]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """All views of a cache and its splits.

    Returns:
        ``views`` ``(N, 9)`` float32 (``num_views`` training views, then the test views) and
        ``splits`` ``{"train", "val", "test"}`` of int64 row indices (disjoint, covering).
    """
    n, t = int(d["num_views"]), int(d["test_views"])
    train = sample_training_views(n, scene.camera_distance, seed=d["seed"], lookat_jitter=d["lookat_jitter"])
    if d.get("test_trajectory"):
        test = load_views_file(d["test_trajectory"])
    elif t > 0:
        test = exploration_trajectory(t, scene.camera_distance, seed=d["seed"], lookat_jitter=d["lookat_jitter"])
    else:
        test = np.zeros((0, 9))
    split = split_train_val(n, val_fraction=d["val_fraction"], seed=d["seed"])
    views = np.concatenate([train, test], axis=0).astype(np.float32)
    # the float32 views are what is stored and rendered: check them again after rounding
    validate_views(views, name="view")
    splits = {"train": split["train"], "val": split["val"], "test": np.arange(n, n + len(test), dtype=np.int64)}
    return views, splits


def _scene_key(scene: Scene) -> dict[str, Any]:
    """Scene pixel settings without provenance that cannot change pixels (file location, notes)."""
    s = copy.deepcopy(scene.pixel_settings())
    s["volume"].pop("source", None)
    s["volume"].pop("info", None)
    return s


def _jsonable(obj: Any) -> Any:
    return json.loads(json.dumps(obj, sort_keys=True, default=_json_default))


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serializable: {type(o).__name__}")


def _digest(*arrays: np.ndarray) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(repr((a.shape, str(a.dtype))).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def cache_settings(scene: Scene, data_cfg, renderer_cfg, views=None, splits=None) -> dict[str, Any]:
    """The hashed settings of a cache: everything that changes its pixels or its rows."""
    d = data_settings(data_cfg)
    if views is None or splits is None:
        views, splits = plan_views(scene, d)
    return _jsonable({
        "format_version": FORMAT_VERSION,
        "scene": _scene_key(scene),
        "renderer": renderer_pixel_settings(renderer_cfg),
        "resolution": d["resolution"],
        "views": {
            "num_views": d["num_views"],
            "test_views": int(len(splits["test"])),
            "val_fraction": d["val_fraction"],
            "seed": d["seed"],
            "lookat_jitter": d["lookat_jitter"],
            "user_test_trajectory": bool(d.get("test_trajectory")),
            # the views and splits themselves: any change in how they are made changes the key
            "sha256": _digest(views, *(splits[k] for k in ("train", "val", "test"))),
        },
    })


def settings_hash(settings: Mapping[str, Any]) -> str:
    return hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:12]


def cache_path_for(scene: Scene, data_cfg, renderer_cfg) -> Path:
    """Where :func:`ensure_cache` puts (or finds) this cache; renders nothing."""
    d = data_settings(data_cfg)
    if d.get("cache_path"):
        return Path(str(d["cache_path"])).expanduser()
    return Path(str(d["cache_dir"])).expanduser() / f"{_safe_name(scene.name)}-{settings_hash(cache_settings(scene, d, renderer_cfg))}"


def _safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", str(name)).strip("._") or "scene"


# ---------------------------------------------------------------------------------------------
# atomic files and the completion log
# ---------------------------------------------------------------------------------------------
def _atomic_json(path: Path, obj: Any) -> None:
    atomic_json(path, obj, default=_json_default)


def _log_line(index: int, crc: int, seconds: float) -> bytes:
    body = f"{int(index)} {int(crc) & 0xFFFFFFFF:08x} {float(seconds):.9f}"
    return f"{body} {zlib.crc32(body.encode()) & 0xFFFFFFFF:08x}\n".encode()


def read_log(path: Path, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Parse the completion log: ``(done (n,) bool, crc (n,) uint32, seconds (n,) float32)``.

    Lines that are torn (a crash while appending), fail their checksum or name an index outside
    ``[0, n)`` are ignored; for repeated indices the last intact line wins.
    """
    done = np.zeros(n, bool)
    crc = np.zeros(n, np.uint32)
    sec = np.full(n, np.nan, np.float32)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return done, crc, sec
    for raw in data.split(b"\n"):
        parts = raw.split(b" ")
        if len(parts) != 4:
            continue
        body = b" ".join(parts[:3])
        try:
            if int(parts[3], 16) != zlib.crc32(body) & 0xFFFFFFFF:
                continue
            i, c, s = int(parts[0]), int(parts[1], 16), float(parts[2])
        except ValueError:
            continue
        if 0 <= i < n and np.isfinite(s):
            done[i], crc[i], sec[i] = True, c, s
    return done, crc, sec


def read_logs(cache_dir: Path, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`read_log` of ``done.log`` merged with every shard's ``done-shard-I-of-N.log``."""
    done, crc, sec = read_log(cache_dir / LOG, n)
    for p in sorted(cache_dir.glob("done-shard-*-of-*.log")):
        d2, c2, s2 = read_log(p, n)
        done[d2], crc[d2], sec[d2] = True, c2[d2], s2[d2]
    return done, crc, sec


def bad_views(images: np.ndarray, rows, crc: np.ndarray) -> np.ndarray:
    """Rows of ``images`` (``(N, m, m, 3)``, e.g. memory-mapped) whose CRC-32 is not ``crc[row]``.

    One CRC-32 per view: about 0.4 ms for a 512x512 view in the page cache, over 1000x less than
    rendering it (0.45-0.55 s for the tiny scene on 2 CPU cores; ``scripts/measure_pixel_check.py``).
    """
    bad = [int(i) for i in np.asarray(rows, np.int64)
           if zlib.crc32(np.ascontiguousarray(images[i])) & 0xFFFFFFFF != int(crc[i])]
    return np.asarray(bad, np.int64)


#: caches whose every logged view was checked in this process: path -> file signature at that time
_CHECKED: dict[str, tuple] = {}


def _signature(path: Path) -> tuple | None:
    try:
        files = [path / IMAGES, path / LOG, *sorted(path.glob("done-shard-*-of-*.log"))]
        return tuple((f.name, st.st_ino, st.st_size, st.st_mtime_ns) for f in files if f.exists() for st in [f.stat()])
    except OSError:
        return None


def _remember_checked(path: Path) -> None:
    sig = _signature(path)
    if sig is not None:
        _CHECKED[str(path.absolute())] = sig


def _checked_already(path: Path) -> bool:
    sig = _CHECKED.get(str(path.absolute()))
    return sig is not None and sig == _signature(path)


class _Log:
    """Append-only completion log (parent process only)."""

    def __init__(self, path: Path, fsync: bool):
        self._f = open(path, "ab")
        self._fsync = fsync
        # a torn last line from a crash: start on a fresh line so the next record parses
        if self._f.tell() > 0:
            with open(path, "rb") as r:
                r.seek(-1, os.SEEK_END)
                if r.read(1) != b"\n":
                    self._f.write(b"\n")

    def append(self, index: int, crc: int, seconds: float) -> None:
        self._f.write(_log_line(index, crc, seconds))
        self._f.flush()
        if self._fsync:
            os.fsync(self._f.fileno())

    def close(self) -> None:
        self._f.close()


# ---------------------------------------------------------------------------------------------
# passing a scene to worker processes without copying memory-mapped volumes
# ---------------------------------------------------------------------------------------------
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


# ---------------------------------------------------------------------------------------------
# workers
# ---------------------------------------------------------------------------------------------
def _write_view(fd: int, img: np.ndarray, index: int, data_offset: int, fsync: bool) -> int:
    b = np.ascontiguousarray(img, dtype=np.uint8).tobytes()
    pos, view = data_offset + index * len(b), memoryview(b)
    while view:  # pwrite may write less than asked
        k = os.pwrite(fd, view, pos)
        view, pos = view[k:], pos + k
    if fsync:
        os.fdatasync(fd)
    return zlib.crc32(b) & 0xFFFFFFFF


def _orphan_exit(*queues) -> None:
    """Let a worker whose parent died exit at once: without this its queues' feeder threads would
    wait at exit for a reader that is gone."""
    for q in queues:
        q.cancel_join_thread()


def _worker_main(setup, parent_pid, tasks, results):
    """Render views taken from ``tasks`` until a ``None``; report ``("done", i, crc, seconds)``.

    The scene, the views and the settings arrive through the ``setup`` queue rather than as
    process arguments: multiprocessing writes arguments into a pipe that blocks for ever if the
    child dies before reading them all (a large volume would hang the parent).
    """
    try:
        while True:  # never block for ever: a parent killed before its setup reached us leaves nothing to wait for
            try:
                payload, renderer_cfg, threads, images_path, data_offset, resolution, views, fsync = setup.get(timeout=0.5)
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
                img = renderer.render(views[i], resolution)
                crc = _write_view(fd, img, i, data_offset, fsync)
                results.put(("done", int(i), crc, float(renderer.last_render_seconds)))
        finally:
            os.close(fd)
    except InputError as err:
        results.put(("error", str(err), True))
    except BaseException as err:  # reported to the parent, which raises it
        import traceback

        results.put(("error", f"render worker {os.getpid()} failed: {type(err).__name__}: {err}\n{traceback.format_exc()}", False))


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
    for name in _OWN_FILES:
        if name in (LOCK, MARKER) and not everything:
            continue
        for p in (path / name, path / (name + ".tmp")):
            try:
                p.unlink()
            except FileNotFoundError:
                pass
    for p in path.glob("done-shard-*-of-*.log"):  # logs of a cache that no longer exists
        p.unlink(missing_ok=True)


def _initialise(path: Path, settings, manifest, views, splits, m: int, user_dir: bool) -> None:
    """Write a fresh cache's files, the manifest last (the directory is locked)."""
    foreign = [p.name for p in path.iterdir() if not _is_own(p.name) and not p.name.endswith(".tmp")
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


def render_cache(scene: Scene, data_cfg, renderer_cfg=None, progress: bool = True) -> CacheReport:
    """Render whatever is missing from the cache of ``(scene, data, renderer)``; see the module doc.

    Args:
        scene: the scene.
        data_cfg: the ``data`` node (see :data:`DATA_DEFAULTS`).
        renderer_cfg: the ``renderer`` node (``name``, ``mapper``, ``threads``).
        progress: show a tqdm progress bar on stderr.

    Returns:
        A :class:`CacheReport` (its ``path`` is the cache directory).

    Raises:
        InputError: bad settings, degenerate views, an unwritable cache directory, a directory whose
            manifest belongs to other settings, too little free disk space.
    """
    from filelock import FileLock

    d = data_settings(data_cfg)
    rcfg = _plain(renderer_cfg, "renderer") if renderer_cfg is not None else {"name": "vtk"}
    renderer_pixel_settings(rcfg)  # validates the renderer name before anything touches the disk
    m = d["resolution"]
    views, splits = plan_views(scene, d)
    settings = cache_settings(scene, d, rcfg, views, splits)
    key = settings_hash(settings)
    user_dir = bool(d.get("cache_path"))
    path = Path(str(d["cache_path"])).expanduser() if user_dir else Path(str(d["cache_dir"])).expanduser() / f"{_safe_name(scene.name)}-{key}"
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
                    "scene": _jsonable(scene.pixel_settings()),
                    "scene_config": _jsonable(scene.config) if scene.config is not None else None,
                    "renderer": _jsonable({**rcfg, "pixel_settings": renderer_pixel_settings(rcfg), "version": renderer_version(rcfg)}),
                    "resolution": m,
                    "view_angle": float(scene.view_angle),
                    # the resolved ray step (scene.sample_distance: auto = half a voxel), in both units
                    "sample_distance": {"normalized": float(scene.sample_distance), "voxels": scene.sample_distance_voxels,
                                        "voxel_size_normalized": voxel_size(scene.volume)},
                    "data": _jsonable({k: d[k] for k in ("num_views", "test_views", "val_fraction", "seed", "lookat_jitter", "test_trajectory")}),
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
        if d["shard"] is None:
            return _render_missing(scene, d, rcfg, path, manifest, views, progress)
    finally:
        if lock.is_locked:
            lock.release()
    # sharded: render outside the cache lock, under the shard's own lock
    i, k = d["shard"]
    shard_lock = FileLock(str(path / f".lock-shard-{i}-of-{k}"))
    _acquire(shard_lock, path, f"waiting for another run that is rendering shard {i}/{k} of {path} ...")
    try:
        return _render_missing(scene, d, rcfg, path, None, views, progress, cache_lock=lock)
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


def _render_missing(scene, d, rcfg, path: Path, manifest, views, progress, cache_lock=None) -> CacheReport:
    """Render the views not logged yet (of ``d["shard"]`` only, when set: then ``manifest`` is None
    and ``cache_lock`` is the cache's lock, taken again to update the manifest)."""
    n, m = len(views), d["resolution"]
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
            _remember_checked(path)
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
    log = _Log(path / (LOG if shard is None else _shard_log_name(shard)), d["fsync"])
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
                    img = renderer.render(views[i], m)
                    crc = _write_view(fd, img, int(i), offset, d["fsync"])
                    log.append(int(i), crc, renderer.last_render_seconds)
                    report.rendered += 1
                    report.render_seconds += renderer.last_render_seconds
                    bar.update(1)
            finally:
                os.close(fd)
                if hasattr(renderer, "close"):
                    renderer.close()
        else:
            _run_workers(scene, rcfg, threads, path / IMAGES, offset, m, views, todo, workers, d["fsync"], log, bar, report)
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
        _remember_checked(path)  # every logged view was checked or written (and checksummed) just now
    return report


def _run_workers(scene, rcfg, threads, images_path, offset, m, views, todo, workers, fsync, log, bar, report):
    import multiprocessing as mp

    ctx = mp.get_context("spawn")  # VTK and OpenGL state must not be forked
    setup, tasks, results = ctx.Queue(), ctx.Queue(), ctx.Queue()
    # dynamic load balancing: views near the volume cost more than far ones, so workers pull
    # the next index when they are free instead of owning a fixed share
    for i in todo:
        tasks.put(int(i))
    for _ in range(workers):
        tasks.put(None)
    payload = (_scene_payload(scene), rcfg, threads, str(images_path), offset, m, views, fsync)
    for _ in range(workers):
        setup.put(payload)
    procs = [ctx.Process(target=_worker_main, args=(setup, os.getpid(), tasks, results), daemon=True) for _ in range(workers)]
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


def ensure_cache(scene: Scene, data_cfg, renderer_cfg=None, progress: bool = True) -> Path:
    """Render what is missing and return the cache directory (see :func:`render_cache`)."""
    return render_cache(scene, data_cfg, renderer_cfg, progress=progress).path


# ---------------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------------
@dataclass
class ViewImageCache:
    """A cache directory opened for reading.

    Attributes:
        path: the directory.
        manifest: the manifest dict (``settings``, ``scene``, ``renderer``, ``resolution``, ...).
        views: ``(N, 9)`` float32 (rows ``splits["test"]`` are the test trajectory, in path order).
        images: ``(N, m, m, 3)`` uint8, memory-mapped read-only.
        splits: ``{"train", "val", "test"}`` -> int64 row indices.
        done: ``(N,)`` bool, which rows are rendered (all, for a complete cache).
        render_seconds: ``(N,)`` float32, the renderer's full-frame render-call time per row.
        crc: ``(N,)`` uint32 CRC-32 of each row's pixels (see :meth:`verify`).
    """

    path: Path
    manifest: dict[str, Any]
    views: np.ndarray
    images: np.ndarray
    splits: dict[str, np.ndarray]
    done: np.ndarray
    render_seconds: np.ndarray
    crc: np.ndarray = field(repr=False)

    @classmethod
    def open(cls, path, require_complete: bool = True, check_pixels: bool = True) -> "ViewImageCache":
        """Open a cache directory (reads only; writes nothing).

        Args:
            path: the cache directory.
            require_complete: refuse a cache with views not rendered yet.
            check_pixels: check every rendered view's pixels against its logged CRC-32 (skipped
                when this process rendered or checked the cache and its files have not changed
                since). Loader processes that open a cache the main process checked pass False.

        Raises:
            InputError: not a cache, damaged files (truncated, changed after rendering), or
                (``require_complete``) some views are not rendered yet.
        """
        p = Path(str(path)).expanduser()
        if not (p / MANIFEST).is_file():
            raise InputError(f"cache {p}: not a view/image cache (no {MANIFEST}); render it with python -m data_gen")
        repair = "run python -m data_gen with the same settings to repair it"
        try:
            manifest = json.loads((p / MANIFEST).read_text())
            views = np.load(p / VIEWS, allow_pickle=False)
            splits = {k: np.asarray(v, np.int64) for k, v in json.loads((p / SPLITS).read_text()).items()}
            images = np.load(p / IMAGES, mmap_mode="r", allow_pickle=False)
        except (OSError, ValueError, EOFError) as err:
            raise InputError(f"cache {p}: damaged or unreadable ({type(err).__name__}: {str(err).splitlines()[0][:100] if str(err) else ''}); {repair}") from None
        settings = manifest.get("settings") or {}
        m = int(manifest.get("resolution", -1))
        if (views.ndim != 2 or views.shape[1:] != (9,) or images.shape != (len(views), m, m, 3)
                or images.dtype != np.uint8 or sorted(splits) != ["test", "train", "val"]):
            raise InputError(f"cache {p}: {VIEWS} / {IMAGES} / {SPLITS} do not match its manifest; {repair}")
        if settings.get("views", {}).get("sha256") not in (None, _digest(views, *(splits[k] for k in ("train", "val", "test")))):
            raise InputError(f"cache {p}: {VIEWS} / {SPLITS} were changed after rendering; {repair}")
        done, crc, sec = read_logs(p, len(views))
        if require_complete and not done.all():
            raise InputError(f"cache {p}: only {int(done.sum())} of {len(views)} views are rendered; run python -m data_gen with the same settings to finish it")
        if check_pixels and not _checked_already(p):
            bad = bad_views(images, np.flatnonzero(done), crc)
            if len(bad):
                raise InputError(
                    f"cache {p}: the pixels of {len(bad)} view(s) do not match their checksums (rows {', '.join(map(str, bad[:5]))}"
                    f"{', ...' if len(bad) > 5 else ''}; changed after rendering); run python -m data_gen with the same settings to re-render them"
                )
            if done.all():
                _remember_checked(p)
        return cls(p, manifest, views, images, splits, done, sec, crc)

    def __len__(self) -> int:
        return len(self.views)

    @property
    def resolution(self) -> int:
        return int(self.images.shape[1])

    @property
    def view_angle(self) -> float:
        return float(self.manifest["view_angle"])

    @property
    def complete(self) -> bool:
        return bool(self.done.all())

    def split(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """``(views (K, 9), images (K, m, m, 3))`` of one split (images read into memory)."""
        idx = self.splits[name]
        return self.views[idx], np.asarray(self.images[idx])

    def verify(self) -> np.ndarray:
        """Indices of rendered rows whose pixels no longer match their logged CRC-32."""
        return bad_views(self.images, np.flatnonzero(self.done), self.crc)

    def scene(self) -> Scene:
        """Rebuild the scene from the manifest (volume from its recorded config, checked against its fingerprint)."""
        from .scene import build_scene

        cfg = self.manifest.get("scene_config")
        if not cfg:
            raise InputError(f"cache {self.path}: the manifest has no scene config (made from a Scene object built in code)")
        scene = build_scene(cfg)
        if _jsonable(_scene_key(scene)) != self.manifest["settings"]["scene"]:
            raise InputError(f"cache {self.path}: the scene rebuilt from the manifest differs from the cached one (volume file changed?)")
        return scene

    def rerender(self, index: int, renderer=None) -> np.ndarray:
        """Render row ``index`` again from the manifest alone: ``(m, m, 3)`` uint8."""
        if renderer is None:
            renderer = make_renderer(self.scene(), self.manifest["renderer"]["pixel_settings"])
        return renderer.render(self.views[int(index)], self.resolution)


__all__ = [
    "ensure_cache", "render_cache", "ViewImageCache", "CacheReport", "cache_path_for", "cache_settings",
    "data_settings", "parse_shard", "plan_views", "read_log", "read_logs", "DATA_DEFAULTS", "FORMAT_VERSION",
]
