"""Shared fixtures of the adaptive tests: real tiny checkpoints (``tiny_checkpoints``, tests/conftest.py),
the IMS checkpoint read as ``target="pim"``, its cache and a renderer."""
from __future__ import annotations

from pathlib import Path

import pytest
import torch

from imls_lightning.inference.checkpoints import load_task

ROOT = Path(__file__).resolve().parents[2]


# ---- fixtures ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def pim_ckpt(tiny_checkpoints, tmp_path_factory) -> Path:
    """The tiny IMS checkpoint with ``target="pim"`` (in ``<run>/checkpoints/``, like a real run)."""
    ck = torch.load(tiny_checkpoints["ims"], map_location="cpu", weights_only=True)
    ck["hyper_parameters"]["target"] = "pim"
    out = tmp_path_factory.mktemp("adaptive_run") / "checkpoints" / "ims_pim.ckpt"
    out.parent.mkdir(parents=True)
    torch.save(ck, out)
    return out


@pytest.fixture(scope="module")
def tiny_cache(tiny_checkpoints):
    """The cache the tiny networks trained on and the adaptive CLI opens (``data=tiny``), found by its settings:
    other tests add caches of their own to the fixture's ``cache_dir``, so the first one in sorted order is not it."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from data_gen.cache import ViewImageCache, ensure_cache
    from data_gen.scenes import build_scene

    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3", job_name="tiny_cache"):
        cfg = compose("train", overrides=["scene=tiny", "data=tiny", "renderer=numba",
                                          f"data.cache_dir={tiny_checkpoints['cache_dir']}"])
    GlobalHydra.instance().clear()
    cache = ViewImageCache.open(ensure_cache(build_scene(cfg.scene), cfg.data, cfg.renderer, progress=False))
    assert cache.resolution == 32 and cache.complete, cache.path
    return cache


@pytest.fixture(scope="module")
def pim_task(pim_ckpt):
    return load_task(pim_ckpt, expect="IMSTask")


@pytest.fixture(scope="module")
def renderer(pim_task):
    from imls_lightning.render import make_renderer
    from data_gen.scenes import build_scene

    return make_renderer(build_scene(pim_task.hparams["scene"]), pim_task.hparams["renderer"])
