"""Shared fixtures of the data_gen tests: the tiny scene preset."""
from __future__ import annotations

from pathlib import Path

import pytest
from omegaconf import OmegaConf

from data_gen.scenes import build_scene

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def tiny_scene():
    return build_scene(OmegaConf.load(ROOT / "conf" / "scene" / "tiny.yaml"))
