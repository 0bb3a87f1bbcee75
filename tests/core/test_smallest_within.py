"""The operating-point search primitives (imls_lightning.core.smallest_within): the smallest setting within epsilon
over measured settings, its interpolation, and the bisection of a knob against a monotone function, scalar and
batched; edge cases (nothing within, everything within, NaN gaps, ties, a batch) and the rule every caller shares."""
from __future__ import annotations

import doctest
import math
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from imls_lightning.core import smallest_within as module
from imls_lightning.core.smallest_within import (Within, bisect_monotone, interpolated_within, smallest_within,
                                                 within)

NAN = math.nan
ROOT = Path(__file__).resolve().parents[2]


def test_module_doctests():
    result = doctest.testmod(module)
    assert result.attempted > 0 and result.failed == 0, result


def test_within_is_inclusive_and_nan_never_is():
    assert within(1.0, 1.0) and not within(1.0 + 1e-12, 1.0) and within(-math.inf, 0.0)
    assert not within(NAN, 1.0) and not within(NAN, math.inf)
    assert within(torch.tensor([0.5, 1.0, 1.5, NAN]), 1.0).tolist() == [True, True, False, False]


# ---------------------------------------------------------------- over measured settings
def test_first_within_of_a_grid_swept_upward():
    assert smallest_within([3.0, 1.5, 0.5, 0.2], 1.0) == Within(2, True, 0.5)
    assert smallest_within([3.0, 1.0, 0.5], 1.0).index == 1          # inclusive
    assert smallest_within([0.1, 0.2], 1.0).index == 0               # everything within: the first


def test_nothing_within_gives_nothing_or_what_otherwise_asks():
    gaps = [3.0, 1.2, 1.6, 1.2]
    assert smallest_within(gaps, 1.0) == Within(None, False)
    assert smallest_within(gaps, 1.0, otherwise="last") == Within(3, False, 1.2)
    assert smallest_within(gaps, 1.0, otherwise="least") == Within(1, False, 1.2)     # the first on a tie
    assert smallest_within(gaps, 1.0, otherwise="closest") == Within(1, False, 1.2)
    assert smallest_within([0.2, 3.0], 1.0, otherwise="least") == Within(0, True, 0.2)  # found: otherwise unused
    with pytest.raises(ValueError, match="otherwise='first'"):
        smallest_within(gaps, 1.0, otherwise="first")


def test_where_nothing_is_within_the_least_gap_is_the_closest():
    """Where nothing is within, every gap lies above epsilon: the least gap is the closest one."""
    gaps = [2.5, 1.7, 4.0, 1.9]
    assert smallest_within(gaps, 1.0, otherwise="least").index == smallest_within(gaps, 1.0, otherwise="closest").index == 1


def test_no_items():
    for otherwise in (None, "last", "least", "closest"):
        assert smallest_within([], 1.0, otherwise=otherwise) == Within(None, False)
    assert interpolated_within([], [], 1.0) is None


def test_nan_gaps_are_never_within():
    assert smallest_within([NAN, 2.0, NAN, 0.5], 1.0).index == 3
    assert smallest_within([NAN, NAN], 1.0) == Within(None, False)
    assert smallest_within([NAN, NAN], 1.0, otherwise="last").index == 1
    assert smallest_within([1.5, NAN, 1.2], 1.0, otherwise="closest").index == 2


def test_records_read_through_gap_and_lazily_up_to_the_first_within():
    read = []

    def records():
        for i, bound in enumerate([2.0, 0.9, 0.5]):
            read.append(i)
            yield {"i": i, "gap_bound_db": bound}

    pick = smallest_within(records(), 1.0, gap=lambda r: r["gap_bound_db"])
    assert pick.index == 1 and pick.item == {"i": 1, "gap_bound_db": 0.9} and read == [0, 1]


def test_smallest_value_among_those_within_in_any_order():
    cands = [{"b": 0.9, "s": 0.41}, {"b": 1.4, "s": 0.10}, {"b": 0.6, "s": 0.30}, {"b": 0.2, "s": 0.30}]
    pick = smallest_within(cands, 1.0, gap=lambda c: c["b"], value=lambda c: c["s"])
    assert pick.index == 2 and pick.found                           # 0.10 fails; 0.30 twice: the earlier
    assert smallest_within(cands, 0.5, gap=lambda c: c["b"], value=lambda c: c["s"]).index == 3
    assert smallest_within(cands, 0.1, gap=lambda c: c["b"], value=lambda c: c["s"], otherwise="least").index == 3


def test_holds_is_a_further_condition_read_only_where_the_gap_is_within():
    asked = []

    def holds(c):
        asked.append(c["s"])
        return c["ok"]

    cands = [{"b": 0.5, "s": 0.2, "ok": False}, {"b": 2.0, "s": 0.1, "ok": True}, {"b": 0.8, "s": 0.4, "ok": True}]
    pick = smallest_within(cands, 1.0, gap=lambda c: c["b"], value=lambda c: c["s"], holds=holds)
    assert pick.index == 2 and asked == [0.2, 0.4]
    assert smallest_within(cands, 1.0, gap=lambda c: c["b"], holds=lambda c: c["ok"]).index == 2


def test_interpolated_within_is_linear_between_the_first_within_and_the_one_before():
    assert interpolated_within([0.2, 0.4, 0.6], [3.0, 1.5, 0.5], 1.0) == pytest.approx(0.5)
    assert interpolated_within([0.2, 0.4, 0.6], [3.0, 2.0, 1.0], 1.0) == pytest.approx(0.6)   # reaches it exactly
    assert interpolated_within([0.2, 0.4], [0.9, 0.1], 1.0) == 0.2                             # the first is within
    assert interpolated_within([0.2, 0.4], [3.0, 2.0], 1.0) is None
    assert math.isnan(interpolated_within([0.2, 0.4], [NAN, 0.5], 1.0))                        # no line from a NaN


# ---------------------------------------------------------------- bisection
@pytest.mark.parametrize("scale", ["log", "linear"])
def test_scalar_bisection_finds_the_knob_of_a_rising_function(scale):
    b = bisect_monotone(lambda u: u ** 2, 0.04, 0.01, 1.0, 40, scale=scale)
    assert b.lo < 0.2 <= b.hi and b.hi == pytest.approx(0.2, rel=1e-9)
    assert len(b.trace) == 40 and b.value_hi is None


def test_falling_function_bisects_a_gap_against_epsilon_and_tracks_the_value_at_hi():
    gap = lambda u: 10 * math.log10(0.3 / u)  # noqa: E731  (0 dB at u = 0.3, 1 dB at u = 0.238)
    b = bisect_monotone(gap, 1.0, 0.01, 1.0, 30, rising=False, value_hi=gap(1.0))
    assert b.hi == pytest.approx(0.3 / 10 ** 0.1, rel=1e-7) and within(b.value_hi, 1.0) and b.value_hi == gap(b.hi)
    assert not within(gap(b.lo), 1.0)


def test_the_midpoints_are_the_geometric_or_arithmetic_means_of_the_bracket():
    log = bisect_monotone(lambda u: 0.0, 1.0, 0.01, 1.0, 1)      # never reaches: lo moves
    lin = bisect_monotone(lambda u: 2.0, 1.0, 0.0, 1.0, 1, scale="linear")  # reaches: hi moves
    assert log.lo == math.exp(0.5 * (math.log(0.01) + math.log(1.0))) and log.hi == 1.0
    assert (lin.lo, lin.hi) == (0.0, 0.5)
    with pytest.raises(ValueError, match="scale='cubic'"):
        bisect_monotone(lambda u: u, 0.5, 0.0, 1.0, 3, scale="cubic")


def test_zero_steps_evaluate_nothing():
    b = bisect_monotone(lambda u: pytest.fail("evaluated"), 0.5, 0.01, 1.0, 0)
    assert (b.lo, b.hi, b.trace) == (0.01, 1.0, [])


def test_nan_counts_as_above_every_target():
    rising = bisect_monotone(lambda u: NAN, 0.5, 0.01, 1.0, 3)
    falling = bisect_monotone(lambda u: NAN, 0.5, 0.01, 1.0, 3, rising=False)
    assert rising.lo == 0.01 and rising.hi < 1.0          # reached: hi moves down
    assert falling.hi == 1.0 and falling.lo > 0.01        # not within: lo moves up


def test_a_batch_is_bisected_element_by_element_with_one_target_each():
    targets = torch.tensor([0.02, 0.3, 0.9, 2.0], dtype=torch.float64)
    lo = torch.full((4,), 0.01, dtype=torch.float64)
    hi = torch.ones(4, dtype=torch.float64)
    calls = []

    def gap(u):
        calls.append(u.shape)
        return (targets - u).clamp(min=0) * 100

    b = bisect_monotone(gap, torch.zeros(4, dtype=torch.float64), lo, hi, 20, rising=False, value_hi=gap(hi))
    assert b.hi[:3].tolist() == pytest.approx([0.02, 0.3, 0.9], rel=1e-5)
    assert b.hi[3].item() == 1.0 and b.value_hi[3].item() == pytest.approx(100.0)   # never within: hi stays
    assert b.value_hi[:3].tolist() == [0.0, 0.0, 0.0] and calls == [torch.Size([4])] * 21
    for i in range(4):  # each element as a scalar bisection of its own: the same bracket, bit for bit
        one = bisect_monotone(lambda u: max(targets[i].item() - u, 0.0) * 100, 0.0, 0.01, 1.0, 20, rising=False)
        assert (b.lo[i].item(), b.hi[i].item()) == (one.lo, one.hi)


def test_a_batch_keeps_its_dtype_shape_and_device():
    lo = torch.zeros(3, 1, 1, 1, dtype=torch.float32)
    b = bisect_monotone(lambda u: u * 2, torch.tensor(0.5), lo, torch.ones_like(lo), 10, scale="linear")
    assert b.hi.dtype == torch.float32 and b.hi.shape == (3, 1, 1, 1) and b.value_hi is None
    assert b.hi.flatten().tolist() == [0.25] * 3


def test_the_module_imports_no_torch():
    """The ORP search (torch-free for Hydra's plugin scan) uses it."""
    code = ("import sys, imls_lightning.core.smallest_within as m; m.smallest_within([2.0, 0.5], 1.0); "
            "m.bisect_monotone(lambda u: u, 0.5, 0.01, 1.0, 4); assert 'torch' not in sys.modules")
    p = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
