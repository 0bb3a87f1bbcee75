"""Every Hydra CLI that composes a scene registers the scene presets' resolvers when it is imported: Hydra resolves
``hydra.run.dir`` (a run's name holds the scene's, which ``scene=file`` takes from the file through
``${imls_volume_name:...}``) before the task runs. ``train scene=file`` once failed there with "Unsupported
interpolation type imls_volume_name" (only the slow demo-on-your-own-file test saw it)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CLIS = ["train", "evaluate", "estimate", "adaptive", "cost_mask", "reproduce", "viewer", "web"]


@pytest.mark.parametrize("module", CLIS)
def test_importing_a_cli_registers_the_scene_resolvers(module):
    code = (f"import imls_lightning.{module}\nfrom omegaconf import OmegaConf\n"
            "assert OmegaConf.has_resolver('imls_volume_name')")
    p = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
