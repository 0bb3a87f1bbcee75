"""What identifies a view/image cache: its file names, the ``data`` settings, the planned views
and the hash of everything that changes its pixels (the directory's name).

See :mod:`data_gen.cache` for the cache's layout and life cycle; nothing here touches the disk
(except :func:`plan_views` reading a user's own test trajectory).

Example:
    >>> parse_shard("1/4"), data_settings({"resolution": 64})["resolution"]
    ((1, 4), 64)
"""
from __future__ import annotations

import copy
import hashlib
import json
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from imls_lightning.base.errors import InputError
from imls_lightning.render import renderer_pixel_settings
from imls_lightning.render.scene import Scene
from imls_lightning.base.validate import check_integer, check_mapping
from .views import (
    check_lookat_jitter,
    check_val_fraction,
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
#: every file a cache directory may hold (temporary files are these names + ".tmp"), besides the
#: per-shard logs and locks (:func:`is_own_file`)
OWN_FILES = (MANIFEST, VIEWS, SPLITS, IMAGES, LOG, SECONDS, LOCK, MARKER, "contact_sheet.png")
#: the shard logs of a cache directory (glob)
SHARD_LOGS = "done-shard-*-of-*.log"
_SHARD_FILE = re.compile(r"^(done-shard-\d+-of-\d+\.log|\.lock-shard-\d+-of-\d+)$")


def shard_log_name(shard: tuple[int, int]) -> str:
    """The completion log of shard ``(I, N)``: ``done-shard-I-of-N.log``."""
    return f"done-shard-{shard[0]}-of-{shard[1]}.log"


def is_own_file(name: str) -> bool:
    """Whether a file name in a cache directory is one of the cache's own files."""
    return name in OWN_FILES or _SHARD_FILE.match(name) is not None


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
def data_settings(data_cfg) -> dict[str, Any]:
    """The ``data`` node with defaults filled in and every value checked.

    Raises:
        InputError: ``resolution <= 0``, ``num_views < 1``, a bad fraction, ...
    """
    raw = {} if data_cfg is None else check_mapping(data_cfg, "data")
    # a missing or null key takes the default (null is the default of the two optional paths)
    d = {k: v if raw.get(k) is None else raw[k] for k, v in DATA_DEFAULTS.items()}
    for key, lo in (("resolution", 1), ("num_views", 1), ("test_views", 0), ("workers", 0), ("seed", 0)):
        d[key] = check_integer(d[key], f"data.{key}", lo)
    d["val_fraction"] = check_val_fraction(d["val_fraction"])
    d["lookat_jitter"] = check_lookat_jitter(d["lookat_jitter"])
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


def scene_key(scene: Scene) -> dict[str, Any]:
    """Scene pixel settings without provenance that cannot change pixels (file location, notes)."""
    s = copy.deepcopy(scene.pixel_settings())
    s["volume"].pop("source", None)
    s["volume"].pop("info", None)
    return s


def jsonable(obj: Any) -> Any:
    """``obj`` as plain JSON data (sorted keys; NumPy values and paths converted)."""
    return json.loads(json.dumps(obj, sort_keys=True, default=json_default))


def json_default(o):
    """``json.dumps``'s ``default`` for NumPy scalars and arrays and paths."""
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serializable: {type(o).__name__}")


def views_digest(views: np.ndarray, splits: Mapping[str, np.ndarray]) -> str:
    """SHA-256 of a cache's views and its train/val/test row indices (shapes and dtypes included)."""
    h = hashlib.sha256()
    for a in (views, *(splits[k] for k in ("train", "val", "test"))):
        a = np.ascontiguousarray(a)
        h.update(repr((a.shape, str(a.dtype))).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def check_train_pixels(pixels, resolution: int) -> np.ndarray | None:
    """``train_pixels`` of a cache: ``None`` (every pixel of every view) or the flat raster indices
    ``(K,)`` of the pixels its training views are rendered at (a RecNN pattern's C-pixels: a model
    that learns from C-Images alone, the IMS, needs no other pixel of its training views).

    Example:
        >>> check_train_pixels([0, 2, 8], 3).tolist(), check_train_pixels(None, 3)
        ([0, 2, 8], None)
        >>> check_train_pixels([2, 1], 3)
        Traceback (most recent call last):
        ...
        imls_lightning.base.errors.InputError: train_pixels: expected strictly ascending flat pixel indices in [0, 9) of the 3x3 image (got 2 values from 1 to 2)
    """
    if pixels is None:
        return None
    a = np.asarray(pixels)
    m2 = int(resolution) ** 2
    if (a.ndim != 1 or a.size == 0 or not np.issubdtype(a.dtype, np.integer) or a.min() < 0 or a.max() >= m2
            or np.any(np.diff(a) <= 0)):
        got = f"{a.size} values from {a.min()} to {a.max()}" if a.size and np.issubdtype(a.dtype, np.number) else f"shape {a.shape}, {a.dtype}"
        raise InputError(f"train_pixels: expected strictly ascending flat pixel indices in [0, {m2}) of the "
                         f"{resolution}x{resolution} image (got {got})")
    return a.astype(np.int64)


def cache_settings(scene: Scene, data_cfg, renderer_cfg, views=None, splits=None, train_pixels=None) -> dict[str, Any]:
    """The hashed settings of a cache: everything that changes its pixels or its rows (with
    ``train_pixels``, :func:`check_train_pixels`, their count and digest; without, the key is
    what it always was)."""
    d = data_settings(data_cfg)
    if views is None or splits is None:
        views, splits = plan_views(scene, d)
    pixels = check_train_pixels(train_pixels, d["resolution"])
    sparse = {} if pixels is None else {"train_pixels": {
        "count": int(pixels.size), "sha256": hashlib.sha256(np.ascontiguousarray(pixels).tobytes()).hexdigest()}}
    return jsonable({
        **sparse,
        "format_version": FORMAT_VERSION,
        "scene": scene_key(scene),
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
            "sha256": views_digest(views, splits),
        },
    })


def settings_hash(settings: Mapping[str, Any]) -> str:
    """The 12 hex digits that name a cache directory: SHA-256 of its hashed settings."""
    return hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:12]


def cache_key(scene: Scene, data_cfg, renderer_cfg=None, train_pixels=None) -> str:
    """The hash of everything that changes a cache's pixels, the volume's content included (its fingerprint), as
    :func:`~data_gen.cache.render_cache` names the cache and writes it into the manifest; renders nothing. A training
    run records it, so that a run trained on other pixels (a volume replaced at the same path, a generator that
    changed) is never reused as this one."""
    rcfg = renderer_cfg if renderer_cfg is not None else {"name": "vtk"}
    return settings_hash(cache_settings(scene, data_cfg, rcfg, train_pixels=train_pixels))


def cache_path_for(scene: Scene, data_cfg, renderer_cfg, train_pixels=None) -> Path:
    """Where :func:`ensure_cache` puts (or finds) this cache; renders nothing."""
    d = data_settings(data_cfg)
    if d.get("cache_path"):
        return Path(str(d["cache_path"])).expanduser()
    return Path(str(d["cache_dir"])).expanduser() / f"{safe_name(scene.name)}-{cache_key(scene, d, renderer_cfg, train_pixels)}"


def safe_name(name: str) -> str:
    """A scene name made safe for a directory name."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", str(name)).strip("._") or "scene"


__all__ = [
    "FORMAT_VERSION", "MANIFEST", "VIEWS", "SPLITS", "IMAGES", "LOG", "SECONDS", "LOCK", "MARKER", "OWN_FILES", "SHARD_LOGS",
    "DATA_DEFAULTS", "shard_log_name", "is_own_file", "data_settings", "parse_shard", "plan_views",
    "scene_key", "jsonable", "json_default", "views_digest", "check_train_pixels", "cache_settings", "settings_hash", "cache_key", "cache_path_for",
    "safe_name",
]
