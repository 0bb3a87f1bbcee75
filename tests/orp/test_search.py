"""ORP search: bisection / k-section logic, settings, the Hydra sweeper plugin and a real CLI sweep."""
from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path

import pytest

from imls_lightning.base.errors import InputError
from imls_lightning import orp
from imls_lightning.orp import ORPSearch, ORPSettings, batched, evaluation_from

ROOT = Path(__file__).resolve().parents[2]
PY = sys.executable


def gap_curve(u_star: float, eps: float = 1.0):
    """Synthetic monotone PSNR gap (dB): decreasing in u, equal to ``eps`` exactly at ``u_star``."""
    return lambda u: eps + 3.0 * math.log2(u_star / u)


def check_brackets(res, u_star: float, tol: float = 0.1) -> None:
    """The answer is the smallest passing point, within ``tol`` (relative) above the true threshold."""
    assert res.found and res.mean == res.bracket[1]
    lo, hi = res.bracket
    assert lo < u_star <= hi, (lo, u_star, hi)
    assert hi <= lo * (1 + tol) + 1e-12
    assert u_star <= res.mean <= u_star * (1 + tol)


# ---- the search ---------------------------------------------------------------------------
@pytest.mark.parametrize("u_star", [0.0137, 0.137, 0.5, 0.97])
def test_bisection_finds_the_known_answer(u_star):
    res = ORPSearch(epsilon_db=1.0, tolerance=0.1).run(batched(gap_curve(u_star)))
    check_brackets(res, u_star)
    assert res.stop_reason == "tolerance" and not res.non_monotone
    assert all(e.status == "ok" for e in res.evaluations)
    # every point tried is on the right side of the threshold
    assert all(e.meets(1.0) == (e.u >= u_star) for e in res.evaluations)
    # bisection in log u over two decades to 10 %: ceil(log2(ln 100 / ln 1.1)) = 6 rounds
    # (+1 when the answer lies so close to the upper end that only u = 1 itself passes)
    assert res.rounds == res.jobs == (7 if u_star > 1 / 1.1 else 6)


def test_bisection_linear_scale_and_no_solution():
    res = ORPSearch(tolerance=0.05, scale="linear").run(batched(gap_curve(0.3)))
    check_brackets(res, 0.3, tol=0.05)
    assert res.evaluations[0].u == pytest.approx(0.505)  # the linear midpoint of [0.01, 1]

    none = ORPSearch(tolerance=0.1).run(batched(gap_curve(3.0)))  # needs u > 1: no ORP in the bracket
    assert not none.found and none.mean is None and none.stop_reason == "no_solution"
    assert none.evaluations[-1].u == 1.0  # the upper end was checked once, last


def test_failed_jobs_are_recorded_as_not_meeting_epsilon_and_the_search_goes_on():
    curve = gap_curve(0.05)
    kinds = ["raise", "none", "nan", "record"]  # the first four jobs fail, each in its own way

    def job(u):
        kind = kinds.pop(0) if kinds else None
        if kind == "raise":
            raise RuntimeError("CUDA out of memory")
        if kind == "none":
            return None
        if kind == "nan":
            return {"status": "ok", "gap_db": float("nan")}
        if kind == "record":
            return {"status": "failed", "error": "ORPJobError: boom"}
        return {"status": "ok", "gap_db": curve(u), "psnr_db": {"recnn": 30.0}}

    res = ORPSearch(tolerance=0.1).run(batched(job))
    failed = [e for e in res.evaluations if e.status == "failed"]
    assert [e.u for e in failed] == [0.1, 0.31623, 0.56234, 0.74989]  # each failure moves lo up
    assert failed[0].error == "RuntimeError: CUDA out of memory"
    assert failed[1].error == "missing result" and "non-finite" in failed[2].error
    assert failed[3].error == "ORPJobError: boom"
    assert all(not e.meets(1.0) for e in failed)
    # these would have passed; counted as failing, the search goes on above them and finds the next passing value
    assert res.found and res.bracket[0] == 0.74989 and res.mean <= 0.74989 * 1.1
    assert res.best.record["psnr_db"] == {"recnn": 30.0}
    assert len(res.evaluations) > len(failed)


def test_a_whole_round_failing_is_recorded_too():
    calls = []

    def objective(us):
        calls.append(list(us))
        if len(calls) == 1:
            raise OSError("launcher down")
        return [gap_curve(0.2)(u) for u in us]

    res = ORPSearch(k=2).run(objective)
    first = [e for e in res.evaluations if e.round == 1]
    assert len(first) == 2 and all(e.status == "failed" and "launcher down" in e.error for e in first)
    assert res.found and res.mean >= 0.2


@pytest.mark.parametrize("u_star", [0.02, 0.137, 0.61])
@pytest.mark.parametrize("k", [2, 3, 5])
def test_k_section_agrees_with_bisection(k, u_star):
    bis = ORPSearch(tolerance=0.1).run(batched(gap_curve(u_star)))
    ks = ORPSearch(tolerance=0.1, k=k).run(batched(gap_curve(u_star)))
    check_brackets(bis, u_star)
    check_brackets(ks, u_star)
    assert abs(math.log(ks.mean / bis.mean)) <= math.log(1.1)
    assert ks.rounds < bis.rounds  # the point of k-section: fewer (parallel) rounds
    assert all(len({e.u for e in ks.evaluations if e.round == r}) <= k for r in range(1, ks.rounds + 1))


def test_ask_tell_protocol_and_max_rounds():
    s = ORPSearch(k=3, max_rounds=2)
    batch = s.next_batch()
    assert batch == [0.031623, 0.1, 0.31623]
    with pytest.raises(RuntimeError, match="tell"):
        s.next_batch()
    s.tell([5.0, 0.5, 0.1])  # only 0.1 and 0.31623 pass
    assert (s.lo, s.hi) == (0.031623, 0.1)
    second = s.next_batch()
    assert len(second) == 3 and all(0.031623 < u < 0.1 for u in second)
    s.tell([5.0, 5.0, 5.0])  # none passes: 0.1 stays the answer, lo moves up
    assert (s.lo, s.hi) == (second[-1], 0.1)
    assert s.next_batch() == [] and s.result().stop_reason == "max_rounds" and s.result().mean == 0.1
    with pytest.raises(RuntimeError, match="pending"):
        s.tell([1.0])


def test_evaluation_from_normalizes_outcomes():
    assert evaluation_from(0.1, 1, 0.5).meets(1.0)
    assert not evaluation_from(0.1, 1, 1.5).meets(1.0)
    assert evaluation_from(0.1, 1, {"gap_db": 0.2, "ipr": 0.1}).record["ipr"] == 0.1
    assert evaluation_from(0.1, 1, {"ipr": 0.1}).status == "failed"           # no gap
    assert evaluation_from(0.1, 1, "abc").status == "failed"
    assert evaluation_from(0.1, 1, float("inf")).status == "failed"
    e = evaluation_from(0.1, 1, orp.ORPJobError("InputError: model.lr=-1: expected a positive number"))
    assert e.error == "InputError: model.lr=-1: expected a positive number"


# ---- the margin for unseen views: a one-sided confidence bound on the mean gap ------------------
@pytest.mark.parametrize("confidence", [0.5, 0.8, 0.95, 0.99])
def test_gap_upper_bound_against_a_direct_computation(confidence):
    import numpy as np

    gaps = [0.4, 1.3, 0.9, 0.2, 1.1, 0.75, 0.6]
    z = {0.5: 0.0, 0.8: 0.8416212335729143, 0.95: 1.6448536269514722, 0.99: 2.3263478740408408}[confidence]
    b = orp.gap_upper_bound(gaps, confidence)
    direct = np.mean(gaps) + z * np.std(gaps, ddof=1) / np.sqrt(len(gaps))
    assert b.views == 7 and b.confidence == confidence
    assert b.mean == pytest.approx(np.mean(gaps)) and b.std == pytest.approx(np.std(gaps, ddof=1))
    assert b.bound == pytest.approx(direct, abs=1e-9) and b.margin == pytest.approx(direct - np.mean(gaps), abs=1e-9)


@pytest.mark.parametrize("future_views", [1, 24, 120])
def test_gap_upper_bound_for_new_views_against_a_direct_computation(future_views):
    """A prediction bound: the mean of m new views varies too, so the margin is z * s * sqrt(1/n + 1/m)."""
    import numpy as np

    gaps = [0.4, 1.3, 0.9, 0.2, 1.1, 0.75, 0.6, 2.0]
    b = orp.gap_upper_bound(gaps, 0.95, future_views=future_views)
    direct = np.mean(gaps) + 1.6448536269514722 * np.std(gaps, ddof=1) * np.sqrt(1 / len(gaps) + 1 / future_views)
    assert b.bound == pytest.approx(direct, abs=1e-9) and b.future_views == future_views
    assert b.bound > orp.gap_upper_bound(gaps, 0.95).bound  # wider than the bound on the mean
    with pytest.raises(InputError, match="future_views=0"):
        orp.gap_upper_bound(gaps, 0.95, future_views=0)


def test_gap_upper_bound_one_view_and_bad_input():
    assert orp.gap_upper_bound([0.7], 0.95).bound == 0.7  # no spread to estimate
    for gaps, conf, needle in (([], 0.95, "no per-view gaps"), ([1.0, math.nan], 0.95, "non-finite per-view gap"),
                               ([1.0], 1.0, "orp_confidence=1.0: expected a confidence in [0.5, 1)"),
                               ([1.0], 0.3, "orp_confidence=0.3")):
        with pytest.raises(InputError, match=re.escape(needle)):
            orp.gap_upper_bound(gaps, conf)


def test_stratified_gap_bound_is_the_plain_bound_in_each_stratum_and_keeps_the_worst():
    gaps, strata = [2.0, 1.6, 0.2, 0.4, 0.3, 1.9], [0, 0, 1, 1, 1, 0]
    worst, each = orp.stratified_gap_bound(gaps, strata, 0.95, future_views=12)
    assert [e.views for e in each] == [3, 3] and [e.future_views for e in each] == [6, 6]
    assert each[0].bound == pytest.approx(orp.gap_upper_bound([2.0, 1.6, 1.9], 0.95, 6).bound)
    assert each[1].bound == pytest.approx(orp.gap_upper_bound([0.2, 0.4, 0.3], 0.95, 6).bound)
    assert worst is each[0] and worst.mean > orp.gap_upper_bound(gaps, 0.95, 12).mean
    # one stratum: the plain bound
    one, _ = orp.stratified_gap_bound(gaps, [0] * 6, 0.95, 12)
    assert one.bound == pytest.approx(orp.gap_upper_bound(gaps, 0.95, 12).bound)
    with pytest.raises(InputError, match="6 gaps but 5 stratum labels"):
        orp.stratified_gap_bound(gaps, strata[:5])


# ---- views along camera paths: a pass, not a view, is one observation ---------------------------
def test_path_passes_split_each_path_where_its_band_changes():
    #            path 0 ............  path 1 .........
    paths = [0, 0, 0, 0, 0, 1, 1, 1, 1]
    bands = [1, 1, 0, 0, 1, 1, 1, 0, 1]
    assert orp.path_passes(paths, bands) == [0, 0, 1, 1, 2, 3, 3, 4, 5]
    assert orp.path_passes(paths) == [0] * 5 + [1] * 4  # no bands: a path is one pass
    with pytest.raises(InputError, match="9 path labels but 2 stratum labels"):
        orp.path_passes(paths, [0, 1])


@pytest.mark.parametrize("future_passes", [None, 1, 3])
def test_pass_gap_bound_is_the_plain_bound_over_pass_means(future_passes):
    """Each pass weighs alike whatever its length: a direct computation on the pass means."""
    import numpy as np

    gaps, passes = [1.0, 1.2, 1.1, 0.2, 0.6, 0.6, 0.9], [0, 0, 0, 1, 2, 2, 3]
    means = np.array([1.1, 0.2, 0.6, 0.9])
    b = orp.pass_gap_bound(gaps, passes, 0.95, future_passes)
    spread = np.sqrt(1 / 4 + (1 / future_passes if future_passes else 0.0))
    assert b.mean == pytest.approx(means.mean()) and b.std == pytest.approx(means.std(ddof=1))
    assert b.bound == pytest.approx(means.mean() + 1.6448536269514722 * means.std(ddof=1) * spread, abs=1e-9)
    assert (b.views, b.passes, b.future_views) == (7, 4, future_passes)


def test_pass_gap_bound_promises_nothing_from_one_pass_and_more_than_the_views_alone():
    import math as _math

    one = orp.pass_gap_bound([0.6, 0.7, 0.65], [3, 3, 3], 0.95, 1)
    assert one.bound == _math.inf and one.passes == 1 and one.mean == pytest.approx(0.65)
    # ten correlated views of two passes: the views alone would claim a tight bound
    gaps = [0.30, 0.32, 0.31, 0.33, 0.30, 0.90, 0.92, 0.91, 0.89, 0.90]
    by_pass = orp.pass_gap_bound(gaps, [0] * 5 + [1] * 5, 0.95, 1)
    assert by_pass.bound > 1.0 > orp.gap_upper_bound(gaps, 0.95, 10).bound
    with pytest.raises(InputError, match="3 gaps but 2 pass labels"):
        orp.pass_gap_bound([1.0, 1.0, 1.0], [0, 1])


def test_stratified_gap_bound_with_passes_bounds_each_bands_passes_for_one_new_path():
    gaps = [2.0, 1.6, 0.2, 0.4, 0.3, 1.9, 1.7, 0.5]
    strata = [0, 0, 1, 1, 1, 0, 0, 1]
    paths = [0, 0, 0, 0, 0, 1, 1, 1]
    passes = orp.path_passes(paths, strata)  # [0, 0, 1, 1, 1, 2, 2, 3]
    worst, each = orp.stratified_gap_bound(gaps, strata, 0.95, 8, passes, paths=2)
    assert [e.passes for e in each] == [2, 2] and [e.future_views for e in each] == [1, 1]
    assert each[0].bound == pytest.approx(orp.pass_gap_bound([2.0, 1.6, 1.9, 1.7], [0, 0, 2, 2], 0.95, 1).bound)
    assert each[1].bound == pytest.approx(orp.pass_gap_bound([0.2, 0.4, 0.3, 0.5], [1, 1, 1, 3], 0.95, 1).bound)
    assert worst is max(each, key=lambda e: e.bound)
    with pytest.raises(InputError, match="8 gaps but 7 pass labels"):
        orp.stratified_gap_bound(gaps, strata, 0.95, 8, passes[:7], paths=2)
    assert [orp.future_path_passes(p, 4) for p in (1, 4, 6, 9)] == [1, 1, 2, 2]
    with pytest.raises(InputError, match="orp_paths=0"):
        orp.future_path_passes(3, 0)


def test_protocol_gap_record_is_the_view_bound_then_the_pass_bound_then_the_worst_band():
    """One home for how the protocol judges per-view gaps (the ORP search and the two-pass sampler's share):
    the view bound; with passes, the pass bound for one new path replaces it; with bands, the worst band's."""
    gaps, passes, strata = [0.2, 0.4, 0.9, 1.1, 0.3, 0.5], [0, 0, 1, 1, 2, 2], [0, 0, 1, 1, 0, 0]
    plain = orp.protocol_gap_record(gaps, 0.95, 6)
    b = orp.gap_upper_bound(gaps, 0.95, 6)
    assert (plain["gap_db"], plain["gap_std_db"], plain["gap_bound_db"], plain["views"]) == (b.mean, b.std, b.bound, 6)
    assert "passes" not in plain and "strata_gap_db" not in plain
    by_pass = orp.protocol_gap_record(gaps, 0.95, 6, passes=passes, paths=3)
    pb = orp.pass_gap_bound(gaps, passes, 0.95, orp.future_path_passes(3, 3))
    assert (by_pass["gap_db"], by_pass["gap_bound_db"], by_pass["passes"]) == (b.mean, pb.bound, 3)
    banded = orp.protocol_gap_record(gaps, 0.95, 6, strata=strata)
    worst, each = orp.stratified_gap_bound(gaps, strata, 0.95, 6)
    assert banded["gap_bound_db"] == worst.bound and banded["strata_gap_db"] == [e.mean for e in each]


def test_strata_by_rank_makes_equal_count_bands_by_value():
    assert orp.strata_by_rank([5, 1, 4, 2, 3, 6], 3) == [2, 0, 1, 0, 1, 2]
    assert orp.strata_by_rank([1.0, 2.0], 4) == [0, 1]  # more strata than values: one value each
    assert orp.strata_by_rank([2.0, 2.0, 1.0], 1) == [0, 0, 0]
    with pytest.raises(InputError, match="orp_strata=0"):
        orp.strata_by_rank([1.0], 0)


def test_the_search_judges_the_criterion_key():
    """criterion="gap_bound_db": the bound decides; the mean gap stays in the record."""
    # mean gap 1 - 2u (within 1 dB everywhere), bound = mean + 0.5: within 1 dB from u = 0.25
    rec = lambda u: {"gap_db": 1.0 - 2 * u, "gap_bound_db": 1.5 - 2 * u}  # noqa: E731
    plain = ORPSearch(epsilon_db=1.0, bracket=(0.01, 1.0), tolerance=0.02).run(batched(rec))
    margin = ORPSearch(epsilon_db=1.0, bracket=(0.01, 1.0), tolerance=0.02, criterion="gap_bound_db").run(batched(rec))
    assert plain.mean < 0.05 and 0.25 <= margin.mean <= 0.25 * 1.02 + 1e-9
    assert margin.best.record["gap_db"] == pytest.approx(1.0 - 2 * margin.mean)
    assert evaluation_from(0.1, 1, {"gap_db": 0.2}, criterion="gap_bound_db").error == "missing result (the job returned no gap_bound_db)"


@pytest.mark.parametrize("module", ["imls_lightning.orp.search", "imls_lightning.orp"])
def test_search_imports_no_torch(module):
    """The search (and the package the Hydra sweeper plugin imports while Hydra scans plugins) loads no torch."""
    code = f"import sys, {module}; assert 'torch' not in sys.modules, sorted(m for m in sys.modules if 'torch' in m)[:5]"
    p = subprocess.run([PY, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]


# ---- settings -----------------------------------------------------------------------------
@pytest.mark.parametrize("knobs, needle", [
    ({"epsilon_db": -1}, "sweeper.epsilon_db=-1: expected a number of dB >= 0"),
    ({"epsilon_db": "abc"}, "sweeper.epsilon_db='abc'"),
    ({"bracket": [0.5, 0.1]}, "sweeper.bracket=[0.5, 0.1]: expected lo < hi"),
    ({"bracket": [0.001, 1]}, "must lie in [0.01, 1.0]"),
    ({"bracket": 0.5}, "sweeper.bracket=0.5: expected two mean values"),
    ({"tolerance": 0}, "sweeper.tolerance=0"),
    ({"k": 0}, "sweeper.k=0: expected an integer >= 1"),
    ({"k": 1.5}, "sweeper.k=1.5"),
    ({"max_rounds": 0}, "sweeper.max_rounds=0"),
    ({"scale": "exp"}, "sweeper.scale='exp'"),
    ({"gap_of": "imls"}, "needs sweeper.with_ims=true"),
    ({"with_ims": "yes"}, "sweeper.with_ims='yes'"),
    ({"ims_overrides": ["model.layers"]}, "sweeper.ims_overrides"),
    ({"latency_renderer": "ospray"}, "sweeper.latency_renderer='ospray'"),
    ({"device": "tpu"}, "sweeper.device='tpu'"),
    ({"param": "+model.mean"}, "sweeper.param='+model.mean'"),
    ({"epsilon": 1}, "sweeper.epsilon: unknown knob"),
])
def test_exception_bad_settings_are_one_line_input_errors(knobs, needle):
    with pytest.raises(InputError) as info:
        ORPSettings.from_mapping(knobs, prefix="sweeper.")
    assert needle in str(info.value) and "\n" not in str(info.value)


# ---- the real CLI sweep -------------------------------------------------------------------
