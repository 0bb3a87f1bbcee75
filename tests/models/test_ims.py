"""IMS generator / discriminator: shapes over C-Image sizes and layer counts, layer plan, view
normalization, target conventions, stability, user errors."""
from __future__ import annotations

import re

import pytest
import torch
from torch import nn

from imls_lightning.base.errors import InputError
from imls_lightning.models.ims import (IMSDiscriminator, IMSGenerator, IMSMaskHead, MaskAt, generator_plan, im_to_target,
                                      output_to_im)
from tests.models.helpers import reference_ims_mask, reference_lift_to_share, reference_lifted_mask


def views(b: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    eye = torch.randn(b, 3, generator=g)
    eye = 3.0 * eye / eye.norm(dim=1, keepdim=True)
    look = 0.1 * torch.randn(b, 3, generator=g)
    up = torch.tensor([0.0, 1.0, 0.0]).expand(b, 3)
    return torch.cat([eye, look, up], dim=1)


@pytest.mark.parametrize("c_size", [8, 32, 48, 64])
@pytest.mark.parametrize("layers", [1, 4, 8])
def test_generator_output_shape_range_and_layer_count(c_size, layers):
    g = IMSGenerator(c_size, layers=layers, base_channels=2, max_channels=16)
    out = g(views(2))
    assert out.shape == (2, 1, c_size, c_size)
    assert (out.abs() < 1).all()
    assert sum(isinstance(m, nn.ConvTranspose2d) for m in g.modules()) == layers
    assert sum(isinstance(m, nn.BatchNorm2d) for m in g.modules()) == layers - 1


def test_generator_256_at_8_layers():
    g = IMSGenerator(256, layers=8, base_channels=2, max_channels=16).eval()
    with torch.no_grad():
        assert g(views(1)).shape == (1, 1, 256, 256)
    assert (g.start_size, g.doublings, g.extra_layers) == (4, 6, 1)


@pytest.mark.parametrize(
    "c_size,layers,plan",
    [(256, 8, (4, 6, 1)), (64, 8, (4, 4, 3)), (32, 8, (4, 3, 4)), (48, 8, (6, 3, 4)), (7, 8, (7, 0, 7)), (256, 3, (64, 2, 0)), (256, 1, (256, 0, 0))],
)
def test_generator_plan(c_size, layers, plan):
    s0, k, extra = generator_plan(c_size, layers)
    assert (s0, k, extra) == plan and s0 * 2**k == c_size and 1 + k + extra == layers


def test_generator_channels_halve_as_the_side_doubles():
    g = IMSGenerator(64, layers=6, base_channels=4, max_channels=32)
    convs = [m for m in g.modules() if isinstance(m, nn.ConvTranspose2d)]
    assert [c.out_channels for c in convs] == [32, 32, 16, 8, 4, 1]  # 4x4 (capped), 8, 16, 32, 64, extra->1
    assert [c.stride[0] for c in convs] == [1, 2, 2, 2, 2, 1]


def test_view_normalization_is_fitted_and_saved():
    v = views(64)
    g = IMSGenerator(16, layers=3, base_channels=2)
    g.fit_view_normalization(v)
    z = (v - g.view_mean) / g.view_std
    torch.testing.assert_close(z[:, :6].mean(0), torch.zeros(6), atol=1e-5, rtol=0)
    torch.testing.assert_close(z[:, :6].std(0, unbiased=False), torch.ones(6), atol=1e-4, rtol=0)
    assert torch.equal(g.view_std[6:], torch.ones(3))  # constant up vector: std kept at 1
    sd = g.state_dict()
    assert "view_mean" in sd and "view_std" in sd
    g2 = IMSGenerator(16, layers=3, base_channels=2)
    g2.load_state_dict(sd)
    g.eval(), g2.eval()
    torch.testing.assert_close(g2(v[:2]), g(v[:2]))


@pytest.mark.parametrize("c_size", [4, 7, 32, 48, 64])
def test_discriminator_one_logit_per_image(c_size):
    d = IMSDiscriminator(c_size, base_channels=2, max_channels=8)
    out = d(torch.rand(3, 1, c_size, c_size) * 2 - 1)
    assert out.shape == (3,)
    assert isinstance(d.net[-1], nn.Conv2d)  # raw logits: no sigmoid in the module
    assert any(isinstance(m, nn.LeakyReLU) and m.negative_slope == 0.2 for m in d.modules()) or c_size <= 4


def test_target_conventions():
    im = (torch.rand(2, 1, 8, 8) > 0.5).float()
    t = im_to_target(im)
    assert set(t.unique().tolist()) <= {-1.0, 1.0}
    assert torch.equal(output_to_im(t), im)
    assert torch.equal(output_to_im(torch.tanh(5 * t)), im)


@pytest.mark.parametrize("autocast", [False, True], ids=["fp32", "bf16"])
def test_gan_step_gradients_finite(autocast):
    g = IMSGenerator(32, layers=5, base_channels=2, max_channels=16).train()
    d = IMSDiscriminator(32, base_channels=2, max_channels=16).train()
    real = im_to_target((torch.rand(2, 1, 32, 32) > 0.7).float())
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
        fake = g(views(2))
        logits_fake, logits_real = d(fake), d(real)
        bce = nn.functional.binary_cross_entropy_with_logits
        loss = bce(logits_fake.float(), torch.ones(2)) + bce(logits_real.float(), torch.ones(2))
    loss.backward()
    assert torch.isfinite(fake).all() and torch.isfinite(loss)
    for p in list(g.parameters()) + list(d.parameters()):
        assert p.grad is not None and torch.isfinite(p.grad).all()


def test_invalid_parameters_refused():
    with pytest.raises(InputError, match="layers"):
        IMSGenerator(32, layers=0)
    with pytest.raises(InputError, match="c_size"):
        IMSGenerator(0)
    with pytest.raises(InputError, match="view_mean"):
        IMSGenerator(8, view_std=torch.zeros(9))
    with pytest.raises(InputError, match="views"):
        IMSGenerator(8, layers=2).fit_view_normalization(torch.rand(4, 6))
    with pytest.raises(ValueError):
        IMSGenerator(8, layers=2)(torch.rand(2, 6))
    with pytest.raises(ValueError):
        IMSDiscriminator(8)(torch.rand(2, 1, 16, 16))


# ---- IMSMaskHead: the one home of the thresholding ------------------------------------------------------
N = 12


class _Fixed(nn.Module):
    """A stand-in generator: a fixed output per view row (saturated pixels, zeros and a graded band)."""

    def __init__(self, g: torch.Tensor):
        super().__init__()
        self.register_buffer("g", g)

    def forward(self, view: torch.Tensor) -> torch.Tensor:
        return self.g[view[:, 0].long()]


def _outputs(seed: int, b: int = 4) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    g = torch.rand(b, 1, N, N, generator=gen) * 2 - 1
    g[torch.rand(b, 1, N, N, generator=gen) < 0.3] = -1.0   # no importance
    g[torch.rand(b, 1, N, N, generator=gen) < 0.05] = 1.0   # saturated
    g[1] = (g[1] * 4).round() / 4                            # ties
    g[2] = g[2] * 0.2 - 0.8                                  # low PIM': the lift's floor
    return g


@pytest.mark.parametrize("target, lower", [("pim", 0.0), ("pim", 0.02), ("im", 0.0)])
@pytest.mark.parametrize("seed", [0, 1])
def test_mask_head_makes_the_masks_of_the_reference_thresholding(target, lower, seed):
    """Same masks as before the head existed (IMSTask.output_to_im / scaled_pim_im, frozen in
    tests/models/helpers.py), bit for bit: trained mean, a mean per call and per view, plain and lifted."""
    gen = torch.Generator().manual_seed(100 + seed)
    g = _outputs(seed)
    P, valid = torch.rand(N, N, generator=gen), torch.rand(N, N, generator=gen) > 0.15
    head = IMSMaskHead(_Fixed(g), P, valid, target, trained_mean=0.1, lower=lower)
    views = torch.arange(4, dtype=torch.float32)[:, None].expand(4, 9).contiguous()
    ref = dict(P=P, valid=valid.view(1, 1, N, N), target=target, trained_mean=0.1, lower=lower)
    assert torch.equal(head(views), reference_ims_mask(g, **ref))
    if target == "im":
        with pytest.raises(InputError, match="target=pim"):
            head(views, 0.3)
        return
    for lift in (False, True):
        for u in (0.05, 0.1, 0.35, 0.8, 1.0, torch.tensor([0.05, 0.3, 0.9, 1.0])):
            got = head(views, u, lift)
            assert got.dtype == torch.bool and torch.equal(got, reference_ims_mask(g, mean=u, lift=lift, **ref)), (u, lift)
            assert torch.equal(head.at(u if not torch.is_tensor(u) else None, lift)(views),
                               head(views, None if torch.is_tensor(u) else u, lift))
    lifted, plain = head(views, 0.9, True), head(views, 0.9)
    assert int(lifted.sum()) > int(plain.sum()) and not bool((plain & ~lifted).any())  # the lift was exercised
    assert bool(head(views, 1.0, True)[:, :, valid].all()) and not bool(head(views, 1.0, True)[:, :, ~valid].any())


def test_mask_head_is_traceable_and_keeps_no_state():
    g = _outputs(3)
    head = IMSMaskHead(_Fixed(g), torch.rand(N, N), torch.ones(N, N, dtype=torch.bool), "pim", trained_mean=0.2).eval()
    view = torch.full((1, 9), 2.0)  # the low PIM' row: lifted, the floor samples
    first = head(view, 0.9, True)
    assert int(first.sum()) > int(head(view, 0.9).sum())
    assert torch.equal(head(view), head(view)) and torch.equal(head(view, 0.9, True), first)  # calls change nothing
    traced = torch.jit.trace(MaskAt(head, 0.9, lift=True), (view,), check_trace=False)
    assert torch.equal(traced(view), first)
    with pytest.raises(InputError, match="target=pim"):
        MaskAt(IMSMaskHead(_Fixed(g), torch.rand(N, N), torch.ones(N, N, dtype=torch.bool), "im"), 0.5)
    with pytest.raises(InputError, match="model.target"):
        IMSMaskHead(_Fixed(g), torch.rand(N, N), torch.ones(N, N, dtype=torch.bool), "pix")


def test_mask_head_names_its_knob_share_and_still_reads_mean():
    """The share of the C-Image is the head's keyword; ``mean=`` (the paper's normalization mean u, the same number)
    is still read, with a DeprecationWarning, and both at once are refused."""
    g = _outputs(3)
    head = IMSMaskHead(_Fixed(g), torch.rand(N, N), torch.ones(N, N, dtype=torch.bool), "pim", trained_mean=0.2).eval()
    view = torch.full((1, 9), 2.0)
    at_share = head(view, share=0.6, lift=True)
    assert torch.equal(at_share, head(view, 0.6, True)) and not torch.equal(at_share, head(view))
    with pytest.warns(DeprecationWarning, match="mean= is share='s older name"):
        assert torch.equal(head(view, mean=0.6, lift=True), at_share)
    with pytest.warns(DeprecationWarning):
        assert torch.equal(head.threshold(g[2:3], mean=0.6, lift=True), at_share)
    with pytest.raises(InputError, match=r"^IMSMaskHead: share=0.6 and mean=0.6; pass share only"):
        head(view, share=0.6, mean=0.6)


def test_distance_means_picks_each_views_band_and_traces():
    """A mean value per band of camera distance (the by-distance operating point): the band is found by the eye's
    distance from the volume's centre; bands are half-open, closed below; tracing keeps the bands."""
    from imls_lightning.models.ims import DistanceMeans

    sched = DistanceMeans([2.7, 3.0], [0.9, 0.7, 0.5])
    eye = torch.tensor([[2.5, 0, 0], [0, 2.7, 0], [0, 0, 2.99], [0, 3.0, 0], [3.3, 0, 0.1]])
    views = torch.cat([eye, torch.zeros(5, 3), torch.tensor([[0.0, 1.0, 0.0]]).expand(5, 3)], 1)
    assert sched(views).tolist() == pytest.approx([0.9, 0.7, 0.7, 0.5, 0.5])
    assert sched(views).dtype == torch.float32 and DistanceMeans([], [0.4])(views).tolist() == pytest.approx([0.4] * 5)
    traced = torch.jit.trace(sched, (views[:1],), check_trace=False)
    assert torch.equal(traced(views), sched(views))
    for edges, means, needle in (([3.0, 2.7], [0.9, 0.7, 0.5], "expected increasing finite distances"),
                                 ([2.7, float("nan")], [0.9, 0.7, 0.5], "expected increasing finite distances"),
                                 ([2.7], [0.9, 1.5], r"expected numbers in \[0.01, 1\]"),
                                 ([2.7], [0.9], "1 mean values for 1 band edges; expected one more mean than edges")):
        with pytest.raises(InputError, match=r"^by_distance: .*" + needle):
            DistanceMeans(edges, means)


def test_mask_at_distance_means_runs_each_view_at_its_bands_mean():
    from imls_lightning.models.ims import DistanceMeans

    g = _outputs(4)
    head = IMSMaskHead(_Fixed(g), torch.rand(N, N), torch.ones(N, N, dtype=torch.bool), "pim", trained_mean=0.2).eval()
    views = torch.arange(4, dtype=torch.float32)[:, None].expand(4, 9).contiguous()  # eye distances 0, 1.7, 3.5, 5.2
    sched = DistanceMeans([1.0, 4.0], [0.9, 0.5, 0.15])
    u = torch.tensor([0.9, 0.5, 0.5, 0.15])
    for lift in (False, True):
        mask = head.at(sched, lift)
        assert mask.lift == lift and mask.mean is None and mask.by_distance is sched
        assert torch.equal(mask(views), head(views, u, lift))
    traced = torch.jit.trace(head.at(sched, True), (views[:1],), check_trace=False)
    assert torch.equal(traced(views), head(views, u, True))


def test_mask_head_sharpness():
    """sharpness=1 is the paper's head bit for bit; gamma > 1 sharpens the PIM' at the same mean before the rescale
    (the reference: sharpen_importance, then the same thresholding), with and without the lift and by distance; it
    shares the generator, traces, and refuses a binary IM (target=im)."""
    from imls_lightning.core.importance import sharpen_importance
    from imls_lightning.models.ims import DistanceMeans

    g = _outputs(5)
    P, valid = torch.rand(N, N), torch.rand(N, N) > 0.15
    head = IMSMaskHead(_Fixed(g), P, valid, "pim", trained_mean=0.2)
    views = torch.arange(4, dtype=torch.float32)[:, None].expand(4, 9).contiguous()
    assert head.sharpness == 1.0 and torch.equal(head.with_sharpness(1.0)(views, 0.4), head(views, 0.4))
    sharp = head.with_sharpness(3.0)
    assert sharp.generator is head.generator and sharp.P.data_ptr() == head.P.data_ptr() and "sharpness=3.0" in repr(sharp)
    pim = sharpen_importance((g + 1) * 0.5, 3.0, valid.view(1, 1, N, N))
    for u in (0.1, 0.2, 0.5):
        scale = u / 0.2
        want = ((pim * scale > P) | ((g >= 1) & (scale >= 1))) & valid
        assert torch.equal(sharp(views, u), want), u
    assert torch.equal(sharp(views), sharp(views, 0.2))  # the trained mean: the sharpened PIM' as it is
    # at one mean value the low floor loses pixels and the high ranks gain them
    low, high = (g + 1) * 0.5 < 0.3, (g + 1) * 0.5 > 0.7
    plain, sharpened = head(views, 0.5), sharp(views, 0.5)
    assert int((sharpened & low).sum()) < int((plain & low).sum())
    assert int((sharpened & high).sum()) >= int((plain & high).sum())
    lifted = sharp(views, 0.9, True)
    assert float(lifted[:, :, valid].float().mean()) == pytest.approx(0.9, abs=0.06)  # the expected share: 4 x ~120 pixels
    sched = DistanceMeans([1.0], [0.6, 0.3])
    traced = torch.jit.trace(sharp.at(sched, True), (views[:1],), check_trace=False)
    assert torch.equal(traced(views), sharp(views, torch.tensor([0.6, 0.3, 0.3, 0.3]), True))  # eye distances 0, 1.7, 3.5, 5.2
    with pytest.raises(InputError, match="sharpness=2: sharpening the IMS's mask needs model.target=pim"):
        IMSMaskHead(_Fixed(g), P, valid, "im", sharpness=2)
    with pytest.raises(InputError, match=r"sharpness=0.5: expected a number in \[1, 8\]"):
        head.with_sharpness(0.5)


def test_sharpened_masks_are_lifted_below_the_trained_mean_too():
    """A sharpened PIM' saturates at any mean value, so its lifted masks are lifted at every u: the share follows u
    below the trained mean too (before, gamma = 3 on flame_whole gave 14% of C at u = 0.2 and 20% at u = 0.201).
    The reference: the lift of tests/models/helpers.py applied at every u; gamma = 1 keeps the lift above it only."""
    from imls_lightning.core.importance import sharpen_importance

    g = _outputs(6)
    P, valid = torch.rand(N, N), torch.rand(N, N) > 0.15
    head = IMSMaskHead(_Fixed(g), P, valid, "pim", trained_mean=0.2)
    views = torch.arange(4, dtype=torch.float32)[:, None].expand(4, 9).contiguous()
    sharp = head.with_sharpness(3.0)
    pim = sharpen_importance((g + 1) * 0.5, 3.0, valid.view(1, 1, N, N))
    shares = []
    for u in (0.1, 0.15, 0.19):
        scale = u / 0.2
        x = pim * scale
        m, f = reference_lift_to_share(x, torch.full((4,), u), valid)
        want = ((x > P) | reference_lifted_mask(x, m, f, P)) & valid
        got = sharp(views, u, True)
        assert torch.equal(got, want), u
        shares.append(float(got[:, :, valid].float().mean()))
        assert not bool((sharp(views, u) & ~got).any())   # the lift only adds pixels
    assert shares == sorted(shares)
    assert float(sharp(views, 0.19)[:, :, valid].float().mean()) < shares[-1] - 0.01  # the plain rescale fell short
    # the paper's masks (gamma = 1) stay the reference's below the trained mean: no lift there
    for u in (0.1, 0.19):
        assert torch.equal(head(views, u, True), reference_ims_mask(g, P, valid, "pim", mean=u, trained_mean=0.2, lift=True))


def test_mask_head_object_floor():
    """object_floor=(margin, tau) raises each view's u to its object's share (unsharpened PIM' > tau over the valid
    pixels, counted directly) plus the margin before the same thresholding: the reference is the plain head at that
    per-view u, with and without the lift, sharpened too, by distance and traced. No floor leaves the head bit for
    bit; a u already above the floor is unchanged; the trained mean is floored too; margin 1 lifted takes every pixel.
    A binary IM is refused, and so is a bad margin, each in one line."""
    from imls_lightning.models.ims import DistanceMeans

    g = _outputs(7)
    P, valid = torch.rand(N, N), torch.rand(N, N) > 0.15
    head = IMSMaskHead(_Fixed(g), P, valid, "pim", trained_mean=0.2)
    views = torch.arange(4, dtype=torch.float32)[:, None].expand(4, 9).contiguous()
    pim = (g + 1) * 0.5
    obj = torch.tensor([float((pim[b, 0][valid] > 0.3).float().mean()) for b in range(4)])
    assert head.with_object_floor(None).object_floor is None
    assert torch.equal(head.with_object_floor(None)(views, 0.4, True), head(views, 0.4, True))
    for margin in (0.0, 0.1, 0.25):
        floored = head.with_object_floor(margin, 0.3)
        assert floored.generator is head.generator and floored.object_floor == (margin, 0.3)
        assert f"object_floor=({margin}, 0.3)" in repr(floored)
        for u in (0.05, 0.3, 0.9):
            want_u = torch.maximum(torch.full((4,), u), (obj + margin).clamp(max=1.0))
            for lift in (False, True):
                assert torch.equal(floored(views, u, lift), head(views, want_u, lift)), (margin, u, lift)
        assert torch.equal(floored(views), head(views, torch.maximum(torch.full((4,), 0.2), (obj + margin).clamp(max=1.0))))
    high = head.with_object_floor(0.0, 0.3)
    assert float(obj.max()) < 0.95 and torch.equal(high(views, 0.95, True), head(views, 0.95, True))  # above the floor
    assert bool(head.with_object_floor(1.0, 0.3)(views, 0.05, True)[:, :, valid].all())
    # sharpened and floored: the floor reads the unsharpened PIM', the mask is the sharpened head's at the floored u
    both = head.with_sharpness(3.0).with_object_floor(0.1, 0.3)
    assert both.sharpness == 3.0 and both.with_sharpness(2.0).object_floor == (0.1, 0.3)
    want_u = torch.maximum(torch.full((4,), 0.2), (obj + 0.1).clamp(max=1.0))
    assert torch.equal(both(views, 0.2, True), head.with_sharpness(3.0)(views, want_u, True))
    sched = DistanceMeans([1.0], [0.6, 0.1])
    traced = torch.jit.trace(both.at(sched, True), (views[:1],), check_trace=False)
    bands = torch.tensor([0.6, 0.1, 0.1, 0.1])
    assert torch.equal(traced(views), head.with_sharpness(3.0)(views, torch.maximum(bands, (obj + 0.1).clamp(max=1.0)), True))
    with pytest.raises(InputError, match="object_floor=.*needs model.target=pim"):
        IMSMaskHead(_Fixed(g), P, valid, "im", object_floor=(0.1, 0.2))
    with pytest.raises(InputError, match=re.escape("object_floor.margin=-0.5: expected a share of the C-Image in [0, 1]")):
        head.with_object_floor(-0.5)


def test_object_floor_margin_per_band_of_camera_distance():
    """DistanceMeans(edges, means, floor_margins): each view's band's margin (None: no floor there) goes to the head
    through MaskAt, and its masks are the one-margin head's at that view's margin (None: the unfloored head's), traced
    too. Margins per view need a head with an object floor (its tau); a bad list is refused in one line."""
    from imls_lightning.models.ims import DistanceMeans

    g = _outputs(8)
    P, valid = torch.rand(N, N), torch.rand(N, N) > 0.15
    head = IMSMaskHead(_Fixed(g), P, valid, "pim", trained_mean=0.2)
    # four views at distances 0, 1.7, 3.5, 5.2 (the first three coordinates are the eye): bands split at 1 and 4
    views = torch.arange(4, dtype=torch.float32)[:, None].expand(4, 9).contiguous()
    sched = DistanceMeans([1.0, 4.0], [0.6, 0.3, 0.1], [0.25, None, 0.0])
    assert sched.band(views).tolist() == [0, 1, 1, 2] and sched.floor_margin(views).tolist() == [0.25, -1.0, -1.0, 0.0]
    assert DistanceMeans([1.0], [0.6, 0.3]).floor_margin(views) is None
    assert "floor_margins=[0.25, None, 0.0]" in repr(sched)
    floored = head.with_object_floor(0.25, 0.3)
    got = floored.at(sched, True)(views)
    u = sched(views)
    for b, margin in enumerate([0.25, None, None, 0.0]):
        want = head.with_object_floor(margin, 0.3)(views[b:b + 1], u[b:b + 1], True)
        assert torch.equal(got[b:b + 1], want), b
    traced = torch.jit.trace(floored.at(sched, True), (views[:1],), check_trace=False)
    assert torch.equal(traced(views), got)
    with pytest.raises(InputError, match="floor_margin: margins per view need a head with an object_floor"):
        head.at(sched, True)(views)
    for bad, msg in (([0.1, None], "floor_margins=[0.1, None]: expected 3 margins"),
                     ([0.1, 1.5, None], "floor_margins[1]=1.5: expected a share of the C-Image in [0, 1] or null")):
        with pytest.raises(InputError, match=re.escape(msg)):
            DistanceMeans([1.0, 4.0], [0.6, 0.3, 0.1], bad)


def test_mask_head_object_floor_extremes_stay_finite_and_boolean():
    """Saturated and empty generator outputs, no valid pixel, tau near its ends: masks stay boolean, shares in [0, 1]."""
    P = torch.rand(N, N)
    views = torch.arange(3, dtype=torch.float32)[:, None].expand(3, 9).contiguous()
    g = torch.stack([torch.ones(1, N, N), -torch.ones(1, N, N), torch.zeros(1, N, N)])
    for valid in (torch.ones(N, N, dtype=torch.bool), torch.zeros(N, N, dtype=torch.bool)):
        for tau in (1e-6, 0.5, 1 - 1e-6):
            head = IMSMaskHead(_Fixed(g), P, valid, "pim", trained_mean=0.2, object_floor=(0.1, tau))
            for u in (0.01, 1.0):
                im = head(views, u, True)
                assert im.dtype == torch.bool and im.shape == (3, 1, N, N)
                assert not bool((im & ~valid).any())
