"""imls_lightning.report.speedup: the speed-up's bootstrap interval over the timed views."""
from __future__ import annotations

import math

import numpy as np
import pytest

from imls_lightning.base.errors import InputError
from imls_lightning.report.speedup import RESAMPLES, SpeedupInterval, paired_totals, speedup_interval, speedup_intervals


def _direct(slow, fast, confidence, resamples, seed):
    """The interval one resample at a time: the same draws, a loop instead of fancy indexing."""
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(slow), size=(resamples, len(slow)))
    ratios = []
    for draw in idx:
        ratios.append(math.fsum(slow[i] for i in draw) / math.fsum(fast[i] for i in draw))
    ratios.sort()
    return float(np.quantile(ratios, (1 - confidence) / 2)), float(np.quantile(ratios, (1 + confidence) / 2))


def test_the_interval_equals_a_direct_bootstrap_and_the_ratio_is_that_of_the_means():
    rng = np.random.default_rng(3)
    slow = list(2500 + 400 * rng.standard_normal(12))
    fast = [s / (2.0 + 0.15 * rng.standard_normal()) for s in slow]
    iv = speedup_interval(slow, fast, confidence=0.9, resamples=2000, seed=7)
    assert iv.speedup == pytest.approx(np.mean(slow) / np.mean(fast), rel=1e-12)
    lo, hi = _direct(slow, fast, 0.9, 2000, 7)
    assert (iv.low, iv.high) == (pytest.approx(lo, rel=1e-12), pytest.approx(hi, rel=1e-12))
    assert iv.low < iv.speedup < iv.high and iv.views == 12 and iv.confidence == 0.9
    assert speedup_interval(slow, fast, 0.9, 2000, 7) == iv  # a fixed seed: a report repeats


def test_a_ratio_the_same_on_every_view_has_no_spread_and_more_views_narrow_it():
    iv = speedup_interval([300.0, 600.0, 900.0], [100.0, 200.0, 300.0])
    assert iv.low == pytest.approx(3.0) and iv.high == pytest.approx(3.0) and iv.text() == "3.00–3.00×"
    rng = np.random.default_rng(0)
    widths = []
    for n in (8, 32, 128):
        slow = 1000 + 300 * rng.random(n)
        fast = slow / (2.0 + 0.3 * rng.standard_normal(n))
        w = speedup_interval(slow, fast)
        widths.append(w.high - w.low)
    assert widths[0] > widths[1] > widths[2]  # about 1/sqrt(n)
    assert widths[0] / widths[2] == pytest.approx(4.0, rel=0.5)


def test_the_interval_covers_the_true_ratio_about_as_often_as_it_says():
    """Views whose ratio scatters around 2.0: the 90% interval over 30 views holds the ratio of the population's
    means in about 90% of 200 draws (a percentile bootstrap runs a little narrow on few views)."""
    rng = np.random.default_rng(11)
    ratio = lambda n: 2.0 + 0.4 * rng.standard_normal(n).clip(-2.5, 2.5)  # noqa: E731  a view's speed-up
    # fast = slow / ratio with ratio independent of slow: mean(slow) / mean(fast) -> 1 / E[1 / ratio]
    truth = 1.0 / np.mean(1.0 / ratio(200_000))
    hits = 0
    for trial in range(200):
        slow = 1000 + 400 * rng.random(30)
        iv = speedup_interval(slow, slow / ratio(30), confidence=0.9, resamples=400, seed=trial)
        hits += iv.low <= truth <= iv.high
    assert 0.8 <= hits / 200 <= 0.97


def test_one_view_gives_its_ratio_and_no_interval_text():
    iv = speedup_interval([300.0], [150.0])
    assert (iv.speedup, iv.low, iv.high, iv.views) == (2.0, 2.0, 2.0, 1) and iv.text() == "–"
    assert SpeedupInterval(**iv.to_dict()) == iv


@pytest.mark.parametrize("slow, fast, kw, match", [
    ([], [], {}, "no timed views"),
    ([1.0, 2.0], [1.0], {}, "2 reference totals but 1 method totals"),
    ([1.0, math.nan], [1.0, 1.0], {}, "finite and > 0"),
    ([1.0, 2.0], [1.0, 0.0], {}, "finite and > 0"),
    ([1.0, 2.0], [1.0, 1.0], {"confidence": 1.0}, r"confidence=1.0: expected a number in \(0, 1\)"),
    ([1.0, 2.0], [1.0, 1.0], {"resamples": 10}, "resamples=10: expected at least 100"),
])
def test_each_documented_error(slow, fast, kw, match):
    with pytest.raises(InputError, match=match):
        speedup_interval(slow, fast, **kw)


def _rows():
    """A metrics.csv's rows: 3 views timed, a fourth measured for PSNR only (no total), LAS timed on two views."""
    rows = []
    for v, (r, i) in enumerate([(400.0, 200.0), (420.0, 200.0), (380.0, 190.0), (None, None)]):
        rows.append({"view": str(v), "method": "recnn", "total_ms": "" if r is None else str(r)})
        rows.append({"view": str(v), "method": "imls", "total_ms": "" if i is None else str(i)})
        rows.append({"view": str(v), "method": "las", "total_ms": str(300.0) if v < 2 else ""})
        rows.append({"view": str(v), "method": "full", "total_ms": ""})
    return rows


def test_paired_totals_and_every_methods_interval_over_the_recnn():
    assert paired_totals(_rows(), "recnn", "imls") == ([400.0, 420.0, 380.0], [200.0, 200.0, 190.0])
    assert paired_totals(_rows(), "recnn", "las") == ([400.0, 420.0], [300.0, 300.0])
    out = speedup_intervals(_rows())
    assert list(out) == ["imls", "las"]  # the reference and a method never timed are left out
    assert out["imls"]["speedup"] == pytest.approx(1200.0 / 590.0) and out["imls"]["views"] == 3
    assert out["las"]["speedup"] == pytest.approx(820.0 / 600.0) and out["las"]["views"] == 2
    assert RESAMPLES >= 10_000


def test_the_gap_by_camera_distance_carries_each_bins_speedup_over_its_timed_views():
    """Where on the trajectory the trade pays: seed_whole's per-view ratio ran 1.65-2.40x, close-ups keeping more of
    the pattern. Each distance bin's speed-up is the ratio of its timed views' summed totals; a bin with none timed
    has none."""
    from imls_lightning.evaluation.operating_point import gap_by_distance

    totals = {0: (400.0, 250.0), 1: (420.0, 240.0), 2: None, 3: (380.0, 150.0), 4: (390.0, 140.0), 5: None}
    rows = []
    for v, tot in totals.items():
        for m, k in (("recnn", 0), ("imls", 1)):
            rows.append({"view": v, "row": v, "method": m, "psnr": 40.0 - 0.5 * k, "c_share": 0.4,
                         "total_ms": None if tot is None else tot[k]})
    near, far = gap_by_distance(rows, lambda r: 3.0 + 0.1 * r, bins=2)
    assert (near["views"], near["timed_views"], far["timed_views"]) == (3, 2, 2)
    assert near["speedup"] == pytest.approx(820.0 / 490.0) and far["speedup"] == pytest.approx(770.0 / 290.0)
    (only,) = gap_by_distance([r for r in rows if r["view"] in (2, 5)], lambda r: 3.0 + 0.1 * r, bins=1)
    assert only["speedup"] is None and only["timed_views"] == 0
