"""U-Net: shapes over depths/sizes, padding and cropping, tiny inputs, stability, user errors."""
from __future__ import annotations

import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.models.unet import UNet, make_norm


@pytest.mark.parametrize(
    "depth,h,w",
    [(1, 5, 7), (2, 8, 8), (3, 20, 13), (3, 37, 29), (4, 8, 8), (5, 16, 16), (5, 33, 40)],
)
def test_smoke_shapes_any_size(depth, h, w):
    net = UNet(3, 2, depth=depth, base_channels=2)
    assert net(torch.rand(2, 3, h, w)).shape == (2, 2, h, w)


def test_smoke_256_at_depth_5():
    net = UNet(3, 1, depth=5, base_channels=2).eval()
    with torch.no_grad():
        assert net(torch.rand(1, 3, 256, 256)).shape == (1, 1, 256, 256)


def test_depth_definition_levels_and_channels():
    net = UNet(3, 1, depth=5, base_channels=32)
    assert net.channels == [32, 64, 128, 256, 512]  # 5 levels, 4 down-steps
    assert len(net.downs) == 4 and len(net.ups) == 4 and net.multiple == 16
    assert UNet(3, 1, depth=6, base_channels=64, max_channels=256).channels == [64, 128, 256, 256, 256, 256]


def test_tiny_input_refused_with_clear_error():
    net = UNet(3, 1, depth=5, base_channels=2)
    with pytest.raises(InputError, match=r"depth=5.*8x8.*16") as err:
        net(torch.rand(1, 3, 8, 8))
    assert "\n" not in str(err.value)


def test_non_divisible_size_is_replicate_padded_then_cropped():
    # documented behaviour, reimplemented: pad bottom/right by replication to a multiple of 2^(depth-1)
    net = UNet(3, 2, depth=3, base_channels=4).eval()
    x = torch.rand(1, 3, 10, 13)
    padded = torch.nn.functional.pad(x, (0, 3, 0, 2), mode="replicate")  # -> 12 x 16
    torch.testing.assert_close(net(x), net(padded)[..., :10, :13])


@pytest.mark.parametrize("up_mode", ["bilinear", "transpose"])
@pytest.mark.parametrize("norm", ["group", "batch", "none"])
def test_smoke_modes_and_norms(up_mode, norm):
    net = UNet(3, 3, depth=3, base_channels=4, up_mode=up_mode, norm=norm)
    assert net(torch.rand(2, 3, 12, 12)).shape == (2, 3, 12, 12)


@pytest.mark.parametrize("kind", ["zero", "constant", "random"])
def test_stability_batch_one_and_bf16_autocast(kind):
    x = {"zero": torch.zeros(1, 3, 16, 16), "constant": torch.full((1, 3, 16, 16), 0.7), "random": torch.rand(1, 3, 16, 16)}[kind]
    net = UNet(3, 1, depth=5, base_channels=4).train()  # bottom level is 1x1
    for autocast in (False, True):
        net.zero_grad()
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
            y = net(x)
        y.float().square().mean().backward()
        assert torch.isfinite(y).all()
        assert all(torch.isfinite(p.grad).all() for p in net.parameters() if p.grad is not None)


def test_group_norm_groups_divide_channels():
    assert make_norm("group", 12, 8).num_groups == 6
    assert make_norm("group", 2, 8).num_groups == 2
    assert make_norm("group", 7, 8).num_groups == 7


@pytest.mark.parametrize(
    "kwargs,match",
    [({"depth": 0}, "depth"), ({"up_mode": "nearest"}, "up_mode"), ({"norm": "layer"}, "norm"), ({"base_channels": 0}, "base_channels")],
)
def test_invalid_parameters_refused(kwargs, match):
    with pytest.raises(InputError, match=match):
        UNet(3, 1, **kwargs)
