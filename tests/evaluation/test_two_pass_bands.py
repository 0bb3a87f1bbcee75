"""The two-pass sampler's share per band of camera distance (imls_lightning.evaluation.two_pass.band_shares) against
the protocol's judgement applied directly, its band edges, and its section of the report."""
from __future__ import annotations

import numpy as np
import pytest

from imls_lightning.evaluation.operating_point import SearchViews, band_edges
from imls_lightning.evaluation.baseline_point import SearchedPoint
from imls_lightning.evaluation.two_pass import band_shares, describe_two_pass
from imls_lightning.orp import gap_upper_bound, protocol_gap_record
from imls_lightning.report.document import _two_pass_lines

SHARES = [0.4, 0.6, 0.8]


def _views(distances, strata, passes=None, paths=1):
    return SearchViews(cache=None, rows=list(range(len(distances))), where="8 test views", distances=list(distances),
                       strata=list(strata), passes=passes, paths=paths)


def _gaps():
    """Band 0 (near) keeps the bound only at 80% of C, band 1 (far) already at 40%."""
    near = np.array([[3.0, 2.0, 0.30], [2.5, 1.8, 0.35], [3.2, 2.2, 0.25], [2.8, 1.9, 0.40]])
    far = np.array([[0.20, 0.10, 0.05], [0.30, 0.15, 0.04], [0.25, 0.12, 0.06], [0.22, 0.11, 0.03]])
    return np.vstack([near, far])


def test_each_band_gets_the_smallest_share_whose_own_bound_holds():
    gaps = _gaps()
    kept = np.tile(np.array(SHARES), (8, 1)) + 0.01
    v = _views([2.6, 2.7, 2.8, 2.9, 3.4, 3.5, 3.6, 3.7], [0, 0, 0, 0, 1, 1, 1, 1])
    b = band_shares(v, SHARES, kept, gaps, confidence=0.95, epsilon_db=1.0, future_views=8)
    assert b["shares"] == [0.8, 0.4] and b["views"] == [4, 4] and b["edges"] == [pytest.approx(3.15)]
    assert (b["lo"], b["hi"]) == ([2.6, 3.4], [2.9, 3.7]) and b["c_shares"] == pytest.approx([0.81, 0.41])
    # the bound of each band is the plain bound of its own four views for its half of the eight new views
    for k, (j, rows) in enumerate([(2, slice(0, 4)), (0, slice(4, 8))]):
        direct = gap_upper_bound(gaps[rows, j].tolist(), 0.95, 4)
        assert b["bounds_db"][k] == pytest.approx(direct.bound) and b["gaps_db"][k] == pytest.approx(direct.mean)
        assert b["bounds_db"][k] <= 1.0


def test_a_band_keeps_the_share_that_held_everywhere_where_none_below_it_holds():
    gaps = _gaps()
    gaps[:4, 2] = 5.0  # the near band holds at no share: it keeps the last one, with its own (failing) numbers
    kept = np.tile(np.array(SHARES), (8, 1))
    v = _views([2.6, 2.7, 2.8, 2.9, 3.4, 3.5, 3.6, 3.7], [0, 0, 0, 0, 1, 1, 1, 1])
    b = band_shares(v, SHARES, kept, gaps, confidence=0.95, epsilon_db=1.0, future_views=8)
    assert b["shares"] == [0.8, 0.4] and b["gaps_db"][0] == pytest.approx(5.0)


def test_band_bounds_count_passes_along_paths():
    """Views along paths: each band's bound counts its passes (a run of a path's views within the band)."""
    gaps = _gaps()
    kept = np.tile(np.array(SHARES), (8, 1))
    passes = [0, 0, 1, 1, 2, 2, 3, 3]
    v = _views([2.6, 2.7, 2.8, 2.9, 3.4, 3.5, 3.6, 3.7], [0, 0, 0, 0, 1, 1, 1, 1], passes=passes, paths=2)
    b = band_shares(v, SHARES, kept, gaps, confidence=0.95, epsilon_db=1.0, future_views=8)
    direct = protocol_gap_record(gaps[4:, 0].tolist(), 0.95, 4, None, passes[4:], 2)
    assert b["bounds_db"][1] == pytest.approx(direct["gap_bound_db"]) and "passes" in direct


def test_bands_that_do_not_separate_give_none_with_a_warning(capsys):
    gaps = _gaps()
    kept = np.tile(np.array(SHARES), (8, 1))
    v = _views([2.6, 3.5, 2.8, 2.9, 3.4, 3.5, 3.6, 3.7], [0, 0, 0, 0, 1, 1, 1, 1])  # band 0 reaches into band 1
    assert band_shares(v, SHARES, kept, gaps, confidence=0.95, epsilon_db=1.0, future_views=8) is None
    assert "do not separate the bands; every view runs at 80% of C" in capsys.readouterr().err


def test_band_edges_are_midpoints_between_neighbouring_bands():
    assert band_edges([2.0], [2.5]) == []
    assert band_edges([2.0, 3.0, 4.0], [2.5, 3.5, 4.5]) == [2.75, 3.75]
    assert band_edges([2.0, 2.4], [2.5, 3.0]) is None


def _point(by_distance=True):
    bands = {"edges": [3.15], "shares": [0.8, 0.4], "c_shares": [0.81, 0.41], "gaps_db": [0.33, 0.24],
             "bounds_db": [0.52, 0.31], "views": [4, 4], "lo": [2.6, 3.4], "hi": [2.9, 3.7]}
    rows = [{"share": x, "c_share": x + 0.01, "gap_db": g, "gap_bound_db": bd}
            for x, g, bd in zip(SHARES, [1.5, 0.9, 0.18], [2.5, 1.6, 0.4])]
    return SearchedPoint("share", 0.8, found=True, where="8 test views", epsilon_db=1.0, record={**rows[2]}, rows=rows,
                         by_distance=bands if by_distance else None, settings={"base": 0.2, "floor": 0.25})


def test_point_describes_and_runs_its_bands():
    p = _point()
    assert "then each band of camera distance its own share" in describe_two_pass(p)
    assert "2.60-2.90: 80% (bound 0.52 dB); 3.40-3.70: 40% (bound 0.31 dB)." in describe_two_pass(p)
    sched = p.values_by_distance()
    assert sched.edges.tolist() == pytest.approx([3.15]) and sched.means.tolist() == pytest.approx([0.8, 0.4])
    assert _point(False).values_by_distance() is None and describe_two_pass(_point(False)).endswith("<= 1 dB).")
    assert p.to_dict()["by_distance"]["shares"] == [0.8, 0.4]


def test_report_section_shows_the_search_the_bands_and_the_test_gap():
    tp = {**_point().to_dict(), "test": {"gap_db": 0.21, "gap_std_db": 0.3, "views": 120, "psnr_recnn": 35.0,
                                         "psnr_imls": 34.79},
          "test_by_distance": [{"lo": 2.6, "hi": 3.0, "views": 60, "gap_db": 0.3, "max_gap_db": 0.9, "c_share": 0.8},
                               {"lo": 3.0, "hi": 3.8, "views": 60, "gap_db": 0.12, "max_gap_db": 0.5, "c_share": 0.4}]}
    text = "\n".join(_two_pass_lines(tp, "the test trajectory"))
    assert "## The two-pass sampler's share (no IMS, searched like the ORP)" in text
    assert "| 80% | 0.18 | 0.40 | 81.0% |" in text                        # the searched shares
    assert "| 2.60-2.90 | 3.150 | 4 | 80% | 81.0% | 0.33 | 0.52 |" in text  # each band's own
    assert "| 3.40-3.70 | – | 4 | 40% | 41.0% | 0.24 | 0.31 |" in text
    assert "a mean gap of 0.21 dB (std 0.30, 120 views; within ε: yes)" in text
    assert "| 2.60–3.00 | 60 | 0.30 | 0.90 | 80.0% |" in text
    tp["by_distance"] = None
    assert "each band of camera distance its own share" not in "\n".join(_two_pass_lines(tp, "the test trajectory"))
