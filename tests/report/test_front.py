"""imls_lightning.report.front: the Pareto marking against its definition, the points, the table, the verdict."""
from __future__ import annotations

import math

import numpy as np
import pytest

from imls_lightning import report as rep
from imls_lightning.report.front import EXACT_PSNR_DB, front_point, front_points, front_verdict, pareto_front


def _dominated_directly(lat, q, i) -> bool:
    """The definition, point by point: some other finite point is as fast and as good, and better in one."""
    if not (math.isfinite(lat[i]) and math.isfinite(q[i])):
        return True
    return any(j != i and math.isfinite(lat[j]) and math.isfinite(q[j]) and lat[j] <= lat[i] and q[j] >= q[i]
               and (lat[j] < lat[i] or q[j] > q[i]) for j in range(len(lat)))


@pytest.mark.parametrize("seed", range(6))
def test_pareto_front_against_the_definition(seed):
    rng = np.random.default_rng(seed)
    n = 25
    # few distinct values: ties in latency, in PSNR and whole duplicate points
    lat = rng.integers(1, 8, n).astype(float)
    q = rng.integers(20, 28, n).astype(float)
    lat[rng.integers(0, n)] = math.nan
    q[rng.integers(0, n)] = math.inf * 0  # NaN
    got = pareto_front(lat, q)
    assert got == [not _dominated_directly(lat, q, i) for i in range(n)]


def test_pareto_front_edge_cases():
    assert pareto_front([], []) == []
    assert pareto_front([2.0, 2.0], [30.0, 30.0]) == [True, True]  # equal points are all on the front
    assert pareto_front([1.0, 2.0], [31.0, 30.0]) == [True, False]
    with pytest.raises(ValueError, match="2 latencies but 1 PSNRs"):
        pareto_front([1.0, 2.0], [3.0])


def _rows():
    rows = []
    for v in (0, 1, 2):
        for m, t, p in (("full", 10.0, EXACT_PSNR_DB), ("recnn", 5.0 + v, 40.0), ("recnn_sparser", 2.0, 37.0), ("imls", 3.0, 39.5)):
            rows.append({"view": v, "method": m, "total_ms": t, "psnr": p, "ssim": 0.9, "c_share": 0.4, "ipr": 0.1})
    sweep = [{"view": v, "method": "imls", "setting": "share", "value": s, "total_ms": 1.0 + 5 * s, "psnr": 36.0 + 4 * s,
              "ssim": 0.9, "c_share": s} for v in (0, 1, 2, 3) for s in (0.1, 1.0)]
    sweep += [{"view": 0, "method": "iml_selective", "setting": "mean", "value": 0.2, "total_ms": 0.1, "psnr": 99.0}]
    return rows, sweep


def test_front_point_median_latency_and_mean_quality_on_the_given_views():
    rows, _ = _rows()
    p = front_point([r for r in rows if r["method"] == "recnn"], "recnn", "its pattern", views=[0, 2])
    assert (p["latency_ms"], p["psnr"], p["views"], p["label"]) == (6.0, 40.0, 2, rep.METHOD_LABELS["recnn"])
    assert front_point([], "recnn", "x") is None


def test_front_points_mark_the_front_and_leave_out_the_oracle():
    rows, sweep = _rows()
    pts = front_points(rows, sweep, views=[0, 1, 2], notes={"imls": "ORP u=0.5"})
    names = [(p["method"], p["note"]) for p in pts]
    assert ("iml_selective", "u=0.2") not in names and ("imls", "10% of C") in names and ("imls", "ORP u=0.5") in names
    assert all(p["views"] == 3 for p in pts)  # view 3 of the sweep is not one of the front's views
    on = {(p["method"], p["note"]) for p in pts if p["on_front"]}
    # 10% (1.5 ms, 36.4) < sparser (2 ms, 37) < IML/S at the ORP (3 ms, 39.5) < RecNN (6 ms, 40) < full (exact);
    # IML/S at 100% of C (6 ms, 40) ties the RecNN alone: both on the front
    assert on == {("imls", "10% of C"), ("recnn_sparser", "as evaluated"), ("imls", "ORP u=0.5"), ("recnn", "as evaluated"),
                  ("imls", "100% of C"), ("full", "as evaluated")}


def test_front_markdown_and_verdict_say_where_imls_lies():
    rows, sweep = _rows()
    pts = front_points(rows, sweep, views=[0, 1, 2], notes={"imls": "ORP u=0.5"})
    text = rep.front_markdown(pts)
    assert text.count("◆") == 6 and "exact" in text and text.splitlines()[2].startswith("| **IML/S + RecNN** | 10% of C")
    v = front_verdict(pts, "flame", operating_note="ORP u=0.5")
    assert v.startswith("**flame**: 3 of the 3 IML/S + RecNN points lie on the Pareto front")
    assert "Its operating point (ORP u=0.5, 3.00 ms, 39.50 dB) is on the front." in v
    assert "RecNN alone, sparser pattern (2.00 ms, 37.00 dB) the operating point's speed-up is 0.67×, its PSNR change +2.50 dB" in v
    # the sparser RecNN made better: it dominates the operating point
    worse = [dict(r, psnr=39.8) if r["method"] == "recnn_sparser" else r for r in rows]
    v2 = front_verdict(front_points(worse, sweep, [0, 1, 2], {"imls": "ORP u=0.5"}), "flame", operating_note="ORP u=0.5")
    assert "is dominated by 1 point(s), e.g. RecNN alone, sparser pattern (as evaluated: 2.00 ms, 39.80 dB)" in v2
    assert "no IML/S point" in front_verdict([p for p in pts if p["method"] != "imls"], "flame")
