"""IMS training task (imls_lightning.tasks.ims.IMSTask) and its config (conf/model/ims.yaml).

Unit tests run the real task, networks and Lightning Trainer on synthetic (view, label) batches;
the tests of :func:`~imls_lightning.training.fit.build_task` use a real VTK cache of the procedural
``tiny`` volume and real IML/RecNN checkpoints; the CLI smoke test chains RecNN -> IML end-to-end
-> IMS through ``python -m imls_lightning.train``."""
from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch
import torch.nn.functional as F
from omegaconf import OmegaConf
from torch.utils.data import DataLoader

from imls_lightning.base.errors import InputError
from imls_lightning.core.compaction import compact
from imls_lightning.core.importance import hard_rejection_sample, normalize_importance
from imls_lightning.tasks.losses import discriminator_loss, generator_loss, im_bce_loss
from imls_lightning.models.ims import im_to_target
from imls_lightning.core.patterns import build_pattern, plastic_rank_pattern
from imls_lightning.inference.checkpoints import load_task
from imls_lightning.tasks.base import psnr_per_image
from imls_lightning.tasks.iml import IMLTask
from imls_lightning.tasks.ims import IMSTask, loss_config, pim_to_target, scaled_pim_im
from imls_lightning.tasks.recnn import RecNNTask

ROOT = Path(__file__).resolve().parents[2]
FR = 32
DOWN = {"kind": "downsample", "factor": 2}            # n = 16, no padding
FOVEAL = {"kind": "foveal", "c_size": 16, "sigma": 0.1}  # n = 16, K = 132: zero-padded C-Image
ENHANCE = {"_target_": "imls_lightning.models.enhancenet.EnhanceNet", "channels": 4, "blocks": 1}
NO_PER = {"bce": 1.0, "perceptual": 0.0, "adversarial": 0.01}
SMALL = dict(layers=5, base_channels=8, disc_base_channels=8)

pytestmark = pytest.mark.filterwarnings("ignore:.*does not have many workers.*", "ignore:.*LeafSpec.*")


def iml_hparams(pattern=DOWN, fr=FR, **kw) -> dict:
    return dict(IMLTask(pattern, fr, depth=2, base_channels=4, **kw).hparams)


FOVOL = {"_target_": "imls_lightning.models.fovolnet.FoVolNet", "features": 4, "depth": 2, "base_channels": 4,
         "filter_channels": 4, "levels": 2}


def recnn_hparams(pattern=DOWN) -> dict:
    """A tiny EnhanceNet (downsampling pattern) or FoVolNet (foveal pattern)."""
    return dict(RecNNTask(ENHANCE if pattern["kind"] == "downsample" else FOVOL, pattern, FR).hparams)


def tiny_task(pattern=DOWN, target="im", loss=None, recnn=True, **kw) -> IMSTask:
    args = dict(SMALL, loss=NO_PER if loss is None else loss)
    args.update(kw)
    return IMSTask(pattern, FR, iml_hparams(pattern), target=target,
                   recnn_hparams=recnn_hparams(pattern) if recnn else None, **args)


def synthetic_items(count: int, seed: int, pattern_cfg=DOWN, fr_size: int = FR) -> list[dict]:
    """Views on a sphere; the label is a Gaussian blob whose C-Image position follows the eye
    direction, normalized to mean 0.1 and dithered against P exactly as the IML does. ``fr`` is a
    smooth random image and ``c`` its C-Image (only the metrics read them)."""
    pat = build_pattern(pattern_cfg, fr_size)
    n = pat.c_size
    g = torch.Generator().manual_seed(seed)
    eye = torch.randn(count, 3, generator=g)
    eye = 3.0 * eye / eye.norm(dim=1, keepdim=True)
    views = torch.cat([eye, torch.zeros(count, 3), torch.tensor([0.0, 1.0, 0.0]).expand(count, 3)], 1)
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, n), torch.linspace(-1, 1, n), indexing="ij")
    cx, cy = eye[:, 0] / 3.0, eye[:, 1] / 3.0
    blob = torch.exp(-((xx - cx[:, None, None]) ** 2 + (yy - cy[:, None, None]) ** 2) / 0.15)[:, None]
    pim = normalize_importance(blob + 1e-3, 0.1, valid=pat.valid)
    im = (hard_rejection_sample(pim, plastic_rank_pattern(n)) & pat.valid).float()
    fr = torch.nn.functional.interpolate(torch.rand(count, 3, 8, 8, generator=g), size=(fr_size, fr_size), mode="bilinear")
    c = compact(fr, pat.indices, n)
    return [{"index": i, "view": views[i], "im": im[i], "pim": pim[i], "fr": fr[i], "c": c[i]} for i in range(count)]


def loader(count=16, seed=0, batch_size=8, pattern_cfg=DOWN, shuffle=False, fr_size=FR) -> DataLoader:
    return DataLoader(synthetic_items(count, seed, pattern_cfg, fr_size), batch_size=batch_size, shuffle=shuffle)


def quiet_trainer(**kw) -> L.Trainer:
    args = dict(accelerator="cpu", logger=False, enable_checkpointing=False, enable_progress_bar=False,
                enable_model_summary=False, num_sanity_val_steps=0)
    args.update(kw)
    return L.Trainer(**args)


class StepRecorder(L.Callback):
    """Every training step's logged values (floats)."""

    def __init__(self):
        self.steps: list[dict[str, float]] = []

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
        self.steps.append({k: float(v) for k, v in trainer.callback_metrics.items() if k.endswith("_step")})


# ------------------------------------------------------------------------------------------
# targets and the predicted mask
# ------------------------------------------------------------------------------------------


def test_target_mapping_im_and_pim():
    task_im, task_pim = tiny_task(FOVEAL, "im"), tiny_task(FOVEAL, "pim")
    batch = next(iter(loader(4, pattern_cfg=FOVEAL, batch_size=4)))
    t = task_im.make_target(batch)
    assert set(t.unique().tolist()) <= {-1.0, 1.0}
    torch.testing.assert_close(t, batch["im"] * 2 - 1)
    tp = task_pim.make_target(batch)
    valid = build_pattern(FOVEAL, FR).valid
    torch.testing.assert_close(tp[:, :, valid], (batch["pim"].clamp(0, 1) * 2 - 1)[:, :, valid])
    assert (tp[:, :, ~valid] == -1).all()  # padding: "not important"
    assert pim_to_target(torch.tensor([-0.5, 0.0, 0.5, 1.0, 7.0])).tolist() == [-1.0, -1.0, 0.0, 1.0, 1.0]
    assert im_to_target(torch.tensor([0.0, 1.0])).tolist() == [-1.0, 1.0]


def test_output_to_im_pim_target_dithers_against_P_like_the_IML():
    task = tiny_task(FOVEAL, "pim")
    pat = build_pattern(FOVEAL, FR)
    P = plastic_rank_pattern(16)
    torch.testing.assert_close(task.P, P)
    pim = torch.rand(3, 1, 16, 16, generator=torch.Generator().manual_seed(1))
    pim = torch.where((pim - P).abs() < 1e-4, pim + 2e-4, pim)  # keep away from float ties
    got = task.output_to_im(pim * 2 - 1)
    want = hard_rejection_sample(pim, P) & pat.valid
    assert got.dtype == torch.bool and torch.equal(got, want)
    # the paper's target: sign of the output
    task_im = tiny_task(FOVEAL, "im")
    g = torch.randn(3, 1, 16, 16)
    assert torch.equal(task_im.output_to_im(g), (g > 0) & pat.valid)


@pytest.mark.parametrize("target", ["im", "pim"])
def test_predict_im_follows_the_generator_and_zeroes_padding(target):
    task = tiny_task(FOVEAL, target).eval()
    valid = build_pattern(FOVEAL, FR).valid
    last = [m for m in task.generator.modules() if isinstance(m, torch.nn.ConvTranspose2d)][-1]
    views = torch.randn(4, 9)
    with torch.no_grad():
        last.bias.fill_(20.0)  # tanh -> 1: everything important ...
        im = task.predict_im(views)
        assert im.shape == (4, 1, 16, 16) and im.dtype == torch.bool
        assert torch.equal(im, valid.expand(4, 1, 16, 16))  # ... except the padding
        last.bias.fill_(-20.0)
        assert not task.predict_im(views).any()
        last.bias.zero_()
        g = task.generator(views)
    assert torch.equal(task.predict_im(views), task.output_to_im(g))


# ------------------------------------------------------------------------------------------
# losses: switches and direct formulas
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "loss, terms",
    [
        ({"bce": 1.0, "perceptual": 0.0, "adversarial": 0.0}, {"bce"}),
        ({"mse": 1.0, "perceptual": 0.0, "adversarial": 0.0}, {"mse"}),
        ({"bce": 0.5, "mse": 2.0, "perceptual": 0.0, "adversarial": 0.3}, {"bce", "mse", "adversarial"}),
        ({"perceptual": {"weight": 1.0, "layers": ["relu1_2"]}, "adversarial": 0.0}, {"perceptual"}),
        ({"perceptual": {"weight": 1.0, "layers": ["relu1_2"]}, "adversarial": 0.01}, {"perceptual", "adversarial"}),
    ],
)
def test_loss_switches_select_the_logged_terms(loss, terms):
    torch.manual_seed(0)
    task = tiny_task(loss=loss)
    d0 = {k: v.clone() for k, v in task.discriminator.state_dict().items()}
    rec = StepRecorder()
    quiet_trainer(max_steps=2, limit_val_batches=0, callbacks=[rec]).fit(task, loader(16))
    logged = {k[len("train/"):-len("_step")] for k in rec.steps[-1]}
    all_terms = {"bce", "mse", "perceptual", "adversarial"}
    assert logged & all_terms == terms
    adv = "adversarial" in terms
    assert ("loss_d" in logged) == adv and ("d_real" in logged) == adv
    d_changed = any(not torch.equal(d0[k], v) for k, v in task.discriminator.state_dict().items() if v.is_floating_point())
    assert d_changed == adv  # the discriminator only trains with the adversarial term
    # the generator loss is the weighted sum of the logged terms
    w = task.loss_weights
    step = rec.steps[-1]
    total = sum(w[t] * step[f"train/{t}_step"] for t in terms)
    assert step["train/loss_g_step"] == pytest.approx(total, rel=1e-5)


def test_losses_against_direct_formulas():
    """The terms the task computes are BCE on the pre-tanh logits, MSE, -log D(G), CE of D."""
    torch.manual_seed(0)
    task = tiny_task(loss={"bce": 1.0, "mse": 1.0, "perceptual": 0.0, "adversarial": 1.0}).eval()
    batch = next(iter(loader(4, batch_size=4)))
    g, pre = task.generator(batch["view"], return_pre_tanh=True)
    torch.testing.assert_close(g, torch.tanh(pre))
    target = task.make_target(batch)
    terms = task.im_loss(g, target, pre_tanh=pre)
    y = (target + 1) / 2
    p = torch.sigmoid(2 * pre)  # (tanh(z) + 1) / 2
    bce = -(y * torch.log(p) + (1 - y) * torch.log(1 - p)).mean()
    torch.testing.assert_close(terms["bce"], bce, rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(terms["mse"], ((g - target) ** 2).mean())
    torch.testing.assert_close(terms["bce"], im_bce_loss(pre, target, pre_tanh=True))
    lr, lf = task.discriminator(target), task.discriminator(g)
    torch.testing.assert_close(generator_loss(lf), -torch.log(torch.sigmoid(lf)).mean())
    torch.testing.assert_close(discriminator_loss(lr, lf), -(torch.log(torch.sigmoid(lr)).mean() + torch.log(1 - torch.sigmoid(lf)).mean()))


def test_loss_config_defaults_are_the_papers():
    lc = loss_config(None)
    assert lc["perceptual"]["weight"] == 1.0 and lc["adversarial"] == 0.01 and lc["bce"] == 0 and lc["mse"] == 0
    assert lc["perceptual"]["backbone"] == "vgg16_hed" and lc["perceptual"]["weights"] is None
    assert loss_config(lc) == lc  # idempotent: checkpoints store the normalized form
    yaml = OmegaConf.load(ROOT / "conf" / "model" / "ims.yaml")
    assert loss_config(yaml.loss) == lc
    assert yaml.monitor == "val/im_error" and yaml.lr == 1e-3 and yaml.layers == 8 and yaml.target == "im"


# ------------------------------------------------------------------------------------------
# training with a real Trainer (manual optimization)
# ------------------------------------------------------------------------------------------


def test_smoke_manual_optimization_300_steps_no_nan():
    """Tiny data (16 views, n=16), lr 1e-3, BCE + adversarial: 300 steps stay finite and learn."""
    torch.manual_seed(0)
    task = tiny_task(loss={"bce": 1.0, "mse": 0.5, "perceptual": 0.0, "adversarial": 0.01})
    assert task.automatic_optimization is False
    rec = StepRecorder()
    tr = quiet_trainer(max_steps=600, check_val_every_n_epoch=50, callbacks=[rec])
    tr.fit(task, loader(16, batch_size=8, shuffle=True), loader(8, seed=1))
    assert len(rec.steps) == 300 and tr.global_step == 600  # Lightning counts both optimizers' steps
    for key in ("train/loss_g_step", "train/loss_d_step", "train/bce_step", "train/adversarial_step"):
        vals = np.array([s[key] for s in rec.steps])
        assert np.isfinite(vals).all(), key
    for p in task.parameters():
        assert torch.isfinite(p).all()
    bce = np.array([s["train/bce_step"] for s in rec.steps])
    assert bce[-20:].mean() < 0.8 * bce[:20].mean()
    assert math.isfinite(float(tr.callback_metrics["val/im_error"]))


def test_decoder_finetuning_trains_only_the_decoder_on_the_ims_masks():
    """decoder_lr > 0: the decoder moves (and only it of the frozen passengers), its loss is the IML's
    end-to-end loss on the generator's own hard masks, and it falls; decoder_lr = 0 keeps it frozen."""
    torch.manual_seed(0)
    loss = {"mse": 1.0, "perceptual": 0.0, "adversarial": 0.0}
    frozen = tiny_task(target="pim", loss=loss)
    assert not any(p.requires_grad for p in frozen.iml.parameters()) and len(frozen.configure_optimizers()) == 2
    task = tiny_task(target="pim", loss=loss, decoder_lr=1e-2)
    assert task.finetunes_decoder and len(task.configure_optimizers()) == 3
    assert all(p.requires_grad for p in task.iml.decoder.parameters())
    before = {k: v.clone() for k, v in task.state_dict().items() if k.startswith(("iml.", "recnn."))}
    rec = StepRecorder()
    tr = quiet_trainer(max_steps=3 * 60, check_val_every_n_epoch=100, callbacks=[rec])
    tr.fit(task, loader(16, batch_size=8, shuffle=True), loader(8, seed=1))
    after = task.state_dict()
    moved = {k for k, v in before.items() if not torch.equal(v, after[k])}
    assert moved and all(k.startswith("iml.decoder.") for k in moved), sorted(moved)[:5]
    dec = np.array([s["train/decoder_loss_step"] for s in rec.steps])
    assert np.isfinite(dec).all() and dec[-10:].mean() < dec[:10].mean()
    # the loss is the IML's end-to-end loss on the masks scaled_pim_im makes (direct computation)
    batch = next(iter(loader(4, seed=2)))
    torch.manual_seed(1)
    with torch.no_grad():
        got = task.decoder_loss(task.generator(batch["view"]), batch)
        torch.manual_seed(1)
        u = task._random_means(4, "cpu")
        im = scaled_pim_im(task, task.generator(batch["view"]), u).float()
        c_rec = task.iml.decoder(im * batch["c"], im)
        want = 0.5 * F.mse_loss(c_rec, batch["c"]) + 0.5 * F.mse_loss(task.recnn(c_rec), batch["fr"])
    assert torch.allclose(got, want, rtol=1e-5)


def test_smoke_short_run_with_the_real_perceptual_loss():
    """Default perceptual loss (HED VGG16, relu1_2..relu4_3) + adversarial 0.01 at n = 32."""
    pytest.importorskip("h5py")
    from imls_lightning.models.backbones import hed_weights_path

    try:
        hed_weights_path()
    except InputError as err:
        pytest.skip(f"perceptual backbone not installed: {err}")
    torch.manual_seed(0)
    task = IMSTask(DOWN, 64, iml_hparams(DOWN, 64), layers=6, base_channels=8, disc_base_channels=8)  # n = 32, paper loss
    assert task.loss_weights == {"bce": 0.0, "mse": 0.0, "perceptual": 1.0, "adversarial": 0.01}
    rec = StepRecorder()
    quiet_trainer(max_steps=16, limit_val_batches=1, callbacks=[rec]).fit(
        task, loader(8, batch_size=4, fr_size=64), loader(4, fr_size=64))
    per = np.array([s["train/perceptual_step"] for s in rec.steps])
    assert len(per) == 8 and np.isfinite(per).all() and (per > 0).all()
    assert all(np.isfinite(s["train/loss_g_step"]) for s in rec.steps)


def test_view_normalization_is_fitted_at_fit_start():
    task = tiny_task()
    assert not bool(task.view_norm_fitted)
    items = synthetic_items(16, 0)
    quiet_trainer(max_steps=1, limit_val_batches=0).fit(task, DataLoader(items, batch_size=8))
    views = torch.stack([it["view"] for it in items])
    assert bool(task.view_norm_fitted)
    torch.testing.assert_close(task.generator.view_mean, views.mean(0))
    std = views.std(0, unbiased=False)
    torch.testing.assert_close(task.generator.view_std, torch.where(std < 1e-6, torch.ones_like(std), std))


# ------------------------------------------------------------------------------------------
# metrics
# ------------------------------------------------------------------------------------------


def test_eval_metrics_against_direct_computation():
    torch.manual_seed(0)
    task = tiny_task(FOVEAL)
    items = synthetic_items(6, 3, FOVEAL)
    batch = {k: torch.stack([torch.as_tensor(it[k]) for it in items]) for k in items[0]}
    out = quiet_trainer().validate(task, DataLoader(items, batch_size=6), verbose=False)[0]
    task.eval()
    pred = task.predict_im(batch["view"])
    label = batch["im"] > 0.5
    valid = build_pattern(FOVEAL, FR).valid.expand_as(pred)
    k = int(valid[0].sum())
    acc = ((pred == label) & valid).flatten(1).sum(1) / k
    inter, union = (pred & label).flatten(1).sum(1), (pred | label).flatten(1).sum(1)
    iou = torch.where(union > 0, inter / union.clamp_min(1), torch.ones(6))
    assert out["val/im_accuracy"] == pytest.approx(acc.float().mean().item(), abs=1e-6)
    assert out["val/im_iou"] == pytest.approx(iou.float().mean().item(), abs=1e-6)
    assert out["val/im_error"] == pytest.approx(1 - iou.float().mean().item(), abs=1e-6)
    assert out["val/ipr"] == pytest.approx(pred.flatten(1).sum(1).float().mean().item() / FR**2, abs=1e-7)
    assert out["val/label_ipr"] == pytest.approx(label.flatten(1).sum(1).float().mean().item() / FR**2, abs=1e-7)
    with torch.no_grad():
        fr_pred = task.recnn(task.decoder(pred.float() * batch["c"], pred.float()))
        fr_label = task.recnn(task.decoder(label.float() * batch["c"], label.float()))
    assert out["val/fr_psnr"] == pytest.approx(psnr_per_image(fr_pred, batch["fr"]).mean().item(), rel=1e-5)
    assert out["val/label_fr_psnr"] == pytest.approx(psnr_per_image(fr_label, batch["fr"]).mean().item(), rel=1e-5)
    assert {"val/fr_ssim", "val/label_fr_ssim", "val/c_psnr", "val/loss", "val/bce"} <= set(out)


def test_without_a_recnn_the_fr_metrics_are_skipped_with_one_warning():
    task = tiny_task(recnn=False)
    assert task.recnn is None
    with pytest.warns(UserWarning, match="no RecNN") as rec:
        out = quiet_trainer().validate(task, loader(8, batch_size=4), verbose=False)[0]
    assert sum("no RecNN" in str(w.message) for w in rec) == 1
    assert "val/fr_psnr" not in out and "val/c_psnr" in out and "val/im_iou" in out


def test_visuals_columns():
    task = tiny_task().eval()
    batch = next(iter(loader(2, batch_size=2)))
    titles, tensors = task.visuals(batch)
    assert titles == ["label IM", "IMS IM", "C-Image", "PR-C-Image (IMS)", "IML/S", "truth"]
    assert [tuple(t.shape[1:]) for t in tensors] == [(1, 16, 16)] * 2 + [(3, 16, 16)] * 2 + [(3, FR, FR)] * 2
    titles, _ = tiny_task(recnn=False).eval().visuals(batch)
    assert titles[-1] == "decoder C-Image"


# ------------------------------------------------------------------------------------------
# checkpoints
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("target", ["im", "pim"])
def test_checkpoint_round_trip_gives_identical_masks(tmp_path, target):
    torch.manual_seed(0)
    task = tiny_task(target=target)
    ckpt = L.pytorch.callbacks.ModelCheckpoint(dirpath=tmp_path, monitor="val/im_error", mode="min", save_top_k=1)
    tr = quiet_trainer(max_steps=6, enable_checkpointing=True, callbacks=[ckpt], check_val_every_n_epoch=1)
    tr.fit(task, loader(16, batch_size=8), loader(4))
    tr.save_checkpoint(tmp_path / "last.ckpt")
    back = load_task(tmp_path / "last.ckpt", expect="IMSTask")
    assert isinstance(back, IMSTask) and not back.training and back.target == target
    task.eval()
    views = torch.randn(5, 9) * 2
    assert torch.equal(back.predict_im(views), task.predict_im(views))
    assert bool(back.view_norm_fitted)
    for a, b in ((back.decoder, task.decoder), (back.recnn, task.recnn), (back.generator, task.generator)):
        for (ka, va), (kb, vb) in zip(a.state_dict().items(), b.state_dict().items()):
            assert ka == kb and torch.equal(va, vb)
    torch.testing.assert_close(back.P, task.P)
    assert Path(ckpt.best_model_path).is_file()
    load_task(ckpt.best_model_path, expect="IMSTask")
    with pytest.raises(InputError, match="IMSTask checkpoint, expected a IMLTask"):
        load_task(tmp_path / "last.ckpt", expect="IMLTask")


# ------------------------------------------------------------------------------------------
# exceptions
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"target": "mask"}, "model.target='mask'"),
        ({"loss": {"bce": -1.0}}, "model.loss.bce=-1.0"),
        ({"loss": {"bce": 0.0, "mse": 0.0, "perceptual": 0.0}}, "all 0"),
        ({"loss": {"l1": 1.0}}, "model.loss.l1: unknown"),
        ({"loss": {"perceptual": {"weight": 1.0, "layer": ["relu1_2"]}}}, "model.loss.perceptual.layer: unknown"),
        ({"loss": {"perceptual": {"weight": 1.0, "layers": ["relu9_9"]}}}, "loss.perceptual.layers"),
        ({"loss": {"perceptual": {"weight": 1.0, "backbone": "vgg16", "weights": "/nonexistent/vgg16.pth"}}}, "loss.perceptual.weights=/nonexistent"),
        ({"betas": [0.5, 1.0]}, "model.betas"),
        ({"lr": 0.0}, "model.lr=0.0"),
        ({"decoder_lr": -1e-3, "target": "pim"}, "model.decoder_lr=-0.001"),
        ({"decoder_lr": float("nan"), "target": "pim"}, "model.decoder_lr=nan"),
        ({"decoder_lr": 1e-3, "target": "im"}, "needs model.target=pim"),
        ({"decoder_lr": 1e-3, "target": "pim", "decoder_every": 0}, "model.decoder_every=0"),
        ({"decoder_lr": 1e-3, "target": "pim", "decoder_mean_range": [0.6, 0.2]}, r"model.decoder_mean_range=\[0.6, 0.2\]"),
        ({"decoder_lr": 1e-3, "target": "pim", "decoder_mean_range": "high"}, "model.decoder_mean_range=high"),
    ],
)
def test_exception_bad_settings(kw, match):
    with pytest.raises(InputError, match=match) as err:
        tiny_task(**kw).im_loss  # the weight file is only read when the loss is built
    assert "\n" not in str(err.value)


def test_loading_for_inference_does_not_need_the_perceptual_backbone(tmp_path):
    """A checkpoint trained with a user's VGG16 file loads (and predicts) after that file is gone."""
    from imls_lightning.models.backbones import VGG16Features

    vgg = tmp_path / "vgg16.pth"
    torch.save(VGG16Features().state_dict(), vgg)
    loss = {"perceptual": {"weight": 1.0, "backbone": "vgg16", "weights": str(vgg), "layers": ["relu1_2"]}, "adversarial": 0.0}
    task = tiny_task(loss=loss)
    quiet_trainer(max_steps=1, limit_val_batches=0).fit(task, loader(8))
    assert task.im_loss.perceptual.backbone_name == "vgg16"
    tr = quiet_trainer()
    tr.strategy.connect(task)
    tr.save_checkpoint(tmp_path / "ims.ckpt")
    vgg.unlink()
    back = load_task(tmp_path / "ims.ckpt", expect="IMSTask")
    views = torch.randn(2, 9)
    assert torch.equal(back.predict_im(views), task.eval().predict_im(views))
    with pytest.raises(InputError, match="loss.perceptual.weights=.*file not found"):
        back.im_loss


def test_exception_iml_and_recnn_on_other_patterns():
    with pytest.raises(InputError, match="iml.checkpoint: the IML was trained on another sampling pattern"):
        IMSTask(FOVEAL, FR, iml_hparams(DOWN), **SMALL, loss=NO_PER)
    with pytest.raises(InputError, match="recnn.checkpoint: the RecNN was trained on another"):
        IMSTask(DOWN, FR, iml_hparams(DOWN), recnn_hparams=recnn_hparams(FOVEAL), **SMALL, loss=NO_PER)


# ------------------------------------------------------------------------------------------
# built from the training config (training.build_task): real cache, real checkpoints
# ------------------------------------------------------------------------------------------


# ------------------------------------------------------------------------------------------
# CLI smoke: RecNN -> IML end-to-end -> IMS
# ------------------------------------------------------------------------------------------


FALLBACK_CONF = {  # used only where conf/ lacks these groups (Hydra's own conf/ comes first)
    "scene/tiny.yaml": "name: tiny\nvolume: {kind: procedural, generator: tiny, seed: 0}\ntransfer_function: {auto: true}\n",
    "data/tiny.yaml": "num_views: 24\ntest_views: 4\nresolution: 32\nworkers: 0\ncache_dir: cache\nbatch_size: 4\nloader_workers: 0\n",
    "data/small.yaml": "num_views: 24\ntest_views: 4\nresolution: 32\nworkers: 0\ncache_dir: cache\nbatch_size: 4\n",
    "renderer/vtk.yaml": "name: vtk\n",
}


def _train(args: list[str], tmp_path: Path) -> str:
    extra = tmp_path / "conf_fallback"
    for rel, text in FALLBACK_CONF.items():
        (extra / rel).parent.mkdir(parents=True, exist_ok=True)
        (extra / rel).write_text(text)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-m", "imls_lightning.train", f"hydra.searchpath=[file://{extra}]", "scene=tiny", "data=tiny",
           "++trainer.fast_dev_run=true", f"paths.runs_dir={tmp_path / 'runs'}", f"data.cache_dir={tmp_path / 'cache'}",
           "logger=none", *args]
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
    last = proc.stdout.strip().splitlines()[-1]
    assert last.endswith(".ckpt") and Path(last).is_file(), proc.stdout[-2000:]
    return last


@pytest.mark.slow
@pytest.mark.parametrize("recnn", ["enhancenet", "fovolnet"])
def test_cli_smoke_recnn_then_iml_then_ims(tmp_path, recnn):
    """RecNN (fast_dev_run) -> IML end-to-end with it -> IMS (makes the labels first): exit 0, checkpoint last."""
    rec = _train(["model=recnn", f"recnn={recnn}"], tmp_path)
    iml = _train(["model=iml", f"recnn={recnn}", "model.mode=end_to_end", f"recnn.checkpoint={rec}",
                  "model.depth=2", "model.base_channels=8"], tmp_path)
    ims = _train(["model=ims", f"recnn={recnn}", f"iml.checkpoint={iml}", "model.layers=5", "model.base_channels=8"], tmp_path)
    task = load_task(ims, expect="IMSTask")
    assert task.recnn is not None and task.hparams.recnn_source == "iml.checkpoint"
    assert task.hparams.loss["perceptual"]["weight"] == 1.0 and task.hparams.loss["adversarial"] == 0.01
    assert len(list((tmp_path / "cache").glob("*/labels/iml-*/meta.json"))) == 1
    im = task.predict_im(torch.tensor([[0.0, 0.0, 3.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]]))
    assert im.shape == (1, 1, task.pattern.c_size, task.pattern.c_size)
    # a mismatched pattern is refused with one line and exit status 2
    other = "fovolnet" if recnn == "enhancenet" else "enhancenet"
    cmd = [sys.executable, "-m", "imls_lightning.train", f"hydra.searchpath=[file://{tmp_path / 'conf_fallback'}]", "scene=tiny",
           "data=tiny", "++trainer.fast_dev_run=true", f"paths.runs_dir={tmp_path / 'runs'}", f"data.cache_dir={tmp_path / 'cache'}",
           "logger=none", "model=ims", f"recnn={other}", f"iml.checkpoint={iml}"]
    proc = subprocess.run(cmd, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True, text=True, timeout=600)
    assert proc.returncode == 2 and "error: iml.checkpoint=" in proc.stdout + proc.stderr


def test_exception_errors_name_the_users_keys():
    """Errors named internal keys (base_channels=) instead of the key the user typed (issue 17, minor)."""
    small = {**SMALL, "loss": NO_PER}
    for kw, key in (({"layers": 0}, "model.layers=0"), ({"base_channels": 0}, "model.base_channels=0"),
                    ({"disc_base_channels": 0}, "model.disc_base_channels=0")):
        with pytest.raises(InputError, match=f"^{key}"):
            IMSTask(DOWN, FR, iml_hparams(DOWN), **{**small, **kw})


def test_decoder_mean_range_overrides_the_imls_range_for_the_fine_tuning_means():
    """The fine-tuning means come from ``decoder_mean_range`` when set, else from the IML's range."""
    iml_default = tiny_task(target="pim", decoder_lr=1e-3)
    assert iml_default.hparams.decoder_mean_range is None
    lo, hi = float(iml_default.iml.mean), float(iml_default.iml.mean)   # the tiny IML has no range: its mean
    u = iml_default._random_means(256, "cpu")
    assert torch.allclose(u, torch.full_like(u, lo)) and hi == lo
    task = tiny_task(target="pim", decoder_lr=1e-3, decoder_mean_range=[0.5, 0.9])
    u = task._random_means(4096, "cpu")
    assert float(u.min()) >= 0.5 and float(u.max()) <= 0.9
    assert float(u.min()) < 0.52 and float(u.max()) > 0.88   # uniform over the whole range


def test_shallow_start_hint_names_the_layers_that_start_at_4x4():
    """The paper-scale schedules ran the generator with 5 layers at a 256^2 mask: it started at 16x16,
    the view reaching 65,536 values through one linear layer (BENCHMARKS.md, "ct_head's IMS")."""
    import doctest

    from imls_lightning.models.ims import generator_plan
    from imls_lightning.tasks import ims as ims_module
    from imls_lightning.tasks.ims import shallow_start_hint

    hint = shallow_start_hint(256, 5)
    assert hint.startswith("model.layers=5 starts the IMS generator at 16x16") and "model.layers=7 starts at 4x4" in hint
    assert "\n" not in hint
    assert generator_plan(256, 7)[0] == 4
    # no hint where the start is narrow already, or where no number of layers narrows it (odd sides)
    assert shallow_start_hint(256, 7) is None and shallow_start_hint(64, 5) is None and shallow_start_hint(32, 4) is None
    assert shallow_start_hint(7, 3) is None  # 7 has no factor of 2: every plan starts at 7x7
    assert "model.layers=4 starts at 6x6" in shallow_start_hint(48, 1)
    failures = doctest.DocTestRunner().run(doctest.DocTestFinder().find(shallow_start_hint, globs=vars(ims_module))[0])
    assert failures.attempted > 0 and failures.failed == 0


@pytest.mark.parametrize("layers, hinted", [(1, True), (3, False)])
def test_training_config_with_a_wide_start_gets_the_hint(tiny_checkpoints, layers, hinted, recwarn):
    """The hint comes when a training is configured (config_context), through Hydra's compose API; not when a
    trained checkpoint is loaded. The tiny scene's 16^2 mask: 1 layer starts at 16x16, 3 at 4x4."""
    import warnings

    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    GlobalHydra.instance().clear()
    with initialize_config_dir(str(Path(__file__).resolve().parents[2] / "conf"), version_base="1.3", job_name="hint"):
        cfg = compose("train", overrides=["scene=tiny", "data=tiny", "renderer=numba", "model=ims", "recnn=enhancenet",
                                          f"data.cache_dir={tiny_checkpoints['cache_dir']}",
                                          f"iml.checkpoint={tiny_checkpoints['iml']}", f"model.layers={layers}"])
    warnings.simplefilter("always")
    IMSTask.config_context(cfg)
    hints = [str(w.message) for w in recwarn if "starts the IMS generator" in str(w.message)]
    assert len(hints) == int(hinted), hints
    if hinted:
        assert hints[0].startswith("model.layers=1 starts the IMS generator at 16x16") and "model.layers=3 starts at 4x4" in hints[0]
    recwarn.clear()
    load_task(str(tiny_checkpoints["ims_pim"]), expect="IMSTask", what="ims")  # 5 layers at 16^2: no hint on load either
    assert not [w for w in recwarn if "starts the IMS generator" in str(w.message)]


def test_smoke_ims_trains_on_c_image_only_views(tiny_checkpoints, tmp_path):
    """``data.train_pixels=pattern``: the IMS's own views ray-cast at the C-pixels only (issue 31): a real
    Trainer run labels them, trains the generator and fine-tunes the decoder on the C-Image term, and
    validates on whole frames; nothing is NaN."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from data_gen.cache import ViewImageCache
    from imls_lightning.train import train

    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3", job_name="c_only_ims"):
        cfg = compose("train", overrides=[
            "scene=tiny", "data=tiny", "renderer=numba", f"data.cache_dir={tmp_path / 'cache'}", "data.train_pixels=pattern",
            f"paths.runs_dir={tmp_path / 'runs'}", f"paths.output_dir={tmp_path / 'runs' / 'ims'}", "logger=none",
            "test=false", "trainer.fast_dev_run=true", "trainer.enable_progress_bar=false", "recnn=enhancenet",
            "recnn.net.channels=4", "recnn.net.blocks=1", "model=ims", f"iml.checkpoint={tiny_checkpoints['iml']}",
            "model.layers=5", "model.base_channels=8", "model.target=pim", "model.loss.mse=1.0",
            "model.loss.perceptual.weight=0", "model.loss.adversarial=0", "model.decoder_lr=1e-3"])
    path = train(cfg)["best_checkpoint"]
    task = load_task(path, expect="IMSTask")
    (cache_dir,) = [p for p in (tmp_path / "cache").iterdir() if p.is_dir() and (p / "manifest.json").is_file()]
    cache = ViewImageCache.open(cache_dir)
    assert len(cache.sparse_rows) == len(cache.splits["train"]) > 0
    iml = load_task(tiny_checkpoints["iml"], expect="IMLTask")
    fine, before = task.iml.decoder.state_dict(), iml.iml.decoder.state_dict()
    assert all(torch.isfinite(v).all() for v in fine.values())
    assert any(not torch.equal(fine[k], before[k]) for k in fine if fine[k].is_floating_point())  # the decoder was fine-tuned


def test_decoder_stage_trains_the_decoder_alone_on_the_evaluations_masks():
    """``train_generator=false``: a real Trainer run moves the decoder only (the generator and discriminator taken
    over from another IMS stay bit for bit, in eval mode), on masks sharpened to one of ``decoder_sharpness`` and
    lifted (``decoder_lift``), the masks the evaluation's ORP runs; its loss falls, and ``val/decoder_fr_psnr`` is the
    IML/S + RecNN PSNR on those masks (direct computation)."""
    torch.manual_seed(0)
    loss = {"mse": 1.0, "perceptual": 0.0, "adversarial": 0.0}
    src = tiny_task(target="pim", loss=loss)
    pretrained = {"generator": src.generator.state_dict(), "discriminator": src.discriminator.state_dict()}
    task = tiny_task(target="pim", loss=loss, decoder_lr=1e-2, train_generator=False, init_checkpoint="ims.ckpt",
                     decoder_sharpness=[3, 2], decoder_lift=True, decoder_mean_range=[0.05, 0.3], pretrained=pretrained)
    assert task.hparams.decoder_sharpness == [2.0, 3.0] and not task.trains_generator and bool(task.view_norm_fitted)
    assert not bool(src.view_norm_fitted)  # a generator of its own fits the normalization at fit start
    opt = task.configure_optimizers()
    assert isinstance(opt, torch.optim.Adam) and {id(p) for g in opt.param_groups for p in g["params"]} == {
        id(p) for p in task.iml.decoder.parameters()}
    assert not any(p.requires_grad for p in [*task.generator.parameters(), *task.discriminator.parameters()])
    before = {k: v.clone() for k, v in task.state_dict().items()}
    rec, modes = StepRecorder(), []

    class Modes(L.Callback):
        def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):  # the modes the step ran in
            modes.append((pl_module.generator.training, pl_module.discriminator.training, pl_module.iml.decoder.training))

    tr = quiet_trainer(max_steps=60, check_val_every_n_epoch=100, callbacks=[rec, Modes()])
    tr.fit(task, loader(16, batch_size=8, shuffle=True), loader(8, seed=1))
    assert set(modes) == {(False, False, False)}  # the frozen passengers' normalization layers in inference mode
    after = task.state_dict()
    moved = {k for k, v in before.items() if not torch.equal(v, after[k])}
    assert moved and all(k.startswith("iml.decoder.") for k in moved), sorted(moved)[:5]
    assert all(torch.equal(after[f"generator.{k}"], v) for k, v in src.generator.state_dict().items())
    dec = np.array([s["train/decoder_loss_step"] for s in rec.steps])
    assert len(dec) == 60 and np.isfinite(dec).all() and dec[-10:].mean() < dec[:10].mean()
    # the masks: the head at the drawn sharpness, lifted; the loss on them (the RNG drawn as decoder_loss draws it)
    batch = next(iter(loader(4, seed=2)))
    task.eval()
    with torch.no_grad():
        g = torch.rand(4, 1, 16, 16, generator=torch.Generator().manual_seed(3)) * 2 - 1  # a generator output with structure
        for gamma in (2.0, 3.0):
            want = task.mask_head.with_sharpness(gamma).threshold(g, 0.25, True)
            assert torch.equal(task.decoder_masks(g, 0.25, gamma), want)
        assert not torch.equal(task.decoder_masks(g, 0.25, 3.0), task.mask_head.threshold(g, 0.25))
        torch.manual_seed(5)
        got = task.decoder_loss(g, batch)
        torch.manual_seed(5)
        gamma = [2.0, 3.0][int(torch.randint(2, ()))]
        im = task.decoder_masks(g, task._random_means(4, "cpu"), gamma).float()
        c_rec = task.iml.decoder(im * batch["c"], im)
        want = 0.5 * F.mse_loss(c_rec, batch["c"]) + 0.5 * F.mse_loss(task.recnn(c_rec), batch["fr"])
        assert torch.allclose(got, want, rtol=1e-5)
        scores = []
        for gamma in (2.0, 3.0):
            for u in (0.05, 0.175, 0.3):
                im = task.decoder_masks(g, u, gamma).float()
                scores.append(psnr_per_image(task.recnn(task.iml.decoder(im * batch["c"], im)), batch["fr"]))
        assert torch.allclose(task.decoder_fr_psnr(g, batch["c"], batch["fr"]), torch.stack(scores).mean(0))


@pytest.mark.parametrize("kw, match", [
    ({"train_generator": False, "decoder_lr": 1e-3}, "model.train_generator=false: trains the decoder alone"),
    ({"train_generator": False, "init_checkpoint": "ims.ckpt"}, "model.train_generator=false"),
    ({"train_generator": "no", "decoder_lr": 1e-3}, "model.train_generator=no: expected true or false"),
    ({"decoder_lift": "yes", "decoder_lr": 1e-3}, "model.decoder_lift=yes: expected true or false"),
    ({"decoder_sharpness": 0.5, "decoder_lr": 1e-3}, r"model.decoder_sharpness=0.5: expected a number in \[1, 8\]"),
    ({"decoder_sharpness": [], "decoder_lr": 1e-3}, r"model.decoder_sharpness=\[\]"),
])
def test_exception_bad_decoder_stage_settings(kw, match):
    with pytest.raises(InputError, match=f"^{match}"):
        tiny_task(target="pim", **kw)


def test_cli_decoder_stage_starts_from_a_trained_ims(tiny_checkpoints, tmp_path):
    """The decoder stage through the train CLI's body: ``model.init_checkpoint`` (the product's tiny IMS) gives the
    generator, kept bit for bit, and the decoder, trained further; the run's hash holds the init checkpoint's content.
    An IMS of other networks is refused in one line naming the key."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from imls_lightning.train import train

    def cfg_for(name: str, extra: list[str]):
        GlobalHydra.instance().clear()
        with initialize_config_dir(str(ROOT / "conf"), version_base="1.3", job_name="decoder_stage"):
            return compose("train", overrides=[
                "scene=tiny", "data=tiny", "renderer=numba", f"data.cache_dir={tiny_checkpoints['cache_dir']}",
                f"paths.runs_dir={tmp_path / 'runs'}", f"paths.output_dir={tmp_path / 'runs' / name}", "logger=none",
                "test=false", "trainer.fast_dev_run=true", "trainer.enable_progress_bar=false", "recnn=enhancenet",
                "recnn.net.channels=4", "recnn.net.blocks=1", "model=ims", f"iml.checkpoint={tiny_checkpoints['iml']}",
                "model.layers=5", "model.base_channels=8", "model.target=pim", "model.loss.mse=1.0",
                "model.loss.perceptual.weight=0", "model.loss.adversarial=0", "model.decoder_lr=1e-2",
                "model.train_generator=false", f"model.init_checkpoint={tiny_checkpoints['ims_pim']}",
                "model.decoder_sharpness=[3.0]", "model.decoder_lift=true", *extra])

    path = train(cfg_for("decoder", []))["best_checkpoint"]
    task = load_task(path, expect="IMSTask")
    src = load_task(tiny_checkpoints["ims_pim"], expect="IMSTask")
    assert task.hparams.init_checkpoint == str(tiny_checkpoints["ims_pim"]) and not task.trains_generator
    assert all(torch.equal(v, src.generator.state_dict()[k]) for k, v in task.generator.state_dict().items())
    fine, start = task.iml.decoder.state_dict(), src.iml.decoder.state_dict()
    assert all(torch.isfinite(v).all() for v in fine.values())
    assert any(not torch.equal(fine[k], start[k]) for k in fine if fine[k].is_floating_point())
    with pytest.raises(InputError, match=f"^model.init_checkpoint={tiny_checkpoints['ims_pim']}: its model.layers is 5, this run's 6"):
        train(cfg_for("decoder_other", ["model.layers=6"]))
