"""Settings and checks shared by the data_gen and render test modules (one home: cache, reader, workers, contact
sheet, both renderers)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

# VTK's fixed-point mapper: deterministic, and fast enough for 24^2 test caches
VTK = {"name": "vtk", "mapper": "fixed_point"}


def cache_data(tmp_path, **kw) -> dict:
    """A small ``data`` config node (10 views + 6 test views at 24^2) caching under ``tmp_path/cache``;
    ``kw`` overrides or adds keys."""
    d = {"num_views": 10, "test_views": 6, "resolution": 24, "workers": 0, "seed": 0,
         "cache_dir": str(tmp_path / "cache")}
    d.update(kw)
    return d


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie or a dead process does not)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ("Z", "X")


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR (dB) of two uint8 images, written out directly (the tests' reference formula)."""
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 10.0 * math.log10(255.0 ** 2 / max(mse, 1e-12))


# ---- sample distance: the opacity correction keeps images alike ---------------------------------
# Measured (64^2, a front and an oblique view, PSNR between 0.5 and 0.25 voxel): tiny 52-53 dB, flame
# 54-61 dB; at 128^2 ct_head 51-56 dB and mri_head 57-61 dB; both renderers alike. The same tiny pair
# without the correction (every sample taking the transfer function's opacity as is) is at 29.6 dB.
MIN_PSNR_ACROSS_SAMPLE_DISTANCES = 45.0
SAMPLE_DISTANCE_VIEWS = [[0.0, -4.5, 0.0, 0, 0, 0, 0, 0, 1], [2.7, 2.2, 2.7, 0, 0, 0, 0, 0, 1]]


def check_images_alike_across_sample_distances(renderer_cls, view) -> None:
    """Renders of the tiny scene at 0.5 and 0.25 voxel agree (the opacity correction), and without the
    correction they clearly do not (so the check can fail)."""
    from omegaconf import OmegaConf

    from data_gen.scenes import build_scene

    cfg = OmegaConf.load(Path(__file__).resolve().parents[2] / "conf" / "scene" / "tiny.yaml")
    half = build_scene(OmegaConf.merge(cfg, {"sample_distance_voxels": 0.5}))
    quarter = build_scene(OmegaConf.merge(cfg, {"sample_distance_voxels": 0.25}), volume=half.volume)
    assert abs(quarter.sample_distance - half.sample_distance / 2) < 1e-9 * half.sample_distance
    a, b = renderer_cls(half).render(view, 64), renderer_cls(quarter).render(view, 64)
    assert (a.max(axis=2) > 10).mean() > 0.05   # something to compare
    assert psnr(a, b) >= MIN_PSNR_ACROSS_SAMPLE_DISTANCES
    raw_half = build_scene(OmegaConf.merge(cfg, {"sample_distance_voxels": 0.5, "opacity_unit_distance": half.sample_distance}),
                           volume=half.volume)
    raw_quarter = build_scene(OmegaConf.merge(cfg, {"sample_distance_voxels": 0.25, "opacity_unit_distance": quarter.sample_distance}),
                              volume=half.volume)
    assert psnr(renderer_cls(raw_half).render(view, 64), renderer_cls(raw_quarter).render(view, 64)) < MIN_PSNR_ACROSS_SAMPLE_DISTANCES - 5
