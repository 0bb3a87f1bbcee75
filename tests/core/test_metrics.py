"""The one home of PSNR and SSIM (imls_lightning.core.metrics), against torchmetrics."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torchmetrics.functional.image import peak_signal_noise_ratio, structural_similarity_index_measure

from imls_lightning.core.metrics import psnr, psnr_from_mse, psnr_per_image, ssim_metric


def _pair(shape=(3, 3, 24, 20), seed=0, dtype=torch.float32):
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(shape, generator=g, dtype=dtype)
    y = (x + 0.05 * torch.randn(shape, generator=g, dtype=dtype)).clamp(0, 1)
    return x, y


def test_psnr_per_image_against_torchmetrics():
    x, y = _pair()
    want = peak_signal_noise_ratio(y, x, data_range=1.0, dim=(1, 2, 3), reduction="none")
    torch.testing.assert_close(psnr_per_image(y, x), want)
    torch.testing.assert_close(psnr(y, x), want.mean())
    x64, y64 = _pair(dtype=torch.float64)
    torch.testing.assert_close(psnr(y64 * 255, x64 * 255, data_range=255.0, reduction="none"),
                               peak_signal_noise_ratio(y64, x64, data_range=1.0, dim=(1, 2, 3), reduction="none"))


def test_psnr_per_image_clamps_detaches_and_caps_at_100_db():
    x, y = _pair()
    over = (y + 0.5).requires_grad_()  # a network output may overshoot [0, 1]
    got = psnr_per_image(over, x)
    assert not got.requires_grad
    torch.testing.assert_close(got, psnr_per_image(over.detach().clamp(0, 1), x))
    same = psnr_per_image(x, x)
    assert torch.equal(same, torch.full((3,), 100.0))


def test_psnr_from_mse_float_and_tensor():
    assert float(psnr_from_mse(0.01)) == pytest.approx(20.0, abs=1e-12)
    assert psnr_from_mse(0.01).dtype == torch.float64
    assert float(psnr_from_mse(0.0)) == pytest.approx(100.0)
    assert float(psnr_from_mse(0.25 * 255**2, data_range=255.0)) == pytest.approx(10 * math.log10(4.0))
    t = torch.tensor([1e-2, 1e-4])
    torch.testing.assert_close(psnr_from_mse(t), torch.tensor([20.0, 40.0]))


def test_ssim_metric_is_torchmetrics():
    x, y = _pair()
    torch.testing.assert_close(ssim_metric(y, x), structural_similarity_index_measure(y, x, data_range=1.0, kernel_size=11))
    tiny_x, tiny_y = _pair((1, 3, 6, 9))  # under the 11-pixel window: the largest odd one that fits
    torch.testing.assert_close(ssim_metric(tiny_y, tiny_x),
                               structural_similarity_index_measure(tiny_y, tiny_x, data_range=1.0, kernel_size=5))


def test_evaluation_and_training_logs_agree_to_the_last_digit():
    """The report's per-view numbers (evaluate.image_quality) are the training logs' functions."""
    from imls_lightning.evaluation import image_quality

    g = np.random.default_rng(0)
    truth = g.integers(0, 256, (32, 32, 3), dtype=np.uint8)
    image = np.clip(truth.astype(int) + g.integers(-20, 21, truth.shape), 0, 255).astype(np.uint8)
    p = torch.from_numpy(image).permute(2, 0, 1)[None].float().div(255.0)
    t = torch.from_numpy(truth).permute(2, 0, 1)[None].float().div(255.0)
    q_psnr, q_ssim = image_quality(image, truth)
    assert q_psnr == float(psnr_per_image(p, t)[0])
    assert q_ssim == float(ssim_metric(p, t))
    assert image_quality(truth, truth) == (100.0, pytest.approx(1.0, abs=1e-6))
