"""LAS baseline networks (imls_lightning.models.las): shapes, the pull-push inpainting against a
direct loop implementation of LAS's CUDA kernels, IPR control, extremes, and a short training run."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.models.las import LASImportanceNet, LASNet, LASReconstructionNet, downsample_low_res, las_loss

LOW, FR = 8, 32


def tiny_net(**kw) -> LASNet:
    args = dict(mean=0.2, importance_channels=8, importance_blocks=1, importance_border=2,
                recon_channels=8, recon_blocks=1)
    args.update(kw)
    return LASNet(LOW, FR, **args)


def scene_batch(b: int = 2, seed: int = 0) -> torch.Tensor:
    """Smooth synthetic 'renders': a bright blob with an edge on a dark background, (B, 3, FR, FR)."""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, FR), torch.linspace(-1, 1, FR), indexing="ij")
    imgs = []
    for _ in range(b):
        cx, cy, r = (torch.rand(3, generator=g) * torch.tensor([0.8, 0.8, 0.3]) + torch.tensor([-0.4, -0.4, 0.3]))
        blob = torch.sigmoid(12 * (r - ((xx - cx) ** 2 + (yy - cy) ** 2).sqrt()))
        col = torch.rand(3, 1, 1, generator=g) * 0.7 + 0.3
        imgs.append(blob * col)
    return torch.stack(imgs)


# ------------------------------------------------------------------------------------------
# pull-push against a direct implementation
# ------------------------------------------------------------------------------------------


# ------------------------------------------------------------------------------------------
# networks
# ------------------------------------------------------------------------------------------


def test_smoke_shapes_and_positivity():
    imp = LASImportanceNet(LOW, FR, channels=8, blocks=2, border=2)
    out = imp(torch.rand(3, 3, LOW, LOW))
    assert out.shape == (3, 1, FR, FR) and bool((out >= 0).all())
    imp2 = LASImportanceNet(LOW, 3 * LOW * 2, in_channels=4, channels=4, blocks=0, border=0, post_upscale=2)
    assert imp2.net_upscale == 3 and imp2(torch.rand(1, 4, LOW, LOW)).shape == (1, 1, 48, 48)
    for arch in ("enhancenet", "unet"):
        rec = LASReconstructionNet(arch=arch, channels=8, blocks=1, unet_depth=3, unet_channels=4)
        y = rec(torch.rand(2, 3, FR, FR), torch.rand(2, FR, FR) > 0.7)
        assert y.shape == (2, 3, FR, FR) and y.dtype == torch.float32
    net = tiny_net().train()
    fr = scene_batch(2)
    pred, mask, importance = net(downsample_low_res(fr, LOW), fr)
    assert pred.shape == (2, 3, FR, FR) and mask.shape == importance.shape == (2, 1, FR, FR)
    assert bool(((mask > 0) & (mask < 1)).any())  # soft in training
    net.eval()
    _, mask, _ = net(downsample_low_res(fr, LOW), fr)
    assert set(mask.unique().tolist()) <= {0.0, 1.0}  # hard in eval


def test_exceptions():
    with pytest.raises(InputError, match="fr_size"):
        LASImportanceNet(8, 30)
    with pytest.raises(InputError, match="mean"):
        tiny_net(mean=0.0)
    with pytest.raises(InputError, match="mean"):
        tiny_net(mean=1.5)
    with pytest.raises(InputError, match="lower"):
        tiny_net(mean=0.01, lower=0.01)
    with pytest.raises(InputError, match="alpha"):
        tiny_net(alpha=0.0)
    with pytest.raises(InputError, match="arch"):
        LASReconstructionNet(arch="resnet")
    net = tiny_net()
    with pytest.raises(InputError, match="low_res"):
        net.importance_mask(torch.rand(1, 3, 16, 16))
    with pytest.raises(InputError, match="fr_image"):
        net(torch.rand(1, 3, LOW, LOW), torch.rand(1, 3, 16, 16))
    with pytest.raises(InputError, match="ipr"):
        net.importance_mask(torch.rand(1, 3, LOW, LOW), ipr=0.0)
    with pytest.raises(InputError, match="samples"):
        net.reconstruct(torch.rand(1, 3, 16, 16), torch.ones(16, 16, dtype=torch.bool))


def test_normalization_and_sampling_formulas():
    net = tiny_net(lower=0.002, mean=0.3).eval()
    raw = torch.rand(2, 1, FR, FR) * 3
    want = (0.002 + raw * (0.3 - 0.002) / (raw.mean(dim=(1, 2, 3), keepdim=True) + 1e-7)).clamp(max=1)
    got = net.normalize(raw)
    torch.testing.assert_close(got, want)
    torch.testing.assert_close(net.sample(got, hard=True), (want > net.P).float())
    net.train()
    net.pattern_augment = False
    torch.testing.assert_close(net.sample(got, hard=False), torch.sigmoid(50.0 * (want - net.P)))


def test_hard_mask_mean_matches_requested_mean():
    net = tiny_net(mean=0.2).eval()
    fr = scene_batch(4, seed=1)
    low = downsample_low_res(fr, LOW)
    for u in (0.05, 0.2, 0.5):
        out = net.run(low, fr, hard=True, mean=u)
        ipr = out.ipr
        # the plastic pattern realizes the importance's mean up to its (small) discrepancy
        torch.testing.assert_close(ipr, out.importance.mean(dim=(1, 2, 3)), atol=0.01, rtol=0)
        # the clamp at 1 only bites for peaked maps; an untrained net is smooth, so ~ u itself
        assert bool(((ipr - u).abs() < 0.02).all()), (u, ipr)
    # bisection on u hits a requested IPR (what LAS's evaluation does)
    for target in (0.1, 0.33):
        m = net.importance_mask(low, ipr=target)
        assert m.dtype == torch.bool and m.shape == (4, FR, FR)
        assert bool(((m.float().mean(dim=(1, 2)) - target).abs() <= 2.0 / FR**2 + 1e-6).all())
    # a structured (edge) map: the hard mask still realizes mean(importance), and the clamp at 1
    # makes that fall below u once the edges saturate
    gy, gx = torch.gradient(fr.mean(1, keepdim=True), dim=(2, 3))
    raw = (gx**2 + gy**2).sqrt() + 0.01
    for u in (0.05, 0.2, 1.0):
        imp = net.normalize(raw, u)
        ipr = net.sample(imp, hard=True).mean(dim=(1, 2, 3))
        torch.testing.assert_close(ipr, imp.mean(dim=(1, 2, 3)), atol=0.02, rtol=0)
    assert bool((ipr < 0.7).all())
    m = net._mask_for_ipr(raw, 0.3, 30)
    assert bool(((m.float().mean(dim=(1, 2, 3)) - 0.3).abs() <= 2.0 / FR**2 + 1e-6).all())
    # a peaked map cannot reach a high IPR at u <= 1: the u = 1 mask is returned
    raw = torch.zeros(1, 1, FR, FR)
    raw[..., :4, :4] = 1.0
    mask = net._mask_for_ipr(raw, 0.9, 30)
    torch.testing.assert_close(mask, net.sample(net.normalize(raw, 1.0), hard=True).bool())


@pytest.mark.parametrize("mean", [0.01, 1.0])
@pytest.mark.parametrize("inputs", ["zero", "random"])
def test_extremes_finite(mean, inputs):
    net = tiny_net(mean=mean, lower=0.0).train()
    fr = torch.zeros(2, 3, FR, FR) if inputs == "zero" else scene_batch(2)
    low = downsample_low_res(fr, LOW)
    out = net.run(low, fr)
    loss, _ = las_loss(out, fr)
    loss.backward()
    assert all(bool(torch.isfinite(t).all()) for t in (out.fr_pred, out.mask, out.importance))
    assert all(bool(torch.isfinite(p.grad).all()) for p in net.parameters() if p.grad is not None)
    net.eval()
    with torch.no_grad():
        hard = net.run(low, fr)
    assert bool(torch.isfinite(hard.fr_pred).all())
    # empty and full masks run through the reconstruction
    for full in (False, True):
        rec = net.reconstruct(fr, torch.full((FR, FR), full))
        assert bool(torch.isfinite(rec).all()) and rec.min() >= 0 and rec.max() <= 1


def test_bf16_autocast_finite():
    net = tiny_net(mean=0.1).train()
    fr = scene_batch(2)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = net.run(downsample_low_res(fr, LOW), fr)
        loss, _ = las_loss(out, fr)
    loss.backward()
    assert out.mask.dtype == torch.float32 and out.importance.dtype == torch.float32
    assert bool(torch.isfinite(out.fr_pred.float()).all()) and bool(torch.isfinite(loss))
    assert all(bool(torch.isfinite(p.grad).all()) for p in net.parameters() if p.grad is not None)


def test_gradients_reach_the_importance_net():
    net = tiny_net().train()
    fr = scene_batch(2)
    out = net.run(downsample_low_res(fr, LOW), fr)
    loss, terms = las_loss(out, fr, heatmap_weight=0.0)
    loss.backward()
    g = [p.grad for p in net.importance_net.parameters()]
    assert all(x is not None and bool(torch.isfinite(x).all()) for x in g)
    assert sum(float(x.abs().sum()) for x in g) > 0  # through the soft mask and the pull-push
    assert set(terms) == {"l1", "mse", "heatmap"}


def test_inference_api_matches_hard_forward():
    torch.manual_seed(0)
    net = tiny_net(mean=0.25).eval()
    fr = scene_batch(1, seed=3)
    low = downsample_low_res(fr, LOW)
    mask = net.importance_mask(low[0])  # unbatched -> (m, m)
    assert mask.shape == (FR, FR) and mask.dtype == torch.bool
    samples = torch.where(mask, fr[0], torch.zeros(()))  # what a selective renderer returns, scattered
    rec = net.reconstruct(samples, mask)
    with torch.no_grad():
        pred, hard_mask, _ = net(low, fr)
    assert torch.equal(hard_mask[0, 0].bool(), mask)
    torch.testing.assert_close(rec, pred[0].clamp(0, 1))
    # the fixed pattern makes inference deterministic
    assert torch.equal(net.importance_mask(low[0]), mask)


def test_pattern_augmentation_in_training_only():
    net = tiny_net().train()
    imp = torch.full((8, 1, FR, FR), 0.3)
    torch.manual_seed(1)
    soft = net.sample(imp, hard=False)
    # different samples see different (flipped/rotated) patterns, each a permutation of P's values
    assert not all(torch.equal(soft[0], soft[i]) for i in range(1, 8))
    for i in range(8):
        torch.testing.assert_close(soft[i].flatten().sort().values,
                                   torch.sigmoid(50.0 * (0.3 - net.P)).flatten().sort().values)


def test_training_steps_reduce_loss():
    torch.manual_seed(0)
    net = tiny_net(mean=0.3, recon_channels=16, recon_blocks=2).train()
    fr = scene_batch(4, seed=7)
    low = downsample_low_res(fr, LOW)
    opt = torch.optim.Adam(net.parameters(), lr=2e-3)
    losses = []
    for _ in range(25):
        opt.zero_grad()
        loss, _ = las_loss(net.run(low, fr), fr)
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert all(math.isfinite(x) for x in losses)
    assert np.mean(losses[-5:]) < 0.7 * np.mean(losses[:3]), losses


def test_state_dict_round_trip():
    torch.manual_seed(0)
    a = tiny_net(mean=0.15).eval()
    b = tiny_net(mean=0.15).eval()
    b.load_state_dict(a.state_dict())
    assert "P" in a.state_dict()
    fr = scene_batch(1)
    low = downsample_low_res(fr, LOW)
    with torch.no_grad():
        torch.testing.assert_close(a(low, fr)[0], b(low, fr)[0])
