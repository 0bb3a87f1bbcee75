"""The smallest setting of a knob whose quality gap stays within epsilon, on any knob (a mean value, a share of C, an
IPR, an object floor's margin): the one home of the operating-point searches' primitives.

* Over settings already measured (a grid, or records): :func:`smallest_within` (which one: the first within in a
  grid swept upward, or the smallest value among those within; what to take where none is) and
  :func:`interpolated_within` (linear between the first within and the setting before it).
* Over a knob a function can be evaluated at: :func:`bisect_monotone`, ``steps`` halvings of ``[lo, hi]`` (in ``log``
  or linear scale) for the knob at which a monotone function reaches a target; on plain numbers, or per element of a
  batch (tensors: every element bisected at once, in the tensors' dtype and on their device).

One comparison everywhere (:func:`within`): a gap is within epsilon when ``gap <= epsilon``, inclusive; a NaN gap
never is (a failed measurement keeps no promise).

Plain Python at import (torch is not imported here): the ORP search's module, which Hydra's plugin scan imports
without torch, uses it; the batched form works with the tensors it is given.

Example:
    >>> smallest_within([3.0, 1.5, 0.5], 1.0).index                     # shares 0.2, 0.4, 0.6: the third
    2
    >>> interpolated_within([0.2, 0.4, 0.6], [3.0, 1.5, 0.5], 1.0)      # the gap reaches 1 dB half-way to 0.6
    0.5
    >>> round(bisect_monotone(lambda u: 10 * (0.2 - u), 0.0, 0.01, 1.0, 20, rising=False).hi, 4)
    0.2
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable

__all__ = ["OTHERWISE", "SCALES", "Within", "within", "smallest_within", "interpolated_within", "Bisection",
           "bisect_monotone"]

#: what :func:`smallest_within` takes where no setting is within epsilon: nothing, the last setting read, the one of
#: the least gap (the first on a tie) or the one whose gap is closest to epsilon (the first on a tie)
OTHERWISE = (None, "last", "least", "closest")
#: where :func:`bisect_monotone` halves its bracket: at the geometric or the arithmetic mean of its ends
SCALES = ("log", "linear")


def within(gap: Any, epsilon: Any) -> Any:
    """Whether ``gap`` is within ``epsilon``: ``gap <= epsilon`` (a NaN gap never is); numbers or tensors.

    Example:
        >>> within(1.0, 1.0), within(1.01, 1.0), within(float("nan"), 1.0)
        (True, False, False)
    """
    return gap <= epsilon


@dataclass(frozen=True)
class Within:
    """What :func:`smallest_within` chose: ``index`` (``None``: nothing), ``found`` (whether it is within epsilon;
    False for a setting taken ``otherwise``) and ``item``, the chosen item itself (``None`` with ``index``)."""

    index: int | None
    found: bool
    item: Any = None


def smallest_within(items: Iterable[Any], epsilon: float, *, gap: Callable[[Any], float] | None = None,
                    value: Callable[[Any], float] | None = None, holds: Callable[[Any], bool] | None = None,
                    otherwise: str | None = None) -> Within:
    """The smallest setting whose gap is within ``epsilon`` (:func:`within`), among measured settings.

    Args:
        items: one per setting: its gap, or a record whose gap ``gap`` reads. Without ``value`` they are the settings
            in ascending order (a grid swept upward) and the first within is taken; they are read lazily, so a
            generator is read (and its records computed) only up to it.
        epsilon: the gap allowed.
        gap: ``item -> gap``; ``None``: the items are the gaps.
        value: ``item -> the setting's value``: the items come in any order and the one of the smallest value among
            those within is taken (the earlier on a tie); every item is read.
        holds: a further condition a setting within must meet (read only where the gap is within).
        otherwise: where none is within (:data:`OTHERWISE`): ``None`` takes nothing; ``"last"`` the last item;
            ``"least"`` the item of the least gap, ``"closest"`` of the gap closest to ``epsilon`` (each the first
            on a tie, over every item).

    Returns:
        :class:`Within`; ``Within(None, False)`` where nothing is taken (no item, or none within and no ``otherwise``).

    Example:
        >>> smallest_within([2.0, 0.9, 0.4], 1.0)
        Within(index=1, found=True, item=0.9)
        >>> smallest_within([2.0, 1.5], 1.0), smallest_within([2.0, 1.5], 1.0, otherwise="last").index
        (Within(index=None, found=False, item=None), 1)
        >>> cands = [{"bound": 0.9, "share": 0.41}, {"bound": 0.6, "share": 0.30}, {"bound": 1.4, "share": 0.2}]
        >>> smallest_within(cands, 1.0, gap=lambda c: c["bound"], value=lambda c: c["share"]).index
        1
        >>> smallest_within([1.6, 1.2, float("nan")], 1.0, otherwise="closest").index
        1
    """
    if otherwise not in OTHERWISE:
        raise ValueError(f"otherwise={otherwise!r}: expected one of {list(OTHERWISE)}")
    read = (lambda item: item) if gap is None else gap
    seen: list[Any] = []
    gaps: list[Any] = []
    held: list[tuple[Any, int]] = []
    for i, item in enumerate(items):
        g = read(item)
        seen.append(item)
        gaps.append(g)
        if within(g, epsilon) and (holds is None or holds(item)):
            if value is None:
                return Within(i, True, item)
            held.append((value(item), i))
    if held:
        i = min(held)[1]
        return Within(i, True, seen[i])
    if not seen or otherwise is None:
        return Within(None, False)
    if otherwise == "last":
        i = len(seen) - 1
    elif otherwise == "least":
        i = min(range(len(gaps)), key=lambda j: (gaps[j], j))
    else:
        i = min(range(len(gaps)), key=lambda j: abs(gaps[j] - epsilon))
    return Within(i, False, seen[i])


def interpolated_within(values: Any, gaps: Any, epsilon: float) -> float | None:
    """The smallest value within ``epsilon`` of a grid swept upward, linear between the first within
    (:func:`smallest_within`) and the value before it: where the gap, read as linear between them, reaches
    ``epsilon``. The first value where it is already within; ``None`` where none is.

    Example:
        >>> interpolated_within([0.2, 0.4], [0.9, 0.1], 1.0), interpolated_within([0.2, 0.4], [3.0, 2.0], 1.0)
        (0.2, None)
    """
    i = smallest_within(gaps, epsilon).index
    if i is None:
        return None
    if i == 0:
        return float(values[0])
    g0, g1 = gaps[i - 1], gaps[i]
    t = (g0 - epsilon) / (g0 - g1)
    return float(values[i - 1] + t * (values[i] - values[i - 1]))


@dataclass
class Bisection:
    """What :func:`bisect_monotone` ends with: the bracket ``(lo, hi)`` (``hi`` reaches the target wherever some
    midpoint did, ``lo`` never does unless it did at the start), ``value_hi`` (the function at ``hi``, where the
    caller gave it at the start; else ``None``) and ``trace``, every midpoint evaluated with its value, in order."""

    lo: Any
    hi: Any
    value_hi: Any = None
    trace: list[tuple[Any, Any]] = field(default_factory=list)


def bisect_monotone(fn: Callable[[Any], Any], target: Any, lo: Any, hi: Any, steps: int, *, scale: str = "log",
                    rising: bool = True, value_hi: Any = None) -> Bisection:
    """The knob at which a monotone ``fn`` reaches ``target``: ``steps`` halvings of ``[lo, hi]``.

    Each step evaluates ``fn`` at the midpoint (``exp((log lo + log hi) / 2)`` with ``scale="log"``, ``(lo + hi) / 2``
    with ``"linear"``) and moves ``hi`` there where it reaches ``target``, else ``lo``. Reaching is
    ``not fn(x) < target`` for a rising ``fn`` (an IPR, a count of pixels) and ``fn(x) <= target`` for a falling one
    (a gap: :func:`within`), so a NaN counts as above every target (reached when rising, not within when falling).
    The ends themselves are not evaluated: a caller that needs to know whether ``hi`` reaches at all, or ``lo``
    already does, evaluates them.

    Args:
        fn: ``knob -> value``; with tensors, ``(B, ...) -> (B, ...)``, one value per element.
        target: a number, or a tensor broadcasting against ``fn``'s values (one target per element).
        lo, hi: the bracket; numbers, or tensors of one shape (every element bisected at once, in their dtype and on
            their device). ``scale="log"`` needs ``lo > 0``.
        steps: halvings; the answer is known to a factor ``(hi / lo) ** (1 / 2 ** steps)`` in log scale.
        scale: :data:`SCALES`.
        rising: whether ``fn`` grows with the knob.
        value_hi: ``fn(hi)`` where the caller measured it: the result's ``value_hi`` is then ``fn`` at the final ``hi``.

    Returns:
        :class:`Bisection`; its ``hi`` is the knob sought.

    Example:
        >>> round(bisect_monotone(lambda u: u * u, 0.04, 0.01, 1.0, 30).hi, 6)
        0.2
        >>> import torch
        >>> b = bisect_monotone(lambda u: u * 2, torch.tensor([0.5, 1.0]), torch.full((2,), 0.01), torch.ones(2), 24)
        >>> [round(x, 4) for x in b.hi.tolist()]
        [0.25, 0.5]
    """
    if scale not in SCALES:
        raise ValueError(f"scale={scale!r}: expected one of {list(SCALES)}")
    log = scale == "log"
    batched = not isinstance(lo, numbers.Real)
    if batched:
        import torch
    trace: list[tuple[Any, Any]] = []
    for _ in range(int(steps)):
        if batched:
            mid = torch.exp(0.5 * (torch.log(lo) + torch.log(hi))) if log else 0.5 * (lo + hi)
        else:
            mid = math.exp(0.5 * (math.log(lo) + math.log(hi))) if log else 0.5 * (lo + hi)
        v = fn(mid)
        trace.append((mid, v))
        if batched:
            ok = ~(v < target) if rising else within(v, target)
            hi = torch.where(ok, mid, hi)
            if value_hi is not None:
                value_hi = torch.where(ok, v, value_hi)
            lo = torch.where(ok, lo, mid)
        elif (not v < target) if rising else within(v, target):
            hi = mid
            if value_hi is not None:
                value_hi = v
        else:
            lo = mid
    return Bisection(lo, hi, value_hi, trace)
