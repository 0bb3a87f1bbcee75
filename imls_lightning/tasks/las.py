"""Training the LAS baseline (Weiss et al., TVCG 2020) on the project's cache.

End to end, as LAS trains: the real low-resolution render of the view (the batch's ``low``, the same
image inference renders) -> importance net -> normalization to the mean ``u`` -> *soft* rejection
sampling against the plastic pattern at full resolution -> ``mask * FR`` -> pull-push inpainting ->
reconstruction net; loss = L1 (+ MSE) + the heatmap prior (:func:`~imls_lightning.models.las.las_loss`).
Validation and test use the *hard* mask, as at inference, so the logged IPR, PSNR and SSIM are what
a user gets. The networks and every formula live in :mod:`imls_lightning.models.las` (``docs/LAS.md``).

Logged under ``{prefix}`` = ``train`` | ``val`` | ``test``: ``loss``, ``l1``, ``heatmap``, ``ipr``
(share of FR pixels the *hard* mask ray-casts, also in training), and for val/test ``fr_psnr``,
``fr_ssim`` of the clamped reconstruction. Checkpoints are monitored on ``val/loss``.
"""
from __future__ import annotations

import math
from typing import Any

import torch
import torch.nn.functional as F

from imls_lightning.base.errors import InputError
from imls_lightning.base.validate import check_integer, check_number

from ..core.importance import check_alpha, check_mean, hard_rejection_sample
from ..models.las import LASNet, LASOutput, las_loss
from .base import ImlsTask

__all__ = ["LASTask"]

RECON_ARCHS = ("enhancenet", "unet")


def check_low_res(low_res: Any, fr_size: int) -> int:
    """``model.low_res`` must divide ``data.resolution`` (the importance net upsamples by an integer).

    Example:
        >>> check_low_res(16, 64)
        16
    """
    h = check_integer(low_res, "model.low_res", 1)
    if h > fr_size or fr_size % h:
        raise InputError(
            f"model.low_res={low_res}: expected a divisor of data.resolution={fr_size} that is <= it "
            f"(e.g. {fr_size // 8 if fr_size % 8 == 0 else fr_size}; the paper renders 64 for 512)"
        )
    return h


class LASTask(ImlsTask):
    """LightningModule for the LAS baseline: low-res render -> importance -> sampling -> reconstruction.

    Batches are dicts with ``fr`` ``(B, 3, m, m)`` (the FR-Image, ground truth and the source of the
    samples) and ``low`` ``(B, 3, h, h)`` (a real render of the same view at ``h = low_res``), both
    float in [0, 1]: what ``ImlsDataModule(fields=("view", "fr"), low_res=h)`` yields.

    Args:
        fr_size: FR-Image side ``m`` (``data.resolution``).
        low_res: side ``h`` of the low-res render; a divisor of ``m`` (paper: 64 for 512).
        mean, lower, delta: normalization ``min(l + I (u - l) / (mean(I) + delta), 1)``.
        alpha: steepness of the soft sampling sigmoid in training (LAS 50).
        importance_channels, importance_blocks, importance_border, post_upscale: importance net
            (paper scale: 64 channels, 5 residual blocks, border 8).
        recon_arch, recon_channels, recon_blocks, unet_depth, unet_channels, inpaint, residual:
            reconstruction net (paper scale: EnhanceNet, 64 channels, 10 residual blocks).
        pattern_augment: random flip/rot90 of the plastic pattern per sample in training.
        l1_weight, mse_weight, heatmap_weight, heatmap_center, border: :func:`las_loss`.
        lr: Adam learning rate (one optimizer over both nets, as LAS).

    The trained :class:`~imls_lightning.models.las.LASNet` is :attr:`net`; inference calls
    ``task.net.importance_mask(low, mean=None, ipr=None)`` and ``task.net.reconstruct(samples, mask)``.

    Example:
        >>> task = LASTask(fr_size=32, low_res=8, importance_channels=4, importance_blocks=1,
        ...                importance_border=2, recon_channels=4, recon_blocks=1)
        >>> fr = torch.rand(2, 3, 32, 32)
        >>> batch = {"fr": fr, "low": F.interpolate(fr, size=8, mode="area")}
        >>> task.eval().predict(batch)[0].shape
        torch.Size([2, 3, 32, 32])
    """

    def __init__(
        self,
        fr_size: int,
        low_res: int = 64,
        mean: float = 0.2,
        lower: float = 0.002,
        delta: float = 1e-7,
        alpha: float = 50.0,
        importance_channels: int = 64,
        importance_blocks: int = 5,
        importance_border: int = 8,
        post_upscale: int = 1,
        recon_arch: str = "enhancenet",
        recon_channels: int = 64,
        recon_blocks: int = 10,
        unet_depth: int = 6,
        unet_channels: int = 64,
        inpaint: bool = True,
        residual: bool = True,
        pattern_augment: bool = True,
        l1_weight: float = 1.0,
        mse_weight: float = 0.0,
        heatmap_weight: float = 0.1,
        heatmap_center: float = 0.5,
        border: int = 0,
        lr: float = 1e-3,
        **_: Any,  # run keys of the model node and stale hyperparameters: see ImlsTask
    ):
        super().__init__()
        m = check_integer(fr_size, "data.resolution", 1)
        h = check_low_res(low_res, m)
        post = check_integer(post_upscale, "model.post_upscale", 1)
        if (m // h) % post:
            raise InputError(f"model.post_upscale={post_upscale}: expected a divisor of data.resolution / model.low_res = {m // h}")
        u = check_mean(mean, "model.mean")
        lo = check_number(lower, "model.lower", 0)
        if not lo < u:
            raise InputError(f"model.lower={lower}: expected 0 <= lower < model.mean ({u})")
        d = float(delta)
        if not (d > 0 and math.isfinite(d)):
            raise InputError(f"model.delta={delta}: expected a small positive number (default 1e-7)")
        a = check_alpha(alpha, "model.alpha")
        if recon_arch not in RECON_ARCHS:
            raise InputError(f"model.recon_arch={recon_arch!r}: expected one of {list(RECON_ARCHS)}")
        sizes = {
            "importance_channels": check_integer(importance_channels, "model.importance_channels", 1),
            "importance_blocks": check_integer(importance_blocks, "model.importance_blocks", 0),
            "importance_border": check_integer(importance_border, "model.importance_border", 0),
            "recon_channels": check_integer(recon_channels, "model.recon_channels", 1),
            "recon_blocks": check_integer(recon_blocks, "model.recon_blocks", 0),
            "unet_depth": check_integer(unet_depth, "model.unet_depth", 1),
            "unet_channels": check_integer(unet_channels, "model.unet_channels", 1),
        }
        weights = {k: check_number(v, f"model.{k}", 0) for k, v in
                   (("l1_weight", l1_weight), ("mse_weight", mse_weight), ("heatmap_weight", heatmap_weight))}
        if weights["l1_weight"] + weights["mse_weight"] == 0:
            raise InputError("model.l1_weight=0 and model.mse_weight=0: expected at least one image loss weight > 0")
        hc = float(heatmap_center)
        if not math.isfinite(hc):
            raise InputError(f"model.heatmap_center={heatmap_center}: expected a finite number")
        b = check_integer(border, "model.border", 0)
        if 2 * b >= m:
            raise InputError(f"model.border={border}: expected fewer than data.resolution / 2 = {m // 2} pixels")
        lr_ = float(lr)
        if not (lr_ > 0 and math.isfinite(lr_)):
            raise InputError(f"model.lr={lr}: expected a positive number")

        self.save_hyperparameters({
            "fr_size": m, "low_res": h, "mean": u, "lower": lo, "delta": d, "alpha": a, **sizes,
            "post_upscale": post, "recon_arch": str(recon_arch), "inpaint": bool(inpaint),
            "residual": bool(residual), "pattern_augment": bool(pattern_augment), **weights,
            "heatmap_center": hc, "border": b, "lr": lr_,
        })
        self.net = LASNet(
            low_res=h, fr_size=m, mean=u, lower=lo, delta=d, alpha=a, post_upscale=post,
            recon_arch=str(recon_arch), inpaint=bool(inpaint), residual=bool(residual),
            pattern_augment=bool(pattern_augment), **sizes,
        )

    # -- construction from the training config ------------------------------------------------
    @classmethod
    def config_context(cls, cfg) -> dict:
        """``fr_size``: the cache's ``data.resolution``, never a model setting; the model node holds the rest."""
        return {"fr_size": cfg.data.resolution}

    @classmethod
    def datamodule_kwargs(cls, cfg) -> dict:
        # `low`: a real render at model.low_res of every cached view (not a downsampled FR-Image),
        # the same input the inference pipeline renders
        return {"fields": ("view", "fr"), "low_res": int(cfg.model.low_res)}

    # -- forward ------------------------------------------------------------------------------
    def _inputs(self, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        if "low" not in batch or "fr" not in batch:
            raise InputError(
                f"LAS batch has keys {sorted(batch)}: expected 'fr' and 'low' (ImlsDataModule(low_res=model.low_res))"
            )
        return batch["low"], batch["fr"]

    def run(self, batch: dict[str, torch.Tensor], hard: bool | None = None) -> LASOutput:
        """The whole pipeline with every intermediate; ``hard=None``: soft in training, hard in eval."""
        low, fr = self._inputs(batch)
        return self.net.run(low, fr, hard=hard)

    def forward(self, low_res: torch.Tensor, fr_image: torch.Tensor, hard: bool | None = None):
        """``(fr_pred (B,3,m,m), mask (B,1,m,m), importance (B,1,m,m))``, see :meth:`LASNet.forward`."""
        return self.net(low_res, fr_image, hard)

    @torch.no_grad()
    def predict(self, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """Inference on a batch: ``(reconstruction (B,3,m,m) in [0,1], bool mask (B,m,m))`` from the
        hard mask and the FR pixels under it (what selective rendering would produce)."""
        low, fr = self._inputs(batch)
        mask = self.net.importance_mask(low)
        return self.net.reconstruct(fr, mask), mask

    # -- steps --------------------------------------------------------------------------------
    def _step(self, batch: dict[str, torch.Tensor], prefix: str) -> torch.Tensor:
        hard = prefix != "train"
        out = self.run(batch, hard=hard)
        fr = batch["fr"]
        hp = self.hparams
        loss, terms = las_loss(out, fr, l1_weight=hp.l1_weight, mse_weight=hp.mse_weight,
                               heatmap_weight=hp.heatmap_weight, heatmap_center=hp.heatmap_center,
                               border=hp.border)
        bs = fr.shape[0]
        on_step = prefix == "train"
        with torch.no_grad():
            # the IPR inference would get from this importance map (training samples softly)
            hard_mask = out.mask if hard else hard_rejection_sample(out.importance, self.net.P)
            ipr = hard_mask.float().flatten(1).mean(1)
        self.log(f"{prefix}/loss", loss, batch_size=bs, prog_bar=True, on_step=on_step, on_epoch=True)
        self.log(f"{prefix}/l1", terms["l1"], batch_size=bs, on_step=False, on_epoch=True)
        self.log(f"{prefix}/heatmap", terms["heatmap"], batch_size=bs, on_step=False, on_epoch=True)
        self.log(f"{prefix}/ipr", ipr.mean(), batch_size=bs, prog_bar=True, on_step=False, on_epoch=True)
        if hard:
            self.log_image_metrics(f"{prefix}/fr", out.fr_pred, fr)
        return loss

    def configure_optimizers(self):
        return torch.optim.Adam(self.parameters(), lr=self.hparams.lr)

    def visuals(self, batch):
        out = self.run(batch, hard=True)
        low, fr = self._inputs(batch)
        return (
            ["low-res", "importance", "mask", "samples", "LAS", "truth"],
            [low, out.importance.clamp(0, 1), out.mask, out.mask * fr, out.fr_pred.clamp(0, 1), fr],
        )
