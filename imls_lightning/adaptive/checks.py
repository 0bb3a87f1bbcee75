"""Validation helpers shared by the modules of :mod:`imls_lightning.adaptive`."""
from __future__ import annotations

from typing import Any

from data_gen.errors import InputError, finite_number

from ..importance import MEAN_RANGE


def check_integer(value: Any, key: str, lo: int, hi: int | None = None) -> int:
    """An integer in ``[lo, hi]`` (``hi=None``: no upper bound), else a one-line :class:`InputError` naming ``key``.

    Example:
        >>> check_integer(3.0, "steps", 1, 60)
        3
    """
    what = f"an integer in [{lo}, {hi}]" if hi is not None else f"an integer >= {lo}"
    x = finite_number(value, key, what)
    if x != int(x) or x < lo or (hi is not None and x > hi):
        raise InputError(f"{key}={value!r}: expected {what}")
    return int(x)


def check_epsilon(epsilon_db: Any, key: str = "epsilon_db") -> float:
    """Validate the PSNR tolerance (dB): a finite number ``>= 0``.

    Example:
        >>> check_epsilon(1)
        1.0
    """
    eps = finite_number(epsilon_db, key, "a finite number of dB >= 0")
    if eps < 0:
        raise InputError(f"{key}={epsilon_db!r}: expected a finite number of dB >= 0")
    return eps


def clamp_mean(u: float) -> float:
    """A float32 ``0.01`` is ``0.0099999998``: clamp to the range ``check_mean`` accepts."""
    return min(max(float(u), MEAN_RANGE[0]), MEAN_RANGE[1])
