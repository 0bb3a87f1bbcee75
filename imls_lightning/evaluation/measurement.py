"""Measuring methods on one view: their stage times (medians, :func:`~imls_lightning.evaluation.timing.time_methods`)
and their images scored against the ground truth (PSNR, SSIM); the views measured (:func:`spaced`). A view as
the networks' input is :func:`imls_lightning.render.camera.view_tensor`."""
from __future__ import annotations

import sys
from typing import Any, Mapping

import numpy as np
import torch

from ..inference.pipeline import Method
from .timing import time_method, time_methods


def image_quality(image: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """PSNR (dB, 100 for identical images) and SSIM of two ``(m, m, 3)`` uint8 images, by the same
    functions as the training logs (:mod:`imls_lightning.core.metrics`)."""
    from ..core.metrics import psnr, ssim_metric

    # np.array copies: the cache's images are read-only memory maps (torch warns on those)
    p = torch.from_numpy(np.array(image)).permute(2, 0, 1)[None].float().div(255.0)
    t = torch.from_numpy(np.array(truth)).permute(2, 0, 1)[None].float().div(255.0)
    return float(psnr(p, t)), float(ssim_metric(p, t))


def measure(method: Method, view: np.ndarray, truth: np.ndarray, repeats: int, warmup: int,
            **run_args: Any) -> tuple[dict[str, Any], np.ndarray, dict[str, Any]]:
    """Time one method on one view and score it: ``(metric row fields, image, info)``."""
    image, med, info = time_method(method, view, repeats=repeats, warmup=warmup, **run_args)
    return _row(med, image, info, truth), image, info


def measure_methods(methods: Mapping[str, Method], view: np.ndarray, truth: np.ndarray, repeats: int, warmup: int,
                    order: str = "interleaved") -> dict[str, tuple[dict[str, Any], np.ndarray, dict[str, Any]]]:
    """Time several methods on one view in one ``order`` (:func:`~imls_lightning.evaluation.timing.time_methods`)
    and score each: ``{name: (metric row fields, image, info)}``."""
    timed = time_methods(methods, view, repeats=repeats, warmup=warmup, order=order)
    return {name: (_row(med, image, info, truth), image, info) for name, (image, med, info) in timed.items()}


def _row(med: Mapping[str, float], image: np.ndarray, info: Mapping[str, Any], truth: np.ndarray) -> dict[str, Any]:
    """A metric row's fields: the stage medians in ms, the share of the pattern rendered, PSNR and SSIM."""
    q_psnr, q_ssim = image_quality(image, truth)
    row: dict[str, Any] = {f"{k}_ms": 1e3 * v for k, v in med.items() if k != "total"}
    row["total_ms"] = 1e3 * med["total"]
    row.update(ipr=info.get("ipr"), c_share=info.get("c_share"), rendered_pixels=info.get("rendered_pixels"),
               psnr=q_psnr, ssim=q_ssim)
    return row


def spaced(n: int, k: int | None) -> np.ndarray:
    """``k`` indices evenly spaced over ``range(n)`` (all when ``k`` is None or >= n)."""
    if k is None or k >= n:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, k).round().astype(np.int64))


def progress_bar(iterable, total: int, desc: str, enabled: bool):
    from tqdm import tqdm

    return tqdm(iterable, total=total, desc=desc, unit="view", file=sys.stderr, disable=not enabled, dynamic_ncols=True)


def view_loader(cache, rows, pattern, batch_size: int = 16):
    """The cache's ``rows`` in batches of ``view``, ``fr`` and ``c`` (the ORP search and the equal-share baselines)."""
    from torch.utils.data import DataLoader

    from ..data.datamodule import ViewImageDataset

    ds = ViewImageDataset(cache.path, np.asarray(rows), pattern, fields=("view", "fr", "c"))
    return DataLoader(ds, batch_size=batch_size, shuffle=False, num_workers=0)
