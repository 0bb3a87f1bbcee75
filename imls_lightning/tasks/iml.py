"""Training the Importance Mask Learning network, standalone or end-to-end with a RecNN.

* ``mode=standalone``: compaction loss only, MSE(decoder(IM * C), C); the RecNN is not built.
* ``mode=end_to_end``: ``compaction_weight * compaction + image_weight * MSE(RecNN(decoder(.)), FR)``,
  starting from a trained RecNN checkpoint (``recnn.checkpoint=...``), frozen unless
  ``model.finetune_recnn=true``.

Training uses the soft rejection sampling (sigmoid; ``model.straight_through=true``: the hard mask
with the sigmoid's gradient); validation and test use the hard mask, as at inference, so the logged
IPR and PSNR (dB) are what a user will get. ``model.mean_range=[lo, hi]`` draws the mean value of
every training batch uniformly from that range, so one decoder serves every mean the ORP search
or a user picks at inference (validation stays at ``model.mean``).

Logged next to the loss: ``val/fr_psnr`` (dB, after the RecNN), ``val/c_psnr``, ``val/fill_c_psnr``
(the untrained pull-push fill of the same pixels, a foveal C-Image's at their FR positions: the decoder
must beat it), and what the encoder
learns: ``val/pim_contrast`` (mean PIM' on object pixels / on empty background, 1 = no preference),
``val/density_background`` and ``val/density_object`` (share of each sampled), and
``train/encoder_grad_norm``.
"""
from __future__ import annotations

from typing import Any, Mapping

import torch
import torch.nn.functional as F

from imls_lightning.base.errors import InputError, config_keys

from ..base.config import to_plain
from ..models.iml import IMLNet, build_decoder
from ..core.pull_push import fill_c_image
from ..core.patterns import build_pattern, plastic_rank_pattern
from ..core.metrics import psnr_per_image
from .checkpoint_checks import check_same_pattern
from .base import ImlsTask
from .recnn import RecNNTask

MODES = ("standalone", "end_to_end")
# a C-Image pixel counts as empty background when every channel is below this (8-bit: < 2/255)
BACKGROUND_LEVEL = 2.0 / 255.0


def background_mask(c_image: torch.Tensor) -> torch.Tensor:
    """``(B, 1, n, n)`` bool: pixels whose colour is (near) black, the empty background of the scene."""
    return c_image.amax(dim=1, keepdim=True) < BACKGROUND_LEVEL


def end_to_end_loss(c_rec: torch.Tensor, c: torch.Tensor, fr_pred: Optional[torch.Tensor] = None,
                    fr: Optional[torch.Tensor] = None, compaction_weight: float = 0.5,
                    image_weight: float = 0.5) -> tuple[torch.Tensor, torch.Tensor, Optional[torch.Tensor]]:
    """The IML's training loss: ``MSE(C', C)`` alone (standalone, no RecNN), or
    ``compaction_weight * MSE(C', C) + image_weight * MSE(RecNN(C'), FR)`` (end to end; paper 0.5 / 0.5).

    Returns ``(loss, compaction term, image term or None)``.

    Example:
        >>> c = torch.zeros(1, 3, 4, 4); fr = torch.zeros(1, 3, 8, 8)
        >>> round(end_to_end_loss(c + 0.1, c, fr + 0.3, fr)[0].item(), 6)   # 0.5 * 0.1**2 + 0.5 * 0.3**2
        0.05
    """
    comp = F.mse_loss(c_rec, c)
    if fr_pred is None:
        return comp, comp, None
    img = F.mse_loss(fr_pred, fr)
    return compaction_weight * comp + image_weight * img, comp, img


#: the :class:`IMLNet` arguments an ``IMLTask``'s hyperparameters hold, with the value a checkpoint written
#: before the hyperparameter existed was trained with (one place for these defaults)
IML_NET_DEFAULTS = {"mean": 0.1, "alpha": 50.0, "depth": 5, "base_channels": 32, "lower": 0.0, "delta": 1e-7,
                    "decoder": "plain", "importance": "learned", "straight_through": False}


def iml_net_kwargs(h: Mapping) -> dict[str, Any]:
    """The :class:`IMLNet` keyword arguments of an ``IMLTask`` with hyperparameters ``h`` (:data:`IML_NET_DEFAULTS`).

    Example:
        >>> iml_net_kwargs({"mean": 0.3})["mean"], iml_net_kwargs({})["decoder"]
        (0.3, 'plain')
    """
    return {k: h.get(k, default) for k, default in IML_NET_DEFAULTS.items()}


#: where the refine decoder's fill runs (``model.fill``): ``c``, in the C-Image's layout (every run trained before
#: the key existed); ``fr``, a foveal C-Image's samples at their FR positions (the same on a grid pattern)
FILLS = ("c", "fr")


def fill_pattern_of(h: Mapping, pattern):
    """The ``fill_pattern`` of an ``IMLTask``'s decoder with hyperparameters ``h``: ``pattern`` when it fills at
    the FR positions (``fill: fr``), else ``None`` (checkpoints written before ``fill`` existed)."""
    return pattern if h.get("fill", "c") == "fr" else None


def iml_net_from_hparams(h: Mapping, pattern) -> IMLNet:
    """The :class:`IMLNet` of an ``IMLTask`` with hyperparameters ``h`` (:func:`iml_net_kwargs`)."""
    n = pattern.c_size
    return IMLNet(n, plastic_rank_pattern(n), valid=pattern.valid, fill_pattern=fill_pattern_of(h, pattern),
                  **iml_net_kwargs(h))


def iml_decoder_from_hparams(h: Mapping, pattern) -> torch.nn.Module:
    """The decoder alone of :func:`iml_net_from_hparams` (the same module as its ``.decoder``; no encoder)."""
    kw = iml_net_kwargs(h)
    return build_decoder(kw["decoder"], kw["depth"], kw["base_channels"], fill_pattern=fill_pattern_of(h, pattern))


def check_mean_range(value, key: str = "model.mean_range") -> list[float] | None:
    """``None``, or ``[lo, hi]`` as floats with ``0.01 <= lo <= hi <= 1``: a range of mean values u.

    Example:
        >>> check_mean_range((0.1, 0.6))
        [0.1, 0.6]
    """
    if value is None:
        return None
    try:
        lo, hi = (float(x) for x in value)
    except (TypeError, ValueError):
        raise InputError(f"{key}={value}: expected null or [lo, hi] with 0.01 <= lo <= hi <= 1") from None
    if not (0.01 <= lo <= hi <= 1.0):
        raise InputError(f"{key}={value}: expected null or [lo, hi] with 0.01 <= lo <= hi <= 1")
    return [lo, hi]


class IMLTask(ImlsTask):
    """LightningModule for the IML network (and, end-to-end, the RecNN behind it).

    Args:
        pattern: the ``pattern`` config node; ``fr_size``: FR-Image side.
        mode: ``"standalone"`` or ``"end_to_end"``.
        mean, alpha, lower, delta: normalization target u, sigmoid steepness, l and delta.
        depth, base_channels: U-Net size of encoder and decoder.
        decoder: ``"refine"`` (fill + learned correction) or ``"plain"`` (the paper's U-Net).
        importance: ``"learned"`` or ``"uniform"`` (the blue-noise mask baseline, decoder only).
        straight_through: train on hard masks with the soft mask's gradient.
        mean_range: ``None`` or ``[lo, hi]``: a random mean value per training batch.
        fill: where the refine decoder's fill runs, ``"c"`` or ``"fr"`` (:data:`FILLS`; the config default: :func:`imls_lightning.base.config.decoder_fill_for`).
        recnn_hparams: hyperparameters of the RecNN task (end-to-end only; taken from its checkpoint).
        finetune_recnn: train the RecNN's weights too.
        pretrained: ``{"recnn": state dict}``: the trained RecNN's weights (not a hyperparameter).
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
        decoder: str = "plain",
        importance: str = "learned",
        straight_through: bool = False,
        mean_range: Any = None,
        fill: str = "c",
        pretrained: Mapping[str, Mapping[str, torch.Tensor]] | None = None,
        **_: Any,  # run keys of the model node and stale hyperparameters: see ImlsTask
    ):
        super().__init__()
        if mode not in MODES:
            raise InputError(f"model.mode={mode!r}: expected one of {list(MODES)}")
        if not lr > 0:
            raise InputError(f"model.lr={lr}: expected a positive number")
        if fill not in FILLS:
            raise InputError(f"model.fill={fill!r}: expected one of {list(FILLS)} (where the decoder's fill runs)")
        if mode == "end_to_end" and not recnn_hparams:
            raise InputError("model.mode=end_to_end needs a trained RecNN: set recnn.checkpoint=<path to a RecNN .ckpt>")
        self.save_hyperparameters({
            "pattern": to_plain(pattern), "fr_size": int(fr_size), "mode": mode, "mean": float(mean),
            "alpha": float(alpha), "lower": float(lower), "delta": float(delta), "depth": int(depth),
            "base_channels": int(base_channels), "compaction_weight": float(compaction_weight),
            "image_weight": float(image_weight), "finetune_recnn": bool(finetune_recnn), "lr": float(lr),
            "recnn_hparams": to_plain(recnn_hparams) if recnn_hparams else None, "recnn_name": recnn_name,
            "decoder": str(decoder), "importance": str(importance), "straight_through": bool(straight_through),
            "mean_range": check_mean_range(to_plain(mean_range)), "fill": str(fill),
        })
        self.pattern = build_pattern(to_plain(pattern), int(fr_size))
        # errors name the user's keys (model.depth=, model.alpha=, ...)
        with config_keys({k: f"model.{k}" for k in ("mean", "alpha", "depth", "base_channels", "lower", "delta",
                                                    "decoder", "importance")}):
            self.iml = iml_net_from_hparams(self.hparams, self.pattern)
        self._rng = torch.Generator().manual_seed(0)
        self.recnn = None
        if mode == "end_to_end":
            rh = dict(recnn_hparams)
            check_same_pattern(rh, self.pattern, key="recnn.checkpoint", network="RecNN",
                               hint="train the IML with the same pattern/data.resolution")
            self.recnn = RecNNTask(**rh).net
            if not finetune_recnn:
                self.recnn.requires_grad_(False)
        self.load_pretrained(pretrained)

    # -- construction from the training config ------------------------------------------------
    @classmethod
    def config_context(cls, cfg) -> dict:
        """The pattern, ``data.resolution`` and, end to end, the RecNN of ``recnn.checkpoint`` (its
        hyperparameters and weights). Without that checkpoint the constructor names the missing key."""
        context = {"pattern": cfg.pattern, "fr_size": cfg.data.resolution, "recnn_name": cfg.recnn.name}
        if cfg.model.mode == "end_to_end" and cfg.recnn.get("checkpoint"):
            rt = RecNNTask.from_checkpoint(cfg.recnn.checkpoint, what="recnn.checkpoint")
            context.update(recnn_hparams=dict(rt.hparams), pretrained={"recnn": rt.net.state_dict()})
        return context

    @classmethod
    def datamodule_kwargs(cls, cfg) -> dict:
        # fully convolutional: trains on random patch crops when data.crop is set (paper scale)
        return {"fields": ("view", "fr", "c"), "crop": cfg.data.get("crop")}

    # -- steps --------------------------------------------------------------------------------
    def train(self, mode: bool = True):
        super().train(mode)
        if self.recnn is not None and not self.hparams.finetune_recnn:
            self.recnn.eval()  # frozen: keep its normalization statistics fixed
        return self

    def _step(self, batch: dict[str, torch.Tensor], prefix: str) -> torch.Tensor:
        c = batch["c"]
        hard = prefix != "train"
        rng = self.hparams.mean_range
        mean = None  # the trained mean; a training step with mean_range draws one, passed to this call only
        if prefix == "train" and rng is not None:
            mean = float(rng[0] + (rng[1] - rng[0]) * torch.rand((), generator=self._rng))
        out = self.iml(c, hard=hard, mean=mean)
        bs = c.shape[0]
        on_step = prefix == "train"
        fr_pred = self.recnn(out.c_recon) if self.recnn is not None else None
        loss, comp, img = end_to_end_loss(out.c_recon, c, fr_pred, batch.get("fr"), self.hparams.compaction_weight,
                                    self.hparams.image_weight)
        if fr_pred is not None:
            self.log(f"{prefix}/image_loss", img, batch_size=bs, on_step=False, on_epoch=True)
            if prefix != "train":
                self.log_image_metrics(f"{prefix}/fr", fr_pred, batch["fr"], prog_bar=True)
        with torch.no_grad():
            hard_im = out.im.detach() if hard else self.iml.sample(out.pim_norm.detach(), hard=True)
            # a training crop (data.crop) holds only pattern pixels: its share is over its own pixels
            whole = tuple(hard_im.shape[-2:]) == (self.pattern.c_size, self.pattern.c_size)
            share = hard_im.flatten(1).sum(1) / float(self.pattern.count if whole else hard_im[0, 0].numel())
            ipr = share * self.pattern.sampling_ratio
        self.log(f"{prefix}/loss", loss, batch_size=bs, prog_bar=True, on_step=on_step, on_epoch=True)
        self.log(f"{prefix}/compaction_loss", comp, batch_size=bs, on_step=False, on_epoch=True)
        self.log(f"{prefix}/ipr", ipr.mean(), batch_size=bs, prog_bar=True, on_step=False, on_epoch=True)
        self.log(f"{prefix}/c_share", share.mean(), batch_size=bs, on_step=False, on_epoch=True)
        if prefix != "train":
            with torch.no_grad():
                self.log(f"{prefix}/c_psnr", psnr_per_image(out.c_recon, c).mean(), batch_size=bs)
                fill = fill_c_image(c, hard_im, self.pattern)  # a foveal C-Image is filled at its FR positions
                self.log(f"{prefix}/fill_c_psnr", psnr_per_image(fill, c).mean(), batch_size=bs)
                if self.recnn is not None:
                    self.log(f"{prefix}/fill_fr_psnr", psnr_per_image(self.recnn(fill), batch["fr"]).mean(), batch_size=bs)
                self._log_importance_stats(prefix, c, out.pim_norm, hard_im, bs)
        return loss

    def _log_importance_stats(self, prefix: str, c: torch.Tensor, pim_norm: torch.Tensor, im: torch.Tensor, bs: int) -> None:
        """What the encoder learned: PIM' and sampling density on empty background vs on the object."""
        valid = self.iml.valid.bool().expand_as(im)
        bg = background_mask(c) & valid
        obj = ~background_mask(c) & valid
        nb, no = bg.sum().clamp_min(1).float(), obj.sum().clamp_min(1).float()
        pim_bg, pim_obj = (pim_norm * bg).sum() / nb, (pim_norm * obj).sum() / no
        self.log(f"{prefix}/pim_contrast", pim_obj / pim_bg.clamp_min(1e-6), batch_size=bs)
        self.log(f"{prefix}/density_background", (im * bg).sum() / nb, batch_size=bs)
        self.log(f"{prefix}/density_object", (im * obj).sum() / no, batch_size=bs)

    def on_before_optimizer_step(self, optimizer) -> None:
        enc = self.iml.encoder
        if enc is None:
            return
        norms = [p.grad.detach().norm() for p in enc.parameters() if p.grad is not None]
        if norms:
            self.log("train/encoder_grad_norm", torch.stack(norms).norm(), on_step=True, on_epoch=False)

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
