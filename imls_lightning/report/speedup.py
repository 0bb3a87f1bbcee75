"""How sure a speed-up is: a bootstrap interval over the timed views (:func:`speedup_interval`).

A row's speed-up is ``mean(RecNN alone's total) / mean(IML/S's total)`` over the views the evaluation timed
(each view's stage times are medians of ``repeats`` runs). The views differ: a close-up keeps more pixels than a
far view. With 6-12 timed views the ratio moves by a few percent with the views drawn, which decides a narrow
pass such as 2.02x against a 2x goal. The interval resamples the timed views (pairs: both methods of a view
stay together) and says how far the ratio moves. It covers the choice of views within one sitting only: a
machine whose ray caster runs at another speed in another sitting moves both totals, and their ratio a little,
which no resampling of one sitting's views can show.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from imls_lightning.base.errors import InputError

from .names import ray_caster_twin

#: resamples of the timed views; 10,000 put the 2.5% and 97.5% quantiles within ~0.002x of their limit
RESAMPLES = 10_000


@dataclass(frozen=True)
class SpeedupInterval:
    """``speedup`` (``sum(slow) / sum(fast)`` over ``views`` paired views) and its percentile bootstrap
    interval ``[low, high]`` at ``confidence``."""

    speedup: float
    low: float
    high: float
    views: int
    confidence: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def text(self) -> str:
        """``1.95–2.09×`` (an en dash); one view gives no spread: ``–``."""
        if self.views < 2 or not (math.isfinite(self.low) and math.isfinite(self.high)):
            return "–"
        return f"{self.low:.2f}–{self.high:.2f}×"


def speedup_interval(slow_ms: Sequence[float], fast_ms: Sequence[float], confidence: float = 0.95,
                     resamples: int = RESAMPLES, seed: int = 0) -> SpeedupInterval:
    """The speed-up of ``fast`` over ``slow`` on paired views, with a percentile bootstrap interval.

    ``speedup = sum(slow) / sum(fast)`` (the ratio of the mean totals, as a row reports it). Each resample draws
    the ``n`` views with replacement, a view's two totals together, and takes the same ratio; ``low`` and
    ``high`` are the ``(1 - confidence) / 2`` and ``(1 + confidence) / 2`` quantiles of the resampled ratios.
    One view gives no spread: ``low = high = speedup``. The seed is fixed, so a report repeats.

    Args:
        slow_ms: ``(n,)`` per-view totals (ms) of the reference, e.g. the RecNN alone; finite, ``> 0``.
        fast_ms: ``(n,)`` per-view totals (ms) of the method on the same views; finite, ``> 0``.
        confidence: in ``(0, 1)``.
        resamples: ``>= 100``.
        seed: the resampling's seed.

    Returns:
        :class:`SpeedupInterval`.

    Raises:
        InputError: no views, lengths that differ, a total that is not finite and positive, ``confidence``
            outside ``(0, 1)`` or fewer than 100 resamples.

    Example:
        >>> iv = speedup_interval([200.0, 210.0, 190.0, 205.0], [100.0, 100.0, 100.0, 100.0])
        >>> round(iv.speedup, 4), iv.views, iv.low <= iv.speedup <= iv.high
        (2.0125, 4, True)
        >>> speedup_interval([300.0], [100.0]).text()
        '–'
    """
    slow, fast = np.asarray(slow_ms, dtype=np.float64), np.asarray(fast_ms, dtype=np.float64)
    if slow.ndim != 1 or fast.ndim != 1 or slow.size != fast.size:
        raise InputError(f"speedup_interval: {slow.size} reference totals but {fast.size} method totals (expected one of each per view)")
    if slow.size == 0:
        raise InputError("speedup_interval: no timed views (expected at least one)")
    if not (np.isfinite(slow).all() and np.isfinite(fast).all() and (slow > 0).all() and (fast > 0).all()):
        raise InputError(f"speedup_interval: every total must be finite and > 0 ms, got {slow.tolist()[:6]} and {fast.tolist()[:6]}")
    if not (isinstance(confidence, (int, float)) and 0.0 < float(confidence) < 1.0):
        raise InputError(f"confidence={confidence!r}: expected a number in (0, 1)")
    if int(resamples) < 100:
        raise InputError(f"resamples={resamples!r}: expected at least 100")
    ratio = float(slow.sum() / fast.sum())
    n = slow.size
    if n == 1:
        return SpeedupInterval(ratio, ratio, ratio, 1, float(confidence))
    idx = np.random.default_rng(seed).integers(0, n, size=(int(resamples), n))
    ratios = slow[idx].sum(axis=1) / fast[idx].sum(axis=1)
    lo, hi = np.quantile(ratios, [(1.0 - confidence) / 2.0, (1.0 + confidence) / 2.0])
    return SpeedupInterval(ratio, float(lo), float(hi), n, float(confidence))


def _total(row: Mapping[str, Any]) -> float:
    try:
        return float(row.get("total_ms"))
    except (TypeError, ValueError):
        return math.nan


def timed_totals(rows: Iterable[Mapping[str, Any]]) -> dict[tuple[str, int], float]:
    """``{(method, view): total_ms}`` of the rows with a finite, positive total (the timed views)."""
    by: dict[tuple[str, int], float] = {}
    for r in rows:
        t = _total(r)
        if math.isfinite(t) and t > 0:
            by[(str(r["method"]), int(r["view"]))] = t
    return by


def paired_totals(rows: Iterable[Mapping[str, Any]], slow: str, fast: str) -> tuple[list[float], list[float]]:
    """The per-view totals of methods ``slow`` and ``fast`` on the views where both were timed, in view order.

    ``rows``: metric rows (``metrics.csv``'s: ``view``, ``method``, ``total_ms``; untimed views have no total)."""
    by = timed_totals(rows)
    views = sorted(v for (m, v) in by if m == slow and (fast, v) in by)
    return [by[(slow, v)] for v in views], [by[(fast, v)] for v in views]


def speedup_intervals(rows: Sequence[Mapping[str, Any]], reference: str = "recnn", confidence: float = 0.95,
                      resamples: int = RESAMPLES) -> dict[str, dict[str, Any]]:
    """Each timed method's :func:`speedup_interval` over ``reference`` (``summary.json``'s ``speedup_interval``):
    ``{method: SpeedupInterval.to_dict()}``, the methods in first-seen order, ``reference`` and methods with
    no view timed beside it left out."""
    methods = list(dict.fromkeys(str(r["method"]) for r in rows))
    out = {}
    for m in methods:
        if m == reference:
            continue
        slow, fast = paired_totals(rows, reference, m)
        if slow:
            out[m] = speedup_interval(slow, fast, confidence, resamples).to_dict()
    return out


def ray_casters(rows: Sequence[Mapping[str, Any]], main_skip: bool, confidence: float = 0.95,
                resamples: int = RESAMPLES) -> dict[str, Any] | None:
    """``summary.json``'s ``ray_casters``: the RecNN alone and IML/S on both ray casters, timed in one run (the
    evaluation's ``both_ray_casters``), and ``speedup_vs_fastest``, IML/S's faster configuration against the faster
    RecNN alone, with its interval over the timed views. ``main_skip``: whether ``recnn`` / ``imls`` ran with
    empty-space skipping (their twins, ``recnn_noskip`` / ``imls_noskip`` or ``recnn_skip`` / ``imls_skip``, on the
    other). None when the twins were not timed.

    Example:
        >>> rows = [{"view": v, "method": m, "total_ms": t} for v in (0, 1) for m, t in
        ...         (("recnn", 100.0), ("imls", 80.0), ("recnn_noskip", 400.0), ("imls_noskip", 180.0))]
        >>> rc = ray_casters(rows, main_skip=True)
        >>> rc["recnn_skip_ms"], rc["imls_noskip_ms"], rc["fastest_recnn"], round(rc["speedup_vs_fastest"], 2)
        (100.0, 180.0, 'skip', 1.25)
    """
    names = {("recnn", main_skip): "recnn", ("imls", main_skip): "imls",
             ("recnn", not main_skip): ray_caster_twin("recnn", not main_skip),
             ("imls", not main_skip): ray_caster_twin("imls", not main_skip)}
    # the four on the views where all four were timed, so the means compare like with like
    per: dict[str, dict[int, float]] = {n: {} for n in names.values()}
    for (method, view), t in timed_totals(rows).items():
        if method in per:
            per[method][view] = t
    views = sorted(set.intersection(*(set(d) for d in per.values())))
    if not views:
        return None
    mean = {key: float(np.mean([per[n][v] for v in views])) for key, n in names.items()}
    fast_recnn = min((True, False), key=lambda s: mean[("recnn", s)])
    fast_imls = min((True, False), key=lambda s: mean[("imls", s)])
    iv = speedup_interval([per[names[("recnn", fast_recnn)]][v] for v in views],
                          [per[names[("imls", fast_imls)]][v] for v in views], confidence, resamples)
    label = {True: "skip", False: "noskip"}
    return {"recnn_skip_ms": mean[("recnn", True)], "recnn_noskip_ms": mean[("recnn", False)],
            "imls_skip_ms": mean[("imls", True)], "imls_noskip_ms": mean[("imls", False)],
            "fastest_recnn": label[fast_recnn], "fastest_imls": label[fast_imls],
            "speedup_vs_fastest": iv.speedup, "speedup_vs_fastest_low": iv.low, "speedup_vs_fastest_high": iv.high,
            "speedup_noskip": mean[("recnn", False)] / mean[("imls", False)], "views": len(views)}
