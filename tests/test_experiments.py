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
    cfg.paths.output_dir = "not-used"  # ${hydra:runtime.output_dir}, never written here
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


PIPELINES = CONF / "pipelines"
#: the stage commands each benchmark row's shell script printed before the row became an experiment (issue 87), one
#: file per experiment, its header naming the script, its settings and the commit that held it
ROW_COMMANDS = ROOT / "tests" / "row_commands"
ROWS = sorted(p.stem for p in ROW_COMMANDS.glob("*.txt"))
#: the pipeline experiments that are benchmark rows: they compose a row protocol (conf/pipelines/protocol)
PROTOCOL_ROWS = sorted(p.stem for p in (PIPELINES / "experiment").glob("*.yaml") if "- /protocol/" in p.read_text())


def _stage_commands(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.startswith("python -m")]


def _row_dry_run(experiment: str, monkeypatch, capsys, tmp_path, *overrides: str) -> list[str]:
    """The stage commands ``bench_paper +experiment=<experiment> dry_run=true`` prints, composed and run in this process
    (the CLI only adds the command-line checks and Hydra's logging), from an empty folder (no earlier tables)."""
    from hydra import compose, initialize_config_dir

    from imls_lightning.pipelines.bench_paper import bench_paper

    for name in ("IMLS_RUNS_DIR", "IMLS_CACHE_DIR"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.chdir(tmp_path)
    with initialize_config_dir(config_dir=str(PIPELINES), version_base="1.3"):
        cfg = compose(config_name="bench_paper", overrides=[f"+experiment={experiment}", "dry_run=true", *overrides])
    capsys.readouterr()
    assert bench_paper(cfg) is None
    return _stage_commands(capsys.readouterr().out)


def test_every_row_script_has_its_experiment():
    assert set(ROWS) <= set(PROTOCOL_ROWS)
    assert {"seed_whole_fastest", "seed_whole_fovolnet", "rt_plumes_enhancenet", "rt_plumes_fovolnet",
            "flame_whole_enhancenet"} <= set(ROWS)
    for name in ROWS:
        assert (PIPELINES / "experiment" / f"{name}.yaml").read_text().startswith("# @package _global_"), name


@pytest.mark.parametrize("experiment", ROWS)
def test_a_row_config_issues_the_commands_its_script_did(experiment, monkeypatch, capsys, tmp_path):
    """``bench_paper +experiment=<row>`` issues, in order and character for character, the stage commands the row's
    shell script issued (tests/row_commands/<row>.txt, printed by the script's dry run before it was deleted): the same
    overrides give the same run hashes, so the networks a row trained are found either way."""
    expected = _stage_commands((ROW_COMMANDS / f"{experiment}.txt").read_text())
    assert expected and _row_dry_run(experiment, monkeypatch, capsys, tmp_path) == expected


@pytest.mark.parametrize("experiment", PROTOCOL_ROWS)
def test_every_row_config_composes_and_runs_dry(experiment, monkeypatch, capsys, tmp_path):
    """A row added as one yaml (no script before it) composes with its protocol and reaches the evaluation, followed
    at most by the per-view adaptive mean (the older rows that ran one)."""
    modules = [c.split()[2] for c in _row_dry_run(experiment, monkeypatch, capsys, tmp_path)]
    assert "imls_lightning.evaluate" in modules
    assert modules[modules.index("imls_lightning.evaluate") + 1:] in ([], ["imls_lightning.adaptive"])


def test_a_rows_knobs_are_settings_of_the_command_line(monkeypatch, capsys, tmp_path):
    """The protocol's knobs (once environment variables of the shell rows) are keys the command line may set, checked
    like any other key; the sparser-pattern RecNN a FoVolNet row skips is one override away."""
    from imls_lightning.base.errors import check_config_keys

    knobs = ["protocol.timed_views=8", "protocol.ims_epochs=12", 'protocol.evaluate_extra=["las_searched=true"]',
             "stages.recnn_sparser=[]"]
    check_config_keys(PIPELINES, "bench_paper", ["+experiment=seed_whole_fovolnet", *knobs])
    commands = _row_dry_run("seed_whole_fovolnet", monkeypatch, capsys, tmp_path, *knobs)
    evaluate = commands[-1].split()
    assert "timed_views=8" in evaluate and "las_searched=true" in evaluate and "timed_views=12" not in evaluate
    assert any("trainer.max_epochs=12 model.monitor=val/fr_psnr" in c for c in commands)
    assert any("pattern.c_size_ratio=0.3536" in c for c in commands)  # the sparser FoVolNet trains


def test_a_row_runs_from_the_command_line(tmp_path):
    """The command a reader types, through the CLI's own checks: the seed_whole row's stage commands."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("IMLS_RUNS_DIR", "IMLS_CACHE_DIR")}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    run = subprocess.run([sys.executable, "-m", "imls_lightning.bench_paper", "+experiment=seed_whole_fastest", "dry_run=true"],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    assert _stage_commands(run.stdout) == _stage_commands((ROW_COMMANDS / "seed_whole_fastest.txt").read_text())


def test_the_tricubic_row_is_the_trilinear_row_with_tricubic_in_every_stage(monkeypatch, capsys, tmp_path):
    """``renderer_overrides`` reaches every stage's command right after ``renderer=<name>`` (the cache and the training
    render its pixels, so their caches and runs are their own), and the tricubic row differs from its trilinear twin
    in nothing else but its own fresh test trajectory."""
    trilinear = _row_dry_run("rayleigh_taylor_fastest", monkeypatch, capsys, tmp_path)
    tricubic = _row_dry_run("rayleigh_taylor_tricubic", monkeypatch, capsys, tmp_path)
    assert len(tricubic) == len(trilinear) == 10
    expected = [c.replace("renderer=numba", "renderer=numba renderer.interpolation=tricubic", 1)
                .replace("trajectory_seed=1208", "trajectory_seed=1209") for c in trilinear]
    assert tricubic == expected
    assert all(c.count("renderer.interpolation=tricubic") == 1 for c in tricubic)


@pytest.mark.parametrize("scene, seed, fresh", [("rayleigh_taylor", 1208, 1210), ("seed_whole", 1207, 1211)])
def test_the_decoder_choice_rows_evaluate_the_committed_networks_with_both_decoders(monkeypatch, capsys, tmp_path,
                                                                                     scene, seed, fresh):
    """<scene>_decoder_choice: the row's committed networks, no training, and an evaluation that differs from the
    row's own only by its fresh trajectory and the decoder candidates."""
    folder = ROOT / "benchmarks" / "rows" / scene
    row = _row_dry_run(f"{scene}_fastest", monkeypatch, capsys, tmp_path, f"trained={folder}")
    choice = _row_dry_run(f"{scene}_decoder_choice", monkeypatch, capsys, tmp_path)
    assert [c.split()[2] for c in choice] == ["imls_lightning.estimate", "data_gen", "imls_lightning.evaluate"]
    assert choice[:2] == row[:2]
    expected = row[2].replace(f"trajectory_seed={seed}", f"trajectory_seed={fresh}")
    extra = " 'orp_decoders=[trained,fill]'"  # shell-quoted as printed
    assert extra in choice[2] and choice[2].replace(extra, "") == expected


def test_a_row_evaluates_its_committed_networks_without_training(monkeypatch, capsys, tmp_path):
    """``trained=<folder>`` (pack_row's trained.yaml): each network it names, checked by SHA-256, stands in for its
    training stage; the cache and the evaluation run as before, on the committed files."""
    folder = ROOT / "benchmarks" / "rows" / "rayleigh_taylor"
    commands = _row_dry_run("rayleigh_taylor_fastest", monkeypatch, capsys, tmp_path, f"trained={folder}")
    assert [c.split()[2] for c in commands] == ["imls_lightning.estimate", "data_gen", "imls_lightning.evaluate"]
    evaluate = commands[-1].split()
    for key in ("ims", "recnn", "iml", "las", "blue_noise", "recnn_sparser"):
        assert f"checkpoints.{key}={folder / (key + '.ckpt')}" in evaluate


def test_a_row_packed_before_trained_yaml_evaluates_from_its_conf_row_record(monkeypatch, capsys, tmp_path):
    """seed_whole's folder has no trained.yaml: its conf/row/seed_whole.yaml names the same networks by SHA-256."""
    folder = ROOT / "benchmarks" / "rows" / "seed_whole"
    assert not (folder / "trained.yaml").exists()
    commands = _row_dry_run("seed_whole_fastest", monkeypatch, capsys, tmp_path, f"trained={folder}")
    assert [c.split()[2] for c in commands] == ["imls_lightning.estimate", "data_gen", "imls_lightning.evaluate"]
    assert f"checkpoints.ims={folder / 'ims.ckpt'}" in commands[-1].split()


def test_trained_networks_refuse_a_missing_record_or_an_altered_network_in_one_line(tmp_path):
    from imls_lightning.base.config import file_hash
    from imls_lightning.base.errors import InputError
    from imls_lightning.pipelines.pack_row import trained_networks

    with pytest.raises(InputError, match="no trained.yaml there"):
        trained_networks(tmp_path)
    (tmp_path / "recnn.ckpt").write_bytes(b"weights")
    record = {"name": "r", "networks": {"recnn": {"file": "recnn.ckpt", "sha256": file_hash(tmp_path / "recnn.ckpt", length=64)}}}
    OmegaConf.save(OmegaConf.create(record), tmp_path / "trained.yaml")
    assert trained_networks(tmp_path) == {"recnn": tmp_path / "recnn.ckpt"}
    (tmp_path / "recnn.ckpt").write_bytes(b"other weights")
    with pytest.raises(InputError, match="row=r: .*recnn.ckpt has SHA-256 .* the file was altered"):
        trained_networks(tmp_path)
    (tmp_path / "recnn.ckpt").unlink()
    with pytest.raises(InputError, match="its network recnn .* is missing"):
        trained_networks(tmp_path)
    OmegaConf.save(OmegaConf.create({"name": "r", "networks": {}}), tmp_path / "trained.yaml")
    with pytest.raises(InputError, match="names no networks"):
        trained_networks(tmp_path)
