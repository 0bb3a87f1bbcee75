"""Config helpers: run hashes take input checkpoints by content; checkpoints are checked before use."""
from __future__ import annotations

import os
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from data_gen.scene import register_resolvers as register_scene_resolvers
from imls_lightning.config import register_resolvers, settings_hash

ROOT = Path(__file__).resolve().parents[1]
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
