"""imls_lightning.adaptive.checks: epsilon and mean-value validation."""
from __future__ import annotations

import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.adaptive import bisect_mean, check_epsilon
from imls_lightning.adaptive.checks import MEAN_RANGE, clamp_mean


@pytest.mark.parametrize("eps", [-1.0, float("nan"), float("inf"), "x", True])
def test_exception_bad_epsilon(eps):
    with pytest.raises(InputError, match="epsilon_db"):
        check_epsilon(eps)
    with pytest.raises(InputError, match="epsilon_db"):
        bisect_mean(lambda u: u * 0, 2, eps)


def test_check_epsilon_accepts_finite_non_negative_numbers():
    assert check_epsilon(0) == 0.0 and check_epsilon(1) == 1.0


def test_clamp_mean_clamps_to_the_mean_range():
    lo, hi = MEAN_RANGE
    assert clamp_mean(float(torch.tensor(0.01, dtype=torch.float32))) == lo  # 0.0099999998
    assert clamp_mean(0.5) == 0.5 and clamp_mean(-3) == lo and clamp_mean(7) == hi
