"""IMLNet: the composed formulas, padding, stability grid (float32 and bf16 autocast), empty/full
masks through decoder and RecNNs, hard/soft agreement, off-the-shelf decoder attachment, errors."""
from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from imls_lightning.base.errors import InputError
from imls_lightning.core.importance import normalize_importance
from imls_lightning.models.enhancenet import EnhanceNet
from imls_lightning.models.fovolnet import FoVolNet
from imls_lightning.models.iml import FillDecoder, IMLNet, IMLRecNN, PlainDecoder, RefineDecoder, c_share, ipr
from imls_lightning.core.pull_push import pull_push_inpaint
from imls_lightning.core.patterns import SamplingPattern

N = 16


def rank_pattern(n: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return ((torch.randperm(n * n, generator=g) + 1).float() / (n * n)).view(n, n)


def small_iml(n: int = N, **kw) -> IMLNet:
    torch.manual_seed(0)
    args = dict(depth=3, base_channels=4)
    args.update(kw)
    return IMLNet(n, rank_pattern(n), **args)


def grid_pattern(n: int, factor: int) -> SamplingPattern:
    m = n * factor
    ii = torch.arange(n)
    return SamplingPattern("downsample", m, n, ((factor * ii)[:, None] * m + (factor * ii)[None, :]).reshape(-1))


def foveal_pattern(m: int, n: int, k: int) -> SamplingPattern:
    g = torch.Generator().manual_seed(1)
    return SamplingPattern("foveal", m, n, torch.randperm(m * m, generator=g)[:k].sort().values)


# ---------------------------------------------------------------- formulas, composed


def test_forward_against_direct_composition():
    net = small_iml(mean=0.2, alpha=30.0).train()
    c = torch.rand(2, 3, N, N)
    out = net(c)
    pim = F.softplus(net.encoder(c))
    torch.testing.assert_close(out.pim, pim)
    mu = pim.mean(dim=(1, 2, 3), keepdim=True)
    torch.testing.assert_close(out.pim_norm, pim * 0.2 / (mu + 1e-7))
    torch.testing.assert_close(out.im, torch.sigmoid(30.0 * (out.pim_norm - net.sampling.P)))
    torch.testing.assert_close(out.pr_c_image, out.im * c)
    fill = pull_push_inpaint(c, out.im)
    refined = fill + net.decoder.net(torch.cat([fill, out.im], 1))
    torch.testing.assert_close(out.c_recon, out.im * c + (1 - out.im) * refined)
    assert out.pim.shape == out.im.shape == (2, 1, N, N) and out.c_recon.shape == (2, 3, N, N)


def test_hard_at_inference_soft_in_training_and_override():
    net = small_iml()
    c = torch.rand(2, 3, N, N)
    hard = net.eval()(c).im
    assert set(hard.unique().tolist()) <= {0.0, 1.0}
    torch.testing.assert_close(hard, (net(c).pim_norm > net.sampling.P).float())
    soft = net.train()(c).im
    assert ((soft > 0) & (soft < 1)).any()
    assert torch.equal(net.train()(c, hard=True).im, hard)
    assert torch.equal(net.importance(c), hard)
    torch.testing.assert_close(net.decode(hard * c, hard), net.eval()(c).c_recon)


def test_padding_is_never_important_and_excluded_from_the_mean():
    valid = torch.arange(N * N).view(N, N) < 200  # K = 200 of 256, as SamplingPattern.valid
    net = small_iml(valid=valid, mean=1.0).eval()
    c = torch.rand(2, 3, N, N)
    out = net(c)
    assert not out.im[:, :, ~valid].any()
    assert not out.pr_c_image[:, :, ~valid].any()
    torch.testing.assert_close(out.pim_norm, normalize_importance(out.pim, 1.0, valid=valid))
    assert (c_share(out.im, valid) > 0).all()


def test_ipr_and_c_share_against_direct_count():
    im = (torch.rand(3, 1, 8, 8) > 0.6).float()
    valid = torch.arange(64).view(8, 8) < 50
    for b in range(3):
        count = int(im[b].sum())
        assert abs(float(ipr(im, 16)[b]) - count / 256) < 1e-7
        assert abs(float(c_share(im, valid)[b]) - int(im[b, 0][valid].sum()) / 50) < 1e-6
        assert abs(float(c_share(im)[b]) - count / 64) < 1e-6


# ---------------------------------------------------------------- stability grid


def _inputs(kind: str) -> torch.Tensor:
    return {
        "zero": torch.zeros(2, 3, N, N),
        "constant": torch.full((2, 3, N, N), 0.6),
        "random": torch.rand(2, 3, N, N, generator=torch.Generator().manual_seed(3)),
    }[kind]


@pytest.mark.parametrize("mean", [0.01, 1.0])
@pytest.mark.parametrize("alpha", [1.0, 50.0, 1e4])
@pytest.mark.parametrize("kind", ["zero", "constant", "random"])
@pytest.mark.parametrize("autocast", [False, True], ids=["fp32", "bf16"])
def test_stability_grid_outputs_and_gradients_finite(mean, alpha, kind, autocast):
    net = small_iml(mean=mean, alpha=alpha).train()
    c = _inputs(kind)
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
        out = net(c)
        loss = F.mse_loss(out.c_recon.float(), c) + out.im.mean()
    loss.backward()
    for name, t in out._asdict().items():
        assert torch.isfinite(t).all(), name
    assert out.im.dtype == torch.float32 and out.pim_norm.dtype == torch.float32
    grads = [p.grad for p in net.parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    assert any(float(p.grad.abs().sum()) > 0 for p in net.encoder.parameters())  # gradient reaches the encoder
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
        hard = net.eval()(c)
    assert all(torch.isfinite(t).all() for t in hard)


@pytest.mark.parametrize("autocast", [False, True], ids=["fp32", "bf16"])
def test_all_zero_pim_gives_empty_mask_and_finite_gradients(autocast):
    net = small_iml(mean=0.5, alpha=1e4).train()
    with torch.no_grad():  # softplus(-200) underflows to exactly 0 in float32
        net.encoder.head.weight.zero_()
        net.encoder.head.bias.fill_(-200.0)
    c = torch.rand(1, 3, N, N)
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
        out = net(c)
        loss = F.mse_loss(out.c_recon.float(), c)
    loss.backward()
    assert float(out.pim.detach().max()) == 0.0 and float(out.pim_norm.detach().max()) == 0.0
    assert float(ipr(net.eval()(c).im, 2 * N).max()) == 0.0
    assert all(torch.isfinite(p.grad).all() for p in net.parameters() if p.grad is not None)


def test_soft_and_hard_masks_agree_for_large_alpha():
    net = small_iml(alpha=1e5).eval()
    c = torch.rand(2, 3, N, N)
    soft, hard = net(c, hard=False), net(c, hard=True)
    away = (soft.pim_norm - net.sampling.P).abs() > 1e-3
    assert away.float().mean() > 0.9
    assert torch.equal(soft.im[away], hard.im[away])  # sigmoid(+-100) is exactly 0/1 in float32
    net.alpha = 1.0
    assert not torch.equal(net(c, hard=False).im[away], hard.im[away])


# ---------------------------------------------------------------- decoder + RecNN


def _recnns(n: int):
    return {
        "enhancenet": EnhanceNet(grid_pattern(n, 2), channels=4, blocks=1),
        "fovolnet": FoVolNet(foveal_pattern(2 * n, n, n * n - 10), features=4, depth=2, base_channels=4, filter_channels=4),
    }


@pytest.mark.parametrize("recnn_name", ["enhancenet", "fovolnet"])
@pytest.mark.parametrize("mask", ["empty", "full"])
@pytest.mark.parametrize("autocast", [False, True], ids=["fp32", "bf16"])
def test_empty_and_full_mask_through_decoder_and_recnn_are_finite(recnn_name, mask, autocast):
    iml = small_iml()
    model = IMLRecNN(iml, _recnns(N)[recnn_name])
    c = torch.rand(2, 3, N, N, requires_grad=True)
    im = (torch.zeros if mask == "empty" else torch.ones)(2, 1, N, N)
    assert float(ipr(im, 2 * N).max()) == (0.0 if mask == "empty" else 0.25)
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
        fr = model.from_im(c, im)
    fr.float().sum().backward()
    assert fr.shape == (2, 3, 2 * N, 2 * N)
    assert torch.isfinite(fr).all() and torch.isfinite(c.grad).all()


def test_iml_recnn_paths_agree():
    iml = small_iml().eval()
    model = IMLRecNN(iml, _recnns(N)["fovolnet"]).eval()
    c = torch.rand(1, 3, N, N)
    im = iml.importance(c)
    torch.testing.assert_close(model(c), model.from_im(c, im))
    torch.testing.assert_close(model(c), model.from_pr_c_image(im * c, im))


def test_standalone_decoder_attaches_to_a_separately_built_recnn(tmp_path):
    # the paper's off-the-shelf case: train IML alone, reload it, put its decoder before any RecNN
    iml = small_iml(mean=0.3)
    torch.save(iml.state_dict(), tmp_path / "iml.pt")
    recnn = _recnns(N)["enhancenet"]
    torch.save(recnn.state_dict(), tmp_path / "recnn.pt")

    iml2 = IMLNet(N, torch.zeros(N, N), mean=0.3, depth=3, base_channels=4)
    iml2.load_state_dict(torch.load(tmp_path / "iml.pt"))
    assert torch.equal(iml2.sampling.P, iml.sampling.P)  # P travels with the checkpoint
    recnn2 = EnhanceNet(grid_pattern(N, 2), channels=4, blocks=1)
    recnn2.load_state_dict(torch.load(tmp_path / "recnn.pt"))
    c = torch.rand(1, 3, N, N)
    im = iml.eval().importance(c)
    want = recnn(iml.decode(im * c, im))
    got = IMLRecNN(iml2, recnn2).eval()(c)
    torch.testing.assert_close(got, want)


# ---------------------------------------------------------------- decoders


@pytest.mark.parametrize("decoder", ["refine", "plain"])
def test_smoke_decoders(decoder):
    net = small_iml(decoder=decoder).eval()
    c = torch.rand(2, 3, N, N)
    out = net(c)
    assert out.c_recon.shape == (2, 3, N, N) and torch.isfinite(out.c_recon).all()
    assert isinstance(net.decoder, RefineDecoder if decoder == "refine" else PlainDecoder)


def test_refine_decoder_keeps_rendered_pixels_and_is_exact_on_a_full_mask():
    dec = small_iml().decoder
    c = torch.rand(2, 3, N, N)
    torch.testing.assert_close(dec(c, torch.ones(2, 1, N, N)), c, rtol=0, atol=0)
    m = (torch.rand(2, 1, N, N) > 0.7).float()
    out = dec(m * c, m)
    torch.testing.assert_close(out * m, c * m, rtol=0, atol=0)  # the pixels it was given, untouched


def test_refine_decoder_with_zero_correction_is_the_pull_push_fill():
    dec = RefineDecoder(depth=2, base_channels=4)
    torch.nn.init.zeros_(dec.net.head.weight)
    torch.nn.init.zeros_(dec.net.head.bias)
    c = torch.rand(1, 3, N, N)
    m = (torch.rand(1, 1, N, N) > 0.6).float()
    torch.testing.assert_close(dec(m * c, m), pull_push_inpaint(m * c, m))
    torch.testing.assert_close(FillDecoder()(m * c, m), pull_push_inpaint(m * c, m))


def test_fill_decoder_with_a_foveal_pattern_fills_at_the_fr_positions():
    """The evaluation's "IML/S mask + fill" decoder: a foveal C-Image is filled where its pixels sit in the
    picture (fill_c_image), not among its neighbours in memory; a grid pattern is the plain fill."""
    from imls_lightning.core.patterns import downsample_pattern, foveal_pattern
    from imls_lightning.core.pull_push import fill_c_image

    c = torch.rand(1, 3, N, N)
    m = (torch.rand(1, 1, N, N) > 0.6).float()
    fov = foveal_pattern(3 * N, N, None)
    torch.testing.assert_close(FillDecoder(fov)(m * c, m), fill_c_image(m * c, m, fov))
    assert not torch.allclose(FillDecoder(fov)(m * c, m), pull_push_inpaint(m * c, m))
    torch.testing.assert_close(FillDecoder(downsample_pattern(2 * N, 2))(m * c, m), pull_push_inpaint(m * c, m))


def test_refine_decoder_gradcheck():
    dec = RefineDecoder(depth=2, base_channels=2).double()
    c = torch.rand(1, 3, 4, 4, dtype=torch.float64, requires_grad=True)
    m = torch.rand(1, 1, 4, 4, dtype=torch.float64).mul(0.8).add(0.1).requires_grad_(True)
    assert torch.autograd.gradcheck(dec, (c, m))


def test_refine_decoder_filling_at_the_fr_positions_starts_at_the_fair_fill():
    """model.fill=fr: with its zero-initialized correction the refine decoder is the foveal fill at the FR positions
    (the untrained baseline it must beat), the sampled pixels pass through, and without a fill pattern it is the
    C-layout fill the earlier runs were trained on."""
    from imls_lightning.core.patterns import foveal_pattern
    from imls_lightning.core.pull_push import fill_c_image

    fov = foveal_pattern(3 * N, N, None)
    c, m = torch.rand(2, 3, N, N), (torch.rand(2, 1, N, N) > 0.6).float()
    out = RefineDecoder(depth=2, base_channels=4, fill_pattern=fov)(m * c, m)
    torch.testing.assert_close(out, fill_c_image(m * c, m, fov))
    torch.testing.assert_close(out * m, c * m)
    torch.testing.assert_close(RefineDecoder(depth=2, base_channels=4)(m * c, m), pull_push_inpaint(m * c, m))
    # a soft mask and an empty or full one stay finite
    for mask in (torch.zeros_like(m), torch.ones_like(m), torch.rand_like(m)):
        assert torch.isfinite(RefineDecoder(depth=2, base_channels=4, fill_pattern=fov)(c, mask)).all()


def test_refine_decoder_filling_at_the_fr_positions_gradcheck():
    from imls_lightning.core.patterns import foveal_pattern

    torch.manual_seed(0)
    dec = RefineDecoder(depth=2, base_channels=2, fill_pattern=foveal_pattern(16, 6, None)).double()
    torch.nn.init.normal_(dec.net.head.weight, std=0.1)  # a non-zero correction: the U-Net's gradient counts too
    c = torch.rand(1, 3, 6, 6, dtype=torch.float64, requires_grad=True)
    m = torch.rand(1, 1, 6, 6, dtype=torch.float64).mul(0.8).add(0.1).requires_grad_(True)
    assert torch.autograd.gradcheck(dec, (c, m))


def test_uniform_importance_is_the_plastic_blue_noise_mask_without_an_encoder():
    P = rank_pattern(N)
    net = IMLNet(N, P, mean=0.25, depth=2, base_channels=2, importance="uniform").train()
    assert net.encoder is None
    im = net(torch.rand(2, 3, N, N)).im  # always hard, also in training
    torch.testing.assert_close(im, (0.25 > P).float().expand(2, 1, N, N))


def test_straight_through_is_hard_forward_with_the_soft_gradient():
    net = small_iml(straight_through=True).train()
    c = torch.rand(1, 3, N, N)
    out = net(c)
    assert set(out.im.unique().tolist()) <= {0.0, 1.0}
    out.c_recon.sum().backward()
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in net.encoder.parameters())


# ---------------------------------------------------------------- errors


def test_invalid_hyperparameters_refused():
    P = rank_pattern(8)
    for mean in (0.0, 0.005, 1.5):
        with pytest.raises(InputError, match="mean"):
            IMLNet(8, P, mean=mean, depth=2, base_channels=2)
    for alpha in (0.0, -5.0):
        with pytest.raises(InputError, match="alpha"):
            IMLNet(8, P, alpha=alpha, depth=2, base_channels=2)
    with pytest.raises(InputError, match="P"):
        IMLNet(8, rank_pattern(4), depth=2, base_channels=2)
    with pytest.raises(InputError, match="valid"):
        IMLNet(8, P, valid=torch.ones(4, 4, dtype=torch.bool), depth=2, base_channels=2)
    net = IMLNet(8, P, depth=2, base_channels=2)
    with pytest.raises(InputError, match="mean"):
        net.mean = 0.0
    with pytest.raises(InputError, match="alpha"):
        net.alpha = -1.0
    with pytest.raises(InputError, match="c_size"):
        IMLRecNN(net, EnhanceNet(grid_pattern(4, 2), channels=2, blocks=0))
    with pytest.raises(ValueError):
        net(torch.rand(1, 3, 16, 16))  # larger than the C-Image (a smaller one is a training crop)
    with pytest.raises(InputError, match="decoder"):
        IMLNet(8, P, depth=2, base_channels=2, decoder="unet")
    with pytest.raises(InputError, match="importance"):
        IMLNet(8, P, depth=2, base_channels=2, importance="random")


# --- training crops (data.crop) -----------------------------------------------------------------
def test_imlnet_crop_smoke_runs_on_a_smaller_c_image_with_the_window_of_p():
    net = small_iml(16).eval()
    c = torch.rand(2, 3, 8, 8)
    out = net(c, hard=True)
    assert out.im.shape == (2, 1, 8, 8) and out.c_recon.shape == (2, 3, 8, 8)
    assert torch.equal(out.im.bool(), out.pim_norm > net.sampling.P[:8, :8])
    assert torch.isfinite(out.c_recon).all()


def test_imlnet_crop_exception_with_padding():
    valid = torch.ones(16, 16, dtype=torch.bool)
    valid[-1, -4:] = False  # a pattern with padding: a crop would not know where its pixels are
    net = small_iml(16, valid=valid)
    with pytest.raises(ValueError, match=r"IMLNet: expected a C-Image \(B, 3, 16, 16\), got"):
        net(torch.rand(1, 3, 8, 8))
