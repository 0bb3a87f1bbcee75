"""The estimate's bound against a direct implementation of its formula."""
from __future__ import annotations

import math

import numpy as np
import pytest

from imls_lightning.base.errors import InputError
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


def _estimate_with_views(c=(2000.0, 2600.0, 1800.0, 2400.0, 2200.0, 2900.0), seed=4):
    """An estimate.json's content whose curve is the mean of its views' (as the estimate makes it), with a sharpened
    curve of its own: each view's silhouette fractions rise with the share, differently per view."""
    from imls_lightning.estimate import SHARES, RenderCost, RenderCurve, slower_render

    rng = np.random.default_rng(seed)
    shares = np.array(SHARES)
    frac = np.array([shares ** (1.0 + 0.4 * rng.random()) for _ in c])
    sharp = np.minimum(frac * 1.15, 1.0)
    cs = np.array(c)
    model = RenderCost(fixed_ms=1.0, object_ms_per_px=0.01, background_ms_per_px=0.005, object_px=20000, background_px=45536)
    curve = slower_render(RenderCurve(SHARES, tuple((frac * cs[:, None]).mean(axis=0)), model.fixed_ms), model, 0.25)
    curve3 = slower_render(RenderCurve(SHARES, tuple((sharp * cs[:, None]).mean(axis=0)), model.fixed_ms), model, 0.25 ** 3)
    return {"c_render_ms": float(cs.mean()), "nets_ms": 60.0, "recnn_ms": 40.0, "background_density": 0.25,
            "render_cost": model.to_dict(), "render_curve": curve.to_dict(),
            "per_view": [{"c_render_ms": float(x), "silhouette_fractions": f.tolist()} for x, f in zip(cs, frac)],
            "by_sharpness": {"3": {"background_density": 0.25 ** 3, "render_curve": curve3.to_dict(),
                                   "silhouette_fractions_per_view": sharp.tolist()}}}


def _direct_interval(est, share, frac_key, density, resamples, seed):
    """The interval one draw at a time, through the package's own curve and bound (RenderCurve, slower_render, speedup_at)."""
    from imls_lightning.estimate import SHARES, RenderCost, RenderCurve, slower_render, speedup_at

    model = RenderCost(**est["render_cost"])
    c = np.array([v["c_render_ms"] for v in est["per_view"]])
    frac = np.array(frac_key)
    idx = np.random.default_rng(seed).integers(0, len(c), size=(resamples, len(c)))
    out = []
    for draw in idx:
        curve = slower_render(RenderCurve(SHARES, tuple((frac[draw] * c[draw][:, None]).mean(axis=0)), model.fixed_ms), model, density)
        out.append(speedup_at(curve, share, c_render_ms=c[draw].mean(), nets_ms=est["nets_ms"], recnn_ms=est["recnn_ms"]))
    return np.quantile(out, [0.025, 0.975])


@pytest.mark.parametrize("share", [0.05, 0.2, 0.375, 0.95, 1.0])
def test_the_estimates_interval_is_a_bootstrap_of_its_own_bound_over_its_views(share):
    from imls_lightning.estimate import estimate_interval, speedup_from_estimate

    est = _estimate_with_views()
    iv = estimate_interval(est, share, resamples=300, seed=2)
    assert iv.speedup == pytest.approx(speedup_from_estimate(est, share), rel=1e-9) and iv.views == 6
    lo, hi = _direct_interval(est, share, [v["silhouette_fractions"] for v in est["per_view"]], 0.25, 300, 2)
    assert (iv.low, iv.high) == (pytest.approx(lo, rel=1e-9), pytest.approx(hi, rel=1e-9))
    sharp = estimate_interval(est, share, sharpness=3.0, resamples=300, seed=2)  # a sharpened mask's own curve
    assert sharp.speedup == pytest.approx(speedup_from_estimate(est, share, 3.0), rel=1e-9)
    lo, hi = _direct_interval(est, share, est["by_sharpness"]["3"]["silhouette_fractions_per_view"], 0.25 ** 3, 300, 2)
    assert (sharp.low, sharp.high) == (pytest.approx(lo, rel=1e-9), pytest.approx(hi, rel=1e-9))


def test_an_estimate_without_per_view_times_or_whose_views_do_not_give_its_curve_has_no_interval():
    """Never trust a record that does not give back its own curve: rt_plumes's row estimate took a median over its
    views, and its per-view times made a curve 7% lower; such an estimate gets no interval rather than a wrong one."""
    from imls_lightning.estimate import bound_intervals, estimate_interval

    est = _estimate_with_views()
    assert estimate_interval({k: v for k, v in est.items() if k != "per_view"}, 0.3) is None
    shifted = {**est, "render_curve": {**est["render_curve"], "times_ms": [1.07 * t for t in est["render_curve"]["times_ms"]]}}
    assert estimate_interval(shifted, 0.3) is None and bound_intervals(shifted) is None
    assert estimate_interval({k: v for k, v in est.items() if k != "render_cost"}, 0.3) is None
    table = bound_intervals(est)
    assert [r["share"] for r in table] == pytest.approx([0.1 * i for i in range(1, 11)])
    assert all(r["low"] <= r["high"] for r in table) and table[0]["low"] > table[-1]["high"]  # fewer pixels, faster
    from imls_lightning.estimate import RenderCurve, slower_render

    same = _estimate_with_views(c=(2000.0,) * 6, seed=0)  # six copies of one view: nothing to resample
    same["per_view"] = [same["per_view"][0]] * 6
    one = RenderCurve(SHARES, tuple(2000.0 * np.array(same["per_view"][0]["silhouette_fractions"])), 1.0)
    same["render_curve"] = slower_render(one, RenderCost(**same["render_cost"]), 0.25).to_dict()
    iv = estimate_interval(same, 0.3)
    assert iv.low == pytest.approx(iv.speedup) and iv.high == pytest.approx(iv.speedup)
