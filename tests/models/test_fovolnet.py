"""imls_lightning.models.fovolnet: FoVolNet RecNN (kernel prediction, masked downsampling)."""
from __future__ import annotations

import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.core.compaction import decompact
from imls_lightning.models.fovolnet import FoVolNet, apply_pixel_kernels, masked_downsample
from imls_lightning.core.patterns import SamplingPattern
from tests.models.helpers import grid_pattern, random_pattern


def small_fovolnet(pattern, **kw) -> FoVolNet:
    args = dict(features=4, depth=2, base_channels=4, filter_channels=4, levels=3, kernel_size=3)
    args.update(kw)
    return FoVolNet(pattern, **args)


def test_apply_pixel_kernels_against_direct_loop():
    b, c, h, w, k = 2, 3, 5, 6, 3
    img = torch.rand(b, c, h, w)
    kern = torch.softmax(torch.randn(b, k * k, h, w), dim=1)
    got = apply_pixel_kernels(img, kern)
    want = torch.zeros_like(img)
    for y in range(h):
        for x in range(w):
            for i in range(k):
                for j in range(k):
                    yy = min(max(y + i - 1, 0), h - 1)  # replicate border
                    xx = min(max(x + j - 1, 0), w - 1)
                    want[:, :, y, x] += kern[:, i * k + j, y, x, None] * img[:, :, yy, xx]
    torch.testing.assert_close(got, want)


def test_masked_downsample_against_direct_computation_and_empty_blocks():
    img = torch.rand(1, 3, 4, 5)
    wt = torch.zeros(1, 1, 4, 5)
    wt[0, 0, 0, 0] = 1.0
    wt[0, 0, 1, 1] = 0.5
    wt[0, 0, 3, 4] = 1.0
    out, cov = masked_downsample(img, wt)
    assert out.shape == (1, 3, 2, 3) and cov.shape == (1, 1, 2, 3)
    want00 = (img[0, :, 0, 0] * 1.0 + img[0, :, 1, 1] * 0.5) / 1.5
    torch.testing.assert_close(out[0, :, 0, 0], want00)
    torch.testing.assert_close(out[0, :, 1, 2], img[0, :, 3, 4])  # ceil-mode edge block
    assert torch.equal(out[0, :, 0, 1], torch.zeros(3))  # no sample: 0, not NaN
    assert torch.isfinite(out).all()


def test_gradcheck_decompaction_and_kernel_filtering():
    pat = random_pattern(6, 3, 8)
    kern = torch.softmax(torch.randn(1, 9, 6, 6, dtype=torch.float64), dim=1)
    c = torch.rand(1, 1, 3, 3, dtype=torch.float64, requires_grad=True)
    fn = lambda t: apply_pixel_kernels(decompact(t, pat.indices, 6), kern)  # noqa: E731
    assert torch.autograd.gradcheck(fn, (c,))
    wt = pat.mask.double().view(1, 1, 6, 6)
    img = torch.rand(1, 2, 6, 6, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: masked_downsample(t, wt)[0], (img,))


@pytest.mark.parametrize("m,n,k", [(16, 8, 40), (20, 10, 100), (12, 6, 36)])
def test_fovolnet_output_shape_and_normalized_kernels(m, n, k):
    net = small_fovolnet(random_pattern(m, n, k), kernel_size=5)
    out, aux = net.reconstruct(decompact(torch.rand(2, 3, n, n), net.decompaction.indices, m), return_aux=True)
    assert out.shape == (2, 3, m, m)
    assert net(torch.rand(2, 3, n, n)).shape == (2, 3, m, m)
    assert len(aux["kernels"]) == 3 and len(aux["blend"]) == 2
    for kern in aux["kernels"]:
        assert kern.shape[1] == 25 and (kern >= 0).all()
        torch.testing.assert_close(kern.sum(dim=1), torch.ones_like(kern[:, 0]))


def test_fovolnet_kernel_path_preserves_a_constant_image():
    # normalized kernels + convex blends: a constant, fully sampled image is reproduced exactly
    n = 8
    full = SamplingPattern("full", n, n, torch.arange(n * n))
    net = small_fovolnet(full, direct=False)
    out = net(torch.full((2, 3, n, n), 0.7))
    torch.testing.assert_close(out, torch.full_like(out, 0.7))


def test_fovolnet_sees_the_mask_channel_and_decompacts_the_c_image():
    pat = random_pattern(8, 4, 16)
    net = small_fovolnet(pat)
    c = torch.rand(1, 3, 4, 4)
    pr = decompact(c, pat.indices, 8)
    torch.testing.assert_close(net(c), net.reconstruct(pr, pat.mask))
    assert not torch.allclose(net(c), net.reconstruct(pr, torch.ones(8, 8)))


@pytest.mark.parametrize("fill", ["zero", "random"])
def test_fovolnet_bf16_autocast_and_gradients_finite(fill):
    pat = random_pattern(16, 8, 50)
    net = small_fovolnet(pat)
    c = (torch.zeros if fill == "zero" else torch.rand)(1, 3, 8, 8).requires_grad_()
    for autocast in (False, True):
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
            y = net(c)
        y.sum().backward()
        assert y.dtype == torch.float32 and torch.isfinite(y).all() and torch.isfinite(c.grad).all()


def test_fovolnet_invalid_parameters_refused():
    pat = random_pattern(8, 4, 16)
    with pytest.raises(InputError, match="kernel_size"):
        FoVolNet(pat, kernel_size=4)
    with pytest.raises(InputError, match="levels"):
        FoVolNet(pat, levels=0)
    with pytest.raises(InputError, match="depth"):
        FoVolNet(pat, depth=5)  # 8 < 2^4
