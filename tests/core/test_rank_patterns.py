"""Rank patterns: void-and-cluster blue noise and the plastic (R2) rank pattern P of LAS."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from imls_lightning.core import rank_patterns as rp
from imls_lightning.core.rank_patterns import blue_noise, plastic_rank_pattern


# --- blue noise --------------------------------------------------------------------------------------


def _low_freq_power_ratio(binary: np.ndarray) -> float:
    """Mean power below 1/8 cycles/pixel relative to white noise of the same density."""
    n = binary.shape[0]
    d = binary.mean()
    power = np.abs(np.fft.fft2(binary - d)) ** 2
    f = np.fft.fftfreq(n)
    r = np.hypot(f[None, :], f[:, None])
    return float(power[(r > 0) & (r < 0.125)].mean() / (n * n * d * (1 - d)))


def test_blue_noise_is_deterministic_and_a_permutation_of_ranks():
    a, b = blue_noise(32, seed=5), blue_noise(32, seed=5)
    assert torch.equal(a, b)
    rp.blue_noise_ranks.cache_clear()  # recomputed, not just the cached array
    assert torch.equal(blue_noise(32, seed=5), a)
    assert not torch.equal(blue_noise(32, seed=6), a)
    assert torch.equal(torch.sort((a * 1024).round().long().flatten()).values, torch.arange(1024))
    assert float(a.min()) == 0.0 and float(a.max()) < 1.0


@pytest.mark.parametrize("density", [0.1, 0.25, 0.5])
def test_blue_noise_has_little_low_frequency_energy(density):
    bn = blue_noise(64, seed=0).numpy()
    white = np.random.default_rng(0).permutation(64 * 64).reshape(64, 64) / (64 * 64)
    assert _low_freq_power_ratio((bn < density).astype(float)) < 0.2
    assert _low_freq_power_ratio((white < density).astype(float)) > 0.6  # the measure can tell


def test_blue_noise_non_square_and_evenly_spread():
    bn = blue_noise((24, 40), seed=1)
    assert bn.shape == (24, 40)
    # every 8x8 block of a 25% threshold holds close to 16 points (white noise: 9..24 on 64x64)
    counts = (bn < 0.25).reshape(3, 8, 5, 8).sum(dim=(1, 3))
    assert int(counts.min()) >= 14 and int(counts.max()) <= 18


# --- plastic rank pattern P --------------------------------------------------------------------------


def _plastic_reference(h: int, w: int) -> np.ndarray:
    """The definition, one point at a time: rank of first visit of k = 1, 2, ..."""
    g = rp.PLASTIC_G
    a1, a2 = 1.0 / g, math.pow(1.0 / g, 2)
    rank = np.zeros((h, w), np.int64)
    filled, k = 0, 0
    while filled < h * w:
        k += 1
        x, y = (0.5 + a1 * k) % 1.0, (0.5 + a2 * k) % 1.0
        row, col = int(math.floor(h * y)), int(math.floor(w * x))
        if rank[row, col] == 0:
            filled += 1
            rank[row, col] = filled
    return rank


@pytest.mark.parametrize("size", [16, (8, 12), (13, 7)])
def test_plastic_matches_a_point_by_point_reimplementation(size):
    h, w = (size, size) if isinstance(size, int) else size
    got = (plastic_rank_pattern(size).double() * (h * w)).round().long().numpy()
    assert np.array_equal(got, _plastic_reference(h, w))


@pytest.mark.parametrize("n", [16, 64, 256])
def test_plastic_values_are_each_rank_once_in_0_1(n):
    p = plastic_rank_pattern(n)
    assert p.shape == (n, n) and p.dtype == torch.float32
    assert float(p.min()) > 0.0 and float(p.max()) == 1.0
    assert torch.equal(torch.sort((p.double() * n * n).round().long().flatten()).values, torch.arange(1, n * n + 1))


def test_plastic_is_deterministic_and_oriented_x_along_columns():
    a = plastic_rank_pattern(16)
    rp._plastic_ranks.cache_clear()
    assert torch.equal(plastic_rank_pattern(16), a)
    # k = 1: x = frac(0.5 + 1/g) = 0.2549 -> col 4, y = frac(0.5 + 1/g^2) = 0.0698 -> row 1
    assert float(a[1, 4]) == 1.0 / 256


def test_plastic_thresholds_are_spread_evenly():
    p = plastic_rank_pattern(64)
    counts = (p <= 0.25).reshape(8, 8, 8, 8).sum(dim=(1, 3))  # 8x8 blocks, 16 expected each
    assert int(counts.min()) >= 13 and int(counts.max()) <= 19  # white noise: 9..24
