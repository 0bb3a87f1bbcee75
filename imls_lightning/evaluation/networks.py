"""The networks an evaluation measures: the checkpoints loaded and cross-checked (pattern, resolution,
the scene and renderer the IMS was trained on) before anything is rendered."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from omegaconf import DictConfig

from imls_lightning.base.errors import InputError

from ..base.config import load_checkpoint
from ..inference.checkpoints import check_resolution, check_same_pattern, load_recnn, load_task, require_recnn
from ..inference.checkpoints import check_trained_on as checkpoint_trained_on
from .settings import Settings


@dataclass
class Networks:
    """What the checkpoints provide."""

    ims_task: Any
    recnn: torch.nn.Module
    iml: torch.nn.Module
    las_task: Any | None
    recnn_name: str
    recnn_source: str
    iml_source: str
    blue: torch.nn.Module | None = None
    recnn_sparser: Any | None = None  # RecNNTask: the same RecNN kind on a sparser pattern of its own


def load_networks(s: Settings, resolution: int) -> Networks:
    """Load and cross-check the checkpoints (pattern, resolution) before anything is rendered."""
    ims = load_task(s.ims, expect="IMSTask", what="checkpoints.ims")
    check_resolution(ims.hparams, resolution, key="checkpoints.ims", path=s.ims, network="IMS", against="this evaluation uses")
    fr = int(ims.hparams["fr_size"])
    same = dict(against="the IMS", hint="pass checkpoints of the IMS's pattern and data.resolution")
    if s.recnn:
        recnn, rh = load_recnn(s.recnn, what="checkpoints.recnn")  # the bare RecNN, no task built
        check_same_pattern(rh, ims.pattern, key="checkpoints.recnn", path=s.recnn, network="RecNN", **same)
        recnn_source, recnn_name = s.recnn, rh.get("recnn_name", "recnn")
    else:
        recnn = require_recnn(ims.recnn, key="checkpoints.ims", path=s.ims, recnn_key="checkpoints.recnn")
        recnn_source = f"{s.ims} ({ims.hparams.get('recnn_source') or 'stored'})"
        recnn_name = (ims.hparams.get("recnn_hparams") or {}).get("recnn_name", "recnn")
    if s.iml:
        it = load_task(s.iml, expect="IMLTask", what="checkpoints.iml")
        check_same_pattern(it.hparams, ims.pattern, key="checkpoints.iml", path=s.iml, network="IML", **same)
        iml, iml_source = it.iml, s.iml
    else:
        iml, iml_source = ims.iml, f"{s.ims} (the IML its labels came from)"
        if float(ims.hparams.get("decoder_lr", 0.0)) > 0:
            iml_source += ", its decoder fine-tuned on the IMS's masks (pass checkpoints.iml= for the IML's own)"
    las = None
    if s.las:
        las = load_task(s.las, expect="LASTask", what="checkpoints.las")
        check_resolution(las.hparams, fr, key="checkpoints.las", path=s.las, network="LAS", against="the IMS at",
                         hint="pass a LAS trained at the IMS's data.resolution")
    blue = None
    if s.blue_noise:
        bt = load_task(s.blue_noise, expect="IMLTask", what="checkpoints.blue_noise")
        check_same_pattern(bt.hparams, ims.pattern, key="checkpoints.blue_noise", path=s.blue_noise, network="IML", **same)
        if bt.hparams.get("importance") != "uniform":
            raise InputError(f"checkpoints.blue_noise={s.blue_noise}: an IML trained with model.importance={bt.hparams.get('importance', 'learned')}; expected model.importance=uniform")
        blue = bt.iml
    sparser = load_sparser_recnn(s.recnn_sparser, ims.pattern, str(recnn_name)) if s.recnn_sparser else None
    return Networks(ims, recnn, iml, las, str(recnn_name), str(recnn_source), str(iml_source), blue, sparser)


def load_sparser_recnn(path: str, pattern, recnn_name: str):
    """The RecNN alone on a sparser pattern (``checkpoints.recnn_sparser``): what a user would do instead
    of IML/S. Checked against the evaluation's RecNN: the same kind (``recnn_name``), the same FR-Image
    size, and a pattern with at most half of ``pattern``'s pixels (EnhanceNet 4x instead of 2x: a
    quarter); otherwise a one-line :class:`InputError`."""
    task = load_task(path, expect="RecNNTask", what="checkpoints.recnn_sparser")
    hint = "train the same RecNN on a sparser pattern (e.g. model=recnn pattern.factor=4, or pattern.c_size_ratio=0.3536)"
    kind = str(task.hparams.get("recnn_name", "recnn"))
    if kind != recnn_name:
        raise InputError(f"checkpoints.recnn_sparser={path}: a {kind} RecNN; the evaluation's RecNN is {recnn_name} ({hint})")
    sp = task.pattern
    if int(sp.fr_size) != int(pattern.fr_size):
        raise InputError(f"checkpoints.recnn_sparser={path}: trained at {sp.fr_size}^2, the evaluation at {pattern.fr_size}^2 ({hint})")
    if 2 * int(sp.count) > int(pattern.count):
        raise InputError(f"checkpoints.recnn_sparser={path}: its pattern has {sp.count} pixels, not at most half of the "
                         f"evaluation's {pattern.count} ({hint})")
    return task


def check_trained_on(cfg: DictConfig, s: Settings) -> None:
    """The scene and renderer of this evaluation must be those the IMS checkpoint was trained on
    (recorded in it); otherwise a one-line error, unless ``allow_mismatch=true``. (The sampling
    pattern and resolution are checked in :func:`load_networks`.) The check itself:
    :func:`imls_lightning.inference.checkpoints.check_trained_on`."""
    hp = load_checkpoint(s.ims, what="checkpoints.ims")["hyper_parameters"]
    if bool(cfg.get("allow_mismatch", False)):
        return
    checkpoint_trained_on(hp, cfg.scene, cfg.renderer, key="checkpoints.ims", path=s.ims, against="this evaluation",
                          escape="or allow_mismatch=true to evaluate it anyway")


def recnn_name(s: Settings) -> str:
    """The RecNN's config name (``enhancenet``, ``fovolnet``) from the checkpoints' hyper-parameters
    alone, as :func:`load_networks` finds it (no network is built)."""
    if s.recnn:
        return str(load_checkpoint(s.recnn, what="checkpoints.recnn")["hyper_parameters"].get("recnn_name", "recnn"))
    hp = load_checkpoint(s.ims, what="checkpoints.ims")["hyper_parameters"]
    return str((hp.get("recnn_hparams") or {}).get("recnn_name", "recnn"))
