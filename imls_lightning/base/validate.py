"""Generic validators of scalar and sequence settings: the one home of "is this a valid integer /
number / triple of numbers" checks.

Every validator returns the value in its canonical type (``int``, ``float``, a tuple) or raises a
one-line :class:`~imls_lightning.base.errors.InputError` of the form ``key=value: expected what``, naming the
setting and what was expected, e.g. ``data.resolution=0: expected an integer >= 1``. Checks that
belong to one domain object (a view, a volume file, a pattern) stay with it and call these.

:func:`~imls_lightning.base.errors.finite_number` and :func:`~imls_lightning.base.errors.boolean` live in
:mod:`imls_lightning.base.errors` (which this module builds on) and are re-exported here.

Example:
    >>> check_integer(3.0, "steps", 1, 60)
    3
    >>> check_number("0.5", "model.mean", 0.01, 1.0)
    0.5
    >>> check_numbers(2, "scene.volume.spacing", 3, lo=0, lo_open=True, broadcast=True)
    (2.0, 2.0, 2.0)
    >>> check_mapping({"name": "vtk"}, "renderer")
    {'name': 'vtk'}
"""
from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np

from .errors import InputError, boolean, finite_number

__all__ = ["check_integer", "check_number", "check_numbers", "check_mapping", "check_frame_memory", "memory_bytes",
           "expected", "shown", "finite_number",
           "boolean"]


def shown(value: Any) -> str:
    """How a value appears in an error message: ``repr`` of its plain Python form.

    NumPy scalars and arrays are shown as the Python numbers and lists they hold (not
    ``np.int64(3)``), tuples as lists.

    Args:
        value: any setting value.

    Returns:
        The text after ``key=`` in a message.

    Example:
        >>> shown(np.int64(3)), shown("8"), shown((1, np.float32(0.5)))
        ('3', "'8'", '[1, 0.5]')
    """
    if isinstance(value, (np.generic, np.ndarray)):
        return repr(value.tolist())
    if isinstance(value, tuple):
        return repr([v.item() if isinstance(v, np.generic) else v for v in value])
    return repr(value)


def expected(key: str, value: Any, what: str) -> InputError:
    """The project's one-line error for a bad setting: ``key=value: expected what`` (to raise).

    Args:
        key: the setting's name, e.g. ``"data.num_views"``.
        value: the value given.
        what: what was expected, e.g. ``"an integer >= 1"``.

    Returns:
        An :class:`~imls_lightning.base.errors.InputError` (not raised).

    Example:
        >>> str(expected("data.num_views", 0, "an integer >= 1"))
        'data.num_views=0: expected an integer >= 1'
    """
    return InputError(f"{key}={shown(value)}: expected {what}")


def renamed_keyword(value: Any, old_value: Any, key: str, old_key: str, where: str) -> Any:
    """The value a caller gave as keyword ``key`` or as ``old_key``, its older name (still read, with a
    ``DeprecationWarning``); ``None`` when neither is given.

    Raises:
        InputError: both are given.

    Example:
        >>> renamed_keyword(0.3, None, "share", "mean", "IMSMaskHead")
        0.3
        >>> with warnings.catch_warnings(record=True) as caught:
        ...     warnings.simplefilter("always")
        ...     renamed_keyword(None, 0.4, "share", "mean", "IMSMaskHead"), caught[0].category.__name__
        (0.4, 'DeprecationWarning')
    """
    if old_value is None:
        return value
    if value is not None:
        raise InputError(f"{where}: {key}={shown(value)} and {old_key}={shown(old_value)}; pass {key} only "
                         f"({old_key} is its older name)")
    warnings.warn(f"{where}: {old_key}= is {key}='s older name; pass {key}=", DeprecationWarning, stacklevel=3)
    return old_value


def _range_text(noun: str, lo, hi, lo_open: bool = False, hi_open: bool = False) -> str:
    if lo is not None and hi is not None:
        return f"{noun} in {'(' if lo_open else '['}{lo}, {hi}{')' if hi_open else ']'}"
    if lo is not None:
        return f"{noun} {'>' if lo_open else '>='} {lo}"
    if hi is not None:
        return f"{noun} {'<' if hi_open else '<='} {hi}"
    return noun


def _outside(x: float, lo, hi, lo_open: bool, hi_open: bool) -> bool:
    return ((lo is not None and (x <= lo if lo_open else x < lo))
            or (hi is not None and (x >= hi if hi_open else x > hi)))


def check_integer(value: Any, key: str, lo: int | None = None, hi: int | None = None, *,
                  strict: bool = False, what: str | None = None) -> int:
    """An integer in ``[lo, hi]`` (``None``: no bound on that side).

    Args:
        value: the setting. Accepted: ``int`` and NumPy integers and, unless ``strict``, any finite
            number or numeric string with an integral value (``3.0``, ``"3"``). A bool never is.
        key: the setting's name, for the message.
        lo: smallest allowed value.
        hi: largest allowed value.
        strict: accept only ``int`` / NumPy integer objects (``3.0`` and ``"3"`` are refused).
        what: the message's "expected ..." text; default ``an integer >= lo`` /
            ``an integer in [lo, hi]``.

    Returns:
        The value as an ``int``.

    Raises:
        InputError: ``key=value: expected what`` (one line).

    Example:
        >>> check_integer(3.0, "steps", 1, 60), check_integer(0, "data.seed", 0)
        (3, 0)
        >>> check_integer(3.0, "resolution", 1, strict=True)
        Traceback (most recent call last):
        ...
        imls_lightning.base.errors.InputError: resolution=3.0: expected an integer >= 1
    """
    what = what or _range_text("an integer", lo, hi)
    if strict:
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise expected(key, value, what)
        x = float(int(value))
    else:
        x = finite_number(value, key, what)
    if x != int(x) or _outside(x, lo, hi, False, False):
        raise expected(key, value, what)
    return int(x)


def check_number(value: Any, key: str, lo: float | None = None, hi: float | None = None, *,
                 lo_open: bool = False, hi_open: bool = False, what: str | None = None) -> float:
    """A finite number in the interval from ``lo`` to ``hi`` (``None``: no bound on that side).

    Args:
        value: the setting: a number or numeric string; a bool, NaN and infinities are refused.
        key: the setting's name, for the message.
        lo: lower bound (included unless ``lo_open``).
        hi: upper bound (included unless ``hi_open``).
        lo_open: exclude ``lo`` itself.
        hi_open: exclude ``hi`` itself.
        what: the message's "expected ..." text; default ``a finite number``, ``a number >= lo``,
            ``a number in [lo, hi)``, ...

    Returns:
        The value as a ``float``.

    Raises:
        InputError: ``key=value: expected what`` (one line).

    Example:
        >>> check_number(0.1, "data.val_fraction", 0, 1, hi_open=True)
        0.1
        >>> check_number(1, "data.val_fraction", 0, 1, hi_open=True)
        Traceback (most recent call last):
        ...
        imls_lightning.base.errors.InputError: data.val_fraction=1: expected a number in [0, 1)
    """
    what = what or (_range_text("a number", lo, hi, lo_open, hi_open) if lo is not None or hi is not None
                    else "a finite number")
    x = finite_number(value, key, what)
    if _outside(x, lo, hi, lo_open, hi_open):
        raise expected(key, value, what)
    return x


def check_numbers(value: Any, key: str, length: int, *, lo: float | None = None, lo_open: bool = False,
                  integer: bool = False, broadcast: bool = False, what: str | None = None) -> tuple:
    """A sequence of exactly ``length`` finite numbers, each ``>= lo`` (``> lo`` when ``lo_open``).

    Args:
        value: a list, tuple or 1-D array (or, with ``broadcast``, one number meaning all of them).
        key: the setting's name, for the message.
        length: how many numbers.
        lo: lower bound of every number (``None``: none).
        lo_open: exclude ``lo`` itself.
        integer: the numbers must be integral (returned as ``int``).
        broadcast: a single number stands for ``length`` equal ones (an isotropic spacing).
        what: the message's "expected ..." text; default ``3 numbers, each >= lo``.

    Returns:
        A tuple of ``length`` floats (ints when ``integer``).

    Raises:
        InputError: ``key=value: expected what`` (one line).

    Example:
        >>> check_numbers([64, 64.0, 32], "scene.volume.dims", 3, lo=2, integer=True)
        (64, 64, 32)
        >>> check_numbers([1, 2], "scene.volume.dims", 3)
        Traceback (most recent call last):
        ...
        imls_lightning.base.errors.InputError: scene.volume.dims=[1, 2]: expected 3 numbers
    """
    noun = f"{length} integers" if integer else f"{length} numbers"
    what = what or (_range_text(noun + ", each", lo, None, lo_open) if lo is not None else noun)
    try:
        ndim = np.ndim(value)
    except ValueError:  # ragged nesting
        raise expected(key, value, what) from None
    if isinstance(value, (str, bytes, bool)) or ndim > 1 or (ndim == 0 and not broadcast):
        raise expected(key, value, what)
    items = [value] * length if ndim == 0 else list(value)
    if len(items) != length:
        raise expected(key, value, what)
    out = []
    for v in items:
        if isinstance(v, (bool, np.bool_)):
            raise expected(key, value, what)
        try:
            x = float(v)
        except (TypeError, ValueError):
            raise expected(key, value, what) from None
        if not np.isfinite(x) or _outside(x, lo, None, lo_open, False) or (integer and x != int(x)):
            raise expected(key, value, what)
        out.append(int(x) if integer else x)
    return tuple(out)


def check_mapping(cfg: Any, key: str, what: str = "a mapping of settings") -> dict[str, Any]:
    """A config node as a plain ``dict``: an OmegaConf ``DictConfig`` (interpolations resolved) or
    any other mapping (copied, one level).

    Args:
        cfg: the node.
        key: the node's name, for the message (``data``, ``renderer``, ``scene``).
        what: the message's "expected ..." text.

    Returns:
        A new ``dict``.

    Raises:
        InputError: ``key: expected what, got <type>`` (one line) for anything else, ``None``
            included (callers that have a default for a missing node handle ``None`` first).

    Example:
        >>> check_mapping([1], "renderer")
        Traceback (most recent call last):
        ...
        imls_lightning.base.errors.InputError: renderer: expected a mapping of settings, got list
    """
    try:
        from omegaconf import DictConfig, OmegaConf

        if isinstance(cfg, DictConfig):
            return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]
    except ImportError:  # pragma: no cover - omegaconf is a dependency
        pass
    if not isinstance(cfg, Mapping):
        raise InputError(f"{key}: expected {what}, got {type(cfg).__name__}")
    return dict(cfg)


def memory_bytes() -> int | None:
    """The memory this process may use: the machine's physical memory, or the cgroup's limit (a container's) where
    that is smaller; ``None`` where neither can be read.

    Example:
        >>> memory_bytes() is None or memory_bytes() > 0
        True
    """
    import os

    try:
        total = int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        total = None
    for limit in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = open(limit).read().strip()
        except OSError:
            continue
        if text.isdigit() and int(text) > 0:
            total = int(text) if total is None else min(total, int(text))
        break
    return total


def _gib(n: float) -> str:
    return f"{n / 2 ** 30:.1f} GiB" if n < 2 ** 40 else f"{n / 2 ** 40:.1f} TiB"


def check_frame_memory(side: int, key: str, bytes_per_pixel: float, what: str, *, total: int | None = None) -> int:
    """Refuse, before anything is allocated, a frame side whose buffers cannot fit in this machine's memory: ``side``
    squared pixels at (at least) ``bytes_per_pixel`` bytes each, against :func:`memory_bytes` (``total`` replaces it).

    Returns:
        ``side``.

    Raises:
        InputError: ``key=side: <what> at side^2 take at least N GiB, more than the M GiB of memory here; expected at
        most <largest side that fits>`` (one line).

    Example:
        >>> check_frame_memory(512, "resolution", 256, "the frames", total=2 ** 33)
        512
        >>> check_frame_memory(100000, "resolution", 256, "the frames", total=2 ** 33)
        Traceback (most recent call last):
        ...
        imls_lightning.base.errors.InputError: resolution=100000: the frames at 100000^2 take at least 2.3 TiB, more than the 8.0 GiB of memory here; expected at most 5792
    """
    total = memory_bytes() if total is None else total
    need = float(side) * float(side) * float(bytes_per_pixel)
    if total is not None and need > total:
        largest = int((total / bytes_per_pixel) ** 0.5)
        raise InputError(f"{key}={side}: {what} at {side}^2 take at least {_gib(need)}, more than the {_gib(total)} of "
                         f"memory here; expected at most {largest}")
    return side
