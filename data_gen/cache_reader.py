"""Reading a view/image cache: :class:`ViewImageCache` (views, memory-mapped images, splits),
checked against its manifest, its completion log and its pixel checksums; it writes nothing.

Example:
    >>> c = ViewImageCache.open("cache/tiny-0123456789ab")          # doctest: +SKIP
    >>> views, images = c.split("train")                             # doctest: +SKIP
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from imls_lightning.base.errors import InputError
from imls_lightning.render import make_renderer
from imls_lightning.render.scene import Scene

from .cache_keys import IMAGES, MANIFEST, SPLITS, VIEWS, jsonable, scene_key, views_digest
from .cache_log import bad_views, checked_already, read_logs, remember_checked


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
        if settings.get("views", {}).get("sha256") not in (None, views_digest(views, splits)):
            raise InputError(f"cache {p}: {VIEWS} / {SPLITS} were changed after rendering; {repair}")
        done, crc, sec = read_logs(p, len(views))
        if require_complete and not done.all():
            raise InputError(f"cache {p}: only {int(done.sum())} of {len(views)} views are rendered; run python -m data_gen with the same settings to finish it")
        if check_pixels and not checked_already(p):
            bad = bad_views(images, np.flatnonzero(done), crc)
            if len(bad):
                raise InputError(
                    f"cache {p}: the pixels of {len(bad)} view(s) do not match their checksums (rows {', '.join(map(str, bad[:5]))}"
                    f"{', ...' if len(bad) > 5 else ''}; changed after rendering); run python -m data_gen with the same settings to re-render them"
                )
            if done.all():
                remember_checked(p)
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
    def sparse_rows(self) -> np.ndarray:
        """Rows whose images hold only the cache's ``train_pixels`` (the training split of a cache
        rendered with them; every other pixel is black), else empty: no FR-Image in those rows."""
        if not (self.manifest.get("settings") or {}).get("train_pixels"):
            return np.zeros(0, np.int64)
        return self.splits["train"]

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
        from data_gen.scenes import build_scene

        cfg = self.manifest.get("scene_config")
        if not cfg:
            raise InputError(f"cache {self.path}: the manifest has no scene config (made from a Scene object built in code)")
        scene = build_scene(cfg)
        if jsonable(scene_key(scene)) != self.manifest["settings"]["scene"]:
            raise InputError(f"cache {self.path}: the scene rebuilt from the manifest differs from the cached one (volume file changed?)")
        return scene

    def rerender(self, index: int, renderer=None) -> np.ndarray:
        """Render row ``index`` again from the manifest alone: ``(m, m, 3)`` uint8 (a whole frame,
        also for a :attr:`sparse_rows` row)."""
        if renderer is None:
            renderer = make_renderer(self.scene(), self.manifest["renderer"]["pixel_settings"])
        return renderer.render(self.views[int(index)], self.resolution)


__all__ = ["ViewImageCache"]
