"""Experiment configs (conf/experiment/): each composes with every model, resolves, sets only keys
that exist, and pins the paper's settings; large_flame reads its volume memory-mapped."""
from __future__ import annotations

import inspect
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from hydra.utils import get_class
from omegaconf import DictConfig, OmegaConf

from data_gen.scenes import register_resolvers as register_scene_resolvers
from imls_lightning.base.config import register_resolvers

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
EXPERIMENTS = sorted(p.stem for p in (CONF / "experiment").glob("*.yaml"))
PAPER = ["paper_enhancenet", "paper_fovolnet"]
MODELS = ["recnn", "iml", "ims", "las"]
# top-level tables an experiment may add (read through interpolations, e.g. ${paper.patience.${model.name}})
OWN_TABLES = {"paper"}

register_resolvers()
register_scene_resolvers()


def _compose(overrides: list[str]) -> DictConfig:
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name="train", overrides=overrides)


def _resolve(cfg: DictConfig) -> DictConfig:
    """Resolve everything but ``${hydra:...}`` (only set inside a running Hydra app)."""
    cfg = OmegaConf.create(OmegaConf.to_container(cfg, resolve=False))
    cfg.paths.output_dir = "/tmp/not-used"  # ${hydra:runtime.output_dir}
    OmegaConf.resolve(cfg)
    return cfg


def _leaves(node, prefix=""):
    """Dotted paths of the leaf keys an experiment file sets (its defaults list left out)."""
    for k, v in node.items():
        if k == "defaults":
            continue
        key = f"{prefix}.{k}" if prefix else str(k)
        if isinstance(v, dict):
            yield from _leaves(v, key)
        else:
            yield key


def test_experiments_are_found():
    assert set(PAPER + ["large_flame"]) <= set(EXPERIMENTS)
    for name in EXPERIMENTS:
        assert (CONF / "experiment" / f"{name}.yaml").read_text().startswith("# @package _global_"), name


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_experiment_composes_resolves_and_sets_only_existing_keys(experiment, model):
    cfg = _resolve(_compose([f"experiment={experiment}", f"model={model}"]))
    assert cfg.model.name == model and isinstance(cfg.run_hash, str) and len(cfg.run_hash) == 8
    # the same composition without the experiment, with the experiment's group choices: every key
    # the experiment sets must already exist there (a typo would otherwise add a key silently)
    raw = OmegaConf.to_container(OmegaConf.load(CONF / "experiment" / f"{experiment}.yaml"))
    choices = [f"{k.split()[-1].lstrip('/')}={v}" for d in raw.get("defaults", []) for k, v in d.items()]
    base = _compose([*choices, f"model={model}"])
    for key in _leaves(raw):
        if key.split(".")[0] in OWN_TABLES:
            continue
        parent, leaf = key.rsplit(".", 1)
        node = OmegaConf.select(base, parent)
        assert node is not None, f"{experiment}: {parent} does not exist"
        if parent == "scene.volume":  # kind=file vs procedural presets hold different subsets
            from data_gen.volumes import VOLUME_CONFIG_KEYS

            assert leaf in VOLUME_CONFIG_KEYS, f"{experiment}: {key} is not a scene.volume key"
        elif leaf in node:
            continue
        elif "_target_" in node:  # constructor arguments the preset leaves at their defaults
            params = inspect.signature(get_class(node["_target_"])).parameters
            assert leaf in params, f"{experiment}: {key} is not an argument of {node['_target_']}"
        else:
            assert leaf in node, f"{experiment}: {key} does not exist without the experiment"


@pytest.mark.parametrize("experiment", PAPER)
def test_paper_experiments_pin_the_papers_settings(experiment):
    from imls_lightning.core.patterns import build_pattern

    per_model = {m: _resolve(_compose([f"experiment={experiment}", f"model={m}"])) for m in MODELS}
    cfg = per_model["iml"]
    # data: 2000 views split 9:1 + the 120-view trajectory, 512^2 FR-Images, 256^2 C-Images
    assert (cfg.data.num_views, cfg.data.test_views, cfg.data.val_fraction, cfg.data.resolution) == (2000, 120, 0.1, 512)
    pattern = build_pattern(OmegaConf.to_container(cfg.pattern), 64)  # the C-Image ratio, cheaply at 64^2
    assert pattern.c_size == 32
    # IML: U-Net depth 5, base 32; end-to-end loss 0.5 / 0.5; Adam 1e-3; patience 20
    m = cfg.model
    assert (m.depth, m.base_channels, m.compaction_weight, m.image_weight, m.lr, m.patience) == (5, 32, 0.5, 0.5, 1e-3, 20)
    # IMS: 8 layers; perceptual 1 + adversarial 0.01; Adam 1e-3; patience 1000
    m = per_model["ims"].model
    assert (m.layers, m.loss.perceptual.weight, m.loss.adversarial, m.lr, m.patience) == (8, 1.0, 0.01, 1e-3, 1000)
    assert per_model["ims"].trainer.max_epochs >= 3000  # the paper's IMS runs took 1632-2901 epochs
    assert per_model["recnn"].model.patience == 20 and per_model["las"].model.patience == 20
    # the command line still wins over the per-model table
    over = _resolve(_compose([f"experiment={experiment}", "model=ims", "model.patience=7", "trainer.max_epochs=9", "scene=tiny"]))
    assert (over.model.patience, over.trainer.max_epochs, over.scene.name) == (7, 9, "tiny")


def test_paper_recnns_are_full_size_and_build():
    import torch

    enh = _resolve(_compose(["experiment=paper_enhancenet"]))
    assert enh.pattern.kind == "downsample" and (enh.recnn.net.channels, enh.recnn.net.blocks) == (64, 10)
    fov = _resolve(_compose(["experiment=paper_fovolnet"]))
    assert fov.pattern.kind == "foveal" and fov.recnn.name == "fovolnet"
    from imls_lightning.tasks.recnn import RecNNTask

    # the full-size FoVolNet builds from the experiment's arguments (at 64^2: the pattern is cheap)
    task = RecNNTask(net=fov.recnn.net, pattern=fov.pattern, fr_size=64)
    n = task.pattern.c_size
    with torch.no_grad():
        assert task(torch.rand(1, 3, n, n)).shape == (1, 3, 64, 64)
    params = sum(p.numel() for p in task.parameters())
    small = RecNNTask(net={"_target_": fov.recnn.net._target_}, pattern=fov.pattern, fr_size=64)
    assert params > 4 * sum(p.numel() for p in small.parameters())  # larger than the CPU-sized default


def test_large_flame_reads_its_volume_memory_mapped(tmp_path):
    """The preset names the Flame-size file; a small file of the same generator, given as
    scene.volume.path, builds a scene whose voxels are a read-only memmap of that file."""
    from data_gen.procedural import make_procedural, write_procedural_raw
    from data_gen.scenes import build_scene
    from data_gen.volumes import parse_raw_name

    cfg = _resolve(_compose(["experiment=large_flame"]))
    info = parse_raw_name(cfg.scene.volume.path)
    assert info is not None and (info["dims"], np.dtype(info["dtype"])) == ((1408, 1080, 1100), np.float32)
    assert cfg.renderer.name == "numba" and cfg.scene.volume.kind == "file"

    dims = (24, 20, 28)
    raw = write_procedural_raw("flame", dims, tmp_path, seed=0, chunk_z=8)
    cfg = _resolve(_compose(["experiment=large_flame", f"scene.volume.path={raw}"]))
    scene = build_scene(cfg.scene)
    data = scene.volume.data
    assert isinstance(data, np.memmap) and not data.flags.writeable and Path(data.filename) == raw
    np.testing.assert_array_equal(np.asarray(data), make_procedural("flame", dims, 0).data)
    # the flame preset's look (transfer function) with the file's voxels
    flame = build_scene(_resolve(_compose(["scene=flame"])).scene, volume=scene.volume)
    np.testing.assert_array_equal(scene.transfer_function.color, flame.transfer_function.color)
    np.testing.assert_array_equal(scene.transfer_function.opacity, flame.transfer_function.opacity)


def test_the_seed_whole_fastest_row_config_issues_the_row_scripts_commands(tmp_path):
    """conf/pipelines/experiment/seed_whole_fastest.yaml is the row script's command as a config: both dry runs print
    the same stage commands (the same run hashes, so the trained networks are found either way). The script runs from
    a copy of its folder whose .venv/bin/activate only puts this interpreter first on PATH."""
    import os
    import shutil
    import subprocess
    import sys

    (tmp_path / "benchmarks" / "seed_whole").mkdir(parents=True)
    for name in ("whole_scene_row.sh", "row_protocol.sh", "seed_whole/row.sh"):
        shutil.copyfile(ROOT / "benchmarks" / name, tmp_path / "benchmarks" / name)
    (tmp_path / ".venv" / "bin").mkdir(parents=True)
    (tmp_path / ".venv" / "bin" / "activate").write_text(f'export PATH="{Path(sys.executable).parent}:$PATH"\n')
    env = {**os.environ, "FLOOR_BY_BAND": "1", "EVAL_EXTRA": "las_searched=true trajectory_seed=1207"}
    script = subprocess.run(["bash", str(tmp_path / "benchmarks" / "seed_whole" / "row.sh"), "dry_run=true"], cwd=tmp_path,
                            env=env, capture_output=True, text=True, timeout=300)
    config = subprocess.run([sys.executable, "-m", "imls_lightning.bench_paper", "+experiment=seed_whole_fastest", "dry_run=true"],
                            cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert script.returncode == 0 and config.returncode == 0, script.stderr[-2000:] + config.stderr[-2000:]
    commands = lambda out: [ln for ln in out.splitlines() if ln.startswith("python -m")]  # noqa: E731
    assert commands(config.stdout) and commands(config.stdout) == commands(script.stdout)
