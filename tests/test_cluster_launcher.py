"""The cluster extra (``pip install 'imls-lightning[cluster]'``, ``docs/CLUSTER.md``): Hydra's submitit
launcher, whose plugin ships the ``hydra/launcher`` configs (``submitit_slurm``, ``submitit_local``),
composes with the training config. Skips, saying why, where the extra is not installed."""
from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_the_cluster_extra_names_the_launcher_the_docs_describe():
    pyproject = (ROOT / "pyproject.toml").read_text()
    extras = pyproject.split("[project.optional-dependencies]", 1)[1].split("\n[", 1)[0]
    assert 'cluster = ["hydra-submitit-launcher>=1.2"]' in extras.splitlines()
    doc = (ROOT / "docs" / "CLUSTER.md").read_text()
    assert "imls-lightning[cluster]" in doc and "hydra/launcher=submitit_slurm" in doc


@pytest.mark.parametrize("launcher, target", [("submitit_slurm", "SlurmLauncher"), ("submitit_local", "LocalLauncher")])
def test_submitit_launcher_composes_with_the_training_config(launcher, target):
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher",
                        reason="hydra-submitit-launcher is not installed (pip install -e '.[cluster]')")
    from hydra import compose, initialize_config_dir

    overrides = [f"hydra/launcher={launcher}", "hydra.launcher.timeout_min=1440", "hydra.launcher.cpus_per_task=8",
                 "model=iml", "model.mean=0.1"]
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3", job_name="test_cluster_launcher"):
        cfg = compose("train", overrides=overrides, return_hydra_config=True)
    assert cfg.hydra.launcher._target_ == f"hydra_plugins.hydra_submitit_launcher.submitit_launcher.{target}"
    assert cfg.hydra.launcher.timeout_min == 1440 and cfg.hydra.launcher.cpus_per_task == 8
    assert cfg.model.mean == 0.1
