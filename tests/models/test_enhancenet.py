"""RecNNs: EnhanceNet (factors, bicubic skip) and static FoVolNet (kernels, pyramid, shapes)."""
from __future__ import annotations

from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

from imls_lightning.base.errors import InputError
from imls_lightning.models.enhancenet import EnhanceNet, bicubic_upsample, prime_factors, regular_grid
from tests.models.helpers import grid_pattern, random_pattern


# ---------------------------------------------------------------- EnhanceNet


@pytest.mark.parametrize("factor", [2, 3, 4])
def test_enhancenet_output_shape_for_factors(factor):
    n = 6
    net = EnhanceNet(grid_pattern(n, factor), channels=4, blocks=2)
    assert net.factor == factor and net.up_factors == prime_factors(factor)
    assert net(torch.rand(2, 3, n, n)).shape == (2, 3, n * factor, n * factor)


def test_prime_factor_upsampling_steps():
    assert prime_factors(4) == [2, 2] and prime_factors(6) == [2, 3] and prime_factors(7) == [7] and prime_factors(1) == []


@pytest.mark.parametrize("factor,offset", [(2, 0), (3, 1), (4, 3)])
def test_enhancenet_zero_residual_equals_bicubic(factor, offset):
    net = EnhanceNet(grid_pattern(5, factor, offset), channels=4, blocks=1)
    with torch.no_grad():
        net.conv_out.weight.zero_()
        net.conv_out.bias.zero_()
    x = torch.rand(2, 3, 5, 5)
    out = net(x)
    torch.testing.assert_close(out, bicubic_upsample(x, factor, (offset, offset)))
    # the skip passes the rendered pixels through exactly (cubic kernel is interpolating)
    torch.testing.assert_close(out[..., offset::factor, offset::factor], x, atol=1e-6, rtol=0)
    if offset == (factor - 1) / 2:  # centred grid: exactly torch's bicubic
        torch.testing.assert_close(out, F.interpolate(x, scale_factor=factor, mode="bicubic"), atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("factor", [1, 2, 3, 4])
def test_bicubic_upsample_centred_against_torch_interpolate(factor):
    x = torch.rand(2, 3, 7, 7)
    want = F.interpolate(x, scale_factor=factor, mode="bicubic", align_corners=False)
    torch.testing.assert_close(bicubic_upsample(x, factor), want, atol=2e-6, rtol=1e-5)


def test_gradcheck_bicubic_upsample():
    x = torch.rand(1, 2, 4, 4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: bicubic_upsample(t, 3, (0, 2)), (x,))


def test_enhancenet_refuses_non_grid_patterns():
    assert regular_grid(grid_pattern(4, 2, 1)) == (2, 1, 1)
    with pytest.raises(InputError, match="downsampling pattern"):
        EnhanceNet(random_pattern(8, 4, 16), channels=2, blocks=0)
    with pytest.raises(InputError, match="downsampling pattern"):
        EnhanceNet(random_pattern(8, 4, 12), channels=2, blocks=0)  # fewer pixels than n*n
    with pytest.raises(ValueError):
        EnhanceNet(grid_pattern(4, 2), channels=2, blocks=0)(torch.rand(1, 1, 5, 5))  # not RGB (any size is a crop)


def test_enhancenet_bf16_autocast_finite_and_float32_skip():
    net = EnhanceNet(grid_pattern(4, 2), channels=4, blocks=1)
    x = torch.rand(1, 3, 4, 4, requires_grad=True)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        y = net(x)
    y.float().sum().backward()
    assert y.dtype == torch.float32 and torch.isfinite(y).all() and torch.isfinite(x.grad).all()


# ---------------------------------------------------------------- FoVolNet


# --- EnhanceNet on training crops (data.crop) ---------------------------------------------------
def test_enhancenet_crop_smoke_bicubic_of_a_crop_is_the_crop_of_the_bicubic_inside():
    from imls_lightning.core.patterns import downsample_pattern

    torch.manual_seed(0)
    net = EnhanceNet(downsample_pattern(32, 2), channels=4, blocks=1).double()
    c = torch.rand(1, 3, 16, 16, dtype=torch.float64)
    y, x, p = 4, 6, 8  # a grid-aligned 8x8 crop of the C-Image = FR window (8, 12) of side 16
    out = net(c[..., y:y + p, x:x + p])
    assert out.shape == (1, 3, 16, 16)
    full, crop = net.bicubic(c), net.bicubic(c[..., y:y + p, x:x + p])
    # away from the crop's border (bicubic taps reach 2 C-pixels) the two agree exactly
    torch.testing.assert_close(crop[..., 4:-4, 4:-4], full[..., 2 * y + 4:2 * (y + p) - 4, 2 * x + 4:2 * (x + p) - 4])


def test_enhancenet_crop_gradcheck():
    from imls_lightning.core.patterns import downsample_pattern

    net = EnhanceNet(downsample_pattern(16, 2), channels=2, blocks=1).double()
    c = torch.rand(1, 3, 4, 4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(net, (c,), eps=1e-6, atol=1e-5)


def test_enhancenet_crop_exception_not_a_c_image():
    from imls_lightning.core.patterns import downsample_pattern

    net = EnhanceNet(downsample_pattern(16, 2), channels=2, blocks=1)
    with pytest.raises(ValueError, match="EnhanceNet: expected a C-Image"):
        net(torch.rand(1, 1, 8, 8))


def _discs(k: int, m: int, seed: int) -> torch.Tensor:
    """``k`` FR-Images of sharp coloured discs on black: bicubic upsampling blurs and rings at their edges."""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.arange(m).float(), torch.arange(m).float(), indexing="ij")
    out = torch.zeros(k, 3, m, m)
    for i in range(k):
        cy, cx, r = (torch.rand(3, generator=g) * torch.tensor([m, m, m / 3]) + torch.tensor([0, 0, 3.0])).tolist()
        out[i] = ((yy - cy) ** 2 + (xx - cx) ** 2 < r * r).float() * torch.rand(3, 1, 1, generator=g)
    return out


def test_enhancenet_trained_with_the_default_loss_learns_beyond_its_bicubic_skip():
    """Regression: with an l1 loss the residual collapsed to a constant and the RecNN was bicubic alone."""
    from omegaconf import OmegaConf

    from imls_lightning.core.patterns import downsample_pattern
    from imls_lightning.tasks.recnn import reconstruction_loss

    default = OmegaConf.load(Path(__file__).resolve().parents[2] / "conf" / "model" / "recnn.yaml").loss
    torch.manual_seed(0)
    net = EnhanceNet(downsample_pattern(32, 2), channels=8, blocks=2)
    train, val = _discs(64, 32, 0), _discs(16, 32, 1)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # small convolutions: one thread is fastest, and immune to a busy machine
    try:
        for step in range(200):
            i = torch.randint(0, 64, (16,))
            loss = reconstruction_loss(net(train[i, :, ::2, ::2]), train[i], default, 0.0)
            opt.zero_grad()
            loss.backward()
            opt.step()
    finally:
        torch.set_num_threads(threads)
    psnr = lambda a: float(10 * torch.log10(1 / ((a.clamp(0, 1) - val) ** 2).mean()))  # noqa: E731
    with torch.no_grad():
        c = val[:, :, ::2, ::2]
        assert psnr(net(c)) > psnr(net.bicubic(c)) + 0.5
        assert float(net.residual(c).std()) > 1e-3
