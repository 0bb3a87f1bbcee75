"""Validation helpers shared by the modules of :mod:`imls_lightning.adaptive`.

``check_integer`` is :func:`imls_lightning.base.validate.check_integer` (the generic validators' one home),
re-exported here for the modules of the package.
"""
from __future__ import annotations

from typing import Any

from imls_lightning.base.validate import check_integer, check_number

from ..core.importance import MEAN_RANGE

__all__ = ["check_integer", "check_epsilon", "clamp_mean"]


def check_epsilon(epsilon_db: Any, key: str = "epsilon_db") -> float:
    """Validate the PSNR tolerance (dB): a finite number ``>= 0``.

    Example:
        >>> check_epsilon(1)
        1.0
    """
    return check_number(epsilon_db, key, 0, what="a finite number of dB >= 0")


def clamp_mean(u: float) -> float:
    """A float32 ``0.01`` is ``0.0099999998``: clamp to the range ``check_mean`` accepts."""
    return min(max(float(u), MEAN_RANGE[0]), MEAN_RANGE[1])
