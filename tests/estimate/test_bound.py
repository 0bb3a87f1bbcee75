"""The estimate's bound against a direct implementation of its formula."""
from __future__ import annotations

import math

import pytest

from data_gen.errors import InputError
from imls_lightning.estimate import (SHARES, RenderCost, bound_table, share_for_speedup, speedup_at,
                                     speedup_from_estimate)

COST = RenderCost(fixed_ms=0.8, object_ms_per_px=0.006, background_ms_per_px=0.0004, object_px=30000, background_px=35536)


def direct_speedup(share, c_render_ms, nets_ms, recnn_ms, b):
    """The formula written out: object first at density d, background at b d, the object full first."""
    K, Ko, Kb = COST.pixels, COST.object_px, COST.background_px
    n = share * K
    d = n / (Ko + b * Kb)
    if d <= 1:
        no, nb = d * Ko, d * b * Kb
    else:
        no, nb = Ko, min(n - Ko, Kb)
    render = COST.fixed_ms + no * COST.object_ms_per_px + nb * COST.background_ms_per_px
    return (c_render_ms + recnn_ms) / (nets_ms + render + recnn_ms)


@pytest.mark.parametrize("b", [0.1, 0.25, 1.0])
@pytest.mark.parametrize("share", [0.0, 0.05, 0.3, 0.62, 1.0])
def test_speedup_matches_direct_formula(share, b):
    got = speedup_at(COST, share, c_render_ms=200.0, nets_ms=30.0, recnn_ms=15.0, background_density=b)
    assert got == pytest.approx(direct_speedup(share, 200.0, 30.0, 15.0, b), rel=1e-12)


def test_all_pixels_cost_the_whole_pattern_and_the_mask_never_exceeds_it():
    for b in (0.1, 0.5, 1.0):
        no, nb = COST.pixels_at(1.0, b)
        assert (no, nb) == (COST.object_px, COST.background_px)
        for s in SHARES:
            no, nb = COST.pixels_at(s, b)
            assert no <= COST.object_px + 1e-9 and nb <= COST.background_px + 1e-9
            assert no + nb == pytest.approx(s * COST.pixels)


def test_uniform_density_samples_object_and_background_alike():
    no, nb = COST.pixels_at(0.4, 1.0)
    assert no / COST.object_px == pytest.approx(nb / COST.background_px) == pytest.approx(0.4)


def test_bound_table_is_monotone_and_limit_exceeds_bound():
    rows = bound_table(COST, c_render_ms=240.0, nets_ms=30.0, recnn_ms=15.0)
    assert [r["share"] for r in rows] == list(SHARES)
    sp = [r["speedup"] for r in rows]
    assert all(a >= b for a, b in zip(sp, sp[1:]))
    assert all(r["limit"] > r["speedup"] for r in rows)


def test_share_for_speedup_picks_the_largest_share_reaching_the_target():
    rows = [{"share": s, "speedup": 3.0 - 2.0 * s} for s in SHARES]   # 2.8 ... 1.0
    assert share_for_speedup(rows, 2.0) == 0.5
    assert share_for_speedup(rows, 5.0) is None
    assert share_for_speedup(rows, 1.0) == 1.0


def test_speedup_from_estimate_reads_the_json_content():
    est = {"render_cost": COST.to_dict(), "c_render_ms": 240.0, "nets_ms": 30.0, "recnn_ms": 15.0, "background_density": 0.25}
    assert speedup_from_estimate(est, 0.37) == pytest.approx(direct_speedup(0.37, 240.0, 30.0, 15.0, 0.25))
    with pytest.raises(InputError, match="estimate: missing"):
        speedup_from_estimate({"c_render_ms": 1.0}, 0.5)


def test_extremes_stay_finite():
    empty = RenderCost(0.0, 0.0, 0.0, 0, 0)
    for s in (0.0, 1.0):
        v = speedup_at(empty, s, c_render_ms=0.0, nets_ms=1.0, recnn_ms=1.0)
        assert math.isfinite(v) and v == pytest.approx(0.5)
    only_bg = RenderCost(0.1, 0.0, 0.001, 0, 1000)
    assert math.isfinite(speedup_at(only_bg, 0.5, c_render_ms=1.1, nets_ms=0.0, recnn_ms=0.0))


@pytest.mark.parametrize("kw,match", [({"share": 1.5}, "share=1.5"), ({"share": -0.1}, "share=-0.1"),
                                      ({"background_density": 0.0}, "background_density=0.0"),
                                      ({"background_density": 2.0}, "background_density=2.0")])
def test_exception_bad_share_or_density(kw, match):
    args = {"share": 0.5, "background_density": 0.25, **kw}
    with pytest.raises(InputError, match=match) as e:
        COST.render_ms(args["share"], args["background_density"])
    assert "\n" not in str(e.value)


def test_render_curve_interpolates_from_the_fixed_cost_and_ignores_the_density():
    from imls_lightning.estimate import RenderCurve

    curve = RenderCurve(shares=(0.2, 0.6, 1.0), times_ms=(30.0, 70.0, 90.0), fixed_ms=2.0)
    assert curve.render_ms(0.1) == pytest.approx(16.0) and curve.render_ms(0.4) == pytest.approx(50.0)
    assert curve.render_ms(1.0) == 90.0 and curve.render_ms(0.0) == 2.0 and curve.render_ms(0.8, 0.5) == pytest.approx(80.0)
    # the bound with a curve is the formula with the measured time
    for row in bound_table(curve, c_render_ms=100.0, nets_ms=10.0, recnn_ms=5.0, shares=(0.2, 0.6)):
        assert row["speedup"] == pytest.approx(105.0 / (10.0 + curve.render_ms(row["share"]) + 5.0), rel=1e-12)


def test_speedup_from_estimate_prefers_the_measured_curve():
    from imls_lightning.estimate import RenderCurve

    curve = RenderCurve(shares=(0.5, 1.0), times_ms=(150.0, 240.0), fixed_ms=1.0)
    est = {"render_cost": COST.to_dict(), "render_curve": curve.to_dict(), "c_render_ms": 240.0, "nets_ms": 30.0,
           "recnn_ms": 15.0, "background_density": 0.25}
    assert speedup_from_estimate(est, 0.5) == pytest.approx(255.0 / (30.0 + 150.0 + 15.0), rel=1e-12)
    assert speedup_from_estimate({**est, "render_curve": None}, 0.37) == pytest.approx(direct_speedup(0.37, 240.0, 30.0, 15.0, 0.25))


def test_speedup_from_estimate_reads_the_curve_of_the_kept_sharpness():
    """A row whose ORP kept gamma = 2 reads the estimate's curve for gamma 2; a sharpness the estimate has no curve
    for (an estimate made before by_sharpness) reads the paper's masks' curve."""
    from imls_lightning.estimate import RenderCurve

    paper = RenderCurve(shares=(0.5, 1.0), times_ms=(150.0, 240.0), fixed_ms=0.0)
    sharp = RenderCurve(shares=(0.5, 1.0), times_ms=(180.0, 240.0), fixed_ms=0.0)
    est = {"render_cost": COST.to_dict(), "render_curve": paper.to_dict(), "c_render_ms": 240.0, "nets_ms": 30.0,
           "recnn_ms": 15.0, "background_density": 0.25, "by_sharpness": {"2": {"render_curve": sharp.to_dict()}}}
    assert speedup_from_estimate(est, 0.5, 2.0) == pytest.approx(255.0 / (30.0 + 180.0 + 15.0), rel=1e-12)
    assert speedup_from_estimate(est, 0.5, 1.0) == pytest.approx(255.0 / (30.0 + 150.0 + 15.0), rel=1e-12)
    assert speedup_from_estimate(est, 0.5, 1.5) == speedup_from_estimate(est, 0.5)
    assert speedup_from_estimate({k: v for k, v in est.items() if k != "by_sharpness"}, 0.5, 2.0) == speedup_from_estimate(est, 0.5)


@pytest.mark.parametrize("shares,times", [((), ()), ((0.5, 0.2), (1.0, 2.0)), ((0.0, 1.0), (1.0, 2.0)), ((0.5,), (1.0, 2.0))])
def test_exception_bad_render_curve(shares, times):
    from imls_lightning.estimate import RenderCurve

    with pytest.raises(InputError, match="render_curve: expected ascending shares") as e:
        RenderCurve(shares=shares, times_ms=times)
    assert "\n" not in str(e.value)


def test_slower_render_takes_the_slower_prediction_at_each_share():
    from imls_lightning.estimate import RenderCurve, slower_render

    curve = RenderCurve(shares=SHARES, times_ms=tuple(300.0 * s for s in SHARES), fixed_ms=0.8)
    out = slower_render(curve, COST, 0.25)
    for s, t, c in zip(out.shares, out.times_ms, curve.times_ms):
        assert t == max(c, COST.render_ms(s, 0.25))
    assert out.fixed_ms == 0.8 and out.shares == curve.shares
    assert any(t > c for t, c in zip(out.times_ms, curve.times_ms)) and any(t == c for t, c in zip(out.times_ms, curve.times_ms))
