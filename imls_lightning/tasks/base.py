"""Shared pieces of every LightningModule ("task") of the project.

A task owns one or more ``nn.Module`` networks (from ``imls_lightning.models``), its losses, its
metrics and its optimizer. Hyperparameters are saved as plain data, so that checkpoints load with
``torch.load(weights_only=True)`` through :func:`~imls_lightning.inference.checkpoints.load_task`.
"""
from __future__ import annotations

from typing import Any, Mapping

import lightning as L
import torch

# load_task lives in ..checkpoints; imported here too, where callers long found it
from ..inference.checkpoints import load_task  # noqa: F401
from ..core.metrics import psnr_per_image, ssim_metric  # psnr_per_image: public here too, by its old name


class ImlsTask(L.LightningModule):
    """Base class: checkpoint identity, construction from config, image-grid hook and metric helpers.

    A task is built in two ways. Training instantiates the ``model`` config node
    (:func:`imls_lightning.training.fit.build_task`): every model setting, its one default in
    ``conf/model/<name>.yaml``, plus :meth:`config_context`, what comes from outside that node.
    :func:`~imls_lightning.inference.checkpoints.load_task` builds it again from a checkpoint's saved hyperparameters. Constructors take
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
    def optional_state_prefixes(cls) -> tuple[str, ...]:
        """State-dict prefixes a checkpoint may lack (e.g. frozen pretrained backbones)."""
        return ()

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

