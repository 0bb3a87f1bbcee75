"""imls_lightning.evaluation.run's helpers: the other jobs' load while the views were timed."""
from __future__ import annotations

from imls_lightning.evaluation.run import load_note, timing_load


def test_timing_load_summarizes_the_timed_views_against_a_direct_count():
    load = [{"view": 0, "cores": 0.02, "seconds": 30.0}, {"view": 5, "cores": 1.3, "seconds": 31.0},
            {"view": 9, "cores": 0.3, "seconds": 29.0}, {"view": 11, "cores": None, "seconds": 1.0}]
    tl = timing_load(load)
    assert tl == {"views": 3, "mean": round((0.02 + 1.3 + 0.3) / 3, 3), "max": 1.3, "over": 2, "limit": 0.25}
    assert timing_load([]) is None and timing_load([{"view": 0, "cores": None, "seconds": 1.0}]) is None


def test_load_note_warns_only_over_the_limit():
    quiet = load_note({"views": 8, "mean": 0.01, "max": 0.04, "over": 0, "limit": 0.25})
    assert quiet == "Other processes kept 0.01 cores busy on average (at most 0.04) while the 8 timed views ran."
    loud = load_note({"views": 8, "mean": 0.6, "max": 1.1, "over": 5, "limit": 0.25})
    assert loud.startswith("Other processes kept 0.60 cores") and "Warning: on 5 of them more than 0.25" in loud
    assert load_note(None) is None
