"""Shared pieces of every LightningModule ("task") of the project.

A task owns one or more ``nn.Module`` networks (from ``imls_lightning.models``), its losses, its
metrics and its optimizer. Hyperparameters are saved as plain data, so that checkpoints load with
``torch.load(weights_only=True)``: :meth:`ImlsTask.from_checkpoint` for a known class,
:func:`~imls_lightning.inference.checkpoints.load_task` for the class a checkpoint names.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import lightning as L
import torch

from imls_lightning.base.errors import InputError

from ..base.config import load_checkpoint
from ..core.metrics import psnr_per_image, ssim_metric  # psnr_per_image: public here too, by its old name


def checkpoint_task_name(ckpt: Mapping[str, Any], path: str | Path, *, expect: str | None = None,
                         what: str = "checkpoint") -> str:
    """The task class name a loaded checkpoint records (``imls_task``, see :meth:`ImlsTask.on_save_checkpoint`).

    Raises:
        InputError: it records none (not a checkpoint of this project), or another task than ``expect``.

    Example:
        >>> checkpoint_task_name({"imls_task": "IMLTask"}, "iml.ckpt", expect="RecNNTask", what="recnn.checkpoint")
        Traceback (most recent call last):
        ...
        imls_lightning.base.errors.InputError: recnn.checkpoint=iml.ckpt: is a IMLTask checkpoint, expected a RecNNTask checkpoint
    """
    name = ckpt.get("imls_task")
    if name is None:
        raise InputError(f"{what}={path}: not a checkpoint of this project (no task name)")
    if expect is not None and name != expect:
        raise InputError(f"{what}={path}: is a {name} checkpoint, expected a {expect} checkpoint")
    return name


class ImlsTask(L.LightningModule):
    """Base class: checkpoint identity, construction from config, image-grid hook and metric helpers.

    A task is built in two ways. Training instantiates the ``model`` config node
    (:func:`imls_lightning.training.fit.build_task`): every model setting, its one default in
    ``conf/model/<name>.yaml``, plus :meth:`config_context`, what comes from outside that node.
    :meth:`from_checkpoint` builds it again from a checkpoint's saved hyperparameters. Constructors take
    ``**_`` and ignore it, on purpose: the node's keys for the training run rather than the networks
    (``name``, ``patience``, ``monitor``, ...) and hyperparameters that older checkpoints saved pass
    both paths alike, with no list of them to keep in step (``tests/training/test_fit.py`` checks
    that every YAML key is an argument or such a run key, so a typo is not swallowed).
    """

    @classmethod
    def config_context(cls, cfg) -> dict[str, Any]:
        """Constructor arguments from outside the ``model`` node of the training config ``cfg``
        (the pattern, ``data.resolution``, input checkpoints, ...); none by default."""
        return {}

    def load_pretrained(self, pretrained: Mapping[str, Mapping[str, torch.Tensor]] | None) -> None:
        """Load trained weights into submodules, ``{"recnn": state dict, ...}``: the networks a task
        takes over from input checkpoints. Weights, not hyperparameters: the task's own checkpoints
        carry them from then on."""
        for name, state in (pretrained or {}).items():
            self.get_submodule(name).load_state_dict(state)

    @classmethod
    def inference_nets(cls, hparams: Mapping[str, Any]) -> dict[str, torch.nn.Module]:
        """The bare networks inference runs, by their state-dict prefix, built from a checkpoint's saved
        hyperparameters without building the task (no losses, no discriminator, no passengers):
        :func:`~imls_lightning.inference.checkpoints.load_nets` loads each prefix's weights into them.

        Raises:
            InputError: this task has no inference networks.
        """
        raise InputError(f"{cls.__name__}: no inference networks to load without the task; use load_task")

    @classmethod
    def optional_state_prefixes(cls) -> tuple[str, ...]:
        """State-dict prefixes a checkpoint may lack (e.g. frozen pretrained backbones)."""
        return ()

    @classmethod
    def from_checkpoint(cls, path: str | Path, *, what: str = "checkpoint", ckpt: Mapping[str, Any] | None = None):
        """This task rebuilt from its checkpoint (``weights_only=True``), in eval mode on the CPU,
        ``checkpoint_path`` set.

        Args:
            path: a ``.ckpt`` of this task, written by this project's training.
            what: the config key the path came from, for error messages.
            ckpt: the checkpoint of ``path`` when it is loaded already.

        Raises:
            InputError: the file is missing or damaged, is not a checkpoint of this class, or its
                weights do not fit the network it describes.
        """
        ckpt = load_checkpoint(path, what=what) if ckpt is None else ckpt
        checkpoint_task_name(ckpt, path, expect=cls.__name__, what=what)
        task = cls(**ckpt["hyper_parameters"])
        missing, unexpected = task.load_state_dict(ckpt["state_dict"], strict=False)
        if unexpected or [k for k in missing if not k.startswith(task.optional_state_prefixes())]:
            raise InputError(f"{what}={path}: weights do not fit the network it describes (missing {missing[:3]}, unexpected {unexpected[:3]})")
        task.eval()
        task.checkpoint_path = str(path)
        return task

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint["imls_task"] = type(self).__name__

    def log(self, name: str, value: Any, *args, **kwargs) -> None:
        """``LightningModule.log``; validation/test values default to ``sync_dist=True``: under DDP
        each process evaluates only its share of the views, and the monitors (early stopping, best
        checkpoint) must see the mean over all of them. No effect in a single process."""
        if not self.training and "sync_dist" not in kwargs:
            kwargs["sync_dist"] = True
        super().log(name, value, *args, **kwargs)

    # -- steps: one body per task (``_step``), run under each stage's prefix -------------------
    def _step(self, batch: dict[str, torch.Tensor], prefix: str) -> torch.Tensor:
        """Loss of one batch, logged under ``prefix`` (``train``, ``val``, ``test``); tasks with
        automatic optimization implement this, a task with its own steps (IMS) overrides those."""
        raise NotImplementedError(f"{type(self).__name__} defines no _step")

    def training_step(self, batch, batch_idx):
        return self._step(batch, "train")

    def validation_step(self, batch, batch_idx):
        return self._step(batch, "val")

    def test_step(self, batch, batch_idx):
        return self._step(batch, "test")

    def visuals(self, batch: dict[str, torch.Tensor]) -> tuple[list[str], list[torch.Tensor]]:
        """Column titles and ``(B, C, H, W)`` tensors for the image-grid callback."""
        return [], []

    def log_image_metrics(self, prefix: str, pred: torch.Tensor, target: torch.Tensor, **kw) -> torch.Tensor:
        """Log mean per-image PSNR and SSIM under ``prefix``; returns the per-image PSNR."""
        psnr = psnr_per_image(pred, target)
        bs = pred.shape[0]
        self.log(f"{prefix}_psnr", psnr.mean(), batch_size=bs, **kw)
        self.log(f"{prefix}_ssim", ssim_metric(pred, target), batch_size=bs, **kw)
        return psnr

