"""Shared fixtures of the adaptive tests: real tiny checkpoints (``tiny_checkpoints``, tests/conftest.py),
the IMS checkpoint read as ``target="pim"``, its cache and a renderer."""
from __future__ import annotations

from pathlib import Path

import pytest
import torch

from imls_lightning.inference.checkpoints import load_task


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
    from data_gen.cache import ViewImageCache

    for manifest in sorted(Path(tiny_checkpoints["cache_dir"]).rglob("manifest.json")):
        c = ViewImageCache.open(manifest.parent, require_complete=False)
        if c.resolution == 32 and c.complete:
            return c
    pytest.fail("no complete 32^2 tiny cache in the fixture's cache_dir")


@pytest.fixture(scope="module")
def pim_task(pim_ckpt):
    return load_task(pim_ckpt, expect="IMSTask")


@pytest.fixture(scope="module")
def renderer(pim_task):
    from data_gen.renderers import make_renderer
    from data_gen.scene import build_scene

    return make_renderer(build_scene(pim_task.hparams["scene"]), pim_task.hparams["renderer"])
