"""Tasks are built from config (``training.build_task``: ``instantiate`` of the ``model`` node plus
the task's ``config_context``), and each model default lives in one place, ``conf/model/<name>.yaml``."""
from __future__ import annotations

import ast
import inspect
import os
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import get_class
from omegaconf import OmegaConf, open_dict

from imls_lightning.base.errors import InputError
from data_gen.scenes import register_resolvers as register_scene_resolvers
from imls_lightning.base.config import is_checkpoint_key, register_resolvers
from imls_lightning.inference.checkpoints import load_task
from imls_lightning.tasks.iml import IMLTask
from imls_lightning.tasks.ims import IMSTask
from imls_lightning.tasks.recnn import RecNNTask
from imls_lightning.training.fit import build_datamodule, build_task

ROOT = Path(__file__).resolve().parents[2]
MODELS = ["recnn", "iml", "ims", "las"]
# keys of a model node for the training run, not the task's constructor (which ignores them, **_):
# the run name, early stopping / best checkpoint, IMS labelling, and a checkpoint that only enters the run hash
RUN_KEYS = {"_target_", "name", "patience", "monitor", "labels_batch_size", "labels_device", "recnn_checkpoint"}
# receivers whose .get(key, default) reads a checkpoint's saved hyperparameters: an older checkpoint may
# lack a key, and the fallback is the behaviour it was trained with, not a second default of the config
HPARAMS = {"h", "hp", "hparams", "self.hparams", "iml_hparams", "recnn_hparams"}
FR = 32
DOWN = {"kind": "downsample", "factor": 2}
FOVEAL = {"kind": "foveal", "c_size": 16, "sigma": 0.1}
ENHANCE = {"_target_": "imls_lightning.models.enhancenet.EnhanceNet", "channels": 4, "blocks": 1}
NO_PER = {"bce": 1.0, "perceptual": 0.0, "adversarial": 0.01}
SMALL = dict(layers=5, base_channels=8, disc_base_channels=8)
pytestmark = pytest.mark.filterwarnings("ignore:.*does not have many workers.*", "ignore:.*LeafSpec.*")
SCENE = {"name": "tiny", "volume": {"kind": "procedural", "generator": "tiny", "seed": 0}, "transfer_function": {"auto": True}}
FOVOL = {"_target_": "imls_lightning.models.fovolnet.FoVolNet", "features": 4, "depth": 2, "base_channels": 4,
         "filter_channels": 4, "levels": 2}

register_resolvers()
register_scene_resolvers()


def _compose(overrides: list[str]):
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3", job_name="test_task_config"):
        return compose("train", overrides=overrides)


def _yaml(model: str):
    return OmegaConf.load(ROOT / "conf" / "model" / f"{model}.yaml")


def _overrides(model: str, ck: dict) -> list[str]:
    """The tiny settings the session's checkpoints (conftest ``tiny_checkpoints``) were trained with."""
    common = ["scene=tiny", "data=tiny", "renderer=numba", f"data.cache_dir={ck['cache_dir']}", "recnn=enhancenet",
              "recnn.net.channels=4", "recnn.net.blocks=1", f"model={model}", "model.lr=0.0042"]
    return common + {
        "recnn": [],
        "iml": ["model.mode=end_to_end", f"recnn.checkpoint={ck['recnn']}", "model.depth=2", "model.base_channels=4"],
        "ims": [f"iml.checkpoint={ck['iml']}", "model.layers=5", "model.base_channels=8", "model.disc_base_channels=8",
                "model.loss.perceptual.weight=0", "model.loss.bce=1"],
        "las": ["model.low_res=16", "model.importance_channels=4", "model.importance_blocks=1",
                "model.recon_channels=4", "model.recon_blocks=1"],
    }[model]


def _same_weights(a: torch.nn.Module, b: torch.nn.Module) -> bool:
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)


@pytest.mark.parametrize("model", MODELS)
def test_build_task_instantiates_the_composed_model_node(model, tiny_checkpoints):
    cfg = _compose(_overrides(model, tiny_checkpoints))
    task = build_task(cfg)
    assert type(task) is get_class(cfg.model._target_)
    # every setting of the node reaches the task as it is there (command-line overrides included)
    node = OmegaConf.to_container(cfg.model, resolve=True)
    shared = [k for k in node if k in task.hparams and not is_checkpoint_key(k)]
    assert "lr" in shared and task.hparams.lr == 0.0042
    for k in shared:
        assert task.hparams[k] == node[k], k
    # and the context from outside it
    assert task.hparams.fr_size == cfg.data.resolution
    if model == "iml":  # end to end: the RecNN of recnn.checkpoint, weights included
        assert _same_weights(task.recnn, load_task(tiny_checkpoints["recnn"], expect="RecNNTask").net)
    if model == "ims":  # the IML of iml.checkpoint and the RecNN inside it; the loss built before any labelling
        iml = load_task(tiny_checkpoints["iml"], expect="IMLTask")
        assert _same_weights(task.iml, iml.iml) and _same_weights(task.recnn, iml.recnn)
        assert task.hparams.recnn_source == "iml.checkpoint" and "_im_loss" in task._modules
        assert task.hparams.iml_checkpoint == str(Path(tiny_checkpoints["iml"]).resolve())


@pytest.mark.parametrize("model", MODELS)
def test_every_yaml_key_is_an_argument_or_a_run_key(model):
    """The constructors ignore unknown keys (**_), so a typo in a model YAML would be swallowed."""
    node = _yaml(model)
    params = set(inspect.signature(get_class(node._target_).__init__).parameters) - {"self", "_"}
    assert set(node) - RUN_KEYS <= params, sorted(set(node) - RUN_KEYS - params)
    assert not (set(node) & RUN_KEYS & params), "a run key is a constructor argument too"


def _model_key_defaults(path: Path, keys: set[str]) -> list[str]:
    """``X.get("<model key>", <default>)`` calls in ``path`` that do not read checkpoint hyperparameters."""
    hits = []
    for node in ast.walk(ast.parse(path.read_text())):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "get"
                and len(node.args) == 2 and isinstance(node.args[0], ast.Constant) and node.args[0].value in keys
                and ast.unparse(node.func.value) not in HPARAMS):
            hits.append(f"{path.name}:{node.lineno}: {ast.unparse(node)}")
    return hits


def test_no_second_default_for_a_model_key():
    """A model key is read from the node as it is (``cfg.model.<key>``), never with a fallback in
    Python: that fallback would be a second default, silently out of step with the YAML."""
    every = set().union(*(set(_yaml(m)) for m in MODELS)) - {"_target_"}
    files = {ROOT / "imls_lightning" / "tasks" / f"{m}.py": set(_yaml(m)) for m in MODELS}
    files[ROOT / "imls_lightning" / "training" / "fit.py"] = every
    hits = [h for path, keys in files.items() for h in _model_key_defaults(path, keys)]
    assert not hits, hits
    for m in MODELS:  # one way from config to task: build_task
        assert not hasattr(get_class(_yaml(m)._target_), "from_config"), m


def test_a_missing_model_key_fails_by_name():
    """Without its YAML default a run key fails, naming itself, instead of taking a Python default."""
    cfg = _compose(["model=ims", "iml.checkpoint=/not/used.ckpt"])
    from imls_lightning.tasks.ims import IMSTask

    assert IMSTask.datamodule_kwargs(cfg)["labels_options"] == {"batch_size": 16, "device": "auto"}
    with open_dict(cfg):
        del cfg.model["labels_batch_size"]
    with pytest.raises(Exception, match="labels_batch_size"):
        IMSTask.datamodule_kwargs(cfg)


@pytest.mark.parametrize("bar", [True, False])
def test_the_trainers_progress_switch_also_silences_the_datamodule(bar):
    """trainer.enable_progress_bar=false (every pipeline stage) also turns off the cache's and labels' bars."""
    cfg = _compose(["model=recnn", f"trainer.enable_progress_bar={str(bar).lower()}"])
    assert build_datamodule(cfg, RecNNTask).progress is bar


def test_resume_path_fallbacks(tmp_path, capsys):
    from omegaconf import OmegaConf

    from imls_lightning.training.fit import _resume_path

    ck = tmp_path / "checkpoints"
    ck.mkdir()
    cfg = OmegaConf.create({"resume": "auto"})
    assert _resume_path(cfg, tmp_path) is None  # nothing yet
    torch.save({"x": torch.zeros(3)}, ck / "epoch001.ckpt")
    (ck / "last.ckpt").write_bytes(b"PK\x03\x04 cut")
    assert _resume_path(cfg, tmp_path) == str(ck / "epoch001.ckpt")
    assert "resuming from the newest intact checkpoint" in capsys.readouterr().err
    _truncate(ck / "epoch001.ckpt")
    assert _resume_path(cfg, tmp_path) is None
    assert "training starts over" in capsys.readouterr().err


def save_checkpoint(task, path, dm=None, steps=2):
    tr = quiet_trainer(max_steps=steps, limit_val_batches=0)
    if dm is not None:
        tr.fit(task, datamodule=dm)
    else:
        tr.strategy.connect(task)
    tr.save_checkpoint(path)
    return str(path)


def ims_cfg(tmp_path, iml_ckpt, recnn_ckpt=None, pattern=DOWN, **model):
    m = OmegaConf.load(ROOT / "conf" / "model" / "ims.yaml")
    m.merge_with({**SMALL, "loss": NO_PER, "labels_device": "cpu", **model})
    return OmegaConf.create({
        "scene": SCENE,
        "data": {"num_views": 24, "test_views": 4, "resolution": FR, "workers": 0, "cache_dir": str(tmp_path / "cache"),
                 "fsync": False, "batch_size": 4},
        "renderer": {"name": "vtk"}, "pattern": pattern,
        "recnn": {"name": "enhancenet", "net": ENHANCE, "checkpoint": recnn_ckpt},
        "iml": {"checkpoint": iml_ckpt}, "model": m,
    })


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory):
    from imls_lightning.data import ImlsDataModule

    root = tmp_path_factory.mktemp("ims_ckpts")
    torch.manual_seed(0)
    data = {"num_views": 24, "test_views": 4, "resolution": FR, "workers": 0, "cache_dir": str(root / "cache"), "fsync": False, "batch_size": 4}
    dm = ImlsDataModule(SCENE, data, {"name": "vtk"}, DOWN, fields=("view", "fr", "c"), progress=False)
    recnn = save_checkpoint(RecNNTask(ENHANCE, DOWN, FR), root / "recnn.ckpt", dm)
    standalone = save_checkpoint(IMLTask(DOWN, FR, depth=2, base_channels=4), root / "iml.ckpt", dm)
    e2e = IMLTask(DOWN, FR, mode="end_to_end", depth=2, base_channels=4, recnn_hparams=recnn_hparams(), finetune_recnn=True)
    e2e = save_checkpoint(e2e, root / "iml_e2e.ckpt", dm)
    return {"recnn": recnn, "standalone": standalone, "e2e": e2e}


def test_build_task_end_to_end_iml_brings_its_recnn(tmp_path, checkpoints, capsys):
    cfg = ims_cfg(tmp_path, checkpoints["e2e"], recnn_ckpt=checkpoints["recnn"])
    task = build_task(cfg)
    assert "recnn.checkpoint is ignored" in capsys.readouterr().out
    iml = load_task(checkpoints["e2e"], expect="IMLTask")
    assert task.hparams.recnn_source == "iml.checkpoint"
    for (k, a), b in zip(task.recnn.state_dict().items(), iml.recnn.state_dict().values()):
        assert torch.equal(a, b), k  # the fine-tuned RecNN of the IML checkpoint, not recnn.checkpoint's
    for a, b in zip(task.iml.state_dict().values(), iml.iml.state_dict().values()):
        assert torch.equal(a, b)
    assert not any(p.requires_grad for p in task.iml.parameters()) and not any(p.requires_grad for p in task.recnn.parameters())
    # the task only records where the labels go; the DataModule makes them (data flows forward)
    labels = Path(task.hparams.labels)
    assert labels.parent.name == "labels" and not labels.exists()
    kw = IMSTask.datamodule_kwargs(cfg)
    assert kw["fields"] == ("view", "fr", "c") and kw["labels_from"] == str(checkpoints["e2e"])
    dm = build_datamodule(cfg, IMSTask)
    dm.prepare_data()
    assert dm.labels == labels and (labels / "meta.json").is_file()
    tr = quiet_trainer(max_epochs=1, limit_train_batches=2, limit_val_batches=1)
    tr.fit(task, datamodule=dm)
    assert bool(task.view_norm_fitted)
    from data_gen.cache import ViewImageCache

    cache = ViewImageCache.open(dm.cache_path)
    torch.testing.assert_close(task.generator.view_mean, torch.from_numpy(np.asarray(cache.views[cache.splits["train"]])).mean(0))
    assert "val/fr_psnr" in tr.callback_metrics and "val/label_fr_psnr" in tr.callback_metrics
    # frozen passengers did not move
    for a, b in zip(task.iml.state_dict().values(), iml.iml.state_dict().values()):
        assert torch.equal(a, b)


def test_build_task_standalone_iml_takes_recnn_checkpoint(tmp_path, checkpoints):
    task = build_task(ims_cfg(tmp_path, checkpoints["standalone"], recnn_ckpt=checkpoints["recnn"], target="pim"))
    rec = load_task(checkpoints["recnn"], expect="RecNNTask")
    assert task.hparams.recnn_source == "recnn.checkpoint" and task.target == "pim"
    for a, b in zip(task.recnn.state_dict().values(), rec.net.state_dict().values()):
        assert torch.equal(a, b)
    task = build_task(ims_cfg(tmp_path, checkpoints["standalone"]))
    assert task.recnn is None and task.hparams.recnn_source is None


def test_build_task_exceptions(tmp_path, checkpoints):
    with pytest.raises(InputError, match="set iml.checkpoint=<path to an IML .ckpt>"):
        build_task(ims_cfg(tmp_path, None))
    with pytest.raises(InputError, match="iml.checkpoint=.*file not found"):
        build_task(ims_cfg(tmp_path, str(tmp_path / "nope.ckpt")))
    with pytest.raises(InputError, match="a RecNNTask checkpoint, expected a IMLTask"):
        build_task(ims_cfg(tmp_path, checkpoints["recnn"]))
    with pytest.raises(InputError, match="choose the recnn/pattern and data.resolution it was trained with"):
        build_task(ims_cfg(tmp_path, checkpoints["standalone"], pattern=FOVEAL))
    with pytest.raises(InputError, match="a IMLTask checkpoint, expected a RecNNTask"):
        build_task(ims_cfg(tmp_path, checkpoints["standalone"], recnn_ckpt=checkpoints["standalone"]))


def _truncate(path: Path) -> None:
    os.truncate(path, path.stat().st_size // 2)


def recnn_hparams(pattern=DOWN) -> dict:
    """A tiny EnhanceNet (downsampling pattern) or FoVolNet (foveal pattern)."""
    return dict(RecNNTask(ENHANCE if pattern["kind"] == "downsample" else FOVOL, pattern, FR).hparams)


def quiet_trainer(**kw) -> L.Trainer:
    args = dict(accelerator="cpu", logger=False, enable_checkpointing=False, enable_progress_bar=False,
                enable_model_summary=False, num_sanity_val_steps=0)
    args.update(kw)
    return L.Trainer(**args)

