"""Training a reconstruction network (EnhanceNet or FoVolNet) on its sampling pattern."""
from __future__ import annotations

from typing import Any, Mapping

import torch
from hydra.utils import instantiate

from imls_lightning.base.errors import InputError

from ..core.compaction import decompact
from ..base.config import to_plain
from ..core.patterns import build_pattern
from .base import ImlsTask
from .losses import image_loss


def build_recnn(net: Mapping, pattern) -> torch.nn.Module:
    """Instantiate a RecNN ``nn.Module`` from its config (``_target_`` + arguments) and the pattern."""
    cfg = dict(to_plain(net))
    if "_target_" not in cfg:
        raise InputError("recnn.net: expected a config with a _target_ (e.g. imls_lightning.models.enhancenet.EnhanceNet)")
    # the pattern is passed at call time: as an instantiate() kwarg the SamplingPattern dataclass
    # would be converted into a config dict by _convert_="all"
    return instantiate(cfg, _partial_=True, _convert_="all")(pattern=pattern)


def reconstruction_loss(pred: torch.Tensor, target: torch.Tensor, kind: str, ssim_weight: float) -> torch.Tensor:
    """L1 or MSE, plus ``ssim_weight * (1 - SSIM)`` when asked: the project's image loss
    (:func:`~imls_lightning.tasks.losses.image_loss`, its differentiable SSIM the metric's to float64 precision), with
    the RecNN's key in the message."""
    if kind not in ("l1", "mse"):
        raise InputError(f"model.loss={kind!r}: expected 'l1' or 'mse'")
    return image_loss(pred, target, kind, float(ssim_weight))


class RecNNTask(ImlsTask):
    """LightningModule that trains a RecNN: C-Image -> FR-Image.

    Args:
        net: the ``recnn.net`` config (``_target_`` + hyperparameters of the ``nn.Module``).
        pattern: the ``pattern`` config node.
        fr_size: FR-Image side ``m`` (``data.resolution``).
        loss: ``"mse"`` or ``"l1"`` (l1 collapses EnhanceNet's residual to zero: see conf/model/recnn.yaml);
            ``ssim_weight`` adds ``w * (1 - SSIM)``.
        lr: Adam learning rate.
    """

    def __init__(
        self,
        net: Mapping,
        pattern: Mapping,
        fr_size: int,
        loss: str = "mse",
        ssim_weight: float = 0.0,
        lr: float = 1e-3,
        recnn_name: str = "recnn",
        **_: Any,  # run keys of the model node and stale hyperparameters: see ImlsTask
    ):
        super().__init__()
        if loss not in ("l1", "mse"):
            raise InputError(f"model.loss={loss!r}: expected 'l1' or 'mse'")
        if not lr > 0:
            raise InputError(f"model.lr={lr}: expected a positive number")
        self.save_hyperparameters({"net": to_plain(net), "pattern": to_plain(pattern), "fr_size": int(fr_size),
                                   "loss": loss, "ssim_weight": float(ssim_weight), "lr": float(lr),
                                   "recnn_name": recnn_name})
        self.pattern = build_pattern(to_plain(pattern), int(fr_size))
        self.net = build_recnn(net, self.pattern)

    @classmethod
    def config_context(cls, cfg) -> dict:
        """The network (``recnn.net``), its pattern and ``data.resolution``: the model node holds the rest."""
        return {"net": cfg.recnn.net, "pattern": cfg.pattern, "fr_size": cfg.data.resolution, "recnn_name": cfg.recnn.name}

    @classmethod
    def datamodule_kwargs(cls, cfg) -> dict:
        # fully convolutional: trains on random patch crops when data.crop is set (paper scale)
        return {"fields": ("view", "fr", "c"), "crop": cfg.data.get("crop")}

    @classmethod
    def inference_nets(cls, hparams: Mapping[str, Any]) -> dict[str, torch.nn.Module]:
        """``{"net": the RecNN}`` of these hyperparameters, built as the task builds it (no task)."""
        return {"net": build_recnn(hparams["net"], build_pattern(to_plain(hparams["pattern"]), int(hparams["fr_size"])))}

    def forward(self, c_image: torch.Tensor) -> torch.Tensor:
        return self.net(c_image)

    def _step(self, batch: dict[str, torch.Tensor], prefix: str) -> torch.Tensor:
        pred = self(batch["c"])
        target = batch["fr"]
        loss = reconstruction_loss(pred, target, self.hparams.loss, self.hparams.ssim_weight)
        bs = target.shape[0]
        on_step = prefix == "train"
        self.log(f"{prefix}/loss", loss, batch_size=bs, prog_bar=True, on_step=on_step, on_epoch=True)
        if prefix != "train":
            self.log_image_metrics(f"{prefix}/fr", pred, target)
        return loss

    def configure_optimizers(self):
        return torch.optim.Adam(self.parameters(), lr=self.hparams.lr)

    def visuals(self, batch):
        pred = self(batch["c"]).clamp(0, 1)
        pr = decompact(batch["c"], self.pattern.indices.to(batch["c"].device), self.pattern.fr_size)
        return ["C-Image", "PR-Image", "RecNN", "truth"], [batch["c"], pr, pred, batch["fr"]]
