"""The DataModule's patch crops (``data.crop``): what the RecNN and the IML train on at paper scale."""
from __future__ import annotations

from pathlib import Path

import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.data import ImlsDataModule
from imls_lightning.core.patterns import downsample_pattern
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def tiny_cfg(tmp_path_factory):
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    GlobalHydra.instance().clear()
    with initialize_config_dir(str(Path(__file__).resolve().parents[2] / "conf"), version_base="1.3", job_name="test_data"):
        cfg = compose("train", overrides=["scene=tiny", "data=tiny", "renderer=numba", "model=recnn",
                                          f"data.cache_dir={tmp_path_factory.mktemp('cache')}"])
    return cfg


def _dm(cfg, **kw):
    return ImlsDataModule(scene=cfg.scene, data=cfg.data, renderer=cfg.renderer, pattern=cfg.pattern, progress=False, **kw)


def test_crop_smoke_train_batches_are_grid_aligned_windows(tiny_cfg):
    dm = _dm(tiny_cfg, fields=("view", "fr", "c"), crop=16)
    dm.setup()
    torch.manual_seed(0)
    item = dm.dataset("train")[0]
    assert item["fr"].shape == (3, 16, 16) and item["c"].shape == (3, 8, 8)
    # the crop's C-Image is exactly the crop's downsampling-pattern pixels (fr[::2, ::2])
    assert torch.equal(item["c"], item["fr"][:, ::2, ::2])
    # and the window is one of the full image's, starting on the pattern's grid
    full = torch.from_numpy(dm.dataset("train")._open().images[int(item["index"])].copy()).permute(2, 0, 1).float() / 255
    hits = [(y, x) for y in range(0, 17, 2) for x in range(0, 17, 2) if torch.equal(full[:, y:y + 16, x:x + 16], item["fr"])]
    assert hits, "the crop is not a grid-aligned window of the FR-Image"
    batch = next(iter(dm.train_dataloader()))
    assert batch["fr"].shape[-2:] == (16, 16) and batch["c"].shape[-2:] == (8, 8)


def test_crop_validation_and_test_stay_whole(tiny_cfg):
    dm = _dm(tiny_cfg, fields=("fr", "c"), crop=16)
    dm.setup()
    for split in ("val", "test"):
        item = dm.dataset(split)[0]
        assert item["fr"].shape == (3, 32, 32) and item["c"].shape == (3, 16, 16)


@pytest.mark.parametrize("kw, needle", [({"crop": 7}, "not a multiple"), ({"crop": 64}, "larger than the FR-Image"),
                                        ({"crop": 4}, "too small to train on")])
def test_crop_exception_bad_value(tiny_cfg, kw, needle):
    with pytest.raises(InputError, match=needle):
        _dm(tiny_cfg, **kw)


def test_crop_exception_foveal_pattern(tiny_cfg):
    from omegaconf import OmegaConf

    with pytest.raises(InputError, match="foveal pattern changes with the position"):
        ImlsDataModule(scene=tiny_cfg.scene, data=tiny_cfg.data, renderer=tiny_cfg.renderer,
                       pattern=OmegaConf.create({"kind": "foveal", "c_size_ratio": 0.5}), crop=16)


def test_crop_exception_with_labels_or_low_res(tiny_cfg, tmp_path):
    from imls_lightning.data import ViewImageDataset

    with pytest.raises(InputError, match="train LAS and IMS with data.crop=null"):
        ViewImageDataset(tmp_path, [0], downsample_pattern(32, 2), labels_path=tmp_path, crop=16)


# ---- DataModule -------------------------------------------------------------------------------
def test_smoke_datamodule_yields_every_field(tmp_path):
    from omegaconf import OmegaConf

    from imls_lightning.core.compaction import compact
    from imls_lightning.data import ImlsDataModule

    conf = ROOT / "conf"
    scene = OmegaConf.load(conf / "scene" / "tiny.yaml")
    data = OmegaConf.merge(OmegaConf.load(conf / "data" / "default.yaml"), OmegaConf.load(conf / "data" / "tiny.yaml"))
    data.pop("defaults", None)
    data.cache_dir = str(tmp_path)
    pattern = OmegaConf.load(conf / "pattern" / "foveal.yaml")
    dm = ImlsDataModule(scene, data, {"name": "numba"}, pattern, progress=False, low_res=16)
    dm.prepare_data()
    dm.setup()
    n, m = dm.pattern.c_size, dm.pattern.fr_size
    batch = next(iter(dm.train_dataloader()))
    b = batch["fr"].shape[0]
    assert batch["view"].shape == (b, 9) and batch["fr"].shape == (b, 3, m, m)
    assert batch["c"].shape == (b, 3, n, n) and batch["pr"].shape == (b, 3, m, m) and batch["low"].shape == (b, 3, 16, 16)
    torch.testing.assert_close(batch["c"], compact(batch["fr"], dm.pattern.indices, n))
    off = ~dm.pattern.mask
    assert float(batch["pr"][..., off].abs().max()) == 0.0
    assert 0.0 <= float(batch["fr"].min()) and float(batch["fr"].max()) <= 1.0 and float(batch["fr"].max()) > 0.1
    sizes = {k: len(dm.dataset(k)) for k in ("train", "val", "test")}
    assert sizes == {"train": int(data.num_views) - int(round(data.num_views * data.val_fraction)),
                     "val": int(round(data.num_views * data.val_fraction)), "test": int(data.test_views)}


def test_exception_datamodule_bad_fields_and_batch_size(tmp_path):
    from imls_lightning.base.errors import InputError
    from imls_lightning.data import ImlsDataModule

    with pytest.raises(InputError, match="data fields"):
        ImlsDataModule({}, {"resolution": 32, "batch_size": 2}, {}, {"kind": "full"}, fields=("fr", "nope"))
    with pytest.raises(InputError, match="data.batch_size"):
        ImlsDataModule({}, {"resolution": 32, "batch_size": 0}, {}, {"kind": "full"})


def test_exception_resolution_too_small_names_the_smallest_that_works():
    """data.resolution=2 ended in a traceback from SSIM (issue 17, 9)."""
    from imls_lightning.base.errors import InputError
    from imls_lightning.data import ImlsDataModule

    for m in (1, 2, 5):
        with pytest.raises(InputError, match=rf"data.resolution={m}: too small to train on; the smallest that works is 6 "):
            ImlsDataModule({}, {"resolution": m, "batch_size": 2}, {}, {"kind": "downsample", "factor": 2})
    with pytest.raises(InputError, match=r"the smallest that works is 8 "):
        ImlsDataModule({}, {"resolution": 4, "batch_size": 2}, {}, {"kind": "downsample", "factor": 4})
    ImlsDataModule({}, {"resolution": 6, "batch_size": 2}, {}, {"kind": "downsample", "factor": 2})


# ---- data.train_pixels=pattern: the IMS's C-Image-only training views ---------------------------
def _with(cfg, **data):
    from omegaconf import OmegaConf

    c = cfg.copy()
    OmegaConf.set_struct(c, False)
    for k, v in data.items():
        c.data[k] = v
    return c


def test_train_pixels_pattern_smoke_c_images_without_fr(tiny_cfg):
    whole = _dm(tiny_cfg, fields=("view", "fr", "c"))
    whole.setup()
    dm = _dm(_with(tiny_cfg, train_pixels="pattern"), fields=("view", "fr", "pr", "c"), train_fr=False)
    dm.setup()
    assert dm.cache_path != whole.cache_path
    item, ref = dm.dataset("train")[0], whole.dataset("train")[0]
    assert "fr" not in item and item["index"] == ref["index"]
    assert torch.equal(item["c"], ref["c"])  # the C-Image is exactly the whole frame's
    assert torch.equal(item["pr"], ref["fr"] * dm.pattern.mask.to(ref["fr"].dtype))
    batch = next(iter(dm.train_dataloader()))
    assert "fr" not in batch and batch["c"].shape[-2:] == (16, 16)
    for split in ("val", "test"):  # validated and tested on whole frames
        assert torch.equal(dm.dataset(split)[0]["fr"], whole.dataset(split)[0]["fr"])


@pytest.mark.parametrize("kw, data, needle", [
    ({}, {"train_pixels": "pattern"}, "only the IMS trains on C-Images alone"),
    ({"train_fr": False, "crop": 16}, {"train_pixels": "pattern"}, "only the IMS trains on C-Images alone"),
    ({"train_fr": False}, {"train_pixels": "some"}, r"data.train_pixels='some': expected one of \['all', 'pattern'\]"),
])
def test_train_pixels_exception_bad_use(tiny_cfg, kw, data, needle):
    with pytest.raises(InputError, match=needle):
        _dm(_with(tiny_cfg, **data), **kw)
