"""Tasks are built from config (``training.build_task``: ``instantiate`` of the ``model`` node plus
the task's ``config_context``), and each model default lives in one place, ``conf/model/<name>.yaml``."""
from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import get_class
from omegaconf import OmegaConf, open_dict

from data_gen.scene import register_resolvers as register_scene_resolvers
from imls_lightning.config import is_checkpoint_key, register_resolvers
from imls_lightning.tasks.base import load_task
from imls_lightning.training import build_task

ROOT = Path(__file__).resolve().parents[1]
MODELS = ["recnn", "iml", "ims", "las"]
# keys of a model node for the training run, not the task's constructor (which ignores them, **_):
# the run name, early stopping / best checkpoint, IMS labelling, and a checkpoint that only enters the run hash
RUN_KEYS = {"_target_", "name", "patience", "monitor", "labels_batch_size", "labels_device", "recnn_checkpoint"}
# receivers whose .get(key, default) reads a checkpoint's saved hyperparameters: an older checkpoint may
# lack a key, and the fallback is the behaviour it was trained with, not a second default of the config
HPARAMS = {"h", "hp", "hparams", "self.hparams", "iml_hparams", "recnn_hparams"}

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
    files[ROOT / "imls_lightning" / "training.py"] = every
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
