"""Image-quality metrics, in one home: PSNR and SSIM for training logs, evaluation, reports, the
ORP, adaptive and the viewer, so that a report and a training log agree to the last digit.

* PSNR: the direct formula ``10 log10(L^2 / MSE)`` per image, with the MSE floored at
  ``1e-10 L^2`` so that identical images give 100 dB rather than infinity (:func:`psnr_from_mse`,
  :func:`psnr`, :func:`psnr_per_image`). Away from that floor it equals torchmetrics'
  ``peak_signal_noise_ratio(..., dim=(1, 2, 3))`` (checked in ``tests/core/test_metrics.py``).
* SSIM: torchmetrics' ``structural_similarity_index_measure`` (Gaussian window 11, sigma 1.5,
  data range 1; smaller images use the largest odd window that fits) (:func:`ssim_metric`).

The differentiable SSIM *loss* term is :func:`imls_lightning.tasks.losses.ssim`, which matches the
metric to float64 precision and stays exact on constant images.
"""
from __future__ import annotations

import torch
from torchmetrics.functional.image import structural_similarity_index_measure

from imls_lightning.base.errors import InputError

__all__ = ["psnr_from_mse", "psnr", "psnr_per_image", "ssim_metric"]


def psnr_from_mse(mse: torch.Tensor | float, data_range: float = 1.0) -> torch.Tensor:
    """PSNR in dB from a mean squared error (a tensor, elementwise; a Python float is taken in float64).

    Example:
        >>> round(float(psnr_from_mse(0.01)), 6)
        20.0
    """
    mse = mse if isinstance(mse, torch.Tensor) else torch.as_tensor(float(mse), dtype=torch.float64)
    peak = float(data_range) ** 2
    return 10.0 * torch.log10(peak / mse.clamp_min(1e-10 * peak))


def psnr(pred: torch.Tensor, target: torch.Tensor, data_range: float = 1.0, reduction: str = "mean") -> torch.Tensor:
    """Peak signal-to-noise ratio in dB, per image then averaged.

    ``10 log10(L^2 / MSE)`` with the MSE floored at ``1e-10 L^2``, so identical images give 100 dB,
    not infinity. Computed in float32 (float64 stays float64) with autocast disabled.

    Args:
        pred, target: ``(B, C, H, W)``.
        data_range: ``L``, the value span (1 for [0, 1] images, 255 for uint8 values, 2 for [-1, 1]).
        reduction: ``"mean"`` -> scalar, ``"none"`` -> ``(B,)``.

    Example:
        >>> x = torch.zeros(1, 3, 4, 4)
        >>> round(psnr(x + 0.1, x).item(), 3)
        20.0
    """
    if pred.shape != target.shape:
        raise ValueError(f"pred and target must have the same shape, got {tuple(pred.shape)} and {tuple(target.shape)}")
    if pred.dim() != 4:
        raise ValueError(f"expected images of shape (B, C, H, W), got {tuple(pred.shape)}")
    if reduction not in ("mean", "none"):
        raise InputError(f"reduction={reduction!r}: expected 'mean' or 'none'")
    with torch.autocast(device_type=pred.device.type, enabled=False):
        d = pred.float() - target.float() if pred.dtype != torch.float64 else pred - target
        per_image = psnr_from_mse(d.pow(2).flatten(1).mean(1), data_range)
    return per_image.mean() if reduction == "mean" else per_image


def psnr_per_image(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """PSNR in dB of each image of a batch ``(B, C, H, W)`` in [0, 1] -> ``(B,)`` (no gradient).

    ``pred`` is clamped to [0, 1] first (a network's output may overshoot); 100 dB when identical.
    """
    return psnr(pred.detach().float().clamp(0, 1), target.detach().float(), reduction="none")


def ssim_metric(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean SSIM (torchmetrics, Gaussian window 11, data range 1) of a batch ``(B, C, H, W)`` in [0, 1]
    (``pred`` clamped to [0, 1], no gradient); images under 11 pixels use the largest odd window that fits."""
    p = pred.detach().float().clamp(0, 1)
    t = target.detach().float()
    k = 11 if min(p.shape[-2:]) >= 11 else (min(p.shape[-2:]) // 2) * 2 - 1
    return structural_similarity_index_measure(p, t, data_range=1.0, kernel_size=max(k, 3))
