"""The baselines' searched points on the shared primitive (imls_lightning.core.smallest_within): the report line of
a SearchedPoint for either knob, the object floor's choice and its fallback, LAS at equal quality where no IPR is
close enough, and a band that keeps the last value."""
from __future__ import annotations

import doctest
import math

import numpy as np

from imls_lightning.evaluation import baseline_point
from imls_lightning.evaluation.baseline_point import SearchedPoint, band_values, say_value, smallest_within
from imls_lightning.evaluation.las_point import describe_las, equal_quality_point
from imls_lightning.evaluation.operating_point import SearchViews, choose_object_floor, object_floor_pick
from imls_lightning.evaluation.two_pass import describe_two_pass

BANDS = {"edges": [3.15], "values": [0.1, 0.05], "shares": [0.8, 0.4], "gaps_db": [0.33, 0.24],
         "bounds_db": [0.52, 0.31], "views": [4, 4], "lo": [2.6, 3.4], "hi": [2.9, 3.7]}
REC = {"gap_db": 0.412, "gap_bound_db": 0.873}
LAS = ("LAS at the product's promise (what a user who chose LAS would run): its IPR searched on 12 views, the smallest "
       "that keeps the bound on the gap to the RecNN alone within 1 dB")
TWO = ("Two passes + fill + RecNN (no IMS, no decoder: the simplest alternative): a blue-noise first pass of 20% of C, "
       "then the pixels whose neighbours predict them worst, pull-push filled; its share was searched on 12 views")


def test_module_doctests():
    result = doctest.testmod(baseline_point)
    assert result.attempted > 0 and result.failed == 0, result


def test_the_report_line_of_las_at_the_promise():
    found = SearchedPoint("ipr", 0.1234, True, "12 views", 1.0, REC)
    assert describe_las(found) == f"{LAS}: IPR 12.3%, gap 0.41 dB there (bound 0.87 dB)."
    banded = SearchedPoint("ipr", 0.1234, True, "12 views", 1.0, REC, by_distance=BANDS)
    assert describe_las(banded) == (f"{LAS}: IPR 12.3%, gap 0.41 dB there (bound 0.87 dB); then each band of camera "
                                    "distance its own, never above that one: 2.60-2.90: 10.0% (bound 0.52 dB); "
                                    "3.40-3.70: 5.0% (bound 0.31 dB).")
    none = SearchedPoint("ipr", 0.4, False, "12 views", 1.0, None)
    assert describe_las(none) == f"{LAS}: none of those searched did, so it runs at the largest, IPR 40.0%."


def test_the_report_line_of_the_two_pass_sampler():
    settings = {"base": 0.2, "floor": 0.25}
    found = SearchedPoint("share", 0.75, True, "12 views", 0.5, REC, settings=settings)
    assert describe_two_pass(found) == f"{TWO}: 75% of C, gap 0.41 dB there (bound 0.87 <= 0.5 dB)."
    banded = SearchedPoint("share", 0.75, True, "12 views", 0.5, REC, by_distance=BANDS, settings=settings)
    assert describe_two_pass(banded).endswith("(bound 0.87 <= 0.5 dB); then each band of camera distance its own share, "
                                              "never above that one, judged on its own search views: 2.60-2.90: 80% "
                                              "(bound 0.52 dB); 3.40-3.70: 40% (bound 0.31 dB).")
    none = SearchedPoint("share", 1.0, False, "12 views", 0.5, None, settings=settings)
    assert describe_two_pass(none) == f"{TWO}: no share below 100% kept the bound within 0.5 dB, so it renders all of C."
    assert (say_value("ipr", 0.05), say_value("share", 0.05)) == ("IPR 5.0%", "5% of C")


def test_the_object_floor_takes_the_cheapest_that_holds_else_the_smallest_bound():
    cands = [{"gap_bound_db": 1.4, "c_share": 0.30}, {"gap_bound_db": 0.9, "c_share": 0.45},
             {"gap_bound_db": 0.6, "c_share": 0.41}, {"gap_bound_db": 0.8, "c_share": 0.41}]
    assert choose_object_floor(cands, 1.0) == 2                            # 0.41 twice: the earlier
    pick = object_floor_pick(cands, 0.5, otherwise="least")
    assert (pick.index, pick.found) == (2, False) and choose_object_floor(cands, 0.5) is None
    cands[2].update(views_over_epsilon=3, views=10)                        # over the tail: no longer holds
    assert choose_object_floor(cands, 1.0, tail=0.2) == 3 and choose_object_floor(cands, 1.0) == 2
    nan = [{"gap_bound_db": math.nan, "c_share": 0.1}, {"gap_bound_db": 2.0, "c_share": 0.2}]
    assert choose_object_floor(nan, 1.0) is None


def test_las_at_equal_quality_takes_the_closest_where_none_is_within():
    pt = SearchedPoint("ipr", 0.3, True, "views", 1.0, None, rows=[{"ipr": 0.2, "gap_db": 0.9}, {"ipr": 0.05, "gap_db": 2.0},
                                                                   {"ipr": 0.1, "gap_db": 1.1}])
    q = equal_quality_point(pt, 0.3)
    assert (q.value, q.found, q.record["gap_db"]) == (0.2, False, 0.9)     # 0.9 is 0.5 from 0.4; 1.1 is 0.7
    assert equal_quality_point(pt, 1.0).value == 0.1 and equal_quality_point(pt, 1.0).found


def _views(strata=None):
    return SearchViews(None, list(range(4)), "4 views", [2.6, 2.7, 3.4, 3.5], strata, None, 1)


def test_the_smallest_value_within_and_a_band_that_keeps_the_last():
    values = [0.2, 0.4, 0.6]
    gaps = np.array([[3.0, 0.9, 0.1], [3.1, 0.8, 0.2], [0.3, 0.2, 0.1], [0.4, 0.3, 0.0]])
    kept = np.tile(np.array(values), (4, 1))
    chosen, rows = smallest_within(_views(), values, kept, gaps, 0.5, 1.0, None)
    assert chosen is rows[1] and chosen["value"] == 0.4 and [r["value"] for r in rows] == values
    assert smallest_within(_views(), values, kept, gaps + 5, 0.5, 1.0, None)[0] is None
    gaps[:2, 1:] = 4.0                                                     # the near band holds nowhere
    b = band_values(_views([0, 0, 1, 1]), values, kept, gaps, 0.5, 1.0, None)
    assert b["values"] == [0.6, 0.2] and b["gaps_db"][0] == 4.0
