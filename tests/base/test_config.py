"""Config helpers: run hashes take input checkpoints by content; checkpoints are checked before use."""
from __future__ import annotations

import os
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from data_gen.scenes import register_resolvers as register_scene_resolvers
from imls_lightning.base.config import register_resolvers, settings_hash

ROOT = Path(__file__).resolve().parents[2]
register_resolvers()
register_scene_resolvers()


def _run_hash(overrides: list[str]) -> str:
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="train", overrides=overrides)
    return str(OmegaConf.select(cfg, "run_hash"))


def test_run_hash_follows_checkpoint_content_not_path(tmp_path):
    """A checkpoint replaced at the same path must not reuse runs made with the old one (issue 17, 4)."""
    ck = tmp_path / "iml.ckpt"
    ck.write_bytes(b"old weights")
    for model, key in (("ims", "iml.checkpoint"), ("iml", "recnn.checkpoint")):
        first = _run_hash([f"model={model}", f"{key}={ck}"])
        ck.write_bytes(b"new weights, same path")
        os.utime(ck, ns=(1, 1))
        assert _run_hash([f"model={model}", f"{key}={ck}"]) != first
        moved = tmp_path / "elsewhere.ckpt"
        moved.write_bytes(ck.read_bytes())
        assert _run_hash([f"model={model}", f"{key}={moved}"]) == _run_hash([f"model={model}", f"{key}={ck}"])
        ck.write_bytes(b"old weights")


def test_settings_hash_checkpoint_keys(tmp_path):
    a, b = tmp_path / "a.ckpt", tmp_path / "b.ckpt"
    a.write_bytes(b"x")
    b.write_bytes(b"x")
    assert settings_hash({"checkpoint": str(a)}) == settings_hash({"checkpoint": str(b)})
    assert settings_hash({"ims_checkpoint": str(a)}) == settings_hash({"ims_checkpoint": str(b)})
    b.write_bytes(b"y")
    assert settings_hash({"checkpoint": str(a)}) != settings_hash({"checkpoint": str(b)})
    # not a file (yet): the path itself
    assert settings_hash({"checkpoint": str(tmp_path / "no.ckpt")}) != settings_hash({"checkpoint": str(tmp_path / "no2.ckpt")})
    assert settings_hash({"checkpoint": None}) == settings_hash({"checkpoint": None})


@pytest.mark.parametrize("metric, mode", [("val/fr_psnr", "max"), ("val/fr_ssim", "max"), ("val/im_iou", "max"),
                                          ("val/im_accuracy", "max"), ("val/im_error", "min"), ("val/loss", "min"),
                                          ("val/ipr_error", "min"), ("val/mse", "min")])
def test_monitor_mode_follows_the_metric(metric, mode):
    from imls_lightning.base.config import monitor_mode

    assert monitor_mode(metric) == mode


def test_callbacks_take_the_monitor_mode_and_the_run_hash_is_unchanged():
    """model.monitor=val/fr_psnr (the product path's PSNR) keeps its best epoch by the highest value; the
    default monitors keep mode min, and runs made before the resolver existed keep their hashes."""
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3"):
        psnr = compose(config_name="train", overrides=["model=ims", "model.monitor=val/fr_psnr"])
        default = compose(config_name="train", overrides=["model=ims"])
    assert psnr.callbacks.model_checkpoint.mode == "max" and psnr.callbacks.early_stopping.mode == "max"
    assert default.callbacks.model_checkpoint.mode == "min" and default.callbacks.early_stopping.mode == "min"
    assert "monitor_mode" not in default.model  # the mode is derived: the model's settings (its run hash) do not change


def test_run_hash_of_the_demos_recnn_stage_is_pinned():
    """A run's directory is the hash of its settings: a refactor or a new config key must not change it,
    or every earlier run is trained again (issue 33, item 8). The demo's RecNN stage as `make demo` ran it
    before its RecNN narrowed to 16 channels."""
    demo_recnn = ["model=recnn", "scene=flame", "data=small", "renderer=numba", "data.cache_dir=cache", "recnn=enhancenet",
                  "paths.runs_dir=runs/demo", "seed=0", "trainer.enable_progress_bar=false", "trainer.max_epochs=10",
                  "recnn.net.channels=32", "recnn.net.blocks=4"]
    assert _run_hash(demo_recnn) == "898ec7f5"
    # a key added later enters the hash only away from the value every earlier run had
    assert _run_hash([*demo_recnn, "data.train_pixels=all"]) == "898ec7f5"
    assert _run_hash([*demo_recnn, "data.train_pixels=pattern"]) != "898ec7f5"
    # renderer.skip_empty (numba.yaml's new key, true) too: caches and runs made before it keep their hashes
    assert _run_hash([*demo_recnn, "renderer.skip_empty=true"]) == "898ec7f5"
    assert _run_hash([*demo_recnn, "renderer.skip_empty=false"]) != "898ec7f5"


def test_the_decoder_stages_keys_leave_earlier_ims_runs_their_hashes():
    """model=ims's decoder-stage keys at their defaults (model.decoder_sharpness, decoder_lift, train_generator,
    init_checkpoint) leave the hash of every IMS run made before them; set, they make a run of their own."""
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3"):
        ims = compose(config_name="train", overrides=["model=ims"])
    node = OmegaConf.to_container(ims.model, resolve=True)
    new = ("decoder_sharpness", "decoder_lift", "train_generator", "init_checkpoint")
    assert [node[k] for k in new] == [[1.0], False, True, None]
    before = {k: v for k, v in node.items() if k not in new}
    assert settings_hash({"model": node}) == settings_hash({"model": before})
    for key, value in (("decoder_sharpness", [3.0]), ("decoder_lift", True), ("train_generator", False), ("init_checkpoint", "a.ckpt")):
        assert settings_hash({"model": {**node, key: value}}) != settings_hash({"model": before}), key


def test_model_fill_defaults_by_pattern_kind_and_only_a_foveal_run_changes_its_hash():
    """The IML decoder fills at a foveal C-Image's FR positions (model.fill=fr); on a grid both fills are the same,
    and model.fill=c leaves out of the hash, so every grid-pattern IML run keeps its directory."""
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3"):
        fov = compose(config_name="train", overrides=["model=iml", "recnn=fovolnet"])
        grid = compose(config_name="train", overrides=["model=iml"])
    assert fov.model.fill == "fr" and grid.model.fill == "c"
    assert settings_hash({"model": {"mean": 0.2}}) == settings_hash({"model": {"mean": 0.2, "fill": "c"}})
    assert settings_hash({"model": {"mean": 0.2}}) != settings_hash({"model": {"mean": 0.2, "fill": "fr"}})


def test_run_hash_of_the_demos_iml_stage_is_pinned_and_only_a_foveal_run_moves_with_model_fill():
    """model.fill entered the IML's settings after runs existed: the demo's IML stage (a grid pattern) keeps its
    directory, a FoVolNet IML filling at the FR positions (the new default) is a new run, and one asked for with
    model.fill=c is found where the runs trained before the key were (hashes computed on the commit before it)."""
    iml = ["model=iml", "scene=flame", "data=small", "renderer=numba", "data.cache_dir=cache", "paths.runs_dir=runs/demo",
           "seed=0", "trainer.enable_progress_bar=false", "model.mode=end_to_end", "model.mean=0.2", "model.mean_range=[0.1,0.6]",
           "model.depth=4", "model.base_channels=8", "data.batch_size=2", "trainer.max_epochs=12"]
    assert _run_hash([*iml, "recnn=enhancenet"]) == "cad82173"
    assert _run_hash([*iml, "recnn=fovolnet", "model.fill=c"]) == "1c27d9eb"
    assert _run_hash([*iml, "recnn=fovolnet"]) not in ("1c27d9eb", "cad82173")
