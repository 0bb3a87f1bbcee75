"""imls_lightning.tasks.recnn: the reconstruction loss against direct formulas, and RecNN building."""
from __future__ import annotations

import pytest
import torch
from torchmetrics.functional.image import structural_similarity_index_measure

from imls_lightning.base.errors import InputError
from imls_lightning.models.enhancenet import EnhanceNet
from imls_lightning.core.patterns import downsample_pattern
from imls_lightning.tasks.recnn import build_recnn, reconstruction_loss


def _pair(n=16, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(2, 3, n, n, generator=g), torch.rand(2, 3, n, n, generator=g)


def test_l1_and_mse_against_direct_formulas():
    p, t = _pair()
    assert reconstruction_loss(p, t, "l1", 0.0).item() == pytest.approx((p - t).abs().mean().item())
    assert reconstruction_loss(p, t, "mse", 0.0).item() == pytest.approx(((p - t) ** 2).mean().item())


def test_ssim_term_against_torchmetrics():
    p, t = _pair(16)
    direct = (p - t).abs().mean() + 0.5 * (1 - structural_similarity_index_measure(p, t, data_range=1.0, kernel_size=11))
    assert reconstruction_loss(p, t, "l1", 0.5).item() == pytest.approx(direct.item(), rel=1e-6)
    assert reconstruction_loss(t, t, "mse", 1.0).item() == pytest.approx(0.0, abs=1e-6)


def test_the_recnn_loss_is_the_projects_image_loss():
    """One home for the image loss: the RecNN's is :func:`image_loss` (on images smaller than the SSIM window too)."""
    from imls_lightning.tasks.losses import image_loss

    for n in (16, 8):
        p, t = _pair(n)
        for kind, w in (("l1", 0.5), ("mse", 0.0), ("mse", 1.0)):
            torch.testing.assert_close(reconstruction_loss(p, t, kind, w), image_loss(p, t, kind, w), rtol=0, atol=0)


def test_exception_unknown_loss():
    p, t = _pair()
    with pytest.raises(InputError, match="model.loss='huber'"):
        reconstruction_loss(p, t, "huber", 0.0)


def test_build_recnn_instantiates_the_target_with_the_pattern():
    pat = downsample_pattern(16, 2)
    net = build_recnn({"_target_": "imls_lightning.models.enhancenet.EnhanceNet", "channels": 4, "blocks": 1}, pat)
    assert isinstance(net, EnhanceNet) and net(torch.rand(1, 3, 8, 8)).shape == (1, 3, 16, 16)
    with pytest.raises(InputError, match="_target_"):
        build_recnn({"channels": 4}, pat)
