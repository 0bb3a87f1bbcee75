"""Training the Importance Mask Learning network, standalone or end-to-end with a RecNN.

* ``mode=standalone``: compaction loss only, MSE(decoder(IM * C), C); the RecNN is not built.
* ``mode=end_to_end``: ``compaction_weight * compaction + image_weight * MSE(RecNN(decoder(.)), FR)``,
  starting from a trained RecNN checkpoint (``recnn.checkpoint=...``), frozen unless
  ``model.finetune_recnn=true``.

Training uses the soft rejection sampling (sigmoid); validation and test use the hard mask, as at
inference, so the logged IPR and PSNR are what a user will get.
"""
from __future__ import annotations

from typing import Any, Mapping

import torch
import torch.nn.functional as F

from data_gen.errors import InputError, config_keys

from ..config import to_plain
from ..models.iml import IMLNet
from ..patterns import build_pattern, plastic_rank_pattern
from .base import ImlsTask, load_task, psnr_per_image
from .recnn import RecNNTask

MODES = ("standalone", "end_to_end")


class IMLTask(ImlsTask):
    """LightningModule for the IML network (and, end-to-end, the RecNN behind it).

    Args:
        pattern: the ``pattern`` config node; ``fr_size``: FR-Image side.
        mode: ``"standalone"`` or ``"end_to_end"``.
        mean, alpha, lower, delta: normalization target u, sigmoid steepness, l and delta.
        depth, base_channels: U-Net size of encoder and decoder.
        recnn_hparams: hyperparameters of the RecNN task (end-to-end only; taken from its checkpoint).
        finetune_recnn: train the RecNN's weights too.
    """

    def __init__(
        self,
        pattern: Mapping,
        fr_size: int,
        mode: str = "standalone",
        mean: float = 0.1,
        alpha: float = 50.0,
        lower: float = 0.0,
        delta: float = 1e-7,
        depth: int = 5,
        base_channels: int = 32,
        compaction_weight: float = 0.5,
        image_weight: float = 0.5,
        finetune_recnn: bool = False,
        lr: float = 1e-3,
        recnn_hparams: Mapping | None = None,
        recnn_name: str = "recnn",
        **_: Any,
    ):
        super().__init__()
        if mode not in MODES:
            raise InputError(f"model.mode={mode!r}: expected one of {list(MODES)}")
        if not lr > 0:
            raise InputError(f"model.lr={lr}: expected a positive number")
        if mode == "end_to_end" and not recnn_hparams:
            raise InputError("model.mode=end_to_end needs a trained RecNN: set recnn.checkpoint=<path to a RecNN .ckpt>")
        self.save_hyperparameters({
            "pattern": to_plain(pattern), "fr_size": int(fr_size), "mode": mode, "mean": float(mean),
            "alpha": float(alpha), "lower": float(lower), "delta": float(delta), "depth": int(depth),
            "base_channels": int(base_channels), "compaction_weight": float(compaction_weight),
            "image_weight": float(image_weight), "finetune_recnn": bool(finetune_recnn), "lr": float(lr),
            "recnn_hparams": to_plain(recnn_hparams) if recnn_hparams else None, "recnn_name": recnn_name,
        })
        self.pattern = build_pattern(to_plain(pattern), int(fr_size))
        n = self.pattern.c_size
        # errors name the user's keys (model.depth=, model.alpha=, ...)
        with config_keys({k: f"model.{k}" for k in ("mean", "alpha", "depth", "base_channels", "lower", "delta")}):
            self.iml = IMLNet(
                n, plastic_rank_pattern(n), mean=mean, alpha=alpha, depth=depth, base_channels=base_channels,
                lower=lower, delta=delta, valid=self.pattern.valid,
            )
        self.recnn = None
        if mode == "end_to_end":
            rh = dict(recnn_hparams)
            if int(rh.get("fr_size", -1)) != int(fr_size) or build_pattern(rh["pattern"], int(fr_size)).fingerprint() != self.pattern.fingerprint():
                raise InputError(
                    "recnn.checkpoint: the RecNN was trained on another sampling pattern or resolution "
                    f"(its fr_size={rh.get('fr_size')}, pattern={rh.get('pattern')}); train the IML with the same pattern/data.resolution"
                )
            self.recnn = RecNNTask(**rh).net
            if not finetune_recnn:
                self.recnn.requires_grad_(False)

    # -- construction from the training config ------------------------------------------------
    @classmethod
    def from_config(cls, cfg) -> "IMLTask":
        m = cfg.model
        recnn_task = None
        if m.mode == "end_to_end":
            if not cfg.recnn.get("checkpoint"):
                raise InputError("model.mode=end_to_end needs a trained RecNN: set recnn.checkpoint=<path to a RecNN .ckpt>")
            recnn_task = load_task(cfg.recnn.checkpoint, expect="RecNNTask", what="recnn.checkpoint")
        task = cls(
            pattern=cfg.pattern, fr_size=cfg.data.resolution, mode=m.mode, mean=m.mean, alpha=m.alpha,
            lower=m.lower, delta=m.delta, depth=m.depth, base_channels=m.base_channels,
            compaction_weight=m.compaction_weight, image_weight=m.image_weight,
            finetune_recnn=m.finetune_recnn, lr=m.lr,
            recnn_hparams=dict(recnn_task.hparams) if recnn_task is not None else None,
            recnn_name=cfg.recnn.name,
        )
        if recnn_task is not None:
            task.recnn.load_state_dict(recnn_task.net.state_dict())
        return task

    @classmethod
    def datamodule_kwargs(cls, cfg) -> dict:
        return {"fields": ("view", "fr", "c")}

    # -- steps --------------------------------------------------------------------------------
    def train(self, mode: bool = True):
        super().train(mode)
        if self.recnn is not None and not self.hparams.finetune_recnn:
            self.recnn.eval()  # frozen: keep its normalization statistics fixed
        return self

    def _step(self, batch: dict[str, torch.Tensor], prefix: str) -> torch.Tensor:
        c = batch["c"]
        hard = prefix != "train"
        out = self.iml(c, hard=hard)
        comp = F.mse_loss(out.c_recon, c)
        loss = comp
        bs = c.shape[0]
        on_step = prefix == "train"
        if self.recnn is not None:
            fr_pred = self.recnn(out.c_recon)
            img = F.mse_loss(fr_pred, batch["fr"])
            loss = self.hparams.compaction_weight * comp + self.hparams.image_weight * img
            self.log(f"{prefix}/image_loss", img, batch_size=bs, on_step=False, on_epoch=True)
            if prefix != "train":
                self.log_image_metrics(f"{prefix}/fr", fr_pred, batch["fr"])
        with torch.no_grad():
            hard_im = out.im if hard else self.iml.sample(out.pim_norm, hard=True)
            ipr = hard_im.flatten(1).sum(1) / float(self.pattern.fr_size**2)
            share = hard_im.flatten(1).sum(1) / float(self.pattern.count)
        self.log(f"{prefix}/loss", loss, batch_size=bs, prog_bar=True, on_step=on_step, on_epoch=True)
        self.log(f"{prefix}/compaction_loss", comp, batch_size=bs, on_step=False, on_epoch=True)
        self.log(f"{prefix}/ipr", ipr.mean(), batch_size=bs, prog_bar=True, on_step=False, on_epoch=True)
        self.log(f"{prefix}/c_share", share.mean(), batch_size=bs, on_step=False, on_epoch=True)
        if prefix != "train":
            self.log(f"{prefix}/c_psnr", psnr_per_image(out.c_recon, c).mean(), batch_size=bs)
        return loss

    def training_step(self, batch, batch_idx):
        return self._step(batch, "train")

    def validation_step(self, batch, batch_idx):
        self._step(batch, "val")

    def test_step(self, batch, batch_idx):
        self._step(batch, "test")

    def configure_optimizers(self):
        params = [p for p in self.parameters() if p.requires_grad]
        return torch.optim.Adam(params, lr=self.hparams.lr)

    def visuals(self, batch):
        out = self.iml(batch["c"], hard=True)
        titles = ["C-Image", "IM", "PR-C-Image", "decoder"]
        tensors = [batch["c"], out.im, out.pr_c_image, out.c_recon.clamp(0, 1)]
        if self.recnn is not None:
            titles += ["RecNN", "truth"]
            tensors += [self.recnn(out.c_recon).clamp(0, 1), batch["fr"]]
        return titles, tensors
