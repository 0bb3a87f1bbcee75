"""The one LightningDataModule of the project.

It renders the (view, image) cache first if it is missing, reads it memory-mapped, and yields per
view what every model here needs:

============  =================  ==========================================================
key           shape              meaning
============  =================  ==========================================================
``index``     ()                 row of the cache
``view``      (9,) float32       eye, lookAt, up
``fr``        (3, m, m) float32  FR-Image in [0, 1]
``pr``        (3, m, m) float32  PR-Image: FR-Image on the pattern, 0 elsewhere
``c``         (3, n, n) float32  C-Image (pattern pixels in raster order, zero padded)
``low``       (3, l, l) float32  a low-resolution render of the same view (LAS), if asked
``im``        (1, n, n) float32  IM label {0, 1} made by a trained IML encoder, if asked
``pim``       (1, n, n) float32  the continuous PIM' behind that label, if asked
============  =================  ==========================================================

The pattern mask itself is constant and lives on :attr:`ImlsDataModule.pattern` (and in every
task), not in the batches. Splits: ``train``/``val`` are the 9:1 split of the random views, ``test``
is the 120-view exploration trajectory.
"""
from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any, Iterable, Mapping

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from imls_lightning.base.errors import InputError

from ..core.compaction import compact
from ..base.config import to_plain
from ..core.patterns import SamplingPattern, build_pattern, crop_pattern

ALL_FIELDS = ("view", "fr", "pr", "c")


class ViewImageDataset(Dataset):
    """Rows of a view/image cache, opened lazily (memory-mapped) in each loader process."""

    def __init__(
        self,
        cache_path: str | Path,
        rows: np.ndarray,
        pattern: SamplingPattern,
        fields: Iterable[str] = ALL_FIELDS,
        low_res_path: str | Path | None = None,
        labels_path: str | Path | None = None,
        crop: int | None = None,
    ):
        self.cache_path = Path(cache_path)
        self.rows = np.asarray(rows, dtype=np.int64)
        self.pattern = pattern
        self.fields = tuple(fields)
        self.low_res_path = Path(low_res_path) if low_res_path else None
        self.labels_path = Path(labels_path) if labels_path else None
        self._cache = self._low = self._labels = None
        # patch training: a random grid-aligned crop x crop window of every FR-Image, and its C-Image
        self.crop = int(crop) if crop else None
        self.crop_pattern = crop_pattern(pattern, self.crop) if self.crop else None
        if self.crop and (low_res_path or labels_path):
            raise InputError("data.crop: the LAS low-resolution images and the IMS labels are whole images; train LAS and IMS with data.crop=null")

    def _open(self):
        from data_gen.cache import ViewImageCache

        if self._cache is None:
            # the DataModule's setup checked every view's pixels (ViewImageCache.open); loader
            # processes do not check them again
            self._cache = ViewImageCache.open(self.cache_path, check_pixels=False)
            if self.low_res_path is not None:
                self._low = ViewImageCache.open(self.low_res_path, check_pixels=False)
            if self.labels_path is not None:
                from .labels import ImportanceLabels

                self._labels = ImportanceLabels.open(self.labels_path)
        return self._cache

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, i: int) -> dict[str, Any]:
        cache = self._open()
        row = int(self.rows[i])
        out: dict[str, Any] = {"index": row, "view": torch.from_numpy(np.asarray(cache.views[row], np.float32))}
        img = torch.from_numpy(np.array(cache.images[row])).permute(2, 0, 1).float().div_(255.0)
        pattern = self.pattern
        if self.crop:
            img, pattern = self._random_crop(img), self.crop_pattern
        if "fr" in self.fields:
            out["fr"] = img
        if "pr" in self.fields:
            out["pr"] = img * pattern.mask.to(img.dtype)
        if "c" in self.fields:
            out["c"] = compact(img[None], pattern.indices, pattern.c_size)[0]
        if self._low is not None:
            out["low"] = torch.from_numpy(np.array(self._low.images[row])).permute(2, 0, 1).float().div_(255.0)
        if self._labels is not None:
            out["im"] = torch.from_numpy(self._labels.im(row)).float()[None]
            out["pim"] = torch.from_numpy(self._labels.pim(row)).float()[None]
        return out


    def _random_crop(self, img: torch.Tensor) -> torch.Tensor:
        """A ``crop x crop`` window starting on the pattern's grid (a multiple of its factor), so the
        window's pattern pixels are exactly :attr:`crop_pattern`'s."""
        step = int(self.pattern.param_dict.get("factor", 1))
        m, c = img.shape[-1], self.crop
        y, x = (int(v) * step for v in torch.randint(0, (m - c) // step + 1, (2,)))
        return img[:, y : y + c, x : x + c].contiguous()


#: ``data.train_pixels``: render the training views whole, or at the pattern's C-pixels only
TRAIN_PIXELS = ("all", "pattern")


def check_train_pixels_mode(value) -> str:
    """``data.train_pixels`` checked (``None``: ``"all"``).

    Example:
        >>> check_train_pixels_mode(None), check_train_pixels_mode("pattern")
        ('all', 'pattern')
    """
    mode = "all" if value is None else str(value)
    if mode not in TRAIN_PIXELS:
        raise InputError(f"data.train_pixels={value!r}: expected one of {list(TRAIN_PIXELS)}")
    return mode


#: smallest FR-Image side the training metrics accept: SSIM's Gaussian window (sigma 1.5, 11 pixels)
#: reflection-pads images by 5 pixels, which needs at least 6
MIN_RESOLUTION = 6


def _smallest_resolution(pattern) -> int:
    """The smallest ``data.resolution >= MIN_RESOLUTION`` the sampling pattern accepts."""
    if isinstance(pattern, SamplingPattern):
        return MIN_RESOLUTION
    for m in range(MIN_RESOLUTION, 4097):
        try:
            build_pattern(to_plain(pattern), m)
            return m
        except (InputError, ValueError):
            continue
    return MIN_RESOLUTION


class ImlsDataModule(L.LightningDataModule):
    """Cache-backed data for every model (RecNN, IML, IMS, LAS).

    Args:
        scene: the ``scene`` config node.
        data: the ``data`` config node (cache settings + ``batch_size`` + ``loader_workers``).
        renderer: the ``renderer`` config node.
        pattern: the ``pattern`` config node (or a built :class:`SamplingPattern`).
        fields: which of ``view, fr, pr, c`` to yield.
        low_res: also yield ``low``, a render of the same views at this resolution (LAS).
        labels: a directory of IML labels (``im``, ``pim``) made by :mod:`imls_lightning.data.labels`.
        labels_from: an IML checkpoint: label the cache with it first (once, kept beside the cache;
            :func:`imls_lightning.data.labels.ensure_labels` with ``labels_options``) and yield its labels.
        crop: train on random ``crop x crop`` windows of the FR-Images (and their C-Images) instead of
            whole images: ``data.crop``, for the fully convolutional RecNN and IML at paper scale.
            Validation and test batches stay whole. Needs a shift-invariant pattern
            (:func:`~imls_lightning.core.patterns.crop_pattern`).
        train_fr: whether the model trains on FR-Images. ``data.train_pixels=pattern`` renders the
            training views at the pattern's C-pixels only (a quarter of the rays for EnhanceNet 2x;
            validation and test views stay whole), and its training batches then carry no ``fr``:
            only a model that learns from C-Images alone (``train_fr=False``: the IMS) accepts it.
    """

    def __init__(
        self,
        scene: Mapping,
        data: Mapping,
        renderer: Mapping,
        pattern: Mapping | SamplingPattern,
        fields: Iterable[str] = ALL_FIELDS,
        low_res: int | None = None,
        labels: str | Path | None = None,
        progress: bool = True,
        crop: int | None = None,
        labels_from: str | Path | None = None,
        labels_options: Mapping[str, Any] | None = None,
        train_fr: bool = True,
    ):
        super().__init__()
        self.scene_cfg = to_plain(scene)
        self.data_cfg = to_plain(data)
        self.renderer_cfg = to_plain(renderer)
        bad = set(fields) - set(ALL_FIELDS)
        if bad:
            raise InputError(f"data fields {sorted(bad)}: expected some of {list(ALL_FIELDS)}")
        self.fields = tuple(fields)
        self.low_res = int(low_res) if low_res else None
        self.labels = Path(labels) if labels else None
        if labels and labels_from:
            raise InputError("ImlsDataModule: give labels (a label directory) or labels_from (an IML checkpoint), not both")
        self.labels_from = str(labels_from) if labels_from else None
        self.labels_options = dict(labels_options or {})
        self.progress = progress
        self.batch_size = int(self.data_cfg.get("batch_size", 8))
        self.loader_workers = int(self.data_cfg.get("loader_workers", 0))
        if self.batch_size <= 0:
            raise InputError(f"data.batch_size={self.batch_size}: expected a positive integer")
        self.fr_size = int(self.data_cfg["resolution"])
        if self.fr_size < MIN_RESOLUTION:
            raise InputError(f"data.resolution={self.fr_size}: too small to train on; the smallest that works is "
                             f"{_smallest_resolution(pattern)} (the SSIM metric's 11-pixel Gaussian window needs images of "
                             f"at least {MIN_RESOLUTION}x{MIN_RESOLUTION}, and the sampling pattern must fit)")
        self.pattern = pattern if isinstance(pattern, SamplingPattern) else build_pattern(to_plain(pattern), self.fr_size)
        self.crop = int(crop) if crop else None
        if self.crop:
            crop_pattern(self.pattern, self.crop)  # refuses what cannot be cropped, in one line
            if self.crop < MIN_RESOLUTION:
                raise InputError(f"data.crop={self.crop}: too small to train on; expected >= {MIN_RESOLUTION} or null")
        self.train_pixels = check_train_pixels_mode(self.data_cfg.get("train_pixels"))
        if self.train_pixels == "pattern" and (train_fr or self.crop or self.low_res):
            raise InputError("data.train_pixels=pattern: this model trains on FR-Images (or crops of them); only the IMS "
                             "trains on C-Images alone: set data.train_pixels=all")
        self.cache_path: Path | None = None
        self.low_res_path: Path | None = None
        self._datasets: dict[str, ViewImageDataset] = {}

    # -- cache --------------------------------------------------------------------------------
    def _low_res_data_cfg(self) -> dict:
        d = copy.deepcopy(self.data_cfg)
        d["resolution"] = self.low_res
        return d

    def cache_keys(self) -> list[str]:
        """The keys of the caches this datamodule reads (the FR cache, then LAS's low-resolution one): what a
        finished run records, and what its reuse is checked against. Once the caches are ensured, their manifests'
        keys; before, computed from the settings and the volume's content without rendering."""
        from data_gen.cache_keys import MANIFEST, cache_key
        from data_gen.scenes import build_scene

        ensured = [p for p in (self.cache_path, self.low_res_path) if p is not None]
        if self.cache_path is not None and all((p / MANIFEST).is_file() for p in ensured):
            return [json.loads((p / MANIFEST).read_text())["hash"] for p in ensured]
        scene = build_scene(self.scene_cfg)
        pixels = self.pattern.indices.numpy() if self.train_pixels == "pattern" else None
        keys = [cache_key(scene, self.data_cfg, self.renderer_cfg, train_pixels=pixels)]
        if self.low_res:
            keys.append(cache_key(scene, self._low_res_data_cfg(), self.renderer_cfg))
        return keys

    def _ensure(self) -> None:
        from data_gen.cache import ensure_cache
        from data_gen.scenes import build_scene

        scene = build_scene(self.scene_cfg)
        pixels = self.pattern.indices.numpy() if self.train_pixels == "pattern" else None
        self.cache_path = Path(ensure_cache(scene, self.data_cfg, self.renderer_cfg, progress=self.progress, train_pixels=pixels))
        if self.low_res:
            self.low_res_path = Path(ensure_cache(scene, self._low_res_data_cfg(), self.renderer_cfg, progress=self.progress))
        if self.labels_from:
            from .labels import ensure_labels

            self.labels = Path(ensure_labels(self.cache_path, self.labels_from, progress=self.progress, **self.labels_options))

    def prepare_data(self) -> None:
        # rank 0 only under DDP: render whatever is missing
        self._ensure()

    def setup(self, stage: str | None = None) -> None:
        from data_gen.cache import ViewImageCache

        if self.cache_path is None:
            self._ensure()  # complete caches are found, not re-rendered
        cache = ViewImageCache.open(self.cache_path)
        if cache.images.shape[1] != self.fr_size:
            raise InputError(f"cache {self.cache_path}: images are {cache.images.shape[1]}^2, expected data.resolution={self.fr_size}")
        sparse = set(cache.sparse_rows.tolist())
        for split in ("train", "val", "test"):
            rows = cache.splits[split]
            # rows rendered at the pattern's pixels only have a C-Image and a PR-Image, no FR-Image
            fields = tuple(f for f in self.fields if f != "fr") if sparse.intersection(rows.tolist()) else self.fields
            self._datasets[split] = ViewImageDataset(
                self.cache_path, rows, self.pattern, fields, self.low_res_path, self.labels,
                crop=self.crop if split == "train" else None,
            )

    def dataset(self, split: str) -> ViewImageDataset:
        if not self._datasets:
            self.setup()
        return self._datasets[split]

    # -- loaders ------------------------------------------------------------------------------
    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        ds = self.dataset(split)
        return DataLoader(
            ds,
            batch_size=self.batch_size,
            shuffle=shuffle,
            num_workers=self.loader_workers,
            persistent_workers=self.loader_workers > 0,
            pin_memory=torch.cuda.is_available(),
        )

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)

    def predict_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)
