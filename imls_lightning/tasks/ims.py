"""Training the Importance Mask Synthesis network (paper, "Importance Mask Synthesis Network").

The IMS generator maps the 9 view floats to the ``n x n`` importance mask; it is trained by
supervised learning on the labels of a trained IML encoder (:mod:`imls_lightning.data.labels`) as a GAN:
generator losses BCE / MSE / perceptual (each selectable and weightable) plus the non-saturating
adversarial loss; the discriminator is trained with the cross-entropy loss. Paper default:
perceptual 1 + adversarial 0.01, Adam lr 1e-3.

Targets (``target``):

* ``"im"`` (paper): the dithered binary IM, ``{0, 1} -> {-1, 1}``; at inference ``IM = g > 0``.
* ``"pim"`` (beyond the paper): the continuous PIM' behind the IM, ``2 clamp(PIM', 0, 1) - 1``
  (-1 on C-Image padding); at inference it is dithered exactly as the IML does, against the same
  fixed plastic pattern ``P``: ``IM = (g + 1) / 2 > P``. Clamping at 1 loses nothing: ``P <= 1``
  (``g = 1``, the target of every ``PIM' >= 1``, counts as important also on the one pixel where
  ``P = 1``).

Either way the IM is boolean, 0 on the C-Image padding. The thresholding is
:class:`~imls_lightning.models.ims.IMSMaskHead`'s (its one home): :attr:`IMSTask.mask_head` is the
generator with it, and :meth:`IMSTask.predict_im` calls it.

Optimization. Lightning manual optimization, one Adam per network, lr 1e-3 (paper), betas
``(0.5, 0.999)`` by default: DCGAN's choice (Radford et al. 2015) - the default ``beta1 = 0.9``
makes the two-player updates oscillate; the paper gives only the learning rate. Per batch: one
generator forward; a discriminator step on ``(real labels, generated.detach())`` (skipped when the
adversarial weight is 0); then a generator step on the weighted image losses +
``adversarial * -log D(G(view))`` through the just-updated discriminator (the PyTorch DCGAN order).

Frozen passengers. The IML network (encoder + decoder) and the RecNN that the final image metric
needs are built from plain hyperparameters (``iml_hparams``, ``recnn_hparams``) and their weights
are stored in the IMS checkpoint, frozen (``requires_grad=False``, always in eval mode, in no
optimizer), so that an IMS checkpoint alone builds the IML/S renderer: view -> IMS IM -> selective
rendering of those C-Image pixels -> IML decoder -> RecNN. The RecNN comes from the IML checkpoint
when the IML was trained end-to-end, otherwise from ``recnn.checkpoint`` (the off-the-shelf case);
without either the FR metrics are skipped with a one-time warning.

Decoder fine-tuning (beyond the paper, ``model.decoder_lr > 0``; needs ``target=pim``). The IML
decoder was trained on the IML's own masks, which the IMS only approximates from the view. With
``decoder_lr > 0`` the decoder (not the encoder, not the RecNN) is trained further, beside the
generator, on the hard masks the generator makes at a random mean value per view (drawn from
``decoder_mean_range``, else the IML's ``mean_range``, else its mean), with the IML's end-to-end loss
``compaction_weight * MSE(C', C) + image_weight * MSE(RecNN(C'), FR)`` (``MSE(C', C)`` alone without a
RecNN). The product path then runs the decoder that was trained for the masks it will get; the
fine-tuned weights are stored in the IMS checkpoint. ``decoder_lr = 0`` (default) keeps it frozen.
A decoder step costs several generator steps (the decoder and the RecNN run forward and backward), so
``decoder_every = k`` takes one every ``k`` batches. ``decoder_mean_range`` exists because the
IMS's mean value is not the IML's: the IMS rescales PIM' regressed at the IML's trained mean, whose
object pixels saturate, so the same share of C needs a larger u on the IMS (on the flame demo the IMS
needs u = 0.70 for 40% of C, where u = 0.4 gives the IML 33%), and the IML's range would leave the
ORP's masks untrained.

The decoder stage (``train_generator=false``, ``init_checkpoint=<a trained IMS>``; ``make bench-paper``'s
``stages.ims_decoder``): the decoder alone trains further, every batch, on the masks of that IMS's generator,
which stays bit for bit; ``decoder_sharpness`` and ``decoder_lift`` make them the masks the evaluation runs
(sharpened, lifted), and ``val/decoder_fr_psnr`` scores IML/S + RecNN on them. Beside the generator, the decoder
had only seen unsharpened masks, for the epochs the generator kept: on flame_whole it then beat the untrained fill
of the same pixels by 0.1 dB; trained for its masks, by 2.15 dB at 10% of C (BENCHMARKS.md).

Logged under ``{prefix}`` = ``train`` | ``val`` | ``test``:

* train: ``loss_g`` (weighted generator loss), the active unweighted terms ``bce``, ``mse``,
  ``perceptual``, ``adversarial``, and (adversarial on) ``loss_d``, ``d_real``, ``d_fake`` (mean
  discriminator probabilities).
* val/test: ``loss`` (weighted image-loss terms, no adversarial term: the discriminator moves) and
  its terms; ``im_accuracy`` (over the valid C-Image pixels) and ``im_iou`` vs the IML label;
  ``im_error = 1 - im_iou`` (the monitor: lower is better, independent of the loss choice, so runs
  of a loss ablation are selected the same way); ``ipr`` (predicted), ``label_ipr``,
  ``ipr_error = |ipr - label_ipr|``; ``c_psnr`` (IML decoder's C-Image from the IMS mask vs the
  C-Image); with a RecNN ``fr_psnr``/``fr_ssim`` of the IML/S path and ``label_fr_psnr``/
  ``label_fr_ssim`` of the same path driven by the label IM (the IML + RecNN upper bound); with
  ``decoder_lr > 0`` ``decoder_fr_psnr`` (:meth:`IMSTask.decoder_fr_psnr`). train, decoder fine-tuning:
  ``decoder_loss``.

The C-Image of the cache is exactly what selective rendering of the pattern's pixels returns, so
``IM * C-Image`` is the selectively rendered PR-C-Image.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Mapping, Optional

import torch
from lightning.pytorch.utilities import rank_zero_warn

from imls_lightning.base.errors import InputError, config_keys
from imls_lightning.base.validate import check_number
from imls_lightning.render.camera import view_tensor

from ..models.backbones import BACKBONES, VGG16_LAYERS
from .checkpoint_checks import check_same_pattern
from ..base.config import to_plain
from .losses import IMLoss, discriminator_loss, generator_loss
from ..models.iml import IMLNet
from ..models.ims import TARGETS, IMSDiscriminator, IMSGenerator, IMSMaskHead, generator_plan, im_to_target
from ..core.importance import check_sharpnesses
from ..core.patterns import build_pattern
from ..core.metrics import psnr_per_image
from .base import ImlsTask
from .iml import IMLTask, check_mean_range, end_to_end_loss, iml_decoder_from_hparams, iml_net_from_hparams
from .recnn import RecNNTask

__all__ = ["IMSTask", "TARGETS", "shallow_start_hint", "loss_config", "build_criterion", "pim_to_target", "build_iml_net", "scaled_pim_im"]

LOSS_TERMS = ("bce", "mse", "perceptual", "adversarial")
PERCEPTUAL_DEFAULTS = {
    "weight": 1.0,
    "backbone": "vgg16_hed",
    "weights": None,
    "layers": ["relu1_2", "relu2_2", "relu3_3", "relu4_3"],
    "layer_weights": None,
    "criterion": "mse",
    "normalize": True,
}


def loss_config(loss: Optional[Mapping]) -> dict:
    """Normalize the ``model.loss`` node: ``{bce, mse, adversarial: float, perceptual: {weight, ...}}``.

    ``perceptual`` may be a number (its weight) or a node with ``weight`` and the options of
    :class:`~imls_lightning.tasks.losses.PerceptualLoss` (``backbone``, ``weights`` = a weight *file*,
    ``layers``, ``layer_weights``, ``criterion``, ``normalize``). Missing keys take the paper
    default: perceptual 1 + adversarial 0.01.

    Example:
        >>> loss_config({"bce": 1, "perceptual": 0})["perceptual"]["weight"]
        0.0
    """
    raw = dict(to_plain(loss) or {})
    unknown = set(raw) - set(LOSS_TERMS)
    if unknown:
        raise InputError(f"model.loss.{sorted(unknown)[0]}: unknown loss term; expected some of {list(LOSS_TERMS)}")
    per = raw.get("perceptual", PERCEPTUAL_DEFAULTS["weight"])
    per = {"weight": per} if not isinstance(per, Mapping) else dict(per)
    bad = set(per) - set(PERCEPTUAL_DEFAULTS)
    if bad:
        raise InputError(f"model.loss.perceptual.{sorted(bad)[0]}: unknown option; expected some of {list(PERCEPTUAL_DEFAULTS)}")
    per = {**PERCEPTUAL_DEFAULTS, **per}
    per["weight"] = check_number(per["weight"], "model.loss.perceptual.weight", 0)
    per["layers"] = [str(x) for x in per["layers"]]
    # names are checked here (cheap); the weight file is read, and checked, when the loss is built
    if per["backbone"] not in BACKBONES:
        raise InputError(f"model.loss.perceptual.backbone={per['backbone']}: expected one of {list(BACKBONES)}")
    bad_layers = [x for x in per["layers"] if x not in VGG16_LAYERS]
    if not per["layers"] or bad_layers:
        raise InputError(f"model.loss.perceptual.layers: unknown layer {bad_layers[:1] or '(none)'}; expected VGG16 names like relu1_2, relu2_2, relu3_3, relu4_3")
    out = {
        "bce": check_number(raw.get("bce", 0.0), "model.loss.bce", 0),
        "mse": check_number(raw.get("mse", 0.0), "model.loss.mse", 0),
        "perceptual": per,
        "adversarial": check_number(raw.get("adversarial", 0.01), "model.loss.adversarial", 0),
    }
    if out["bce"] == 0 and out["mse"] == 0 and per["weight"] == 0:
        raise InputError("model.loss: bce, mse and perceptual.weight are all 0; the generator needs at least one image loss > 0")
    return out


def build_criterion(loss: Mapping) -> IMLoss:
    """:class:`~imls_lightning.tasks.losses.IMLoss` of a (normalized) ``model.loss`` node; loads the
    perceptual backbone when its weight is > 0 (InputError when its weights are missing)."""
    lc = loss_config(loss)
    per = lc["perceptual"]
    return IMLoss(
        bce=lc["bce"], mse=lc["mse"], perceptual=per["weight"],
        perceptual_kwargs={k: per[k] for k in ("backbone", "weights", "layers", "layer_weights", "criterion", "normalize")},
    )


def pim_to_target(pim: torch.Tensor, valid: Optional[torch.Tensor] = None) -> torch.Tensor:
    """PIM' (``>= 0``) -> generator target ``2 clamp(PIM', 0, 1) - 1`` in ``[-1, 1]``; -1 where not ``valid``.

    Args:
        pim: ``(B, 1, n, n)`` PIM'.
        valid: optional ``(n, n)`` / ``(1, 1, n, n)`` bool, the pattern's C-Image pixels.

    Example:
        >>> pim_to_target(torch.tensor([0.0, 0.25, 3.0])).tolist()
        [-1.0, -0.5, 1.0]
    """
    t = pim.float().clamp(0.0, 1.0) * 2.0 - 1.0
    if valid is not None:
        t = torch.where(valid.to(device=t.device, dtype=torch.bool), t, torch.full_like(t, -1.0))
    return t


def scaled_pim_im(task, g: torch.Tensor, u: torch.Tensor | float, u_train: float | None = None,
                  lift: bool = False) -> torch.Tensor:
    """IM of an IMS (``target="pim"``) output at mean value ``u`` instead of the trained ``u_train``:
    :meth:`IMSMaskHead.threshold <imls_lightning.models.ims.IMSMaskHead.threshold>` of the task's
    :attr:`~IMSTask.mask_head` (the one home of the arithmetic; see there).

    Args:
        task: the :class:`~imls_lightning.tasks.ims.IMSTask`.
        g: ``(B, 1, n, n)`` generator output in ``[-1, 1]``.
        u: ``(B,)`` tensor or a number: the mean value per view.
        u_train: the mean the IMS targets were normalized to (default: the IML's trained mean).
        lift: lift the rescaled PIM' to the share ``u`` above the trained mean (default False: the
            paper's rescale).

    Returns:
        ``(B, 1, n, n)`` bool IM.
    """
    head = task.mask_head
    if u_train is not None and float(u_train) != head.trained_mean:
        head = IMSMaskHead(head.generator, head.P, head.valid, head.target, float(u_train), head.lower)
    return head.threshold(g, u, lift)


#: the widest start side the generator should have: the view reaches the first ``s0 x s0`` map through one
#: linear layer, so a wide start leaves only a few nonlinear layers to map the view to the mask
MAX_START_SIDE = 8


def shallow_start_hint(c_size: int, layers: int) -> str | None:
    """A one-line hint when ``layers`` starts the generator wider than :data:`MAX_START_SIDE` and more
    layers would start it narrower (the hint names the fewest layers that reach the narrowest start); None
    otherwise.

    Measured on ct_head at a 256^2 C-Image (BENCHMARKS.md): ``layers=5`` starts at 16 x 16; ``layers=7``
    starts at 4 x 4, costs 1 ms more per frame, and its mask beat blue noise by 1.08 / 1.39 / 2.10 dB at
    10 / 20 / 40% of C where the 5-layer one did by 0.83 / 1.04 / 1.64.

    Example:
        >>> shallow_start_hint(256, 7) is None, shallow_start_hint(64, 5) is None
        (True, True)
        >>> shallow_start_hint(256, 5).split(":")[0]
        'model.layers=5 starts the IMS generator at 16x16 for a 256x256 mask'
    """
    s0 = generator_plan(c_size, layers)[0]
    narrowest, doublings, _ = generator_plan(c_size, layers + 32)  # as many doublings as the side allows
    if s0 <= MAX_START_SIDE or narrowest == s0:
        return None
    better = doublings + 1  # the projection, then one layer per doubling
    return (f"model.layers={layers} starts the IMS generator at {s0}x{s0} for a {c_size}x{c_size} mask: the view reaches "
            f"it through one linear layer; model.layers={better} starts at {narrowest}x{narrowest} (on ct_head at 256^2 "
            f"that mask beat blue noise by 0.25 to 0.46 dB more)")


def _plain_json(obj: Any) -> Any:
    """Plain JSON data (checkpoint hyperparameters must load with ``weights_only=True``)."""
    return json.loads(json.dumps(to_plain(obj), default=str))


def build_iml_net(iml_hparams: Mapping, pattern) -> IMLNet:
    """The :class:`IMLNet` an ``IMLTask`` with these hyperparameters builds (loading its weights
    strictly checks it): :func:`imls_lightning.tasks.iml.iml_net_from_hparams`."""
    return iml_net_from_hparams(iml_hparams, pattern)


def _input_iml(cfg, pattern) -> tuple[str, IMLTask]:
    """``(iml.checkpoint, its IMLTask)``, trained on ``pattern`` (at its resolution).

    Raises:
        InputError: the key is unset, the file is not an IML checkpoint, or the IML was trained on
            another pattern or resolution.
    """
    if cfg.get("iml") is None or not cfg.iml.get("checkpoint"):
        raise InputError("model=ims needs a trained IML network: set iml.checkpoint=<path to an IML .ckpt> (python -m imls_lightning.train model=iml ...)")
    ck = str(cfg.iml.checkpoint)
    iml_task = IMLTask.from_checkpoint(ck, what="iml.checkpoint")
    check_same_pattern(iml_task.hparams, pattern, key="iml.checkpoint", path=ck, network="IML",
                       hint="choose the recnn/pattern and data.resolution it was trained with")
    return ck, iml_task


def _input_recnn(cfg, iml_task: IMLTask, pattern) -> tuple[Optional[dict], Optional[dict], Optional[str]]:
    """The RecNN behind the IMS's final-image metrics: ``(hyperparameters, state dict, source key)``.

    The one inside an end-to-end IML checkpoint (its decoder was trained for it), else
    ``recnn.checkpoint`` (off-the-shelf), else ``(None, None, None)``: the FR metrics are skipped.
    """
    if iml_task.recnn is not None:
        if cfg.recnn.get("checkpoint"):
            print("[ims] using the RecNN inside the end-to-end IML checkpoint; recnn.checkpoint is ignored", flush=True)
        # possibly fine-tuned end to end
        return iml_task.hparams["recnn_hparams"], iml_task.recnn.state_dict(), "iml.checkpoint"
    if not cfg.recnn.get("checkpoint"):
        print("[ims] no RecNN (standalone IML and no recnn.checkpoint): the final FR PSNR/SSIM metrics are skipped", flush=True)
        return None, None, None
    rt = RecNNTask.from_checkpoint(cfg.recnn.checkpoint, what="recnn.checkpoint")
    check_same_pattern(rt.hparams, pattern, key="recnn.checkpoint", path=cfg.recnn.checkpoint, network="RecNN",
                       against="the IML", hint="use a RecNN trained on the IML's pattern and resolution")
    return dict(rt.hparams), rt.net.state_dict(), "recnn.checkpoint"


#: the generator's and discriminator's shape: an ``init_checkpoint`` checkpoint must have the configured ones
_NET_KEYS = ("target", "layers", "base_channels", "max_channels", "disc_base_channels", "disc_max_channels")


def _init_checkpoint(cfg, iml_sha256: str) -> dict[str, dict]:
    """The weights ``model.init_checkpoint`` (a trained IMS checkpoint) starts this run with: its generator,
    discriminator and IML (with its fine-tuned decoder), checked against the configured networks' shape and
    the IML its labels came from.

    Raises:
        InputError: not an intact IMS checkpoint, or of another shape or IML.
    """
    path = str(cfg.model.init_checkpoint)
    src = IMSTask.from_checkpoint(path, what="model.init_checkpoint")
    for key in _NET_KEYS:
        if src.hparams.get(key) != to_plain(cfg.model.get(key)):
            raise InputError(f"model.init_checkpoint={path}: its model.{key} is {src.hparams.get(key)}, this run's "
                             f"{to_plain(cfg.model.get(key))}; start from an IMS of the same networks")
    if src.hparams.get("iml_checkpoint_sha256") != iml_sha256:
        raise InputError(f"model.init_checkpoint={path}: trained on the labels of another IML than iml.checkpoint="
                         f"{cfg.iml.checkpoint}; start from an IMS of the same IML")
    return {"generator": src.generator.state_dict(), "discriminator": src.discriminator.state_dict(),
            "iml": src.iml.state_dict()}


class IMSTask(ImlsTask):
    """LightningModule of the IMS GAN (generator + discriminator) with the frozen IML decoder and
    RecNN for the final-image metrics.

    Args:
        pattern: the ``pattern`` config node; ``fr_size``: FR-Image side ``m``.
        iml_hparams: the IML task's hyperparameters (plain data, from its checkpoint).
        target: ``"im"`` (paper) or ``"pim"`` (regress PIM', dither against P at inference).
        layers, base_channels, max_channels: generator size (paper: 8 layers).
        disc_base_channels, disc_max_channels: discriminator size.
        loss: the ``model.loss`` node (see :func:`loss_config`).
        lr: Adam learning rate of both networks (paper 1e-3); ``betas``: Adam betas.
        recnn_hparams: the RecNN task's hyperparameters (plain), or None (no FR metrics).
        recnn_source: ``"iml.checkpoint"``, ``"recnn.checkpoint"`` or None (provenance).
        iml_checkpoint, iml_checkpoint_sha256, labels: provenance only.
        decoder_lr, decoder_every, decoder_mean_range: the decoder's fine-tuning (the module doc).
        decoder_sharpness: the mask sharpness(es) the decoder is fine-tuned on (one drawn per batch);
            ``decoder_lift``: its masks lifted to the share ``u`` (:meth:`decoder_masks`).
        train_generator: False: the decoder alone trains, on the masks of ``init_checkpoint``'s generator,
            which stays as trained (the decoder stage); ``init_checkpoint``: that IMS (provenance here: training
            loads its weights through ``pretrained``).
        pretrained: ``{"iml": state dict, "recnn": state dict}`` (and, from ``init_checkpoint``, ``"generator"``
            and ``"discriminator"``): the input networks' weights (not hyperparameters).
        criterion: the generator's loss, already built from ``loss`` (training builds it before any
            labelling); None: built on first use (:attr:`im_loss`).

    Attributes:
        generator (:class:`IMSGenerator`), discriminator (:class:`IMSDiscriminator`), iml
        (:class:`IMLNet`, frozen), recnn (``nn.Module`` or None, frozen), pattern; :attr:`mask_head`
        (:class:`~imls_lightning.models.ims.IMSMaskHead`: the generator and its thresholding, the mean
        value and lift given to each call; an operating point's sharpness and floor given by the point).

    Example:
        >>> task = build_task(cfg)  # model=ims iml.checkpoint=...  # doctest: +SKIP
        >>> task.predict_im(torch.tensor([[0, 0, 3, 0, 0, 0, 0, 1, 0.]])).shape  # doctest: +SKIP
        torch.Size([1, 1, 128, 128])
    """

    def __init__(
        self,
        pattern: Mapping,
        fr_size: int,
        iml_hparams: Mapping,
        target: str = "im",
        layers: int = 8,
        base_channels: int = 32,
        max_channels: int = 512,
        disc_base_channels: int = 32,
        disc_max_channels: int = 256,
        loss: Optional[Mapping] = None,
        lr: float = 1e-3,
        betas: tuple = (0.5, 0.999),
        recnn_hparams: Optional[Mapping] = None,
        recnn_source: Optional[str] = None,
        iml_checkpoint: Optional[str] = None,
        iml_checkpoint_sha256: Optional[str] = None,
        labels: Optional[str] = None,
        scene: Optional[Mapping] = None,
        renderer: Optional[Mapping] = None,
        decoder_lr: float = 0.0,
        decoder_every: int = 1,
        decoder_mean_range: Any = None,
        decoder_sharpness: Any = (1.0,),
        decoder_lift: bool = False,
        train_generator: bool = True,
        init_checkpoint: Optional[str] = None,
        pretrained: Optional[Mapping[str, Mapping[str, torch.Tensor]]] = None,
        criterion: Optional[IMLoss] = None,
        **_: Any,  # run keys of the model node (name, patience, labels_*, ...) and stale hyperparameters: see ImlsTask
    ):
        super().__init__()
        if target not in TARGETS:
            raise InputError(f"model.target={target!r}: expected one of {list(TARGETS)}")
        if not (isinstance(lr, (int, float)) and lr > 0 and math.isfinite(lr)):
            raise InputError(f"model.lr={lr}: expected a positive number")
        if not (isinstance(decoder_lr, (int, float)) and not isinstance(decoder_lr, bool) and decoder_lr >= 0 and math.isfinite(decoder_lr)):
            raise InputError(f"model.decoder_lr={decoder_lr}: expected a number >= 0 (0: the IML decoder stays frozen)")
        if isinstance(decoder_every, bool) or not isinstance(decoder_every, int) or decoder_every < 1:
            raise InputError(f"model.decoder_every={decoder_every}: expected an integer >= 1 (a decoder step every that many batches)")
        if decoder_lr > 0 and target != "pim":
            raise InputError(f"model.decoder_lr={decoder_lr}: fine-tuning the decoder on the IMS's masks needs model.target=pim")
        if not isinstance(decoder_lift, bool):
            raise InputError(f"model.decoder_lift={decoder_lift}: expected true or false")
        if not isinstance(train_generator, bool):
            raise InputError(f"model.train_generator={train_generator}: expected true or false")
        if not train_generator and not (decoder_lr > 0 and init_checkpoint):
            raise InputError("model.train_generator=false: trains the decoder alone, so it needs model.decoder_lr > 0 and "
                             "model.init_checkpoint=<a trained IMS .ckpt> (whose generator makes the masks)")
        betas = tuple(float(b) for b in to_plain(betas))
        if len(betas) != 2 or not all(0.0 <= b < 1.0 for b in betas):
            raise InputError(f"model.betas={list(betas)}: expected two numbers in [0, 1)")
        lc = loss_config(loss)
        if not iml_hparams:
            raise InputError("model=ims needs the IML's hyperparameters (iml_hparams); build the task with imls_lightning.training.fit.build_task and iml.checkpoint=<IML .ckpt>")
        self.automatic_optimization = False
        self.save_hyperparameters({
            "pattern": _plain_json(pattern), "fr_size": int(fr_size), "iml_hparams": _plain_json(iml_hparams),
            "target": target, "layers": int(layers), "base_channels": int(base_channels),
            "max_channels": int(max_channels), "disc_base_channels": int(disc_base_channels),
            "disc_max_channels": int(disc_max_channels), "loss": lc, "lr": float(lr), "betas": list(betas),
            "recnn_hparams": _plain_json(recnn_hparams) if recnn_hparams else None, "recnn_source": recnn_source,
            "iml_checkpoint": None if iml_checkpoint is None else str(iml_checkpoint),
            "iml_checkpoint_sha256": iml_checkpoint_sha256, "labels": None if labels is None else str(labels),
            # the scene and renderer the IMS was trained on: IMLSRenderer.from_checkpoints needs nothing else
            "scene": _plain_json(scene) if scene else None, "renderer": _plain_json(renderer) if renderer else None,
            "decoder_lr": float(decoder_lr), "decoder_every": int(decoder_every),
            "decoder_mean_range": check_mean_range(to_plain(decoder_mean_range), "model.decoder_mean_range"),
            "decoder_sharpness": check_sharpnesses(to_plain(decoder_sharpness), "model.decoder_sharpness"),
            "decoder_lift": bool(decoder_lift), "train_generator": bool(train_generator),
            "init_checkpoint": None if init_checkpoint is None else str(init_checkpoint),
        })
        self.pattern = build_pattern(to_plain(pattern), int(fr_size))
        n = self.pattern.c_size
        check_same_pattern(iml_hparams, self.pattern, key="iml.checkpoint", network="IML",
                           hint="use the recnn/pattern and data.resolution it was trained with")
        with config_keys({k: f"model.{k}" for k in ("layers", "base_channels", "max_channels")}):  # the user's keys
            self.generator = IMSGenerator(n, layers=layers, base_channels=base_channels, max_channels=max_channels)
        with config_keys({"base_channels": "model.disc_base_channels", "max_channels": "model.disc_max_channels"}):
            self.discriminator = IMSDiscriminator(n, base_channels=disc_base_channels, max_channels=disc_max_channels)
        self.iml = build_iml_net(iml_hparams, self.pattern).requires_grad_(False)
        if decoder_lr > 0:
            self.iml.decoder.requires_grad_(True)
        self.recnn = None
        if recnn_hparams:
            check_same_pattern(recnn_hparams, self.pattern, key="recnn.checkpoint", network="RecNN", against="the IML",
                               hint="use a RecNN trained on the IML's pattern and resolution")
            self.recnn = RecNNTask(**dict(recnn_hparams)).net.requires_grad_(False)
        if not train_generator:  # the decoder alone trains, on the masks of a trained generator (init_checkpoint)
            self.generator.requires_grad_(False)
            self.discriminator.requires_grad_(False)
        self.load_pretrained(pretrained)
        if criterion is not None:
            self.add_module("_im_loss", criterion)
        self.register_buffer("valid", self.pattern.valid.view(1, 1, n, n).clone(), persistent=False)
        # set once the generator's view normalization was fitted on the training views (checkpointed); a generator
        # taken over from init_checkpoint keeps the normalization it was trained with
        self.register_buffer("view_norm_fitted", torch.tensor("generator" in (pretrained or {})))
        self._warned_no_recnn = False

    # -- accessors ----------------------------------------------------------------------------
    @property
    def decoder(self) -> torch.nn.Module:
        """The IML decoder (PR-C-Image -> C-Image): frozen, or fine-tuned on the IMS's masks (``decoder_lr > 0``)."""
        return self.iml.decoder

    @property
    def finetunes_decoder(self) -> bool:
        return float(self.hparams.get("decoder_lr", 0.0)) > 0

    @property
    def trains_generator(self) -> bool:
        """False: the generator (and discriminator) of ``init_checkpoint`` stay as trained; only the decoder trains."""
        return bool(self.hparams.get("train_generator", True))

    @property
    def P(self) -> torch.Tensor:
        """``(n, n)`` the plastic rank pattern the IML labels were dithered with."""
        return self.iml.sampling.P

    @property
    def target(self) -> str:
        return self.hparams.target

    @property
    def im_loss(self) -> IMLoss:
        """The generator's image losses (:class:`~imls_lightning.tasks.losses.IMLoss`), built on first use.

        Lazy on purpose: loading an IMS checkpoint for inference (the IML/S renderer) must not need
        the perceptual backbone's weight file; training builds it in :meth:`config_context`, before any
        label is made, so a missing backbone fails early there.
        """
        crit = self._modules.get("_im_loss")
        if crit is None:
            crit = build_criterion(self.hparams.loss).to(self.device)
            self.add_module("_im_loss", crit)
        return crit

    @property
    def loss_weights(self) -> dict[str, float]:
        lc = self.hparams.loss
        return {"bce": lc["bce"], "mse": lc["mse"], "perceptual": lc["perceptual"]["weight"], "adversarial": lc["adversarial"]}

    # -- construction from the training config ------------------------------------------------
    @classmethod
    def config_context(cls, cfg) -> dict:
        """Everything from outside the model node: the pattern and resolution, the IML of
        ``iml.checkpoint`` (hyperparameters, weights, provenance), the RecNN for the final-image
        metrics, where the labels go, the scene and renderer, and the generator's loss, built here
        so that a missing perceptual backbone fails before any labelling."""
        res = int(cfg.data.resolution)
        pattern = build_pattern(to_plain(cfg.pattern), res)
        shallow = shallow_start_hint(pattern.c_size, int(cfg.model.layers))
        if shallow:  # when a training is configured, not each time a trained checkpoint is loaded
            rank_zero_warn(shallow)
        ck, iml_task = _input_iml(cfg, pattern)
        recnn_hparams, recnn_state, source = _input_recnn(cfg, iml_task, pattern)
        # the labels themselves are made by the DataModule (datamodule_kwargs); here only their provenance
        from data_gen.cache import cache_path_for
        from data_gen.scenes import build_scene

        from ..data.labels import labels_path_for

        labels = labels_path_for(cache_path_for(build_scene(cfg.scene), cfg.data, cfg.renderer), ck)
        pretrained = {"iml": iml_task.iml.state_dict()}
        if recnn_state is not None:
            pretrained["recnn"] = recnn_state
        if cfg.model.get("init_checkpoint"):
            pretrained.update(_init_checkpoint(cfg, labels.name[len("iml-"):]))
        return {
            "pattern": cfg.pattern, "fr_size": res, "iml_hparams": dict(iml_task.hparams), "pretrained": pretrained,
            "recnn_hparams": recnn_hparams, "recnn_source": source,
            # the resolved path (the model node's iml_checkpoint is the one given, for the run hash)
            "iml_checkpoint": str(Path(ck).expanduser().resolve()),
            "iml_checkpoint_sha256": labels.name[len("iml-"):], "labels": str(labels),
            "scene": to_plain(cfg.scene), "renderer": to_plain(cfg.get("renderer")) if cfg.get("renderer") is not None else None,
            "criterion": build_criterion(cfg.model.loss),
        }

    @classmethod
    def inference_nets(cls, hparams: Mapping[str, Any]) -> dict[str, torch.nn.Module]:
        """The product's networks of an IMS checkpoint, built from its hyperparameters without the task
        (no discriminator, no IML encoder, no RecNN task): ``{"generator", "iml.decoder", "recnn"}``
        (``recnn`` only when the checkpoint stores one). The rank pattern ``P`` is the buffer
        ``iml.sampling.P`` of the checkpoint's state dict."""
        pattern = build_pattern(to_plain(hparams["pattern"]), int(hparams["fr_size"]))
        nets = {"generator": IMSGenerator(pattern.c_size, layers=int(hparams.get("layers", 8)),
                                          base_channels=int(hparams.get("base_channels", 32)),
                                          max_channels=int(hparams.get("max_channels", 512))),
                "iml.decoder": iml_decoder_from_hparams(hparams["iml_hparams"], pattern)}
        if hparams.get("recnn_hparams"):
            nets["recnn"] = RecNNTask.inference_nets(hparams["recnn_hparams"])["net"]
        return nets

    @classmethod
    def datamodule_kwargs(cls, cfg) -> dict:
        # the DataModule labels the cache with the IML (once; imls_lightning.data.labels) and yields im / pim.
        # train_fr=False: the mask is learned from the view and the C-Image's labels alone, so the IMS's own
        # views may be rendered at the C-pixels only (data.train_pixels=pattern); the decoder is then
        # fine-tuned on the C-Image term alone (decoder_loss), validated end to end on whole frames
        m = cfg.model
        return {"fields": ("view", "fr", "c"), "labels_from": str(cfg.iml.checkpoint), "train_fr": False,
                "labels_options": {"batch_size": int(m.labels_batch_size), "device": m.labels_device}}

    # -- the mask -------------------------------------------------------------------------------
    def make_target(self, batch: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """The generator's target ``(B, 1, n, n)`` in [-1, 1] from the batch's ``im`` / ``pim`` labels."""
        if self.target == "im":
            return im_to_target(batch["im"])
        return pim_to_target(batch["pim"], self.valid)

    @property
    def mask_head(self) -> IMSMaskHead:
        """The generator with its thresholding (:class:`~imls_lightning.models.ims.IMSMaskHead`): the
        task's generator and buffers (``P``, ``valid``), its target, the IML's trained mean and lower
        bound; the paper's masks (an operating point's sharpness and floor are the point's:
        :meth:`~imls_lightning.models.ims.IMSMaskHead.for_point`). Made on each access (cheap, nothing copied), so it
        follows the task across devices."""
        return IMSMaskHead(self.generator, self.P, self.valid, self.target, float(self.iml.mean),
                           float(self.iml.normalization.lower))

    def output_to_im(self, g: torch.Tensor) -> torch.Tensor:
        """Generator output ``(B, 1, n, n)`` -> IM ``(B, 1, n, n)`` bool at the trained mean, False on
        C-Image padding (:meth:`IMSMaskHead.threshold <imls_lightning.models.ims.IMSMaskHead.threshold>`)."""
        return self.mask_head.threshold(g)

    def output_to_im_at(self, g: torch.Tensor, mean: torch.Tensor | float | None, lift: bool = False) -> torch.Tensor:
        """:meth:`output_to_im` at mean value ``mean`` (``None``: the trained one), lifted with ``lift``."""
        return self.mask_head.threshold(g, mean, lift)

    @torch.no_grad()
    def predict_im(self, view: torch.Tensor, mean: float | None = None, lift: bool = False) -> torch.Tensor:
        """Importance mask of views ``(B, 9)`` -> ``(B, 1, n, n)`` bool (the IMS product), at the
        trained mean value or at ``mean`` (``target="pim"`` only: the regressed PIM' is rescaled, lifted
        with ``lift``): :attr:`mask_head`.

        Uses the generator in whatever mode the task is in (``eval()`` for inference).
        """
        return self.mask_head(view_tensor(view, self.valid.device), mean, lift)

    def reconstruct(self, im: torch.Tensor, c_image: torch.Tensor) -> tuple[torch.Tensor, Optional[torch.Tensor]]:
        """IML/S path from an IM and the C-Image: ``(decoder C-Image (B, 3, n, n), FR (B, 3, m, m) or None)``."""
        im = im.to(c_image.dtype)
        c_rec = self.decoder(im * c_image, im)
        return c_rec, (self.recnn(c_rec) if self.recnn is not None else None)

    # -- training ------------------------------------------------------------------------------
    def train(self, mode: bool = True):
        super().train(mode)
        self._passengers_in_eval_mode()
        return self

    def _passengers_in_eval_mode(self) -> None:
        # frozen passengers: keep their normalization layers in inference mode (a frozen generator's BatchNorm would
        # otherwise make the decoder's masks from batch statistics and move its running statistics)
        self.iml.eval()
        if self.recnn is not None:
            self.recnn.eval()
        if not self.trains_generator:
            self.generator.eval()
            self.discriminator.eval()

    def on_train_batch_start(self, batch, batch_idx) -> None:
        # Lightning may restore each submodule's own mode past train() (after validation): set them again
        self._passengers_in_eval_mode()

    def _fit_view_normalization(self, views: torch.Tensor) -> None:
        self.generator.fit_view_normalization(views.to(self.generator.view_mean.device))
        self.view_norm_fitted.fill_(True)

    def setup(self, stage: str) -> None:
        # DDP: the discriminator and generator steps are separate backward passes, each leaving the
        # other network without gradients; DDP has to expect that (Lightning's advice for GANs
        # under manual optimization). Runs before the strategy wraps the module in DDP.
        ddp_kwargs = getattr(self.trainer.strategy, "_ddp_kwargs", None)
        if stage == "fit" and isinstance(ddp_kwargs, dict):
            ddp_kwargs.setdefault("find_unused_parameters", True)

    def on_fit_start(self) -> None:
        if bool(self.view_norm_fitted):
            return  # resumed (or fine-tuned): keep the normalization the weights were trained with
        dm = getattr(self.trainer, "datamodule", None)
        ds = dm.dataset("train") if dm is not None and hasattr(dm, "dataset") else None
        if ds is not None and hasattr(ds, "cache_path"):
            import numpy as np

            from data_gen.cache import ViewImageCache

            views = ViewImageCache.open(ds.cache_path).views[np.asarray(ds.rows)]
            self._fit_view_normalization(view_tensor(views))

    def on_train_start(self) -> None:
        if bool(self.view_norm_fitted):
            return
        # plain DataLoaders (no ImlsDataModule): one pass over the training views
        loader = self.trainer.train_dataloader
        views = [b["view"] for b in loader] if loader is not None else []
        if views:
            self._fit_view_normalization(torch.cat(views).float())

    def configure_optimizers(self):
        if not self.trains_generator:
            return torch.optim.Adam(self.iml.decoder.parameters(), lr=float(self.hparams.decoder_lr))
        lr, betas = self.hparams.lr, tuple(self.hparams.betas)
        opt_g = torch.optim.Adam(self.generator.parameters(), lr=lr, betas=betas)
        opt_d = torch.optim.Adam(self.discriminator.parameters(), lr=lr, betas=betas)
        if not self.finetunes_decoder:
            return [opt_g, opt_d]
        return [opt_g, opt_d, torch.optim.Adam(self.iml.decoder.parameters(), lr=float(self.hparams.decoder_lr))]

    def decoder_mean_range(self) -> tuple[float, float]:
        """``(lo, hi)`` of the mean values the decoder is fine-tuned at: ``decoder_mean_range``, else the IML's
        ``mean_range``, else its mean (one home for the fine-tuning and its validation)."""
        lo, hi = (self.hparams.get("decoder_mean_range") or self.hparams.iml_hparams.get("mean_range")
                  or (float(self.iml.mean), float(self.iml.mean)))
        return float(lo), float(hi)

    def _random_means(self, n: int, device) -> torch.Tensor:
        """``(n,)`` mean values for decoder fine-tuning, uniform in :meth:`decoder_mean_range`."""
        lo, hi = self.decoder_mean_range()
        return lo + (hi - lo) * torch.rand(n, device=device)

    def decoder_masks(self, g: torch.Tensor, means: torch.Tensor | float, sharpness: float) -> torch.Tensor:
        """The hard masks ``(B, 1, n, n)`` bool the decoder is fine-tuned and validated on: the generator's
        output ``g`` at ``means``, sharpened to ``sharpness``, lifted to the share ``means`` where
        ``decoder_lift`` (as the evaluation's ORP runs them)."""
        head = self.mask_head.with_sharpness(float(sharpness))
        return head.threshold(g.detach(), means, bool(self.hparams.get("decoder_lift", False)))

    def decoder_loss(self, g: torch.Tensor, batch: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """The IML's end-to-end loss of the decoder on the generator's hard masks ``g`` (detached) at
        random mean values and one of ``decoder_sharpness`` (drawn per batch): what :attr:`decoder` is
        fine-tuned on."""
        c = batch["c"]
        gammas = self.hparams.get("decoder_sharpness") or [1.0]
        gamma = gammas[int(torch.randint(len(gammas), ()))]
        with torch.no_grad():
            im = self.decoder_masks(g, self._random_means(c.shape[0], c.device), gamma).to(c.dtype)
        c_rec = self.iml.decoder(im * c, im)
        end_to_end = self.recnn is not None and "fr" in batch
        fr_pred, fr = (self.recnn(c_rec).float(), batch["fr"].float()) if end_to_end else (None, None)
        weights = {k: float(v) for k, v in self.hparams.iml_hparams.items() if k in ("compaction_weight", "image_weight")}
        return end_to_end_loss(c_rec.float(), c.float(), fr_pred, fr, **weights)[0]

    def training_step(self, batch, batch_idx):
        if not self.trains_generator:
            return self._decoder_step(batch)
        opts = self.optimizers()
        opt_g, opt_d = opts[0], opts[1]
        view = batch["view"]
        target = self.make_target(batch).to(view.device)
        bs = view.shape[0]
        w_adv = self.loss_weights["adversarial"]
        fake, pre = self.generator(view, return_pre_tanh=True)
        log = dict(batch_size=bs, on_step=True, on_epoch=True)

        if w_adv > 0:
            self.toggle_optimizer(opt_d)
            real_logits = self.discriminator(target)
            fake_logits = self.discriminator(fake.detach())
            loss_d = discriminator_loss(real_logits, fake_logits)
            opt_d.zero_grad(set_to_none=True)
            self.manual_backward(loss_d)
            opt_d.step()
            self.untoggle_optimizer(opt_d)
            self.log("train/loss_d", loss_d.detach(), **log)
            self.log("train/d_real", torch.sigmoid(real_logits.detach().float()).mean(), **log)
            self.log("train/d_fake", torch.sigmoid(fake_logits.detach().float()).mean(), **log)

        self.toggle_optimizer(opt_g)
        terms = self.im_loss(fake, target, pre_tanh=pre)
        loss_g = terms.pop("total")
        if w_adv > 0:
            terms["adversarial"] = generator_loss(self.discriminator(fake))
            loss_g = loss_g + w_adv * terms["adversarial"]
        opt_g.zero_grad(set_to_none=True)
        self.manual_backward(loss_g)
        opt_g.step()
        self.untoggle_optimizer(opt_g)

        self.log("train/loss_g", loss_g.detach(), prog_bar=True, **log)
        for k, v in terms.items():
            self.log(f"train/{k}", v.detach(), **log)
        if self.finetunes_decoder and batch_idx % int(self.hparams.get("decoder_every", 1)) == 0:
            opt_dec = opts[2]
            self.toggle_optimizer(opt_dec)
            loss_dec = self.decoder_loss(fake, batch)
            opt_dec.zero_grad(set_to_none=True)
            self.manual_backward(loss_dec)
            opt_dec.step()
            self.untoggle_optimizer(opt_dec)
            self.log("train/decoder_loss", loss_dec.detach(), **log)
        return loss_g.detach()

    def _decoder_step(self, batch) -> torch.Tensor:
        """``train_generator=false``: one step of the decoder alone, on the masks of the frozen generator."""
        opt = self.optimizers()
        with torch.no_grad():
            g = self.generator(batch["view"])
        loss = self.decoder_loss(g, batch)
        opt.zero_grad(set_to_none=True)
        self.manual_backward(loss)
        opt.step()
        self.log("train/decoder_loss", loss.detach(), prog_bar=True, batch_size=g.shape[0], on_step=True, on_epoch=True)
        return loss.detach()

    # -- evaluation ----------------------------------------------------------------------------
    def _eval_step(self, batch: Mapping[str, torch.Tensor], prefix: str) -> None:
        view = batch["view"]
        bs = view.shape[0]
        g, pre = self.generator(view, return_pre_tanh=True)
        terms = self.im_loss(g, self.make_target(batch), pre_tanh=pre)
        log = dict(batch_size=bs, on_step=False, on_epoch=True)
        self.log(f"{prefix}/loss", terms.pop("total"), prog_bar=True, **log)
        for k, v in terms.items():
            self.log(f"{prefix}/{k}", v, **log)

        pred = self.output_to_im(g)
        label = (batch["im"] > 0.5) & self.valid
        valid = self.valid.expand_as(pred)
        k = float(self.pattern.count)
        m2 = float(self.pattern.fr_size) ** 2
        acc = ((pred == label) & valid).flatten(1).sum(1).float() / k
        inter = (pred & label).flatten(1).sum(1).float()
        union = (pred | label).flatten(1).sum(1).float()
        iou = torch.where(union > 0, inter / union.clamp_min(1.0), torch.ones_like(union))  # both empty: a match
        ipr = pred.flatten(1).sum(1).float() / m2
        label_ipr = label.flatten(1).sum(1).float() / m2
        self.log(f"{prefix}/im_accuracy", acc.mean(), **log)
        self.log(f"{prefix}/im_iou", iou.mean(), **log)
        self.log(f"{prefix}/im_error", 1.0 - iou.mean(), **log)
        self.log(f"{prefix}/ipr", ipr.mean(), prog_bar=True, **log)
        self.log(f"{prefix}/label_ipr", label_ipr.mean(), **log)
        self.log(f"{prefix}/ipr_error", (ipr - label_ipr).abs().mean(), **log)

        if "c" not in batch:
            return
        c = batch["c"]
        c_rec, fr_pred = self.reconstruct(pred, c)
        self.log(f"{prefix}/c_psnr", psnr_per_image(c_rec, c).mean(), **log)
        if fr_pred is None or "fr" not in batch:
            if not self._warned_no_recnn:
                rank_zero_warn("IMSTask: no RecNN (standalone IML checkpoint and no recnn.checkpoint): final FR PSNR/SSIM not computed")
                self._warned_no_recnn = True
            return
        fr = batch["fr"]
        self.log_image_metrics(f"{prefix}/fr", fr_pred, fr, on_step=False, on_epoch=True)
        _, fr_label = self.reconstruct(label, c)
        self.log_image_metrics(f"{prefix}/label_fr", fr_label, fr, on_step=False, on_epoch=True)
        if self.finetunes_decoder:
            self.log(f"{prefix}/decoder_fr_psnr", self.decoder_fr_psnr(g, c, fr).mean(), **log)

    def decoder_fr_psnr(self, g: torch.Tensor, c: torch.Tensor, fr: torch.Tensor) -> torch.Tensor:
        """``(B,)`` IML/S + RecNN PSNR on the masks the decoder is fine-tuned on (:meth:`decoder_masks`), averaged
        over each ``decoder_sharpness`` and the low end, middle and high end of the mean values it draws from: the
        decoder's own validation (``model.monitor=val/decoder_fr_psnr`` keeps its best epoch)."""
        lo, hi = self.decoder_mean_range()
        scores = []
        for gamma in self.hparams.get("decoder_sharpness") or [1.0]:
            for u in sorted({lo, (lo + hi) / 2, hi}):
                _, fr_pred = self.reconstruct(self.decoder_masks(g, u, gamma), c)
                scores.append(psnr_per_image(fr_pred, fr))
        return torch.stack(scores).mean(0)

    def validation_step(self, batch, batch_idx):
        self._eval_step(batch, "val")

    def test_step(self, batch, batch_idx):
        self._eval_step(batch, "test")

    def visuals(self, batch):
        c = batch["c"]
        pred = self.predict_im(batch["view"]).float()
        c_rec, fr_pred = self.reconstruct(pred, c)
        titles = ["label IM", "IMS IM", "C-Image", "PR-C-Image (IMS)"]
        tensors = [batch["im"], pred, c, pred * c]
        if fr_pred is not None:
            titles += ["IML/S", "truth"]
            tensors += [fr_pred.clamp(0, 1), batch["fr"]]
        else:
            titles += ["decoder C-Image"]
            tensors += [c_rec.clamp(0, 1)]
        return titles, tensors
